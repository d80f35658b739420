"""Small labelled test sets on disk, one per format pdcov reads (COCO, YOLO, VisDrone),
for the tests of the readers and of the detector-statistics inputs."""

from __future__ import annotations

import json
from pathlib import Path

from PIL import Image


def coco_set(tmp_path: Path, annotations=None, images=None) -> Path:
    """gt.json: image 1 (640x480) with a person and a crowd car, image 2 with no box;
    ``annotations`` / ``images`` replace those."""
    doc = {
        "images": images or [{"id": 1, "file_name": "a.jpg", "width": 640, "height": 480},
                             {"id": 2, "file_name": "sub/b.jpg", "width": 800, "height": 600}],
        "annotations": annotations if annotations is not None else [
            {"id": 1, "image_id": 1, "category_id": 1, "bbox": [10, 20, 30, 40], "area": 1200,
             "iscrowd": 0},
            {"id": 2, "image_id": 1, "category_id": 3, "bbox": [0, 0, 100, 100],
             "area": 1e4, "iscrowd": 1}],
        "categories": [{"id": 1, "name": "person"}, {"id": 3, "name": "car"}]}
    p = tmp_path / "gt.json"
    p.write_text(json.dumps(doc, indent=1))
    return p


def yolo_set(tmp_path: Path) -> tuple[Path, Path]:
    """labels/ (a.txt: two normalised boxes) and sizes.txt (a 800x600; b 1000x500, no
    label file)."""
    labels = tmp_path / "labels"
    labels.mkdir()
    (labels / "a.txt").write_text("0 0.5 0.5 0.25 0.5\n\n1 0.1 0.2 0.1 0.1\n")
    sizes = tmp_path / "sizes.txt"
    sizes.write_text("a.jpg 800 600\nb.png,1000,500\n")  # b has no label file: no objects
    return labels, sizes


def visdrone_set(tmp_path: Path) -> Path:
    """A VisDrone split: 0001 with two ignored regions, a pedestrian, ignored people and a
    car; 0002 empty; their images for the sizes."""
    split = tmp_path / "VisDrone2019-DET-val"
    (split / "annotations").mkdir(parents=True)
    (split / "images").mkdir()
    (split / "annotations" / "0001.txt").write_text(
        "684,8,273,116,0,0,0,0\n"  # ignored region
        "406,119,265,70,0,0,0,0\n"
        "10,20,30,40,1,1,0,0\n"  # pedestrian
        "50,60,10,20,0,2,0,1\n"  # people, score 0: ignored in evaluation
        "70,80,15,25,1,4,1,0,\n")  # car, trailing comma
    (split / "annotations" / "0002.txt").write_text("")
    Image.new("RGB", (1360, 765)).save(split / "images" / "0001.jpg")
    Image.new("RGB", (960, 540)).save(split / "images" / "0002.jpg")
    return split
