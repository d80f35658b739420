"""The simulator's MAVLink endpoint over real sockets on 127.0.0.1 (UDP, TCP, a serial
pseudo-terminal), with pymavlink and pdcov's own link code as the ground station: stream
rates, set-interval, commands, parameters, mission upload and read-back, the tlog, and every
fault seen from the receiving side."""

from __future__ import annotations

import math
import os
import socket
import struct
import time
from collections import Counter

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.geodesy import Origin
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_items import home_item, mission_items
from pdcov.telemetry.link_params import read_mount_params, read_params
from pdcov.telemetry.upload import mavlink2_connection, upload_mission
from pdcov_sitl.endpoint import TLOG_EPOCH_UNIX_S, AutopilotEndpoint
from pdcov_sitl.faults import FaultSpec
from pdcov_sitl.link import LinkError, LinkUrl, open_link
from pdcov_sitl.protocol import message_id
from tests.support.sitl_feed import PARAMS, STREAMS_HZ, FeedThread

ORIGIN = Origin(-35.363261, 149.165230, 584.0)
PLAN = Plan((Waypoint(0.0, 0.0, 10.0, 5.0), Waypoint(0.0, 40.0, 10.0, 5.0, 2.0),
             Waypoint(10.0, 40.0, 10.0, 5.0), Waypoint(10.0, 0.0, 10.0, 5.0),
             Waypoint(20.0, 0.0, 10.0, 5.0)))


def listener():
    """A ground station listening on a free UDP port: (connection, port)."""
    conn = mavlink2_connection("udpin:127.0.0.1:0", 255, 190)
    return conn, conn.port.getsockname()[1]


def start_vehicle(url, autopilot="ardupilot", faults=None, tlog_path=None, streams=None,
                  seed=0):
    endpoint = AutopilotEndpoint(url, system_id=1, autopilot=autopilot, params=dict(PARAMS),
                                 streams=dict(STREAMS_HZ if streams is None else streams),
                                 faults=faults, seed=seed, tlog_path=tlog_path)
    feed = FeedThread(endpoint, autopilot)
    feed.start()
    return feed


def collect(conn, seconds, types=None):
    """(monotonic arrival time, message) for ``seconds``; BAD_DATA included."""
    out = []
    t_end = time.monotonic() + seconds
    while (left := t_end - time.monotonic()) > 0:
        msg = conn.recv_match(type=types, blocking=True, timeout=min(left, 0.1))
        if msg is not None:
            out.append((time.monotonic(), msg))
    return out


def wait_for(conn, kind, timeout_s=5.0, where=lambda m: True):
    t_end = time.monotonic() + timeout_s
    while (left := t_end - time.monotonic()) > 0:
        msg = conn.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and where(msg):
            return msg
    raise AssertionError(f"no {kind} within {timeout_s} s")


def command_ack(conn, cmd, *params, target=(1, 1)):
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(*target, cmd, 0, *p)
    return wait_for(conn, "COMMAND_ACK", where=lambda m: m.command == cmd)


def test_udp_streams_rates_set_interval_and_params():
    conn, port = listener()
    feed = start_vehicle(f"udpout:127.0.0.1:{port}")
    try:
        wait_for(conn, "HEARTBEAT")
        window_s = 6.0
        got = Counter(m.get_type() for _, m in collect(conn, window_s))
        for name, hz in STREAMS_HZ.items():
            if hz >= 1.0:
                assert got[name] == pytest.approx(hz * window_s, rel=0.2, abs=1), name
        assert got["BAD_DATA"] == 0
        # set-interval: ATTITUDE 25 -> 50 Hz, GPS_RAW_INT off, HOME_POSITION on at 2 Hz
        for name, interval_us in (("ATTITUDE", 20_000), ("GPS_RAW_INT", -1),
                                  ("HOME_POSITION", 500_000)):
            ack = command_ack(conn, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id(name),
                              interval_us)
            assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        ack = command_ack(conn, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 60_000, 1000)
        assert ack.result == mavlink2.MAV_RESULT_DENIED
        ack = command_ack(conn, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id("VFR_HUD"),
                          1000)
        assert ack.result == mavlink2.MAV_RESULT_UNSUPPORTED
        collect(conn, 0.3)
        got = Counter(m.get_type() for _, m in collect(conn, 4.0))
        assert got["ATTITUDE"] == pytest.approx(200, rel=0.2)
        assert got["GPS_RAW_INT"] == 0
        assert got["HOME_POSITION"] == pytest.approx(8, abs=2)
        # request-message: one HOME_POSITION now
        ack = command_ack(conn, mavlink2.MAV_CMD_REQUEST_MESSAGE, message_id("AUTOPILOT_VERSION"))
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        assert wait_for(conn, "AUTOPILOT_VERSION").uid == 1
        # parameters through pdcov's own reader
        mount = read_mount_params(conn, 1, target_system=1, timeout_s=3.0)
        assert mount.values["MNT1_TYPE"] == 1.0 and mount.values["MNT1_PITCH_MIN"] == -90.0
        assert read_params(conn, ["NO_SUCH_PARAM"], target_system=1, timeout_s=0.5) == {}
        conn.mav.param_request_list_send(1, 1)
        listed = collect(conn, 1.0, types="PARAM_VALUE")
        assert {m.param_id for _, m in listed} == set(PARAMS)
    finally:
        feed.stop()
        conn.close()


