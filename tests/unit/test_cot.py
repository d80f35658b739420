"""Cursor-on-Target (ground/cot.py, ground/cot_feed.py): the sensor wedge measured on a
footprint, the schedule's rates and stale times, and the feed sent through pytak to
loopback receivers (a UDP socket, a TCP server on 127.0.0.1) that parse every event's XML
and check its type, uid, point, times and sensor detail."""

from __future__ import annotations

import asyncio
import math
import re
import socket
import xml.etree.ElementTree as ET
from datetime import datetime, timedelta

import numpy as np
import pytest

from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.errors import ConfigError
from pdcov.ground.cot import CotSchedule, sensor_from_footprint, track_between
from pdcov.ground.cot_feed import CotFeed, parse_cot_url
from pdcov.ground.feed import VehicleFeed
from pdcov.report.cot_events import AIRCRAFT_TYPE, CANDIDATE_TYPE
from tests.support.exports_fixtures import candidate

AIR = Origin(46.5, 7.25, 0.0)


def ring(points_enu) -> list[list[float]]:
    lla = enu_to_geodetic(np.c_[np.asarray(points_enu, float), np.zeros(len(points_enu))], AIR)
    return [[lon, lat] for lat, lon, _ in lla]


def test_a_nadir_footprint_is_the_cameras_fov_straight_down():
    # A 40 x 30 m footprint under a camera 20 m up, long side east: heading 90.
    s = sensor_from_footprint(AIR.lat_deg, AIR.lon_deg, 20.0, 90.0,
                              ring([(-20, -15), (20, -15), (20, 15), (-20, 15)]))
    assert s.azimuth_deg == pytest.approx(90.0)
    assert s.elevation_deg == pytest.approx(-90.0)
    assert s.range_m == pytest.approx(20.0, abs=1e-3)
    assert s.fov_deg == pytest.approx(2 * math.degrees(math.atan(15 / 20)), abs=1e-3)
    assert s.vfov_deg == pytest.approx(2 * math.degrees(math.atan(20 / 20)), abs=1e-3)


def test_an_oblique_footprint_points_the_wedge_at_it():
    # A camera 30 m up pitched 45 degrees down towards the north-east.
    az, h, half = math.radians(45.0), 30.0, math.radians(10.0)
    corners = []
    for da, de in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        dep = math.radians(45.0) + de * half  # depression of the ray
        a = az + da * half
        d = h / math.tan(dep)
        corners.append((d * math.sin(a), d * math.cos(a)))
    s = sensor_from_footprint(AIR.lat_deg, AIR.lon_deg, h, 0.0, ring(corners))
    assert s.azimuth_deg == pytest.approx(45.0, abs=1.0)
    assert s.elevation_deg == pytest.approx(-45.0, abs=3.0)
    assert 15.0 < s.fov_deg < 25.0 and 15.0 < s.vfov_deg < 25.0


def test_no_wedge_without_a_footprint_or_height():
    assert sensor_from_footprint(46.5, 7.25, 0.0, 0.0, ring([(0, 0), (1, 0), (1, 1)])) is None
    assert sensor_from_footprint(46.5, 7.25, 10.0, 0.0, [[7.25, 46.5]]) is None


def feed_with(pose_t_s: float = 1.0, candidates=()) -> VehicleFeed:
    f = VehicleFeed("uav1")
    f.status = {"pose": {"lat_deg": 46.5, "lon_deg": 7.25, "alt_msl_m": 620.0,
                         "heading_deg": 90.0, "t_s": pose_t_s},
                "grid": {"origin": {"lat_deg": 46.5, "lon_deg": 7.25,
                                    "ground_alt_msl_m": 600.0}}}
    f.footprint = {"geometry": {"type": "Polygon", "coordinates": [
        ring([(-20, -15), (20, -15), (20, 15), (-20, 15), (-20, -15)])]}}
    f.candidates = {c["uid"]: c for c in candidates}
    return f


def parse(event: bytes) -> ET.Element:
    e = ET.fromstring(event)
    assert e.tag == "event" and e.get("version") == "2.0"
    return e


def when(text: str) -> datetime:
    return datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ")


