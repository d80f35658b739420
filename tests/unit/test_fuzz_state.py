"""Fuzzing the grid's saved and published state (issue 15, bad input): checkpoints and the
Zenoh payloads a watcher receives (tiles, status, snapshots). A bad checkpoint is set aside,
never half loaded; a bad tile, status or snapshot never changes the watcher's grid. The
file readers: test_fuzz_files.py."""

from __future__ import annotations

import io
import json
import shutil
import struct
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zarr
from hypothesis import given
from hypothesis import strategies as st

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles
from pdcov.config.load import mission_from_dict
from pdcov.core.grid_layer import Layer
from pdcov.core.pose import CameraPose
from pdcov.ground.watcher import Watcher
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
from tests.support.fuzz_inputs import (
    HOSTILE,
    SETTINGS,
    mutated_bytes,
    only_pdcov_errors,
)
from tests.support.link_feed import MISSION

# --- checkpoints ------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def grid_and_checkpoint(tmp_path_factory):
    """A mission grid that saw a few frames and its checkpoint folder."""
    d = tmp_path_factory.mktemp("ckpt")
    mission = mission_from_dict(MISSION, "m.yaml", d)
    grid = mission.new_mission_grid()
    R_down = np.diag([1.0, -1.0, -1.0])
    for k in range(6):
        grid.update(CameraPose(R_down, np.array([5.0 + 3 * k, 15.0, 12.0]), 2.0 * k))
    write_checkpoint(d / CHECKPOINT_NAME, grid, {"mission_hash": "h", "t0_s": 0.0,
                                                 "last_frame_t_s": 10.0})
    return mission, grid, d / CHECKPOINT_NAME


def check_resume(tmp_path: Path, mission, grid, folder: Path,
                 damage: Callable[[Path], None]) -> None:
    """Resume from a copy of the checkpoint ``folder`` with ``damage`` done to it: either
    the very grid that was saved, or a fresh start with the folder set aside (kept,
    renamed) and nothing of it loaded."""
    state = tmp_path / "state"
    if state.exists():
        shutil.rmtree(state)
    state.mkdir()
    shutil.copytree(folder, state / CHECKPOINT_NAME)
    damage(state / CHECKPOINT_NAME)
    fresh = mission.new_mission_grid()
    r = only_pdcov_errors(resume, state, "h", fresh)
    assert r is not None, "resume must not raise: a bad checkpoint is set aside"
    if r.grid is None:
        assert r.set_aside is not None and r.set_aside.is_dir()
        assert not (state / CHECKPOINT_NAME).exists()
        assert fresh.tile_keys() == [] and fresh.frames == 0
        return
    for layer in (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS, Layer.LIMITING):
        np.testing.assert_array_equal(r.grid.read(layer), grid.read(layer))


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file())


def test_a_good_checkpoint_resumes(tmp_path, grid_and_checkpoint):
    mission, grid, folder = grid_and_checkpoint
    check_resume(tmp_path, mission, grid, folder, lambda f: None)


@SETTINGS
@given(data=st.data())
def test_damaged_checkpoints_are_set_aside(tmp_path, grid_and_checkpoint, data):
    mission, grid, folder = grid_and_checkpoint
    names = [p.relative_to(folder) for p in _files(folder)]
    name = data.draw(st.sampled_from(names))

    def damage(f: Path) -> None:
        (f / name).write_bytes(data.draw(mutated_bytes((f / name).read_bytes())))

    check_resume(tmp_path, mission, grid, folder, damage)


def _set_cell(layer: str, value) -> Callable[[Path], None]:
    def damage(f: Path) -> None:
        arr = zarr.open_group(str(f / "a" / "grid.zarr"), mode="a")[layer]
        rows, cols = np.nonzero(np.asarray(arr[...]) != arr.fill_value)
        arr[int(rows[0]), int(cols[0])] = value
    return damage


def _set_attr(key: str, value) -> Callable[[Path], None]:
    def damage(f: Path) -> None:
        zarr.open_group(str(f / "a" / "grid.zarr"), mode="a").attrs[key] = value
    return damage


def _write(name: str, text: bytes) -> Callable[[Path], None]:
    def damage(f: Path) -> None:
        (f / name).write_bytes(text)
    return damage


