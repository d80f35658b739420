"""Detector-statistics inputs that used to be read wrongly without complaint: scores outside
[0, 1], thresholds out of range (YOLO labels in pixels: test_annotations); and the
Object-Detection-Metrics text format in both box variants."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from pdcov.core.detector import DetectorModel
from pdcov.detection.annotations import detect_format, read_detections, read_truth
from pdcov.errors import ConfigError, DetectorModelError, InputFileError
from tests.support.labelled_sets import coco_set, visdrone_set, yolo_set


def test_yolo_values_rounded_just_past_one_are_normalised(tmp_path):
    labels, sizes = yolo_set(tmp_path)
    (labels / "a.txt").write_text("0 0.5 0.5 1.0000004 0.5\n")  # printed with rounding
    assert read_truth(labels, sizes_path=sizes).images["a"].boxes.xywh[0, 2] == \
        pytest.approx(800, abs=1e-3)


def test_scores_outside_zero_one_are_refused_in_every_format(tmp_path):
    truth = read_truth(coco_set(tmp_path))
    dt = tmp_path / "dt.json"
    dt.write_text(json.dumps([{"image_id": 1, "category_id": 1, "bbox": [1, 2, 3, 4],
                               "score": 0.5},
                              {"image_id": 1, "category_id": 1, "bbox": [1, 2, 3, 4],
                               "score": 3.2}]))
    with pytest.raises(InputFileError, match=r"dt.json: \[1\]: detection score 3.2 outside "
                                             r"\[0, 1\]"):
        read_detections(dt, truth)
    labels, sizes = yolo_set(tmp_path)
    yolo_truth = read_truth(labels, sizes_path=sizes)
    pred = tmp_path / "pred"
    pred.mkdir()
    (pred / "a.txt").write_text("0 0.5 0.5 0.1 0.2 -0.4\n")
    with pytest.raises(InputFileError, match=r"pred/a.txt:1: detection score -0.4 outside"):
        read_detections(pred, yolo_truth)
    split = visdrone_set(tmp_path)
    vis_truth = read_truth(split)
    vis = tmp_path / "vis"
    vis.mkdir()
    (vis / "0001.txt").write_text("10,20,30,40,0.9,1\n10,20,30,40,87,1\n")
    with pytest.raises(InputFileError, match=r"vis/0001.txt:2: detection score 87 outside"):
        read_detections(vis, vis_truth)


@pytest.mark.parametrize("key, value", [("confidence_threshold", 1.5),
                                        ("confidence_threshold", -0.1),
                                        ("iou_threshold", 0.0), ("iou_threshold", 7)])
def test_model_thresholds_out_of_range_are_refused(tmp_path, key, value):
    doc = DetectorModel.illustrative().to_dict() | {key: value}
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(DetectorModelError, match=rf"m.yaml: {key}: expected a value in"):
        DetectorModel.from_yaml(path)


def _odm(root: Path, name: str, lines: dict[str, str]) -> Path:
    d = root / name
    d.mkdir()
    for stem, text in lines.items():
        (d / f"{stem}.txt").write_text(text)
    return d


def test_object_detection_metrics_format_both_box_variants(tmp_path):
    sizes = tmp_path / "sizes.txt"
    sizes.write_text("im1 640 480\nim2 640 480\n")
    gt_xywh = _odm(tmp_path, "gt_xywh", {"im1": "person 10 20 30 40\ncar 100 100 50 25\n",
                                         "im2": ""})
    gt_xyrb = _odm(tmp_path, "gt_xyrb", {"im1": "person 10 20 40 60\ncar 100 100 150 125\n",
                                         "im2": ""})
    dt_xywh = _odm(tmp_path, "dt_xywh", {"im1": "person 0.9 11 20 30 40\n"
                                                "car 0.4 300 300 10 10\n"})
    dt_xyrb = _odm(tmp_path, "dt_xyrb", {"im1": "person 0.9 11 20 41 60\n"
                                                "car 0.4 300 300 310 310\n"})
    assert detect_format(gt_xywh) == "odm"
    a = read_truth(gt_xywh, sizes_path=sizes)
    b = read_truth(gt_xyrb, "odm", sizes_path=sizes, box_format="xyrb")
    assert a.format == "odm" and a.classes == ("car", "person")
    assert a.images["im1"].boxes.labels == ("person", "car") and len(a.images["im2"].boxes) == 0
    np.testing.assert_array_equal(a.images["im1"].boxes.xywh, [[10, 20, 30, 40],
                                                               [100, 100, 50, 25]])
    np.testing.assert_array_equal(b.images["im1"].boxes.xywh, a.images["im1"].boxes.xywh)
    assert a.images["im1"].width_px == 640
    da = read_detections(dt_xywh, a)
    db = read_detections(dt_xyrb, b, box_format="xyrb")
    np.testing.assert_array_equal(da["im1"].xywh, [[11, 20, 30, 40], [300, 300, 10, 10]])
    np.testing.assert_array_equal(db["im1"].xywh, da["im1"].xywh)
    assert da["im1"].scores.tolist() == [0.9, 0.4] and da["im1"].labels == ("person", "car")


def test_object_detection_metrics_errors_name_file_and_line(tmp_path):
    gt = _odm(tmp_path, "gt", {"im1": "person 10 20 30 40\nperson 10 20 30\n"})
    with pytest.raises(InputFileError, match=r"gt/im1.txt:2: expected 'class left top width "
                                             r"height', got 4 fields"):
        read_truth(gt, "odm")
    gt = _odm(tmp_path, "gt2", {"im1": "person 10 20 30 40\n"})
    truth = read_truth(gt, "odm")
    dt = _odm(tmp_path, "dt", {"im1": "person 10 20 30 40\n"})
    with pytest.raises(InputFileError, match=r"dt/im1.txt:1: expected 'class confidence left "
                                             r"top right bottom', got 5 fields"):
        read_detections(dt, truth, box_format="xyrb")
    with pytest.raises(ConfigError, match="--box-format"):
        read_truth(gt, "odm", box_format="cxcywh")
