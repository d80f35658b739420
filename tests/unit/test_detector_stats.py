"""Detector statistics: matching (against pycocotools' COCOeval), bins, intervals, fits, tests,
on the synthetic labelled set of tests/synthetic_detections.py."""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import special, stats

from pdcov.core.detector import DetectorModel
from pdcov.detection.annotations import Boxes, ImageTruth, read_detections, read_truth
from pdcov.detection.matching import (
    DetectionStatus,
    MatchSettings,
    TruthStatus,
    iou_matrix,
    match_image,
    match_images,
)
from pdcov.detection.statistics import (
    ValidationReport,
    auto_bin_edges,
    count_in_bins,
    fit_binned,
    fit_confidence,
    fit_logistic,
    fit_logistic_curve,
    proportion_ci,
    validate,
)
from pdcov.errors import ConfigError, DetectorModelError
from tests.support.synthetic_detections import EDGES, INPUT, P_D, P_FA, synthetic_set, write_coco


@pytest.fixture(scope="module")
def fitted_synthetic():
    truth, dets = synthetic_set(seed=1, n_per_bin=600)
    settings = MatchSettings(0.5, 0.5, INPUT, ("person",))
    matches = match_images(((truth[k], dets[k]) for k in truth), settings)
    return matches, fit_binned(matches, EDGES, "wilson")


# -- matching ---------------------------------------------------------------------------------


def _image(gt, labels=None, ignore=None, regions=()):
    labels = labels or ["person"] * len(gt)
    return ImageTruth("a", 100, 100, Boxes.from_rows(gt, labels, ignore=ignore),
                      np.asarray(regions, float).reshape(-1, 4))


def _dets(rows, scores, labels=None):
    return Boxes.from_rows(rows, labels or ["person"] * len(rows), scores)


S = MatchSettings(0.5, 0.5, None, None)


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
    m = match_image(_image(gt), _dets([det1, det2], [0.9, 0.8]), S)
    assert m.truth_status.tolist() == [TruthStatus.MISSED, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.TRUE, DetectionStatus.FALSE]


def test_duplicate_detections_one_true_rest_false():
    m = match_image(_image([(10, 10, 20, 20)]),
                    _dets([(10, 10, 20, 20), (11, 10, 20, 20), (10, 11, 20, 20)],
                          [0.6, 0.9, 0.7]), S)
    assert m.truth_status.tolist() == [TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.FALSE, DetectionStatus.TRUE,
                                           DetectionStatus.FALSE]


def test_image_without_boxes_and_without_truth():
    empty = match_image(_image([]), _dets([], []), S)
    assert empty.truth_status.size == 0 and empty.detection_status.size == 0
    m = match_image(_image([]), _dets([(0, 0, 5, 5), (50, 50, 8, 8)], [0.9, 0.2]), S)
    assert m.detection_status.tolist() == [DetectionStatus.FALSE,
                                           DetectionStatus.BELOW_THRESHOLD]


def test_zero_and_negative_sizes_are_not_counted():
    m = match_image(_image([(0, 0, 0, 10), (0, 0, 10, -3), (20, 20, 10, 10)]),
                    _dets([(0, 0, 0, 10), (20, 20, 10, 10), (20, 20, -1, -1)],
                          [0.9, 0.9, 0.9]), S)
    assert m.truth_status.tolist() == [TruthStatus.DEGENERATE, TruthStatus.DEGENERATE,
                                       TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.DEGENERATE, DetectionStatus.TRUE,
                                           DetectionStatus.DEGENERATE]


