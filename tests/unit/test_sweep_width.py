"""Lateral range curve, sweep width and Koopman's figures (core/sweep_width.py), checked by
hand, against a lawnmower flown through the grid, and in `pdcov evaluate`'s metrics.json."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose, FixedMount, fixed_mount_pose
from pdcov.core.sweep_width import FlightSample, SearchEffort, lateral_range
from tests.support.evaluate_inputs import (
    expected_poses,
    known_flight,
    mission_doc,
    run,
    write_config,
    write_pose_csv,
)

# 90 deg across track (640 px wide, east for a northbound nadir camera), 73.7 deg along it:
# at 20 m the footprint is 40 m wide and 30 m long.
CAMERA = CameraModel.from_fov(640, 480, 90.0)
H_M, WIDTH_M, LENGTH_M = 20.0, 40.0, 30.0


def detector(p: float) -> DetectorModel:
    """P_D ``p`` per look for every size a cell shows at these heights (1 m cells at 20 m:
    16 px), 0 beyond the one bin."""
    return DetectorModel(bin_edges_px=(1.0, 1e5), p_detect=(p,), p_false_alarm=(0.0,))


def test_nadir_sweep_width_is_the_footprint_width():
    curve = lateral_range(CAMERA, detector(1.0), FixedMount(), altitude_m=H_M, speed_mps=10,
                          frame_rate_hz=1, cell_size_m=1.0)
    assert curve.sweep_width_m == pytest.approx(WIDTH_M, abs=2.0)
    inside = np.abs(curve.offsets_m) < WIDTH_M / 2  # the columns at +-20 m have their
    assert np.all(curve.p[inside] == 1.0)  # centres on the image's edge: rounding decides
    assert np.all(curve.p[np.abs(curve.offsets_m) > WIDTH_M / 2] == 0.0)


@pytest.mark.parametrize("n_looks", [1, 3])
def test_plateau_of_n_independent_looks(n_looks):
    # A frame every LENGTH_M / n metres: each cell in n frames.
    curve = lateral_range(CAMERA, detector(0.5), FixedMount(), altitude_m=H_M,
                          speed_mps=LENGTH_M / n_looks, frame_rate_hz=1, cell_size_m=1.0)
    middle = curve.p[np.abs(curve.offsets_m) <= 15]
    assert middle == pytest.approx(1 - 0.5 ** n_looks, abs=1e-6)
    assert curve.sweep_width_m == pytest.approx((1 - 0.5 ** n_looks) * WIDTH_M, abs=2.0)


def test_a_camera_tilted_to_the_right_shifts_and_narrows_the_curve():
    # Looking east, 20 deg off nadir: the image's 480 px (73.7 deg) across the track, from
    # h tan(20 - 36.9 deg) = -6.1 m to h tan(20 + 36.9 deg) = 30.6 m.
    mount = FixedMount(pitch_rad=math.radians(-70), yaw_rad=math.radians(90))
    tilted = lateral_range(CAMERA, detector(1.0), mount, altitude_m=H_M, speed_mps=10,
                           frame_rate_hz=1, cell_size_m=1.0, max_range_m=200)
    seen = tilted.offsets_m[tilted.p > 0.5]
    assert seen.min() == pytest.approx(-6.1, abs=1.5)
    assert seen.max() == pytest.approx(30.6, abs=1.5)
    assert tilted.sweep_width_m == pytest.approx(36.7, abs=2.0)
    assert tilted.sweep_width_m < WIDTH_M


def test_koopman_figures_by_hand():
    effort = SearchEffort(sweep_width_m=40.0, track_length_m=2000.0, area_m2=200_000.0)
    assert effort.coverage_factor == pytest.approx(0.4)
    assert effort.pod_random_search == pytest.approx(1 - math.exp(-0.4))
    assert effort.pod_parallel_sweeps == pytest.approx(0.4)
    assert SearchEffort(40.0, 20_000.0, 200_000.0).pod_parallel_sweeps == 1.0
    assert SearchEffort(40.0, 20_000.0, 200_000.0).pod_random_search == pytest.approx(
        1 - math.exp(-4))


def test_flight_sample():
    poses = [CameraPose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 4.0 * k, 30.0 + k]),
                        t_s=0.5 * k) for k in range(5)]
    s = FlightSample.of(poses)
    assert s.track_length_m == pytest.approx(16.0)
    assert s.time_on_scene_s == 2.0  # 5 frames 0.5 s apart
    assert s.speeds_mps == pytest.approx([8.0] * 4)
    assert np.median(s.heights_agl_m) == 32.0
    assert s.unusable() is None
    assert "at least 2" in FlightSample.of(poses[:1]).unusable()
    assert "never moved at 0.5 m/s" in FlightSample.of([poses[0], poses[0]]).unusable()
    joined = FlightSample.joined([s, s])
    assert joined.track_length_m == 32.0 and len(joined.speeds_mps) == 8
    assert joined.time_on_scene_s == 4.0


def test_hovering_frames_are_not_the_search_speed():
    # Mostly hovering (1e-9 m/s, a multicopter's log between position updates), 8 m/s
    # between a few frames: the sweep is taken at 8 m/s, not at the median 1e-9.
    y = np.concatenate([np.full(20, 0.0) + 1e-9 * np.arange(20), 2e-8 + 4.0 * np.arange(1, 4)])
    poses = [CameraPose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, yk, 30.0]), t_s=0.5 * k)
             for k, yk in enumerate(y)]
    s = FlightSample.of(poses)
    assert np.median(s.speeds_mps) < 1e-6
    assert s.search_speed_mps == pytest.approx(8.0)
    assert s.unusable() is None


def test_a_pass_of_too_many_frames_is_refused():
    # 30 m of footprint at 1 mm a frame: 30,000 frames.
    with pytest.raises(ValueError, match=r"would take 3\d,\d{3} frames"):
        lateral_range(CAMERA, detector(1.0), FixedMount(), altitude_m=H_M, speed_mps=0.01,
                      frame_rate_hz=10, cell_size_m=1.0)


def test_sweep_width_over_lane_spacing_is_the_lawnmowers_mean_pd():
    """A lawnmower with spacing S >> W over an area A: mean P_D = W L / A = W / S."""
    det, c, spacing = detector(0.5), 2.0, 120.0
    curve = lateral_range(CAMERA, det, FixedMount(), altitude_m=H_M, speed_mps=15,
                          frame_rate_hz=1, cell_size_m=c)
    side_x, side_y = 360.0, 240.0
    geometry = GridGeometry(0.0, 0.0, c, int(side_y / c), int(side_x / c))
    grid = CoverageGrid(geometry, np.ones(geometry.shape, bool), CAMERA, det)
    # Lanes on column centres, as the curve's track is.
    t, lanes = 0.0, np.arange(spacing / 2 + c / 2, side_x, spacing)
    for k, x in enumerate(lanes):  # past both ends, so every cell sees the whole pass
        ys = np.arange(-LENGTH_M, side_y + LENGTH_M, 15.0)
        for y in ys if k % 2 == 0 else ys[::-1]:
            R = np.eye(3) if k % 2 == 0 else np.diag([-1.0, -1.0, 1.0])  # north, south
            grid.update(fixed_mount_pose(R, np.array([x, y, H_M]), FixedMount(), t))
            t += 1.0
    effort = SearchEffort(curve.sweep_width_m, len(lanes) * side_y, side_x * side_y)
    assert effort.coverage_factor == pytest.approx(curve.sweep_width_m / spacing)
    assert float(grid.pd.mean()) == pytest.approx(effort.coverage_factor, rel=0.03)


def test_evaluate_writes_the_sweep_width(tmp_path):
    cfg = write_config(tmp_path, mission_doc())
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None))
    out = tmp_path / "run"
    assert run("evaluate", "--config", str(cfg), "--poses", str(csv), "--out", str(out),
               "--no-progress") == 0
    block = json.loads((out / "metrics.json").read_text())["sweep_width"]
    assert set(block) >= {"altitude_agl_m", "speed_mps", "sweep_width_m", "track_length_m",
                          "area_m2", "coverage_factor", "pod_random_search",
                          "pod_parallel_sweeps"}
    assert 8.0 <= block["altitude_agl_m"] <= 12.0  # 10 + 2 sin(t / 5) m
    assert block["speed_mps"] == pytest.approx(2.0, abs=0.3)  # 2 m/s north, some sway
    assert block["area_m2"] == pytest.approx(40 * 40 - 4 * 4)
    assert block["track_length_m"] > 40.0
    assert 0 < block["sweep_width_m"] < 40
    c = block["sweep_width_m"] * block["track_length_m"] / block["area_m2"]
    assert block["coverage_factor"] == pytest.approx(c)
    assert block["pod_random_search"] == pytest.approx(1 - math.exp(-c))
    assert block["pod_parallel_sweeps"] == pytest.approx(min(c, 1.0))


def test_evaluate_of_one_frame_says_why_no_sweep_width(tmp_path):
    cfg = write_config(tmp_path, mission_doc())
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None)[:1])
    out = tmp_path / "run"
    assert run("evaluate", "--config", str(cfg), "--poses", str(csv), "--out", str(out),
               "--no-progress") == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["sweep_width"] is None
    assert "at least 2" in doc["sweep_width_unknown"]
