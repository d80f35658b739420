"""core/utc_clock.py: the autopilot's boot clock mapped to UTC from (t_s, boot_s, unix_s)
pairs, by hand-checkable cases; the adapters that make the pairs; the tracker and the
detections document carrying the UTC; datetime.fromisoformat as the independent reader."""

from __future__ import annotations

import math
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import numpy as np
import pytest

from pdcov.bus.detections import decode_detections, detections_document, encode_detections
from pdcov.bus.errors import BusPayloadError
from pdcov.core.detections import Box, Candidate, Detection
from pdcov.core.geodesy import Origin
from pdcov.core.utc_clock import (
    GPS_LEAP_S,
    MAX_BOOTS,
    STEP_S,
    UtcClock,
    gps_week_to_unix_s,
    utc_text,
)
from pdcov.detection.candidate_state import candidates_of_docs, state_doc
from pdcov.telemetry.adapters import sample_from_mavlink, samples_from_dataflash
from pdcov.telemetry.samples import PositionSample, UtcSample

T0 = datetime(2026, 12, 6, 21, 40, tzinfo=timezone.utc)
T0_S = T0.timestamp()  # 1_796_593_200


def test_one_system_time_pair_maps_a_detection_time_exactly() -> None:
    # SYSTEM_TIME time_boot_ms 10_000, time_unix_usec 2026-12-06T21:40:10.000Z: boot time
    # 0 was 21:40:00.000Z, so a frame at t_boot_s 121.25 was 21:42:01.250Z.
    c = UtcClock()
    c.add(10.0, 10.0, T0_S + 10.0)
    assert c.unix_s(121.25) == T0_S + 121.25
    assert c.text(121.25) == "2026-12-06T21:42:01.250Z"
    assert datetime.fromisoformat(c.text(121.25) or "") == T0 + timedelta(seconds=121.25)
    assert c.text(3.0) == "2026-12-06T21:40:03.000Z"  # before the pair, in its boot: known


def test_unset_time_maps_to_none_and_is_counted() -> None:
    c = UtcClock()
    for t in (1.0, 2.0, 3.0):
        c.add(t, t, math.nan)  # SYSTEM_TIME time_unix_usec 0: adapters say NaN
    c.add(4.0, 4.0, 0.0)
    c.add(5.0, 5.0, 315_964_800.0)  # GPS week 0: not a set clock
    assert c.unset == 5 and not c.known
    assert math.isnan(c.unix_s(4.0)) and c.text(4.0) is None
    c.add(6.0, 6.0, T0_S + 6.0)  # GPS time arrives: the whole boot is known
    assert c.known and c.unix_s(2.0) == T0_S + 2.0
    assert math.isnan(UtcClock().unix_s(1.0))


def test_a_reboot_keeps_each_boot_s_own_offset() -> None:
    # BootClock places a second boot 60 s after the first one's end: boot 1 ran 0..100 s
    # (time_boot_ms), boot 2's time_boot_ms 0 is t_s 160. Boot 1 knew UTC, boot 2 does not
    # at first, then learns it: 21:50:00Z at its time_boot_ms 0.
    c = UtcClock()
    c.add(50.0, 50.0, T0_S + 50.0)
    c.add(165.0, 5.0, math.nan)
    assert c.unix_s(99.0) == T0_S + 99.0  # boot 1's
    assert math.isnan(c.unix_s(170.0))  # boot 2's: unknown, not boot 1's offset
    c.add(170.0, 10.0, T0_S + 600.0 + 10.0)
    assert c.unix_s(161.0) == T0_S + 601.0
    assert c.unix_s(99.0) == T0_S + 99.0  # boot 1 still maps with its own


def test_raw_boot_times_going_back_start_a_new_boot() -> None:
    c = UtcClock()  # a caller feeding time_boot_ms as is: a reboot sends it back to 0
    c.add(100.0, 100.0, T0_S + 100.0)
    c.add(3.0, 3.0, T0_S + 1000.0)
    assert c.unix_s(4.0) == T0_S + 1001.0  # the latest boot's


