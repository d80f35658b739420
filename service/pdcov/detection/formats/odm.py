"""Object-Detection-Metrics (rafaelpadilla; format ``odm``): one ``<image stem>.txt`` per
image, lines ``class left top width height`` (ground truth) or ``class confidence left top
width height`` (detections) in image pixels, the class a name; ``box_format`` ``xyrb``
reads ``left top right bottom`` instead (the tools' ``-gtformat`` / ``-detformat``)."""

from __future__ import annotations

import math
from pathlib import Path

from pdcov.detection.formats.fields import detection_score, file_lines, line_numbers
from pdcov.detection.truth_set import Boxes, ImageTruth, TruthSet
from pdcov.errors import InputFileError

__all__ = ["read_odm_file", "read_odm_truth"]


def read_odm_file(txt: Path, box_format: str, detection: bool) -> Boxes:
    """Lines ``class [confidence] left top width height`` (``xyrb``: ``... right bottom``) in
    image pixels; the class is a name (no blanks)."""
    corners = "right bottom" if box_format == "xyrb" else "width height"
    layout = f"'class {'confidence ' if detection else ''}left top {corners}'"
    xywh, labels, scores = [], [], []
    for where, fields in file_lines(txt, commas=False):
        n = 6 if detection else 5
        if len(fields) != n:
            raise InputFileError(f"{where}: expected {layout}, got {len(fields)} fields")
        v = line_numbers(where, fields[1:], (n - 1,), layout)
        x0, y0, a, b = v[-4:]
        xywh.append((x0, y0, a - x0, b - y0) if box_format == "xyrb" else (x0, y0, a, b))
        labels.append(fields[0])
        scores.append(detection_score(where, v[0]) if detection else math.nan)
    return Boxes.from_rows(xywh, labels, scores)


def read_odm_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None,
                   box_format: str) -> TruthSet:
    images = {}
    for txt in sorted(labels.glob("*.txt")):
        if sizes is not None and txt.stem not in sizes:
            raise InputFileError(f"{txt}: no image {txt.stem!r} among the image sizes")
        w, h = sizes[txt.stem] if sizes is not None else (None, None)
        images[txt.stem] = ImageTruth(txt.stem, w, h, read_odm_file(txt, box_format, False))
    if not images:
        raise InputFileError(f"{labels}: no Object-Detection-Metrics ground-truth (.txt) files")
    names = sorted({lab for image in images.values() for lab in image.boxes.labels})
    return TruthSet(images, tuple(names), str(labels), "odm")
