"""The limiting factor over the bus (tiles version 2, the snapshot): the watcher's grids and
the recording's fleet report show the vehicles' own limiting factors, merged by the maximum;
tiles version 1 (older daemons) leave them unknown, and the report says so."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from pdcov.bus.errors import BusPayloadError, Refusal
from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot, grid_hash
from pdcov.bus.tiles import BYTES_PER_CELL, apply_tiles, decode_tiles, encode_tiles, tile_grid_shape
from pdcov.config.load import load_mission
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.pose import CameraPose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.ground.record import LIMITING_NOT_SENT, Recording
from pdcov.ground.watcher import Watcher
from pdcov.service.tile_sender import TileSender

DEMO = str(Path(__file__).resolve().parents[2] / "service/pdcov/data/demo_mission.yaml")
R_ENU_CAM_NADIR = np.diag([1.0, -1.0, -1.0])
TILE = 8


@pytest.fixture(scope="module")
def mission():
    return load_mission(DEMO)


def short_range_grid(mission) -> CoverageGrid:
    """The demo mission's grid (same cells and hash) with a 25 m range, so that tilted
    frames mark cells too far, also beyond the window they observe."""
    g = mission.new_mission_grid()
    return CoverageGrid(g.geometry, g.mask, g.camera, g.detector, max_range_m=25.0)


def fly(grid: CoverageGrid, frames: int, x0_m: float, yaw0: float):
    """Frames at nadir and tilted, low and high (poses: ENU m, s)."""
    for k in range(frames):
        R = R_ENU_CAM_NADIR @ R_from_euler_zyx(yaw0 + 0.3 * k, (0.0, 0.6, 1.0)[k % 3], 0.0)
        yield CameraPose(R, np.array([x0_m + 3.0 * k, -50.0 + k, (8.0, 20.0)[k % 2]]), 0.5 * k)


def flown_to_watcher(watcher: Watcher, vid: str, grid: CoverageGrid, poses) -> None:
    """``grid`` flown through the daemon's TileSender into ``watcher``: the snapshot first,
    then a tiles message after every frame (no bandwidth limit: the watcher's grid equals
    the vehicle's after each)."""
    watcher.on_snapshot(vid, decode_snapshot(encode_snapshot(grid)), 0.0)
    sender = TileSender(grid, grid_hash(grid.geometry, grid.mask), TILE, 1e9, 0.0)
    for k, pose in enumerate(poses):
        grid.update(pose)
        if grid.touched is not None:
            sender.touch(grid.touched)
        payload = sender.send(0.1 * (k + 1), pose.t_s)
        if payload is not None:
            assert not watcher.on_tiles(vid, decode_tiles(payload), 0.1 * (k + 1))
        state_seen = watcher.feeds[vid].state
        assert state_seen is not None and state_seen.limiting is not None
        assert (state_seen.limiting == grid.limiting).all(), f"frame {k}"
        assert (state_seen.n_obs == grid.n_obs).all(), f"frame {k}"


def test_the_watchers_grid_has_the_vehicles_limiting_factors(mission):
    grid = short_range_grid(mission)
    w = Watcher()
    flown_to_watcher(w, "uav1", grid, fly(grid, 24, -70.0, 0.0))
    counts = grid.limiting_counts()
    # Cells too far (marked beyond the observed window too), seen and never in view.
    assert counts["too_far"] > 100 and counts["seen"] > 100 and counts["never_in_view"] > 0
    state = w.feeds["uav1"].state
    np.testing.assert_array_equal(state.limiting, grid.limiting)
    np.testing.assert_array_equal(state.n_obs, grid.n_obs)
    fleet, ids = w.fleet_state()
    assert ids == ("uav1",)
    np.testing.assert_array_equal(fleet.limiting, grid.limiting)


def test_two_vehicles_merge_by_the_maximum_as_coverage_grids_do(mission):
    a, b = short_range_grid(mission), short_range_grid(mission)
    w = Watcher()
    flown_to_watcher(w, "uav1", a, fly(a, 24, -70.0, 0.0))
    flown_to_watcher(w, "uav2", b, fly(b, 18, -40.0, 1.5))
    assert (a.limiting != b.limiting).any()
    core = short_range_grid(mission)
    core.merge(a)
    core.merge(b)
    fleet, ids = w.fleet_state()
    assert ids == ("uav1", "uav2")
    np.testing.assert_array_equal(fleet.limiting, core.limiting)
    np.testing.assert_array_equal(fleet.limiting, np.maximum(a.limiting, b.limiting))


def every_code_grid(mission) -> CoverageGrid:
    """The demo grid flown a little, then every cell given a random limiting code (any
    LimitingFactor)."""
    grid = mission.new_mission_grid()
    for pose in fly(grid, 6, -60.0, 0.0):
        grid.update(pose)
    grid.layer(Layer.LIMITING).write(
        (0, grid.geometry.n_rows, 0, grid.geometry.n_cols),
        np.random.default_rng(5).integers(0, len(LimitingFactor), grid.geometry.shape))
    return grid


def test_limiting_round_trips_through_the_snapshot_and_tiles(mission):
    grid = every_code_grid(mission)
    snap = decode_snapshot(encode_snapshot(grid))
    np.testing.assert_array_equal(snap.limiting, grid.limiting)
    assert snap.limiting.dtype == np.uint8
    dst = GridState.empty(grid.geometry, grid.mask)
    rows, cols = tile_grid_shape(TILE, *grid.geometry.shape)
    ids = [(r, c) for r in range(rows) for c in range(cols)]
    apply_tiles(dst, decode_tiles(encode_tiles(GridState.from_grid(grid), ids, seq=0,
                                               t_s=1.0, tile_size=TILE)))
    np.testing.assert_array_equal(dst.limiting, grid.limiting)


def v1_tiles(state: GridState, ids, *, seq: int, t_s: float, tile_size: int) -> bytes:
    """A tiles message in version 1's layout, written from docs/protocol.md (no limiting)."""
    g = state.geometry
    head = struct.pack("<4sHHQ8sdIHHII", b"PDTL", 1, 0, seq, bytes.fromhex(state.hash), t_s,
                       state.frames, tile_size, len(ids), g.n_rows, g.n_cols)
    body = b""
    for tr, tc in ids:
        win = np.s_[tr * tile_size:(tr + 1) * tile_size, tc * tile_size:(tc + 1) * tile_size]
        body += (struct.pack("<HH", tr, tc) + state.log_miss_d[win].astype("<f4").tobytes()
                 + state.log_miss_fa[win].astype("<f4").tobytes()
                 + state.n_obs[win].astype("<u4").tobytes()
                 + np.rint(state.pd[win] * 65535).astype("<u2").tobytes())
    return head + zlib.compress(body)


def test_version_1_tiles_decode_with_the_limiting_factor_unknown(mission):
    grid = every_code_grid(mission)
    state = GridState.from_grid(grid)
    update = decode_tiles(v1_tiles(state, [(0, 0), (2, 3)], seq=4, t_s=2.0, tile_size=TILE))
    assert update.version == 1 and all(t.limiting is None for t in update.tiles)
    np.testing.assert_array_equal(update.tiles[1].n_obs, grid.n_obs[16:24, 24:32])
    w = Watcher()
    w.on_snapshot("old", decode_snapshot(encode_snapshot(grid)), 0.0)
    assert w.feeds["old"].state.limiting is not None
    w.on_tiles("old", update, 0.1)
    assert w.feeds["old"].state.limiting is None  # stale once v1 tiles rewrote cells
    fleet, _ = w.fleet_state()
    assert fleet.limiting is None
    np.testing.assert_array_equal(fleet.n_obs, grid.n_obs)


def recorded_report(tmp_path: Path, watcher: Watcher, mission) -> tuple[str, dict]:
    rec = Recording(tmp_path / "rec")
    rec.close()
    lines = "\n".join(rec.finish(watcher, mission))
    return lines, json.loads((tmp_path / "rec" / "fleet" / "metrics.json").read_text())


def test_the_fleet_report_shows_the_vehicles_limiting_counts(tmp_path, mission):
    grid = mission.new_mission_grid()
    w = Watcher()
    flown_to_watcher(w, "demo", grid, fly(grid, 24, -70.0, 0.0))
    text, doc = recorded_report(tmp_path, w, mission)
    counts = grid.limiting_counts()
    assert counts["seen"] > 0 and counts["never_in_view"] < grid.mask.sum()
    assert doc["limiting_cells"] == counts
    want = "   ".join(f"{k.replace('_', ' ')}: {n}" for k, n in counts.items())
    assert f"limiting factor of free cells: {want}" in text
    with np.load(tmp_path / "rec" / "demo" / "grid.npz") as z:
        np.testing.assert_array_equal(z["limiting"], grid.limiting)


def test_the_fleet_report_says_when_a_vehicle_sent_no_limiting(tmp_path, mission):
    grid = mission.new_mission_grid()
    for pose in fly(grid, 6, -60.0, 0.0):
        grid.update(pose)
    w = Watcher()
    w.on_snapshot("old", decode_snapshot(encode_snapshot(grid)), 0.0)
    state = GridState.from_grid(grid)
    w.on_tiles("old", decode_tiles(v1_tiles(state, [(0, 0)], seq=0, t_s=3.0,
                                            tile_size=TILE)), 0.1)
    text, doc = recorded_report(tmp_path, w, mission)
    assert f"limiting factor of free cells: {LIMITING_NOT_SENT}" in text
    assert "never in view" not in text
    assert doc["limiting_cells"] is None and doc["limiting_unknown"] == LIMITING_NOT_SENT
    with np.load(tmp_path / "rec" / "fleet" / "grid.npz") as z:
        assert "limiting" not in z.files


@pytest.mark.parametrize("code", [len(LimitingFactor), 255])
def test_a_limiting_code_outside_the_factors_is_refused_and_counted(mission, code):
    grid = every_code_grid(mission)
    state = GridState.from_grid(grid)
    state.write(Layer.LIMITING, (3, 4, 5, 6), code)
    payload = encode_tiles(state, [(0, 0)], seq=0, t_s=1.0, tile_size=TILE)
    with pytest.raises(BusPayloadError, match=f"uav1/tiles.*limiting: codes must lie in "
                       f"0..{len(LimitingFactor) - 1}") as err:
        decode_tiles(payload, "pdcov/uav1/tiles")
    assert err.value.reason is Refusal.BAD_FIELD
    w = Watcher()
    w.on_snapshot("uav1", decode_snapshot(encode_snapshot(mission.new_mission_grid())), 0.0)
    w.on_bad_payload("uav1", err.value)
    assert w.refused["payloads: bad field"] == 1 and w.feeds["uav1"].bad_payloads == 1
    assert not w.feeds["uav1"].state.limiting.any()  # nothing applied
    grid.layer(Layer.LIMITING).write((3, 4, 5, 6), code)
    with pytest.raises(BusPayloadError, match="snapshot.*limiting: codes must lie in 0..7"):
        decode_snapshot(encode_snapshot(grid))


def test_a_version_2_record_holds_one_more_byte_a_cell():
    assert BYTES_PER_CELL == {1: 14, 2: 15}
