"""Reading COCO, YOLO and VisDrone test sets: the common structure and the errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from pdcov.detection.annotations import detect_format, read_detections, read_truth
from pdcov.errors import ConfigError, InputFileError
from tests.support.labelled_sets import coco_set, visdrone_set, yolo_set


def test_coco_truth_and_detections(tmp_path):
    truth = read_truth(coco_set(tmp_path))
    assert truth.format == "coco" and truth.classes == ("person", "car")
    a = truth.images["1"]
    assert (a.width_px, a.height_px) == (640, 480)
    assert a.boxes.labels == ("person", "car")
    assert a.boxes.ignore.tolist() == [False, True]  # crowd
    np.testing.assert_array_equal(a.boxes.xywh[0], [10, 20, 30, 40])
    assert len(truth.images["2"].boxes) == 0  # an image without boxes
    dt = tmp_path / "dt.json"
    dt.write_text(json.dumps([
        {"image_id": 1, "category_id": 3, "bbox": [1, 2, 3, 4], "score": 0.75},
        {"image_id": "b", "category_id": 1, "bbox": [5, 6, 7, 8], "score": 0.5}]))
    dets = read_detections(dt, truth)
    assert dets["1"].labels == ("car",) and dets["1"].scores.tolist() == [0.75]
    assert dets["2"].xywh.tolist() == [[5, 6, 7, 8]]  # named by the file stem, as Ultralytics


@pytest.mark.parametrize("ann, message", [
    ({"id": 1, "image_id": 1, "category_id": 1}, r"gt.json: annotations\[0\]: missing 'bbox'"),
    ({"id": 1, "image_id": 9, "category_id": 1, "bbox": [0, 0, 1, 1]},
     r"annotations\[0\]: image_id 9 is not in 'images'"),
    ({"id": 1, "image_id": 1, "category_id": 7, "bbox": [0, 0, 1, 1]},
     r"annotations\[0\]: class 7 is not a class of"),
    ({"id": 1, "image_id": 1, "category_id": 1, "bbox": [0, 0, "1", 1]},
     r"annotations\[0\]: 'bbox' must be 4 finite numbers"),
])
def test_coco_malformed_records_are_named(tmp_path, ann, message):
    with pytest.raises(InputFileError, match=message):
        read_truth(coco_set(tmp_path, annotations=[ann]))


def test_coco_syntax_error_names_the_line(tmp_path):
    p = tmp_path / "gt.json"
    p.write_text('{"images": [],\n "annotations": [,]}')
    with pytest.raises(InputFileError, match=r"gt.json:2: not valid JSON"):
        read_truth(p)


def test_coco_detection_errors(tmp_path):
    truth = read_truth(coco_set(tmp_path))
    dt = tmp_path / "dt.json"
    dt.write_text(json.dumps([{"image_id": 1, "category_id": 1, "bbox": [0, 0, 1, 1],
                               "score": 0.9},
                              {"image_id": 5, "category_id": 1, "bbox": [0, 0, 1, 1],
                               "score": 0.9}]))
    with pytest.raises(InputFileError, match=r"dt.json: \[1\]: image_id 5 is not in the ground"):
        read_detections(dt, truth)
    dt.write_text(json.dumps([{"image_id": 1, "category_id": 1, "bbox": [0, 0, 1, 1]}]))
    with pytest.raises(InputFileError, match=r"\[0\]: missing 'score'"):
        read_detections(dt, truth)


def test_unknown_classes_are_named(tmp_path):
    truth = read_truth(coco_set(tmp_path))
    truth.check_classes(("person",))
    with pytest.raises(ConfigError, match=r"'pedestrain' not among the classes .*person, car"):
        truth.check_classes(("person", "pedestrain"))


# -- YOLO -------------------------------------------------------------------------------------


def test_yolo_truth_is_unnormalised(tmp_path):
    labels, sizes = yolo_set(tmp_path)
    assert detect_format(labels) == "yolo"
    truth = read_truth(labels, sizes_path=sizes)
    a = truth.images["a"]
    np.testing.assert_allclose(a.boxes.xywh, [[300, 150, 200, 300], [40, 90, 80, 60]])
    assert a.boxes.labels == ("0", "1") and truth.classes == ("0", "1")
    assert len(truth.images["b"].boxes) == 0 and truth.images["b"].width_px == 1000


def test_yolo_names_and_detections(tmp_path):
    labels, sizes = yolo_set(tmp_path)
    names = tmp_path / "data.yaml"
    names.write_text("path: x\nnames:\n  0: person\n  1: car\n")
    truth = read_truth(labels, "yolo", sizes_path=sizes, names_path=names)
    assert truth.classes == ("person", "car")
    dets = tmp_path / "pred"
    dets.mkdir()
    (dets / "b.txt").write_text("1 0.5 0.5 0.1 0.2 0.875\n")
    d = read_detections(dets, truth)
    assert d["b"].labels == ("car",) and d["b"].scores.tolist() == [0.875]
    np.testing.assert_allclose(d["b"].xywh, [[450, 200, 100, 100]])
    (dets / "b.txt").write_text("1 0.5 0.5 0.1 0.2 0.875\n2 0.5 0.5 0.1 0.2 0.5\n")
    with pytest.raises(InputFileError, match=r"pred/b.txt:2: class 2 is not a class of"):
        read_detections(dets, truth)
    (dets / "c.txt").write_text("")
    (dets / "b.txt").unlink()
    with pytest.raises(InputFileError, match=r"c.txt: image 'c' is not in the ground truth"):
        read_detections(dets, truth)


def test_yolo_names_one_a_line(tmp_path):
    labels, sizes = yolo_set(tmp_path)
    names = tmp_path / "classes.txt"
    names.write_text("pedestrian\npeople\n")
    truth = read_truth(labels, "yolo", sizes_path=sizes, names_path=names)
    assert truth.images["a"].boxes.labels == ("pedestrian", "people")


@pytest.mark.parametrize("line, message", [
    ("0 0.5 0.5 0.2", r"a.txt:2: expected 'class cx cy w h', got 4 fields"),
    ("0 0.5 0.5 0.2 zero", r"a.txt:2: expected numbers"),
    ("0.5 0.5 0.5 0.2 0.1", r"a.txt:2: class must be an integer >= 0, got 0.5"),
    ("0 nan 0.5 0.2 0.1", r"a.txt:2: non-finite number"),
    # pixel coordinates, not normalised (issue 10)
    ("0 400 300 200 300", r"a.txt:2: cx 400, cy 300, w 200, h 300 outside \[0, 1\]: YOLO "
                          r"boxes are normalised"),
    ("0 0.5 0.5 1.5 0.2", r"a.txt:2: w 1.5 outside \[0, 1\]"),
    ("0 -0.2 0.5 0.1 0.2", r"a.txt:2: cx -0.2 outside"),
])
def test_yolo_malformed_lines_are_named(tmp_path, line, message):
    labels, sizes = yolo_set(tmp_path)
    (labels / "a.txt").write_text("0 0.5 0.5 0.25 0.5\n" + line + "\n")
    with pytest.raises(InputFileError, match=message):
        read_truth(labels, sizes_path=sizes)


def test_yolo_needs_sizes_and_an_image_per_label(tmp_path):
    labels, sizes = yolo_set(tmp_path)
    with pytest.raises(InputFileError, match="pass --images DIR or --sizes FILE"):
        read_truth(labels)
    (labels / "z.txt").write_text("0 0.5 0.5 0.1 0.1\n")
    with pytest.raises(InputFileError, match=r"z.txt: no image 'z' among the image sizes"):
        read_truth(labels, sizes_path=sizes)
    sizes.write_text("a.jpg 800\n")
    with pytest.raises(InputFileError, match=r"sizes.txt:1: expected 'image width height'"):
        read_truth(labels, sizes_path=sizes)


def test_yolo_sizes_from_images_in_the_ultralytics_layout(tmp_path):
    labels = tmp_path / "ds" / "labels" / "val"
    images = tmp_path / "ds" / "images" / "val"
    labels.mkdir(parents=True)
    images.mkdir(parents=True)
    Image.new("RGB", (320, 240)).save(images / "a.png")
    Image.new("RGB", (64, 48)).save(images / "b.jpg")
    (labels / "a.txt").write_text("0 0.5 0.5 0.5 0.5\n")
    truth = read_truth(labels)
    assert set(truth.images) == {"a", "b"}
    assert truth.images["b"].width_px == 64
    np.testing.assert_allclose(truth.images["a"].boxes.xywh, [[80, 60, 160, 120]])


# -- VisDrone ---------------------------------------------------------------------------------


def test_visdrone_truth(tmp_path):
    split = visdrone_set(tmp_path)
    assert detect_format(split) == "visdrone"
    truth = read_truth(split)
    a = truth.images["0001"]
    assert (a.width_px, a.height_px) == (1360, 765)
    assert a.boxes.labels == ("pedestrian", "people", "car")
    assert a.boxes.ignore.tolist() == [False, True, False]
    assert a.ignore_regions_xywh.tolist() == [[684, 8, 273, 116], [406, 119, 265, 70]]
    assert "ignored regions" not in truth.classes and "pedestrian" in truth.classes
    assert len(truth.images["0002"].boxes) == 0


def test_visdrone_detections_and_errors(tmp_path):
    split = visdrone_set(tmp_path)
    truth = read_truth(split)
    dets = tmp_path / "det"
    dets.mkdir()
    (dets / "0001.txt").write_text("10,20,30,40,0.9,1,-1,-1\n1,2,3,4,0.3,2\n")
    d = read_detections(dets, truth)
    assert d["0001"].labels == ("pedestrian", "people")
    assert d["0001"].scores.tolist() == [0.9, 0.3]
    (dets / "0001.txt").write_text("10,20,30,40,0.9,12,-1,-1\n")
    with pytest.raises(InputFileError, match=r"0001.txt:1: class 12 is not a class of"):
        read_detections(dets, truth)
    (split / "annotations" / "0002.txt").write_text("1,2,3,4,1,1,0\n")
    with pytest.raises(InputFileError, match=r"0002.txt:1: expected 'x,y,w,h,score,category"):
        read_truth(split)


def test_visdrone_sizes_unknown_without_images(tmp_path):
    split = visdrone_set(tmp_path)
    for p in (split / "images").iterdir():
        p.unlink()
    (split / "images").rmdir()
    truth = read_truth(split / "annotations")
    assert truth.images["0001"].width_px is None
    with pytest.raises(InputFileError, match="size of image '0001' unknown"):
        truth.check_sizes()


def test_format_errors(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_truth(tmp_path / "missing.json")
    (tmp_path / "x.csv").write_text("1,2")
    with pytest.raises(InputFileError, match="expected a COCO .json file or a directory"):
        read_truth(tmp_path / "x.csv")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError, match="pass --format"):
        read_truth(tmp_path / "empty")
