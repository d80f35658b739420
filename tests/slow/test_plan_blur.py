"""Planning sees motion blur: with camera.exposure_s and a detector model with blur bins a
faster flight predicts a lower P_D per look; without them the predictions are today's."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import yaml

from pdcov.cli import main
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.pose import FixedMount
from pdcov.planning.optimise import PlanParams, Scenario, build_plan, predict
from tests.support.blur_detector import blur_detector


def blur_model() -> DetectorModel:
    """The illustrative model, P_D scaled down with blur (detector-input px)."""
    return blur_detector((0.0, 0.5, 1.0, 2.0, 4.0, 64.0), (1.0, 0.9, 0.7, 0.45, 0.2))


def scenario(detector: DetectorModel, exposure_s: float | None) -> Scenario:
    """A 40 m square, a nadir camera; min_revisit_s over the whole flight counts one look
    per cell, so that a slower flight does not win by looking more often."""
    dom = Domain.from_enu([(0, 0), (40, 0), (40, 40), (0, 40)])
    geo = dom.grid_geometry(1.0)
    return Scenario(dom.free_space, geo, dom.free_mask(geo), CameraModel.from_fov(640, 480, 70),
                    detector, FixedMount(), frame_rate_hz=4.0, min_revisit_s=1e6,
                    exposure_s=exposure_s)


def mean_pd(sc: Scenario, speed_mps: float) -> float:
    plan, _ = build_plan(sc, PlanParams("lawnmower", 15.0, speed_mps))
    p = predict(sc, plan)
    assert p.grid.frames_blurred == (p.grid.frames if sc.exposure_s and sc.detector.blur
                                     else 0)
    return float(p.grid.pd[sc.mask].mean())


def test_predicted_pd_falls_with_speed_with_a_blur_model_and_not_without():
    speeds = (2.0, 6.0, 12.0)
    blurred = [mean_pd(scenario(blur_model(), 0.01), v) for v in speeds]
    sharp = [mean_pd(scenario(blur_model(), None), v) for v in speeds]
    assert blurred[0] > blurred[1] > blurred[2]
    assert max(sharp) - min(sharp) < 0.1 * max(sharp)  # one look per cell at every speed
    # f = 457 px at 15 m over 10 ms (input scale 1): blur 0.6, 1.8, 3.7 px in cruise, the
    # blur bins' P_D factors 0.9, 0.7, 0.45 (a cell first seen in a turn or while
    # accelerating is slower, so a little sharper).
    ratio = [b / s for b, s in zip(blurred, sharp, strict=True)]
    assert 0.85 < ratio[0] <= 0.9 + 1e-9 and 0.6 < ratio[1] < 0.72 and 0.45 <= ratio[2] < 0.6


def test_without_exposure_or_blur_bins_the_prediction_is_the_size_only_one():
    one_d = DetectorModel.illustrative()
    ref = predict(scenario(one_d, None), build_plan(scenario(one_d, None),
                                                   PlanParams("lawnmower", 15.0, 8.0))[0])
    for sc in (scenario(blur_model(), None), scenario(one_d, 0.01)):
        p = predict(sc, build_plan(sc, PlanParams("lawnmower", 15.0, 8.0))[0])
        assert np.array_equal(p.grid.log_miss_d, ref.grid.log_miss_d)
        assert np.array_equal(p.grid.log_miss_fa, ref.grid.log_miss_fa)


def test_pdcov_plan_says_blur_applied(tmp_path):
    cfg = yaml.safe_load((resources.files("pdcov") / "data" / "demo_mission.yaml").read_text())
    cfg["camera"]["exposure_s"] = 0.008
    cfg["detector"] = blur_model().to_dict()
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = {}
    for speed in ("4", "12"):
        run = tmp_path / speed
        assert main(["plan", "--config", str(path), "--pattern", "lawnmower", "--altitude-m",
                     "20", "--speed-mps", speed, "--out", str(run), "--no-figures"]) == 0
        out[speed] = json.loads((run / "metrics.json").read_text())
        assert out[speed]["motion_blur"]["effect"] == "applied"
        assert out[speed]["motion_blur"]["frames_blurred"] == out[speed]["frames"] > 0
    assert out["12"]["mean_pd"] < out["4"]["mean_pd"]


def test_planned_poses_carry_the_flights_velocity_and_turn_rate():
    from pdcov.planning.trajectory import camera_poses, fly
    sc = scenario(blur_model(), 0.01)
    plan, _ = build_plan(sc, PlanParams("lawnmower", 15.0, 6.0))
    flight = fly(plan, 4.0)
    poses = camera_poses(flight, FixedMount())
    assert all(p.has_motion for p in poses)
    v = np.array([p.v_cam_enu_m_s for p in poses])
    speed = np.linalg.norm(v[:, :2], axis=1)
    cruise = flight.speed_mps == 6.0
    assert cruise.sum() > 30
    np.testing.assert_allclose(speed[cruise], 6.0, rtol=1e-6)
    # Accelerating, the flown positions (linear between 0.1 m path samples) move at each
    # sample step's mean speed, which the interpolated speed_mps leads or lags a little.
    np.testing.assert_allclose(speed, flight.speed_mps, atol=0.4)
    # The heading turns about ENU up (clockwise from north: negative), never faster than
    # the kinematic limit, and not at all on the straight legs.
    omega_z = np.array([p.omega_enu_rad_s[2] for p in poses])
    assert np.abs(omega_z).max() <= sc.kinematics.max_yaw_rate_rad_s + 1e-6
    assert np.abs(omega_z).max() > 0.3 and (np.abs(omega_z[cruise]) < 1e-9).all()


def test_a_bad_exposure_is_named(tmp_path):
    import pytest

    from pdcov.config.load import load_mission
    from pdcov.errors import ConfigError
    cfg = yaml.safe_load((resources.files("pdcov") / "data" / "demo_mission.yaml").read_text())
    for bad in (0, -0.01, "fast", float("nan")):
        cfg["camera"]["exposure_s"] = bad
        path = tmp_path / "m.yaml"
        path.write_text(yaml.safe_dump(cfg))
        with pytest.raises(ConfigError, match=r"m.yaml: camera.exposure_s: expected a"):
            load_mission(path)
    cfg["camera"]["exposure_s"] = 0.002
    path.write_text(yaml.safe_dump(cfg))
    m = load_mission(path)
    assert m.first_camera.exposure_s == 0.002 and m.new_mission_grid().exposure_s == 0.002