def test_an_outlier_moves_nothing_and_jitter_never_steps() -> None:
    c = UtcClock()
    for k in range(1, 11):  # millisecond stamps: offsets within +-1 ms
        c.add(float(k), float(k), T0_S + k + (0.001 if k % 2 else -0.0005))
    first = c.unix_s(5.0) - 5.0
    c.add(11.0, 11.0, T0_S + 11.0 + 30.0)  # one SYSTEM_TIME 30 s off
    c.add(12.0, 12.0, T0_S + 12.0)
    assert c.unix_s(5.0) - 5.0 == first and c.unix_s(12.0) - 12.0 == first
    assert abs(first - T0_S) <= 0.001


def test_a_corrected_clock_is_followed_from_where_it_moved() -> None:
    c = UtcClock()
    for k in range(1, 6):
        c.add(float(k), float(k), T0_S + k)
    for k in range(6, 30):  # the clock corrected by 0.5 s at t 6
        c.add(float(k), float(k), T0_S + k + 0.5)
    assert c.unix_s(3.0) == T0_S + 3.0  # times before keep the offset they had
    assert abs(c.unix_s(29.0) - (T0_S + 29.5)) < STEP_S


def test_memory_is_bounded() -> None:
    c = UtcClock()
    for b in range(3 * MAX_BOOTS):
        for k in range(100):
            c.add(1000.0 * b + k, float(k), T0_S + 1000.0 * b + k + b * 0.1 * k)
    assert len(c._boots) == MAX_BOOTS
    assert all(len(b.offsets_s) <= b.offsets_s.maxlen for b in c._boots)  # type: ignore
    assert math.isnan(c.unix_s(5.0))  # the forgotten first boot: before every boot kept


def test_vectorised_mapping_agrees() -> None:
    c = UtcClock()
    c.add(5.0, 5.0, T0_S + 5.0)
    c.add(105.0, 2.0, T0_S + 500.0)
    t = np.array([-10.0, 1.0, 50.0, 104.0, 200.0])
    np.testing.assert_array_equal(c.unix_s_many(t), [c.unix_s(x) for x in t])


def test_gps_week_and_leap_seconds() -> None:
    # The servo-gimbal flight's DataFlash GPS record: GWk 2446, GMS 11_081_400 is
    # 2026-11-22 03:04:41.400 GPS time, 18 s ahead of UTC.
    assert gps_week_to_unix_s(2446, 11_081_400) == datetime(
        2026, 11, 22, 3, 4, 23, 400_000, tzinfo=timezone.utc).timestamp()
    # Before 2017-01-01 GPS led UTC by 17 s (the beast log's 2016 flight: GPS time
    # 2016-12-23 14:15:38.600).
    assert gps_week_to_unix_s(1928, 483_338_600) == datetime(
        2016, 12, 23, 14, 15, 21, 600_000, tzinfo=timezone.utc).timestamp()
    starts = [datetime.fromtimestamp(s, tz=timezone.utc) for s, _ in GPS_LEAP_S]
    assert [f"{d:%Y-%m-%d}" for d in starts] == [
        "2006-01-01", "2009-01-01", "2012-07-01", "2015-07-01", "2017-01-01"]
    assert [leap for _, leap in GPS_LEAP_S] == [14, 15, 16, 17, 18]


def test_utc_text() -> None:
    assert utc_text(T0_S + 0.2505) == "2026-12-06T21:40:00.250Z"  # to the millisecond
    assert utc_text(T0_S + 59.9996) == "2026-12-06T21:41:00.000Z"  # rounded, carried
    assert utc_text(None) is None and utc_text(math.nan) is None
    assert datetime.fromisoformat(utc_text(T0_S) or "") == T0


