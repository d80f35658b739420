"""The Zenoh protocol's payloads (pdcov.bus): round trips that reproduce the daemon's grid
exactly, and hostile payloads that give BusPayloadError and change nothing."""

from __future__ import annotations

import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.footprint import decode_footprint, encode_footprint
from pdcov.bus.frames import decode_frames, encode_frames
from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot, grid_hash
from pdcov.bus.json_doc import finite_or_null
from pdcov.bus.keys import VehicleKeys, all_vehicles, parse_key
from pdcov.bus.mission import decode_mission, encode_mission
from pdcov.bus.session import (
    BusConfig,
    bus_config_from_dict,
    describe_session,
    peer_warning,
    quiet_hint,
    resolve_mode,
    session_mode,
    zenoh_config,
)
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiles import apply_tiles, decode_tiles, encode_tiles
from pdcov.config.load import load_mission
from pdcov.core.detections import FrameBoxes
from pdcov.core.domain import GridGeometry
from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.pose import CameraPose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.errors import ConfigError

DEMO = str(Path(__file__).resolve().parents[2] / "service/pdcov/data/demo_mission.yaml")


@pytest.fixture(scope="module")
def grid():
    """The demo mission's grid after a few nadir frames."""
    mission = load_mission(DEMO)
    g = mission.new_mission_grid()
    R_enu_cam = np.diag([1.0, -1.0, -1.0])  # optical axis down, image x east
    for k in range(12):
        g.update(CameraPose(R_enu_cam @ R_from_euler_zyx(0.02 * k, 0, 0),
                            np.array([-50.0 + 2 * k, -40.0, 12.0]), 1.1 * k))
    return g


def random_state(rng, shape=(70, 45)) -> GridState:
    geometry = GridGeometry(-3.0, 7.5, 0.5, *shape)
    mask = rng.random(shape) > 0.1
    return GridState.from_arrays(
        geometry, mask, -rng.exponential(1.0, shape).astype(np.float32) * mask,
        -rng.exponential(0.1, shape).astype(np.float32) * mask,
        rng.integers(0, 50, shape) * mask, 1234,
        rng.integers(0, len(LimitingFactor), shape) * mask)


def test_keys():
    keys = VehicleKeys("uav-1_a")
    assert keys.status == "pdcov/uav-1_a/status"
    assert parse_key(keys.tiles) == ("uav-1_a", "tiles")
    assert all_vehicles("alive") == "pdcov/*/alive"
    for bad in ("a/b", "*", "uav 1", ""):
        with pytest.raises(ValueError):
            VehicleKeys(bad)
    with pytest.raises(BusPayloadError):
        parse_key("pdcov/uav1/other")


def test_snapshot_bytes_are_the_npz_evaluate_writes(grid, tmp_path):
    payload = encode_snapshot(grid)
    grid.save_npz(tmp_path / "grid.npz")
    with np.load(io.BytesIO(payload)) as z, np.load(tmp_path / "grid.npz") as f:
        assert sorted(z.files) == sorted(f.files)
        for k in z.files:
            np.testing.assert_array_equal(z[k], f[k])
    state = decode_snapshot(payload)
    np.testing.assert_array_equal(state.log_miss_d, grid.log_miss_d)
    np.testing.assert_array_equal(state.log_miss_fa, grid.log_miss_fa)
    np.testing.assert_array_equal(state.n_obs, grid.n_obs)
    np.testing.assert_array_equal(state.pd, grid.pd)
    assert state.frames == grid.frames == 12
    assert state.hash == grid_hash(grid.geometry, grid.mask)


