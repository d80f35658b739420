"""The DEM cross-check (telemetry/terrain_check.py) and the samples it reads: hand-made
samples over a DEM of known heights, numbers a person can check."""

from __future__ import annotations

import math
import os
from types import SimpleNamespace

import numpy as np
import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.telemetry.adapters import sample_from_mavlink, samples_from_dataflash
from pdcov.telemetry.logs.ulog import _ulog_rangefinder
from pdcov.telemetry.samples import (
    AttitudeSample,
    HomeSample,
    PositionSample,
    RangefinderSample,
    TerrainReportSample,
)
from pdcov.telemetry.terrain_check import CheckSource, Refused, TerrainCheck

LAT, LON, GROUND_M = 47.0, 8.0, 488.0
M_PER_DEG_LAT = 111_200.0  # about, at 47 deg: only used to build the sloped DEM


class PlaneDem:
    """Ground at ``ground_m`` m AMSL rising ``slope`` m per m northwards from LAT, within
    0.01 deg of (LAT, LON); NaN outside."""

    def __init__(self, ground_m: float = GROUND_M, slope: float = 0.0) -> None:
        self.ground_m, self.slope = ground_m, slope

    def height_msl_m(self, lat_deg, lon_deg) -> np.ndarray:
        lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
        h = self.ground_m + self.slope * (lat - LAT) * M_PER_DEG_LAT
        inside = (np.abs(lat - LAT) < 0.01) & (np.abs(lon - LON) < 0.01)
        return np.where(inside, h, np.nan)


def report(terrain_m: float, *, has_data: bool = True, t_s: float = 1.0
           ) -> TerrainReportSample:
    return TerrainReportSample(t_s, LAT, LON, terrain_m, 100.0, has_data)


def hover(check: TerrainCheck, alt_msl_m: float, roll_rad: float = 0.0,
          t_s: tuple[float, ...] = (1.0, 1.1)) -> None:
    q = tuple(float(v) for v in quat_wxyz_from_euler_zyx(roll_rad, 0.0, 0.0))
    for t in t_s:
        check.add(PositionSample(t, LAT, LON, alt_msl_m))
        check.add(AttitudeSample(t, q))  # type: ignore[arg-type]


def down(d_m: float, t_s: float = 1.05, **kw) -> RangefinderSample:
    return RangefinderSample(t_s, d_m, kw.pop("orientation", 25), kw.pop("in_range", True))


def test_dem_12_m_too_high_is_counted_and_said():
    check = TerrainCheck(PlaneDem(GROUND_M + 12.0))
    assert check.warning() is None
    check.add(report(GROUND_M))
    assert check.checked[CheckSource.TERRAIN_REPORT] == 1 and check.mismatches == 1
    assert check.largest is not None and check.largest.difference_m == pytest.approx(12.0)
    assert "+12.0 m (terrain_report at" in (check.warning() or "")
    assert "1 of 1 measurements" in check.summary_line()
    doc = check.as_dict()
    assert doc["mismatches"] == 1 and doc["largest"]["difference_m"] == 12.0
    assert doc["latest"]["source"] == "terrain_report"


def test_within_margin_is_silent():
    check = TerrainCheck(PlaneDem(GROUND_M + 9.9))
    check.add(report(GROUND_M))
    assert check.checked[CheckSource.TERRAIN_REPORT] == 1
    assert check.mismatches == 0 and check.warning() is None
    assert check.as_dict()["largest"] is None
    assert "agree with the DEM within 10 m" in check.summary_line()


def test_margin_is_configurable():
    check = TerrainCheck(PlaneDem(GROUND_M + 6.0), margin_m=5.0)
    check.add(report(GROUND_M))
    assert check.mismatches == 1
    with pytest.raises(ValueError, match="margin"):
        TerrainCheck(PlaneDem(), margin_m=0.0)


def test_largest_and_latest():
    check = TerrainCheck(PlaneDem())
    for t, terrain in ((1.0, GROUND_M - 30.0), (2.0, GROUND_M + 15.0), (3.0, GROUND_M)):
        check.add(report(terrain, t_s=t))
    assert check.mismatches == 2
    assert check.largest is not None and check.largest.difference_m == pytest.approx(30.0)
    assert check.latest is not None and check.latest.t_s == 2.0


