"""Detector model: P_D(s) and P_FA(s) per bin of apparent object size (paper, section III-B).

Size s is the side length sqrt(w * h) of a bounding box in detector-input pixels. A size below
the first bin edge, or at or above the last, has P_D = P_FA = 0: the model claims nothing where
it has no data. The YAML format is documented in docs/detector-model.md.

False alarms are a rate: ``fa_rate_per_mpx``, false boxes of size s per frame per megapixel
of detector input. A region of A detector-input px^2 in one frame then holds at least one
false box with probability 1 - exp(-rate(s) A) (Poisson; ``p_false_alarm_per_look``).
``p_false_alarm`` is the paper's 1 - precision, kept for the fit's report.

Confidences are evidence (the optional ``confidence`` section): per size bin, histograms of
the confidences of true and of false boxes; a box of confidence c and size s weighs
log(f_TP(c | s) / f_FP(c | s)) for a person (``confidence_log_lr``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pdcov.errors import DetectorModelError, where
from pdcov.schema import Section, check_keys
from pdcov.yaml_file import load_yaml

# 2: the optional ``looks`` section (per-person correlation); 3: ``blur``; 4: fa_rate_per_mpx;
# 5: ``confidence``. A model is written in the oldest version that holds its sections.
FORMAT_VERSION = 5
_READABLE_VERSIONS = (1, 2, 3, 4, 5)
_PX2_PER_MPX = 1e6
MAX_MODEL_BYTES = 4 << 20
"""Largest detector model file read (a fitted model of 100 size x 100 blur bins is ~0.5 MB)."""
MAX_BINS = 1000
"""Most size bins, and most blur bins, of a detector model (checked before any array is
built: the grid's tables are (blur bins + 2) x (size bins + 2))."""
SIZE_METRICS = ("sqrt_area",)

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
_ENGINE_KEYS = ("version", "bin_edges_px", "p_detect", "p_false_alarm", "fa_rate_per_mpx",
                "input_size_px",
                "confidence_threshold", "iou_threshold", "size_metric", "counts", "looks",
                "blur", "confidence")


@dataclass(frozen=True, slots=True)
class BlurModel:
    """P_D and P_FA by motion-blur bin and size bin (version 3's ``blur`` section).

    edges_px: M + 1 strictly increasing blur lengths in detector-input pixels (scaled from
    image pixels as sizes are), the first 0; blur bin j is [edges_px[j], edges_px[j + 1]).
    p_detect, p_false_alarm: M rows (blur bins) of N values (the model's size bins). A blur
    at or above the last edge has P_D = P_FA = 0 (the model claims nothing there).
    ``extra``: the fit's other keys (intervals, counts), kept as written.
    """

    edges_px: tuple[float, ...]
    p_detect: tuple[tuple[float, ...], ...]
    p_false_alarm: tuple[tuple[float, ...], ...]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_bins(self) -> int:
        return len(self.edges_px) - 1


@dataclass(frozen=True, slots=True)
class ConfidenceModel:
    """How a box's confidence tells a person from a false alarm (version 5's ``confidence``
    section), per size bin of the model (the box's own size, detector-input px).

    edges: K + 1 strictly increasing confidences in [0, 1], the last 1 (a fit's: K equal bins
    over [confidence_threshold, 1]); bin k is [edges[k], edges[k + 1]), the last one closed.
    tp_density, fp_density: N rows (size bins) of K histogram densities (per unit confidence)
    of the confidences of true and of false boxes, finite and > 0; each row is rescaled to
    integrate to 1 where it is used (``probabilities``), so rounding does not bias the ratio.
    ``extra``: the fit's other keys (counts, smoothing), kept as written.
    """

    edges: tuple[float, ...]
    tp_density: tuple[tuple[float, ...], ...]
    fp_density: tuple[tuple[float, ...], ...]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_bins(self) -> int:
        return len(self.edges) - 1

    def probabilities(self, true_positive: bool) -> np.ndarray:
        """(N, K): per size bin, the probability of each confidence bin for a true box
        (``true_positive``) or a false one."""
        d = np.asarray(self.tp_density if true_positive else self.fp_density, dtype=float)
        mass = d * np.diff(np.asarray(self.edges))
        return mass / mass.sum(axis=1, keepdims=True)

    def log_lr_table(self) -> np.ndarray:
        """(N, K): per size bin and confidence bin, log(f_TP / f_FP), the evidence of a box
        of that confidence for a person."""
        return np.log(self.probabilities(True)) - np.log(self.probabilities(False))

    def bin_index(self, confidence: np.ndarray) -> np.ndarray:
        """Confidence bin 0..K-1 of each confidence; outside the edges the nearest bin."""
        k = np.searchsorted(np.asarray(self.edges), np.asarray(confidence, dtype=float),
                            side="right") - 1
        return np.clip(k, 0, self.n_bins - 1)


@dataclass(frozen=True, slots=True)
class LooksModel:
    """How one person's looks are correlated (version 2's ``looks`` section).

    Each person has a latent detectability: in size bin i it is Beta distributed with the
    bin's mean P_D and intra-person correlation ``correlation[i]`` (rho = 1 / (a + b + 1));
    rho = 0 is the paper's independent looks. ``extra``: the fit's other keys (intervals,
    tests), kept as written.
    """

    correlation: tuple[float, ...]
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class BinCounts:
    """The counts behind each bin: ground-truth objects, those detected, all detections."""

    n_true: tuple[int, ...]
    n_detected: tuple[int, ...]
    n_detections: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class DetectorModel:
    """Binned detection and false-alarm probabilities of one detector at fixed thresholds.

    bin_edges_px: N + 1 strictly increasing sizes in detector-input pixels.
    p_detect: N probabilities in [0, 1].
    p_false_alarm: N values of the paper's 1 - precision in [0, 1] (reported, not used by
        the grid).
    fa_rate_per_mpx: N false-box rates >= 0 (false boxes of the bin's size per frame per
        megapixel of detector input); None for a model fitted before version 4, whose false
        alarms are then unknown (the grid counts none).
    input_size_px: detector input size; image pixels are scaled by
        input_size_px / max(image width, image height). None: sizes are image pixels.
    """

    bin_edges_px: tuple[float, ...]
    p_detect: tuple[float, ...]
    p_false_alarm: tuple[float, ...]
    fa_rate_per_mpx: tuple[float, ...] | None = None
    input_size_px: int | None = None
    confidence_threshold: float | None = None
    iou_threshold: float | None = None
    size_metric: str = "sqrt_area"
    counts: BinCounts | None = None
    looks: LooksModel | None = None
    blur: BlurModel | None = None
    confidence: ConfidenceModel | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        edges = np.asarray(self.bin_edges_px, dtype=float)
        n = len(edges) - 1
        src = self.source
        if n < 1:
            raise DetectorModelError(
                f"{where(src, 'bin_edges_px')}: need at least 2 edges, got {len(edges)}")
        if not np.all(np.isfinite(edges)) or np.any(np.diff(edges) <= 0) or edges[0] < 0:
            raise DetectorModelError(
                f"{where(src, 'bin_edges_px')}: edges must be finite, >= 0 and strictly "
                f"increasing, got {list(self.bin_edges_px)}")
        for key in ("p_detect", "p_false_alarm"):
            p = np.asarray(getattr(self, key), dtype=float)
            if p.shape != (n,):
                raise DetectorModelError(
                    f"{where(src, key)}: expected {n} values (one per bin), got {p.size}")
            if not np.all((p >= 0) & (p <= 1)):
                raise DetectorModelError(
                    f"{where(src, key)}: probabilities must lie in [0, 1], got {p.tolist()}")
        if self.fa_rate_per_mpx is not None:
            r = np.asarray(self.fa_rate_per_mpx, dtype=float)
            if r.shape != (n,) or not np.all(np.isfinite(r) & (r >= 0)):
                raise DetectorModelError(
                    f"{where(src, 'fa_rate_per_mpx')}: expected {n} finite rates >= 0 (false "
                    f"boxes per frame per megapixel, one per bin), got "
                    f"{list(self.fa_rate_per_mpx)}")
        if self.size_metric not in SIZE_METRICS:
            raise DetectorModelError(
                f"{where(src, 'size_metric')}: expected one of {SIZE_METRICS}, "
                f"got {self.size_metric!r}")
        if self.input_size_px is not None and self.input_size_px <= 0:
            raise DetectorModelError(
                f"{where(src, 'input_size_px')}: expected a positive integer or null, "
                f"got {self.input_size_px}")
        for key, lo_open in (("confidence_threshold", False), ("iou_threshold", True)):
            v = getattr(self, key)
            if v is not None and not ((0 < v if lo_open else 0 <= v) and v <= 1):
                raise DetectorModelError(
                    f"{where(src, key)}: expected a value in {'(0' if lo_open else '[0'}, 1] "
                    f"or null, got {v}")
        if self.counts is not None:
            for key in ("n_true", "n_detected", "n_detections"):
                c = getattr(self.counts, key)
                if len(c) != n or any(v < 0 for v in c):
                    raise DetectorModelError(
                        f"{where(src, 'counts.' + key)}: expected {n} non-negative counts, "
                        f"got {list(c)}")

        if self.looks is not None:
            rho = np.asarray(self.looks.correlation, dtype=float)
            if rho.shape != (n,) or not np.all((rho >= 0) & (rho < 1)):
                raise DetectorModelError(
                    f"{where(src, 'looks.correlation')}: expected {n} values in [0, 1) "
                    f"(one per bin), got {list(self.looks.correlation)}")
        if self.blur is not None:
            self._check_blur(self.blur, n)
        if self.confidence is not None:
            self._check_confidence(self.confidence, n)

    def _check_blur(self, blur: BlurModel, n: int) -> None:
        src = self.source
        e = np.asarray(blur.edges_px, dtype=float)
        if (len(e) < 2 or not np.all(np.isfinite(e)) or e[0] != 0
                or np.any(np.diff(e) <= 0)):
            raise DetectorModelError(
                f"{where(src, 'blur.edges_px')}: expected at least 2 finite, strictly "
                f"increasing blur lengths (px), the first 0, got {list(blur.edges_px)}")
        for key in ("p_detect", "p_false_alarm"):
            rows = getattr(blur, key)
            if len(rows) != len(e) - 1 or any(len(row) != n for row in rows):
                raise DetectorModelError(
                    f"{where(src, 'blur.' + key)}: expected {len(e) - 1} rows (one per blur "
                    f"bin) of {n} values (one per size bin)")
            p = np.asarray(rows, dtype=float)
            if not np.all((p >= 0) & (p <= 1)):
                raise DetectorModelError(
                    f"{where(src, 'blur.' + key)}: probabilities must lie in [0, 1], "
                    f"got {p.tolist()}")

    def _check_confidence(self, conf: ConfidenceModel, n: int) -> None:
        src = self.source
        e = np.asarray(conf.edges, dtype=float)
        if (len(e) < 2 or not np.all(np.isfinite(e)) or e[0] < 0 or e[-1] != 1
                or np.any(np.diff(e) <= 0)):
            raise DetectorModelError(
                f"{where(src, 'confidence.edges')}: expected at least 2 strictly increasing "
                f"confidences in [0, 1], the last 1, got {list(conf.edges)}")
        for key in ("tp_density", "fp_density"):
            rows = getattr(conf, key)
            if len(rows) != n or any(len(row) != len(e) - 1 for row in rows):
                raise DetectorModelError(
                    f"{where(src, 'confidence.' + key)}: expected {n} rows (one per size "
                    f"bin) of {len(e) - 1} values (one per confidence bin)")
            d = np.asarray(rows, dtype=float)
            bad = np.argwhere(~(np.isfinite(d) & (d > 0)))
            if len(bad):
                i, k = bad[0]
                raise DetectorModelError(
                    f"{where(src, 'confidence.' + key)}: densities must be finite and > 0 "
                    f"(a 0 would make one confidence proof, for or against a person; smooth "
                    f"the histogram as `pdcov detector fit` does), got {d[i, k]} in row {i} "
                    f"(size bin), column {k} (confidence bin)")

    @property
    def n_bins(self) -> int:
        return len(self.bin_edges_px) - 1

    def nearest_bin(self, size_px: np.ndarray) -> np.ndarray:
        """Size bin 0..N-1 of sizes in detector-input pixels; a size outside the bins takes
        the nearest one (NaN: the first)."""
        return np.clip(self.bin_index(size_px) - 1, 0, self.n_bins - 1)

    def confidence_log_lr(self, size_px: np.ndarray, confidence: np.ndarray) -> np.ndarray:
        """Per box, the evidence of its confidence for a person: log(f_TP(c | bin) /
        f_FP(c | bin)), the bin that of its size ``size_px`` (sqrt(w h), detector-input px,
        as the fit bins boxes; outside the bins the nearest one) and ``confidence`` in [0, 1]
        (outside the confidence edges the nearest bin). 0 without a confidence section, and
        where the size or the confidence is NaN."""
        s, c = np.broadcast_arrays(np.asarray(size_px, dtype=float),
                                   np.asarray(confidence, dtype=float))
        if self.confidence is None:
            return np.zeros(s.shape)
        conf = self.confidence
        lr = conf.log_lr_table()[self.nearest_bin(s), conf.bin_index(c)]
        return np.where(np.isnan(s) | np.isnan(c), 0.0, lr)

    @property
    def n_table_rows(self) -> int:
        """Rows of ``padded_tables_by_blur``: 1 (blur unknown) + M blur bins + 1 beyond."""
        return 1 if self.blur is None else self.blur.n_bins + 2

    def blur_row(self, blur_px: np.ndarray) -> np.ndarray:
        """Row of ``padded_tables_by_blur`` for blurs in detector-input pixels: j + 1 for
        blur bin j, M + 1 at or above the last edge or NaN. Needs blur bins (ValueError)."""
        if self.blur is None:
            raise ValueError("blur_row needs a detector model with blur bins")
        b = np.asarray(blur_px, dtype=float)
        return np.searchsorted(np.asarray(self.blur.edges_px), b, side="right")

    def padded_tables_by_blur(self) -> tuple[np.ndarray, np.ndarray]:
        """P_D and P_FA as flat tables indexed by ``row * (N + 2) + bin_index``: row 0 is
        ``padded_tables`` (blur unknown: P by size only), rows 1..M the blur bins, row M + 1
        zeros (blur beyond the last edge). Without blur bins: just row 0."""
        pd, pfa = self.padded_tables()
        if self.blur is None:
            return pd, pfa
        n = self.n_bins
        tables = []
        for one_d, rows in ((pd, self.blur.p_detect), (pfa, self.blur.p_false_alarm)):
            t = np.zeros((self.blur.n_bins + 2, n + 2))
            t[0] = one_d
            t[1:-1, 1:-1] = np.asarray(rows, dtype=float)
            tables.append(t.ravel())
        return tables[0], tables[1]

    def padded_fa_rate_per_px2_by_blur(self) -> np.ndarray:
        """False boxes per frame per detector-input px^2, indexed as ``padded_tables_by_blur``
        (0 outside the size bins and beyond the last blur edge; the same rate, by size only,
        in every blur row: the fit measures it by size only). All 0 without
        ``fa_rate_per_mpx``."""
        rate = np.zeros((self.n_table_rows, self.n_bins + 2))
        if self.fa_rate_per_mpx is not None:
            rate[:max(1, self.n_table_rows - 1), 1:-1] = (
                np.asarray(self.fa_rate_per_mpx, dtype=float) / _PX2_PER_MPX)
        return rate.ravel()

    def p_false_alarm_per_look(self, size_px: np.ndarray, area_px2: np.ndarray) -> np.ndarray:
        """Probability of at least one false box in a region of ``area_px2`` detector-input
        px^2 in one frame, whose objects would be ``size_px`` (detector-input px): the false
        boxes of that size are a Poisson process over the image, 1 - exp(-rate(s) A)."""
        rate = self.padded_fa_rate_per_px2_by_blur()[: self.n_bins + 2]
        return -np.expm1(-rate[self.bin_index(size_px)] * np.asarray(area_px2, dtype=float))

    def image_to_input_scale(self, width_px: int, height_px: int) -> float:
        """Factor from image pixels to detector-input pixels for an image of this size."""
        if self.input_size_px is None:
            return 1.0
        return self.input_size_px / max(width_px, height_px)

    def bin_index(self, size_px: np.ndarray) -> np.ndarray:
        """Index into ``lookup_table`` arrays: 0 below the first edge, N + 1 at/above the last,
        i + 1 for bin i. NaN sizes map to 0. A scalar size gives a 0-d array."""
        s = np.asarray(size_px, dtype=float)
        idx = np.searchsorted(np.asarray(self.bin_edges_px), s, side="right")
        return np.where(np.isnan(s), 0, idx)

    def lookup(self, size_px: np.ndarray, blur_px: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """P_D and P_FA for sizes in detector-input pixels (vectorised; 0 outside the bins),
        by blur bin too when ``blur_px`` (detector-input pixels) is given and the model has
        blur bins; otherwise by size only."""
        idx = self.bin_index(size_px)
        if blur_px is not None and self.blur is not None:
            idx = self.blur_row(blur_px) * (self.n_bins + 2) + idx
        pd, pfa = self.padded_tables_by_blur()
        return pd[idx], pfa[idx]

    def padded_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """P_D and P_FA with a zero prepended and appended, indexed by ``bin_index``."""
        pd = np.concatenate(([0.0], np.asarray(self.p_detect, dtype=float), [0.0]))
        pfa = np.concatenate(([0.0], np.asarray(self.p_false_alarm, dtype=float), [0.0]))
        return pd, pfa

    # -- YAML -------------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, doc: Any, source: str | None = None) -> DetectorModel:
        """Build from a parsed YAML mapping; errors name ``source`` and the key."""
        if not isinstance(doc, dict):
            raise DetectorModelError(f"{source or 'detector model'}: expected a mapping")
        check_keys(doc, MODEL_SCHEMA, source, "", DetectorModelError)
        version = doc.get("version")
        if version not in _READABLE_VERSIONS:
            raise DetectorModelError(
                f"{where(source, 'version')}: expected "
                f"{' or '.join(map(str, _READABLE_VERSIONS))}, got {version!r}")
        looks = None
        if doc.get("looks") is not None:
            if version < 2:
                raise DetectorModelError(
                    f"{where(source, 'looks')}: needs version 2, the file says {version}")
            lk = doc["looks"]
            rho = lk.get("correlation") if isinstance(lk, dict) else None
            if not isinstance(rho, list) or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in rho):
                raise DetectorModelError(
                    f"{where(source, 'looks.correlation')}: expected a list of numbers, "
                    f"got {rho!r}")
            looks = LooksModel(tuple(float(v) for v in rho),
                               {k: v for k, v in lk.items() if k != "correlation"})
        blur = None
        if doc.get("blur") is not None:
            if version < 3:
                raise DetectorModelError(
                    f"{where(source, 'blur')}: needs version 3, the file says {version}")
            blur = _blur_from_dict(doc["blur"], source)
        confidence = None
        if doc.get("confidence") is not None:
            if version < 5:
                raise DetectorModelError(
                    f"{where(source, 'confidence')}: needs version 5, the file says {version}")
            confidence = _confidence_from_dict(doc["confidence"], source)
        for key in ("bin_edges_px", "p_detect", "p_false_alarm"):
            if key not in doc:
                raise DetectorModelError(f"{where(source, key)}: missing (a list of numbers)")
            _check_bins(doc[key], key, source)
            if not isinstance(doc[key], list) or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in doc[key]):
                raise DetectorModelError(
                    f"{where(source, key)}: expected a list of numbers, got {doc[key]!r}")
        counts = None
        if doc.get("counts") is not None:
            c = doc["counts"]
            try:
                counts = BinCounts(tuple(int(v) for v in c["n_true"]),
                                   tuple(int(v) for v in c["n_detected"]),
                                   tuple(int(v) for v in c["n_detections"]))
            except (KeyError, TypeError, ValueError) as exc:
                raise DetectorModelError(
                    f"{where(source, 'counts')}: expected n_true, n_detected and n_detections "
                    f"lists of integers ({exc})") from None
        input_size = doc.get("input_size_px")
        if input_size is not None and (not isinstance(input_size, int)
                                       or isinstance(input_size, bool)):
            raise DetectorModelError(
                f"{where(source, 'input_size_px')}: expected an integer or null, "
                f"got {input_size!r}")
        return cls(
            bin_edges_px=tuple(float(v) for v in doc["bin_edges_px"]),
            p_detect=tuple(float(v) for v in doc["p_detect"]),
            p_false_alarm=tuple(float(v) for v in doc["p_false_alarm"]),
            fa_rate_per_mpx=_fa_rate_from_dict(doc, version, source),
            input_size_px=input_size,
            confidence_threshold=_opt_float(doc, "confidence_threshold", source),
            iou_threshold=_opt_float(doc, "iou_threshold", source),
            size_metric=doc.get("size_metric", "sqrt_area"),
            counts=counts,
            looks=looks,
            blur=blur,
            confidence=confidence,
            extra={k: v for k, v in doc.items() if k not in _ENGINE_KEYS},
            source=source,
        )

    @classmethod
    def from_yaml(cls, path: str | Path) -> DetectorModel:
        doc = load_yaml(path, "detector model", DetectorModelError, MAX_MODEL_BYTES)
        return cls.from_dict(doc, source=str(path))

    @classmethod
    def illustrative(cls) -> DetectorModel:
        """The bundled illustrative model (shape like the paper's Fig. 6; not a real detector)."""
        ref = resources.files("pdcov") / "data" / "illustrative_detector.yaml"
        return cls.from_dict(yaml.safe_load(ref.read_text()), source=str(ref))

    def to_dict(self) -> dict[str, Any]:
        sections = ((FORMAT_VERSION, self.confidence), (4, self.fa_rate_per_mpx), (3, self.blur),
                    (2, self.looks))
        doc: dict[str, Any] = {
            "version": next((v for v, part in sections if part is not None), 1),
            "size_metric": self.size_metric,
            "input_size_px": self.input_size_px,
            "confidence_threshold": self.confidence_threshold,
            "iou_threshold": self.iou_threshold,
            "bin_edges_px": [float(v) for v in self.bin_edges_px],
            "p_detect": [float(v) for v in self.p_detect],
            "p_false_alarm": [float(v) for v in self.p_false_alarm],
        }
        if self.fa_rate_per_mpx is not None:
            doc["fa_rate_per_mpx"] = [float(v) for v in self.fa_rate_per_mpx]
        if self.counts is not None:
            doc["counts"] = {"n_true": list(self.counts.n_true),
                             "n_detected": list(self.counts.n_detected),
                             "n_detections": list(self.counts.n_detections)}
        if self.looks is not None:
            doc["looks"] = {"correlation": [float(v) for v in self.looks.correlation],
                            **self.looks.extra}
        if self.blur is not None:
            doc["blur"] = {"edges_px": [float(v) for v in self.blur.edges_px],
                           "p_detect": [[float(v) for v in row] for row in self.blur.p_detect],
                           "p_false_alarm": [[float(v) for v in row]
                                             for row in self.blur.p_false_alarm],
                           **self.blur.extra}
        if self.confidence is not None:
            c = self.confidence
            doc["confidence"] = {"edges": [float(v) for v in c.edges],
                                 "tp_density": [[float(v) for v in row] for row in c.tp_density],
                                 "fp_density": [[float(v) for v in row] for row in c.fp_density],
                                 **c.extra}
        doc.update(self.extra)
        return doc

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)


