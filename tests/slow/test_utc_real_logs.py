"""UTC of real autopilot logs (../shared/real-logs, see its README; skipped where absent):
each frame's UTC checked against the log's own SYSTEM_TIME / GPS records, read
independently with pymavlink, and the GPS week converted with datetime."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from pdcov.core.pose import FixedMount
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log, utc_clock_of
from pdcov.telemetry.logs import read_flight_log

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real-logs"
pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")

TLOG = REAL / "ardupilot_sitl_servo_gimbal.tlog"
BIN = REAL / "ardupilot_sitl_servo_gimbal.BIN"
HOME = dict(origin_lat_deg=-35.363261, origin_lon_deg=149.165230, ground_alt_msl_m=None)
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)


def _system_times(path: Path) -> list[tuple[float, float]]:
    """(time_boot_ms / 1000, time_unix_usec / 1e6) of the autopilot's set SYSTEM_TIMEs."""
    m = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := m.recv_match(type="SYSTEM_TIME")) is not None:
        if msg.get_srcComponent() == 1 and msg.time_unix_usec:
            out.append((msg.time_boot_ms / 1000, msg.time_unix_usec / 1e6))
    return out


def _gps_times(path: Path, leap_s: int) -> list[tuple[float, float]]:
    """(TimeUS / 1e6, UTC s) of the first receiver's GPS records with a week and a 3D fix."""
    m = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := m.recv_match(type="GPS")) is not None:
        if getattr(msg, "I", 0) == 0 and msg.GWk > 0 and msg.Status >= 3:
            utc = GPS_EPOCH + timedelta(weeks=msg.GWk, milliseconds=msg.GMS - 1000 * leap_s)
            out.append((msg.TimeUS / 1e6, utc.timestamp()))
    return out


def test_tlog_frames_are_at_the_system_time_utc() -> None:
    lp = poses_from_log(TLOG, Framing(FixedMount(), 5.0), **HOME)
    pairs = _system_times(TLOG)
    assert len(pairs) > 100
    assert any(line.startswith("UTC: from SYSTEM_TIME") for line in lp.summary_lines)
    boot_s, unix_s = np.array(pairs).T
    for pose in lp.poses[:: max(1, len(lp.poses) // 50)]:  # one boot: t_s is time_boot_ms
        k = int(np.argmin(abs(boot_s - pose.t_s)))  # the nearest SYSTEM_TIME
        mine = lp.utc.unix_s(pose.t_s)
        assert abs(mine - (unix_s[k] + pose.t_s - boot_s[k])) < 0.002, pose.t_s
    first = datetime.fromisoformat(lp.utc.text(lp.poses[0].t_s) or "")
    assert first.date().isoformat() == "2026-11-22"  # the simulator's GPS date


def test_dataflash_frames_are_at_the_gps_utc_and_agree_with_the_tlog() -> None:
    log = read_flight_log(BIN)
    clock = utc_clock_of(log)
    gps = _gps_times(BIN, 18)
    assert len(gps) > 100 and clock.known
    for t_s, utc in gps[:: len(gps) // 40]:
        assert abs(clock.unix_s(t_s) - utc) < 0.03, t_s
    # The same flight's tlog: its SYSTEM_TIME is the autopilot's clock stamped when sent,
    # the GPS records the fix's time (the receiver's latency earlier: 37 ms here).
    tlog = utc_clock_of(read_flight_log(TLOG))
    for t in (30.0, 90.0, 150.0):
        assert 0.0 < tlog.unix_s(t) - clock.unix_s(t) < 0.1


def test_a_2016_dataflash_log_takes_17_leap_seconds() -> None:
    path = REAL / "beast_log_0036_mechanical_failure.bin"
    clock = utc_clock_of(read_flight_log(path))
    for t_s, utc in _gps_times(path, 17)[::50]:
        assert abs(clock.unix_s(t_s) - utc) < 0.03
    assert (clock.text(250.0) or "").startswith("2016-12-23T14:")


def test_a_boot_without_gps_time_has_no_utc() -> None:
    # Two boots: the first never had GPS time (time_unix_usec 0), the second has.
    log = read_flight_log(REAL / "uavlogviewer_flight_logs.tlog")
    clock = utc_clock_of(log)
    (restart,) = log.restarts_t_s
    assert math.isnan(clock.unix_s(restart - 61.0))
    pairs = _system_times(REAL / "uavlogviewer_flight_logs.tlog")
    boot_s, unix_s = pairs[-1]  # the last boot keeps its own time_boot_ms as t_s
    assert clock.unix_s(boot_s) == pytest.approx(unix_s, abs=0.002)
    assert clock.unix_s(restart + 1.0) == pytest.approx(unix_s - boot_s + restart + 1.0,
                                                        abs=0.002)
