"""Matching detections to truth (detection/matching.py): by hand (IoU, greedy by confidence,
duplicates, crowds, ignored regions, classes, sizes, settings) and against pycocotools'
COCOeval on random overlapping sets (tests/unit/test_detector_stats.py: what is fitted
from the matches)."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from pdcov.detection.annotations import Boxes, read_detections, read_truth
from pdcov.detection.matching import (
    DetectionStatus,
    MatchSettings,
    TruthStatus,
    iou_matrix,
    match_image,
    match_images,
)
from pdcov.detection.statistics import count_in_bins
from pdcov.detection.truth_set import ImageTruth
from pdcov.errors import ConfigError
from tests.support.detection_boxes import S, dets_of, truth_image
from tests.support.synthetic_detections import EDGES, synthetic_set, write_coco


def test_iou_matrix_by_hand():
    d = np.array([[0.0, 0.0, 10.0, 10.0]])
    t = np.array([[5.0, 0.0, 10.0, 10.0], [0.0, 0.0, 20.0, 20.0]])
    iou = iou_matrix(d, t, np.array([False, True]))
    assert iou[0, 0] == pytest.approx(50 / 150)
    assert iou[0, 1] == pytest.approx(1.0)  # crowd: intersection over the detection's area


def test_greedy_highest_confidence_takes_its_best_iou():
    # det 1 (0.9) overlaps A with IoU 0.6 and B with 0.7 -> takes B; det 2 (0.8) then finds
    # B taken and A below the threshold -> a false alarm, although A+det2... is not a pair.
    gt = [(0, 0, 10, 10), (3, 0, 10, 10)]
    det1 = (2.0, 0, 10, 10)  # IoU with A 8/12 = 0.667, with B 9/11 = 0.818
    det2 = (4.0, 0, 10, 10)  # IoU with A 6/14 = 0.43, with B 0.818
    m = match_image(truth_image(gt), dets_of([det1, det2], [0.9, 0.8]), S)
    assert m.truth_status.tolist() == [TruthStatus.MISSED, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.TRUE, DetectionStatus.FALSE]


def test_duplicate_detections_one_true_rest_false():
    m = match_image(truth_image([(10, 10, 20, 20)]),
                    dets_of([(10, 10, 20, 20), (11, 10, 20, 20), (10, 11, 20, 20)],
                          [0.6, 0.9, 0.7]), S)
    assert m.truth_status.tolist() == [TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.FALSE, DetectionStatus.TRUE,
                                           DetectionStatus.FALSE]


def test_image_without_boxes_and_without_truth():
    empty = match_image(truth_image([]), dets_of([], []), S)
    assert empty.truth_status.size == 0 and empty.detection_status.size == 0
    m = match_image(truth_image([]), dets_of([(0, 0, 5, 5), (50, 50, 8, 8)], [0.9, 0.2]), S)
    assert m.detection_status.tolist() == [DetectionStatus.FALSE,
                                           DetectionStatus.BELOW_THRESHOLD]


def test_zero_and_negative_sizes_are_not_counted():
    m = match_image(truth_image([(0, 0, 0, 10), (0, 0, 10, -3), (20, 20, 10, 10)]),
                    dets_of([(0, 0, 0, 10), (20, 20, 10, 10), (20, 20, -1, -1)],
                          [0.9, 0.9, 0.9]), S)
    assert m.truth_status.tolist() == [TruthStatus.DEGENERATE, TruthStatus.DEGENERATE,
                                       TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.DEGENERATE, DetectionStatus.TRUE,
                                           DetectionStatus.DEGENERATE]


def test_other_classes_are_left_out():
    s = MatchSettings(0.5, 0.5, None, ("pedestrian", "people"))
    m = match_image(truth_image([(0, 0, 10, 10), (20, 0, 10, 10), (40, 0, 10, 10)],
                           ["pedestrian", "car", "people"]),
                    dets_of([(0, 0, 10, 10), (20, 0, 10, 10), (40, 0, 10, 10)], [0.9] * 3,
                          ["people", "car", "people"]), s)
    # matched within each class (COCO), then merged: a 'people' box never detects a
    # 'pedestrian', even when both are target classes
    assert m.truth_status.tolist() == [TruthStatus.MISSED, TruthStatus.OTHER_CLASS,
                                       TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.FALSE, DetectionStatus.OTHER_CLASS,
                                           DetectionStatus.TRUE]


def test_max_detections_keeps_the_highest_scores_per_class():
    s = MatchSettings(0.5, 0.5, None, None, max_detections=2)
    boxes = [(0, 0, 10, 10), (20, 0, 10, 10), (40, 0, 10, 10), (60, 0, 10, 10)]
    m = match_image(truth_image(boxes, ["a", "a", "a", "b"]),
                    dets_of(boxes, [0.6, 0.9, 0.8, 0.7], ["a", "a", "a", "b"]), s)
    # class a: the 0.9 and 0.8 detections count, the 0.6 one is over the cap; b has one
    assert m.detection_status.tolist() == [DetectionStatus.OVER_MAX_DETECTIONS,
                                           DetectionStatus.TRUE, DetectionStatus.TRUE,
                                           DetectionStatus.TRUE]
    assert m.truth_status.tolist() == [TruthStatus.MISSED] + [TruthStatus.DETECTED] * 3
    assert MatchSettings().max_detections == 100
    with pytest.raises(ConfigError, match="--max-detections"):
        MatchSettings(max_detections=0)


def test_crowd_truth_absorbs_detections_without_being_counted():
    m = match_image(truth_image([(0, 0, 50, 50), (60, 60, 10, 10)], ignore=[True, False]),
                    dets_of([(5, 5, 10, 10), (20, 20, 10, 10), (60, 60, 10, 10)],
                          [0.9, 0.8, 0.7]), S)
    assert m.truth_status.tolist() == [TruthStatus.IGNORED, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.ON_IGNORED_TRUTH] * 2 + [
        DetectionStatus.TRUE]


def test_real_truth_beats_crowd():
    # a detection on both a crowd box and a real object is the object's
    m = match_image(truth_image([(0, 0, 50, 50), (10, 10, 10, 10)], ignore=[True, False]),
                    dets_of([(10, 10, 10, 10)], [0.9]), S)
    assert m.truth_status.tolist() == [TruthStatus.IGNORED, TruthStatus.DETECTED]


def test_ignored_regions_drop_boxes_at_least_half_inside():
    # two regions that overlap: the union counts, as the VisDrone toolkit's mask does
    regions = [(0, 0, 30, 20), (20, 0, 30, 20)]
    gt = [(40, 0, 20, 10), (45, 0, 10, 10), (80, 80, 10, 10)]  # 50 % in, 50 % in, out
    m = match_image(truth_image(gt, regions=regions),
                    dets_of([(40, 0, 20, 10), (48, 0, 10, 10), (80, 80, 10, 10)], [0.9] * 3), S)
    assert m.truth_status.tolist() == [TruthStatus.IN_IGNORED_REGION,
                                       TruthStatus.IN_IGNORED_REGION, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.IN_IGNORED_REGION,
                                           DetectionStatus.FALSE, DetectionStatus.TRUE]


def test_iou_threshold_one_matches_identical_boxes():
    s = MatchSettings(0.5, 1.0, None, None)
    m = match_image(truth_image([(1.5, 2.5, 7.25, 3.5)]), dets_of([(1.5, 2.5, 7.25, 3.5)], [0.9]),
                    s)
    assert m.truth_status.tolist() == [TruthStatus.DETECTED]


def test_sizes_are_scaled_to_the_detector_input():
    image = ImageTruth("a", 1920, 1080, Boxes.from_rows([(0, 0, 40, 90)], ["p"]))
    m = match_images([(image, dets_of([(0, 0, 40, 90)], [0.9], ["p"]))],
                     MatchSettings(0.5, 0.5, 640, None))
    assert m.truth_size_px[0] == pytest.approx(60 / 3)  # sqrt(40*90) * 640/1920
    assert m.detection_size_px[0] == pytest.approx(20)
    assert m.status_counts == {"detection_true": 1, "truth_detected": 1}


def test_settings_are_checked():
    with pytest.raises(ConfigError, match="--iou"):
        MatchSettings(0.5, 0.0)
    with pytest.raises(ConfigError, match="--conf"):
        MatchSettings(1.5, 0.5)


def _cocoeval(gt_path: Path, results: list[dict], area_ranges: list[list[float]]):
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    with contextlib.redirect_stdout(io.StringIO()):
        gt = COCO(str(gt_path))
        dt = gt.loadRes(results) if results else COCO()
        ev = COCOeval(gt, dt, "bbox")
        ev.params.catIds = [1]
        ev.params.iouThrs = np.array([0.5])
        ev.params.maxDets = [100000]
        ev.params.areaRng = area_ranges
        ev.params.areaRngLbl = [str(i) for i in range(len(area_ranges))]
        ev.evaluate()
    return gt, ev


def _random_overlapping_set(seed: int, n_images: int):
    rng = np.random.default_rng(seed)
    truth, dets = {}, {}
    for k in range(n_images):
        n = rng.integers(0, 9)
        xy = rng.uniform(0, 300, (n, 2))
        wh = rng.uniform(5, 80, (n, 2))
        gt = np.hstack([xy, wh])
        labels = list(rng.choice(["person", "car"], n, p=[0.8, 0.2]))
        crowd = list(rng.random(n) < 0.1)
        rows, scores, dlabels = [], [], []
        for g, lab in zip(gt, labels, strict=True):
            for _ in range(rng.integers(0, 3)):  # 0, 1 or 2 (duplicate) detections
                rows.append(g + rng.normal(0, 0.15, 4) * np.r_[g[2:], g[2:]] * 0.5)
                scores.append(rng.random())
                dlabels.append(lab if rng.random() < 0.9 else "car")
        for _ in range(rng.integers(0, 4)):  # background false alarms
            rows.append(np.r_[rng.uniform(0, 300, 2), rng.uniform(5, 80, 2)])
            scores.append(rng.random())
            dlabels.append("person")
        rows = [np.r_[r[:2], np.clip(r[2:], 1, None)] for r in rows]
        image_id = f"im{k}"
        truth[image_id] = ImageTruth(image_id, 400, 400,
                                     Boxes.from_rows(gt.tolist(), labels, ignore=crowd))
        dets[image_id] = Boxes.from_rows([list(r) for r in rows], dlabels, scores)
    return truth, dets


def test_matching_agrees_with_cocoeval_on_overlapping_boxes_and_crowds(tmp_path):
    truth, dets = _random_overlapping_set(seed=7, n_images=150)
    write_coco(truth, dets, tmp_path / "gt.json", tmp_path / "dt.json")
    conf = 0.3
    results = [r for r in json.loads((tmp_path / "dt.json").read_text()) if r["score"] >= conf]
    gt, ev = _cocoeval(tmp_path / "gt.json", results, [[0, 1e10]])
    # ours, from the same files
    t = read_truth(tmp_path / "gt.json")
    d = read_detections(tmp_path / "dt.json", t)
    settings = MatchSettings(conf, 0.5, None, ("person",))
    n_checked = {"tp": 0, "fp": 0, "ign": 0, "crowd": 0}
    for e in ev.evalImgs:
        if e is None:
            continue
        image_id = str(e["image_id"])
        m = match_image(t.images[image_id], d.get(image_id, Boxes.from_rows([], [])), settings)
        # COCO numbers annotations in file order; ours index the boxes in file order
        gt_ids = sorted(gt.getAnnIds(imgIds=[e["image_id"]]))
        ours_gt = {gt_ids[i] for i, s in enumerate(m.truth_status) if s == TruthStatus.DETECTED}
        theirs_gt = {g for g, hit, ig in zip(e["gtIds"], e["gtMatches"][0], e["gtIgnore"],
                                             strict=True) if hit and not ig}
        assert ours_gt == theirs_gt, image_id
        ours = Counter_of(m.detection_status)
        tp = int(np.sum((e["dtMatches"][0] > 0) & ~e["dtIgnore"][0].astype(bool)))
        fp = int(np.sum((e["dtMatches"][0] == 0) & ~e["dtIgnore"][0].astype(bool)))
        ign = int(np.sum(e["dtIgnore"][0].astype(bool)))
        assert (ours[DetectionStatus.TRUE], ours[DetectionStatus.FALSE],
                ours[DetectionStatus.ON_IGNORED_TRUTH]) == (tp, fp, ign), image_id
        n_checked["tp"] += tp
        n_checked["fp"] += fp
        n_checked["ign"] += ign
        n_checked["crowd"] += int(np.sum(e["gtIgnore"]))
    assert min(n_checked.values()) >= 10, n_checked  # every case was exercised


def test_multi_class_matching_and_max_dets_agree_with_cocoeval(tmp_path):
    """Two target classes matched separately and merged, with COCO's per-image, per-class
    detection cap (maxDets 3, so that many images exceed it)."""
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    truth, dets = _random_overlapping_set(seed=11, n_images=150)
    write_coco(truth, dets, tmp_path / "gt.json", tmp_path / "dt.json")
    conf, cap = 0.3, 3
    results = [r for r in json.loads((tmp_path / "dt.json").read_text()) if r["score"] >= conf]
    with contextlib.redirect_stdout(io.StringIO()):
        gt = COCO(str(tmp_path / "gt.json"))
        ev = COCOeval(gt, gt.loadRes(results), "bbox")
        ev.params.catIds = [1, 2]
        ev.params.iouThrs = np.array([0.5])
        ev.params.maxDets = [cap]
        ev.params.areaRng = [[0, 1e10]]
        ev.params.areaRngLbl = ["all"]
        ev.evaluate()
    t = read_truth(tmp_path / "gt.json")
    d = read_detections(tmp_path / "dt.json", t)
    settings = MatchSettings(conf, 0.5, None, ("person", "car"), max_detections=cap)
    ours_total = {"tp": 0, "fp": 0, "ign": 0, "capped": 0, "detected": 0}
    theirs_total = dict.fromkeys(ours_total, 0)
    for image_id, image in t.images.items():
        m = match_image(image, d.get(image_id, Boxes.from_rows([], [])), settings)
        gt_ids = sorted(gt.getAnnIds(imgIds=[int(image_id)]))
        ours_gt = {gt_ids[i] for i, s in enumerate(m.truth_status) if s == TruthStatus.DETECTED}
        theirs_gt = set()
        n_results = sum(1 for r in results if r["image_id"] == int(image_id))
        n_kept = 0
        for e in ev.evalImgs:
            if e is None or e["image_id"] != int(image_id):
                continue
            theirs_gt |= {g for g, hit, ig in zip(e["gtIds"], e["gtMatches"][0], e["gtIgnore"],
                                                  strict=True) if hit and not ig}
            ignored = e["dtIgnore"][0].astype(bool)
            theirs_total["tp"] += int(np.sum((e["dtMatches"][0] > 0) & ~ignored))
            theirs_total["fp"] += int(np.sum((e["dtMatches"][0] == 0) & ~ignored))
            theirs_total["ign"] += int(np.sum(ignored))
            n_kept += len(e["dtIds"])
        assert ours_gt == theirs_gt, image_id
        theirs_total["capped"] += n_results - n_kept
        theirs_total["detected"] += len(theirs_gt)
        ds = m.detection_status
        above = d[image_id].scores >= conf if image_id in d else np.zeros(0, bool)
        ours_total["tp"] += int(np.sum(ds == DetectionStatus.TRUE))
        ours_total["fp"] += int(np.sum(ds == DetectionStatus.FALSE))
        ours_total["ign"] += int(np.sum(ds == DetectionStatus.ON_IGNORED_TRUTH))
        ours_total["capped"] += int(np.sum((ds == DetectionStatus.OVER_MAX_DETECTIONS) & above))
        ours_total["detected"] += len(ours_gt)
    assert ours_total == theirs_total
    assert min(ours_total.values()) >= 10, ours_total  # every case was exercised


def Counter_of(status: np.ndarray) -> dict[int, int]:
    return {s: int(np.sum(status == s)) for s in DetectionStatus}


def test_recall_per_size_range_agrees_with_cocoeval(tmp_path):
    truth, dets = synthetic_set(seed=3, n_per_bin=80)
    write_coco(truth, dets, tmp_path / "gt.json", tmp_path / "dt.json")
    conf = 0.5
    results = [r for r in json.loads((tmp_path / "dt.json").read_text()) if r["score"] >= conf]
    edges_img = [2 * e for e in EDGES]  # image px (no rescaling): sizes are twice the input's
    ranges = [[lo ** 2, hi ** 2] for lo, hi in zip(edges_img, edges_img[1:], strict=False)]
    _, ev = _cocoeval(tmp_path / "gt.json", results, ranges)
    t = read_truth(tmp_path / "gt.json")
    d = read_detections(tmp_path / "dt.json", t)
    matches = match_images(((t.images[k], d.get(k, Boxes.from_rows([], []))) for k in t.images),
                           MatchSettings(conf, 0.5, None, ("person",)))
    c = count_in_bins(matches, tuple(edges_img))
    for a, rng in enumerate(ranges):
        found = [e for e in ev.evalImgs if e is not None and e["aRng"] == rng]
        n_true = sum(int(np.sum(~e["gtIgnore"].astype(bool))) for e in found)
        n_hit = sum(int(np.sum((e["gtMatches"][0] > 0) & ~e["gtIgnore"].astype(bool)))
                    for e in found)
        assert (c.n_true[a], c.n_detected[a]) == (n_true, n_hit)
        assert n_true == 80
