"""Labelled test sets and detector outputs: COCO JSON, YOLO txt, VisDrone txt and the
plain-text boxes of Object-Detection-Metrics.

Every format becomes the same structure: a ``TruthSet`` (per image, its size, its ground-truth
boxes and any ignored regions) and, per image, the detector's ``Boxes`` with their confidences.
Boxes are top-left (x, y, width, height) in image pixels. Errors name the file and the line
(text formats) or the record (JSON) that is wrong.

* COCO: the ground truth is an instances JSON (``images`` with width/height, ``annotations``
  with ``bbox``, ``category_id``, ``iscrowd``, ``categories``); detections are the results list
  (``image_id``, ``category_id``, ``bbox``, ``score``). Crowd annotations are ignored regions in
  COCO's sense: a detection matching one is neither true nor false.
* YOLO: one ``<image stem>.txt`` per image, lines ``class cx cy w h`` normalised to the image
  (detections add a confidence column). Image sizes come from the images or a sizes file; an
  image without a label file has no objects. Class names from a ``names`` file (data YAML or
  one name a line), else the class ids as text. A coordinate above 1 (pixels, not
  normalised) is refused naming the file and line.
* VisDrone-DET: one ``<image stem>.txt`` per image, lines ``x,y,w,h,score,category,truncation,
  occlusion``. Category 0 ("ignored regions") boxes are regions: objects and detections lying
  at least half inside them are dropped, as the VisDrone-DET toolkit does; ground truth with
  score 0 is ignored like a COCO crowd box.
* Object-Detection-Metrics (rafaelpadilla; format ``odm``): one ``<image stem>.txt`` per
  image, lines ``class left top width height`` (ground truth) or ``class confidence left top
  width height`` (detections) in image pixels, the class a name; ``box_format`` ``xyrb``
  reads ``left top right bottom`` instead (the tools' ``-gtformat`` / ``-detformat``).

Detection confidences must lie in [0, 1]; a score outside is refused naming the file and the
line or record.

Over 450 lines on purpose: one concept (four formats read into one structure) whose readers
share the line, number and size helpers; split it per format when a fifth format arrives.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pdcov.errors import ConfigError, InputFileError

FORMATS = ("coco", "yolo", "visdrone", "odm")
BOX_FORMATS = ("xywh", "xyrb")  # Object-Detection-Metrics: width/height or right/bottom
_NORMALISED_TOL = 1e-6  # YOLO coordinates printed with rounding may pass 1 by this much
VISDRONE_CLASSES = ("ignored regions", "pedestrian", "people", "bicycle", "car", "van", "truck",
                    "tricycle", "awning-tricycle", "bus", "motor", "others")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


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


# -- entry points ----------------------------------------------------------------------------


def detect_format(path: Path) -> str:
    """Guess the format: a ``.json`` file is COCO; a directory of txt files is VisDrone when its
    first non-empty line is comma-separated, Object-Detection-Metrics when it starts with a
    class name (not a number), YOLO otherwise."""
    if path.is_file() and path.suffix.lower() == ".json":
        return "coco"
    if path.is_dir():
        for txt in sorted(_labels_dir(path).glob("*.txt")):
            for line in txt.read_text(errors="replace").splitlines():
                if line.strip():
                    if "," in line:
                        return "visdrone"
                    return "yolo" if _is_number(line.split()[0]) else "odm"
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
        return _read_coco_truth(path)
    labels = _labels_dir(path)
    sizes = _image_sizes(labels, images_dir, sizes_path)
    if fmt == "yolo":
        return _read_yolo_truth(labels, sizes, _class_names(names_path))
    if fmt == "visdrone":
        return _read_visdrone_truth(labels, sizes)
    if fmt == "odm":
        return _read_odm_truth(labels, sizes, _box_format(box_format))
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
        return _read_coco_detections(path, truth)
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
            out[image_id] = _visdrone_detections(txt, truth)
        elif fmt == "odm":
            out[image_id] = _read_odm_file(txt, box, True)
        else:
            image = truth.images[image_id]
            if image.width_px is None or image.height_px is None:
                raise InputFileError(f"{txt}: normalised boxes need the size of image "
                                     f"{image_id!r}; pass --images or --sizes")
            out[image_id] = _read_yolo_file(txt, truth, image.width_px, image.height_px, True)
    return out


# -- COCO ------------------------------------------------------------------------------------


def _load_json(path: Path) -> Any:
    try:
        with path.open() as f:
            return json.load(f)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot read ({exc.strerror})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        line = f":{exc.lineno}" if isinstance(exc, json.JSONDecodeError) else ""
        raise InputFileError(f"{path}{line}: not valid JSON ({exc})") from None


def _field(rec: Any, key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    if not isinstance(rec, dict) or key not in rec:
        raise InputFileError(f"{where}: missing {key!r}")
    v = rec[key]
    if isinstance(v, bool) or not isinstance(v, kind):
        raise InputFileError(f"{where}: {key!r} has the wrong type ({v!r})")
    return v


def _bbox(rec: Any, where: str) -> tuple[float, float, float, float]:
    b = _field(rec, "bbox", where, list)
    if len(b) != 4 or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                              and math.isfinite(v) for v in b):
        raise InputFileError(f"{where}: 'bbox' must be 4 finite numbers [x, y, w, h], got {b!r}")
    return (float(b[0]), float(b[1]), float(b[2]), float(b[3]))


def _read_coco_truth(path: Path) -> TruthSet:
    doc = _load_json(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("images"), list) \
            or not isinstance(doc.get("annotations"), list) \
            or not isinstance(doc.get("categories", []), list):
        raise InputFileError(f"{path}: expected a COCO instances object with 'images', "
                             f"'annotations' and 'categories' lists")
    class_ids = {}
    for i, rec in enumerate(doc.get("categories", [])):
        where = f"{path}: categories[{i}]"
        class_ids[str(_field(rec, "id", where, int))] = _field(rec, "name", where, str)
    truth = TruthSet({}, tuple(dict.fromkeys(class_ids.values())), str(path), "coco",
                     class_ids, {})
    sizes: dict[str, tuple[int, int]] = {}
    for i, rec in enumerate(doc["images"]):
        where = f"{path}: images[{i}]"
        image_id = str(_field(rec, "id", where, (int, str)))
        sizes[image_id] = (_field(rec, "width", where, int), _field(rec, "height", where, int))
        if isinstance(rec.get("file_name"), str):
            truth.aliases[Path(rec["file_name"]).stem] = image_id
    rows: dict[str, list[Any]] = {k: [] for k in sizes}
    for i, rec in enumerate(doc["annotations"]):
        where = f"{path}: annotations[{i}]"
        image_id = str(_field(rec, "image_id", where, (int, str)))
        if image_id not in rows:
            raise InputFileError(f"{where}: image_id {image_id} is not in 'images'")
        name = truth.class_name(where, _field(rec, "category_id", where, int))
        rows[image_id].append((_bbox(rec, where), name, bool(rec.get("iscrowd", 0))))
    for k, v in rows.items():
        truth.images[k] = ImageTruth(k, sizes[k][0], sizes[k][1], Boxes.from_rows(
            [r[0] for r in v], [r[1] for r in v], ignore=[r[2] for r in v]))
    return truth


def _read_coco_detections(path: Path, truth: TruthSet) -> dict[str, Boxes]:
    doc = _load_json(path)
    if not isinstance(doc, list):
        raise InputFileError(f"{path}: expected a COCO results list of detections")
    rows: dict[str, list[Any]] = {}
    for i, rec in enumerate(doc):
        where = f"{path}: [{i}]"
        ref = str(_field(rec, "image_id", where, (int, str)))
        image_id = truth.resolve(ref)
        if image_id is None:
            raise InputFileError(f"{where}: image_id {ref} is not in the ground truth "
                                 f"{truth.source}")
        name = truth.class_name(where, _field(rec, "category_id", where, int))
        score = _score(where, float(_field(rec, "score", where, (int, float))))
        rows.setdefault(image_id, []).append((_bbox(rec, where), name, score))
    return {k: Boxes.from_rows([r[0] for r in v], [r[1] for r in v], [r[2] for r in v])
            for k, v in rows.items()}


# -- text formats (YOLO, VisDrone) -----------------------------------------------------------


def _labels_dir(path: Path) -> Path:
    """A VisDrone-DET split directory holds its labels in ``annotations/``."""
    return path / "annotations" if (path / "annotations").is_dir() else path


def _lines(path: Path, commas: bool = True) -> Iterator[tuple[str, list[str]]]:
    """(``file:line``, fields) of each non-empty line; fields split at blanks (and commas,
    unless ``commas`` is False)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: cannot read ({exc})") from None
    for n, line in enumerate(text.splitlines(), start=1):
        line = line.strip().rstrip(",") if commas else line.strip()
        if line:
            yield f"{path}:{n}", (line.replace(",", " ") if commas else line).split()


