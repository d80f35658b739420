"""Detector statistics (paper, section III-B): from matched boxes to a ``DetectorModel``.

Pure: the matches of a labelled test set in (``detection/matching.py``: COCO's rule, object
sizes in detector-input pixels), counts, models and test results out. Steps:

1. ``count_in_bins``: N_true and N_det by ground-truth size, N_total and N_TP by detection size;
   ``fit_binned``: P_D = N_det / N_true, P_FA = 1 - N_TP / N_total with 95 % intervals,
   and the false-box rate (N_total - N_TP) / (images' area, Mpx) with its Garwood interval;
   ``fit_logistic``: P_D and P_FA as logistic functions of log size (MIL-HDBK-1823A hit/miss);
   ``fit_confidence``: per size bin, the histograms of true and of false boxes' confidences.
2. ``validate``: observed against predicted detections per bin on another split, and the
   false boxes per frame per Mpx against the model's rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import optimize, special, stats

from pdcov.core.detector import DetectorModel
from pdcov.core.detector_sections import BinCounts, BlurModel, ConfidenceModel
from pdcov.detection.matching import Matches
from pdcov.errors import ConfigError, DetectorModelError, InputFileError

CONFIDENCE_LEVEL = 0.95
INTERVAL_METHODS = {"wilson": "wilson", "clopper-pearson": "exact"}  # ours -> scipy's name
BIN_RULES = ("quantile", "log")
DEFAULT_CONFIDENCE_BINS = 10
VALIDATION_TESTS = ("binomial", "chi2", "fisher")
_Z95 = float(stats.norm.ppf(0.5 + CONFIDENCE_LEVEL / 2))


# -- bins and intervals ----------------------------------------------------------------------


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


# -- models ----------------------------------------------------------------------------------


def _fit_record(matches: Matches, c: BinnedCounts) -> dict[str, Any]:
    s = matches.settings
    return {"classes": list(s.classes) if s.classes is not None else None,
            "n_images": matches.n_images,
            "max_detections": s.max_detections,
            "truth_outside_bins": c.truth_outside,
            "detections_outside_bins": c.detections_outside,
            "status_counts": matches.status_counts}


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


def _model(matches: Matches, c: BinnedCounts, p_d: np.ndarray, p_fa: np.ndarray,
           extra: dict[str, Any]) -> DetectorModel:
    s = matches.settings
    if not matches.image_area_mpx > 0:
        raise InputFileError(
            "the false-alarm rate is per image area: every image's width and height are "
            "needed (--sizes FILE or --images DIR)")
    n_false = c.n_detections - c.n_true_positives
    rate, rate_lo, rate_hi = false_box_rate(n_false, matches.image_area_mpx)
    return DetectorModel(
        bin_edges_px=c.edges_px, p_detect=tuple(round(float(v), 6) for v in p_d),
        p_false_alarm=tuple(round(float(v), 6) for v in p_fa),
        fa_rate_per_mpx=tuple(_round_sig(float(v)) for v in rate),
        input_size_px=s.input_size_px,
        confidence_threshold=s.confidence_threshold, iou_threshold=s.iou_threshold,
        counts=BinCounts(tuple(int(v) for v in c.n_true), tuple(int(v) for v in c.n_detected),
                         tuple(int(v) for v in c.n_detections)),
        extra={**extra, "n_true_positives": [int(v) for v in c.n_true_positives],
               "fa_rate_per_mpx_ci95": [[_round_sig(float(a)), _round_sig(float(b))]
                                        for a, b in zip(rate_lo, rate_hi, strict=True)],
               "n_false_boxes": [int(v) for v in n_false],
               "fit": {**_fit_record(matches, c),
                       "image_area_mpx": _round_sig(matches.image_area_mpx)}})


def _round_sig(v: float) -> float:
    """``v`` to 6 significant digits (rates per Mpx span decades)."""
    return float(f"{v:.6g}")


def _pairs(lo: np.ndarray, hi: np.ndarray) -> list[list[float]]:
    return [[round(float(a), 6), round(float(b), 6)] for a, b in zip(lo, hi, strict=True)]


def _binned_rates(c: BinnedCounts, interval: str
                  ) -> tuple[np.ndarray, np.ndarray, list[list[float]], list[list[float]]]:
    """P_D, P_FA and their 95 % intervals (pairs) of the counts; P = 0 in an empty bin."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p_d = np.where(c.n_true > 0, c.n_detected / c.n_true, 0.0)
        p_fa = np.where(c.n_detections > 0, 1 - c.n_true_positives / c.n_detections, 0.0)
    d_lo, d_hi = proportion_ci(c.n_detected, c.n_true, interval)
    prec_lo, prec_hi = proportion_ci(c.n_true_positives, c.n_detections, interval)
    return p_d, p_fa, _pairs(d_lo, d_hi), _pairs(1 - prec_hi, 1 - prec_lo)


