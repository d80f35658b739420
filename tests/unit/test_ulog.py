"""PX4 ULog reading: GPS fallback when the log has no global position, and a log cut short
(ULogs written by tests/support/ulog_fixture.py; pyulog reads them back as the oracle)."""

from __future__ import annotations

import numpy as np
import pytest
from pyulog import ULog

from pdcov.errors import TelemetryError
from pdcov.flight.ground_altitude import DEFAULT_HOME_WAIT_S, GroundAltitude
from pdcov.flight.log_frames import ground_alt_of_log
from pdcov.telemetry.logs import read_flight_log
from tests.support.ulog_fixture import write_ulog

T0_US = 1_000_000
ATTITUDE = ([("uint64_t", "timestamp"), ("float[4]", "q")],
            [(T0_US + 100_000 * i, 1.0, 0.0, 0.0, 0.0) for i in range(50)])
# PX4 up to 1.13: lat/lon in 1e-7 deg, alt in mm; fix_type 3 = 3D fix.
GPS_OLD = ([("uint64_t", "timestamp"), ("int32_t", "lat"), ("int32_t", "lon"),
            ("int32_t", "alt"), ("uint8_t", "fix_type")],
           [(T0_US + 200_000 * i, 473_977_420 + 10 * i, 85_455_940, 488_000, 1 if i < 3 else 3)
            for i in range(25)])
# PX4 1.14+ sensor_gps: degrees and metres as doubles.
GPS_NEW = ([("uint64_t", "timestamp"), ("double", "latitude_deg"), ("double", "longitude_deg"),
            ("double", "altitude_msl_m"), ("uint8_t", "fix_type")],
           [(T0_US + 200_000 * i, 47.397742, 8.545594, 488.0 + i, 2 if i == 0 else 4)
            for i in range(25)])
GLOBAL = ([("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"), ("float", "alt")],
          [(T0_US + 100_000 * i, 47.4, 8.5, 500.0) for i in range(50)])


def test_fixture_is_a_ulog_pyulog_reads(tmp_path):
    ulog = ULog(str(write_ulog(tmp_path / "a.ulg", {"vehicle_attitude": ATTITUDE,
                                                    "vehicle_gps_position": GPS_OLD})))
    lengths = {d.name: len(d.data["timestamp"]) for d in ulog.data_list}
    assert lengths == {"vehicle_attitude": 50, "vehicle_gps_position": 25}
    assert not ulog.file_corruption


def test_gps_positions_with_a_fix_when_there_is_no_global_position(tmp_path):
    # Such logs were refused for "no position messages".
    log = read_flight_log(write_ulog(tmp_path / "old.ulg", {"vehicle_attitude": ATTITUDE,
                                                            "vehicle_gps_position": GPS_OLD}))
    assert len(log.position.t_s) == 22  # the 3 samples without a fix are skipped
    assert log.position.t_s[0] == pytest.approx(1.6)
    assert np.allclose(log.position.lat_deg[:2], [47.397745, 47.397746], atol=1e-9)
    assert np.allclose(log.position.alt_msl_m, 488.0)
    note = next(n for n in log.notes if "vehicle_gps_position" in n)
    assert "no vehicle_global_position" in note and "3 without a fix skipped" in note

    log = read_flight_log(write_ulog(tmp_path / "new.ulg", {"vehicle_attitude": ATTITUDE,
                                                            "sensor_gps": GPS_NEW}))
    assert len(log.position.t_s) == 24
    assert np.allclose(log.position.lon_deg, 8.545594)
    assert log.position.alt_msl_m[0] == pytest.approx(489.0)
    assert any("positions from sensor_gps" in n for n in log.notes)


def test_global_position_is_preferred_and_no_fix_is_still_no_position(tmp_path):
    log = read_flight_log(write_ulog(tmp_path / "g.ulg", {
        "vehicle_attitude": ATTITUDE, "vehicle_global_position": GLOBAL,
        "vehicle_gps_position": GPS_OLD}))
    assert len(log.position.t_s) == 50 and np.allclose(log.position.alt_msl_m, 500.0)
    assert not any("gps" in n.lower() for n in log.notes)
    fields, rows = GPS_OLD
    no_fix = (fields, [(*r[:4], 1) for r in rows])
    with pytest.raises(TelemetryError, match="no position"):
        read_flight_log(write_ulog(tmp_path / "nofix.ulg", {"vehicle_attitude": ATTITUDE,
                                                            "vehicle_gps_position": no_fix}))


