"""Size bins, counts per bin and their 95 % intervals (paper, section III-B): the counting
step of the detector statistics, from the matches of a labelled test set
(detection/matching.py; sizes in detector-input pixels) to counts per bin, binomial
intervals of proportions and the Garwood interval of a false-box rate."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pdcov.detection.matching import Matches
from pdcov.errors import ConfigError, InputFileError

__all__ = ["BIN_RULES", "CONFIDENCE_LEVEL", "INTERVAL_METHODS", "BinnedCounts",
           "auto_bin_edges", "bin_of", "count_in_bins", "false_box_rate", "interval_pairs",
           "proportion_ci", "round_sig"]

CONFIDENCE_LEVEL = 0.95
INTERVAL_METHODS = {"wilson": "wilson", "clopper-pearson": "exact"}  # ours -> scipy's name
BIN_RULES = ("quantile", "log")


def auto_bin_edges(size_px: np.ndarray, rule: str, n_bins: int) -> tuple[float, ...]:
    """Bin edges (px) spanning the sizes: ``quantile`` puts about equal counts in each bin,
    ``log`` spaces edges evenly in log size. Edges are rounded to 0.1 px (first down, last up
    past the largest size); edges that coincide merge, so ties can give fewer bins."""
    s = np.asarray(size_px, dtype=float)
    if rule not in BIN_RULES:
        raise ConfigError(f"--bins: expected edges or a rule {BIN_RULES}, got {rule!r}")
    if n_bins < 1:
        raise ConfigError(f"--bins: expected at least 1 bin, got {n_bins}")
    if s.size < 2:
        raise InputFileError(f"cannot choose bins from {s.size} ground-truth objects; "
                             f"give --bins edges")
    lo, hi = float(s.min()), float(s.max())
    if rule == "quantile":
        inner = np.quantile(s, np.linspace(0, 1, n_bins + 1)[1:-1], method="inverted_cdf")
    else:
        inner = np.geomspace(lo, hi, n_bins + 1)[1:-1]
    first, last = math.floor(lo * 10) / 10, math.floor(hi * 10) / 10 + 0.1
    inner = np.round(inner, 1)
    edges = np.unique(np.concatenate([[first], inner[(inner > first) & (inner < last)],
                                      [last]]))
    return tuple(round(float(e), 1) for e in edges)


def proportion_ci(k: np.ndarray, n: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """95 % interval of a binomial proportion k / n per element (``wilson`` or
    ``clopper-pearson``); [0, 1] where n = 0."""
    if method not in INTERVAL_METHODS:
        raise ConfigError(f"--interval: expected one of {tuple(INTERVAL_METHODS)}, "
                          f"got {method!r}")
    lo, hi = np.zeros(len(n)), np.ones(len(n))
    for i, (ki, ni) in enumerate(zip(k, n, strict=True)):
        if ni > 0:
            ci = stats.binomtest(int(ki), int(ni)).proportion_ci(
                confidence_level=CONFIDENCE_LEVEL, method=INTERVAL_METHODS[method])
            lo[i], hi[i] = ci.low, ci.high
    return lo, hi


@dataclass(frozen=True, slots=True)
class BinnedCounts:
    """Counts per bin [edge_i, edge_i+1) px: ground truth (n_true) and the detected part
    (n_detected) by ground-truth size; detections (n_detections) and the true ones
    (n_true_positives) by detection size; sizes outside all bins."""

    edges_px: tuple[float, ...]
    n_true: np.ndarray
    n_detected: np.ndarray
    n_detections: np.ndarray
    n_true_positives: np.ndarray
    truth_outside: int
    detections_outside: int


def bin_of(size_px: np.ndarray, edges: tuple[float, ...]) -> np.ndarray:
    """Bin index of each size, -1 outside [edges[0], edges[-1])."""
    i = np.searchsorted(np.asarray(edges), size_px, side="right") - 1
    return np.where((i >= 0) & (i < len(edges) - 1), i, -1)


def count_in_bins(matches: Matches, edges: tuple[float, ...]) -> BinnedCounts:
    n = len(edges) - 1
    if n < 1 or np.any(np.diff(edges) <= 0):
        raise ConfigError(f"--bins: edges must be at least 2 strictly increasing sizes, "
                          f"got {list(edges)}")
    ti = bin_of(matches.truth_size_px, edges)
    di = bin_of(matches.detection_size_px, edges)

    def count(i: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
        keep = i >= 0
        return np.bincount(i[keep], None if w is None else w[keep], minlength=n).astype(int)

    return BinnedCounts(tuple(edges), count(ti), count(ti, matches.truth_detected),
                        count(di), count(di, matches.detection_true),
                        int((ti < 0).sum()), int((di < 0).sum()))


def false_box_rate(n_false: np.ndarray, area_mpx: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """False boxes per frame per megapixel (the Poisson rate's maximum-likelihood estimate,
    n / area) and its 95 % Garwood exact interval: chi2(a/2; 2n) / 2 and chi2(1 - a/2;
    2n + 2) / 2 boxes over the area (low 0 at n = 0)."""
    n = np.asarray(n_false, dtype=float)
    a = 1 - CONFIDENCE_LEVEL
    lo = np.where(n > 0, stats.chi2.ppf(a / 2, 2 * np.maximum(n, 1)) / 2, 0.0)
    hi = stats.chi2.ppf(1 - a / 2, 2 * n + 2) / 2
    return n / area_mpx, lo / area_mpx, hi / area_mpx


def round_sig(v: float) -> float:
    """``v`` to 6 significant digits (rates per Mpx span decades)."""
    return float(f"{v:.6g}")


def interval_pairs(lo: np.ndarray, hi: np.ndarray) -> list[list[float]]:
    return [[round(float(a), 6), round(float(b), 6)] for a, b in zip(lo, hi, strict=True)]