def test_tcp_server_serves_a_client_that_reconnects():
    feed = start_vehicle("tcp:127.0.0.1:0")
    port = feed.endpoint.link.local_address[1]
    try:
        for _ in range(2):
            conn = mavlink2_connection(f"tcp:127.0.0.1:{port}", 255, 190)
            try:
                assert wait_for(conn, "HEARTBEAT").autopilot == \
                    mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
                ack = command_ack(conn, mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL,
                                  message_id("ATTITUDE"))
                assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
                assert wait_for(conn, "MESSAGE_INTERVAL").interval_us == 40_000
            finally:
                conn.close()
    finally:
        feed.stop()


def test_pty_is_a_serial_port_for_the_client():
    feed = start_vehicle("pty:")
    path = feed.endpoint.link.slave_path
    try:
        conn = mavutil.mavlink_connection(path, baud=115200, source_system=255,
                                          source_component=190)
        conn.mav = mavlink2.MAVLink(conn, srcSystem=255, srcComponent=190)
        try:
            wait_for(conn, "HEARTBEAT")
            ack = command_ack(conn, mavlink2.MAV_CMD_REQUEST_MESSAGE, 60_000)
            assert ack.result == mavlink2.MAV_RESULT_DENIED
        finally:
            conn.close()
    finally:
        feed.stop()


def test_link_urls_are_checked():
    assert LinkUrl.parse("tcp:127.0.0.1:5760") == LinkUrl("tcpin", "127.0.0.1", 5760)
    for bad in ("udp:1.2.3.4:5", "udpout:127.0.0.1", "tcpin:host:99999", "serial"):
        with pytest.raises(LinkError, match="expected"):
            open_link(bad)


def read_back(conn, n_expected):
    conn.mav.mission_request_list_send(1, 1, 0)
    count = wait_for(conn, "MISSION_COUNT").count
    assert count == n_expected
    items = []
    for seq in range(count):
        conn.mav.mission_request_int_send(1, 1, seq, 0)
        items.append(wait_for(conn, "MISSION_ITEM_INT", where=lambda m, s=seq: m.seq == s))
    conn.mav.mission_ack_send(1, 1, mavlink2.MAV_MISSION_ACCEPTED, 0)
    return items


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_mission_upload_with_pdcov_upload_and_read_back(autopilot):
    feed = start_vehicle("udpin:127.0.0.1:0", autopilot=autopilot)
    port = feed.endpoint.link.local_address[1]
    try:
        items = mission_items(PLAN, ORIGIN)
        result = upload_mission(items, f"udpout:127.0.0.1:{port}", home_item(ORIGIN),
                                timeout_s=10.0)
        assert result.accepted, result.report()
        sent = (home_item(ORIGIN), *items) if autopilot == "ardupilot" else items
        assert feed.endpoint.mission is not None and len(feed.endpoint.mission) == len(sent)
        conn = mavlink2_connection(f"udpout:127.0.0.1:{port}", 255, 190)
        try:
            conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID,
                                    0, 0, 0)
            got = read_back(conn, len(sent))
        finally:
            conn.close()
        # ArduPilot-like asks with MISSION_REQUEST, PX4-like with MISSION_REQUEST_INT; pdcov's
        # uploader answers both with MISSION_ITEM_INT: integer degE7, exact
        for g, i in zip(got, sent, strict=True):
            assert (g.command, g.frame) == (i.command, i.frame)
            assert g.x == round(i.lat_deg * 1e7)
            assert g.y == round(i.lon_deg * 1e7)
            assert g.z == pytest.approx(i.z_m, abs=1e-4)
    finally:
        feed.stop()


def test_tlog_records_every_message_in_simulated_time(tmp_path):
    conn, port = listener()
    tlog = tmp_path / "flight.tlog"
    feed = start_vehicle(f"udpout:127.0.0.1:{port}", tlog_path=tlog,
                         faults=FaultSpec.parse("drop=0.5"))
    try:
        collect(conn, 2.0)
    finally:
        feed.stop()
        conn.close()
    n_sent = feed.endpoint.n_sent
    log = mavutil.mavlink_connection(str(tlog))
    stamps = []
    while (msg := log.recv_msg()) is not None:
        stamps.append(msg._timestamp)
    assert len(stamps) == n_sent > 100  # all of them, although half were dropped
    assert stamps == sorted(stamps)
    assert TLOG_EPOCH_UNIX_S <= stamps[0] < stamps[-1] < TLOG_EPOCH_UNIX_S + 3.0
    data = tlog.read_bytes()
    assert struct.unpack(">Q", data[:8])[0] == pytest.approx(stamps[0] * 1e6, abs=1)


def sequences(received, kind="ATTITUDE"):
    return [m.get_seq() for _, m in received if m.get_type() == kind]


