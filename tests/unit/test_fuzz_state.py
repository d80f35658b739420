"""Fuzzing the grid's saved and published state (issue 15, bad input): checkpoints and the
Zenoh payloads a watcher receives (tiles, status, snapshots). A bad checkpoint is set aside,
never half loaded; a bad tile, status or snapshot never changes the watcher's grid. The
file readers: test_fuzz_files.py."""

from __future__ import annotations

import io
import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles
from pdcov.config.load import mission_from_dict
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
    """A mission grid that saw a few frames and its checkpoint's bytes."""
    d = tmp_path_factory.mktemp("ckpt")
    mission = mission_from_dict(MISSION, "m.yaml", d)
    grid = mission.new_mission_grid()
    R_down = np.diag([1.0, -1.0, -1.0])
    for k in range(6):
        grid.update(CameraPose(R_down, np.array([5.0 + 3 * k, 15.0, 12.0]), 2.0 * k))
    write_checkpoint(d / CHECKPOINT_NAME, grid, {"mission_hash": "h", "t0_s": 0.0,
                                                 "last_frame_t_s": 10.0})
    return mission, grid, (d / CHECKPOINT_NAME).read_bytes()


def _npz_with(data: bytes, name: str, value) -> bytes:
    """The checkpoint with one array replaced (a well-formed zip with a bad value)."""
    src = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            if info.filename == f"{name}.npy":
                buf = io.BytesIO()
                np.save(buf, value)
                dst.writestr(info.filename, buf.getvalue())
            else:
                dst.writestr(info, src.read(info))
    return out.getvalue()


def check_resume(tmp_path: Path, mission, grid, data: bytes) -> None:
    """Resume from ``data``: either the very grid that was saved, or a fresh start with the
    file set aside (kept, renamed) and nothing of it loaded."""
    state = tmp_path / "state"
    state.mkdir(exist_ok=True)
    for f in state.iterdir():
        f.unlink()
    (state / CHECKPOINT_NAME).write_bytes(data)
    fresh = mission.new_mission_grid()
    r = only_pdcov_errors(resume, state, "h", fresh)
    assert r is not None, "resume must not raise: a bad checkpoint is set aside"
    if r.grid is None:
        assert r.set_aside is not None and r.set_aside.read_bytes() == data
        assert not (state / CHECKPOINT_NAME).exists()
        assert not fresh.n_obs.any() and not fresh.log_miss_d.any()
        return
    for name in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(r.grid, name), getattr(grid, name))


def test_a_good_checkpoint_resumes(tmp_path, grid_and_checkpoint):
    mission, grid, data = grid_and_checkpoint
    check_resume(tmp_path, mission, grid, data)


@SETTINGS
@given(data=st.data())
def test_damaged_checkpoints_are_set_aside(tmp_path, grid_and_checkpoint, data):
    mission, grid, good = grid_and_checkpoint
    check_resume(tmp_path, mission, grid, data.draw(mutated_bytes(good)))


@pytest.mark.parametrize(("name", "value"), [
    ("log_miss_d", "nan"), ("log_miss_d", "positive"), ("log_miss_d", "shape"),
    ("log_miss_fa", "inf"), ("n_obs", "negative"), ("n_obs", "float"), ("mask", "shape"),
    ("x0_m", "nan"), ("cell_size_m", "zero"), ("frames", "negative"), ("version", "other"),
    ("pdcov_checkpoint.json", "garbage")])
def test_checkpoints_with_bad_values_are_set_aside(tmp_path, grid_and_checkpoint, name,
                                                   value):
    mission, grid, good = grid_and_checkpoint
    if name == "pdcov_checkpoint.json":
        src = zipfile.ZipFile(io.BytesIO(good))
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w") as dst:
            for info in src.infolist():
                dst.writestr(info, b"{not json" if info.filename == name else src.read(info))
        bad = out.getvalue()
    else:
        with np.load(io.BytesIO(good)) as z:
            a = z[name].copy()
        a = {"nan": lambda: np.where(a == a.flat[0], np.nan, a).astype(a.dtype),
             "positive": lambda: a + 1.0, "inf": lambda: np.full_like(a, np.inf),
             "shape": lambda: a[:-1], "negative": lambda: a - 100,
             "float": lambda: a.astype(float) + 0.5, "zero": lambda: a * 0,
             "other": lambda: a + 7}[value]()
        bad = _npz_with(good, name, a)
    state = tmp_path / "state"
    state.mkdir()
    (state / CHECKPOINT_NAME).write_bytes(bad)
    r = resume(state, "h", mission.new_mission_grid())
    assert r.grid is None and r.set_aside is not None, r.message


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
    other.log_miss_d[:] = -1.0
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
def test_found_damaged_checkpoints_are_set_aside(tmp_path, grid_and_checkpoint, damage):
    mission, grid, good = grid_and_checkpoint
    bad = (_garbled_deflate(good, "log_miss_d.npy") if damage.startswith("deflate")
           else _with_member(good, "log_miss_d.npy", _npy_with_header(DAMAGED_MEMBERS[damage])))
    check_resume(tmp_path, mission, grid, bad)
    assert (tmp_path / "state" / CHECKPOINT_NAME).exists() is False


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
    path = tmp_path / CHECKPOINT_NAME
    write_checkpoint(path, grid, {"mission_hash": "h", "t0_s": 10**400, "last_frame_t_s": 1.0})
    check_resume(tmp_path, mission, grid, path.read_bytes())
    assert not (tmp_path / "state" / CHECKPOINT_NAME).exists()
