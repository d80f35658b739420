"""The mission payload (pdcov/<id>/mission) in memory: round trips checked against pymap3d
and against the grid hash, hostile payloads refused with the field named, the watcher's
mission queries stepped in time, and which domain the web map draws."""

from __future__ import annotations

import copy
import json

import pymap3d
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import decode_snapshot, grid_hash
from pdcov.bus.keys import VehicleKeys, parse_key
from pdcov.bus.mission import MAX_VERTICES, decode_mission, encode_mission
from pdcov.bus.status import decode_status
from pdcov.config.load import load_mission, mission_from_dict
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin
from pdcov.ground.queries import QueryMission
from pdcov.ground.watcher import Watcher
from pdcov.ground.web import domain_layer, map_state
from tests.support.watch_fixtures import DEMO, TinyPublisher


def payload_of(mission, vehicle_id: str | None = None, alt_known: bool = True) -> bytes:
    g = mission.new_mission_grid()
    return encode_mission(vehicle_id or mission.vehicle_id, mission.origin(), mission.domain,
                          g.geometry, grid_hash(g.geometry, g.mask), ground_alt_known=alt_known,
                          thresholds=mission.thresholds, target_pd=max(mission.thresholds))


def with_obstacle(domain_doc: dict) -> dict:
    doc = yaml.safe_load(open(DEMO))
    doc["domain"] = domain_doc
    return doc


@pytest.fixture(scope="module")
def demo():
    return load_mission(DEMO)


@pytest.fixture(scope="module")
def geodetic_mission():
    """A mission given in WGS84 with an obstacle: the ENU rings are projections."""
    lat0, lon0 = -35.36, 149.16
    d = 1e-4
    doc = with_obstacle({
        "polygon_geodetic_deg": [[lat0, lon0], [lat0 + 4 * d, lon0 + d],
                                 [lat0 + 3 * d, lon0 + 5 * d], [lat0 - d, lon0 + 4 * d]],
        "obstacles_geodetic_deg": [[[lat0 + d, lon0 + 2 * d], [lat0 + 2 * d, lon0 + 2 * d],
                                    [lat0 + 2 * d, lon0 + 3 * d]]],
        "cell_size_m": 0.7})
    doc["origin"] = {"lat_deg": lat0, "lon_deg": lon0, "ground_alt_msl_m": 584.0}
    return mission_from_dict(doc, source="geodetic.yaml")


def test_key_and_round_trip_of_the_demo_mission(demo):
    assert VehicleKeys("uav1").mission == "pdcov/uav1/mission"
    assert parse_key("pdcov/uav1/mission") == ("uav1", "mission")
    m = decode_mission(payload_of(demo, "uav1"), "pdcov/uav1/mission", "uav1")
    g = demo.new_mission_grid()
    assert m.vehicle_id == "uav1" and m.grid_hash == grid_hash(g.geometry, g.mask)
    assert (m.origin_lat_deg, m.origin_lon_deg, m.ground_alt_msl_m) == (39.35, -76.33, 5.0)
    assert m.geometry == g.geometry and m.obstacles_enu_m == ()
    assert m.boundary_enu_m == tuple(demo.domain.boundary.exterior.coords)
    assert m.thresholds == (0.5, 0.7, 0.8) and m.target_pd == 0.8
    # WGS84 corners as pymap3d puts them (an oracle independent of pdcov.core.geodesy).
    for (x, y), (lon, lat) in zip(m.boundary_enu_m, m.boundary_lon_lat_deg, strict=True):
        lat_ref, lon_ref, _ = pymap3d.enu2geodetic(x, y, 0.0, 39.35, -76.33, 5.0)
        assert lat == pytest.approx(lat_ref, abs=2e-9) and lon == pytest.approx(lon_ref,
                                                                             abs=2e-9)
    unknown = decode_mission(payload_of(demo, alt_known=False))
    assert unknown.ground_alt_msl_m is None


def test_geometry_rebuilds_the_grid_hash_with_obstacles(geodetic_mission):
    """The rings are sent at full precision: a receiver rebuilding the free mask from them
    gets the daemon's grid hash bit for bit."""
    m = decode_mission(payload_of(geodetic_mission, "uav2"), vehicle_id="uav2")
    assert len(m.obstacles_enu_m) == 1 and len(m.obstacles_lon_lat_deg) == 1
    dom = m.domain()
    geo = dom.grid_geometry(m.geometry.cell_size_m)
    assert geo == m.geometry
    assert grid_hash(geo, dom.free_mask(geo)) == m.grid_hash
    # The WGS84 rings are the config's (given in WGS84) to the encoder's 1e-9 deg.
    lat0, lon0 = -35.36, 149.16
    assert m.boundary_lon_lat_deg[0] == pytest.approx((lon0, lat0), abs=2e-9)
    assert m.obstacles_lon_lat_deg[0][1] == pytest.approx((lon0 + 2e-4, lat0 + 2e-4), abs=2e-9)


