"""A labelled test set and detector outputs in one structure, whatever file format they came
from (detection/annotations.py reads them): a ``TruthSet`` (per image, its size, its
ground-truth boxes and any ignored regions) and, per image, the detector's ``Boxes`` with
their confidences. Boxes are top-left (x, y, width, height) in image pixels."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pdcov.errors import ConfigError, InputFileError

__all__ = ["NO_BOXES", "Boxes", "ImageTruth", "TruthSet"]


@dataclass(frozen=True, slots=True)
class Boxes:
    """Axis-aligned boxes of one image.

    xywh: (n, 4) top-left x, y, width, height in image pixels.
    labels: n class names.
    scores: (n,) detector confidence; NaN for ground truth.
    ignore: (n,) True for ground truth not to be counted (COCO crowd, VisDrone score 0).
    """

    xywh: np.ndarray
    labels: tuple[str, ...]
    scores: np.ndarray
    ignore: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.labels)
        if (self.xywh.shape != (n, 4) or self.scores.shape != (n,)
                or self.ignore.shape != (n,)):
            raise ValueError(f"Boxes: inconsistent shapes {self.xywh.shape}, {n} labels, "
                             f"{self.scores.shape}, {self.ignore.shape}")

    @classmethod
    def from_rows(cls, rows: Sequence[Sequence[float]], labels: list[str],
                  scores: list[float] | None = None, ignore: list[bool] | None = None) -> Boxes:
        n = len(labels)
        return cls(xywh=np.asarray(rows, dtype=float).reshape(n, 4), labels=tuple(labels),
                   scores=np.asarray(scores if scores is not None else [math.nan] * n, float),
                   ignore=np.asarray(ignore if ignore is not None else [False] * n, bool))

    def __len__(self) -> int:
        return len(self.labels)


NO_BOXES = Boxes.from_rows([], [])


@dataclass(frozen=True, slots=True)
class ImageTruth:
    """Ground truth of one image: size in pixels (None where unknown), boxes, ignored regions
    ((m, 4) xywh image pixels; boxes at least half inside their union are not evaluated)."""

    image_id: str
    width_px: int | None
    height_px: int | None
    boxes: Boxes
    ignore_regions_xywh: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))


@dataclass(frozen=True, slots=True)
class TruthSet:
    """A labelled test set: images by id, the class names, the format's class ids (as text) to
    names (empty when the ids are the names), and file stems by which detections may name an
    image."""

    images: dict[str, ImageTruth]
    classes: tuple[str, ...]
    source: str
    format: str
    class_ids: dict[str, str] = field(default_factory=dict)
    aliases: dict[str, str] = field(default_factory=dict)

    def resolve(self, image_ref: str) -> str | None:
        """The image id a detection file's reference names, or None if no image has it."""
        if image_ref in self.images:
            return image_ref
        return self.aliases.get(image_ref)

    def class_name(self, where: str, class_id: int) -> str:
        """The name of a numeric class id read at ``where``; unknown ids are an error."""
        if not self.class_ids:
            return str(class_id)
        if str(class_id) not in self.class_ids:
            raise InputFileError(f"{where}: class {class_id} is not a class of {self.source}")
        return self.class_ids[str(class_id)]

    def check_classes(self, classes: tuple[str, ...]) -> None:
        """Raise ``ConfigError`` naming any class this set does not define."""
        unknown = [c for c in classes if c not in self.classes]
        if unknown:
            raise ConfigError(
                f"--classes: {', '.join(map(repr, unknown))} not among the classes of "
                f"{self.source}: {', '.join(self.classes)}")

    def check_sizes(self) -> None:
        """Raise ``InputFileError`` if an image's size is unknown (needed to scale boxes)."""
        for image in self.images.values():
            if image.width_px is None or image.height_px is None:
                raise InputFileError(
                    f"{self.source}: size of image {image.image_id!r} unknown; pass --images "
                    f"DIR or --sizes FILE, or --input-size none to keep image pixels")
