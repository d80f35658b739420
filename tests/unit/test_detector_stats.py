"""Detector statistics: bins, intervals, fits and validation tests, on the synthetic labelled
set of tests/support/synthetic_detections.py (the matching: test_detector_matching.py)."""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy import special, stats

from pdcov.core.detector import DetectorModel
from pdcov.detection.logistic import fit_logistic, fit_logistic_curve
from pdcov.detection.matching import MatchSettings, match_images
from pdcov.detection.statistics import (
    auto_bin_edges,
    count_in_bins,
    fit_binned,
    fit_confidence,
    proportion_ci,
)
from pdcov.detection.validation import ValidationReport, validate
from pdcov.errors import ConfigError, DetectorModelError
from tests.support.detection_boxes import S, dets_of, truth_image
from tests.support.synthetic_detections import EDGES, INPUT, P_D, P_FA, synthetic_set


@pytest.fixture(scope="module")
def fitted_synthetic():
    truth, dets = synthetic_set(seed=1, n_per_bin=600)
    settings = MatchSettings(0.5, 0.5, INPUT, ("person",))
    matches = match_images(((truth[k], dets[k]) for k in truth), settings)
    return matches, fit_binned(matches, EDGES, "wilson")


# -- matching ---------------------------------------------------------------------------------


# -- agreement with pycocotools ---------------------------------------------------------------


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
    dets = dets_of(gt + [(0, 50, 20, 20), (30, 50, 20, 20)], [0.9, 0.8, 0.6, 0.55, 0.3])
    matches = match_images([(truth_image(gt), dets)], S)
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
    assert fit_confidence(match_images([(truth_image(gt), dets)], MatchSettings(1.0, 0.5, None)),
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
    from pdcov.detection.validation import _poisson_test

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
