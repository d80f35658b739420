"""A detector model checked on another split of labelled data, per size bin: observed
detections against those the model predicts (binomial, chi-square or Fisher's exact test),
and the false boxes over the images' area against the model's rate (Poisson, or the
two-sample test of rates); the report and its JSON document."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from pdcov.core.detector import DetectorModel
from pdcov.detection.bins import BinnedCounts, bin_of, count_in_bins, false_box_rate, round_sig
from pdcov.detection.matching import Matches
from pdcov.errors import ConfigError, InputFileError

__all__ = ["VALIDATION_TESTS", "BinTest", "RateTest", "ValidationReport", "validate"]

VALIDATION_TESTS = ("binomial", "chi2", "fisher")


@dataclass(frozen=True, slots=True)
class BinTest:
    """One bin's check: trials n, observed successes, successes the model predicts, p-value
    (None for an empty bin)."""

    n: int
    observed: int
    expected: float
    p_value: float | None


@dataclass(frozen=True, slots=True)
class RateTest:
    """One bin's false boxes on the split: ``observed`` over the images' area, their rate
    (false boxes per frame per Mpx) with its 95 % Garwood interval, the count the model's
    rate predicts (None: not comparable, see ``validate``) and the p-value (None: untested).
    """

    observed: int
    rate_per_mpx: float
    rate_ci95: tuple[float, float]
    expected: float | None
    p_value: float | None


@dataclass(frozen=True, slots=True)
class ValidationReport:
    """Per-bin tests of a model on another split: detections among ground truth (P_D), true
    detections among detections (precision, the paper's 1 - P_FA) and false boxes over the
    images' area (``fa_rate``, the rate the grid uses; empty when the images' area is
    unknown, and in a report of version 1)."""

    bin_edges_px: tuple[float, ...]
    detect: tuple[BinTest, ...]
    precision: tuple[BinTest, ...]
    test: str
    alpha: float = 0.05
    model: dict[str, Any] = field(default_factory=dict)
    fa_rate: tuple[RateTest, ...] = ()
    image_area_mpx: float | None = None

    def n_failed(self, which: str) -> tuple[int, int]:
        """(bins with p < alpha, bins tested) for ``detect``, ``precision`` or ``fa_rate``."""
        tests = [t for t in getattr(self, which) if t.p_value is not None]
        return sum(t.p_value < self.alpha for t in tests), len(tests)

    def to_dict(self) -> dict[str, Any]:
        bins: list[dict[str, Any]] = []
        for i, (d, p) in enumerate(zip(self.detect, self.precision, strict=True)):
            bins.append({"lo_px": self.bin_edges_px[i], "hi_px": self.bin_edges_px[i + 1],
                         "n_true": d.n, "detected": d.observed,
                         "expected_detected": round(d.expected, 6), "p_value_detect": d.p_value,
                         "n_detections": p.n, "true_positives": p.observed,
                         "expected_true_positives": round(p.expected, 6),
                         "p_value_precision": p.p_value})
            if self.fa_rate:
                r = self.fa_rate[i]
                bins[-1].update(
                    false_boxes=r.observed, fa_rate_per_mpx=round_sig(r.rate_per_mpx),
                    fa_rate_per_mpx_ci95=[round_sig(v) for v in r.rate_ci95],
                    expected_false_boxes=None if r.expected is None else round_sig(r.expected),
                    p_value_fa_rate=r.p_value)
        fd, nd = self.n_failed("detect")
        fp, np_ = self.n_failed("precision")
        fr, nr = self.n_failed("fa_rate")
        return {"version": 2, "test": self.test, "alpha": self.alpha, "model": self.model,
                "image_area_mpx": self.image_area_mpx,
                "bins": bins, "failed_detect": fd, "tested_detect": nd,
                "failed_precision": fp, "tested_precision": np_,
                "failed_fa_rate": fr, "tested_fa_rate": nr}

    @classmethod
    def from_dict(cls, doc: Any, source: str) -> ValidationReport:
        """A report of version 2, or 1 (without the false-box rate)."""
        try:
            bins = doc["bins"]
            edges = tuple(float(b["lo_px"]) for b in bins) + (float(bins[-1]["hi_px"]),)
            detect = tuple(BinTest(int(b["n_true"]), int(b["detected"]),
                                   float(b["expected_detected"]), b["p_value_detect"])
                           for b in bins)
            precision = tuple(BinTest(int(b["n_detections"]), int(b["true_positives"]),
                                      float(b["expected_true_positives"]),
                                      b["p_value_precision"]) for b in bins)
            fa_rate = tuple(RateTest(int(b["false_boxes"]), float(b["fa_rate_per_mpx"]),
                                     (float(b["fa_rate_per_mpx_ci95"][0]),
                                      float(b["fa_rate_per_mpx_ci95"][1])),
                                     b["expected_false_boxes"], b["p_value_fa_rate"])
                            for b in bins) if "false_boxes" in bins[0] else ()
            return cls(edges, detect, precision, str(doc["test"]), float(doc["alpha"]),
                       dict(doc.get("model", {})), fa_rate, doc.get("image_area_mpx"))
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            raise InputFileError(f"{source}: not a pdcov validation report ({exc!r})") from None


def _poisson_test(k: int, expected: float) -> float:
    """Two-sided p-value of ``k`` events where Poisson(``expected``) are predicted: twice the
    smaller tail, at most 1 (1 for k = 0, 0 for k > 0 when nothing is expected)."""
    if expected <= 0:
        return 1.0 if k == 0 else 0.0
    tail = min(stats.poisson.cdf(k, expected), stats.poisson.sf(k - 1, expected))
    return float(min(1.0, 2 * tail))


def _rate_tests(model: DetectorModel, c: BinnedCounts, area_mpx: float, test: str
                ) -> tuple[RateTest, ...]:
    """The false boxes of each bin of ``c`` over ``area_mpx`` against the model's rate; ()
    when the area is unknown. The rate is compared only on the model's own bins (it is a
    count per bin, with no rule for a share of a bin) and when the model has one (version 4):
    elsewhere ``expected`` and the p-value are None. ``fisher``: the fit's false boxes over
    its area (``n_false_boxes``, ``fit.image_area_mpx``) against these, the exact
    conditional test of two Poisson rates (given both counts' sum, these are binomial with
    p = area / (area + fit's area) under equal rates)."""
    if not area_mpx > 0:
        return ()
    n_false = c.n_detections - c.n_true_positives
    rate, lo, hi = false_box_rate(n_false, area_mpx)
    model_rate = (model.fa_rate_per_mpx if c.edges_px == tuple(model.bin_edges_px)
                  else None)
    fit = model.extra.get("fit")
    fit_n, fit_area = model.extra.get("n_false_boxes"), (
        fit.get("image_area_mpx") if isinstance(fit, dict) else None)
    out = []
    for i, k in enumerate(int(v) for v in n_false):
        expected = p = None
        if model_rate is not None:
            expected = model_rate[i] * area_mpx
            if test != "fisher":
                p = _poisson_test(k, expected)
            elif fit_n is not None and fit_area and k + fit_n[i] > 0:
                p = float(stats.binomtest(k, k + int(fit_n[i]),
                                          area_mpx / (area_mpx + fit_area)).pvalue)
        out.append(RateTest(k, float(rate[i]), (float(lo[i]), float(hi[i])), expected, p))
    return tuple(out)


def _bin_test(n: int, k: int, expected: float, test: str,
              fitted: tuple[int, int] | None = None) -> BinTest:
    """``fitted``: (successes, trials) of the fit in this bin, for the two-sample test."""
    if n == 0 or (fitted is not None and fitted[1] == 0):
        return BinTest(n, k, expected, None)
    if fitted is not None:
        k0, n0 = fitted
        pv = stats.fisher_exact([[k, n - k], [k0, n0 - k0]]).pvalue
    elif test == "chi2" and 0 < expected < n:
        pv = stats.chisquare([k, n - k], [expected, n - expected]).pvalue
    else:  # exact; also where chi-square is undefined (a predicted count of 0)
        pv = stats.binomtest(k, n, min(max(expected / n, 0.0), 1.0)).pvalue
    return BinTest(n, k, expected, float(pv))


def validate(model: DetectorModel, matches: Matches, edges: tuple[float, ...] | None = None,
             test: str = "binomial", alpha: float = 0.05) -> ValidationReport:
    """Compare, per bin (the model's unless ``edges``), the observed detections with the
    number the model predicts: the sum of P_D over the ground truth in the bin, and of
    1 - P_FA over the detections; and the false boxes with the model's rate times the
    images' area (``_rate_tests``: on the model's own bins, exact Poisson test, or with
    ``fisher`` the two-sample test of rates).

    ``binomial``: exact two-sided test with the bin's mean predicted probability (exact for a
    binned model on its own bins); ``chi2``: Pearson's chi-square, one degree of freedom. Both
    take the model as exact, so they reject too often when the fit's split is not much larger
    than this one. ``fisher``: Fisher's exact test of the fit's counts against these (two
    samples; needs the model's counts and its own bins)."""
    if test not in VALIDATION_TESTS:
        raise ConfigError(f"--test: expected one of {VALIDATION_TESTS}, got {test!r}")
    if not 0 < alpha < 1:
        raise ConfigError(f"--alpha: expected a level in (0, 1), got {alpha}")
    edges = tuple(edges or model.bin_edges_px)
    n = len(edges) - 1
    fitted_d: list[tuple[int, int] | None] = [None] * n
    fitted_p: list[tuple[int, int] | None] = [None] * n
    if test == "fisher":
        tp = model.extra.get("n_true_positives")
        if model.counts is None or tp is None or edges != tuple(model.bin_edges_px):
            raise ConfigError("--test fisher compares with the counts of the fit: it needs a "
                              "model written by 'pdcov detector fit', tested on its own bins")
        fitted_d = list(zip(model.counts.n_detected, model.counts.n_true, strict=True))
        fitted_p = list(zip(tp, model.counts.n_detections, strict=True))
    c = count_in_bins(matches, edges)
    pd, _ = model.lookup(matches.truth_size_px)
    _, pfa = model.lookup(matches.detection_size_px)
    ti, di = bin_of(matches.truth_size_px, edges), bin_of(matches.detection_size_px, edges)
    exp_d = np.bincount(ti[ti >= 0], pd[ti >= 0], minlength=n)
    exp_tp = np.bincount(di[di >= 0], 1 - pfa[di >= 0], minlength=n)
    return ValidationReport(
        edges,
        tuple(_bin_test(int(c.n_true[i]), int(c.n_detected[i]), float(exp_d[i]), test,
                        fitted_d[i]) for i in range(n)),
        tuple(_bin_test(int(c.n_detections[i]), int(c.n_true_positives[i]), float(exp_tp[i]),
                        test, fitted_p[i]) for i in range(n)),
        test, alpha, fa_rate=_rate_tests(model, c, matches.image_area_mpx, test),
        image_area_mpx=(round_sig(matches.image_area_mpx) if matches.image_area_mpx > 0
                        else None))