def test_tiles_rebuild_the_grid_exactly():
    rng = np.random.default_rng(1)
    src = random_state(rng)
    dst = GridState.empty(src.geometry, src.mask)
    all_tiles = [(r, c) for r in range(3) for c in range(2)]  # 70 x 45 in 32-cell tiles
    # Two messages, one tile in both: applying is idempotent and order within seq is free.
    for seq, ids in enumerate((all_tiles[:4], all_tiles[3:])):
        update = decode_tiles(encode_tiles(src, ids, seq=seq, t_s=10.0 + seq, tile_size=32))
        assert update.seq == seq and len(update.tiles) == len(ids)
        apply_tiles(dst, update)
    np.testing.assert_array_equal(dst.log_miss_d, src.log_miss_d)
    np.testing.assert_array_equal(dst.log_miss_fa, src.log_miss_fa)
    np.testing.assert_array_equal(dst.n_obs, src.n_obs)
    assert dst.frames == 1234
    t = update.tiles[0]
    np.testing.assert_allclose(t.pd_q / 65535.0, src.pd[64:70, 32:45] if t.tile_row == 2
                               else t.pd_q / 65535.0, atol=1 / 65535)


def test_tiles_for_another_grid_change_nothing():
    rng = np.random.default_rng(2)
    src = random_state(rng)
    other = GridState.empty(GridGeometry(-3.0, 7.5, 0.5, 70, 45), ~src.mask)
    update = decode_tiles(encode_tiles(src, [(0, 0)], seq=0, t_s=0.0, tile_size=32))
    with pytest.raises(BusPayloadError, match="fetch the snapshot"):
        apply_tiles(other, update)
    assert not other.n_obs.any()


def _header_fields(payload: bytes) -> list:
    return list(struct.unpack_from("<4sHHQ8sdIHHII", payload))


def _with_header(payload: bytes, **change) -> bytes:
    names = ["magic", "version", "flags", "seq", "hash", "t_s", "frames", "tile_size",
             "n_tiles", "n_rows", "n_cols"]
    fields = _header_fields(payload)
    for k, v in change.items():
        fields[names.index(k)] = v
    return struct.pack("<4sHHQ8sdIHHII", *fields) + payload[48:]


def test_hostile_tiles_are_refused():
    rng = np.random.default_rng(3)
    src = random_state(rng)
    good = encode_tiles(src, [(0, 0), (1, 1)], seq=7, t_s=1.0, tile_size=32)
    cases = {
        "magic": _with_header(good, magic=b"XXXX"),
        "version": _with_header(good, version=3),
        "outside": _with_header(good, n_rows=20),
        "count": _with_header(good, n_tiles=3),
        "truncated": good[:-5],
        "trailing": good + b"\x00",
        "short": good[:20],
        "bomb": good[:48] + zlib.compress(b"\x00" * (40 << 20)),
    }
    nan = src.copy()
    nan.write(Layer.LOG_MISS_D, (0, 1, 0, 1), np.nan)
    cases["nan"] = encode_tiles(nan, [(0, 0)], seq=0, t_s=0.0, tile_size=32)
    pos = GridState.from_arrays(src.geometry, src.mask, np.abs(src.log_miss_d) + 1,
                                src.log_miss_fa, src.n_obs, limiting=src.limiting)
    cases["positive"] = encode_tiles(pos, [(0, 0)], seq=0, t_s=0.0, tile_size=32)
    for name, payload in cases.items():
        with pytest.raises(BusPayloadError, match="tiles"):
            decode_tiles(payload)
        assert name  # every case raised


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 200))
def test_random_bytes_never_crash_a_decoder(junk, cut):
    rng = np.random.default_rng(4)
    good = encode_tiles(random_state(rng, (20, 20)), [(0, 0)], seq=1, t_s=0.0, tile_size=8)
    for payload in (junk, good[:cut] + junk, good[:48] + junk):
        for decode in (decode_tiles, decode_snapshot, decode_status, decode_footprint,
                       decode_frames):
            try:
                decode(payload)
            except BusPayloadError:
                pass


def test_hostile_snapshots_are_refused(grid):
    good = encode_snapshot(grid)
    with np.load(io.BytesIO(good)) as z:
        arrays = {k: z[k] for k in z.files}

    def npz(**change) -> bytes:
        buf = io.BytesIO()
        np.savez(buf, **{**arrays, **change})
        return buf.getvalue()

    for payload in (b"PK\x03\x04junk", npz(version=99), npz(n_obs=arrays["n_obs"][:3]),
                    npz(log_miss_d=np.ones_like(arrays["log_miss_d"])),
                    npz(cell_size_m=-1.0), npz(mask=np.zeros((0, 0), bool)),
                    npz(log_miss_d=np.array(["x"] * arrays["mask"].size).reshape(
                        arrays["mask"].shape))):
        with pytest.raises(BusPayloadError, match="snapshot"):
            decode_snapshot(payload)
    del arrays["log_miss_fa"]
    with pytest.raises(BusPayloadError, match="missing log_miss_fa"):
        decode_snapshot(npz())


