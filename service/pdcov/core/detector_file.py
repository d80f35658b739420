"""The detector model file (docs/detector-model.md): its format versions, its keys
(``MODEL_SCHEMA``), the bounds checked before anything is built, and the readers of its
numbers and optional sections; ``DetectorModel.from_dict`` composes them."""

from __future__ import annotations

import math
import warnings
from typing import Any

from pdcov.core.detector_sections import BlurModel, ConfidenceModel
from pdcov.errors import DetectorModelError, where
from pdcov.schema import Section

# 2: the optional ``looks`` section (per-person correlation); 3: ``blur``; 4: fa_rate_per_mpx;
# 5: ``confidence``. A model is written in the oldest version that holds its sections.
FORMAT_VERSION = 5
READABLE_VERSIONS = (1, 2, 3, 4, 5)
MAX_MODEL_BYTES = 4 << 20
"""Largest detector model file read (a fitted model of 100 size x 100 blur bins is ~0.5 MB)."""
MAX_BINS = 1000
"""Most size bins, and most blur bins, of a detector model (checked before any array is
built: the grid's tables are (blur bins + 2) x (size bins + 2))."""

# The keys of a model file (docs/detector-model.md): the engine's, then those `pdcov detector
# fit` writes for validate and plot (kept in ``DetectorModel.extra``), and free-text notes.
_LOGISTIC_CURVE = Section.of("log_center", "log_scale", "coefficients", "covariance")
MODEL_SCHEMA = Section.of(
    "version", "size_metric", "input_size_px", "confidence_threshold", "iou_threshold",
    "bin_edges_px", "p_detect", "p_false_alarm", "fa_rate_per_mpx",
    "model", "interval_method", "confidence_level", "p_detect_ci95", "p_false_alarm_ci95",
    "fa_rate_per_mpx_ci95", "n_false_boxes", "n_true_positives", "illustrative", "notes",
    counts=Section.of("n_true", "n_detected", "n_detections"),
    fit=Section.of("classes", "n_images", "truth_outside_bins", "detections_outside_bins",
                   "max_detections", "image_area_mpx", "ground_truth", "detections", "bins",
                   status_counts=Section(open=True)),
    logistic=Section.of("link", "covariate", "degree", "fit_range_px",
                        p_detect=_LOGISTIC_CURVE, p_false_alarm=_LOGISTIC_CURVE),
    looks=Section.of(
        "correlation",  # the engine's; the others are the fit's (detection/looks_fit.py)
        "model", "estimated", "no_estimate_reason", "correlation_mle", "correlation_ci95",
        "mean_pd", "mean_pd_ci95", "interval_method", "test", "p_value_independent",
        "min_people", "n_people", "n_looks", "n_hits",
        found_within=Section.of("share", "n_people"),
        tracks=Section.of("format", "n_sequences", "n_frames", "n_people", "n_track_gaps",
                          "looks_outside_bins")),
    blur=Section.of("edges_px", "p_detect", "p_false_alarm", "p_detect_ci95",
                    "p_false_alarm_ci95", "n_true", "n_detected", "n_detections",
                    "n_true_positives", "truth_outside_bins", "detections_outside_bins",
                    "csv", "bins", "speed_to_blur"),
    confidence=Section.of("edges", "tp_density", "fp_density",  # the engine's
                          "smoothing", "n_true_positives", "n_false_positives", "notes"))
ENGINE_KEYS = ("version", "bin_edges_px", "p_detect", "p_false_alarm", "fa_rate_per_mpx",
                "input_size_px",
                "confidence_threshold", "iou_threshold", "size_metric", "counts", "looks",
                "blur", "confidence")


def opt_float(doc: dict[str, Any], key: str, source: str | None) -> float | None:
    v = doc.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise DetectorModelError(f"{where(source, key)}: expected a number, got {v!r}")
    return float(v)


