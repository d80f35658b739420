"""MAVSDK (its C++ core, in-process through the ``mavsdk`` wheel) as an independent ground
station: it finds the simulator's endpoint over UDP on 127.0.0.1, reads position, attitude
and home from a minimal message feed, and uploads and downloads a mission with mission_raw.
The fly loop's own messages are checked against MAVSDK in the flight tests."""

from __future__ import annotations

import math
import time

import pytest

mavsdk = pytest.importorskip("mavsdk")
from mavsdk import Autopilot, ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.plugins.mission_raw import MissionItem as RawItem  # noqa: E402
from mavsdk.plugins.mission_raw import MissionRaw  # noqa: E402
from mavsdk.plugins.telemetry import Telemetry  # noqa: E402

from pdcov_sitl.endpoint import AutopilotEndpoint  # noqa: E402
from tests.support.sitl_feed import ALT_MSL_M, LAT_DEG, LON_DEG, PARAMS, STREAMS_HZ, FeedThread  # noqa: E402

MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_CMD_NAV_WAYPOINT = 16


def wait_value(read, ok, timeout_s=5.0):
    t_end = time.monotonic() + timeout_s
    while True:
        value = read()
        if ok(value) or time.monotonic() > t_end:
            return value
        time.sleep(0.05)


@pytest.mark.parametrize(("autopilot", "kind"), [("px4", Autopilot.PX4),
                                                  ("ardupilot", Autopilot.ARDUPILOT)])
def test_mavsdk_sees_the_vehicle_and_round_trips_a_mission(autopilot, kind):
    endpoint = AutopilotEndpoint("udpin:127.0.0.1:0", system_id=1, autopilot=autopilot,
                                 params=dict(PARAMS), streams=dict(STREAMS_HZ), faults=None,
                                 seed=0, tlog_path=None)
    port = endpoint.link.local_address[1]
    feed = FeedThread(endpoint, autopilot)
    feed.start()
    gcs = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert int(gcs.add_any_connection(f"udpout://127.0.0.1:{port}")) == 0
        system = gcs.first_autopilot(10.0)
        assert system is not None, "MAVSDK found no autopilot"
        assert system.is_connected() and system.autopilot_type() == kind
        telemetry = Telemetry(system)
        position = wait_value(telemetry.position, lambda p: not math.isnan(p.latitude_deg))
        assert position.latitude_deg == pytest.approx(LAT_DEG, abs=1e-7)
        assert position.longitude_deg == pytest.approx(LON_DEG, abs=1e-7)
        assert position.relative_altitude_m == pytest.approx(10.0, abs=1e-3)
        attitude = wait_value(telemetry.attitude_euler, lambda a: a.timestamp_us > 0)
        assert attitude.roll_deg == pytest.approx(math.degrees(0.01), abs=1e-4)
        assert attitude.pitch_deg == pytest.approx(math.degrees(-0.02), abs=1e-4)
        home = wait_value(telemetry.home, lambda h: not math.isnan(h.latitude_deg))
        assert home.latitude_deg == pytest.approx(LAT_DEG, abs=1e-7)
        assert home.absolute_altitude_m == pytest.approx(ALT_MSL_M, abs=1e-3)

        items = [RawItem(seq, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_WAYPOINT, int(seq == 0),
                         1, 0.0, 0.0, 0.0, 0.0, round((LAT_DEG + seq * 1e-4) * 1e7),
                         round(LON_DEG * 1e7) + seq, 10.0 + seq, 0) for seq in range(6)]
        MissionRaw(system).upload_mission(items)
        mission = endpoint.mission
        assert mission is not None and len(mission) == len(items)
        for got, sent in zip(mission, items, strict=True):
            assert got.lat_deg == pytest.approx(sent.x * 1e-7, abs=1e-9)
            assert got.lon_deg == pytest.approx(sent.y * 1e-7, abs=1e-9)
        back = MissionRaw(system).download_mission()
        assert [(b.seq, b.command, b.x, b.y, b.z) for b in back] == [
            (s.seq, s.command, s.x, s.y, s.z) for s in items]
    finally:
        gcs.destroy()
        feed.stop()
