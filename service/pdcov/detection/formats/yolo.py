"""YOLO: one ``<image stem>.txt`` per image, lines ``class cx cy w h`` normalised to the
image (detections add a confidence column). Image sizes come from the images or a sizes
file; an image without a label file has no objects. Class names from a ``names`` file (data
YAML or one name a line), else the class ids as text. A coordinate above 1 (pixels, not
normalised) is refused naming the file and line."""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from pdcov.detection.formats.fields import class_id_of, detection_score, file_lines, line_numbers
from pdcov.detection.truth_set import NO_BOXES, Boxes, ImageTruth, TruthSet
from pdcov.errors import InputFileError

__all__ = ["read_class_names", "read_yolo_file", "read_yolo_truth"]

_NORMALISED_TOL = 1e-6  # YOLO coordinates printed with rounding may pass 1 by this much


def read_class_names(path: str | Path | None) -> tuple[str, ...] | None:
    """Class names from a YOLO data YAML (``names:`` list or {id: name}) or one name a line."""
    if path is None:
        return None
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read class names ({exc.strerror})") from None
    if path.suffix.lower() not in (".yaml", ".yml"):
        return tuple(line.strip() for line in text.splitlines() if line.strip())
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputFileError(f"{path}: not valid YAML ({exc})") from None
    names = doc.get("names") if isinstance(doc, dict) else None
    if isinstance(names, dict) and sorted(names) == list(range(len(names))):
        names = [names[i] for i in range(len(names))]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise InputFileError(f"{path}: names: expected a list of class names or "
                             f"{{0: name, 1: ...}}")
    return tuple(names)


def read_yolo_file(txt: Path, truth: TruthSet, width: int, height: int,
                   detection: bool) -> Boxes:
    layout = "'class cx cy w h" + (" confidence'" if detection else "'")
    xywh, labels, scores = [], [], []
    for where, fields in file_lines(txt):
        v = line_numbers(where, fields, (6,) if detection else (5,), layout)
        labels.append(truth.class_name(where, class_id_of(where, v[0])))
        pixels = [f"{name} {x:g}" for name, x in zip(("cx", "cy", "w", "h"), v[1:5],
                                                      strict=True)
                  if not -_NORMALISED_TOL <= x <= 1 + _NORMALISED_TOL]
        if pixels:
            raise InputFileError(f"{where}: {', '.join(pixels)} outside [0, 1]: YOLO boxes are "
                                 "normalised to the image size (pixel coordinates? use "
                                 "--format odm or divide by the image width and height)")
        cx, cy, w, h = v[1] * width, v[2] * height, v[3] * width, v[4] * height
        xywh.append((cx - w / 2, cy - h / 2, w, h))
        scores.append(detection_score(where, v[5]) if detection else math.nan)
    return Boxes.from_rows(xywh, labels, scores)


def read_yolo_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None,
                    names: tuple[str, ...] | None) -> TruthSet:
    if sizes is None:
        raise InputFileError(f"{labels}: YOLO boxes are normalised to the image; pass --images "
                             f"DIR or --sizes FILE to give the image sizes")
    class_ids = {str(i): n for i, n in enumerate(names or ())}
    truth = TruthSet({k: ImageTruth(k, w, h, NO_BOXES) for k, (w, h) in sizes.items()},
                     names or (), str(labels), "yolo", class_ids)
    for txt in sorted(labels.glob("*.txt")):
        if txt.stem not in sizes:
            raise InputFileError(f"{txt}: no image {txt.stem!r} among the image sizes")
        w, h = sizes[txt.stem]
        truth.images[txt.stem] = ImageTruth(txt.stem, w, h,
                                            read_yolo_file(txt, truth, w, h, False))
    if names is None:  # the ids are the names
        seen = {lab for image in truth.images.values() for lab in image.boxes.labels}
        truth = TruthSet(truth.images, tuple(sorted(seen, key=int)), str(labels), "yolo")
    return truth