@settings(max_examples=25, deadline=None)
@given(st.floats(-80, 80), st.floats(-180, 180), st.floats(-400, 4000),  # cells <= MAX_CELLS
       st.floats(5, 3000), st.floats(5, 3000), st.floats(-2000, 2000), st.floats(1, 20))
def test_round_trip_anywhere(lat, lon, alt, w, h, x0, cell):
    origin = Origin(lat, lon, alt)
    domain = Domain.from_enu([[x0, -h / 2], [x0 + w, -h / 2], [x0 + w, h / 2], [x0, h / 2]])
    geo = domain.grid_geometry(cell)
    m = decode_mission(encode_mission("v", origin, domain, geo, "0123456789abcdef",
                                      ground_alt_known=True, thresholds=[0.8], target_pd=0.8))
    assert m.boundary_enu_m == tuple(domain.boundary.exterior.coords)
    assert m.geometry == geo and m.ground_alt_msl_m == alt


def mutate(doc: dict, path: str, value) -> dict:
    out = copy.deepcopy(doc)
    *head, last = path.split(".")
    node = out
    for k in head:
        node = node[int(k)] if isinstance(node, list) else node[k]
    if isinstance(node, list):
        node[int(last)] = value
    elif value is KeyError:
        del node[last]
    else:
        node[last] = value
    return out


def test_hostile_payloads_are_refused_naming_the_field(demo):
    doc = json.loads(payload_of(demo, "uav1"))
    ring = doc["domain"]["boundary_enu_m"]
    ll = doc["domain"]["boundary_lon_lat_deg"]
    bowtie = [[-60, -60], [-20, -20], [-60, -20], [-20, -60], [-60, -60]]
    moved = [[lon + 2e-5, lat] for lon, lat in ll]  # ~1.7 m east
    cases = {
        "schema": mutate(doc, "schema", "pdcov.status"),
        "version": mutate(doc, "version", 2),
        "vehicle_id": mutate(doc, "vehicle_id", "a/b"),
        "key is vehicle": mutate(doc, "vehicle_id", "uav9"),
        "grid_hash": mutate(doc, "grid_hash", "0123456789ABCDEF"),
        "lat_deg": mutate(doc, "origin.lat_deg", 91.0),
        "ground_alt_msl_m": mutate(doc, "origin.ground_alt_msl_m", "high"),
        "origin: expected an object": mutate(doc, "origin", [1, 2]),
        "cell_size_m": mutate(doc, "grid.cell_size_m", 0),
        "n_rows": mutate(doc, "grid.n_rows", True),
        "at most": mutate(doc, "grid.n_cols", 10**9),
        "x0_m": mutate(doc, "grid.x0_m", 1e300),
        "not closed": mutate(doc, "domain.boundary_enu_m", ring[:-1]),
        "4 or more": mutate(doc, "domain.boundary_enu_m", [ring[0], ring[1], ring[0]]),
        "invalid polygon": mutate(doc, "domain.boundary_enu_m", bowtie),
        "Self-intersection": mutate(doc, "domain.boundary_enu_m",  # no area, a line
                                    [[-60, -60], [-40, -40], [-20, -20], [-60, -60]]),
        "pair of finite": mutate(doc, "domain.boundary_enu_m.1", [-60, "x"]),
        "extends beyond the grid": mutate(doc, "domain.boundary_enu_m",
                                          [[x + 5, y] for x, y in ring]),
        "m from the ENU ring": mutate(doc, "domain.boundary_lon_lat_deg", moved),
        "WGS84 positions": mutate(doc, "domain.boundary_lon_lat_deg", ll[:1] + ll[2:]),
        "[lon, lat]": mutate(doc, "domain.boundary_lon_lat_deg.1", [-76.3, 95.0]),
        "obstacles_lon_lat_deg: 1 rings": mutate(doc, "domain.obstacles_lon_lat_deg", [ll]),
        "obstacles_enu_m": mutate(doc, "domain.obstacles_enu_m", KeyError),
        "thresholds": mutate(doc, "thresholds", [0.5, 1.5]),
        "target_pd": mutate(doc, "target_pd", 0),
    }
    for why, bad_doc in cases.items():
        payload = json.dumps(bad_doc).encode()
        with pytest.raises(BusPayloadError, match="pdcov/uav1/mission") as err:
            decode_mission(payload, "pdcov/uav1/mission", "uav1")
        assert why in str(err.value), (why, str(err.value))
    nan = json.dumps(doc).replace('"lat_deg": 39.35', '"lat_deg": NaN').encode()
    ring13 = ring[:4] * 3 + ring[:1]  # 13 positions, closed
    n = MAX_VERTICES // 13 + 1
    many = mutate(mutate(doc, "domain.obstacles_enu_m", [ring13] * n),
                  "domain.obstacles_lon_lat_deg", [ring13] * n)
    for payload, why in ((b"\xff\xfe", "UTF-8"), (b"[1, 2]", "JSON object"),
                         (b"[" * 100_000, "JSON"), (nan, "lat_deg"),
                         (b" " * (9 << 20), "bytes"),
                         (json.dumps(many).encode(), f"at most {MAX_VERTICES} in all rings")):
        with pytest.raises(BusPayloadError, match=why):
            decode_mission(payload, "pdcov/uav1/mission")


