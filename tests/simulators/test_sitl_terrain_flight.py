"""The simulator over terrain, end to end in process (JSBSim): a short mission in
MAV_FRAME_GLOBAL_TERRAIN_ALT over a tilted plane with a ridge, flown at full speed; from the
tlog: the height above the terrain on the survey legs, TERRAIN_REPORT against the terrain,
DISTANCE_SENSOR against the true height above the ground, and the return climbing to
RTL_ALT (15 m above home) before coming home."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jsbsim")

from pymavlink import mavutil

from pdcov.config.load import load_mission
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.mission import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_WAYPOINT, MissionItem
from pdcov.planning.plan_files import wpl_text
from pdcov_sitl.fly import FlyOptions, fly
from tests.support.sitl_terrain import TiltedPlane

LAT, LON, H0 = 46.5, 7.9, 1200.0
# 10 % up to the east, a 3 m ridge every ~94 m northwards: 6 m of relief under the legs.
GROUND = TiltedPlane(LAT, LON, H0, slope_e=0.1, slope_n=0.0, ridge_m=3.0, extent_m=300.0)
CONFIG = """\
vehicle_id: sim
origin: {lat_deg: 46.5, lon_deg: 7.9}
domain:
  polygon_enu_m: [[0, 0], [60, 0], [60, 30], [0, 30]]
  cell_size_m: 1.0
camera:
  width_px: 640
  height_px: 480
  K: [[480.0, 0.0, 319.5], [0.0, 480.0, 239.5], [0.0, 0.0, 1.0]]
  frame_rate_hz: 5