def test_schedule_sends_new_poses_and_changed_candidates_at_bounded_rates():
    sched = CotSchedule(aircraft_period_s=1.0, candidate_period_s=15.0, max_events_per_s=20)
    f = feed_with(candidates=[candidate(k, k, 0) for k in range(30)])
    first = [parse(e) for e in sched.due([f], 0.0, 1_700_000_000.0)]
    assert len(first) == 20  # the bucket: 20 events at most at once
    assert first[0].get("type") == AIRCRAFT_TYPE and first[0].get("uid") == "pdcov-uav1"
    air = first[0]
    assert when(air.get("stale")) - when(air.get("time")) == timedelta(seconds=10)
    sensor = air.find("detail/sensor")
    assert float(sensor.get("elevation")) == pytest.approx(-90.0)
    assert float(sensor.get("range")) == pytest.approx(20.0, abs=0.1)
    assert float(sensor.get("fov")) == pytest.approx(73.7, abs=0.1)  # 2 atan(15/20)
    second = [parse(e) for e in sched.due([f], 0.5, 1_700_000_000.5)]
    assert len(second) == 10 and {e.get("type") for e in second} == {CANDIDATE_TYPE}
    assert len(sched.due([f], 0.9, 1_700_000_000.9)) == 1  # the last candidate
    assert sched.due([f], 0.95, 1_700_000_000.95) == []  # nothing new, no new pose
    f.status["pose"]["t_s"] = 2.0
    assert sched.due([f], 0.97, 1_700_000_000.97) == []  # new, but within the period ...
    (again,) = sched.due([f], 1.0, 1_700_000_001.0)
    assert parse(again).get("type") == AIRCRAFT_TYPE  # ... then sent once
    f.candidates["uav1.3fa2c1.3"] = candidate(3, 3, 0, hits=10, looks=15, p_person=0.98765)
    (changed,) = sched.due([f], 2.0, 1_700_000_002.0)
    e = parse(changed)
    assert e.get("uid") == "uav1.3fa2c1.3"  # the pin's uid: durable across restarts
    assert "person pin uav1.3fa2c1.3: p_person 0.9877, detected 10 of 15 looks" in \
        e.findtext("detail/remarks")
    assert e.find("detail/contact").get("callsign") == "person 0.99 uav1.3fa2c1.3"
    f.candidates["uav1.3fa2c1.3"] = candidate(3, 3, 0, hits=10, looks=16, p_person=0.9)
    (missed,) = sched.due([f], 3.0, 1_700_000_003.0)  # a look without a hit: sent again
    assert "p_person 0.9000, detected 10 of 16 looks" in parse(missed).findtext(
        "detail/remarks")
    assert when(e.get("stale")) - when(e.get("time")) == timedelta(seconds=300)
    assert float(e.find("point").get("ce")) == pytest.approx(2.146 * 0.5, abs=0.05)
    assert len(sched.due([f], 16.0, 1_700_000_016.0)) == 20  # the repeats, still bounded


def pose_at(x_m: float, y_m: float, t_s: float | None, heading_deg: float = 90.0) -> dict:
    """A status pose at ENU (x_m, y_m) about AIR, at autopilot time ``t_s``."""
    lat, lon, _ = enu_to_geodetic(np.array([x_m, y_m, 0.0]), AIR)
    return {"lat_deg": round(float(lat), 7), "lon_deg": round(float(lon), 7),
            "alt_msl_m": 620.0, "heading_deg": heading_deg, "t_s": t_s}


def test_the_track_is_the_velocity_between_two_status_positions():
    t = track_between(pose_at(0, 0, 10.0), pose_at(3.0, 4.0, 11.0))  # 5 m in 1 s, to ENE
    assert t.speed_mps == pytest.approx(5.0, abs=0.02)
    assert t.course_deg == pytest.approx(math.degrees(math.atan2(3.0, 4.0)), abs=0.2)
    west = track_between(pose_at(0, 0, 10.0), pose_at(-8.0, 0.0, 12.0))
    assert (west.speed_mps, west.course_deg) == pytest.approx((4.0, 270.0), abs=0.2)
    hover = track_between(pose_at(0, 0, 10.0), pose_at(0.1, 0.0, 11.0, heading_deg=200.0))
    assert hover.speed_mps < 0.5 and hover.course_deg == 200.0  # its nose, not its drift
    assert track_between(pose_at(0, 0, 10.0), pose_at(5, 0, 16.0)) is None  # a status lost
    assert track_between(pose_at(0, 0, 10.0), pose_at(5, 0, 10.0)) is None
    assert track_between(pose_at(0, 0, None), pose_at(5, 0, 11.0)) is None


