"""COCO: the ground truth is an instances JSON (``images`` with width/height,
``annotations`` with ``bbox``, ``category_id``, ``iscrowd``, ``categories``); detections
are the results list (``image_id``, ``category_id``, ``bbox``, ``score``). Crowd
annotations are ignored regions in COCO's sense: a detection matching one is neither true
nor false. Errors name the file and the record."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from pdcov.detection.formats.fields import detection_score
from pdcov.detection.truth_set import Boxes, ImageTruth, TruthSet
from pdcov.errors import InputFileError

__all__ = ["read_coco_detections", "read_coco_truth"]


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


def read_coco_truth(path: Path) -> TruthSet:
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


def read_coco_detections(path: Path, truth: TruthSet) -> dict[str, Boxes]:
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
        score = detection_score(where, float(_field(rec, "score", where, (int, float))))
        rows.setdefault(image_id, []).append((_bbox(rec, where), name, score))
    return {k: Boxes.from_rows([r[0] for r in v], [r[1] for r in v], [r[2] for r in v])
            for k, v in rows.items()}
