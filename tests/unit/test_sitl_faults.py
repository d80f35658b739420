"""``--faults``: the grammar, its error messages, and the injector's decisions in memory."""

from __future__ import annotations

from itertools import pairwise

import pytest

from pdcov_sitl.faults import (
    FaultInjector,
    FaultSpec,
    FaultSpecError,
    GimbalHealth,
    NanFault,
    Window,
)

FULL = ("drop=0.05,corrupt=0.001,outage=30+10,gps_glitch=60+5,reboot=120,gimbal_fail=200,"
        "nan=attitude@90,reorder=0.01,duplicate=0.01")


def test_the_documented_example_parses():
    spec = FaultSpec.parse(FULL)
    assert (spec.drop, spec.corrupt, spec.reorder, spec.duplicate) == (0.05, 0.001, 0.01, 0.01)
    assert spec.outages == (Window(30.0, 10.0),)
    assert spec.gps_glitches[0].window == Window(60.0, 5.0)
    assert spec.reboots == (Window(120.0, 2.0),)
    assert spec.gimbal_failures == (Window(200.0, 2.0),)
    assert spec.nans == (NanFault("ATTITUDE", "roll", Window(90.0, 0.0)),)


def test_repeated_events_fields_and_magnitudes():
    spec = FaultSpec.parse("outage=1+2, outage=10+1,nan=LOCAL_POSITION_NED.vx@5+1,"
                           "gps_glitch=3+4:50,reboot=7+0.5")
    assert spec.outages == (Window(1.0, 2.0), Window(10.0, 1.0))
    assert spec.nans[0] == NanFault("LOCAL_POSITION_NED", "vx", Window(5.0, 1.0))
    assert spec.gps_glitches[0].jump_m == 50.0
    assert spec.reboots == (Window(7.0, 0.5),)
    assert FaultSpec.parse("") == FaultSpec()


@pytest.mark.parametrize(("text", "says"), [
    ("drop=2", "'drop=2': probability '2' must be in [0, 1]"),
    ("drop=x", "'drop=x': probability 'x' is not a number"),
    ("drop=0.1,drop=0.2", "'drop=0.2': drop given twice"),
    ("outage=30", "'outage=30': expected START+DURATION"),
    ("outage=30+-1", "DURATION '-1' must be finite and >= 0"),
    ("jam=3", "unknown fault 'jam'"),
    ("drop", "'drop': expected NAME=VALUE"),
    ("nan=attitude", "expected MESSAGE[.FIELD]@START"),
    ("nan=attitudes@3", "'ATTITUDES' is no MAVLink message"),
    ("nan=attitude.time_boot_ms@3", "ATTITUDE has no float field 'time_boot_ms'"),
    ("nan=heartbeat@3", "HEARTBEAT has no float field"),
    ("gps_glitch=1+2:far", "JUMP_M 'far' is not a number"),
])
def test_errors_name_the_bad_item(text, says):
    with pytest.raises(FaultSpecError) as err:
        FaultSpec.parse(text)
    assert says in str(err.value)


def test_gps_glitch_and_gimbal_failure_over_time():
    spec = FaultSpec.parse("gps_glitch=60+5:30,gimbal_fail=200+3")
    assert spec.gps_offset_ned_m(59.9) == (0.0, 0.0, 0.0)
    assert spec.gps_offset_ned_m(60.0) == (30.0, 0.0, 0.0)
    assert spec.gps_offset_ned_m(65.0) == (0.0, 0.0, 0.0)
    assert [spec.gimbal_health(t) for t in (199.0, 200.0, 202.9, 203.0, 500.0)] == [
        GimbalHealth.OK, GimbalHealth.FAILED, GimbalHealth.FAILED, GimbalHealth.SILENT,
        GimbalHealth.SILENT]


def packets(n):
    return [bytes([0xFD, 4, 0, 0, i % 256, 1, 1, 30, 0, 0, 1, 2, 3, 4, 9, 9]) for i in range(n)]


def transmit_all(injector, pkts, t_s=0.0):
    out = []
    for p in pkts:
        out += injector.transmit(p, t_s)
    return out


def test_drop_rate_and_determinism():
    pkts = packets(20_000)
    out = transmit_all(FaultInjector(FaultSpec(drop=0.05), seed=1), pkts)
    assert len(out) / len(pkts) == pytest.approx(0.95, abs=0.006)
    assert out == transmit_all(FaultInjector(FaultSpec(drop=0.05), seed=1), pkts)
    assert out != transmit_all(FaultInjector(FaultSpec(drop=0.05), seed=2), pkts)


def test_corrupt_flips_bytes_at_the_rate():
    pkts = packets(10_000)
    out = transmit_all(FaultInjector(FaultSpec(corrupt=0.01), seed=1), pkts)
    flipped = sum(a != b for p, q in zip(pkts, out, strict=True) for a, b in zip(p, q, strict=True))
    assert flipped / (16 * len(pkts)) == pytest.approx(0.01, rel=0.1)


def test_duplicate_and_reorder():
    pkts = packets(10_000)
    out = transmit_all(FaultInjector(FaultSpec(duplicate=0.02), seed=1), pkts)
    assert (len(out) - len(pkts)) / len(pkts) == pytest.approx(0.02, abs=0.005)
    out = transmit_all(FaultInjector(FaultSpec(reorder=0.02), seed=1), pkts)
    assert sorted(out) == sorted(pkts[:len(out)]) and len(out) >= len(pkts) - 1
    swaps = sum(1 for a, b in pairwise(out) if a[4] == (b[4] + 1) % 256)
    assert swaps / len(pkts) == pytest.approx(0.02, abs=0.006)


def test_outage_silences_both_directions():
    injector = FaultInjector(FaultSpec.parse("outage=10+5"), seed=0)
    assert injector.transmit(b"x", 9.9) == [b"x"] and injector.receive_ok(9.9)
    assert injector.transmit(b"x", 10.0) == [] and not injector.receive_ok(14.9)
    assert injector.transmit(b"x", 15.0) == [b"x"]


def test_nan_once_or_during_a_window():
    injector = FaultInjector(FaultSpec.parse("nan=attitude@5,nan=local_position_ned.vz@8+1"),
                             seed=0)
    assert injector.nan_field("ATTITUDE", 4.9) is None
    assert injector.nan_field("SYS_STATUS", 5.0) is None
    assert injector.nan_field("ATTITUDE", 5.01) == "roll"
    assert injector.nan_field("ATTITUDE", 5.02) is None
    assert [injector.nan_field("LOCAL_POSITION_NED", t) for t in (7.9, 8.0, 8.5, 9.0)] == [
        None, "vz", "vz", None]
