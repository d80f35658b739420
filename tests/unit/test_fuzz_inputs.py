"""Fuzzing the file and payload readers (issue 15, bad input): mission YAML, camera_info,
detector YAML, pose CSV, .plan / WPL, checkpoints, and the Zenoh payloads a watcher receives.
Every bad input gets a PdcovError (a clear message, exit 2 at the CLI), never another
exception; a bad checkpoint is set aside, never half loaded; a bad tile, status or snapshot
never changes the watcher's grid."""

from __future__ import annotations

import copy
import io
import json
import math
import os
import re
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles
from pdcov.config.load import load_mission, mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.geodesy import Origin
from pdcov.core.pose import CameraPose
from pdcov.errors import PdcovError
from pdcov.ground.watcher import Watcher
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import read_mission, write_plan
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
from pdcov.telemetry.pose_csv import read_pose_csv
from tests.support.link_feed import MISSION

EXAMPLES = int(os.environ.get("PDCOV_FUZZ_EXAMPLES", "25"))
SETTINGS = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])
HOSTILE = (None, "", "x" * 300, -1, 0, 1e308, -1e308, math.nan, math.inf, True, [], {},
           [[]], {"a": 1}, [1, 2, 3], 2**64, "0", "nan", ".inf")


# --- mutations ------------------------------------------------------------------------------

def _paths(doc, prefix=()):
    """Every path (tuple of keys / indices) to a node of a JSON-like document."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated_doc(draw, doc):
    """``doc`` with a few nodes replaced by hostile values or deleted."""
    out = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p in _paths(out) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = out
        for k in path[:-1]:
            parent = parent[k]
        if draw(st.booleans()) and isinstance(parent, dict):
            del parent[path[-1]]
        else:
            # A copy: a later mutation may write into it, and HOSTILE's lists and mappings
            # are shared by every example (writing into them made cyclic documents).
            parent[path[-1]] = copy.deepcopy(draw(st.one_of(
                st.sampled_from(HOSTILE), st.floats(), st.integers(), st.text(max_size=20))))
    return out


@st.composite
def mutated_bytes(draw, data: bytes):
    """``data`` truncated, with bytes flipped, deleted or inserted."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(("flip", "cut", "insert", "truncate")))
        i = draw(st.integers(0, max(0, len(b) - 1)))
        if op == "flip" and b:
            b[i] ^= draw(st.integers(1, 255))
        elif op == "cut":
            del b[i:i + draw(st.integers(1, 16))]
        elif op == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=16))
        else:
            del b[i:]
    return bytes(b)


def only_pdcov_errors(read, *args) -> object | None:
    """Call the reader: a value, or None when it raised a PdcovError with a message. Any
    other exception fails the test (it would reach the user as a traceback)."""
    try:
        return read(*args)
    except PdcovError as exc:
        assert str(exc).strip(), "an error without a message"
        return None


# --- file readers ---------------------------------------------------------------------------

CAMERA_INFO = {"image_width": 640, "image_height": 480,
               "camera_matrix": {"rows": 3, "cols": 3,
                                 "data": [480.0, 0, 319.5, 0, 480.0, 239.5, 0, 0, 1]},
               "distortion_model": "plumb_bob",
               "distortion_coefficients": {"rows": 1, "cols": 5,
                                           "data": [-0.05, 0.01, 0, 0, 0]}}
DETECTOR = yaml.safe_load(DetectorModel.illustrative().to_yaml())


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, bytes]:
    """The valid files every mutation starts from."""
    d = tmp_path_factory.mktemp("valid")
    plan = Plan((Waypoint(0.0, 0.0, 10.0, 5.0), Waypoint(0.0, 20.0, 10.0, 5.0, 3.0),
                 Waypoint(10.0, 20.0, 12.0, 3.5)))
    origin = Origin(47.39, 8.54, 488.0)
    write_plan(d / "p.plan", plan, origin)
    write_plan(d / "p.waypoints", plan, origin)
    poses = "t_s,x_m,y_m,z_m,qw,qx,qy,qz\n" + "".join(
        f"{t},{t},2.0,10.0,0.0,1.0,0.0,0.0\n" for t in range(5))
    return {"plan": (d / "p.plan").read_bytes(), "wpl": (d / "p.waypoints").read_bytes(),
            "poses": poses.encode(), "mission": yaml.safe_dump(MISSION).encode(),
            "camera_info": yaml.safe_dump(CAMERA_INFO).encode(),
            "detector": yaml.safe_dump(DETECTOR).encode()}


READERS = {"mission": load_mission, "camera_info": CameraModel.from_camera_info,
           "detector": DetectorModel.from_yaml, "poses": read_pose_csv, "plan": read_mission,
           "wpl": read_mission}
SUFFIX = {"plan": ".plan", "wpl": ".waypoints", "poses": ".csv"}