def fit_binned(matches: Matches, edges: tuple[float, ...],
               interval: str = "wilson") -> DetectorModel:
    """The paper's histogram model with ``interval`` 95 % intervals. An empty bin has
    P = 0 (the engine assumes nothing where there is no data) and the interval [0, 1]."""
    c = count_in_bins(matches, edges)
    p_d, p_fa, ci_d, ci_fa = _binned_rates(c, interval)
    return _model(matches, c, p_d, p_fa, {
        "model": "binned", "interval_method": interval, "confidence_level": CONFIDENCE_LEVEL,
        "p_detect_ci95": ci_d, "p_false_alarm_ci95": ci_fa})


def blur_bin_edges(blur_px: np.ndarray, rule: str, n_bins: int) -> tuple[float, ...]:
    """Blur bin edges (px) from a rule as ``auto_bin_edges``, the first edge 0."""
    edges = auto_bin_edges(blur_px, rule, n_bins)
    return (0.0, *(e for e in edges[1:] if e > 0))


def fit_binned_blur(matches: Matches, edges: tuple[float, ...],
                    blur_edges: tuple[float, ...], interval: str = "wilson") -> DetectorModel:
    """``fit_binned`` over all images, and the same fit in each blur bin [blur_edges[j],
    blur_edges[j + 1]) of the images' blur (detector-input px; the model's ``blur``
    section, with its intervals and counts). Needs matches with blurs."""
    b = np.asarray(blur_edges, dtype=float)
    if len(b) < 2 or b[0] != 0 or np.any(np.diff(b) <= 0):
        raise ConfigError(f"--blur-bins: edges must be at least 2 strictly increasing blurs "
                          f"(px), the first 0, got {list(blur_edges)}")
    if np.isnan(matches.truth_blur_px).any() or np.isnan(matches.detection_blur_px).any():
        raise ValueError("fit_binned_blur needs the blur of every image")
    model = fit_binned(matches, edges, interval)
    ti = bin_of(matches.truth_blur_px, blur_edges)
    di = bin_of(matches.detection_blur_px, blur_edges)
    rows: dict[str, list[Any]] = {k: [] for k in (
        "p_detect", "p_false_alarm", "p_detect_ci95", "p_false_alarm_ci95", "n_true",
        "n_detected", "n_detections", "n_true_positives")}
    for j in range(len(blur_edges) - 1):
        sub = replace(matches, truth_size_px=matches.truth_size_px[ti == j],
                      truth_detected=matches.truth_detected[ti == j],
                      detection_size_px=matches.detection_size_px[di == j],
                      detection_true=matches.detection_true[di == j],
                      detection_confidence=matches.detection_confidence[di == j])
        c = count_in_bins(sub, edges)
        p_d, p_fa, ci_d, ci_fa = _binned_rates(c, interval)
        for key, v in (("p_detect", p_d), ("p_false_alarm", p_fa)):
            rows[key].append(tuple(round(float(x), 6) for x in v))
        rows["p_detect_ci95"].append(ci_d)
        rows["p_false_alarm_ci95"].append(ci_fa)
        for key in ("n_true", "n_detected", "n_detections", "n_true_positives"):
            rows[key].append([int(x) for x in getattr(c, key)])
    extra: dict[str, Any] = {k: v for k, v in rows.items()
                             if k not in ("p_detect", "p_false_alarm")}
    extra.update(truth_outside_bins=int((ti < 0).sum()),
                 detections_outside_bins=int((di < 0).sum()))
    return replace(model, blur=BlurModel(tuple(float(e) for e in blur_edges),
                                         tuple(rows["p_detect"]), tuple(rows["p_false_alarm"]),
                                         extra))


