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


@pytest.mark.parametrize("change, key", [
    ({"version": 5}, "version"),
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
    from pdcov.core.detector import MAX_BINS, MAX_MODEL_BYTES

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