def test_level_rangefinder_interpolated_between_positions():
    # Positions 100 m and 110 m above the ground at t 1.0 and 1.1: 105 m at the reading.
    check = TerrainCheck(PlaneDem())
    check.add(down(105.0))
    assert not check.checked  # waits for the position after it
    check.add(PositionSample(1.0, LAT, LON, GROUND_M + 100.0))
    check.add(AttitudeSample(1.0, (1.0, 0.0, 0.0, 0.0)))
    check.add(PositionSample(1.1, LAT, LON, GROUND_M + 110.0))
    assert not check.checked  # and for the attitude after it
    check.add(AttitudeSample(1.1, (1.0, 0.0, 0.0, 0.0)))
    assert check.checked[CheckSource.RANGEFINDER] == 1 and check.mismatches == 0
    check.add(down(93.0))  # 105 - 93 = 12 m: the ground measured 12 m above the DEM
    assert check.mismatches == 1
    assert check.latest is not None and check.latest.difference_m == pytest.approx(-12.0)


def test_tilted_rangefinder_measures_along_the_body_axis():
    # 200 m above flat ground, rolled 20 deg: the axis meets the ground 200 / cos 20 =
    # 212.84 m away. Taking 200 m as if vertical would put the ground 200 (1 - cos 20) =
    # 12.06 m too high.
    roll = math.radians(20.0)
    check = TerrainCheck(PlaneDem())
    hover(check, GROUND_M + 200.0, roll)
    check.add(down(200.0 / math.cos(roll), t_s=1.0))
    assert check.checked[CheckSource.RANGEFINDER] == 1 and check.mismatches == 0
    check.add(down(200.0, t_s=1.1))
    assert check.mismatches == 1
    assert check.latest is not None
    assert check.latest.difference_m == pytest.approx(-200.0 * (1 - math.cos(roll)), abs=0.01)
    # Rolled right (right wing down), the body's down axis leans left: facing north, the
    # ground point of the 200 m reading lies 200 sin 20 = 68.4 m west.
    east_m = (check.latest.lon_deg - LON) * M_PER_DEG_LAT * math.cos(math.radians(LAT))
    assert east_m == pytest.approx(-200.0 * math.sin(roll), rel=0.01)


def test_rangefinder_on_a_slope_uses_the_ground_point_it_hit():
    # Ground rising 0.2 m/m northwards, the vehicle facing north pitched 25 deg nose-up:
    # its down axis leans forward (north) and meets the slope uphill of the vehicle.
    pitch = math.radians(25.0)
    dem = PlaneDem(slope=0.2)
    check = TerrainCheck(dem)
    q = tuple(float(v) for v in quat_wxyz_from_euler_zyx(0.0, pitch, 0.0))
    h = 150.0  # above the ground under the vehicle
    for t in (1.0, 1.1):
        check.add(PositionSample(t, LAT, LON, GROUND_M + h))
        check.add(AttitudeSample(t, q))  # type: ignore[arg-type]
    # Along the axis (north s = d sin p, down d cos p) the ground is at +0.2 s: h - d cos p
    # = 0.2 d sin p, so d = h / (cos p + 0.2 sin p) = 151.39 m.
    d = h / (math.cos(pitch) + 0.2 * math.sin(pitch))
    assert d == pytest.approx(151.39, abs=0.01)
    check.add(down(d, t_s=1.0))
    assert check.mismatches == 0
    check.add(down(h / math.cos(pitch), t_s=1.1))  # 165.5 m as if flat: 14.0 m off
    assert check.mismatches == 1


def test_too_tilted_and_other_orientations_are_refused_and_counted():
    check = TerrainCheck(PlaneDem())
    hover(check, GROUND_M + 100.0, math.radians(40.0))
    check.add(down(100.0, t_s=1.05))
    for orientation in (0, 24, 100):  # forward, upward, custom
        check.add(down(100.0, orientation=orientation))
    assert not check.checked
    assert check.refused == {Refused.TILTED: 1, Refused.NOT_DOWNWARD: 3}