def test_watcher_asks_for_the_mission_per_grid_hash(demo, geodetic_mission):
    pub = TinyPublisher("uav1")
    w = Watcher()
    assert w.missions_due(0.0) == []  # nothing known yet
    w.on_alive("uav1", True, 0.0)
    assert w.missions_due(0.1) == []  # no grid hash yet: wait for the status or snapshot
    w.on_status("uav1", decode_status(pub.status()), 0.5)
    assert w.missions_due(0.6) == [QueryMission("uav1")]
    assert w.missions_due(0.8) == []  # asked; the reply is awaited
    w.on_mission_failed("uav1", 5.0)  # timed out (an older daemon has no such queryable)
    assert w.missions_due(14.9) == []
    assert w.missions_due(15.0) == [QueryMission("uav1")]
    other = decode_mission(payload_of(geodetic_mission, "uav1"))
    w.on_mission("uav1", other, 15.5)  # another grid's (the daemon was restarting)
    assert w.mission_for(decode_status(pub.status())["grid"]["hash"]) is None
    assert w.missions_due(20.0) == [] and w.missions_due(25.5) == [QueryMission("uav1")]
    mine = decode_mission(payload_of(demo, "uav1"))
    w.on_mission("uav1", mine, 26.0)
    assert w.mission_for(mine.grid_hash) is mine and w.mission_for(None) is mine
    assert w.missions_due(100.0) == []  # it describes the vehicle's grid: never again
    # The daemon restarts with another mission: its status announces another grid hash.
    st = decode_status(pub.status())
    st["grid"]["hash"] = other.grid_hash
    st["uptime_s"] = 0.0
    w.on_status("uav1", st, 101.0)
    assert w.missions_due(101.1) == [QueryMission("uav1")]
    Watcher(vehicle="uav2").on_mission("uav1", mine, 1.0)  # not followed: ignored


def test_web_map_draws_the_domain_of_the_grid_shown(demo, geodetic_mission):
    pub = TinyPublisher("uav1")
    pub.step(3)
    w = Watcher()
    w.on_status("uav1", decode_status(pub.status()), 0.0)
    w.on_snapshot("uav1", decode_snapshot(pub.snapshot()), 0.1)
    shown = w.fleet_state()[0].hash
    demo_hash = decode_mission(payload_of(demo)).grid_hash
    assert shown == demo_hash
    other_grid = geodetic_mission.new_mission_grid()
    other_hash = grid_hash(other_grid.geometry, other_grid.mask)
    # No mission reply yet, no --config: nothing drawn, and the page says why.
    domain, note = domain_layer(w, shown, None, None)
    assert domain is None and f"mission geometry of grid {shown}" in note
    w.on_mission("uav1", decode_mission(payload_of(demo, "uav1")), 0.2)
    domain, note = domain_layer(w, shown, None, None)
    assert domain["source"] == "vehicle uav1" and note is None
    assert domain["boundary"] == [[-60, -60], [-60, -20], [-20, -20], [-20, -60], [-60, -60]]
    # --config describing the same grid is drawn from the file.
    domain, note = domain_layer(w, shown, demo, demo_hash)
    assert domain["source"] == "--config" and note is None
    # --config describing another grid is not drawn over this one.
    domain, note = domain_layer(w, shown, geodetic_mission, other_hash)
    assert domain["source"] == "vehicle uav1"
    assert "geodetic.yaml describes grid" in note and "not drawn" in note
    state = map_state(w, w.report(1.0), geodetic_mission, 7, None, other_hash)
    assert state["domain"]["source"] == "vehicle uav1" and "not drawn" in state["domain_note"]
    assert state["origin"] == {"lat_deg": 39.35, "lon_deg": -76.33}
    # Before any grid arrives, --config is drawn (nothing to disagree with).
    assert domain_layer(Watcher(), None, geodetic_mission, other_hash)[0]["source"] \
        == "--config"


def test_json_nested_too_deep_is_refused_by_every_json_decoder():
    """``[[[[…`` makes json raise RecursionError; it once escaped decode_status and
    decode_frames (a traceback in the watcher's and the daemon's loops)."""
    from pdcov.bus.footprint import decode_footprint
    from pdcov.bus.frames import decode_frames

    deep = b"[" * 60_000
    for decode in (decode_status, decode_footprint, decode_frames, decode_mission):
        with pytest.raises(BusPayloadError, match="not UTF-8 JSON"):
            decode(deep)
