"""The simulator over terrain, in memory: the rangefinder's ray, ArduCopter's RTL altitude
rule, terrain-frame waypoints and their guidance, TERRAIN_REPORT and DISTANCE_SENSOR as
ArduPilot and PX4 fill them, the terrain frames kept by the mission protocol, RTL_* as
parameters. Hand-checkable numbers on level and tilted planes."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.mission import MissionItem
from pdcov.errors import InputFileError
from pdcov_sitl.dynamics import VehicleState, local_scales
from pdcov_sitl.guidance import Guidance
from pdcov_sitl.messages import MessageBuilder, Rangefinder, Snapshot, autopilot_params
from pdcov_sitl.mission import ReturnRule, flight_plan_from_items
from pdcov_sitl.protocol import AutopilotProtocol, StreamSchedule
from pdcov_sitl.terrain import FlatGround, LocalGround, slant_range_m
from tests.support.sitl_terrain import TiltedPlane

LAT, LON, H0 = 46.5, 7.9, 1200.0
ORIGIN = Origin(LAT, LON, H0)
PLANE = TiltedPlane(LAT, LON, H0, slope_e=0.1, extent_m=200.0)
GCS = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)


def _state(n_m: float, e_m: float, alt_msl_m: float, roll_deg: float = 0.0,
           pitch_deg: float = 0.0) -> VehicleState:
    m_n, m_e = local_scales(LAT)
    return VehicleState(0.0, LAT + math.degrees(n_m / m_n), LON + math.degrees(e_m / m_e),
                        alt_msl_m, (n_m, e_m, H0 - alt_msl_m), (0.0, 0.0, 0.0),
                        math.radians(roll_deg), math.radians(pitch_deg), 0.0, 0.0, 0.0, 0.0,
                        alt_msl_m - H0)


def _decoded(msg):
    return mavlink2.MAVLink(None).decode(bytearray(msg.pack(mavlink2.MAVLink(None))))


# --- the rangefinder's ray ------------------------------------------------------------------

def test_slant_range_on_level_and_tilted_ground() -> None:
    flat = FlatGround(100.0)
    assert slant_range_m(flat, LAT, LON, 110.0, (0.0, 0.0, 1.0), 40.0) == \
        pytest.approx(10.0, abs=2e-3)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    assert slant_range_m(flat, LAT, LON, 110.0, (0.0, s, c), 40.0) == \
        pytest.approx(10.0 / c, abs=2e-3)  # 11.547 m
    assert math.isnan(slant_range_m(flat, LAT, LON, 110.0, (0.0, 1.0, 0.0), 40.0))  # level
    assert math.isnan(slant_range_m(flat, LAT, LON, 150.0, (0.0, 0.0, 1.0), 40.0))  # too far
    # 20 m east on a 10 % slope the ground is 2 m higher: 12 m above it, 10 m below the ray.
    st = _state(0.0, 20.0, H0 + 12.0)
    assert slant_range_m(PLANE, st.lat_deg, st.lon_deg, st.alt_msl_m, (0.0, 0.0, 1.0),
                         40.0) == pytest.approx(10.0, abs=2e-3)
    # Looking 45 deg east (uphill) from 10 m above the slope: t cos45 (1 + 0.1) = 10.
    st = _state(0.0, 0.0, H0 + 10.0)
    r = math.sqrt(0.5)
    assert slant_range_m(PLANE, st.lat_deg, st.lon_deg, st.alt_msl_m, (0.0, r, r), 40.0) == \
        pytest.approx(10.0 / (r * 1.1), abs=2e-3)
    outside = _state(0.0, 199.0, H0 + 30.0)  # the ray leaves the DEM at 200 m east
    assert math.isnan(slant_range_m(PLANE, outside.lat_deg, outside.lon_deg,
                                    outside.alt_msl_m, (0.0, 0.8, 0.6), 40.0))


# --- ArduCopter's RTL altitude ----------------------------------------------------------------

def test_return_altitude_follows_arducopter() -> None:
    rule = ReturnRule()  # RTL_ALT 15 m, no minimum climb, cone slope 3
    assert rule.return_alt_m(10.0, 100.0) == 15.0    # climbs to RTL_ALT
    assert rule.return_alt_m(20.0, 100.0) == 20.0    # above it: returns where it is
    assert rule.return_alt_m(10.0, 4.0) == 12.0      # within the cone: 4 m * 3
    assert rule.return_alt_m(10.0, 1.0) == 10.0      # the cone never makes it descend
    assert ReturnRule(climb_min_m=5.0).return_alt_m(12.0, 100.0) == 17.0
    assert ReturnRule(cone_slope=0.4).return_alt_m(10.0, 1.0) == 15.0  # shallow: no cone
    assert ReturnRule(alt_m=0.0).return_alt_m(0.1, 100.0) == 0.3     # RTL_ALT_MIN 30 cm
    rule = ReturnRule.from_params({"RTL_ALT": 2500.0, "RTL_CLIMB_MIN": 200.0,
                                   "RTL_CONE_SLOPE": 0.0, "RTL_ALT_TYPE": 1.0,
                                   "RTL_LOITER_TIME": 2000.0})
    assert rule == ReturnRule(25.0, 2.0, 0.0, True, 2.0)


def test_rtl_parameters_are_read_and_set_over_mavlink() -> None:
    params = autopilot_params("ardupilot", "fixed", 1, ())
    proto = AutopilotProtocol(mavlink2.MAVLink(None), system_id=1, autopilot="ardupilot",
                              params=params, schedule=StreamSchedule({}, random.Random(0)))
    msg = _decoded(GCS.param_set_encode(1, 1, b"RTL_ALT", 3000.0,
                                        mavlink2.MAV_PARAM_TYPE_REAL32))
    reply, = proto.receive(msg, 0.0, 0.0)
    assert _decoded(reply).param_id == "RTL_ALT" and _decoded(reply).param_value == 3000.0
    assert ReturnRule.from_params(proto.params).alt_m == 30.0
    assert ReturnRule.from_params(params) == ReturnRule()


# --- terrain-frame waypoints and their guidance ------------------------------------------------

def _items(frame: int, pts_enu, alt_m: float = 10.0) -> list[MissionItem]:
    geo = enu_to_geodetic(np.array([[x, y, 0.0] for x, y in pts_enu]), ORIGIN)
    return [MissionItem(178, 2, 1.0, 5.0, -1.0)] + [
        MissionItem(16, frame, lat_deg=float(la), lon_deg=float(lo), z_m=alt_m)
        for la, lo, _ in geo]


PTS = [(0.0, 0.0), (60.0, 0.0), (60.0, 30.0), (10.0, 30.0)]


@pytest.mark.parametrize("frame", [10, 11])
def test_terrain_frame_waypoints_sit_above_the_terrain(frame: int) -> None:
    ground = LocalGround(PLANE, LAT, LON)
    plan = flight_plan_from_items(_items(frame, PTS), ORIGIN, "t", ground=ground)
    survey = plan.survey_legs
    assert all(leg.above_terrain for leg in survey)
    # (60, 0) ENU: 6 m up the slope, so 16 m above home.
    assert survey[1].end_ned_m[2] == pytest.approx(-16.0, abs=1e-3)


@pytest.mark.parametrize("frame", [3, 6])
def test_relative_frames_ignore_the_terrain(frame: int) -> None:
    ground = LocalGround(PLANE, LAT, LON)
    plan = flight_plan_from_items(_items(frame, PTS), ORIGIN, "t", ground=ground)
    assert not any(leg.above_terrain for leg in plan.legs)
    assert plan.survey_legs[1].end_ned_m[2] == pytest.approx(-10.0, abs=1e-6)


def test_terrain_waypoint_outside_the_dem_is_refused() -> None:
    ground = LocalGround(PLANE, LAT, LON)
    with pytest.raises(InputFileError, match=r"plan\.waypoints: item 2: the terrain-frame "
                                             r"waypoint at \(.*\) lies outside the DEM"):
        flight_plan_from_items(_items(10, [(0.0, 0.0), (300.0, 0.0)]), ORIGIN,
                               "plan.waypoints", ground=ground)


def test_guidance_keeps_the_height_above_the_terrain() -> None:
    model = TiltedPlane(LAT, LON, H0, slope_e=0.1, ridge_m=3.0)
    ground = LocalGround(model, LAT, LON)
    g = Guidance(flight_plan_from_items(_items(10, PTS), ORIGIN, "t", ground=ground),
                 ground=ground)
    worst, steepest = 0.0, 0.0
    for t in np.arange(0.0, g.reference_end_s, 0.05):
        sp = g.setpoint(float(t))
        if g.leg is not None and g.leg.kind == "waypoint" and g.leg.above_terrain:
            n, e, d = sp.r_ned_m
            worst = max(worst, abs(-d - float(ground.height_m(n, e)) - 10.0))
            steepest = max(steepest, -sp.v_ned_mps[2])
    assert worst < 0.2  # metres, the averaging's rounding of the ridge
    assert steepest < 2.5 + 0.05  # the climb limit holds up the slope


def test_relative_plan_is_unchanged_by_the_terrain() -> None:
    plan = flight_plan_from_items(_items(3, PTS), ORIGIN, "t")
    ground = LocalGround(PLANE, LAT, LON)
    a, b = Guidance(plan), Guidance(plan, ground=ground)
    for t in (3.0, 17.5, 30.0):
        assert a.setpoint(t) == b.setpoint(t)


# --- TERRAIN_REPORT and DISTANCE_SENSOR -------------------------------------------------------

def _snapshot(st: VehicleState) -> Snapshot:
    return Snapshot(st, 12_345, 0, (0.0, 0.0, 0.0), "waypoint", True, None, 0, 0, 0.0, 1.0)


def test_terrain_report_as_ardupilot_fills_it() -> None:
    b = MessageBuilder(mavlink2.MAVLink(None), "ardupilot", (LAT, LON, H0), 0, ground=PLANE)
    st = _state(5.0, 20.0, H0 + 14.0)  # 2 m up the slope, 12 m above it
    r = _decoded(b.build("TERRAIN_REPORT", _snapshot(st)))
    assert (r.lat, r.lon) == (round(st.lat_deg * 1e7), round(st.lon_deg * 1e7))
    assert r.terrain_height == pytest.approx(H0 + 2.0, abs=1e-3)
    assert r.current_height == pytest.approx(12.0, abs=1e-3)
    assert (r.spacing, r.pending, r.loaded) == (100, 0, 672)
    off = _decoded(b.build("TERRAIN_REPORT", _snapshot(_state(0.0, 250.0, H0 + 30.0))))
    assert (off.spacing, off.terrain_height, off.current_height) == (0, 0.0, 0.0)
    assert MessageBuilder(mavlink2.MAVLink(None), "ardupilot", (LAT, LON, H0), 0).build(
        "TERRAIN_REPORT", _snapshot(st)) is None  # no terrain, no report


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_distance_sensor_slant_range_down_the_body(autopilot: str) -> None:
    rf = Rangefinder(0.2, 40.0, 0.0)
    b = MessageBuilder(mavlink2.MAVLink(None), autopilot, (LAT, LON, H0), 0,
                       ground=FlatGround(H0), rangefinder=rf)
    level = _decoded(b.build("DISTANCE_SENSOR", _snapshot(_state(0.0, 0.0, H0 + 10.0))))
    assert (level.time_boot_ms, level.min_distance, level.max_distance,
            level.current_distance) == (12_345, 20, 4000, 1000)
    assert (level.orientation, level.type, level.id, level.covariance,
            level.signal_quality) == (mavlink2.MAV_SENSOR_ROTATION_PITCH_270,
                                      mavlink2.MAV_DISTANCE_SENSOR_LASER, 0, 0, 0)
    rolled = _decoded(b.build("DISTANCE_SENSOR",
                              _snapshot(_state(0.0, 0.0, H0 + 10.0, roll_deg=20.0))))
    assert rolled.current_distance == round(1000 / math.cos(math.radians(20)))  # 1064 cm
    high = _decoded(b.build("DISTANCE_SENSOR", _snapshot(_state(0.0, 0.0, H0 + 60.0))))
    assert high.current_distance == 4100  # no return: max + 1 m


def test_distance_sensor_noise_is_seeded_and_px4_reports_its_variance() -> None:
    rf = Rangefinder(0.2, 40.0, 0.05)
    snap = _snapshot(_state(0.0, 0.0, H0 + 10.0))
    px4 = [MessageBuilder(mavlink2.MAVLink(None), "px4", (LAT, LON, H0), seed,
                          ground=FlatGround(H0), rangefinder=rf) for seed in (1, 1, 2)]
    readings = [[_decoded(b.build("DISTANCE_SENSOR", snap)).current_distance
                 for _ in range(50)] for b in px4]
    assert readings[0] == readings[1] != readings[2]
    assert 2 < np.std(readings[0]) < 8 and abs(np.mean(readings[0]) - 1000) < 3  # 5 cm
    assert _decoded(px4[0].build("DISTANCE_SENSOR", snap)).covariance == 25  # cm^2
    ap = MessageBuilder(mavlink2.MAVLink(None), "ardupilot", (LAT, LON, H0), 1,
                        ground=FlatGround(H0), rangefinder=rf)
    assert _decoded(ap.build("DISTANCE_SENSOR", snap)).covariance == 0  # as ArduPilot


# --- the mission protocol keeps the frames ------------------------------------------------------

def test_mission_upload_and_download_keep_terrain_frames() -> None:
    proto = AutopilotProtocol(mavlink2.MAVLink(None, srcSystem=1, srcComponent=1),
                              system_id=1, autopilot="px4", params={},
                              schedule=StreamSchedule({}, random.Random(0)))
    frames = (10, 11, 3)
    proto.receive(_decoded(GCS.mission_count_encode(1, 1, len(frames), 0)), 0.0, 0.0)
    for seq, frame in enumerate(frames):
        proto.receive(_decoded(GCS.mission_item_int_encode(
            1, 1, seq, frame, 16, 0, 1, 0, 0, 0, 0, 465000000, 79000000, 10.0, 0)), 0.0, 0.0)
    assert [it.frame for it in proto.missions.mission] == list(frames)
    for seq, frame in enumerate(frames):
        msg, = proto.receive(_decoded(GCS.mission_request_int_encode(1, 1, seq, 0)), 0, 0)
        assert _decoded(msg).frame == frame