def _cut(name: str) -> Callable[[Path], None]:
    def damage(f: Path) -> None:
        path = f / name
        path.write_bytes(path.read_bytes()[:len(path.read_bytes()) // 2])
    return damage


BAD_CHECKPOINTS = {
    "log_miss_d NaN": _set_cell("log_miss_d", np.nan),
    "log_miss_d positive": _set_cell("log_miss_d", 0.5),
    "log_miss_fa inf": _set_cell("log_miss_fa", np.inf),
    "n_obs negative": _set_cell("n_obs", -3),
    "limiting code 9": _set_cell("limiting", 9),
    "x0_m not a number": _set_attr("x0_m", "west"),
    "cell_size_m zero": _set_attr("cell_size_m", 0.0),
    "frames negative": _set_attr("frames", -1),
    "store version": _set_attr("pdcov_grid", 7),
    "free space garbage": _set_attr("free_space_wkb", "0102ff"),
    "looks rule": _set_attr("looks", "correlated"),
    "tile size": _set_attr("tile_cells", 64),
    "meta.json garbage": _write("a/meta.json", b"{not json"),
    "meta.json gone": lambda f: (f / "a" / "meta.json").unlink(),
    "current names nothing": _write("current", b"c"),
    "current gone": lambda f: (f / "current").unlink(),
    "a chunk garbled": _write("a/grid.zarr/log_miss_d/c/0/0", b"\xff" * 64),
    "a chunk cut": _cut("a/grid.zarr/log_miss_d/c/0/0"),
    "array metadata garbage": _write("a/grid.zarr/n_obs/zarr.json", b"{"),
    "an array gone": lambda f: shutil.rmtree(f / "a" / "grid.zarr" / "n_obs"),
}


@pytest.mark.parametrize("damage", list(BAD_CHECKPOINTS))
def test_checkpoints_with_bad_values_are_set_aside(tmp_path, grid_and_checkpoint, damage):
    mission, grid, folder = grid_and_checkpoint
    assert (folder / "current").read_text() == "a"
    state = tmp_path / "state"
    state.mkdir()
    shutil.copytree(folder, state / CHECKPOINT_NAME)
    BAD_CHECKPOINTS[damage](state / CHECKPOINT_NAME)
    r = only_pdcov_errors(resume, state, "h", mission.new_mission_grid())
    assert r is not None and r.grid is None and r.set_aside is not None, r and r.message
    assert "set aside" in r.message and "it cannot be read" in r.message


def test_an_earlier_pdcovs_checkpoint_file_is_set_aside_not_lost(tmp_path, grid_and_checkpoint):
    mission, grid, _ = grid_and_checkpoint
    old = tmp_path / "checkpoint.npz"
    grid.save_npz(old)
    data = old.read_bytes()
    r = resume(tmp_path, "h", mission.new_mission_grid())
    assert r.grid is None and r.set_aside is not None and r.set_aside.read_bytes() == data
    assert "written by an earlier pdcov" in r.message and not old.exists()


# --- Zenoh payloads into the watcher ---------------------------------------------------------

@pytest.fixture(scope="module")
def payloads(grid_and_checkpoint):
    _, grid, _ = grid_and_checkpoint
    state = GridState.from_grid(grid)
    status = {"vehicle_id": "fuzz", "seq": 3, "uptime_s": 3.0, "thresholds": [0.5, 0.8],
              "proportion_at_or_above": {"0.5": 0.1, "0.8": 0.0}, "mean_pd": 0.1,
              "expected_false_alarms": 0.0, "cells_free": 900, "cells_observed": 10,
              "frames": {"used": 6, "skipped": {}, "pending": 0}, "link": {"state": "x"},
              "gimbal": {}, "pose": {"lat_deg": 47.4, "lon_deg": 8.5, "t_s": 1.0},
              "grid": {"hash": state.hash, "x0_m": 0.0, "y0_m": 0.0, "cell_size_m": 1.0,
                       "n_rows": 30, "n_cols": 30, "tile_size": 8, "origin": {}},
              "tiles_seq": 0, "faults": {}}
    return {"state": state, "tiles": encode_tiles(state, [(0, 0), (1, 2), (3, 3)], seq=1,
                                                  t_s=10.0, tile_size=8),
            "snapshot": encode_snapshot(grid), "status": encode_status(status)}


def watcher_with_grid(state: GridState) -> Watcher:
    w = Watcher()
    w.on_alive("fuzz", True, 0.0)
    w.on_snapshot("fuzz", state.copy(), 0.0)
    return w


def deliver(w: Watcher, kind: str, data: bytes) -> bool:
    """What the watcher's shell does with a payload: decode, then hand it over; a payload
    that does not decode is counted and dropped. True when it was applied."""
    decode = {"tiles": decode_tiles, "snapshot": decode_snapshot, "status": decode_status}
    try:
        value = decode[kind](data, f"pdcov/fuzz/{kind}")
    except BusPayloadError as exc:
        w.on_bad_payload("fuzz", exc)
        return False
    {"tiles": w.on_tiles, "snapshot": w.on_snapshot, "status": w.on_status}[kind](
        "fuzz", value, 1.0)
    return True


def grid_values(w: Watcher) -> tuple[np.ndarray, ...]:
    s = w.feeds["fuzz"].state
    return s.log_miss_d.copy(), s.log_miss_fa.copy(), s.n_obs.copy()


def grid_is_valid(w: Watcher) -> None:
    s = w.feeds["fuzz"].state
    if s is None:
        return
    for a in (s.log_miss_d, s.log_miss_fa):
        assert not np.isnan(a).any() and (a <= 0).all()
    assert (s.n_obs >= 0).all() and s.log_miss_d.shape == s.mask.shape


@pytest.mark.parametrize("kind", ["tiles", "snapshot", "status"])
@SETTINGS
@given(data=st.data())
def test_hostile_payloads_never_corrupt_the_watchers_grid(payloads, kind, data):
    w = watcher_with_grid(payloads["state"])
    before = grid_values(w)
    bad = data.draw(st.one_of(mutated_bytes(payloads[kind]), st.binary(max_size=600)))
    applied = deliver(w, kind, bad)
    grid_is_valid(w)
    if not applied:
        assert w.feeds["fuzz"].bad_payloads == 1
        for a, b in zip(before, grid_values(w), strict=True):
            np.testing.assert_array_equal(a, b)


@SETTINGS
@given(doc=st.dictionaries(st.sampled_from(("hash", "n_rows", "n_cols", "tile_size",
                                            "cell_size_m", "x0_m")),
                           st.sampled_from(HOSTILE[:12]), min_size=1))
def test_hostile_status_grid_fields(payloads, doc):
    status = json.loads(payloads["status"])
    status["grid"].update(doc)
    w = watcher_with_grid(payloads["state"])
    before = grid_values(w)
    try:
        data = json.dumps(status, allow_nan=True).encode()
    except ValueError:
        return
    deliver(w, "status", data)
    grid_is_valid(w)
    for a, b in zip(before, grid_values(w), strict=True):
        np.testing.assert_array_equal(a, b)  # a status never writes into the grid


def test_tiles_of_another_grid_or_a_wrong_shape_change_nothing(payloads):
    state = payloads["state"]
    w = watcher_with_grid(state)
    before = grid_values(w)
    other = GridState.empty(state.geometry, ~state.mask)  # another hash, same shape
    other.write(Layer.LOG_MISS_D, (0, state.geometry.n_rows, 0, state.geometry.n_cols), -1.0)
    deliver(w, "tiles", encode_tiles(other, [(0, 0)], seq=1, t_s=1.0, tile_size=8))
    for a, b in zip(before, grid_values(w), strict=True):
        np.testing.assert_array_equal(a, b)
    assert w.feeds["fuzz"].bad_payloads == 1



def _npy_with_header(header: str) -> bytes:
    """A version-1.0 .npy member whose header text is ``header`` (padded as numpy pads it),
    followed by enough bytes for the array a valid header would describe."""
    h = header.encode("latin1")
    h += b" " * (64 - (10 + len(h) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(h)) + h + bytes(8 * 30 * 30)


def _with_member(data: bytes, name: str, raw: bytes) -> bytes:
    src = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            dst.writestr(info, raw if info.filename == name else src.read(info))
    return out.getvalue()


def _garbled_deflate(data: bytes, name: str) -> bytes:
    """The zip with member ``name``'s compressed bytes overwritten with 0xff (an invalid
    deflate block type: zlib.error -3 while inflating; the zip headers stay valid)."""
    info = zipfile.ZipFile(io.BytesIO(data)).getinfo(name)
    b = bytearray(data)
    n_name, n_extra = struct.unpack("<HH", b[info.header_offset + 26:info.header_offset + 30])
    start = info.header_offset + 30 + n_name + n_extra
    b[start:start + info.compress_size] = b"\xff" * info.compress_size
    return bytes(b)


DAMAGED_MEMBERS = {
    # numpy's header parser: ast.literal_eval fails, its old-format fallback tokenizes
    "unclosed header (tokenize.TokenError)":
        "{'descr': '<f4', 'fortran_order': False, 'shape': (30,(, }",
    "indented header (IndentationError, a SyntaxError)": "x\n  y\n z",
    "huge shape (MemoryError)": "{'descr': '<f8', 'fortran_order': False, "
                                "'shape': (10000000000000,), }",
}


@pytest.mark.parametrize("damage", [*DAMAGED_MEMBERS, "deflate (zlib.error)"])
def test_found_damaged_snapshots_are_counted(payloads, damage):
    good = payloads["snapshot"]
    bad = (_garbled_deflate(good, "log_miss_d.npy") if damage.startswith("deflate")
           else _with_member(good, "log_miss_d.npy", _npy_with_header(DAMAGED_MEMBERS[damage])))
    w = watcher_with_grid(payloads["state"])
    before = grid_values(w)
    assert deliver(w, "snapshot", bad) is False
    assert w.feeds["fuzz"].bad_payloads == 1
    for a, b in zip(before, grid_values(w), strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_checkpoint_time_no_float_holds_is_set_aside(tmp_path, grid_and_checkpoint):
    """JSON reads integers exactly: 10**400 made math.isfinite raise OverflowError."""
    mission, grid, _ = grid_and_checkpoint
    path = tmp_path / "written" / CHECKPOINT_NAME
    write_checkpoint(path, grid, {"mission_hash": "h", "t0_s": 10**400, "last_frame_t_s": 1.0})
    check_resume(tmp_path, mission, grid, path, lambda f: None)
    assert not (tmp_path / "state" / CHECKPOINT_NAME).exists()
