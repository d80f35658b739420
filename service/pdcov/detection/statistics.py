"""Detector statistics (paper, section III-B): from matched boxes to a ``DetectorModel``.

Pure: the matches of a labelled test set in (``detection/matching.py``: COCO's rule, object
sizes in detector-input pixels), counts, models and test results out. Steps:

1. ``count_in_bins`` (detection/bins.py): N_true and N_det by ground-truth size, N_total
   and N_TP by detection size;
   ``fit_binned``: P_D = N_det / N_true, P_FA = 1 - N_TP / N_total with 95 % intervals,
   and the false-box rate (N_total - N_TP) / (images' area, Mpx) with its Garwood interval;
   ``fit_binned_blur``: the same per blur bin;
   ``fit_logistic`` (detection/logistic.py): P_D and P_FA as logistic functions of log size
   (MIL-HDBK-1823A hit/miss);
   ``fit_confidence``: per size bin, the histograms of true and of false boxes' confidences.
2. ``validate`` (detection/validation.py): observed against predicted detections per bin on
   another split, and the false boxes per frame per Mpx against the model's rate.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from pdcov.core.detector import BinCounts, BlurModel, ConfidenceModel, DetectorModel
from pdcov.detection.bins import (
    CONFIDENCE_LEVEL,
    BinnedCounts,
    auto_bin_edges,
    bin_of,
    count_in_bins,
    false_box_rate,
    interval_pairs,
    proportion_ci,
    round_sig,
)
from pdcov.detection.matching import Matches
from pdcov.errors import ConfigError, InputFileError

__all__ = ["DEFAULT_CONFIDENCE_BINS", "blur_bin_edges", "fit_binned", "fit_binned_blur",
           "fit_confidence", "model_of_counts"]

DEFAULT_CONFIDENCE_BINS = 10


def _fit_record(matches: Matches, c: BinnedCounts) -> dict[str, Any]:
    s = matches.settings
    return {"classes": list(s.classes) if s.classes is not None else None,
            "n_images": matches.n_images,
            "max_detections": s.max_detections,
            "truth_outside_bins": c.truth_outside,
            "detections_outside_bins": c.detections_outside,
            "status_counts": matches.status_counts}


def model_of_counts(matches: Matches, c: BinnedCounts, p_d: np.ndarray, p_fa: np.ndarray,
                    extra: dict[str, Any]) -> DetectorModel:
    """The model of ``c``'s bins with P_D ``p_d`` and P_FA ``p_fa`` per bin, the false-box
    rate of the counts over the images' area and ``extra`` (InputFileError when the images'
    area is unknown)."""
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
        fa_rate_per_mpx=tuple(round_sig(float(v)) for v in rate),
        input_size_px=s.input_size_px,
        confidence_threshold=s.confidence_threshold, iou_threshold=s.iou_threshold,
        counts=BinCounts(tuple(int(v) for v in c.n_true), tuple(int(v) for v in c.n_detected),
                         tuple(int(v) for v in c.n_detections)),
        extra={**extra, "n_true_positives": [int(v) for v in c.n_true_positives],
               "fa_rate_per_mpx_ci95": [[round_sig(float(a)), round_sig(float(b))]
                                        for a, b in zip(rate_lo, rate_hi, strict=True)],
               "n_false_boxes": [int(v) for v in n_false],
               "fit": {**_fit_record(matches, c),
                       "image_area_mpx": round_sig(matches.image_area_mpx)}})


def _binned_rates(c: BinnedCounts, interval: str
                  ) -> tuple[np.ndarray, np.ndarray, list[list[float]], list[list[float]]]:
    """P_D, P_FA and their 95 % intervals (pairs) of the counts; P = 0 in an empty bin."""
    with np.errstate(divide="ignore", invalid="ignore"):
        p_d = np.where(c.n_true > 0, c.n_detected / c.n_true, 0.0)
        p_fa = np.where(c.n_detections > 0, 1 - c.n_true_positives / c.n_detections, 0.0)
    d_lo, d_hi = proportion_ci(c.n_detected, c.n_true, interval)
    prec_lo, prec_hi = proportion_ci(c.n_true_positives, c.n_detections, interval)
    return p_d, p_fa, interval_pairs(d_lo, d_hi), interval_pairs(1 - prec_hi, 1 - prec_lo)


def fit_binned(matches: Matches, edges: tuple[float, ...],
               interval: str = "wilson") -> DetectorModel:
    """The paper's histogram model with ``interval`` 95 % intervals. An empty bin has
    P = 0 (the engine assumes nothing where there is no data) and the interval [0, 1]."""
    c = count_in_bins(matches, edges)
    p_d, p_fa, ci_d, ci_fa = _binned_rates(c, interval)
    return model_of_counts(matches, c, p_d, p_fa, {
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
        return tuple(tuple(round_sig(float(v)) for v in row) for row in d)

    n_tp, n_fp = counts(True), counts(False)
    return ConfidenceModel(tuple(round(float(e), 6) for e in c_edges), density(n_tp),
                           density(n_fp), {"smoothing": "add-one",
                                           "n_true_positives": n_tp.tolist(),
                                           "n_false_positives": n_fp.tolist()})