def test_nan_and_out_of_range_are_refused_and_counted():
    check = TerrainCheck(PlaneDem(GROUND_M + 50.0))
    hover(check, GROUND_M + 100.0)
    check.add(down(math.nan))
    check.add(down(100.0, in_range=False))
    check.add(report(math.nan))
    check.add(report(GROUND_M, has_data=False))
    check.add(TerrainReportSample(1.0, LAT + 1.0, LON, GROUND_M, 0.0, True))  # off the DEM
    check.add(PositionSample(1.2, math.nan, LON, GROUND_M))  # never a position
    assert not check.checked and check.mismatches == 0
    assert check.refused == {Refused.NOT_FINITE: 2, Refused.OUT_OF_RANGE: 1,
                             Refused.NO_TERRAIN_DATA: 1, Refused.OUTSIDE_DEM: 1}
    assert "not compared" in check.summary_line()


def test_reading_without_position_before_it_or_across_a_gap():
    check = TerrainCheck(PlaneDem())
    check.add(down(100.0, t_s=0.5))
    hover(check, GROUND_M + 100.0, t_s=(1.0, 3.0))  # none before 0.5; 2 s apart
    check.add(down(100.0, t_s=2.0))
    hover(check, GROUND_M + 100.0, t_s=(3.5,))
    assert check.refused == {Refused.NO_POSE: 2} and not check.checked


def test_home_is_compared_once_per_home():
    check = TerrainCheck(PlaneDem())
    home = HomeSample(1.0, LAT, LON, GROUND_M - 12.0, "HOME_POSITION")
    for t in (1.0, 6.0, 11.0):  # HOME_POSITION every 5 s
        check.add(HomeSample(t, home.lat_deg, home.lon_deg, home.alt_msl_m, home.source))
    assert check.checked[CheckSource.HOME] == 1 and check.mismatches == 1
    check.add(HomeSample(20.0, LAT, LON, GROUND_M + 0.3, "HOME_POSITION"))  # reset at arming
    assert check.checked[CheckSource.HOME] == 2 and check.mismatches == 1


# --- the adapters -------------------------------------------------------------------------

def test_mavlink_distance_sensor_and_terrain_report():
    mav = mavlink.MAVLink(None)
    ds = mav.distance_sensor_encode(1500, 20, 40000, 12345, 0, 1, 25, 0)
    s = sample_from_mavlink(ds, 1.5)
    assert s == RangefinderSample(1.5, 123.45, 25, True, 1)
    beyond = mav.distance_sensor_encode(1500, 20, 40000, 40001, 0, 0, 25, 0)
    assert sample_from_mavlink(beyond, 1.5).in_range is False  # type: ignore[union-attr]
    invalid = mav.distance_sensor_encode(1500, 20, 4000, 300, 0, 0, 25, 0, signal_quality=1)
    assert sample_from_mavlink(invalid, 1.5).in_range is False  # type: ignore[union-attr]
    tr = mav.terrain_report_encode(470_000_000, 80_000_000, 30, 488.5, 95.25, 0, 12)
    assert sample_from_mavlink(tr, 2.0) == TerrainReportSample(2.0, 47.0, 8.0, 488.5, 95.25,
                                                               True)
    no_data = mav.terrain_report_encode(470_000_000, 80_000_000, 0, 0.0, 0.0, 4, 0)
    assert sample_from_mavlink(no_data, 2.0).has_data is False  # type: ignore[union-attr]


def _df(mtype: str, **fields):
    return SimpleNamespace(get_type=lambda: mtype, **fields)


def test_dataflash_terr_and_rfnd():
    terr = _df("TERR", TimeUS=1, Status=2, Lat=47.0, Lng=8.0, Spacing=30, TerrH=488.5,
               CHeight=95.0, Pending=0, Loaded=10)
    assert samples_from_dataflash(terr, 1.0) == (
        TerrainReportSample(1.0, 47.0, 8.0, 488.5, 95.0, True),)
    unhealthy = _df("TERR", TimeUS=1, Status=1, Lat=47.0, Lng=8.0, Spacing=30, TerrH=0.0,
                    CHeight=0.0, Pending=4, Loaded=0)
    assert samples_from_dataflash(unhealthy, 1.0)[0].has_data is False  # type: ignore[union-attr]
    rfnd = _df("RFND", TimeUS=1, Instance=0, Dist=12.34, Stat=4, Orient=25)
    assert samples_from_dataflash(rfnd, 1.0) == (RangefinderSample(1.0, 12.34, 25, True, 0),)
    high = _df("RFND", TimeUS=1, Instance=1, Dist=40.0, Stat=3, Orient=25)
    assert samples_from_dataflash(high, 1.0)[0].in_range is False  # type: ignore[union-attr]
    old = _df("RFND", TimeUS=1, Dist1=1.0, Dist2=2.0)  # ArduPilot 3.5: no orientation
    assert samples_from_dataflash(old, 1.0) == ()


