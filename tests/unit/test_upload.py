"""Mission upload over a real UDP socket on 127.0.0.1 to a vehicle-side MAVLink mission peer.

The peer is written here with pymavlink: it answers the ground station's HEARTBEAT, takes
MISSION_COUNT, asks for every item with MISSION_REQUEST_INT (or the older MISSION_REQUEST),
checks each item, and ends with MISSION_ACK; it can refuse a frame or run out of space.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.geodesy import Origin
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_items import home_item, mission_items
from pdcov.telemetry.upload import MissionUpload, UploadError, mavlink2_connection, upload_mission

ORIGIN = Origin(39.35, -76.33, 12.5)
PLAN = Plan((Waypoint(0.0, 0.0, 10.0, 5.0), Waypoint(0.0, 40.0, 10.0, 5.0, 2.0),
             Waypoint(8.0, 40.0, 10.0, 5.0)))
ITEMS = mission_items(PLAN, ORIGIN)


class Vehicle(threading.Thread):
    """A vehicle's mission server on a UDP port of 127.0.0.1."""

    def __init__(self, autopilot=mavlink2.MAV_AUTOPILOT_PX4, capacity=100,
                 refuse_frame=None, legacy_requests=False, drop_first_count=False,
                 gimbal_heartbeat=False):
        super().__init__(daemon=True)
        self.conn = mavlink2_connection("udpin:127.0.0.1:0", 1, 1)
        self.port = self.conn.port.getsockname()[1]
        self.autopilot = autopilot
        self.capacity = capacity
        self.refuse_frame = refuse_frame
        self.legacy_requests = legacy_requests
        self.drop_first_count = drop_first_count
        self.gimbal = (mavlink2.MAVLink(self.conn, srcSystem=1, srcComponent=154)
                       if gimbal_heartbeat else None)
        self.count_components: list[int] = []
        self.received: dict[int, object] = {}
        self.counts_seen = 0
        self.stop = threading.Event()

    def _request(self, seq):
        if self.legacy_requests:
            self.conn.mav.mission_request_send(255, 190, seq, 0)
        else:
            self.conn.mav.mission_request_int_send(255, 190, seq, 0)

    def run(self):
        count = None
        while not self.stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "HEARTBEAT":
                if self.gimbal is not None:  # a gimbal on the same link speaks first
                    self.gimbal.heartbeat_send(mavlink2.MAV_TYPE_GIMBAL,
                                               mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, self.autopilot,
                                             0, 0, mavlink2.MAV_STATE_STANDBY)
            elif kind == "MISSION_COUNT" and msg.target_system == 1:
                self.counts_seen += 1
                self.count_components.append(msg.target_component)
                if self.drop_first_count and self.counts_seen == 1:
                    continue  # lost on the link: the ground station must resend it
                count = msg.count
                if count > self.capacity:
                    self.conn.mav.mission_ack_send(255, 190, mavlink2.MAV_MISSION_NO_SPACE, 0)
                    continue
                self._request(0)
            elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM") and count is not None:
                self.received[msg.seq] = msg
                if msg.frame == self.refuse_frame:
                    self.conn.mav.mission_ack_send(
                        255, 190, mavlink2.MAV_MISSION_UNSUPPORTED_FRAME, 0)
                    count = None
                elif msg.seq + 1 < count:
                    self._request(msg.seq + 1)
                else:
                    self.conn.mav.mission_ack_send(255, 190, mavlink2.MAV_MISSION_ACCEPTED, 0)
                    count = None
        self.conn.close()


@pytest.fixture
def vehicle_factory():
    started = []

    def make(**kw):
        v = Vehicle(**kw)
        v.start()
        started.append(v)
        return v
    yield make
    for v in started:
        v.stop.set()
        v.join(timeout=2)


def url(v):
    return f"udpout:127.0.0.1:{v.port}"


def test_px4_accepts_every_item(vehicle_factory):
    v = vehicle_factory()
    result = upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=5)
    assert result.accepted, result.report()
    assert "accepted" in result.report() and result.n_items == len(ITEMS)
    assert sorted(v.received) == list(range(len(ITEMS)))
    for seq, it in enumerate(ITEMS):
        got = v.received[seq]
        assert got.get_type() == "MISSION_ITEM_INT"
        assert (got.command, got.frame) == (it.command, it.frame)
        assert got.x == round(it.lat_deg * 1e7) and got.y == round(it.lon_deg * 1e7)
        assert got.z == pytest.approx(it.z_m)