def test_other_classes_are_left_out():
    s = MatchSettings(0.5, 0.5, None, ("pedestrian", "people"))
    m = match_image(_image([(0, 0, 10, 10), (20, 0, 10, 10), (40, 0, 10, 10)],
                           ["pedestrian", "car", "people"]),
                    _dets([(0, 0, 10, 10), (20, 0, 10, 10), (40, 0, 10, 10)], [0.9] * 3,
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
    m = match_image(_image(boxes, ["a", "a", "a", "b"]),
                    _dets(boxes, [0.6, 0.9, 0.8, 0.7], ["a", "a", "a", "b"]), s)
    # class a: the 0.9 and 0.8 detections count, the 0.6 one is over the cap; b has one
    assert m.detection_status.tolist() == [DetectionStatus.OVER_MAX_DETECTIONS,
                                           DetectionStatus.TRUE, DetectionStatus.TRUE,
                                           DetectionStatus.TRUE]
    assert m.truth_status.tolist() == [TruthStatus.MISSED] + [TruthStatus.DETECTED] * 3
    assert MatchSettings().max_detections == 100
    with pytest.raises(ConfigError, match="--max-detections"):
        MatchSettings(max_detections=0)


def test_crowd_truth_absorbs_detections_without_being_counted():
    m = match_image(_image([(0, 0, 50, 50), (60, 60, 10, 10)], ignore=[True, False]),
                    _dets([(5, 5, 10, 10), (20, 20, 10, 10), (60, 60, 10, 10)],
                          [0.9, 0.8, 0.7]), S)
    assert m.truth_status.tolist() == [TruthStatus.IGNORED, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.ON_IGNORED_TRUTH] * 2 + [
        DetectionStatus.TRUE]


def test_real_truth_beats_crowd():
    # a detection on both a crowd box and a real object is the object's
    m = match_image(_image([(0, 0, 50, 50), (10, 10, 10, 10)], ignore=[True, False]),
                    _dets([(10, 10, 10, 10)], [0.9]), S)
    assert m.truth_status.tolist() == [TruthStatus.IGNORED, TruthStatus.DETECTED]


def test_ignored_regions_drop_boxes_at_least_half_inside():
    # two regions that overlap: the union counts, as the VisDrone toolkit's mask does
    regions = [(0, 0, 30, 20), (20, 0, 30, 20)]
    gt = [(40, 0, 20, 10), (45, 0, 10, 10), (80, 80, 10, 10)]  # 50 % in, 50 % in, out
    m = match_image(_image(gt, regions=regions),
                    _dets([(40, 0, 20, 10), (48, 0, 10, 10), (80, 80, 10, 10)], [0.9] * 3), S)
    assert m.truth_status.tolist() == [TruthStatus.IN_IGNORED_REGION,
                                       TruthStatus.IN_IGNORED_REGION, TruthStatus.DETECTED]
    assert m.detection_status.tolist() == [DetectionStatus.IN_IGNORED_REGION,
                                           DetectionStatus.FALSE, DetectionStatus.TRUE]


def test_iou_threshold_one_matches_identical_boxes():
    s = MatchSettings(0.5, 1.0, None, None)
    m = match_image(_image([(1.5, 2.5, 7.25, 3.5)]), _dets([(1.5, 2.5, 7.25, 3.5)], [0.9]), s)
    assert m.truth_status.tolist() == [TruthStatus.DETECTED]


def test_sizes_are_scaled_to_the_detector_input():
    image = ImageTruth("a", 1920, 1080, Boxes.from_rows([(0, 0, 40, 90)], ["p"]))
    m = match_images([(image, _dets([(0, 0, 40, 90)], [0.9], ["p"]))],
                     MatchSettings(0.5, 0.5, 640, None))
    assert m.truth_size_px[0] == pytest.approx(60 / 3)  # sqrt(40*90) * 640/1920
    assert m.detection_size_px[0] == pytest.approx(20)
    assert m.status_counts == {"detection_true": 1, "truth_detected": 1}


def test_settings_are_checked():
    with pytest.raises(ConfigError, match="--iou"):
        MatchSettings(0.5, 0.0)
    with pytest.raises(ConfigError, match="--conf"):
        MatchSettings(1.5, 0.5)


# -- agreement with pycocotools ---------------------------------------------------------------


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


# -- bins, intervals, fits --------------------------------------------------------------------


def test_fit_recovers_known_rates_within_intervals(fitted_synthetic):
    matches, model = fitted_synthetic
    lo_d, hi_d = np.array(model.extra["p_detect_ci95"]).T
    lo_f, hi_f = np.array(model.extra["p_false_alarm_ci95"]).T
    misses = int(np.sum((P_D < lo_d) | (P_D > hi_d)) + np.sum((P_FA < lo_f) | (P_FA > hi_f)))
    # 14 intervals of 95 %: P(more than 3 miss) < 0.5 %; a size or matching error misses all
    assert misses <= 3
    n = np.array(model.counts.n_true)
    assert np.all(n == 600)
    se = np.sqrt(np.array(P_D) * (1 - np.array(P_D)) / n)
    assert np.all(np.abs(np.array(model.p_detect) - P_D) < 4 * se)
    assert model.extra["fit"]["truth_outside_bins"] == 0
    assert model.input_size_px == INPUT and model.confidence_threshold == 0.5


def test_model_round_trips_through_yaml(fitted_synthetic):
    _, model = fitted_synthetic
    again = DetectorModel.from_dict(yaml_round_trip(model.to_dict()))
    assert again.p_detect == model.p_detect
    assert again.extra["n_true_positives"] == model.extra["n_true_positives"]
    pd, pfa = again.lookup(np.array([10.0, 100.0, 5.0]))
    assert pd[0] == model.p_detect[0] and pd[1] == 0 and pd[2] == 0 and pfa[1] == 0


def yaml_round_trip(doc):
    import yaml
    return yaml.safe_load(yaml.safe_dump(doc))


def test_empty_bins_are_explicit_without_warnings(fitted_synthetic):
    matches, _ = fitted_synthetic
    edges = (1.0, 2.0) + EDGES + (200.0,)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = fit_binned(matches, edges, "clopper-pearson")
    assert model.counts.n_true[0] == 0 and model.counts.n_detections[-1] == 0
    assert model.p_detect[0] == 0 and model.p_false_alarm[-1] == 0
    assert model.p_detect[1] == pytest.approx(model.counts.n_detected[1] / 600, abs=1e-6)
    assert model.extra["p_detect_ci95"][0] == [0.0, 1.0]
    assert model.extra["p_false_alarm_ci95"][-1] == [0.0, 1.0]


def test_confidence_histograms_by_hand():
    """One image: 3 people found at 0.9, 0.8, 0.6 and a false box at 0.55, a box below the
    threshold. Two confidence bins [0.5, 0.75), [0.75, 1]; add-one smoothing."""
    gt = [(0, 0, 20, 20), (30, 0, 20, 20), (60, 0, 20, 20)]
    dets = _dets(gt + [(0, 50, 20, 20), (30, 50, 20, 20)], [0.9, 0.8, 0.6, 0.55, 0.3])
    matches = match_images([(_image(gt), dets)], S)
    np.testing.assert_array_equal(matches.detection_confidence, [0.9, 0.8, 0.6, 0.55])
    conf = fit_confidence(matches, (10.0, 30.0, 100.0), n_bins=2)
    assert conf.edges == (0.5, 0.75, 1.0)
    assert conf.extra["n_true_positives"] == [[1, 2], [0, 0]]
    assert conf.extra["n_false_positives"] == [[1, 0], [0, 0]]
    # (n_k + 1) / ((n + K) w): true (1 + 1) / 5 / 0.25 = 1.6, (2 + 1) / 5 / 0.25 = 2.4.
    np.testing.assert_allclose(conf.tp_density, [[1.6, 2.4], [2.0, 2.0]], rtol=1e-5)
    np.testing.assert_allclose(conf.fp_density, [[8 / 3, 4 / 3], [2.0, 2.0]], rtol=1e-5)
    model = replace(DetectorModel((10.0, 30.0, 100.0), (0.5, 0.5), (0.1, 0.1)),
                    confidence=conf)
    np.testing.assert_allclose(model.confidence_log_lr([20.0, 20.0, 50.0], [0.9, 0.6, 0.9]),
                               [np.log(0.6 / (1 / 3)), np.log(0.4 / (2 / 3)), 0.0],
                               rtol=1e-5)
    assert fit_confidence(match_images([(_image(gt), dets)], MatchSettings(1.0, 0.5, None)),
                          (10.0, 30.0)) is None  # threshold 1: nothing to bin
    with pytest.raises(ConfigError, match="--confidence-bins: expected at least 1"):
        fit_confidence(matches, (10.0, 30.0), n_bins=0)


def test_proportion_intervals():
    lo, hi = proportion_ci(np.array([0, 5]), np.array([10, 10]), "clopper-pearson")
    assert lo[0] == 0 and hi[0] == pytest.approx(1 - 0.025 ** (1 / 10))  # exact: k = 0
    wl, wh = proportion_ci(np.array([5]), np.array([10]), "wilson")
    z = stats.norm.ppf(0.975)
    half = z * math.sqrt(0.25 / 10 + z * z / 400) / (1 + z * z / 10)
    assert (wl[0], wh[0]) == pytest.approx((0.5 - half, 0.5 + half))
    with pytest.raises(ConfigError, match="--interval"):
        proportion_ci(np.array([1]), np.array([2]), "bayes")


@pytest.mark.parametrize("rule", ["quantile", "log"])
def test_auto_bins_cover_every_size(rule):
    sizes = np.exp(np.random.default_rng(0).normal(3, 0.6, 5000))
    edges = auto_bin_edges(sizes, rule, 20)
    assert edges[0] <= sizes.min() and edges[-1] > sizes.max()
    assert np.all(np.diff(edges) > 0) and len(edges) == 21
    counts = np.histogram(sizes, edges)[0]
    if rule == "quantile":
        assert counts.min() > 200 and counts.max() < 300  # about 250 each
    else:
        ratios = np.array(edges[2:-1]) / np.array(edges[1:-2])  # inner edges: rounded to 0.1
        expected = (sizes.max() / sizes.min()) ** (1 / 20)
        assert np.all(np.abs(ratios - expected) < 0.03)


def test_auto_bins_merge_tied_edges():
    edges = auto_bin_edges(np.array([10.0] * 50 + [20.0] * 50), "quantile", 10)
    assert edges == (10.0, 20.0, 20.1)


def test_logistic_curve_recovers_coefficients():
    rng = np.random.default_rng(5)
    s = np.exp(rng.uniform(np.log(4), np.log(200), 4000))
    a, b = -4.0, 1.5
    hit = rng.random(s.size) < special.expit(a + b * np.log(s))
    curve = fit_logistic_curve(s, hit, degree=1)
    grid = np.geomspace(5, 150, 30)
    p, lo, hi = curve.evaluate(grid)
    truth = special.expit(a + b * np.log(grid))
    assert np.all(lo <= p) and np.all(p <= hi)
    assert np.mean((truth >= lo) & (truth <= hi)) > 0.9
    assert np.max(np.abs(p - truth)) < 0.05


def test_logistic_model_has_the_engine_format(fitted_synthetic):
    matches, _ = fitted_synthetic
    model = fit_logistic(matches, EDGES, n_fine=40, degree=2)
    assert model.n_bins == 40 and model.extra["model"] == "logistic"
    assert model.bin_edges_px[0] == pytest.approx(EDGES[0])
    assert sum(model.counts.n_true) == len(matches.truth_size_px)
    # the quadratic follows the hump of P_D: highest in the middle, lower at both ends
    p = np.array(model.p_detect)
    assert p.argmax() not in (0, len(p) - 1) and p[0] < 0.35 and p.max() > 0.75
    DetectorModel.from_dict(yaml_round_trip(model.to_dict()))


def test_logistic_refuses_separated_data():
    s = np.array([5.0, 6, 7, 8, 20, 21, 22, 23])
    with pytest.raises(DetectorModelError, match="binned"):
        fit_logistic_curve(s, s > 10)


# -- validation -------------------------------------------------------------------------------


def _matches(seed, p_d=P_D):
    truth, dets = synthetic_set(seed=seed, n_per_bin=300, p_d=p_d)
    return match_images(((truth[k], dets[k]) for k in truth),
                        MatchSettings(0.5, 0.5, INPUT, ("person",)))


def test_validation_passes_same_process_and_fails_a_different_one(fitted_synthetic):
    _, model = fitted_synthetic
    same = validate(model, _matches(11))
    failed, tested = same.n_failed("detect")
    assert tested == 7 and failed <= 2
    assert same.n_failed("precision")[0] <= 2
    worse = validate(model, _matches(12, p_d=tuple(p - 0.15 for p in P_D)), test="chi2")
    assert worse.n_failed("detect")[0] >= 6
    assert worse.detect[3].observed < worse.detect[3].expected


def test_validation_expected_counts_and_report_round_trip(fitted_synthetic):
    _, model = fitted_synthetic
    matches = _matches(13)
    report = validate(model, matches)
    c = count_in_bins(matches, model.bin_edges_px)
    for i, t in enumerate(report.detect):
        assert t.n == c.n_true[i]
        assert t.expected == pytest.approx(c.n_true[i] * model.p_detect[i])
        assert t.p_value == pytest.approx(
            stats.binomtest(t.observed, t.n, model.p_detect[i]).pvalue)
    again = ValidationReport.from_dict(json.loads(json.dumps(report.to_dict())), "r.json")
    assert again.detect[2].p_value == pytest.approx(report.detect[2].p_value)
    assert again.bin_edges_px == report.bin_edges_px


def test_validation_of_empty_bins_has_no_p_value(fitted_synthetic):
    _, model = fitted_synthetic
    report = validate(model, _matches(14), edges=(1.0, 2.0) + EDGES[1:])
    assert report.detect[0].p_value is None
    assert report.n_failed("detect")[1] == len(EDGES) - 1


def test_fisher_test_compares_with_the_fit_counts(fitted_synthetic):
    _, model = fitted_synthetic
    same = validate(model, _matches(15), test="fisher")
    c = model.counts
    k, n = same.detect[0].observed, same.detect[0].n
    assert same.detect[0].p_value == pytest.approx(stats.fisher_exact(
        [[k, n - k], [c.n_detected[0], c.n_true[0] - c.n_detected[0]]]).pvalue)
    assert same.n_failed("detect")[0] <= 2
    worse = validate(model, _matches(16, p_d=tuple(p - 0.15 for p in P_D)), test="fisher")
    assert worse.n_failed("detect")[0] >= 5
    with pytest.raises(ConfigError, match="its own bins"):
        validate(model, _matches(15), edges=EDGES[:4], test="fisher")


def test_validation_compares_false_boxes_per_mpx_with_the_models_rate(fitted_synthetic):
    _, model = fitted_synthetic
    matches = _matches(17)
    report = validate(model, matches)
    c = count_in_bins(matches, model.bin_edges_px)
    area = matches.image_area_mpx
    assert area == pytest.approx(matches.n_images * 0.3072)  # 640 x 480 detector-input px
    for i, r in enumerate(report.fa_rate):
        k = int(c.n_detections[i] - c.n_true_positives[i])
        mu = model.fa_rate_per_mpx[i] * area
        assert (r.observed, r.expected) == (k, pytest.approx(mu))
        assert r.rate_per_mpx == pytest.approx(k / area)
        assert r.rate_ci95[0] < k / area < r.rate_ci95[1]
        tail = min(stats.poisson.cdf(k, mu), stats.poisson.sf(k - 1, mu))
        assert r.p_value == pytest.approx(min(1.0, 2 * tail))
    assert report.n_failed("fa_rate")[0] <= 2 and report.n_failed("fa_rate")[1] == 7
    # Twice as many false boxes per true one: the rate fails nearly everywhere.
    worse = validate(model, match_images(
        ((t, d) for t, d in _set_pairs(18, tuple(min(0.9, 2 * q) for q in P_FA))),
        MatchSettings(0.5, 0.5, INPUT, ("person",))))
    assert worse.n_failed("fa_rate")[0] >= 5
    assert all(w.observed > w.expected for w in worse.fa_rate)
    again = ValidationReport.from_dict(json.loads(json.dumps(report.to_dict())), "r.json")
    assert again.fa_rate[3].p_value == pytest.approx(report.fa_rate[3].p_value)
    assert again.fa_rate[3].rate_ci95 == pytest.approx(report.fa_rate[3].rate_ci95, rel=1e-5)
    assert again.image_area_mpx == pytest.approx(area)


def _set_pairs(seed, p_fa):
    truth, dets = synthetic_set(seed=seed, n_per_bin=300, p_fa=p_fa)
    return ((truth[k], dets[k]) for k in truth)


def test_false_box_rate_test_by_hand_and_where_it_is_not_comparable(fitted_synthetic):
    from pdcov.detection.statistics import _poisson_test

    # 7 boxes where 3 are expected: P(X >= 7) = 0.0335, doubled; 0 where 3: 2 e^-3.
    assert _poisson_test(7, 3.0) == pytest.approx(2 * (1 - stats.poisson.cdf(6, 3.0)))
    assert _poisson_test(0, 3.0) == pytest.approx(2 * math.exp(-3))
    assert _poisson_test(3, 3.0) == 1.0 and _poisson_test(0, 0.0) == 1.0
    assert _poisson_test(1, 0.0) == 0.0
    # docs/detector-statistics.md: 2 per Mpx over 50 x 0.2304 Mpx, 35 false boxes observed.
    assert _poisson_test(35, 2 * 50 * 0.2304) == pytest.approx(0.0242, abs=1e-4)
    _, model = fitted_synthetic
    other = validate(model, _matches(19), edges=EDGES[:4])
    assert other.fa_rate and all(r.expected is None and r.p_value is None
                                 for r in other.fa_rate)
    fisher = validate(model, _matches(19), test="fisher")
    n0, a0 = model.extra["n_false_boxes"][2], model.extra["fit"]["image_area_mpx"]
    r, area = fisher.fa_rate[2], fisher.image_area_mpx
    assert r.p_value == pytest.approx(
        stats.binomtest(r.observed, r.observed + n0, area / (area + a0)).pvalue, rel=1e-4)
    old = validate(replace(model, fa_rate_per_mpx=None), _matches(19))
    assert all(r.p_value is None for r in old.fa_rate)
    doc = other.to_dict()
    for b in doc["bins"]:
        for key in ("false_boxes", "fa_rate_per_mpx", "fa_rate_per_mpx_ci95",
                    "expected_false_boxes", "p_value_fa_rate"):
            del b[key]
    assert ValidationReport.from_dict(doc | {"version": 1}, "r.json").fa_rate == ()
