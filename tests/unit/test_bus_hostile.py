"""Hostile payloads against the bus decoders (issue 23): every field the watcher and the web
map read is validated before use, non-finite numbers are refused in every JSON payload,
and each bound (payload bytes, thresholds, cells per grid) is refused before anything large
is allocated, with a BusPayloadError naming the key, the field and a countable reason."""

from __future__ import annotations

import copy
import functools
import io
import json
import math
import struct
import tracemalloc
import zipfile
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pdcov.bus import grid_state, tiles
from pdcov.bus.errors import BusPayloadError, Refusal
from pdcov.bus.footprint import decode_footprint, encode_footprint
from pdcov.bus.grid_state import MAX_CELLS, decode_snapshot
from pdcov.bus.json_doc import finite_or_null
from pdcov.bus.mission import decode_mission, encode_mission
from pdcov.bus.status import MAX_STATUS_BYTES, MAX_THRESHOLDS, decode_status
from pdcov.bus.tiles import MAX_TILES_BYTES, decode_tiles
from pdcov.ground.watcher import Watcher
from pdcov.ground.web import map_state
from tests.support.watch_fixtures import TinyPublisher

KEY = "pdcov/uav1/status"


@functools.cache
def _good_status_bytes() -> bytes:
    pub = TinyPublisher("uav1")
    pub.step(3)
    return pub.status()


def good_status() -> dict:
    """A status as the stand-in publisher sends it, after a few frames (a fresh copy)."""
    return json.loads(_good_status_bytes())


def with_field(doc: dict, path: str, value) -> dict:
    """``doc`` with the field at dotted ``path`` set to ``value``."""
    out = copy.deepcopy(doc)
    *head, last = path.split(".")
    node = out
    for k in head:
        node = node[k]
    node[last] = value
    return out


def refused(payload: bytes, decoder=decode_status, key=KEY) -> BusPayloadError:
    with pytest.raises(BusPayloadError) as err:
        decoder(payload, key)
    assert key in str(err.value)
    return err.value


def test_the_good_status_decodes():
    doc = decode_status(json.dumps(good_status()).encode(), KEY, "uav1")
    assert doc["vehicle_id"] == "uav1"


@pytest.mark.parametrize("path, value, named", [
    # The red team's: each made `pdcov watch` exit with a ValueError.
    ("proportion_at_or_above", {"abc": 0.5}, "proportion_at_or_above.abc"),
    ("thresholds", ["x"], "thresholds[0]"),
    # The other fields the watcher and the web map read, with the wrong type or range.
    ("thresholds", [], "thresholds"),
    ("thresholds", [1.5], "thresholds[0]"),
    ("proportion_at_or_above", {"0.8": "1"}, "proportion_at_or_above.0.8"),
    ("proportion_at_or_above", {"0.3": 0.5}, "proportion_at_or_above.0.3"),
    ("mean_pd", "0.5", "mean_pd"),
    ("mean_pd", 2.0, "mean_pd"),
    ("seq", True, "seq"),
    ("uptime_s", "1", "uptime_s"),
    ("uptime_s", -1.0, "uptime_s"),
    ("t_s", "now", "t_s"),
    ("cells_free", 10**9, "cells_free"),
    ("cells_observed", 10**9, "cells_observed"),
    ("frames", [], "frames"),
    ("frames.used", "3", "frames.used"),
    ("frames.used", -1, "frames.used"),
    ("frames.used", 2**32, "frames.used"),
    ("frames.grid", 1.5, "frames.grid"),
    ("frames.skipped", 3, "frames.skipped"),
    ("frames.skipped", {"stale": "x"}, "frames.skipped.stale"),
    ("link", "up", "link"),
    ("link.state", 5, "link.state"),
    ("link.state", "x" * 1000, "link.state"),
    ("pose", [1, 2], "pose"),
    ("pose.lat_deg", "39.3", "pose.lat_deg"),
    ("pose.lat_deg", 91.0, "pose.lat_deg"),
    ("pose.lon_deg", None, "pose.lon_deg"),
    ("pose.alt_msl_m", "15", "pose.alt_msl_m"),
    ("pose.t_s", [], "pose.t_s"),
    ("gimbal", None, "gimbal"),
    ("gimbal.describe", {}, "gimbal.describe"),
    ("grid", 5, "grid"),
    ("grid.hash", "XYZ", "grid.hash"),
    ("grid.n_rows", 0, "grid.n_rows"),
    ("grid.cell_size_m", 0, "grid.cell_size_m"),
    ("grid.x0_m", 1e300, "grid.x0_m"),
    ("grid.tile_size", 10**6, "grid.tile_size"),
    ("grid.origin", "here", "grid.origin"),
    ("grid.origin.lat_deg", "x", "grid.origin.lat_deg"),
    ("grid.origin.ground_alt_msl_m", "x", "grid.origin.ground_alt_msl_m"),
    ("tiles_seq", "1", "tiles_seq"),
    ("tiles_seq", 1.5, "tiles_seq"),
    ("tiles_seq", -2, "tiles_seq"),
    ("faults", {"x": -1}, "faults.x"),
    ("checkpoint", 5, "checkpoint"),
    ("full", "yes", "full"),
    ("vehicle_id", "uav1/../x", "vehicle_id"),
])
def test_every_field_read_is_validated(path, value, named):
    err = refused(json.dumps(with_field(good_status(), path, value)).encode())
    assert f"{named}:" in str(err), str(err)
    assert err.reason is Refusal.BAD_FIELD