def test_adapters_make_the_pairs() -> None:
    st = SimpleNamespace(get_type=lambda: "SYSTEM_TIME", time_boot_ms=12_500,
                         time_unix_usec=round((T0_S + 12.5) * 1e6))
    assert sample_from_mavlink(st, 12.5) == UtcSample(12.5, 12.5, T0_S + 12.5)
    unset = SimpleNamespace(get_type=lambda: "SYSTEM_TIME", time_boot_ms=900,
                            time_unix_usec=0)
    u = sample_from_mavlink(unset, 0.9)
    assert isinstance(u, UtcSample) and math.isnan(u.unix_s)
    gps = SimpleNamespace(get_type=lambda: "GPS", TimeUS=19_609_000, I=0, Status=6,
                          GWk=2446, GMS=11_081_400, Lat=-35.36, Lng=149.17, Alt=584.0)
    pos, utc = samples_from_dataflash(gps, 19.609)
    assert isinstance(pos, PositionSample)
    assert isinstance(utc, UtcSample) and utc.t_s == 19.609
    assert utc.boot_s == pytest.approx(19.609, abs=1e-9)  # TimeUS * 1e-6
    assert utc.unix_s == gps_week_to_unix_s(2446, 11_081_400)
    no_fix = SimpleNamespace(**{**vars(gps), "Status": 1, "GWk": 0})
    (only,) = samples_from_dataflash(no_fix, 9.8)
    assert isinstance(only, UtcSample) and math.isnan(only.unix_s)


def _candidate(first: float, last: float) -> Candidate:
    return Candidate(0, "person", np.zeros(3), 0.5, 1, 1, 0.5, 0.01, 0.9, 10.0, 12.0,
                     "uav1.abc123.0", 0.7, first, last)


def test_the_document_carries_time_utc_and_receivers_check_it() -> None:
    det = Detection(12.0, Box("person", 0.9, 1, 2, 3, 4), np.zeros(3), 0.5, 0,
                    T0_S + 12.0)
    doc = detections_document([det], [_candidate(T0_S + 10.0, T0_S + 12.0)],
                              Origin(47.0, 8.0, 400.0), "uav1")
    back = decode_detections(encode_detections(doc))
    assert back["detections"][0]["time_utc"] == "2026-12-06T21:40:12.000Z"
    c = back["candidates"][0]
    assert (c["first_time_utc"], c["last_time_utc"]) == (
        "2026-12-06T21:40:10.000Z", "2026-12-06T21:40:12.000Z")
    unknown = detections_document([Detection(12.0, det.box, np.zeros(3), 0.5, 0)],
                                  [_candidate(math.nan, math.nan)], Origin(47, 8, 400), "uav1")
    assert unknown["detections"][0]["time_utc"] is None
    assert decode_detections(encode_detections(unknown))["candidates"][0][
        "last_time_utc"] is None
    old = encode_detections(unknown).replace(b'"time_utc":null,', b"")
    assert b"time_utc\":null," not in old.split(b'"candidates"')[0]
    decode_detections(old)  # an older daemon's document: no field, read
    bad = dict(doc, detections=[dict(doc["detections"][0], time_utc="yesterday")])
    with pytest.raises(BusPayloadError, match="time_utc"):
        decode_detections(encode_detections(bad))


def test_candidate_state_keeps_its_utc_and_reads_states_saved_before() -> None:
    from pdcov.detection.candidate_state import CandidateState

    g = CandidateState("person", 4.0, np.zeros(3), 1, 1, 0.9, 10.0, 10.0, 1.0, 0.0, None,
                       None, T0_S + 10.0, T0_S + 10.0)
    g.detected_at(12.0, T0_S + 12.0)
    g.detected_at(13.0, math.nan)  # a frame whose UTC was unknown changes no UTC time
    assert (g.first_unix_s, g.last_unix_s, g.last_t_boot_s) == (T0_S + 10.0, T0_S + 12.0,
                                                                13.0)
    (doc,) = state_doc({0: g}, 1)["candidates"]
    assert candidates_of_docs([doc], "c")[0].last_unix_s == T0_S + 12.0
    old = {k: v for k, v in doc.items() if not k.endswith("_unix_s")}
    assert math.isnan(candidates_of_docs([old], "c")[0].first_unix_s)