def read_file(tmp_path: Path, kind: str, data: bytes):
    path = tmp_path / f"input{SUFFIX.get(kind, '.yaml')}"
    path.write_bytes(data)
    return only_pdcov_errors(READERS[kind], path)


@pytest.mark.parametrize("kind", sorted(READERS))
def test_the_valid_files_read(tmp_path, files, kind):
    assert read_file(tmp_path, kind, files[kind]) is not None


@pytest.mark.parametrize("kind", sorted(READERS))
@SETTINGS
@given(data=st.data())
def test_damaged_files_give_a_pdcov_error(tmp_path, files, kind, data):
    read_file(tmp_path, kind, data.draw(mutated_bytes(files[kind])))


@pytest.mark.parametrize("kind", sorted(READERS))
@SETTINGS
@given(blob=st.binary(max_size=2000))
def test_random_bytes_give_a_pdcov_error(tmp_path, kind, blob):
    read_file(tmp_path, kind, blob)


@pytest.mark.parametrize("kind", ["mission", "camera_info", "detector", "plan"])
@SETTINGS
@given(data=st.data())
def test_hostile_values_give_a_pdcov_error(tmp_path, files, kind, data):
    doc = json.loads(files[kind]) if kind == "plan" else yaml.safe_load(files[kind])
    bad = data.draw(mutated_doc(doc))
    text = json.dumps(bad) if kind == "plan" else yaml.safe_dump(bad)
    read_file(tmp_path, kind, text.encode())


@SETTINGS
@given(data=st.data())
def test_hostile_mission_documents_in_memory(tmp_path, data):
    """mission_from_dict directly (the daemon's and every command's config path)."""
    only_pdcov_errors(mission_from_dict, data.draw(mutated_doc(MISSION)), "m.yaml", tmp_path)


def test_a_bad_file_is_exit_2_without_a_traceback(tmp_path, files, capsys):
    from pdcov.cli import main
    (tmp_path / "m.yaml").write_bytes(files["mission"][:-40] + b"\x00\xff: [")
    (tmp_path / "p.csv").write_bytes(b"t_s,x_m\n1,2\n")
    assert main(["evaluate", "--config", str(tmp_path / "m.yaml"), "--poses",
                 str(tmp_path / "p.csv"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "m.yaml" in err


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


# --- inputs the 500-example run found (docs: PDCOV_FUZZ_EXAMPLES=500), kept as plain cases ----

@pytest.mark.parametrize(("section", "key", "value", "message"), [
    ("camera", "K", [[], [0, 480, 239.5], [0, 0, 1]],
     "camera.K: expected 3 rows of 3 numbers, row 1 has 0"),  # numpy ValueError before
    ("camera", "K", [[480, 0, 319.5], [0, 480, 239.5, 7], [0, 0, 1]],
     "camera.K: expected 3 rows of 3 numbers, row 2 has 4"),
    ("camera", "distortion_model", [], "distortion_model: expected one of"),  # TypeError
    ("camera", "distortion_model", {"a": 1}, "distortion_model: expected one of"),
    # Integers no float holds (YAML reads them exactly): OverflowError in math.isfinite.
    ("camera", "K", [[10**400, 0, 319.5], [0, 480, 239.5], [0, 0, 1]], "camera.K: a number"),
    ("origin", "lat_deg", 10**400, "origin.lat_deg: expected a finite number"),
    ("mount", "lever_arm_frd_m", [0, 0, -10**400], "mount.lever_arm_frd_m: expected"),
    # Cells so small that the cell count has no float quotient (OverflowError before), or
    # that the domain's width in cells is infinite.
    ("domain", "cell_size_m", 1.8e-274, "= 10^550 cells, more memory than any machine has"),
    ("domain", "cell_size_m", 5e-324, "too small for a 30 x 30 m domain"),
], ids=["K-empty-row", "K-long-row", "model-list", "model-mapping", "K-huge-int",
        "lat-huge-int", "lever-arm-huge-int", "cell-1e-274", "cell-denormal"])
def test_found_mission_values_give_a_pdcov_error(tmp_path, section, key, value, message):
    doc = copy.deepcopy(MISSION)
    if section == "mount":
        doc["mount"] = {"type": "fixed"}
    doc[section][key] = value
    for read in (lambda: mission_from_dict(doc, "m.yaml", tmp_path),
                 lambda: load_mission(_written(tmp_path / "m.yaml", yaml.safe_dump(doc)))):
        with pytest.raises(PdcovError, match=re.escape(message)):
            read()


def _written(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


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


@pytest.mark.parametrize("text", ["origin: {lat_deg: " + "1" * 5000 + "}\n",  # ValueError
                                  "camera: " + "[" * 5000 + "]" * 5000 + "\n"])
def test_yaml_that_python_cannot_build_gives_a_pdcov_error(tmp_path, text):
    with pytest.raises(PdcovError, match="m.yaml: not valid YAML"):
        load_mission(_written(tmp_path / "m.yaml", text))
