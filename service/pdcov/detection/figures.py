"""The paper's Fig. 6: P_D (recall) and precision by object size, with 95 % intervals and,
given a validation report, the per-bin p-values written over the bins.

matplotlib is an optional extra (``pdcov[plots]``); it is imported when a figure is drawn,
with the non-interactive Agg canvas, so nothing here touches a display.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pdcov.core.detector import DetectorModel
from pdcov.detection.statistics import BinTest, ValidationReport
from pdcov.errors import PdcovError


def plot_detector_model(model: DetectorModel, out_path: str | Path,
                        report: ValidationReport | None = None,
                        title: str | None = None) -> None:
    """Write the figure to ``out_path`` (format from its suffix)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.ticker import LogLocator
    except ImportError:
        raise PdcovError("plotting needs matplotlib: pip install 'pdcov[plots]'") from None
    edges = np.asarray(model.bin_edges_px)
    fig = Figure(figsize=(10, 6.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_d, ax_p = fig.subplots(2, 1, sharex=True)
    precision = 1 - np.asarray(model.p_false_alarm)
    ci_fa = model.extra.get("p_false_alarm_ci95")
    ci_p = [[1 - hi, 1 - lo] for lo, hi in ci_fa] if ci_fa else None
    # A binned model's empty bins hold no estimate; a logistic model's curve spans them.
    no_data = np.zeros(model.n_bins, bool), np.zeros(model.n_bins, bool)
    if model.counts is not None and model.extra.get("model") != "logistic":
        no_data = (np.asarray(model.counts.n_true) == 0,
                   np.asarray(model.counts.n_detections) == 0)
    _panel(ax_d, edges, np.asarray(model.p_detect), model.extra.get("p_detect_ci95"),
           "P_D (recall)", "tab:blue", no_data[0], report.detect if report else None, report)
    _panel(ax_p, edges, precision, ci_p, "precision (1 − P_FA)", "tab:orange", no_data[1],
           report.precision if report else None, report)
    if edges[0] > 0 and edges[-1] / edges[0] > 8:
        ax_p.set_xscale("log")
        ax_p.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 3.0, 5.0)))
        ax_p.xaxis.set_major_formatter("{x:g}")
        ax_p.xaxis.set_minor_formatter("")
    ax_p.set_xlim(edges[0], edges[-1])
    unit = (f"{model.input_size_px}-px detector input" if model.input_size_px
            else "image pixels")
    ax_p.set_xlabel(f"bounding-box side length sqrt(w·h), px ({unit})")
    thresholds = []
    if model.confidence_threshold is not None:
        thresholds.append(f"confidence ≥ {model.confidence_threshold:g}")
    if model.iou_threshold is not None:
        thresholds.append(f"IoU ≥ {model.iou_threshold:g}")
    method = model.extra.get("interval_method")
    whiskers = f"whiskers: 95 % interval ({method})"
    fig.suptitle(title or "Detector model: recall and precision by object size")
    notes = thresholds + ([whiskers] if method else [])
    if report is not None:
        split = report.model.get("ground_truth", "a second split")
        notes.append(f"p-values: {report.test} test on {split}, red < {report.alpha:g}")
    ax_d.set_title("   ".join(notes), fontsize=8, color="0.3", loc="left")
    fig.savefig(out_path, dpi=150)


def _centres(edges: np.ndarray) -> np.ndarray:
    """Bin centres: geometric (they sit mid-bin on a log axis) unless an edge is 0."""
    lo, hi = edges[:-1], edges[1:]
    return np.sqrt(lo * hi) if edges[0] > 0 else (lo + hi) / 2


def _panel(ax: Any, edges: np.ndarray, p: np.ndarray, ci: list[list[float]] | None,
           label: str, color: str, no_data: np.ndarray,
           tests: tuple[BinTest, ...] | None, report: ValidationReport | None) -> None:
    lo, width = edges[:-1], np.diff(edges)
    ok = ~no_data
    ax.bar(lo[ok], p[ok], width=width[ok], align="edge", color=color, alpha=0.75,
           edgecolor="white", linewidth=0.5)
    if no_data.any():
        ax.bar(lo[no_data], np.ones(no_data.sum()), width=width[no_data], align="edge",
               color="none", edgecolor="0.6", hatch="//", linewidth=0, label="no data")
        ax.legend(loc="upper right", fontsize=8, frameon=False)
    if ci:
        c = np.asarray(ci, dtype=float)[ok]
        ax.errorbar(_centres(edges)[ok], p[ok],
                    yerr=np.clip([p[ok] - c[:, 0], c[:, 1] - p[ok]], 0, None),
                    fmt="none", ecolor="black", elinewidth=1, capsize=2)
    ax.set_ylim(0, 1.3 if tests else 1.02)
    ax.set_yticks(np.linspace(0, 1, 6))
    ax.set_ylabel(label)
    ax.grid(axis="y", color="0.9")
    ax.set_axisbelow(True)
    if tests and report is not None:
        for x, t in zip(_centres(np.asarray(report.bin_edges_px)), tests, strict=True):
            if t.p_value is None:
                continue
            bad = t.p_value < report.alpha
            ax.text(x, 1.03, f"{t.p_value:.2g}", rotation=90, ha="center", va="bottom",
                    fontsize=7, color="tab:red" if bad else "0.2",
                    fontweight="bold" if bad else "normal")