def fit_confidence(matches: Matches, edges: tuple[float, ...],
                   n_bins: int = DEFAULT_CONFIDENCE_BINS) -> ConfidenceModel | None:
    """Per size bin of ``edges`` (by detection size, px), the densities of the confidences of
    the counted detections, the true (matched) and the false (unmatched) apart, on ``n_bins``
    equal bins over [confidence threshold, 1]. Smoothed add-one (Laplace): a bin of width w
    holding n_k of a size bin's n boxes has density (n_k + 1) / ((n + K) w), so no bin is 0
    and a size bin without boxes is uniform (its confidences are no evidence). None at a
    threshold of 1, where there is no range to bin."""
    if n_bins < 1:
        raise ConfigError(f"--confidence-bins: expected at least 1 bin, got {n_bins}")
    threshold = matches.settings.confidence_threshold
    if threshold >= 1:
        return None
    c_edges = np.linspace(threshold, 1.0, n_bins + 1)
    si = bin_of(matches.detection_size_px, edges)
    ci = np.clip(np.searchsorted(c_edges, matches.detection_confidence, side="right") - 1,
                 0, n_bins - 1)
    n_size = len(edges) - 1

    def counts(true: bool) -> np.ndarray:
        keep = (si >= 0) & (matches.detection_true == true)
        return np.bincount(si[keep] * n_bins + ci[keep],
                           minlength=n_size * n_bins).reshape(n_size, n_bins)

    def density(n: np.ndarray) -> tuple[tuple[float, ...], ...]:
        d = (n + 1) / (n.sum(axis=1, keepdims=True) + n_bins) / np.diff(c_edges)
        return tuple(tuple(_round_sig(float(v)) for v in row) for row in d)

    n_tp, n_fp = counts(True), counts(False)
    return ConfidenceModel(tuple(round(float(e), 6) for e in c_edges), density(n_tp),
                           density(n_fp), {"smoothing": "add-one",
                                           "n_true_positives": n_tp.tolist(),
                                           "n_false_positives": n_fp.tolist()})


