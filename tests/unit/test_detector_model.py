"""Detector model YAML and lookup."""

import numpy as np
import pytest
import yaml

from pdcov.core.detector import DetectorModel
from pdcov.errors import DetectorModelError


def model(**kw):
    doc = {"version": 1, "bin_edges_px": [10, 20, 40], "p_detect": [0.3, 0.7],
           "p_false_alarm": [0.1, 0.2], "input_size_px": 640} | kw
    return DetectorModel.from_dict(doc, source="det.yaml")


def test_lookup_bins_and_outside():
    pd, pfa = model().lookup(np.array([5, 10, 19.99, 20, 39.9, 40, 100, np.nan]))
    np.testing.assert_allclose(pd, [0, 0.3, 0.3, 0.7, 0.7, 0, 0, 0])
    np.testing.assert_allclose(pfa, [0, 0.1, 0.1, 0.2, 0.2, 0, 0, 0])


def test_lookup_of_a_scalar_size():
    # searchsorted returns a numpy scalar for a scalar; marking NaN by item assignment failed.
    assert model().lookup(15.0) == (pytest.approx(0.3), pytest.approx(0.1))
    assert model().lookup(float("nan")) == (0.0, 0.0)


def test_input_scale():
    m = model()
    assert m.image_to_input_scale(1920, 1080) == pytest.approx(640 / 1920)
    assert model(input_size_px=None).image_to_input_scale(1920, 1080) == 1.0


def test_yaml_round_trip(tmp_path):
    m = model(counts={"n_true": [10, 20], "n_detected": [3, 14], "n_detections": [5, 16]})
    path = tmp_path / "d.yaml"
    path.write_text(m.to_yaml())
    again = DetectorModel.from_yaml(path)
    assert again.p_detect == m.p_detect and again.counts == m.counts


def test_illustrative_model_is_labelled_and_peaks_in_the_middle():
    m = DetectorModel.illustrative()
    assert m.extra.get("illustrative") is True
    p = np.array(m.p_detect)
    assert p[0] < p.max() and p[-1] < p.max()


def test_illustrative_confidences_are_the_simulators_beta_rule_and_say_so():
    from scipy import stats

    conf = DetectorModel.illustrative().confidence
    assert conf.extra["notes"].startswith("ILLUSTRATIVE, not measured")
    u = (np.asarray(conf.edges) - 0.5) / 0.5  # threshold 0.5: c = 0.5 + 0.5 Beta
    for true_positive, (a, b) in ((True, (4, 2)), (False, (2, 4))):
        mass = np.diff(stats.beta.cdf(u, a, b))
        np.testing.assert_allclose(conf.probabilities(true_positive),
                                   np.tile(mass, (15, 1)), atol=2e-4)


@pytest.mark.parametrize("change, key", [
    ({"version": 6}, "version"),
    ({"bin_edges_px": [10, 5, 40]}, "bin_edges_px"),
    ({"p_detect": [0.3]}, "p_detect"),
    ({"p_false_alarm": [0.1, 1.5]}, "p_false_alarm"),
    ({"p_detect": "high"}, "p_detect"),
    ({"input_size_px": -3}, "input_size_px"),
    ({"size_metric": "height"}, "size_metric"),
])
def test_bad_model_names_the_key(change, key):
    with pytest.raises(DetectorModelError, match=f"det.yaml: {key}"):
        model(**change)


