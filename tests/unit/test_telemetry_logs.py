"""Log readers on synthetic tlogs: clocks, reboots, sources, junk and corrupt files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pdcov.core.mount import GimbalMount
from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.errors import TelemetryError
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.telemetry.clocks import REBOOT_GAP_S, BootClock
from pdcov.telemetry.logs import read_flight_log
from pdcov.telemetry.samples import AttitudeSample, GimbalSample, ParamSample, PositionSample
from tests.support.mavlink_fixtures import Heartbeat, encode, tlog_bytes, write_tlog
from tests.support.telemetry_flights import ALT, LAT, LON, flight, gimbal_flight


def test_boot_clock_restart() -> None:
    c = BootClock()
    assert [c.to_s(t) for t in (1.0, 2.0, 1.5, 3.0)] == [1.0, 2.0, 1.5, 3.0]  # reordering
    t = c.to_s(0.5)  # reboot
    assert t == pytest.approx(3.0 + REBOOT_GAP_S + 0.5) and c.restarts_t_s == [t]


def test_round_trip(tmp_path: Path) -> None:
    samples = flight()
    samples.append(GimbalSample(1.05, tuple(quat_wxyz_from_euler_zyx(0, -1.0, 0)), 44, 0, 1, 1, 1))
    samples.append(ParamSample(1.0, "MNT1_TYPE", 1.0))
    log = read_flight_log(write_tlog(tmp_path / "a.tlog", samples))
    assert log.format == "tlog" and log.system_id == 1
    np.testing.assert_allclose(log.attitude.t_s, 1.0 + 0.1 * np.arange(50), atol=1e-9)
    q = np.array([s.q_ned_body_wxyz for s in samples if isinstance(s, AttitudeSample)])
    np.testing.assert_allclose(log.attitude.q_ned_body_wxyz, q, atol=1e-6)
    np.testing.assert_allclose(log.position.lat_deg, LAT + 1e-6 * np.arange(50), atol=1e-7)
    np.testing.assert_allclose(log.position.alt_msl_m, ALT + 10.0, atol=1e-3)
    assert log.gimbal_source == (1, 1, 1) and list(log.gimbal.flags) == [44]
    assert log.params == {"MNT1_TYPE": 1.0}
    assert log.homes[-1].alt_msl_m == pytest.approx(ALT)


def test_junk_prefix_and_unknown_bytes(tmp_path: Path) -> None:
    junk = b"console output: booting...\r\n" * 40 + bytes(range(256))
    log = read_flight_log(write_tlog(tmp_path / "j.tlog", flight(), prefix=junk))
    assert len(log.attitude.t_s) == 50
    assert any("not MAVLink" in n for n in log.notes)


def test_wall_clock_stamps_are_ignored(tmp_path: Path) -> None:
    path = tmp_path / "fast.tlog"
    path.write_bytes(tlog_bytes([Heartbeat(1.0), *flight(n=300, dt=1.0)],
                                wall_clock_scale=1 / 25))
    log = read_flight_log(path)
    assert log.attitude.t_s[-1] - log.attitude.t_s[0] == pytest.approx(299.0)


def test_reboot_keeps_last_boot_time(tmp_path: Path) -> None:
    first = tlog_bytes([Heartbeat(1.0), *flight(t0=1.0, n=50)])
    second = tlog_bytes(flight(t0=100.0, n=30), boot_offset_s=98.0)  # boots again: 2.0 s
    path = tmp_path / "reboot.tlog"
    path.write_bytes(first + second)
    log = read_flight_log(path)
    assert len(log.restarts_t_s) == 1 and any("restarted" in n for n in log.notes)
    # The last boot keeps its own time_boot_ms; the first is placed before it.
    assert log.attitude.t_s[-1] == pytest.approx(2.0 + 2.9)
    assert np.all(np.diff(log.attitude.t_s) > 0)
    assert log.attitude.t_s[49] < 2.0 - REBOOT_GAP_S + 1e-9


def test_follows_the_autopilot_among_sources(tmp_path: Path) -> None:
    path = tmp_path / "two.tlog"
    gcs = Heartbeat(0.5, 255, 190, autopilot=8, vehicle_type=6)
    other = [encode(s, system_id=2) for s in flight(n=5)]
    data = tlog_bytes([gcs, Heartbeat(0.6), *flight()])
    path.write_bytes(data + b"".join(b"\0" * 8 + f for f in other))
    log = read_flight_log(path)
    assert log.system_id == 1 and len(log.attitude.t_s) == 50
    assert any("following system 1" in n for n in log.notes)
    assert read_flight_log(path, system_id=2).attitude.t_s.size == 5
    with pytest.raises(TelemetryError, match="system id 7"):
        read_flight_log(path, system_id=7)


def test_gimbal_device_report_preferred_and_reclocked(tmp_path: Path) -> None:
    samples = flight()
    q = tuple(quat_wxyz_from_euler_zyx(0, -1.0, 0))
    for k in range(50):
        t = 1.0 + 0.1 * k
        samples.append(GimbalSample(t, q, 44, 0, 1, 1, 1))  # the autopilot's report
        # The gimbal's own report, stamped in its own boot clock (started 500 s later).
        samples.append(GimbalSample(t - 0.02 + 1e-4, q, 32, 0, 1, 154, 0))
    path = tmp_path / "g.tlog"
    data = tlog_bytes(s for s in samples if not (isinstance(s, GimbalSample)
                                                 and s.component_id == 154))
    own = [s for s in samples if isinstance(s, GimbalSample) and s.component_id == 154]
    # Interleave the device's frames with its own clock 500 s behind the autopilot's.
    frames = b"".join(b"\0" * 8 + encode(s, boot_offset_s=-500.0) for s in own)
    path.write_bytes(tlog_bytes([Heartbeat(0.5)]) + frames[: len(frames) // 2] + data
                     + frames[len(frames) // 2:])
    log = read_flight_log(path)
    assert log.gimbal_source == (1, 154, 0)
    assert any("following (1, 154, 0)" in n for n in log.notes)
    assert np.all(log.gimbal.flags == 32)
    # Device times mapped onto the autopilot clock, not left 500 s off.
    assert abs(np.median(log.gimbal.t_s) - np.median(log.attitude.t_s)) < 5.0


def test_gimbal_instance_chooses_among_the_autopilots_gimbals(tmp_path: Path) -> None:
    samples = flight()
    for k in range(50):
        t = 1.0 + 0.1 * k
        samples.append(GimbalSample(t, tuple(quat_wxyz_from_euler_zyx(0, -1.0, 0)), 44, 0,
                                    1, 1, 1))
        samples.append(GimbalSample(t, tuple(quat_wxyz_from_euler_zyx(0, -0.5, 0)), 44, 0,
                                    1, 1, 2))
    path = write_tlog(tmp_path / "two.tlog", samples)
    assert read_flight_log(path).gimbal_source == (1, 1, 1)
    assert read_flight_log(path, gimbal_instance=2).gimbal_source == (1, 1, 2)


@pytest.mark.parametrize("content, match", [
    (b"", "empty file"),
    (bytes(np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8)), "no MAVLink"),
    (b"FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format\nPARM, RATE_RLL_P, 0.15\n" * 20,
     "text DataFlash"),
    (b"\xa3\x95" + b"\x00" * 100, "DataFlash|no attitude"),
])
def test_bad_files_name_the_file(tmp_path: Path, content: bytes, match: str) -> None:
    path = tmp_path / "bad.log"
    path.write_bytes(content)
    with pytest.raises(TelemetryError, match=match) as exc:
        read_flight_log(path)
    assert str(path) in str(exc.value)


def test_missing_file() -> None:
    with pytest.raises(TelemetryError, match="cannot open"):
        read_flight_log("/nonexistent/flight.tlog")


def test_truncated_log_keeps_what_was_read(tmp_path: Path) -> None:
    data = tlog_bytes([Heartbeat(0.5), *flight()])
    path = tmp_path / "cut.tlog"
    path.write_bytes(data[: len(data) * 2 // 3 + 5])
    log = read_flight_log(path)
    assert 10 < len(log.attitude.t_s) < 50


def test_no_position_is_an_error(tmp_path: Path) -> None:
    only_att = [s for s in flight() if isinstance(s, AttitudeSample)]
    with pytest.raises(TelemetryError, match="no position"):
        read_flight_log(write_tlog(tmp_path / "np.tlog", only_att))


def test_zero_position_before_fix_is_dropped(tmp_path: Path) -> None:
    samples = [PositionSample(0.5, 0.0, 0.0, 0.0, 0.0), *flight()]
    log = read_flight_log(write_tlog(tmp_path / "z.tlog", samples))
    assert log.position.t_s[0] == pytest.approx(1.0)
    assert not math.isnan(log.position.relative_alt_m[0])


# --- damaged tlogs: resynchronise, read up to the damage, say where it stopped --------------


@pytest.mark.parametrize("junk", [
    b"\xfe\x05" + b"\x00" * 20,  # a MAVLink 1 magic first: pymavlink then drops MAVLink 2
    b"\x00" * 8 + b"\xfe\x09\x00\x01\x01\x00" + bytes(11),  # a MAVLink 1 header, bad checksum
    bytes(np.random.default_rng(7).integers(0, 256, 3000, dtype=np.uint8)),
])
def test_junk_at_start_keeps_mavlink2_messages(tmp_path: Path, junk: bytes) -> None:
    log = read_flight_log(write_tlog(tmp_path / "j.tlog", gimbal_flight(), prefix=junk))
    assert len(log.attitude.t_s) == 50
    assert len(log.gimbal.t_s) == 50  # GIMBAL_DEVICE_ATTITUDE_STATUS is MAVLink 2 only
    assert any("not MAVLink" in n and "at byte 0" in n for n in log.damage)


def test_junk_appended_is_read_up_to_and_located(tmp_path: Path) -> None:
    data = tlog_bytes([Heartbeat(0.5), *gimbal_flight()])
    junk = bytes(np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8))
    path = tmp_path / "tail.tlog"
    path.write_bytes(data + junk)
    log = read_flight_log(path)
    assert len(log.attitude.t_s) == 50 and len(log.gimbal.t_s) == 50
    assert any(f"reading stopped at byte {len(data)} of {len(data) + 4096}" in n
               for n in log.notes)


def test_junk_inserted_anywhere_loses_only_the_damaged_record(tmp_path: Path) -> None:
    """Random junk at random places: every message outside the damage is read, and no
    message is made up from the junk."""
    records = [struct_record(s) for s in [Heartbeat(0.5), *flight(n=200)]]
    rng = np.random.default_rng(11)
    for trial in range(6):
        cuts = sorted(rng.choice(len(records), 3, replace=False))
        parts, damaged = [], set()
        for k, rec in enumerate(records):
            if k in cuts:  # junk inside this record: it is lost
                at = int(rng.integers(1, len(rec)))
                junk = bytes(rng.integers(0, 256, int(rng.integers(1, 600)), dtype=np.uint8))
                rec = rec[:at] + junk + rec[at:]
                damaged.add(k)
            parts.append(rec)
        path = tmp_path / f"mid{trial}.tlog"
        path.write_bytes(b"".join(parts))
        log = read_flight_log(path)
        n_att_damaged = sum(1 for k in damaged if k % 2 == 1)  # records 1, 3, ...: attitude
        assert len(log.attitude.t_s) >= 200 - n_att_damaged
        assert len(log.attitude.t_s) <= 200
        assert set(np.round(log.attitude.t_s, 3)) <= set(np.round(1.0 + 0.1 * np.arange(200), 3))
        assert any("runs of bytes that are not MAVLink" in n for n in log.damage)


def struct_record(sample: object) -> bytes:
    """One tlog record (stamp + frame) of a sample."""
    return b"\x00\x06" + b"\x00" * 6 + encode(sample)


def test_truncated_log_says_it_was_cut(tmp_path: Path) -> None:
    data = tlog_bytes([Heartbeat(0.5), *flight()])
    path = tmp_path / "cut.tlog"
    path.write_bytes(data[: len(data) - 7])
    log = read_flight_log(path)
    assert len(log.attitude.t_s) == 50 and len(log.position.t_s) == 49
    assert any("cut short" in n for n in log.damage)
    assert read_flight_log(write_tlog(tmp_path / "whole.tlog", flight())).damage == ()


def test_missing_gimbal_never_suggests_another_mount(tmp_path: Path) -> None:
    path = write_tlog(tmp_path / "ng.tlog", flight(), prefix=b"\x01" * 40)
    with pytest.raises(TelemetryError) as exc:
        poses_from_log(path, Framing(GimbalMount(), 5.0), origin_lat_deg=LAT,
                       origin_lon_deg=LON, ground_alt_msl_m=ALT)
    message = str(exc.value)
    assert "no gimbal attitude" in message and "fixed" not in message
    assert "not MAVLink" in message  # what reading the log skipped is named
