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

The file's keys, versions and section readers are in detector_file.py; the optional
sections' types in detector_sections.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pdcov.core.detector_file import (
    ENGINE_KEYS,
    FORMAT_VERSION,
    MAX_MODEL_BYTES,
    MODEL_SCHEMA,
    READABLE_VERSIONS,
    blur_from_dict,
    check_bins,
    confidence_from_dict,
    fa_rate_from_dict,
    opt_float,
)
from pdcov.core.detector_sections import BinCounts, BlurModel, ConfidenceModel, LooksModel
from pdcov.errors import DetectorModelError, where
from pdcov.schema import check_keys
from pdcov.yaml_file import load_yaml

_PX2_PER_MPX = 1e6
SIZE_METRICS = ("sqrt_area",)


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
        if version not in READABLE_VERSIONS:
            raise DetectorModelError(
                f"{where(source, 'version')}: expected "
                f"{' or '.join(map(str, READABLE_VERSIONS))}, got {version!r}")
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
            blur = blur_from_dict(doc["blur"], source)
        confidence = None
        if doc.get("confidence") is not None:
            if version < 5:
                raise DetectorModelError(
                    f"{where(source, 'confidence')}: needs version 5, the file says {version}")
            confidence = confidence_from_dict(doc["confidence"], source)
        for key in ("bin_edges_px", "p_detect", "p_false_alarm"):
            if key not in doc:
                raise DetectorModelError(f"{where(source, key)}: missing (a list of numbers)")
            check_bins(doc[key], key, source)
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
            fa_rate_per_mpx=fa_rate_from_dict(doc, version, source),
            input_size_px=input_size,
            confidence_threshold=opt_float(doc, "confidence_threshold", source),
            iou_threshold=opt_float(doc, "iou_threshold", source),
            size_metric=doc.get("size_metric", "sqrt_area"),
            counts=counts,
            looks=looks,
            blur=blur,
            confidence=confidence,
            extra={k: v for k, v in doc.items() if k not in ENGINE_KEYS},
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