def test_unreadable_file(tmp_path):
    with pytest.raises(DetectorModelError, match="cannot read"):
        DetectorModel.from_yaml(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: [1\n")
    with pytest.raises(DetectorModelError, match="not valid YAML"):
        DetectorModel.from_yaml(bad)
    bad.write_text(yaml.safe_dump([1, 2]))
    with pytest.raises(DetectorModelError, match="mapping"):
        DetectorModel.from_yaml(bad)


def test_a_model_file_too_large_or_of_too_many_bins_is_refused_before_parsing(tmp_path):
    from pdcov.core.detector_file import MAX_BINS, MAX_MODEL_BYTES

    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * MAX_MODEL_BYTES)
    with pytest.raises(DetectorModelError, match=r"big.yaml: 4,194,306 bytes, more than the "
                                                 r"4,194,304 a detector model may have"):
        DetectorModel.from_yaml(big)
    n = MAX_BINS + 1
    doc = {"version": 1, "bin_edges_px": list(range(n + 1)), "p_detect": [0.5] * n,
           "p_false_alarm": [0.0] * n}
    with pytest.raises(DetectorModelError, match=r"bin_edges_px: 1,002 entries, more than a "
                                                 r"model of 1000 bins has"):
        DetectorModel.from_dict(doc, source="m.yaml")


# -- the confidence section (version 5) -------------------------------------------------------

CONFIDENCE = {"edges": [0.5, 0.75, 1.0],
              # Rows are rescaled to integrate to 1: [2, 6] is the densities [1, 3].
              "tp_density": [[2.0, 6.0], [2.0, 2.0]],
              "fp_density": [[3.0, 1.0], [1.0, 1.0]]}


def confident(**kw):
    return model(version=5, fa_rate_per_mpx=[0.1, 0.2], confidence=CONFIDENCE | kw)


def test_confidence_log_lr_by_hand():
    m = confident()
    # Size bin [10, 20): P_TP = [0.25, 0.75], P_FP = [0.75, 0.25]: -log 3 low, +log 3 high.
    # Size bin [20, 40): both uniform, no evidence. Outside the bins: the nearest bin.
    sizes = np.array([15, 15, 5, 15, 15, 30, 100, np.nan, 15])
    conf = np.array([0.6, 0.9, 0.9, 1.0, 0.3, 0.9, 0.6, 0.9, np.nan])
    np.testing.assert_allclose(m.confidence_log_lr(sizes, conf),
                               [-np.log(3), np.log(3), np.log(3), np.log(3), -np.log(3),
                                0, 0, 0, 0], atol=1e-12)
    assert m.confidence_log_lr(15.0, 0.8) == pytest.approx(np.log(3))  # scalars
    np.testing.assert_array_equal(model().confidence_log_lr(sizes, conf), np.zeros(9))


def test_confidence_section_round_trips_as_version_5(tmp_path):
    m = confident(smoothing="add-one", n_true_positives=[[0, 2], [1, 1]])
    path = tmp_path / "d.yaml"
    path.write_text(m.to_yaml())
    doc = yaml.safe_load(path.read_text())
    assert doc["version"] == 5 and doc["confidence"]["smoothing"] == "add-one"
    again = DetectorModel.from_yaml(path)
    assert again.confidence == m.confidence
    assert yaml.safe_load(model().to_yaml())["version"] == 1  # no section: as before


@pytest.mark.parametrize("change, key, message", [
    ({"edges": [0.5, 0.9]}, "confidence.edges", "the last 1"),
    ({"edges": [0.5, 0.4, 1.0]}, "confidence.edges", "strictly increasing"),
    ({"edges": "0.5,1"}, "confidence.edges", "a list of numbers"),
    ({"tp_density": [[1.0, 1.0]]}, "confidence.tp_density", "2 rows .* of 2 values"),
    ({"fp_density": [[1.0, 1.0], [1.0]]}, "confidence.fp_density", "2 rows"),
    ({"fp_density": [[1.0, 0.0], [1.0, 1.0]]}, "confidence.fp_density",
     "finite and > 0 .* got 0.0 in row 0 \\(size bin\\), column 1"),
    ({"tp_density": [[1.0, float("inf")], [1.0, 1.0]]}, "confidence.tp_density", "finite"),
    ({"tp_density": [1.0, 1.0]}, "confidence.tp_density", "rows of numbers"),
    ({"tp_densty": [[1.0, 1.0]]}, "confidence.tp_densty", "did you mean"),
])
def test_a_bad_confidence_section_names_the_field(change, key, message):
    with pytest.raises(DetectorModelError, match=f"det.yaml: {key}.*{message}"):
        confident(**change)


def test_a_confidence_section_needs_version_5_and_stays_within_the_bin_cap():
    from pdcov.core.detector_file import MAX_BINS

    with pytest.raises(DetectorModelError, match="det.yaml: confidence: needs version 5, the "
                                                 "file says 4"):
        model(version=4, fa_rate_per_mpx=[0.1, 0.2], confidence=CONFIDENCE)
    k = MAX_BINS
    with pytest.raises(DetectorModelError, match="confidence.tp_density: 1,002 entries"):
        confident(edges=[i / k for i in range(k + 1)],
                  tp_density=[[1.0] * (k + 2)] * 2, fp_density=[[1.0] * k] * 2)