def test_a_ulog_cut_short_says_so(tmp_path):
    whole = write_ulog(tmp_path / "whole.ulg", {"vehicle_attitude": ATTITUDE,
                                                "vehicle_global_position": GLOBAL})
    data = whole.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:len(data) * 2 // 3 + 3])  # mid-message
    full, short = read_flight_log(whole), read_flight_log(cut)
    assert not any("cut short" in n for n in full.notes) and full.damage == ()
    assert 0 < len(short.attitude.t_s) < len(full.attitude.t_s)
    (line,) = [n for n in short.notes if "cut short" in n]
    assert f"of {cut.stat().st_size})" in line and line in short.damage


def test_a_ulogs_arming_gives_the_home_in_force_at_arming(tmp_path):
    """vehicle_status.arming_state 2 (armed) from 2 s: the home then (vehicle_status read
    as the daemon reads HEARTBEAT), not the one PX4 moved it to later."""
    status = ([("uint64_t", "timestamp"), ("uint8_t", "arming_state")],
              [(T0_US + 500_000 * i, 2 if i >= 2 else 1) for i in range(10)])
    home = ([("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"),
             ("float", "alt")],
            [(T0_US + 1_500_000, 47.4, 8.5, 480.0), (T0_US + 4_000_000, 47.4, 8.5, 470.0)])
    log = read_flight_log(write_ulog(tmp_path / "armed.ulg", {
        "vehicle_attitude": ATTITUDE, "vehicle_global_position": GLOBAL,
        "vehicle_status": status, "home_position": home}))
    assert log.armed_states == ((1.0, False), (2.0, True))
    ground = ground_alt_of_log(log, GroundAltitude(None, DEFAULT_HOME_WAIT_S))
    assert ground == (480.0, "the autopilot's home at arming (home_position)")
    # Without vehicle_status: as a link without HEARTBEAT, the latest home.
    log = read_flight_log(write_ulog(tmp_path / "bare.ulg", {
        "vehicle_attitude": ATTITUDE, "vehicle_global_position": GLOBAL,
        "home_position": home}))
    assert log.armed_states is None
    alt, _how = ground_alt_of_log(log, GroundAltitude(None, DEFAULT_HOME_WAIT_S))
    assert alt == 470.0


def test_a_log_whose_vehicle_never_armed_takes_the_latest_home_and_says_so(tmp_path):
    """The daemon waits for arming; a log has ended: the latest home, said so."""
    status = ([("uint64_t", "timestamp"), ("uint8_t", "arming_state")],
              [(T0_US + 500_000 * i, 1) for i in range(10)])
    home = ([("uint64_t", "timestamp"), ("double", "lat"), ("double", "lon"),
             ("float", "alt")],
            [(T0_US + 1_500_000, 47.4, 8.5, 480.0), (T0_US + 4_000_000, 47.4, 8.5, 470.0)])
    log = read_flight_log(write_ulog(tmp_path / "disarmed.ulg", {
        "vehicle_attitude": ATTITUDE, "vehicle_global_position": GLOBAL,
        "vehicle_status": status, "home_position": home}))
    assert log.armed_states == ((1.0, False),)
    alt, how = ground_alt_of_log(log, GroundAltitude(None, DEFAULT_HOME_WAIT_S))
    assert alt == 470.0 and "never armed" in how
    # A configured ground altitude is taken at once, armed or not.
    assert ground_alt_of_log(log, GroundAltitude(488.0, DEFAULT_HOME_WAIT_S)) == (
        488.0, "configured")


def test_gps_time_utc_usec_gives_the_utc_of_the_boot_clock(tmp_path):
    # vehicle_gps_position.time_utc_usec (0 until the receiver knows the time) beside its
    # timestamp: timestamp 1.6 s was 2026-12-06T21:40:00.000Z.
    from pdcov.flight.log_frames import utc_clock_of

    t0_us = 1_796_593_200_000_000
    fields, rows = GPS_OLD
    timed = ([*fields, ("uint64_t", "time_utc_usec")],
             [(*r, 0 if i < 3 else t0_us + r[0] - 1_600_000) for i, r in enumerate(rows)])
    log = read_flight_log(write_ulog(tmp_path / "t.ulg", {"vehicle_attitude": ATTITUDE,
                                                          "vehicle_gps_position": timed}))
    assert len(log.utc) == 25
    clock = utc_clock_of(log)
    assert clock.unset == 3
    assert clock.text(2.1) == "2026-12-06T21:40:00.500Z"