@pytest.mark.parametrize("text", ["Infinity", "-Infinity", "NaN", "1e400"])
@pytest.mark.parametrize("path", ["mean_pd", "grid.x0_m", "pose.lat_deg", "link.messages"])
def test_non_finite_numbers_are_refused_naming_the_field(text, path):
    payload = json.dumps(with_field(good_status(), path, "@@")).replace('"@@"', text)
    err = refused(payload.encode())
    assert f"{path}: a non-finite number" in str(err) and err.reason is Refusal.NON_FINITE


def test_status_bounds():
    doc = good_status()
    many = [round(i / 100, 2) for i in range(MAX_THRESHOLDS + 1)]
    err = refused(json.dumps({**doc, "thresholds": many}).encode())
    assert f"more than {MAX_THRESHOLDS}" in str(err) and err.reason is Refusal.OVER_BOUND
    err = refused(json.dumps({**doc, "pad": "x" * MAX_STATUS_BYTES}).encode())
    assert err.reason is Refusal.TOO_LARGE
    grid = {**doc["grid"], "n_rows": 70_000, "n_cols": 70_000}  # 4.9e9 cells > 2**32
    err = refused(json.dumps({**doc, "grid": grid}).encode())
    assert "MAX_GRID_CELLS" in str(err) and err.reason is Refusal.OVER_BOUND


def test_the_vehicle_id_must_be_the_keys():
    err = refused(json.dumps(good_status()).encode(), lambda p, k: decode_status(p, k, "uav2"))
    assert "vehicle 'uav2'" in str(err)


# Any JSON value (non-finite floats included) in any field: either refused, or the watcher
# and the web map take the status without an exception and the page's JSON stays strict.
JSON = st.recursive(st.none() | st.booleans() | st.integers(-2**70, 2**70)
                    | st.floats(allow_nan=True) | st.text(max_size=8),
                    lambda kids: st.lists(kids, max_size=3)
                    | st.dictionaries(st.text(max_size=5), kids, max_size=3), max_leaves=6)
PATHS = ["seq", "uptime_s", "t_s", "thresholds", "proportion_at_or_above", "mean_pd",
         "cells_free", "frames", "frames.used", "frames.skipped", "link", "link.state",
         "pose", "pose.lat_deg", "pose.t_s", "grid.origin", "grid.origin.lat_deg",
         "tiles_seq", "faults", "full"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(PATHS), JSON)