def test_ulog_distance_sensor():
    fields = {"timestamp": np.array([1_000_000, 2_000_000, 3_000_000]),
              "current_distance": np.array([12.5, 50.0, 3.0]),
              "min_distance": np.full(3, 0.2), "max_distance": np.full(3, 40.0),
              "orientation": np.array([25, 25, 25]), "signal_quality": np.array([-1, 100, 0])}
    out = _ulog_rangefinder(fields, 1)
    assert out == [RangefinderSample(1.0, 12.5, 25, True, 1),
                   RangefinderSample(2.0, 50.0, 25, False, 1),  # beyond max_distance
                   RangefinderSample(3.0, 3.0, 25, False, 1)]  # signal quality 0: invalid


def _dataflash_log(records: list[tuple[str, str, str, tuple]]) -> bytes:
    """A DataFlash binary log of ``records`` (name, format, columns, values), each type
    announced by its FMT record first (ids from 129 on)."""
    import struct

    from pymavlink.DFReader import FORMAT_TO_STRUCT

    head, out, ids = b"\xa3\x95", bytearray(), {}

    def fmt(type_id: int, length: int, name: str, form: str, cols: str) -> bytes:
        return head + struct.pack("<BBB4s16s64s", 128, type_id, length, name.encode(),
                                  form.encode(), cols.encode())

    out += fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
    for name, form, cols, values in records:
        layout = "<" + "".join(FORMAT_TO_STRUCT[c][0] for c in form)
        if name not in ids:
            ids[name] = 129 + len(ids)
            out += fmt(ids[name], 3 + struct.calcsize(layout), name, form, cols)
        out += head + bytes([ids[name]]) + struct.pack(layout, *values)
    return bytes(out)


def test_dataflash_log_carries_terrain_and_rangefinder(tmp_path):
    from pdcov.telemetry.logs import read_flight_log

    recs = []
    for k in range(5):
        us = 1_000_000 + 100_000 * k
        recs.append(("ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw", (us, 0.0, 0.0, 0.0)))
        recs.append(("POS", "QLLf", "TimeUS,Lat,Lng,Alt", (us, 470_000_000, 80_000_000, 500.0)))
        # RFND Dist: uint16 cm with multiplier 0.01 (format C): 1234 -> 12.34 m.
        recs.append(("RFND", "QBCBB", "TimeUS,Instance,Dist,Stat,Orient",
                     (us + 50_000, 0, 1234, 4, 25)))
    recs.append(("TERR", "QBLLHffHH", "TimeUS,Status,Lat,Lng,Spacing,TerrH,CHeight,Pending,"
                 "Loaded", (1_200_000, 2, 470_000_000, 80_000_000, 30, 488.5, 11.5, 0, 9)))
    path = tmp_path / "terrain.bin"
    path.write_bytes(_dataflash_log(recs))
    log = read_flight_log(path)
    assert len(log.rangefinder) == 5
    assert log.rangefinder[0].distance_m == pytest.approx(12.34)
    assert log.rangefinder[0].t_s - log.attitude.t_s[0] == pytest.approx(0.05)
    assert log.terrain_reports == (TerrainReportSample(
        log.terrain_reports[0].t_s, pytest.approx(47.0), pytest.approx(8.0), 488.5, 11.5,
        True),)
    from pdcov.telemetry.terrain_check import check_flight_log

    check = TerrainCheck(PlaneDem())
    check_flight_log(check, log)
    # Readings at 1.05 .. 1.45 s: the last has no position after it. 500 - 12.34 = 487.66.
    assert check.checked == {CheckSource.RANGEFINDER: 4, CheckSource.TERRAIN_REPORT: 1}
    assert check.mismatches == 0
