"""`pdcov evaluate`'s input files in memory: a calibration file with a relative detector
path, priors from GeoJSON segments and GeoTIFF, a prior summing above one refused."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from pdcov.config.load import load_mission
from tests.support.evaluate_inputs import ORIGIN, mission_doc, write_config


def test_calibration_file_and_relative_detector_path(tmp_path):
    from pdcov.core.detector import DetectorModel

    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "det.yaml").write_text(DetectorModel.illustrative().to_yaml())
    (tmp_path / "cam.yaml").write_text(yaml.safe_dump({
        "image_width": 640, "image_height": 480,
        "camera_matrix": {"rows": 3, "cols": 3, "data": [480, 0, 319.5, 0, 480, 239.5, 0, 0, 1]},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.05, 0.01, 0, 0, 0]}}))
    doc = mission_doc(detector="models/det.yaml")
    doc["camera"] = {"calibration": "cam.yaml", "frame_rate_hz": 5}
    mission = load_mission(write_config(tmp_path, doc))
    inline = load_mission(write_config(tmp_path, mission_doc(), "inline.yaml"))
    (cam,), (inline_cam,) = mission.cameras, inline.cameras
    np.testing.assert_array_equal(cam.camera.K, inline_cam.camera.K)
    assert cam.detector.p_detect == inline_cam.detector.p_detect
    assert math.isclose(cam.frame_rate_hz, 5.0)


def test_prior_from_geojson_segments_and_geotiff(tmp_path):
    from pdcov.core.geodesy import enu_to_geodetic
    from pdcov.report.gis import array_band, write_geotiff
    from pdcov.report.outputs import read_prior

    mission = load_mission(write_config(tmp_path, mission_doc()))
    g = mission.domain.grid_geometry(1.0)
    mask = mission.domain.free_mask(g)

    def ring(x0, y0, x1, y1):
        enu = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x0, y0, 0]])
        return [[lon, lat] for lat, lon, _ in enu_to_geodetic(enu, ORIGIN)]
    doc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"poa": 0.6},
         "geometry": {"type": "Polygon", "coordinates": [ring(0, 0, 10, 10)]}},
        {"type": "Feature", "properties": {"poa": 0.3},
         "geometry": {"type": "Polygon", "coordinates": [ring(30, 30, 40, 40)]}}]}
    (tmp_path / "segments.geojson").write_text(json.dumps(doc))
    poa = read_prior(tmp_path / "segments.geojson", g, mask, ORIGIN).poa
    assert poa.sum() == pytest.approx(0.9)
    assert poa[5, 5] == pytest.approx(0.6 / 100) and poa[35, 35] == pytest.approx(0.3 / 100)
    assert poa[20, 5] == 0
    write_geotiff(tmp_path / "prior.tif", {"poa": array_band(poa)}, g, ORIGIN,
                  array_band(np.ones_like(mask)), exact_grid=True)  # as posterior.tif
    np.testing.assert_allclose(read_prior(tmp_path / "prior.tif", g, mask, ORIGIN).poa, poa,
                               rtol=1e-6)
    doc["features"][0]["properties"] = {}
    (tmp_path / "bad.geojson").write_text(json.dumps(doc))
    from pdcov.errors import InputFileError
    with pytest.raises(InputFileError, match="bad.geojson.*poa"):
        read_prior(tmp_path / "bad.geojson", g, mask, ORIGIN)


def test_prior_summing_above_one_is_rejected(tmp_path):
    # A prior of weights rather than probabilities gave a probability of success above 1.
    from pdcov.errors import InputFileError
    from pdcov.report.outputs import read_prior

    mission = load_mission(write_config(tmp_path, mission_doc()))
    g = mission.domain.grid_geometry(1.0)
    mask = mission.domain.free_mask(g)
    np.save(tmp_path / "weights.npy", np.ones(g.shape))
    with pytest.raises(InputFileError, match=r"weights.npy.*sum to 1600"):
        read_prior(tmp_path / "weights.npy", g, mask, ORIGIN)
    np.save(tmp_path / "prior.npy", np.full(g.shape, 1.0 / g.n_rows / g.n_cols))
    assert read_prior(tmp_path / "prior.npy", g, mask, ORIGIN).poa.sum() == pytest.approx(1.0)
