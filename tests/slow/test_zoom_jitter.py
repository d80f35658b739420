"""A zoom lens jittering between frames reuses the grid's cameras, and quantising the focal
length changes no cell (many frames: slow)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pdcov.config.load import load_mission
from pdcov.core.pose import CameraPose
from pdcov.core.zoom import (
    FovLens,
    hfov_rad,
    quantised_hfov_rad,
)


def test_zoom_jitter_reuses_cameras_and_quantising_changes_no_cell():
    """A report jittering by 0.01 deg builds a handful of cameras, not one per frame; the
    quantised camera's grid equals the exact one's to 1e-5 in P_D (FOV_FOCAL_STEP)."""
    m = load_mission(Path(__file__).resolve().parents[2]
                     / "service/pdcov/data/demo_mission.yaml")
    (cam,) = m.cameras
    wide = cam.camera
    lens = FovLens(wide, math.radians(10.0))
    h0 = math.radians(40.0)
    for k in range(200):
        lens.camera(h0 + math.radians(0.01) * ((-1) ** k) * (k % 3))
    assert len(lens._cache.cameras) <= 5, len(lens._cache.cameras)  # built once each
    build = lens._build
    exact, quant = m.new_mission_grid(), m.new_mission_grid()
    R = np.diag([1.0, -1.0, -1.0])  # looking straight down
    for k, h in enumerate(np.radians([20.003, 33.337, 40.011, 51.2349])):
        pose = CameraPose(R, np.array([-40.0 + 3.0 * k, -40.0, 25.0]), float(k))
        exact.update_with(pose, build(float(h)), cam.detector)
        quant.update_with(pose, build(quantised_hfov_rad(float(h), hfov_rad(wide))),
                          cam.detector)
    assert exact.n_obs.sum() > 100
    np.testing.assert_array_equal(quant.n_obs, exact.n_obs)
    np.testing.assert_allclose(quant.pd, exact.pd, atol=1e-5)