def test_link_faults_as_a_receiver_sees_them():
    conn, port = listener()
    faults = FaultSpec.parse("drop=0.1,corrupt=0.002,duplicate=0.05,reorder=0.05")
    feed = start_vehicle(f"udpout:127.0.0.1:{port}", faults=faults,
                         streams={"HEARTBEAT": 1.0, "ATTITUDE": 100.0})
    try:
        received = collect(conn, 5.0)
    finally:
        feed.stop()
        conn.close()
    seqs = [m.get_seq() for _, m in received if m.get_type() != "BAD_DATA"]
    pairs = list(zip(seqs, seqs[1:], strict=False))
    n_dup = sum(1 for a, b in pairs if a == b)
    n_back = sum(1 for a, b in pairs if (a - b) % 256 == 1)
    n_gap = sum(1 for a, b in pairs if (b - a) % 256 == 2)  # one lost between
    n_bad = sum(1 for _, m in received if m.get_type() == "BAD_DATA")
    n = feed.endpoint.n_sent
    assert n > 300
    assert n_dup / n == pytest.approx(0.05, abs=0.03)
    assert n_back / n == pytest.approx(0.05, abs=0.03)
    assert n_gap / n == pytest.approx(0.1, abs=0.05)
    assert n_bad > 0  # ~3 % of 40-byte packets have a flipped byte


def test_autopilot_faults_as_a_receiver_sees_them(tmp_path):
    conn, port = listener()
    streams = {**STREAMS_HZ, "GIMBAL_DEVICE_ATTITUDE_STATUS": 10.0}
    faults = FaultSpec.parse("outage=1+1,gps_glitch=2.5+0.5:50,nan=attitude@3,"
                             "reboot=3.5+0.5,gimbal_fail=4.5+0.5")
    tlog = tmp_path / "faults.tlog"
    feed = start_vehicle(f"udpout:127.0.0.1:{port}", faults=faults, streams=streams,
                         tlog_path=tlog)
    try:
        wait_for(conn, "HEARTBEAT")
        ack = command_ack(conn, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, message_id("ATTITUDE"),
                          10_000)  # 100 Hz, until the reboot forgets it
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
        received = [(t - feed.t0, m) for t, m in collect(conn, 6.5 - feed.now_s())]
    finally:
        feed.stop()
        conn.close()
    times = [t for t, _ in received]
    # outage: nothing arrives between 1 and 2 s of simulated (= wall) time
    assert not [t for t in times if 1.05 < t < 1.95]
    # gps glitch: 50 m north (4.5e-4 deg) between 2.5 and 3 s
    lat = [(t, m.lat * 1e-7) for t, m in received if m.get_type() == "GLOBAL_POSITION_INT"]
    jumped = [t for t, la in lat if la - ORIGIN.lat_deg > 4e-4]
    assert jumped and 2.5 <= min(jumped) and max(jumped) < 3.1
    # NaN: one ATTITUDE with roll NaN, just after 3 s
    nans = [t for t, m in received if m.get_type() == "ATTITUDE" and math.isnan(m.roll)]
    assert len(nans) == 1 and 3.0 <= nans[0] < 3.1
    # reboot: silence, then time_boot_ms restarts and ATTITUDE is back at its 25 Hz default
    boot = [(t, m.time_boot_ms) for t, m in received if m.get_type() == "ATTITUDE"]
    assert not [t for t, _ in boot if 3.55 < t < 3.95]
    after = [ms for t, ms in boot if t > 4.0]
    assert after and after[0] < 700
    rate_before = sum(1 for t, _ in boot if 2.0 < t < 3.0)
    rate_after = sum(1 for t, _ in boot if 5.0 < t < 6.0)
    assert rate_before == pytest.approx(100, rel=0.2)
    assert rate_after == pytest.approx(25, rel=0.2)
    # gimbal: failure flags from 4.5 s, silence from 5 s
    gimbal = [(t, m.failure_flags) for t, m in received
              if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert all(f == 0 for t, f in gimbal if t < 4.45)
    assert any(f != 0 for t, f in gimbal if 4.5 <= t < 5.05)
    assert not [t for t, _ in gimbal if t > 5.1]
    # the tlog holds what the autopilot sent: the NaN, and messages during the outage
    log = mavutil.mavlink_connection(str(tlog))
    in_outage = 0
    while (msg := log.recv_msg()) is not None:
        if 1.1 < msg._timestamp - TLOG_EPOCH_UNIX_S < 1.9:
            in_outage += 1
    assert in_outage > 20


def test_tcpout_client_connects_once_the_ground_station_listens():
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    feed = start_vehicle(f"tcpout:127.0.0.1:{port}")  # nobody listens yet: it retries
    try:
        time.sleep(0.5)
        conn = mavlink2_connection(f"tcpin:127.0.0.1:{port}", 255, 190)
        try:
            assert wait_for(conn, "HEARTBEAT", timeout_s=5.0).get_srcSystem() == 1
            ack = command_ack(conn, mavlink2.MAV_CMD_REQUEST_MESSAGE, 60_000)
            assert ack.result == mavlink2.MAV_RESULT_DENIED
        finally:
            conn.close()
    finally:
        feed.stop()
