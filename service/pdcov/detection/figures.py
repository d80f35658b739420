"""The paper's Fig. 6: P_D (recall) and precision by object size, and beside them the
false boxes per frame per Mpx that the grid's P_FA uses, with 95 % intervals and, given a
validation report, the per-bin p-values written over the bins (and the split's measured
rate).

matplotlib is an optional extra (``pdcov[plots]``); it is imported when a figure is drawn,
with the non-interactive Agg canvas, so nothing here touches a display.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.core.detector import DetectorModel
from pdcov.detection.validation import BinTest, RateTest, ValidationReport
from pdcov.errors import PdcovError


def plot_detector_model(model: DetectorModel, out_path: str | Path,
                        report: ValidationReport | None = None,
                        title: str | None = None) -> None:
    """Write the figure to ``out_path`` (format from its suffix)."""
    detector_figure(model, report, title).savefig(out_path, dpi=150)


def detector_figure(model: DetectorModel, report: ValidationReport | None = None,
                    title: str | None = None) -> Any:
    """The figure (a matplotlib Figure on the Agg canvas), drawn but not saved."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import LogLocator
    except ImportError:
        raise PdcovError("plotting needs matplotlib: pip install 'pdcov[plots]'") from None
    edges = np.asarray(model.bin_edges_px)
    scale = _x_scale(edges)
    # Bars are drawn at x positions: the edges themselves, or 0..N on an index axis.
    x_edges = np.arange(len(edges), dtype=float) if scale == "index" else edges
    rate = model.fa_rate_per_mpx
    fig = Figure(figsize=(10, 6.5 if rate is None else 9), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(2 if rate is None else 3, 1, sharex=True)
    ax_d, ax_p, ax_x = axes[0], axes[1], axes[-1]  # ax_x: the bottom axis, with the sizes
    precision = 1 - np.asarray(model.p_false_alarm)
    ci_fa = model.extra.get("p_false_alarm_ci95")
    ci_p = [[1 - hi, 1 - lo] for lo, hi in ci_fa] if ci_fa else None
    # A binned model's empty bins hold no estimate; a logistic model's curve spans them.
    no_data = np.zeros(model.n_bins, bool), np.zeros(model.n_bins, bool)
    if model.counts is not None and model.extra.get("model") != "logistic":
        no_data = (np.asarray(model.counts.n_true) == 0,
                   np.asarray(model.counts.n_detections) == 0)
    # A validation report on the model's own bins is drawn at their places; on other bins
    # only where the axis shows sizes.
    report_x = measured_x = None
    if report is not None:
        r_edges = np.asarray(report.bin_edges_px)
        if scale != "index":
            report_x, measured_x = _centres(r_edges, scale), _centres(r_edges, scale, 0.7)
        elif np.array_equal(r_edges, edges):
            report_x = _centres(x_edges, "linear")
            measured_x = _centres(x_edges, "linear", 0.7)
    _panel(ax_d, x_edges, scale, np.asarray(model.p_detect), model.extra.get("p_detect_ci95"),
           "P_D (recall)", "tab:blue", no_data[0], report.detect if report else None,
           report, report_x)
    _panel(ax_p, x_edges, scale, precision, ci_p, "precision\n(the paper's 1 − P_FA)",
           "tab:orange", no_data[1], report.precision if report else None, report, report_x)
    if rate is not None:
        _rate_panel(ax_x, x_edges, scale, np.asarray(rate),
                    model.extra.get("fa_rate_per_mpx_ci95"), report, report_x, measured_x)
    if scale == "log":
        ax_x.set_xscale("log")
        ax_x.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 3.0, 5.0)))
        ax_x.xaxis.set_major_formatter("{x:g}")
        ax_x.xaxis.set_minor_formatter("")
    elif scale == "index":
        # Edges spanning many orders of magnitude (0 to 1e9): equal-width bins, labelled.
        step = max(1, len(edges) // 16)
        ticks = np.arange(0, len(edges), step)
        ax_x.set_xticks(ticks, [f"{edges[i]:.4g}" for i in ticks],
                        rotation=45 if len(ticks) > 8 else 0)
    ax_x.set_xlim(x_edges[0], x_edges[-1])
    unit = (f"{model.input_size_px}-px detector input" if model.input_size_px
            else "image pixels")
    ax_x.set_xlabel(f"bounding-box side length sqrt(w·h), px ({unit})"
                    + ("; bins drawn equally wide, labelled by their edges"
                       if scale == "index" else ""))
    thresholds = []
    if model.confidence_threshold is not None:
        thresholds.append(f"confidence ≥ {model.confidence_threshold:g}")
    if model.iou_threshold is not None:
        thresholds.append(f"IoU ≥ {model.iou_threshold:g}")
    method = model.extra.get("interval_method")
    whiskers = f"whiskers: 95 % interval ({method})"
    fig.suptitle(textwrap.fill(title or "Detector model: recall and precision by object "
                               "size" + ("" if rate is None else ", and false boxes per Mpx"),
                               90))
    notes = thresholds + ([whiskers] if method else [])
    if report is not None:
        split = report.model.get("ground_truth")
        on = _short_path(str(split)) if split else "a second split"
        notes.append(f"p-values: {report.test} test on {on}, red < {report.alpha:g}")
    # Wrapped so that a long line never runs past the figure's edge.
    ax_d.set_title(textwrap.fill("   ".join(notes), 150), fontsize=8, color="0.3",
                   loc="left")
    return fig


def _x_scale(edges: np.ndarray) -> str:
    """'log', 'linear', or 'index' (equal-width bins) when the edges span so many orders of
    magnitude that some bin would be a sliver on either axis: narrower than a quarter of
    the mean bin width."""
    lo, hi = edges[:-1], edges[1:]
    log_axis = edges[0] > 0 and edges[-1] / edges[0] > 8
    w = np.log(hi / lo) if log_axis else hi - lo
    if w.min() < w.sum() / (4 * len(w)):
        return "index"
    return "log" if log_axis else "linear"


def _short_path(path: str, keep: int = 60) -> str:
    """A path shortened to its last parts, at most about ``keep`` characters."""
    if len(path) <= keep:
        return path
    parts = Path(path).parts
    out = parts[-1]
    for part in reversed(parts[:-1]):
        if len(out) + len(part) + 1 > keep - 2:
            break
        out = f"{part}/{out}"
    return f"…/{out}"


def _centres(edges: np.ndarray, scale: str, at: float = 0.5) -> np.ndarray:
    """Bin centres on the axis (``at`` 0.5; another share of the way across each bin):
    geometric on a log axis (mid-bin there), else midpoints."""
    lo, hi = edges[:-1], edges[1:]
    return lo ** (1 - at) * hi**at if scale == "log" else lo + at * (hi - lo)


def _panel(ax: Any, edges: np.ndarray, scale: str, p: np.ndarray,
           ci: list[list[float]] | None, label: str, color: str, no_data: np.ndarray,
           tests: Sequence[BinTest | RateTest] | None,
           report: ValidationReport | None, report_x: np.ndarray | None,
           y_max: float = 1.0) -> None:
    """One panel: bars over ``edges`` (axis positions) up to ``y_max``, whiskers, no-data
    hatching, and the report's p-values at ``report_x``."""
    from matplotlib.patches import Patch

    lo, width = edges[:-1], np.diff(edges)
    ok = ~no_data
    ax.bar(lo[ok], p[ok], width=width[ok], align="edge", color=color, alpha=0.75,
           edgecolor="white", linewidth=0.5)
    if no_data.any():
        ax.bar(lo[no_data], np.full(no_data.sum(), y_max), width=width[no_data], align="edge",
               facecolor="none", edgecolor="0.6", hatch="//", linewidth=0)
        # A legend entry of its own: the bar's zero-width edge would draw a garbled mark.
        ax.legend(handles=[Patch(facecolor="white", edgecolor="0.6", hatch="////",
                                 linewidth=0.8, label="no data")],
                  loc="upper right", fontsize=8, frameon=False, handlelength=2.5,
                  handleheight=1.2)
    if ci:
        c = np.asarray(ci, dtype=float)[ok]
        ax.errorbar(_centres(edges, scale)[ok], p[ok],
                    yerr=np.clip([p[ok] - c[:, 0], c[:, 1] - p[ok]], 0, None),
                    fmt="none", ecolor="black", elinewidth=1, capsize=2)
    ax.set_ylim(0, y_max * (1.3 if tests else 1.02))
    ax.set_yticks(np.linspace(0, y_max, 6))
    ax.set_ylabel(label)
    ax.grid(axis="y", color="0.9")
    ax.set_axisbelow(True)
    if tests and report is not None and report_x is not None:
        for x, t in zip(report_x, tests, strict=True):
            if t.p_value is None:
                continue
            bad = t.p_value < report.alpha
            ax.text(x, 1.03 * y_max, f"{t.p_value:.2g}", rotation=90, ha="center",
                    va="bottom", fontsize=7, color="tab:red" if bad else "0.2",
                    fontweight="bold" if bad else "normal")


def _rate_panel(ax: Any, edges: np.ndarray, scale: str, rate: np.ndarray,
                ci: list[list[float]] | None, report: ValidationReport | None,
                report_x: np.ndarray | None, measured_x: np.ndarray | None) -> None:
    """The model's false boxes per frame per Mpx with their interval; given a report, the
    split's measured rates (points at ``measured_x``, beside the model's whiskers, with
    their Garwood whiskers) and the p-values of the comparison at ``report_x``."""
    measured = report.fa_rate if report is not None and report_x is not None else ()
    tops = [rate.max(initial=0.0), *(hi for _, hi in ci or ()),
            *(t.rate_ci95[1] for t in measured)]
    _panel(ax, edges, scale, rate, ci, "false boxes / frame / Mpx\n(the grid's P_FA)",
           "tab:red", np.zeros(len(rate), bool), measured or None, report, report_x,
           _nice_ceiling(max(tops)))
    if measured and measured_x is not None:
        r = np.array([t.rate_per_mpx for t in measured])
        lo_hi = np.array([t.rate_ci95 for t in measured])
        ax.errorbar(measured_x, r, yerr=np.clip([r - lo_hi[:, 0], lo_hi[:, 1] - r], 0, None),
                    fmt="o", ms=3, color="0.35", elinewidth=0.8, capsize=2,
                    label="measured on the split")
        ax.legend(loc="upper left", fontsize=8, frameon=False)


def _nice_ceiling(v: float) -> float:
    """The smallest of 1, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten at or above ``v`` (1 for
    v <= 0): the rate axis's top."""
    if not v > 0:
        return 1.0
    power = 10.0 ** np.floor(np.log10(v))
    return float(next(m * power for m in (1, 2, 2.5, 3, 4, 5, 6, 8, 10)
                      if m * power >= v * (1 - 1e-12)))


def plot_looks(model: DetectorModel, out_path: str | Path, title: str | None = None) -> None:
    """Write the looks figure (``looks_figure``) to ``out_path`` (format from its suffix)."""
    looks_figure(model, title).savefig(out_path, dpi=150)


MIN_CURVE_PEOPLE = 5  # measured points from fewer people are not drawn


def looks_figure(model: DetectorModel, title: str | None = None) -> Any:
    """Per size bin with an estimate: the share of people found within n looks, measured on
    the tracks (a person is found within n looks if any of their first n looks in the bin
    was a hit), against the independent model 1 - (1 - mu)^n and the fitted beta-binomial
    1 - B(a, b + n) / B(a, b). Needs a model fitted on tracked sequences."""
    from pdcov.detection.looks_fit import found_within

    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PdcovError("plotting needs matplotlib: pip install 'pdcov[plots]'") from None
    lk = model.looks
    curves = lk.extra.get("found_within") if lk is not None else None
    if lk is None or not isinstance(curves, dict):
        raise PdcovError(f"{model.source or 'detector model'}: no looks section with measured "
                         f"curves; fit the model on tracked sequences (--format mot)")
    mean, rho = lk.extra.get("mean_pd", []), lk.extra.get("correlation_mle", [])
    bins = [i for i in range(model.n_bins) if i < len(mean) and mean[i] is not None]
    if not bins:
        raise PdcovError(f"{model.source or 'detector model'}: no bin has an estimate of the "
                         f"correlation of the looks")
    ncol = min(4, len(bins))
    nrow = -(-len(bins) // ncol)
    fig = Figure(figsize=(3.2 * ncol + 1, 2.6 * nrow + 1.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharex=True, sharey=True, squeeze=False))
    share = np.asarray(curves["share"], dtype=float)
    people = np.asarray(curves["n_people"], dtype=int)
    n = np.arange(1, share.shape[1] + 1)
    for ax, i in zip(axes.flat, bins, strict=False):
        ok = people[i] >= MIN_CURVE_PEOPLE
        ax.plot(n[ok], share[i][ok], "o", ms=3, color="black", label="measured")
        ax.plot(n, found_within(n, mean[i], 0.0), "--", color="tab:orange",
                label="independent looks")
        ax.plot(n, found_within(n, mean[i], rho[i]), "-", color="tab:blue",
                label="beta-binomial fit")
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        ax.set_title(f"{lo:g}–{hi:g} px: mean P_D {mean[i]:.2f}, ρ {rho[i]:.2f}", fontsize=8)
        ax.set_ylim(0, 1.02)
        ax.grid(color="0.9")
        ax.set_axisbelow(True)
    for ax in axes.flat[len(bins):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("looks n")
    for ax in axes[:, 0]:
        ax.set_ylabel("share found")
    axes.flat[0].legend(fontsize=7, loc="lower right", frameon=False)
    fig.suptitle(textwrap.fill(title or "Found within n looks: measured per person vs "
                               "independent looks vs beta-binomial", 90))
    return fig