mount: {type: fixed, pitch_deg: -90}
detector: illustrative
"""
HAG_M = 10.0


def _plan(path: Path, origin: Origin) -> Path:
    """A short survey at 10 m above the terrain, frame 10 (GLOBAL_TERRAIN_ALT), and frame 11
    (its _INT twin) for the last waypoint."""
    enu = np.array([[0, 0, 0], [60, 0, 0], [60, 30, 0], [10, 30, 0]], float)
    geo = enu_to_geodetic(enu, origin)
    items = [MissionItem(MAV_CMD_DO_CHANGE_SPEED, 2, 1.0, 5.0, -1.0)]
    for k, (lat, lon, _h) in enumerate(geo):
        items.append(MissionItem(MAV_CMD_NAV_WAYPOINT, 11 if k == len(geo) - 1 else 10,
                                 lat_deg=float(lat), lon_deg=float(lon), z_m=HAG_M))
    path.write_text(wpl_text(tuple(items), origin))
    return path


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> dict[str, list]:
    d = tmp_path_factory.mktemp("terrain")
    (d / "mission.yaml").write_text(CONFIG)
    mission = load_mission(d / "mission.yaml")
    origin = Origin(LAT, LON, H0)
    plan = _plan(d / "plan.waypoints", origin)
    result = fly(FlyOptions(mission=mission, plan_path=plan, out_dir=d / "out",
                            connect="udpout:127.0.0.1:9", speed=0.0, ground=GROUND))
    msgs: dict[str, list] = {}
    log = mavutil.mavlink_connection(str(result.tlog))
    while (m := log.recv_match()) is not None:
        msgs.setdefault(m.get_type(), []).append(m)
    return msgs


def _ground_msl_m(lat_e7, lon_e7) -> np.ndarray:
    return GROUND.height_msl_m(np.asarray(lat_e7) * 1e-7, np.asarray(lon_e7) * 1e-7)


def test_home_and_take_off_on_the_terrain(flight) -> None:
    home = flight["HOME_POSITION"][0]
    assert home.altitude / 1000 == pytest.approx(H0, abs=1e-3)
    first = flight["GLOBAL_POSITION_INT"][0]
    assert first.alt / 1000 - H0 == pytest.approx(0.15, abs=0.05)  # on its gear
    assert first.relative_alt / 1000 == pytest.approx(0.15, abs=0.05)


def test_survey_legs_keep_their_height_above_the_terrain(flight) -> None:
    modes = [(m._timestamp, m.custom_mode) for m in flight["HEARTBEAT"]]
    gpi = flight["GLOBAL_POSITION_INT"]
    t = np.array([m._timestamp for m in gpi])
    hag = np.array([m.alt / 1000 for m in gpi]) - _ground_msl_m([m.lat for m in gpi],
                                                                [m.lon for m in gpi])
    east = np.array([GROUND.ne_m(m.lat * 1e-7, m.lon * 1e-7)[1] for m in gpi])
    # AUTO (3) after the take-off: from reaching the first waypoint's height to the RTL.
    rtl_t = min(ts for ts, mode in modes if mode == 6)
    climbed = t[np.argmax(hag > HAG_M - 0.3)]
    survey = (t > climbed + 1.0) & (t < rtl_t)
    assert survey.sum() > 200
    assert east[survey].max() > 55  # it went up the slope
    err = np.abs(hag[survey] - HAG_M)
    print(f"height above terrain on the survey: max error {err.max():.2f} m, "
          f"p95 {np.percentile(err, 95):.2f} m over {survey.sum()} fixes")
    assert err.max() < 2.0


def test_terrain_report_is_the_dem_under_the_vehicle(flight) -> None:
    reports = flight["TERRAIN_REPORT"]
    assert len(reports) > 50
    dem = _ground_msl_m([r.lat for r in reports], [r.lon for r in reports])
    assert np.abs(np.array([r.terrain_height for r in reports]) - dem).max() < 0.5
    assert {r.spacing for r in reports} == {100} and {r.pending for r in reports} == {0}
    # current_height: above the terrain, against the position fix nearest in time.
    gpi = flight["GLOBAL_POSITION_INT"]
    t = np.array([m._timestamp for m in gpi])
    for r in reports[::5]:
        g = gpi[int(np.argmin(abs(t - r._timestamp)))]
        truth = g.alt / 1000 - float(_ground_msl_m(g.lat, g.lon))
        assert r.current_height == pytest.approx(truth, abs=0.5)


def test_distance_sensor_measures_the_height_above_the_ground(flight) -> None:
    ranges = flight["DISTANCE_SENSOR"]
    assert len(ranges) > 50
    assert {(r.orientation, r.min_distance, r.max_distance, r.covariance, r.id)
            for r in ranges} == {(25, 20, 4000, 0, 0)}
    # Level (within 2 deg: a tilted ray meets the sloping ground aft or ahead, a few dm
    # off), in the air: the slant range is the height above the ground below.
    gpi, att = flight["GLOBAL_POSITION_INT"], flight["ATTITUDE"]
    t = np.array([m._timestamp for m in gpi])
    t_att = np.array([m._timestamp for m in att])
    errs = []
    for r in ranges:
        g = gpi[int(np.argmin(abs(t - r._timestamp)))]
        a = att[int(np.argmin(abs(t_att - r._timestamp)))]
        hag = g.alt / 1000 - float(_ground_msl_m(g.lat, g.lon))
        if hag > 1.0 and max(abs(a.roll), abs(a.pitch)) < np.radians(2.0):
            errs.append(r.current_distance / 100 - hag)
    errs_m = np.array(errs)
    print(f"DISTANCE_SENSOR - height above ground, level: median {np.median(errs_m):.3f} m, "
          f"max |.| {np.abs(errs_m).max():.2f} m over {len(errs_m)} readings")
    assert len(errs_m) > 20 and np.abs(errs_m).max() < 0.15


def test_rtl_climbs_to_rtl_alt_then_comes_home(flight) -> None:
    modes = [(m._timestamp, m.custom_mode) for m in flight["HEARTBEAT"]]
    rtl_t = min(ts for ts, mode in modes if mode == 6)
    land_t = min(ts for ts, mode in modes if mode == 9)
    gpi = [m for m in flight["GLOBAL_POSITION_INT"] if rtl_t - 3.0 <= m._timestamp < land_t]
    rel = np.array([m.relative_alt / 1000 for m in gpi])
    ne = np.array([GROUND.ne_m(m.lat * 1e-7, m.lon * 1e-7) for m in gpi])
    # The last waypoint (30 m north, 10 m east): 10 m above the terrain there, which is
    # 0.1 * 10 + 3 sin(30 / 15) = 3.73 m above home: 13.73 m above home, below RTL_ALT
    # (15 m above home): it climbs there over the waypoint, then returns at 15 m.
    at_wp = np.hypot(ne[:, 0] - 30.0, ne[:, 1] - 10.0) < 0.5
    assert rel[at_wp].min() == pytest.approx(13.73, abs=0.3)
    first_top = int(np.argmax(rel > 14.8))
    assert at_wp[first_top]  # the climb is over the waypoint, before the return
    assert rel[first_top:].max() == pytest.approx(15.0, abs=0.3)
    assert np.hypot(*ne[-1]) < 0.5 and rel[-1] == pytest.approx(15.0, abs=0.3)
