"""Matching a detector's boxes to a labelled test set's ground truth (COCO's rule), per image
and per class; the first step of the detector statistics (``detection/statistics.py``).

1. ``match_image`` / ``match_images``: per image and per class (COCO never matches a
   detection to an object of another class), keep at most ``max_detections`` detections of
   highest confidence (COCO's maxDets), drop degenerate boxes and boxes at least half inside
   ignored regions, and match detections at or above the confidence threshold, highest
   confidence first, each to the unmatched ground truth of its class of highest IoU at or
   above the IoU threshold (the COCO rule, crowd/ignored ground truth last, matched by
   intersection over the detection's area and never consumed). The counts of the classes of
   the class set are then merged into one target class.
2. Object size s = sqrt(w h) in detector-input pixels (image pixels times
   input_size_px / max(image width, height)).

Boxes are top-left (x, y, width, height) in image pixels.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import shapely

from pdcov.detection.truth_set import Boxes, ImageTruth
from pdcov.errors import ConfigError, InputFileError

__all__ = ["DEFAULT_MAX_DETECTIONS", "DetectionStatus", "ImageMatch", "MatchCollector",
           "Matches", "MatchSettings", "TruthStatus", "input_scale", "iou_matrix",
           "match_image", "match_images"]

DEFAULT_MAX_DETECTIONS = 100  # COCO's maxDets for AP and recall at 100


class TruthStatus(IntEnum):
    """What matching made of a ground-truth box; only MISSED and DETECTED are counted."""

    MISSED = 0
    DETECTED = 1
    OTHER_CLASS = 2
    IGNORED = 3  # COCO crowd, VisDrone score 0
    DEGENERATE = 4  # width or height <= 0
    IN_IGNORED_REGION = 5


class DetectionStatus(IntEnum):
    """What matching made of a detection; only FALSE and TRUE are counted."""

    FALSE = 0
    TRUE = 1
    OTHER_CLASS = 2
    BELOW_THRESHOLD = 3
    DEGENERATE = 4
    IN_IGNORED_REGION = 5
    ON_IGNORED_TRUTH = 6
    OVER_MAX_DETECTIONS = 7  # beyond the image's max_detections of its class (COCO maxDets)


@dataclass(frozen=True, slots=True)
class MatchSettings:
    """Thresholds and the class set of a fit. classes None: every class, merged.
    max_detections: per image and class, only this many detections of highest confidence
    are evaluated (COCO's maxDets, 100); None: all."""

    confidence_threshold: float = 0.5
    iou_threshold: float = 0.5
    input_size_px: int | None = 640
    classes: tuple[str, ...] | None = None
    max_detections: int | None = DEFAULT_MAX_DETECTIONS

    def __post_init__(self) -> None:
        if self.max_detections is not None and not self.max_detections >= 1:
            raise ConfigError(f"--max-detections: expected a number of detections >= 1 or "
                              f"'none', got {self.max_detections}")
        if not 0 <= self.confidence_threshold <= 1:
            raise ConfigError(f"--conf: expected a confidence in [0, 1], got "
                              f"{self.confidence_threshold}")
        if not 0 < self.iou_threshold <= 1:
            raise ConfigError(f"--iou: expected an IoU in (0, 1], got {self.iou_threshold}")
        if self.input_size_px is not None and self.input_size_px <= 0:
            raise ConfigError(f"--input-size: expected a positive number of pixels, got "
                              f"{self.input_size_px}")
        if self.classes is not None and not self.classes:
            raise ConfigError("--classes: expected at least one class name")


@dataclass(frozen=True, slots=True)
class ImageMatch:
    """Status of each ground-truth box and each detection of one image, in input order."""

    truth_status: np.ndarray
    detection_status: np.ndarray


@dataclass(frozen=True, slots=True)
class Matches:
    """Matching outcome of a whole set: sizes (detector-input px) of the counted ground truth
    and whether it was detected; of the counted detections, whether they were true and their
    confidences; and
    how many boxes each status holds (e.g. ``truth_degenerate``). truth_blur_px,
    detection_blur_px: the motion blur of each counted box's image, in detector-input px
    (NaN when no blur was given). image_area_mpx: the images' summed area in megapixels of
    detector input (NaN when an image's size is unknown), over which false boxes are counted.
    """

    settings: MatchSettings
    truth_size_px: np.ndarray
    truth_detected: np.ndarray
    detection_size_px: np.ndarray
    detection_true: np.ndarray
    detection_confidence: np.ndarray
    n_images: int
    status_counts: dict[str, int]
    truth_blur_px: np.ndarray
    detection_blur_px: np.ndarray
    image_area_mpx: float = math.nan


def iou_matrix(det_xywh: np.ndarray, truth_xywh: np.ndarray,
               over_detection: np.ndarray) -> np.ndarray:
    """(n_det, n_truth) intersection over union; over the detection's area alone in the
    columns where ``over_detection`` is True (COCO crowd boxes)."""
    d = det_xywh[:, None, :]
    t = truth_xywh[None, :, :]
    iw = np.clip(np.minimum(d[..., 0] + d[..., 2], t[..., 0] + t[..., 2])
                 - np.maximum(d[..., 0], t[..., 0]), 0, None)
    ih = np.clip(np.minimum(d[..., 1] + d[..., 3], t[..., 1] + t[..., 3])
                 - np.maximum(d[..., 1], t[..., 1]), 0, None)
    inter = iw * ih
    area_d = d[..., 2] * d[..., 3]
    union = np.where(over_detection[None, :], area_d, area_d + t[..., 2] * t[..., 3] - inter)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def _in_regions(xywh: np.ndarray, regions_xywh: np.ndarray) -> np.ndarray:
    """True for boxes at least half of whose area lies in the union of the regions."""
    if len(regions_xywh) == 0 or len(xywh) == 0:
        return np.zeros(len(xywh), bool)
    r = regions_xywh
    union = shapely.union_all(shapely.box(r[:, 0], r[:, 1], r[:, 0] + r[:, 2], r[:, 1] + r[:, 3]))
    boxes = shapely.box(xywh[:, 0], xywh[:, 1], xywh[:, 0] + xywh[:, 2], xywh[:, 1] + xywh[:, 3])
    area = xywh[:, 2] * xywh[:, 3]
    return shapely.area(shapely.intersection(boxes, union)) >= 0.5 * area


def _in_class_set(labels: tuple[str, ...], classes: tuple[str, ...] | None) -> np.ndarray:
    if classes is None:
        return np.ones(len(labels), bool)
    return np.array([lab in classes for lab in labels], bool).reshape(len(labels))


def match_image(truth: ImageTruth, detections: Boxes, settings: MatchSettings) -> ImageMatch:
    """Match one image's detections to its ground truth (see the module docstring)."""
    gt, dt = truth.boxes, detections
    ts = np.full(len(gt), TruthStatus.MISSED, np.int8)
    ts[gt.ignore] = TruthStatus.IGNORED
    ts[(gt.xywh[:, 2] <= 0) | (gt.xywh[:, 3] <= 0)] = TruthStatus.DEGENERATE
    ts[(ts != TruthStatus.DEGENERATE) & _in_regions(gt.xywh, truth.ignore_regions_xywh)] = \
        TruthStatus.IN_IGNORED_REGION
    ts[~_in_class_set(gt.labels, settings.classes)] = TruthStatus.OTHER_CLASS

    ds = np.full(len(dt), DetectionStatus.FALSE, np.int8)
    ds[dt.scores < settings.confidence_threshold] = DetectionStatus.BELOW_THRESHOLD
    degenerate = (dt.xywh[:, 2] <= 0) | (dt.xywh[:, 3] <= 0)
    ds[degenerate] = DetectionStatus.DEGENERATE
    ds[~degenerate & _in_regions(dt.xywh, truth.ignore_regions_xywh)] = \
        DetectionStatus.IN_IGNORED_REGION
    in_set = _in_class_set(dt.labels, settings.classes)
    ds[~in_set] = DetectionStatus.OTHER_CLASS

    gt_labels, dt_labels = np.asarray(gt.labels, dtype=object), np.asarray(dt.labels, dtype=object)
    for label in sorted(set(dt.labels[i] for i in np.flatnonzero(in_set))):
        of_class = np.flatnonzero(dt_labels == label)
        if settings.max_detections is not None and len(of_class) > settings.max_detections:
            # COCOeval: the maxDets of highest score, ties in input order.
            order = np.argsort(-dt.scores[of_class], kind="mergesort")
            ds[of_class[order[settings.max_detections:]]] = DetectionStatus.OVER_MAX_DETECTIONS
        _match_class(gt, dt, ts, ds, np.flatnonzero(gt_labels == label), of_class,
                     settings.iou_threshold)
    return ImageMatch(ts, ds)


def _match_class(gt: Boxes, dt: Boxes, ts: np.ndarray, ds: np.ndarray, gt_idx: np.ndarray,
                 dt_idx: np.ndarray, iou_threshold: float) -> None:
    """Greedy COCO matching of the detections ``dt_idx`` to the ground truth ``gt_idx`` of
    one class, updating the statuses ``ts`` and ``ds`` in place."""
    real = gt_idx[ts[gt_idx] == TruthStatus.MISSED]
    crowd = gt_idx[ts[gt_idx] == TruthStatus.IGNORED]
    cand = dt_idx[ds[dt_idx] == DetectionStatus.FALSE]
    cand = cand[np.argsort(-dt.scores[cand], kind="mergesort")]
    if not (len(cand) and len(real) + len(crowd)):
        return
    cols = np.concatenate([real, crowd])
    ious = iou_matrix(dt.xywh[cand], gt.xywh[cols], np.arange(len(cols)) >= len(real))
    thr = min(iou_threshold, 1 - 1e-10)  # as COCOeval, so that IoU 1 can match
    free = np.ones(len(real), bool)
    for row, d in zip(ious, cand, strict=True):
        ok = free & (row[:len(real)] >= thr)
        if ok.any():
            # COCOeval keeps the last of equal best IoUs
            best = np.where(ok, row[:len(real)], -1.0)
            g = len(best) - 1 - int(np.argmax(best[::-1]))
            free[g] = False
            ts[real[g]] = TruthStatus.DETECTED
            ds[d] = DetectionStatus.TRUE
        elif (row[len(real):] >= thr).any():
            ds[d] = DetectionStatus.ON_IGNORED_TRUTH


def _sqrt_area(xywh: np.ndarray) -> np.ndarray:
    return np.sqrt(xywh[:, 2] * xywh[:, 3])


def input_scale(truth: ImageTruth, settings: MatchSettings) -> float:
    """Factor from the image's pixels to detector-input pixels (1 without an input size)."""
    if settings.input_size_px is None:
        return 1.0
    if truth.width_px is None or truth.height_px is None:
        raise InputFileError(f"image {truth.image_id!r}: size unknown, needed to scale "
                             f"to the {settings.input_size_px}-px detector input")
    return settings.input_size_px / max(truth.width_px, truth.height_px)


class MatchCollector:
    """Matches images one at a time (``add``) and gathers the counted sizes and outcomes of
    the whole set (``result``); for callers that also need each image's statuses."""

    def __init__(self, settings: MatchSettings) -> None:
        self.settings = settings
        self._t_size: list[np.ndarray] = []
        self._t_hit: list[np.ndarray] = []
        self._d_size: list[np.ndarray] = []
        self._d_true: list[np.ndarray] = []
        self._d_conf: list[np.ndarray] = []
        self._t_blur: list[np.ndarray] = []
        self._d_blur: list[np.ndarray] = []
        self._counts: Counter[str] = Counter()
        self._n_images = 0
        self._area_px2 = 0.0

    def add(self, truth: ImageTruth, dets: Boxes, blur_px: float = math.nan
            ) -> tuple[ImageMatch, np.ndarray]:
        """Match one image (motion blur ``blur_px`` in image px, NaN: not given); its
        statuses and the size (detector-input px) of every ground-truth box, in input
        order."""
        m = match_image(truth, dets, self.settings)
        scale = input_scale(truth, self.settings)
        size = _sqrt_area(truth.boxes.xywh) * scale
        tk = m.truth_status <= TruthStatus.DETECTED
        dk = m.detection_status <= DetectionStatus.TRUE
        self._t_size.append(size[tk])
        self._t_hit.append(m.truth_status[tk] == TruthStatus.DETECTED)
        self._d_size.append(_sqrt_area(dets.xywh[dk]) * scale)
        self._d_true.append(m.detection_status[dk] == DetectionStatus.TRUE)
        self._d_conf.append(dets.scores[dk])
        self._t_blur.append(np.full(int(tk.sum()), blur_px * scale))
        self._d_blur.append(np.full(int(dk.sum()), blur_px * scale))
        self._counts.update(f"truth_{TruthStatus(s).name.lower()}" for s in m.truth_status)
        self._counts.update(f"detection_{DetectionStatus(s).name.lower()}"
                            for s in m.detection_status)
        self._n_images += 1
        w, h = truth.width_px, truth.height_px
        self._area_px2 += math.nan if w is None or h is None else w * h * scale**2
        return m, size

    def result(self) -> Matches:
        def cat(parts: list[np.ndarray], dtype: type) -> np.ndarray:
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        return Matches(self.settings, cat(self._t_size, float), cat(self._t_hit, bool),
                       cat(self._d_size, float), cat(self._d_true, bool),
                       cat(self._d_conf, float), self._n_images,
                       dict(sorted(self._counts.items())), cat(self._t_blur, float),
                       cat(self._d_blur, float), self._area_px2 / 1e6)


def match_images(pairs: Iterable[tuple[ImageTruth, Boxes]], settings: MatchSettings,
                 image_blur_px: Mapping[str, float] | None = None) -> Matches:
    """Match every image and gather counted sizes (detector-input px) and outcomes;
    ``image_blur_px``: each image's motion blur (image px, by image id), scaled to the
    detector input as the sizes are."""
    collector = MatchCollector(settings)
    for truth, dets in pairs:
        collector.add(truth, dets,
                      math.nan if image_blur_px is None else image_blur_px[truth.image_id])
    return collector.result()