def _numbers(where: str, fields: list[str], counts: tuple[int, ...], layout: str) -> list[float]:
    if len(fields) not in counts:
        raise InputFileError(f"{where}: expected {layout}, got {len(fields)} fields")
    try:
        values = [float(v) for v in fields]
    except ValueError:
        raise InputFileError(f"{where}: expected numbers ({layout}), got "
                             f"{' '.join(fields)!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputFileError(f"{where}: non-finite number in {' '.join(fields)!r}")
    return values


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _score(where: str, value: float) -> float:
    """A detection's confidence, which must be a probability."""
    if not 0 <= value <= 1:
        raise InputFileError(f"{where}: detection score {value:g} outside [0, 1] (a "
                             "confidence is a probability; logits or percentages must be "
                             "converted)")
    return value


def _box_format(box_format: str) -> str:
    if box_format not in BOX_FORMATS:
        raise ConfigError(f"--box-format: expected one of {BOX_FORMATS}, got {box_format!r}")
    return box_format


def _class_id(where: str, value: float) -> int:
    if value != int(value) or value < 0:
        raise InputFileError(f"{where}: class must be an integer >= 0, got {value:g}")
    return int(value)


def _image_sizes(labels: Path, images_dir: str | Path | None,
                 sizes_path: str | Path | None) -> dict[str, tuple[int, int]] | None:
    if sizes_path is not None:
        return _read_sizes(Path(sizes_path))
    if images_dir is None:
        candidates = [labels.parent / "images"]
        if "labels" in labels.parts:  # Ultralytics layout: .../labels/val beside .../images/val
            i = len(labels.parts) - 1 - labels.parts[::-1].index("labels")
            candidates.append(Path(*labels.parts[:i], "images", *labels.parts[i + 1:]))
        images_dir = next((c for c in candidates if c.is_dir()), None)
        if images_dir is None:
            return None
    return _sizes_from_images(Path(images_dir))


def _read_sizes(path: Path) -> dict[str, tuple[int, int]]:
    """A sizes file: lines ``image width height`` (image file name or stem)."""
    if not path.is_file():
        raise InputFileError(f"{path}: no such sizes file")
    sizes = {}
    for where, fields in _lines(path):
        try:
            w, h = int(fields[1]), int(fields[2])
            if len(fields) != 3 or w <= 0 or h <= 0:
                raise ValueError
        except (ValueError, IndexError):
            raise InputFileError(f"{where}: expected 'image width height' with positive "
                                 f"integer sizes, got {' '.join(fields)!r}") from None
        name = Path(fields[0])
        sizes[name.stem if name.suffix.lower() in IMAGE_SUFFIXES else fields[0]] = (w, h)
    return sizes


def _sizes_from_images(images_dir: Path) -> dict[str, tuple[int, int]]:
    if not images_dir.is_dir():
        raise InputFileError(f"{images_dir}: no such images directory")
    try:
        from PIL import Image  # opening reads only the header
    except ImportError:
        raise InputFileError(f"{images_dir}: reading image sizes needs Pillow; install it or "
                             f"pass --sizes FILE") from None
    sizes = {}
    for p in sorted(images_dir.iterdir()):
        if p.suffix.lower() in IMAGE_SUFFIXES:
            try:
                with Image.open(p) as im:
                    sizes[p.stem] = im.size
            except OSError as exc:
                raise InputFileError(f"{p}: cannot read image size ({exc})") from None
    return sizes


def _class_names(path: str | Path | None) -> tuple[str, ...] | None:
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


def _read_yolo_file(txt: Path, truth: TruthSet, width: int, height: int,
                    detection: bool) -> Boxes:
    layout = "'class cx cy w h" + (" confidence'" if detection else "'")
    xywh, labels, scores = [], [], []
    for where, fields in _lines(txt):
        v = _numbers(where, fields, (6,) if detection else (5,), layout)
        labels.append(truth.class_name(where, _class_id(where, v[0])))
        pixels = [f"{name} {x:g}" for name, x in zip(("cx", "cy", "w", "h"), v[1:5],
                                                      strict=True)
                  if not -_NORMALISED_TOL <= x <= 1 + _NORMALISED_TOL]
        if pixels:
            raise InputFileError(f"{where}: {', '.join(pixels)} outside [0, 1]: YOLO boxes are "
                                 "normalised to the image size (pixel coordinates? use "
                                 "--format odm or divide by the image width and height)")
        cx, cy, w, h = v[1] * width, v[2] * height, v[3] * width, v[4] * height
        xywh.append((cx - w / 2, cy - h / 2, w, h))
        scores.append(_score(where, v[5]) if detection else math.nan)
    return Boxes.from_rows(xywh, labels, scores)


def _read_yolo_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None,
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
                                            _read_yolo_file(txt, truth, w, h, False))
    if names is None:  # the ids are the names
        seen = {lab for image in truth.images.values() for lab in image.boxes.labels}
        truth = TruthSet(truth.images, tuple(sorted(seen, key=int)), str(labels), "yolo")
    return truth