def check_bins(v: Any, key: str, source: str | None) -> None:
    """Refuse a list of more than MAX_BINS + 1 entries before anything is built of it."""
    if isinstance(v, list) and len(v) > MAX_BINS + 1:
        raise DetectorModelError(f"{where(source, key)}: {len(v):,} entries, more than a "
                                 f"model of {MAX_BINS} bins has ({MAX_BINS + 1} edges)")


def fa_rate_from_dict(doc: dict[str, Any], version: int, source: str | None
                       ) -> tuple[float, ...] | None:
    """``fa_rate_per_mpx``: required from version 4. An older file loads, with one warning,
    without false alarms: its ``p_false_alarm`` is 1 - precision, a share of detections that
    no rule turns into a probability per cell without the frames and image area of the fit
    (not written before version 4). Its P_D is still right, so a plan or an evaluation by
    P_D need not be refused; its P_FA map is 0 (unknown), and the warning says so."""
    rate = doc.get("fa_rate_per_mpx")
    if rate is None:
        if version >= 4:
            raise DetectorModelError(
                f"{where(source, 'fa_rate_per_mpx')}: missing (version 4 needs false boxes "
                f"per frame per megapixel, one per bin; `pdcov detector fit` writes it)")
        warnings.warn(
            f"{source or 'detector model'}: version {version} has no fa_rate_per_mpx (its "
            f"p_false_alarm is 1 - precision, not a probability per cell); the grid counts "
            f"no false alarms with it (P_FA 0, unknown). Refit with `pdcov detector fit` "
            f"for the false-alarm rate", UserWarning, stacklevel=3)
        return None
    if version < 4:
        raise DetectorModelError(
            f"{where(source, 'fa_rate_per_mpx')}: needs version 4, the file says {version}")
    if not isinstance(rate, list) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in rate):
        raise DetectorModelError(
            f"{where(source, 'fa_rate_per_mpx')}: expected a list of numbers, got {rate!r}")
    return tuple(float(v) for v in rate)


def blur_from_dict(bl: Any, source: str | None) -> BlurModel:
    """The ``blur`` section: edges_px (numbers), p_detect and p_false_alarm (rows of
    numbers); the values are checked by DetectorModel."""
    edges, rows, extra = _tables_from_dict(bl, "blur", "edges_px",
                                           ("p_detect", "p_false_alarm"), source)
    return BlurModel(edges, rows[0], rows[1], extra)


def confidence_from_dict(sec: Any, source: str | None) -> ConfidenceModel:
    """The ``confidence`` section: edges (numbers), tp_density and fp_density (rows of
    numbers); the values are checked by DetectorModel."""
    edges, rows, extra = _tables_from_dict(sec, "confidence", "edges",
                                           ("tp_density", "fp_density"), source)
    return ConfidenceModel(edges, rows[0], rows[1], extra)


def _tables_from_dict(sec: Any, name: str, edges_key: str, table_keys: tuple[str, ...],
                      source: str | None
                      ) -> tuple[tuple[float, ...], list[tuple[tuple[float, ...], ...]],
                                 dict[str, Any]]:
    """A section of edges and tables (rows of numbers): the edges, the tables in the order
    of ``table_keys``, and the section's other keys. Sizes are bounded before anything is
    built (``check_bins``); the values are checked by DetectorModel."""
    if not isinstance(sec, dict):
        raise DetectorModelError(f"{where(source, name)}: expected a mapping")

    def numbers(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)

    for key in (edges_key, *table_keys):
        v = sec.get(key)
        for part in (v, *(v if key != edges_key and isinstance(v, list) else ())):
            check_bins(part, f"{name}.{key}", source)
        if key == edges_key and not numbers(v) or key != edges_key and not (
                isinstance(v, list) and all(numbers(row) for row in v)):
            raise DetectorModelError(
                f"{where(source, name + '.' + key)}: expected "
                f"{'a list of numbers' if key == edges_key else 'a list of rows of numbers'}"
                f", got {v!r}")
    return (tuple(float(x) for x in sec[edges_key]),
            [tuple(tuple(float(x) for x in row) for row in sec[key]) for key in table_keys],
            {k: v for k, v in sec.items() if k not in (edges_key, *table_keys)})
