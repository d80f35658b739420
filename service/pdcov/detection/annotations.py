"""Labelled test sets and detector outputs: COCO JSON, YOLO txt, VisDrone txt and the
plain-text boxes of Object-Detection-Metrics (one reader per format in
detection/formats/), each read into a ``TruthSet`` and per image ``Boxes``
(detection/truth_set.py). Errors name the file and the line (text formats) or the record
(JSON) that is wrong. Detection confidences must lie in [0, 1]; a score outside is refused
naming the file and the line or record.
"""

from __future__ import annotations

from pathlib import Path

from pdcov.detection.formats.coco import read_coco_detections, read_coco_truth
from pdcov.detection.formats.fields import image_sizes, is_number, labels_dir
from pdcov.detection.formats.odm import read_odm_file, read_odm_truth
from pdcov.detection.formats.visdrone import read_visdrone_detections, read_visdrone_truth
from pdcov.detection.formats.yolo import read_class_names, read_yolo_file, read_yolo_truth
from pdcov.detection.truth_set import Boxes, TruthSet
from pdcov.errors import ConfigError, InputFileError

__all__ = ["BOX_FORMATS", "FORMATS", "detect_format", "read_detections", "read_truth"]

FORMATS = ("coco", "yolo", "visdrone", "odm")
BOX_FORMATS = ("xywh", "xyrb")  # Object-Detection-Metrics: width/height or right/bottom


def detect_format(path: Path) -> str:
    """Guess the format: a ``.json`` file is COCO; a directory of txt files is VisDrone when its
    first non-empty line is comma-separated, Object-Detection-Metrics when it starts with a
    class name (not a number), YOLO otherwise."""
    if path.is_file() and path.suffix.lower() == ".json":
        return "coco"
    if path.is_dir():
        for txt in sorted(labels_dir(path).glob("*.txt")):
            for line in txt.read_text(errors="replace").splitlines():
                if line.strip():
                    if "," in line:
                        return "visdrone"
                    return "yolo" if is_number(line.split()[0]) else "odm"
        raise InputFileError(f"{path}: no non-empty .txt file to tell the format from; "
                             f"pass --format")
    raise InputFileError(f"{path}: expected a COCO .json file or a directory of .txt files")


def read_truth(path: str | Path, fmt: str | None = None, images_dir: str | Path | None = None,
               sizes_path: str | Path | None = None,
               names_path: str | Path | None = None, box_format: str = "xywh") -> TruthSet:
    """Read a labelled test set. Image sizes for the text formats come from ``sizes_path``
    (lines ``image width height``) or the images in ``images_dir`` (default: an ``images``
    directory beside the labels); YOLO class names from ``names_path``; ``box_format``
    (``xywh`` or ``xyrb``) applies to the ``odm`` format."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path}: no such file or directory")
    fmt = fmt or detect_format(path)
    if fmt == "coco":
        return read_coco_truth(path)
    labels = labels_dir(path)
    sizes = image_sizes(labels, images_dir, sizes_path)
    if fmt == "yolo":
        return read_yolo_truth(labels, sizes, read_class_names(names_path))
    if fmt == "visdrone":
        return read_visdrone_truth(labels, sizes)
    if fmt == "odm":
        return read_odm_truth(labels, sizes, _box_format(box_format))
    raise ConfigError(f"--format: expected one of {FORMATS}, got {fmt!r}")


def read_detections(path: str | Path, truth: TruthSet, fmt: str | None = None,
                    box_format: str = "xywh") -> dict[str, Boxes]:
    """Read detector outputs for the images of ``truth`` (whose class ids name the classes);
    images without any have none. A detection on an image not in ``truth`` is an error.
    ``fmt`` None: a directory is in the ground truth's text format, else as detected.
    ``box_format``: of the ``odm`` format."""
    path = Path(path)
    if not path.exists():
        raise InputFileError(f"{path}: no such file or directory")
    if fmt is None:  # a directory of text files is read like the ground truth's
        fmt = truth.format if path.is_dir() and truth.format != "coco" else detect_format(path)
    if fmt == "coco":
        return read_coco_detections(path, truth)
    if fmt not in ("yolo", "visdrone", "odm"):
        raise ConfigError(f"--format: expected one of {FORMATS}, got {fmt!r}")
    box = _box_format(box_format)
    if not path.is_dir():
        raise InputFileError(f"{path}: expected a directory of per-image .txt detection files")
    out = {}
    for txt in sorted(path.glob("*.txt")):
        image_id = truth.resolve(txt.stem)
        if image_id is None:
            raise InputFileError(f"{txt}: image {txt.stem!r} is not in the ground truth "
                                 f"{truth.source}")
        if fmt == "visdrone":
            out[image_id] = read_visdrone_detections(txt, truth)
        elif fmt == "odm":
            out[image_id] = read_odm_file(txt, box, True)
        else:
            image = truth.images[image_id]
            if image.width_px is None or image.height_px is None:
                raise InputFileError(f"{txt}: normalised boxes need the size of image "
                                     f"{image_id!r}; pass --images or --sizes")
            out[image_id] = read_yolo_file(txt, truth, image.width_px, image.height_px, True)
    return out


def _box_format(box_format: str) -> str:
    if box_format not in BOX_FORMATS:
        raise ConfigError(f"--box-format: expected one of {BOX_FORMATS}, got {box_format!r}")
    return box_format