STATUS_FIELDS = {"vehicle_id": "uav1", "seq": 3, "uptime_s": 1.5, "thresholds": [0.5],
                 "proportion_at_or_above": {"0.5": 0.25}, "mean_pd": 0.1,
                 "expected_false_alarms": 0.5, "cells_free": 10, "cells_observed": 4,
                 "frames": {"used": 3, "skipped": {}}, "link": {"age_s": float("nan")},
                 "gimbal": {},
                 "grid": {"hash": "0123456789abcdef", "x0_m": 0.0, "y0_m": 0.0,
                          "cell_size_m": 1.0, "n_rows": 4, "n_cols": 5, "tile_size": 32,
                          "origin": {}},
                 "tiles_seq": 0, "faults": {}}


def test_status_round_trip_and_validation():
    fields = STATUS_FIELDS
    doc = decode_status(encode_status(fields))
    assert doc["version"] == 1 and doc["link"]["age_s"] is None
    for change in ({"seq": "3"}, {"proportion_at_or_above": {"0.5": 2}},
                   {"grid": {**fields["grid"], "n_rows": 0}}):
        with pytest.raises(BusPayloadError, match="status"):
            decode_status(encode_status({**fields, **change}))
    with pytest.raises(BusPayloadError, match="version"):
        decode_status(json.dumps(finite_or_null(
            {**fields, "schema": "pdcov.status", "version": 9})).encode())


def test_footprint_and_frames():
    ring = np.array([[149.1, -35.3], [149.2, -35.3], [149.2, -35.2]])
    doc = decode_footprint(encode_footprint("uav1", 12.5, ring))
    coords = doc["geometry"]["coordinates"][0]
    assert coords[0] == coords[-1] and len(coords) == 4
    assert decode_footprint(encode_footprint("uav1", 1.0, None))["geometry"] is None
    with pytest.raises(BusPayloadError):
        decode_footprint(encode_footprint("uav1", 1.0, ring * [1, 10]))  # latitude 353
    assert decode_frames(encode_frames([1.0, 1.5])) == (FrameBoxes(1.0), FrameBoxes(1.5))
    for bad in ([], [-1.0], [float("inf")]):
        with pytest.raises(BusPayloadError, match="frames"):
            decode_frames(json.dumps({"schema": "pdcov.frames", "version": 1,
                                      "t_boot_s": bad}).encode())


def json_payloads() -> dict[str, tuple]:
    """Each JSON payload kind: its decoder and a good payload."""
    mission = load_mission(DEMO)
    g = mission.new_mission_grid()
    ring = np.array([[149.1, -35.3], [149.2, -35.3], [149.2, -35.2]])
    return {
        "status": (decode_status, encode_status(STATUS_FIELDS)),
        "footprint": (decode_footprint, encode_footprint("uav1", 1.0, ring)),
        "frames": (decode_frames, encode_frames([1.0])),
        "mission": (decode_mission, encode_mission(
            "uav1", mission.origin(), mission.domain, g.geometry,
            grid_hash(g.geometry, g.mask), ground_alt_known=True,
            thresholds=mission.thresholds, target_pd=0.9)),
    }