def test_the_aircraft_carries_speed_and_course_and_a_pin_none():
    sched = CotSchedule(aircraft_period_s=1.0)
    f = feed_with(candidates=[candidate(3, 15.0, 2.0)])
    f.status["pose"] = pose_at(0.0, 0.0, 20.0)
    first = {parse(e).get("type"): parse(e) for e in sched.due([f], 0.0, 1.7e9)}
    assert first[AIRCRAFT_TYPE].find("detail/track") is None  # one position: no velocity
    f.status["pose"] = pose_at(0.0, 6.0, 21.5)  # 6 m north in 1.5 s
    (air,) = [parse(e) for e in sched.due([f], 1.0, 1.7e9 + 1.0)]
    track = air.find("detail/track")
    assert float(track.get("speed")) == pytest.approx(4.0, abs=0.02)  # m/s
    assert float(track.get("course")) == pytest.approx(0.0, abs=0.2)  # deg true: north
    pt = air.find("point")
    assert all(re.fullmatch(r"-?\d+\.\d{7}", pt.get(k)) for k in ("lat", "lon"))
    assert first[CANDIDATE_TYPE].find("detail/track") is None  # a pin stands still
    f.status["pose"] = pose_at(0.0, 6.0, 29.0)  # after 7.5 s: the velocity is unknown
    (late,) = [parse(e) for e in sched.due([f], 2.0, 1.7e9 + 2.0)]
    assert late.find("detail/track") is None


def test_cot_url_is_checked():
    assert parse_cot_url("udp://239.2.3.1:6969") == "udp://239.2.3.1:6969"
    for bad in ("239.2.3.1:6969", "http://x:1", "udp://host", "tcp://:8087", "udp://h:x"):
        with pytest.raises(ConfigError, match="--cot"):
            parse_cot_url(bad)


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def check_events(events: list[ET.Element]) -> None:
    """Every event of one aircraft and its candidate, well formed."""
    kinds = {e.get("type") for e in events}
    assert kinds == {AIRCRAFT_TYPE, CANDIDATE_TYPE}
    for e in events:
        assert e.get("uid") in ("pdcov-uav1", "uav1.3fa2c1.3")
        assert when(e.get("stale")) > when(e.get("time")) == when(e.get("start"))
        pt = e.find("point")
        assert float(pt.get("lat")) == pytest.approx(46.5, abs=1e-3)
        assert float(pt.get("lon")) == pytest.approx(7.25, abs=1e-3)
        assert pt.get("hae") == "9999999.0"
    pin = next(e for e in events if e.get("type") == CANDIDATE_TYPE)
    assert "pin uav1.3fa2c1.3: p_person 0.9731, detected 9 of 14 looks" in pin.findtext(
        "detail/remarks")
    air = next(e for e in events if e.get("type") == AIRCRAFT_TYPE)
    assert {"azimuth", "elevation", "fov", "vfov", "range"} <= set(air.find(
        "detail/sensor").attrib)


async def run_feed(url: str, receive) -> list[ET.Element]:
    f = feed_with(candidates=[candidate(3, 15.0, 2.0)])
    feed = CotFeed(url, CotSchedule(), lambda: [f], period_s=0.05)
    stop = asyncio.Event()
    task = asyncio.create_task(feed.run(stop))
    try:
        return await asyncio.wait_for(receive(), 10.0)
    finally:
        stop.set()
        await task


def test_udp_events_reach_a_loopback_receiver():
    port = free_port(socket.SOCK_DGRAM)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.setblocking(False)

    async def receive() -> list[ET.Element]:
        loop = asyncio.get_running_loop()
        got = []
        while len(got) < 2:
            got.append(parse(await loop.sock_recv(rx, 65536)))  # one event a datagram
        return got

    try:
        check_events(asyncio.run(run_feed(f"udp://127.0.0.1:{port}", receive)))
    finally:
        rx.close()


def test_tcp_events_reach_a_loopback_server_and_survive_its_absence():
    port = free_port(socket.SOCK_STREAM)

    async def main() -> list[ET.Element]:
        got: list[ET.Element] = []
        done = asyncio.Event()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            buf = b""
            while not done.is_set():
                chunk = await reader.read(65536)
                if not chunk:
                    break
                buf += chunk
                while b"</event>" in buf:  # a stream of events, as a TAK server reads it
                    event, buf = buf.split(b"</event>", 1)
                    got.append(parse(event + b"</event>"))
                if len(got) >= 2:
                    done.set()
            writer.close()

        f = feed_with(candidates=[candidate(3, 15.0, 2.0)])
        feed = CotFeed(f"tcp://127.0.0.1:{port}", CotSchedule(), lambda: [f],
                       period_s=0.05, retry_s=0.2, settle_s=0.0)
        stop = asyncio.Event()
        task = asyncio.create_task(feed.run(stop))
        await asyncio.sleep(0.3)  # nobody listens yet: refused, logged, retried
        assert feed.failures >= 1 and "connecting" in feed.warning
        server = await asyncio.start_server(serve, "127.0.0.1", port)
        try:
            await asyncio.wait_for(done.wait(), 10.0)
        finally:
            stop.set()
            await task
            server.close()
        assert feed.warning is None  # sending again
        return got

    check_events(asyncio.run(main()))