def test_ardupilot_gets_home_at_seq_0_and_legacy_requests(vehicle_factory):
    """ArduCopter 4.7 asks with MISSION_REQUEST; the answer is still MISSION_ITEM_INT, so
    every coordinate arrives to 1e-7 deg (float32 MISSION_ITEM moved them by ~0.5 m)."""
    origin = Origin(-35.36308075, 149.16523412, 584.0)  # not representable in float32
    items = mission_items(PLAN, origin)
    v = vehicle_factory(autopilot=mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, legacy_requests=True)
    result = upload_mission(items, url(v), home_item(origin), timeout_s=5)
    assert result.accepted and result.n_items == len(items) + 1
    home = v.received[0]
    assert home.get_type() == "MISSION_ITEM_INT" and home.frame == 0
    assert home.z == pytest.approx(584.0)
    sent = (home_item(origin), *items)
    for seq, it in enumerate(sent):
        got = v.received[seq]
        assert got.get_type() == "MISSION_ITEM_INT" and got.command == it.command
        if it.lat_deg or it.lon_deg:
            assert abs(got.x * 1e-7 - it.lat_deg) <= 1e-7
            assert abs(got.y * 1e-7 - it.lon_deg) <= 1e-7


def test_refused_frame_is_reported_with_the_item(vehicle_factory):
    v = vehicle_factory(refuse_frame=2)  # MAV_FRAME_MISSION: the speed-change item
    result = upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=5)
    assert not result.accepted
    assert result.result == "MAV_MISSION_UNSUPPORTED_FRAME"
    assert result.refused_seq == 1 and result.refused_command == 178
    assert "refused the mission at item 1 (command 178)" in result.report()


def test_no_space_is_reported(vehicle_factory):
    v = vehicle_factory(capacity=3)
    result = upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=5)
    assert not result.accepted and result.result == "MAV_MISSION_NO_SPACE"
    assert result.refused_seq is None and "storage" in result.detail


def test_lost_count_is_resent(vehicle_factory):
    v = vehicle_factory(drop_first_count=True)
    result = upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=5, retry_s=0.3)
    assert result.accepted and v.counts_seen == 2


def test_gimbal_heartbeat_is_not_the_vehicle(vehicle_factory):
    v = vehicle_factory(gimbal_heartbeat=True)
    result = upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=5)
    assert result.accepted and v.count_components == [1]


def test_silent_link_raises(vehicle_factory):
    v = vehicle_factory()
    v.stop.set()
    v.join(timeout=2)
    t0 = time.monotonic()
    with pytest.raises(UploadError, match="no vehicle HEARTBEAT"):
        upload_mission(ITEMS, url(v), home_item(ORIGIN), timeout_s=0.5)
    assert time.monotonic() - t0 < 3


def test_state_machine_times_out_after_retries():
    mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    up = MissionUpload(ITEMS, 1, 1, mav, retry_s=1.0, max_retries=2)
    (count,) = up.start(0.0)
    assert count.get_type() == "MISSION_COUNT" and count.count == len(ITEMS)
    assert up.poll(0.5) == []
    assert [m.get_type() for m in up.poll(1.0)] == ["MISSION_COUNT"]
    assert [m.get_type() for m in up.poll(2.0)] == ["MISSION_COUNT"]
    assert up.poll(3.0) == [] and up.result is not None
    assert up.result.result == "TIMEOUT" and "MISSION_COUNT after 2 resends" in up.result.detail


def test_cli_upload_reports_success_and_refusal(vehicle_factory, tmp_path, capsys):
    from pdcov.cli import main
    from pdcov.planning.plan_files import write_plan

    path = write_plan(tmp_path / "m.plan", PLAN, ORIGIN)
    ok = vehicle_factory()
    assert main(["upload", str(path), "--connect", url(ok), "--timeout-s", "5"]) == 0
    assert "vehicle accepted" in capsys.readouterr().out
    assert len(ok.received) == len(ITEMS)
    full = vehicle_factory(capacity=2)
    assert main(["upload", str(path), "--connect", url(full), "--timeout-s", "5"]) == 1
    assert "MAV_MISSION_NO_SPACE" in capsys.readouterr().err


def test_terrain_frame_is_not_sent_to_px4(vehicle_factory):
    """The HEARTBEAT says PX4, whose mission refuses MAV_FRAME_GLOBAL_TERRAIN_ALT: pdcov
    says which item before sending anything; ArduPilot takes the same items."""
    terrain = tuple(replace(it, frame=10) if it.command == 16 else it for it in ITEMS)
    px4 = vehicle_factory()
    with pytest.raises(UploadError, match=r"runs px4.*item 2: MAV_FRAME_GLOBAL_TERRAIN_ALT"):
        upload_mission(terrain, url(px4), home_item(ORIGIN), timeout_s=5)
    assert px4.counts_seen == 0 and not px4.received
    ardupilot = vehicle_factory(autopilot=mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert upload_mission(terrain, url(ardupilot), home_item(ORIGIN), timeout_s=5).accepted