_VISDRONE_IDS = {str(i): n for i, n in enumerate(VISDRONE_CLASSES)}


def _read_visdrone_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None) -> TruthSet:
    images = {}
    for txt in sorted(labels.glob("*.txt")):
        boxes, names, ignore, regions = [], [], [], []
        for where, fields in _lines(txt):
            v = _numbers(where, fields, (8,), "'x,y,w,h,score,category,truncation,occlusion'")
            cat = _class_id(where, v[5])
            if cat >= len(VISDRONE_CLASSES):
                raise InputFileError(f"{where}: VisDrone category must be 0..11, got {cat}")
            if cat == 0:
                regions.append(v[:4])
            else:
                boxes.append(tuple(v[:4]))
                names.append(VISDRONE_CLASSES[cat])
                ignore.append(v[4] == 0)  # score 0: "ignored in evaluation"
        if sizes is not None and txt.stem not in sizes:
            raise InputFileError(f"{txt}: no image {txt.stem!r} among the image sizes")
        w, h = sizes[txt.stem] if sizes is not None else (None, None)
        images[txt.stem] = ImageTruth(txt.stem, w, h,
                                      Boxes.from_rows(boxes, names, ignore=ignore),
                                      np.asarray(regions, dtype=float).reshape(-1, 4))
    if not images:
        raise InputFileError(f"{labels}: no VisDrone annotation (.txt) files")
    return TruthSet(images, VISDRONE_CLASSES[1:], str(labels), "visdrone", _VISDRONE_IDS)