def test_a_status_that_decodes_never_breaks_the_watcher(path, value):
    payload = json.dumps(with_field(good_status(), path, value)).encode()
    try:
        doc = decode_status(payload, KEY)
    except BusPayloadError:
        return
    w = Watcher()
    w.on_status("uav1", doc, 0.0)
    w.on_status("uav1", doc, 1.0)
    report = w.report(2.0)
    json.loads(json.dumps(finite_or_null(map_state(w, report, None, 1, None)),
                          allow_nan=False), parse_constant=_no_constant)


def _no_constant(name):
    raise AssertionError(f"{name} in the page's JSON")


# -- tiles ----------------------------------------------------------------------------

def tiles_payload(**header) -> bytes:
    pub = TinyPublisher("uav1")
    pub.step(3)
    payload = pub.tiles()
    assert payload is not None
    fields = dict(zip(("magic", "version", "flags", "seq", "ghash", "t_s", "frames",
                       "tile_size", "n_tiles", "n_rows", "n_cols"),
                      struct.unpack_from("<4sHHQ8sdIHHII", payload), strict=True))
    fields.update(header)
    return struct.pack("<4sHHQ8sdIHHII", *fields.values()) + payload[48:]


def test_tiles_bounds_and_finite_time():
    decode_tiles(tiles_payload(), "pdcov/uav1/tiles")
    err = refused(tiles_payload(n_rows=70_000, n_cols=70_000), decode_tiles,
                  "pdcov/uav1/tiles")
    assert "MAX_GRID_CELLS" in str(err) and err.reason is Refusal.OVER_BOUND
    for t in (math.nan, math.inf):
        err = refused(tiles_payload(t_s=t), decode_tiles, "pdcov/uav1/tiles")
        assert "t_s" in str(err) and err.reason is Refusal.NON_FINITE
    err = refused(tiles_payload() + bytes(MAX_TILES_BYTES), decode_tiles, "pdcov/uav1/tiles")
    assert err.reason is Refusal.TOO_LARGE


def test_a_tiles_bomb_declaring_a_huge_grid_inflates_nothing():
    """A few bytes declaring a 4.9e9-cell grid: refused from the header, zlib never runs."""
    header = struct.pack("<4sHHQ8sdIHHII", b"PDTL", 1, 0, 1, bytes(8), 0.0, 1, 1024, 24,
                         70_000, 70_000)
    body = zlib.compress(bytes(24 * (4 + 14 * 1024 * 1024)))  # ~340 MB inflated
    tracemalloc.start()
    try:
        err = refused(header + body, decode_tiles, "pdcov/uav1/tiles")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert err.reason is Refusal.OVER_BOUND and peak < 2 * len(body) + (1 << 20)


# -- snapshot -------------------------------------------------------------------------

