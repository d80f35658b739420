"""coverage.min_revisit_s: the same poses give the same grid whatever the order of the pose
CSV's rows and whatever the time origin (boot clock or Unix epoch); the grid refuses frames
that go back in time; old float32 snapshots load only where their clock is exact enough."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.errors import InputFileError
from tests.support.evaluate_inputs import (
    expected_poses,
    known_flight,
    load_grid,
    mission_doc,
    run,
    write_config,
    write_pose_csv,
)
from tests.support.square_grid import DETECTOR, PINHOLE, pose, square_grid

EPOCH_S = 1.7e9


def shifted(p: CameraPose, dt_s: float) -> CameraPose:
    return CameraPose(p.R_enu_cam, p.r_cam_enu, p.t_s + dt_s)


def evaluate_csv(tmp_path, name: str, poses) -> dict:
    config = write_config(tmp_path, mission_doc(coverage={"min_revisit_s": 1.0}))
    csv = write_pose_csv(tmp_path / f"{name}.csv", poses)
    assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / name), "--no-progress") == 0
    return load_grid(tmp_path / name)


def test_row_order_and_time_origin_do_not_change_the_grid(tmp_path):
    poses = expected_poses(known_flight(), None)
    rng = np.random.default_rng(7)
    variants = {
        "reversed": poses[::-1],
        "shuffled": [poses[i] for i in rng.permutation(len(poses))],
        "epoch": [shifted(p, EPOCH_S) for p in poses],
        "epoch_shuffled": [shifted(poses[i], EPOCH_S) for i in rng.permutation(len(poses))],
    }
    ref = evaluate_csv(tmp_path, "sorted", poses)
    assert ref["n_obs"].sum() > 500
    for name, variant in variants.items():
        out = evaluate_csv(tmp_path, name, variant)
        for key in ("n_obs", "log_miss_d", "log_miss_fa", "pd"):
            np.testing.assert_array_equal(out[key], ref[key], err_msg=f"{name}: {key}")


def test_revisit_interval_is_exact_at_epoch_times_and_decimal_steps():
    # Frames 0.1 s apart: 0.3 - 0.1 is 0.19999999999999998 in float64, and at 1.7e9 s the
    # times are 2.4e-7 s apart; both must count a look every 0.2 s, as the exact times do.
    for t0 in (0.0, EPOCH_S):
        grid = square_grid(min_revisit_s=0.2)
        for k in range(11):
            grid.update(pose(xyz=(0.5, 0.5, 10), t_s=t0 + round(0.1 * k, 1)))
        assert grid.n_obs[40, 40] == 6, t0


def test_grid_refuses_frames_going_back_in_time_before_counting():
    grid = square_grid(min_revisit_s=1.0)
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=5.0))
    with pytest.raises(ValueError, match="time order.*4.0"):
        grid.update(pose(xyz=(0.5, 0.5, 10), t_s=4.0))
    assert grid.frames == 1 and grid.n_obs[40, 40] == 1
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=5.0))  # the same time again is fine
    plain = square_grid()  # without the revisit clock order does not matter
    plain.update(pose(xyz=(0.5, 0.5, 10), t_s=5.0))
    plain.update(pose(xyz=(0.5, 0.5, 10), t_s=4.0))
    assert plain.n_obs[40, 40] == 2


def test_snapshot_keeps_epoch_clock_exactly(tmp_path):
    grid = square_grid(min_revisit_s=1.0)
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=EPOCH_S + 0.25))
    grid.save_npz(tmp_path / "g.npz")
    again = CoverageGrid.load_npz(tmp_path / "g.npz", PINHOLE, DETECTOR, min_revisit_s=1.0)
    assert again.last_obs_s[40, 40] == EPOCH_S + 0.25
    with pytest.raises(ValueError, match="time order"):
        again.update(pose(xyz=(0.5, 0.5, 10), t_s=EPOCH_S))
    again.update(pose(xyz=(0.5, 0.5, 10), t_s=EPOCH_S + 1.0))  # 0.75 s later: not counted
    again.update(pose(xyz=(0.5, 0.5, 10), t_s=EPOCH_S + 1.25))
    assert again.n_obs[40, 40] == 2


def version_1_snapshot(tmp_path, t_s: float):
    """A snapshot as pdcov wrote it before version 2: float32 revisit clock."""
    grid = square_grid(min_revisit_s=1.0)
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=t_s))
    grid.save_npz(tmp_path / "new.npz")
    with np.load(tmp_path / "new.npz") as z:
        data = {k: z[k] for k in z.files if k != "latest_frame_t_s"}
    data |= {"version": np.int64(1), "last_obs_s": data["last_obs_s"].astype(np.float32)}
    path = tmp_path / f"v1_{t_s:.0f}.npz"
    np.savez(path, **data)
    return path


def test_version_1_snapshots_load_where_their_clock_is_exact(tmp_path):
    path = version_1_snapshot(tmp_path, 120.5)
    old = CoverageGrid.load_npz(path, PINHOLE, DETECTOR, min_revisit_s=1.0)
    assert old.last_obs_s.dtype == np.float64 and old.last_obs_s[40, 40] == 120.5
    assert old.latest_frame_t_s == 120.5 and old.n_obs[40, 40] == 1
    epoch = version_1_snapshot(tmp_path, EPOCH_S)
    with pytest.raises(InputFileError, match=r"v1_1700000000.npz.*version 1.*float32.*128 s"):
        CoverageGrid.load_npz(epoch, PINHOLE, DETECTOR, min_revisit_s=1.0)
    # Without min_revisit_s the clock is not used, so the snapshot loads.
    loaded = CoverageGrid.load_npz(epoch, PINHOLE, DETECTOR)
    assert loaded.last_obs_s is None and loaded.n_obs[40, 40] == 1
    assert math.isinf(square_grid(min_revisit_s=1.0).latest_frame_t_s)
