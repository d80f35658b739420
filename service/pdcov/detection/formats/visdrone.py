"""VisDrone-DET: one ``<image stem>.txt`` per image, lines ``x,y,w,h,score,category,
truncation,occlusion``. Category 0 ("ignored regions") boxes are regions: objects and
detections lying at least half inside them are dropped, as the VisDrone-DET toolkit does;
ground truth with score 0 is ignored like a COCO crowd box."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pdcov.detection.formats.fields import class_id_of, detection_score, file_lines, line_numbers
from pdcov.detection.truth_set import Boxes, ImageTruth, TruthSet
from pdcov.errors import InputFileError

__all__ = ["VISDRONE_CLASSES", "read_visdrone_detections", "read_visdrone_truth"]

VISDRONE_CLASSES = ("ignored regions", "pedestrian", "people", "bicycle", "car", "van", "truck",
                    "tricycle", "awning-tricycle", "bus", "motor", "others")

_VISDRONE_IDS = {str(i): n for i, n in enumerate(VISDRONE_CLASSES)}


def read_visdrone_truth(labels: Path, sizes: dict[str, tuple[int, int]] | None) -> TruthSet:
    images = {}
    for txt in sorted(labels.glob("*.txt")):
        boxes, names, ignore, regions = [], [], [], []
        for where, fields in file_lines(txt):
            v = line_numbers(where, fields, (8,), "'x,y,w,h,score,category,truncation,occlusion'")
            cat = class_id_of(where, v[5])
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


def read_visdrone_detections(txt: Path, truth: TruthSet) -> Boxes:
    xywh, labels, scores = [], [], []
    for where, fields in file_lines(txt):
        v = line_numbers(where, fields, (6, 8), "'x,y,w,h,score,category[,truncation,occlusion]'")
        xywh.append(tuple(v[:4]))
        labels.append(truth.class_name(where, class_id_of(where, v[5])))
        scores.append(detection_score(where, v[4]))
    return Boxes.from_rows(xywh, labels, scores)