@dataclass(frozen=True, slots=True)
class LogisticCurve:
    """P(s) = 1 / (1 + exp(-(b0 + b1 z + ... + b_k z^k))), z = (ln s - log_center) / log_scale,
    s in px; ``covariance`` of the coefficients from the observed information."""

    coefficients: tuple[float, ...]
    covariance: tuple[tuple[float, ...], ...]
    log_center: float
    log_scale: float

    def design(self, size_px: np.ndarray) -> np.ndarray:
        z = (np.log(np.asarray(size_px, dtype=float)) - self.log_center) / self.log_scale
        return np.vander(z, len(self.coefficients), increasing=True)

    def evaluate(self, size_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P and its pointwise 95 % band (Wald on the logit scale) at the sizes."""
        X = self.design(size_px)
        eta = X @ np.asarray(self.coefficients)
        se = np.sqrt(np.einsum("ij,jk,ik->i", X, np.asarray(self.covariance), X))
        return special.expit(eta), special.expit(eta - _Z95 * se), special.expit(eta + _Z95 * se)

    def to_dict(self) -> dict[str, Any]:
        return {"log_center": self.log_center, "log_scale": self.log_scale,
                "coefficients": list(self.coefficients),
                "covariance": [list(r) for r in self.covariance]}


def fit_logistic_curve(size_px: np.ndarray, hit: np.ndarray, degree: int = 1) -> LogisticCurve:
    """Maximum-likelihood logistic regression of hits on a polynomial in log size."""
    s, y = np.asarray(size_px, dtype=float), np.asarray(hit, dtype=float)
    if degree not in (1, 2):
        raise ConfigError(f"--logistic-degree: expected 1 or 2, got {degree}")
    if s.size == 0 or y.sum() < degree + 1 or (1 - y).sum() < degree + 1:
        raise DetectorModelError(
            f"logistic fit needs at least {degree + 1} hits and {degree + 1} misses, got "
            f"{int(y.sum())} and {int((1 - y).sum())}; use the binned model")
    ln = np.log(s)
    curve = LogisticCurve((0.0,) * (degree + 1), (), float(ln.mean()),
                          float(ln.std()) or 1.0)
    X = curve.design(s)

    def nll(b: np.ndarray) -> tuple[float, np.ndarray]:
        eta = X @ b
        return float(np.sum(np.logaddexp(0, eta) - y * eta)), X.T @ (special.expit(eta) - y)

    def hess(b: np.ndarray) -> np.ndarray:
        p = special.expit(X @ b)
        return (X * (p * (1 - p))[:, None]).T @ X

    res = optimize.minimize(nll, np.zeros(degree + 1), jac=True, hess=hess,
                            method="trust-exact")
    H = hess(res.x)
    cov = np.linalg.pinv(H)
    # Where size separates hits from misses the MLE does not exist: the optimiser stops at
    # large coefficients whose standard errors (in units of z) explode.
    if not res.success or np.max(np.sqrt(np.abs(np.diag(cov)))) > 10:
        raise DetectorModelError(
            f"logistic fit is undetermined ({res.message.rstrip('.')}; standard errors "
            f"{np.sqrt(np.abs(np.diag(cov))).round(1).tolist()}): too few objects, or size "
            f"separates hits from misses; use the binned model")
    return LogisticCurve(tuple(float(v) for v in res.x),
                         tuple(tuple(float(v) for v in r) for r in cov),
                         curve.log_center, curve.log_scale)


def fit_logistic(matches: Matches, edges: tuple[float, ...], n_fine: int = 64,
                 degree: int = 1) -> DetectorModel:
    """P_D and P_FA as logistic functions of log size (hit/miss analysis of MIL-HDBK-1823A),
    fitted to the objects and detections inside [edges[0], edges[-1]) and written on
    ``n_fine`` log-spaced bins over that range, valued at each bin's geometric centre."""
    if n_fine < 1:
        raise ConfigError(f"--fine-bins: expected at least 1, got {n_fine}")
    lo = edges[0] if edges[0] > 0 else float(matches.truth_size_px.min(initial=math.inf))
    if not lo < edges[-1]:
        raise InputFileError("no ground-truth object inside the bins to fit")
    fine = tuple(float(v) for v in np.geomspace(lo, edges[-1], n_fine + 1))
    ti = bin_of(matches.truth_size_px, fine) >= 0
    di = bin_of(matches.detection_size_px, fine) >= 0
    pd_curve = fit_logistic_curve(matches.truth_size_px[ti], matches.truth_detected[ti], degree)
    fa_curve = fit_logistic_curve(matches.detection_size_px[di], ~matches.detection_true[di],
                                  degree)
    centres = np.sqrt(np.asarray(fine[:-1]) * np.asarray(fine[1:]))
    p_d, d_lo, d_hi = pd_curve.evaluate(centres)
    p_fa, fa_lo, fa_hi = fa_curve.evaluate(centres)
    c = count_in_bins(matches, fine)
    return _model(matches, c, p_d, p_fa, {
        "model": "logistic", "interval_method": "wald-logit", "confidence_level":
        CONFIDENCE_LEVEL, "p_detect_ci95": _pairs(d_lo, d_hi),
        "p_false_alarm_ci95": _pairs(fa_lo, fa_hi),
        "logistic": {"link": "logit", "covariate": "z = (ln(size_px) - log_center) / log_scale",
                     "degree": degree, "fit_range_px": [lo, edges[-1]],
                     "p_detect": pd_curve.to_dict(), "p_false_alarm": fa_curve.to_dict()}})


# -- validation ------------------------------------------------------------------------------


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
                    false_boxes=r.observed, fa_rate_per_mpx=_round_sig(r.rate_per_mpx),
                    fa_rate_per_mpx_ci95=[_round_sig(v) for v in r.rate_ci95],
                    expected_false_boxes=None if r.expected is None else _round_sig(r.expected),
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
        image_area_mpx=(_round_sig(matches.image_area_mpx) if matches.image_area_mpx > 0
                        else None))