def lying_snapshot(n_rows: int, n_cols: int) -> bytes:
    """A grid.npz of an n_rows x n_cols empty grid written member by member (never whole
    in memory): the red team's 0.3 MB snapshot of 25 M cells."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, dtype in (("mask", "|b1"), ("log_miss_d", "<f4"), ("log_miss_fa", "<f4"),
                            ("n_obs", "<i4")):
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array_header_1_0(
                    fh, {"descr": dtype, "fortran_order": False, "shape": (n_rows, n_cols)})
                chunk = bytes(np.dtype(dtype).itemsize * n_cols * 100)
                for _ in range(n_rows // 100):
                    fh.write(chunk)
        for name, value in (("version", 2), ("x0_m", 0.0), ("y0_m", 0.0),
                            ("cell_size_m", 1.0), ("frames", 0)):
            a = io.BytesIO()
            np.save(a, np.array(value))
            zf.writestr(f"{name}.npy", a.getvalue())
    return buf.getvalue()


def test_a_small_snapshot_of_a_huge_grid_is_refused_before_allocating():
    payload = lying_snapshot(5000, 5000)
    assert len(payload) < 1_000_000
    tracemalloc.start()
    try:
        err = refused(payload, decode_snapshot, "pdcov/uav1/snapshot")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "MAX_CELLS" in str(err) and err.reason is Refusal.OVER_BOUND
    assert peak < 4 * len(payload) + (4 << 20), peak  # the 25 M cells were never read
    state = decode_snapshot(lying_snapshot(200, 300))  # the same writer, in bounds
    assert state.geometry.shape == (200, 300) and MAX_CELLS >= 16_000_000


def test_snapshot_bytes_and_scalars(monkeypatch):
    pub = TinyPublisher("uav1")
    payload = pub.snapshot()
    decode_snapshot(payload)
    monkeypatch.setattr(grid_state, "MAX_SNAPSHOT_BYTES", len(payload) - 1)
    assert refused(payload, decode_snapshot, "snap").reason is Refusal.TOO_LARGE
    monkeypatch.undo()
    arrays = dict(np.load(io.BytesIO(payload)))
    for name, value in (("frames", np.float64(np.nan)), ("frames", np.int64(-1)),
                        ("version", np.array([2, 2])), ("x0_m", np.float64(np.inf))):
        buf = io.BytesIO()
        np.savez_compressed(buf, **{**arrays, name: value})
        assert name in str(refused(buf.getvalue(), decode_snapshot, "snap"))


def test_tiles_constant_is_the_one_documented():
    assert tiles.MAX_TILES_BYTES == 4 << 20


# -- footprint and mission ------------------------------------------------------------

def test_footprint_fields():
    ring = np.array([[149.1, -35.3], [149.2, -35.3], [149.2, -35.2]])
    good = json.loads(encode_footprint("uav1", 1.0, ring))
    key = "pdcov/uav1/footprint"
    for geometry in ([1, 2], {"type": "Polygon", "coordinates": "x"},
                     {"type": "Polygon", "coordinates": [[[1, 2]] * 3]}):
        err = refused(json.dumps({**good, "geometry": geometry}).encode(), decode_footprint,
                      key)
        assert "geometry" in str(err)
    many = {"type": "Polygon", "coordinates": [[[149.1, -35.3]] * 10_001]}
    err = refused(json.dumps({**good, "geometry": many}).encode(), decode_footprint, key)
    assert err.reason is Refusal.OVER_BOUND
    props = with_field(good, "properties.t_s", "@@")
    err = refused(json.dumps(props).replace('"@@"', "Infinity").encode(), decode_footprint,
                  key)
    assert "properties.t_s" in str(err) and err.reason is Refusal.NON_FINITE


def test_mission_thresholds_bound_is_the_statuses():
    pub = TinyPublisher("uav1")
    m, g = pub.mission, pub.grid
    payload = encode_mission("uav1", m.origin(), m.domain, g.geometry,
                             grid_state.grid_hash(g.geometry, g.mask), ground_alt_known=True,
                             thresholds=[0.5] * (MAX_THRESHOLDS + 1), target_pd=0.5)
    err = refused(payload, decode_mission, "pdcov/uav1/mission")
    assert f"1..{MAX_THRESHOLDS}" in str(err)


def test_shares_at_many_thresholds_are_the_daemons_and_computed_once():
    """64 thresholds (the bound) cost one P_D computation of the grid, and give the
    daemon's own figures."""
    pub = TinyPublisher("uav1")
    pub.step(12)
    state = grid_state.GridState.from_grid(pub.grid)
    thresholds = [round((i + 1) / (MAX_THRESHOLDS + 1), 4) for i in range(MAX_THRESHOLDS)]
    shares = state.proportions_at_or_above(thresholds)
    assert shares == pub.grid.metrics(thresholds).proportion_at_or_above
    assert shares == {t: state.proportion_at_or_above(t) for t in thresholds}
    assert 0 < shares[thresholds[0]] and shares[thresholds[0]] > shares[thresholds[-1]]