def _visdrone_detections(txt: Path, truth: TruthSet) -> Boxes:
    xywh, labels, scores = [], [], []
    for where, fields in _lines(txt):
        v = _numbers(where, fields, (6, 8), "'x,y,w,h,score,category[,truncation,occlusion]'")
        xywh.append(tuple(v[:4]))
        labels.append(truth.class_name(where, _class_id(where, v[5])))
        scores.append(_score(where, v[4]))
    return Boxes.from_rows(xywh, labels, scores)


# -- Object-Detection-Metrics ----------------------------------------------------------------


def _read_odm_file(txt: Path, box_format: str, detection: bool) -> Boxes:
    """Lines ``class [confidence] left top width height`` (``xyrb``: ``... right bottom``) in
    image pixels; the class is a name (no blanks)."""
    corners = "right bottom" if box_format == "xyrb" else "width height"
    layout = f"'class {'confidence ' if detection else ''}left top {corners}'"
    xywh, labels, scores = [], [], []
    for where, fields in _lines(txt, commas=False):
        n = 6 if detection else 5
        if len(fields) != n:
            raise InputFileError(f"{where}: expected {layout}, got {len(fields)} fields")
        v = _numbers(where, fields[1:], (n - 1,), layout)
        x0, y0, a, b = v[-4:]
        xywh.append((x0, y0, a - x0, b - y0) if box_format == "xyrb" else (x0, y0, a, b))
        labels.append(fields[0])
        scores.append(_score(where, v[0]) if detection else math.nan)
    return Boxes.from_rows(xywh, labels, scores)


def _read_odm_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None,
                    box_format: str) -> TruthSet:
    images = {}
    for txt in sorted(labels.glob("*.txt")):
        if sizes is not None and txt.stem not in sizes:
            raise InputFileError(f"{txt}: no image {txt.stem!r} among the image sizes")
        w, h = sizes[txt.stem] if sizes is not None else (None, None)
        images[txt.stem] = ImageTruth(txt.stem, w, h, _read_odm_file(txt, box_format, False))
    if not images:
        raise InputFileError(f"{labels}: no Object-Detection-Metrics ground-truth (.txt) files")
    names = sorted({lab for image in images.values() for lab in image.boxes.labels})
    return TruthSet(images, tuple(names), str(labels), "odm")
