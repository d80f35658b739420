"""``pdcov-sitl replay``: tlog scanning with damage, pacing, and real logs sent over UDP to a
pymavlink listener on 127.0.0.1, arriving complete and in order."""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

from pdcov_sitl.replay import main, scan_tlog
from tests.support.replay_packets import packets, tlog_bytes

REAL_LOGS = Path(__file__).resolve().parents[3] / "shared" / "real-logs"


class Listener(threading.Thread):
    """A pymavlink ground station on a free UDP port, keeping every packet's bytes."""

    def __init__(self):
        super().__init__(daemon=True)
        self.conn = mavutil.mavlink_connection("udpin:127.0.0.1:0")
        self.port = self.conn.port.getsockname()[1]
        self.packets: list[bytes] = []
        self.times: list[float] = []
        self.n_bad = 0
        self.stopping = threading.Event()

    def run(self):
        while not self.stopping.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None:
                continue
            if msg.get_type() == "BAD_DATA":
                self.n_bad += 1
                continue
            self.packets.append(bytes(msg.get_msgbuf()))
            self.times.append(time.monotonic())

    def stop(self):
        self.stopping.set()
        self.join(timeout=5)
        self.conn.close()


def replay_to_listener(path, speed, capsys):
    listener = Listener()
    listener.start()
    try:
        rc = main([str(path), "--connect", f"udpout:127.0.0.1:{listener.port}",
                   "--speed", str(speed)])
        time.sleep(0.5)  # the last datagrams reach the listener
    finally:
        listener.stop()
    assert rc == 0
    return listener, capsys.readouterr().out


def test_replay_of_a_real_ardupilot_log_arrives_complete_and_in_order(capsys):
    path = REAL_LOGS / "ardupilot_sitl_servo_gimbal.tlog"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    scan = scan_tlog(path.read_bytes())
    t_start = time.monotonic()
    listener, out = replay_to_listener(path, 0, capsys)
    took_s = time.monotonic() - t_start
    assert listener.n_bad == 0
    assert len(listener.packets) == len(scan.records) == 28573
    assert listener.packets == [p for _, p in scan.records]
    assert out.startswith("replayed 28573 messages spanning 152.1 s in ")
    assert took_s < 30  # far faster than the 152 s flight


def test_replay_keeps_the_pace_at_speed_n(tmp_path, capsys):
    path = tmp_path / "paced.tlog"
    path.write_bytes(tlog_bytes(packets(51), step_us=20_000))  # 1 s of log
    listener, out = replay_to_listener(path, 4, capsys)
    assert len(listener.packets) == 51
    assert listener.times[-1] - listener.times[0] == pytest.approx(0.25, abs=0.1)
    assert "spanning 1.0 s" in out


def test_a_log_with_console_junk_replays_its_mavlink_part():
    path = REAL_LOGS / "uavlogviewer_flight_logs.tlog"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    data = path.read_bytes()
    scan = scan_tlog(data)
    log = mavutil.mavlink_connection(str(path))
    n_pymavlink = 0  # messages pymavlink's own tlog reader decodes
    while (msg := log.recv_msg()) is not None:
        n_pymavlink += msg.get_type() != "BAD_DATA"
    assert 1000 < scan.skipped_bytes < 0.01 * len(data)
    assert len(scan.records) >= n_pymavlink - 10


def test_replay_as_a_tcp_server_waits_for_its_client(tmp_path):
    path = tmp_path / "tcp.tlog"
    pkts = packets(2000)
    path.write_bytes(tlog_bytes(pkts, step_us=1000))
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    rc: list[int] = []
    sender = threading.Thread(target=lambda: rc.append(main(
        [str(path), "--connect", f"tcp:127.0.0.1:{port}", "--speed", "0"])), daemon=True)
    sender.start()
    time.sleep(0.3)
    conn = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}")
    got = []
    try:
        t_end = time.monotonic() + 20
        while len(got) < len(pkts) and time.monotonic() < t_end:
            msg = conn.recv_match(blocking=True, timeout=0.2)
            if msg is not None and msg.get_type() != "BAD_DATA":
                got.append(bytes(msg.get_msgbuf()))
    finally:
        conn.close()
        sender.join(timeout=10)
    assert rc == [0]
    assert got == pkts
