"""``pdcov-sitl replay``: tlog scanning with damage, pacing, and real logs sent over UDP to a
pymavlink listener on 127.0.0.1, arriving complete and in order."""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
from pathlib import Path

import pytest

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from pdcov_sitl.replay import main, replay_schedule, scan_tlog

REAL_LOGS = Path(__file__).resolve().parents[2] / "shared" / "real-logs"
T0_US = 1_767_225_600_000_000


def packets(n, msg_type="attitude"):
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for i in range(n):
        msg = mav.attitude_encode(i * 10, 0.1 * i, 0.0, 0.0, 0.0, 0.0, 0.0)
        out.append(bytes(msg.pack(mav)))
        mav.seq = (mav.seq + 1) % 256
    return out


def tlog_bytes(pkts, step_us=20_000):
    return b"".join(struct.pack(">Q", T0_US + i * step_us) + p for i, p in enumerate(pkts))


def test_scan_finds_every_record_of_a_clean_log():
    pkts = packets(50)
    scan = scan_tlog(tlog_bytes(pkts))
    assert [p for _, p in scan.records] == pkts and scan.skipped_bytes == 0
    assert scan.span_s == pytest.approx(49 * 0.02)


def test_scan_skips_junk_bad_checksums_and_broken_stamps():
    pkts = packets(6)
    records = [struct.pack(">Q", T0_US + i * 1000) + p for i, p in enumerate(pkts)]
    damaged = bytearray(records[2])
    damaged[20] ^= 0xFF  # payload byte: the checksum fails
    broken_stamp = b"\xff" * 8 + pkts[4]
    data = (b"console text\r\n\xfd\x09" + records[0] + records[1] + bytes(damaged)
            + records[3] + broken_stamp + records[5] + b"\x00\x01truncated\xfd")
    scan = scan_tlog(data)
    assert [p for _, p in scan.records] == [pkts[0], pkts[1], pkts[3], pkts[5]]
    assert scan.skipped_bytes == len(data) - sum(len(records[i]) for i in (0, 1, 3, 5))


def test_schedule_follows_the_log_pace():
    times = [T0_US, T0_US + 1_000_000, T0_US + 500_000, T0_US + 3_000_000]
    assert replay_schedule(times, 1.0) == [0.0, 1.0, 1.0, 3.0]  # never back in time
    assert replay_schedule(times, 10.0) == pytest.approx([0.0, 0.1, 0.1, 0.3])
    assert replay_schedule(times, 0.0) == [0.0] * 4
    with pytest.raises(ValueError, match="-1"):
        replay_schedule(times, -1.0)


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


@pytest.mark.parametrize(("args", "says"), [
    (["missing.tlog"], "cannot read missing.tlog"),
    (["{junk}"], "no MAVLink tlog records found"),
    (["{junk}", "--speed", "-2"], "--speed -2.0: expected a number >= 0"),
    (["{clean}", "--connect", "udp:1:2"], "link 'udp:1:2': expected"),
])
def test_bad_input_exits_2_with_a_message(tmp_path, capsys, monkeypatch, args, says):
    (tmp_path / "junk.tlog").write_bytes(b"not a tlog at all" * 10)
    (tmp_path / "clean.tlog").write_bytes(tlog_bytes(packets(2)))
    monkeypatch.chdir(tmp_path)
    args = [a.format(junk=tmp_path / "junk.tlog", clean=tmp_path / "clean.tlog")
            for a in args]
    assert main(args) == 2
    assert says in capsys.readouterr().err


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