def _opt_float(doc: dict[str, Any], key: str, source: str | None) -> float | None:
    v = doc.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise DetectorModelError(f"{where(source, key)}: expected a number, got {v!r}")
    return float(v)


def _check_bins(v: Any, key: str, source: str | None) -> None:
    """Refuse a list of more than MAX_BINS + 1 entries before anything is built of it."""
    if isinstance(v, list) and len(v) > MAX_BINS + 1:
        raise DetectorModelError(f"{where(source, key)}: {len(v):,} entries, more than a "
                                 f"model of {MAX_BINS} bins has ({MAX_BINS + 1} edges)")


def _fa_rate_from_dict(doc: dict[str, Any], version: int, source: str | None
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


def _blur_from_dict(bl: Any, source: str | None) -> BlurModel:
    """The ``blur`` section: edges_px (numbers), p_detect and p_false_alarm (rows of
    numbers); the values are checked by DetectorModel."""
    edges, rows, extra = _tables_from_dict(bl, "blur", "edges_px",
                                           ("p_detect", "p_false_alarm"), source)
    return BlurModel(edges, rows[0], rows[1], extra)


def _confidence_from_dict(sec: Any, source: str | None) -> ConfidenceModel:
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
    built (``_check_bins``); the values are checked by DetectorModel."""
    if not isinstance(sec, dict):
        raise DetectorModelError(f"{where(source, name)}: expected a mapping")

    def numbers(v: Any) -> bool:
        return isinstance(v, list) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)

    for key in (edges_key, *table_keys):
        v = sec.get(key)
        for part in (v, *(v if key != edges_key and isinstance(v, list) else ())):
            _check_bins(part, f"{name}.{key}", source)
        if key == edges_key and not numbers(v) or key != edges_key and not (
                isinstance(v, list) and all(numbers(row) for row in v)):
            raise DetectorModelError(
                f"{where(source, name + '.' + key)}: expected "
                f"{'a list of numbers' if key == edges_key else 'a list of rows of numbers'}"
                f", got {v!r}")
    return (tuple(float(x) for x in sec[edges_key]),
            [tuple(tuple(float(x) for x in row) for row in sec[key]) for key in table_keys],
            {k: v for k, v in sec.items() if k not in (edges_key, *table_keys)})