@pytest.mark.parametrize("kind", ["status", "footprint", "frames", "mission"])
def test_schema_and_version_checked_alike(kind):
    """One check for every JSON payload (bus.json_doc.check_schema); the footprint's schema
    and version live in its GeoJSON properties. The message names the key, the payload
    kind, the field, what came and what was expected; the version is the integer itself."""
    decode, payload = json_payloads()[kind]
    key = f"pdcov/uav1/{kind}"
    decode(payload, key)
    where = "properties." if kind == "footprint" else ""
    versions = "one of 1, 2" if kind == "frames" else "1"  # frames: both versions read
    cases = {"schema 'pdcov.other', expected 'pdcov.": ("schema", "pdcov.other"),
             "schema missing, expected": ("schema", KeyError),
             "schema 'xxxxx": ("schema", "x" * 10_000),
             f"version 9, expected {versions}": ("version", 9),
             f"version True, expected {versions}": ("version", True),
             f"version 1.0, expected {versions}": ("version", 1.0),
             f"version '1', expected {versions}": ("version", "1"),
             f"version missing, expected {versions}": ("version", KeyError)}
    for why, (name, value) in cases.items():
        doc = json.loads(payload)
        holder = doc["properties"] if kind == "footprint" else doc
        if value is KeyError:
            del holder[name]
        else:
            holder[name] = value
        with pytest.raises(BusPayloadError) as err:
            decode(json.dumps(doc).encode(), key)
        msg = str(err.value)
        assert msg.startswith(f"{key}: not a usable {kind}") and f": {where}{why}" in msg, msg
        assert len(msg) < 200, msg


def test_bus_config():
    bus = bus_config_from_dict({"mode": "client", "connect": "tcp/127.0.0.1:7447",
                                "multicast_scouting": False,
                                "zenoh": {"transport/link/tx/lease": 4000}}, "m.yaml")
    assert bus.connect == ("tcp/127.0.0.1:7447",)
    conf = json.loads(zenoh_config(bus).get_json("transport/link/tx/lease"))
    assert conf == 4000
    assert json.loads(zenoh_config(bus).get_json("scouting/multicast/enabled")) is False
    with pytest.raises(ConfigError, match="did you mean 'connect'"):
        bus_config_from_dict({"conect": []}, "m.yaml")
    with pytest.raises(ConfigError, match="bus.mode"):
        bus_config_from_dict({"mode": "server"}, "m.yaml")
    with pytest.raises(ConfigError, match="Zenoh refuses"):
        zenoh_config(BusConfig(zenoh={"no/such/path": 1}))


R = ("tcp/10.0.0.2:7447",)


@pytest.mark.parametrize(("mode", "connect", "listen", "opens"), [
    ("auto", R, (), "client"),  # through a router: a client, which the router brokers
    ("auto", R, ("tcp/0.0.0.0:7447",), "peer"),  # listens: other peers reach it
    ("auto", (), (), "peer"),  # no endpoint: a peer finding others by scouting
    ("auto", (), ("tcp/0.0.0.0:7447",), "peer"),
    ("peer", R, (), "peer"), ("client", R, (), "client"), ("router", (), R, "router")])
def test_session_mode_follows_the_endpoints_when_auto(mode, connect, listen, opens):
    bus = BusConfig(mode=mode, connect=connect, listen=listen)
    assert resolve_mode(mode, list(connect), list(listen)) == opens
    assert session_mode(bus) == opens
    assert json.loads(zenoh_config(bus).get_json("mode")) == opens
    assert describe_session(bus).startswith(opens + (" (auto)" if mode == "auto" else ""))


def test_auto_is_the_default_and_a_config_file_s_endpoints_count(tmp_path):
    assert BusConfig().mode == "auto" and bus_config_from_dict({}).mode == "auto"
    (tmp_path / "z.json5").write_text('{connect: {endpoints: ["tcp/10.0.0.2:7447"]}}')
    assert session_mode(BusConfig(config_file=str(tmp_path / "z.json5"))) == "client"


def test_a_peer_behind_a_router_listening_nowhere_is_warned_about():
    assert "listening nowhere" in peer_warning(BusConfig(mode="peer", connect=R))
    for ok in (BusConfig(connect=R), BusConfig(mode="peer", connect=R, listen=R),
               BusConfig(mode="peer")):
        assert peer_warning(ok) is None


def test_quiet_hint_names_the_session_and_what_to_check():
    assert "client (auto), connect [tcp/10.0.0.2:7447]" in quiet_hint(BusConfig(connect=R))
    assert "--mode client" in quiet_hint(BusConfig(mode="peer", connect=R))
    assert "multicast scouting finds daemons on this LAN" in quiet_hint(BusConfig())
    assert "--zenoh-listen" in quiet_hint(BusConfig(multicast_scouting=False))
