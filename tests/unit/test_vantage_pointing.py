"""Vantage plans on a gimbal: the pointing commands after take-off and where the pointing
changes, the mission files round-tripping them, earth-frame yaws held whatever the heading
and credited with their frame, pointings the mount cannot hold refused, and the simulated
gimbal holding a locked yaw."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from pdcov.core.mission import (
    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    MAV_CMD_DO_MOUNT_CONTROL,
    MAV_CMD_NAV_TAKEOFF,
    GimbalCommand,
    HoverItem,
    mission_item_int_params56,
    mission_item_int_xy,
)
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount, heading_rad
from pdcov.errors import ConfigError
from pdcov.planning.optimise import flight_poses, predict
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint
from pdcov.planning.plan_files import read_plan, write_plan
from pdcov.planning.plan_items import mission_items, plan_from_mission_items
from pdcov.planning.trajectory import Flight, camera_poses, fly
from pdcov.planning.vantage_missions import plan_vantage_missions
from tests.support.vantage_scene import GREEDY, OBLIQUE_A, OBLIQUE_B, ORIGIN, pointed_plan, scene


@pytest.mark.parametrize("command, cmd, pitch_param", [
    (GimbalCommand.MANAGER, MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, "param1"),
    (GimbalCommand.MOUNT, MAV_CMD_DO_MOUNT_CONTROL, "param1")])
def test_gimbal_plans_point_the_gimbal_after_take_off(command, cmd, pitch_param):
    from pdcov_sitl.mission import flight_plan_from_items

    plan = Plan((Waypoint(5.0, 0.0, 10.0, 3.0, hover_s=2.0,
                          gimbal=GimbalPointing(math.radians(-60.0))),
                 Waypoint(5.0, 5.0, 10.0, 3.0)), gimbal_command=command)
    items = mission_items(plan, ORIGIN)
    assert items[0].command == MAV_CMD_NAV_TAKEOFF and items[1].command == cmd
    assert getattr(items[1], pitch_param) == pytest.approx(-60.0)
    if command is GimbalCommand.MOUNT:
        assert items[1].z_m == 2.0  # param7 MAV_MOUNT_MODE_MAVLINK_TARGETING
    back = plan_from_mission_items(items, ORIGIN)
    assert [w.hover_s for w in back.waypoints] == [2.0, 0.0]
    legs = flight_plan_from_items(items, ORIGIN, "test").survey_legs
    assert all(leg.gimbal_pitch_rad == pytest.approx(math.radians(-60.0)) for leg in legs)


@pytest.mark.parametrize("hover_item", list(HoverItem))
def test_pointing_items_where_it_changes_and_the_files_round_trip(tmp_path, hover_item):
    from pdcov_sitl.mission import flight_plan_from_items

    plan = pointed_plan(hover_item)
    items = mission_items(plan, ORIGIN)
    hover_cmd = 19 if hover_item is HoverItem.LOITER_TIME else 16
    assert [it.command for it in items] == [22, 1000, 178, 16, 1000, 16, hover_cmd, 1000,
                                            hover_cmd, 20]
    a, b = items[4], items[7]
    assert (a.param1, a.param2, a.lat_deg) == pytest.approx((-45.0, 45.0, 16.0))
    assert (b.param1, b.param2, b.lat_deg) == pytest.approx((-60.0, -135.0, 16.0))
    assert items[1].lat_deg == 0.0  # nadir, the yaw following the vehicle
    assert items[6].param1 == 4.0 and items[8].param1 == 2.0
    for name in ("p.plan", "p.waypoints"):
        write_plan(tmp_path / name, plan, ORIGIN)
        back = read_plan(tmp_path / name, ORIGIN, 3.0)
        assert back.hover_item is hover_item
        assert [w.hover_s for w in back.waypoints] == [0.0, 0.0, 4.0, 2.0]
        again = mission_items(back, ORIGIN)
        assert [it.command for it in again] == [it.command for it in items]
        for x, y in zip(again, items, strict=True):
            np.testing.assert_allclose([x.param1, x.param2, x.lat_deg, x.lon_deg, x.z_m],
                                       [y.param1, y.param2, y.lat_deg, y.lon_deg, y.z_m],
                                       atol=1e-6)
    sc = scene(GimbalMount())  # the plan read back predicts as the plan written
    np.testing.assert_allclose(predict(sc, back).grid.log_miss_d,
                               predict(sc, plan).grid.log_miss_d, atol=1e-5)
    legs = flight_plan_from_items(items, ORIGIN, "test").survey_legs
    assert [leg.gimbal_earth_yaw for leg in legs] == [False, True, True, True]
    assert [leg.hover_s for leg in legs] == [0.0, 0.0, 4.0, 2.0]
    assert legs[3].gimbal_yaw_rad == pytest.approx(math.radians(-135.0))


def test_a_mission_item_int_carries_param5_of_a_do_command_as_it_is():
    """x of a MAV_FRAME_MISSION item is param5 itself (the gimbal manager's flags), not
    degrees * 1e7 (which would turn YAW_LOCK 16 into 160000000, whose bit 4 is 0)."""
    gimbal = OBLIQUE_A.item(GimbalCommand.MANAGER)
    assert mission_item_int_xy(gimbal) == (16, 0)
    assert mission_item_int_params56(gimbal.frame, 16, 0) == (16.0, 0.0)
    wp = mission_items(pointed_plan(HoverItem.WAYPOINT), ORIGIN)[3]
    x, y = mission_item_int_xy(wp)
    assert (x, y) == (round(wp.lat_deg * 1e7), round(wp.lon_deg * 1e7))
    assert mission_item_int_params56(wp.frame, x, y) == pytest.approx((wp.lat_deg,
                                                                      wp.lon_deg))


def test_the_prediction_holds_each_points_earth_yaw_whatever_the_heading():
    """The kinematic model's gimbal holds the pointing the mission commands: at both hovers
    the optical axis points down at the pitch and along the earth-frame yaw, while the
    vehicle turns towards the next leg; on the way to the first waypoint it looks down."""
    sc = scene(GimbalMount())
    plan = pointed_plan(HoverItem.WAYPOINT)
    flight = fly(plan, 10.0, sc.kinematics)
    poses = flight_poses(sc, plan, flight)
    for k, aim in ((2, OBLIQUE_A), (3, OBLIQUE_B)):
        w = plan.waypoints[k]
        at = (np.hypot(flight.r_body_enu[:, 0] - w.x_enu_m, flight.r_body_enu[:, 1] - w.y_enu_m)
              < 1e-6) & (flight.speed_mps < 1e-6)
        assert at.sum() >= 10 * w.hover_s - 1
        headings = {round(math.degrees(heading_rad(R)), 1) for R in flight.R_ned_body[at]}
        if k == 2:
            assert len(headings) > 1  # it turns while it holds
        for i in np.flatnonzero(at):
            axis_enu = poses[i].R_enu_cam[:, 2]  # the optical axis
            bearing = math.degrees(math.atan2(axis_enu[0], axis_enu[1]))
            assert math.remainder(bearing - math.degrees(aim.yaw_rad), 360) == \
                pytest.approx(0.0, abs=1e-6)
            assert math.degrees(math.asin(axis_enu[2])) == pytest.approx(
                math.degrees(aim.pitch_rad), abs=1e-6)
    first = flight.waypoint_index == 0
    assert first.sum() >= 1
    assert all(p.R_enu_cam[2, 2] == pytest.approx(-1.0) for p, f in zip(poses, first,
                                                                         strict=True) if f)


def test_an_earth_yaw_candidate_is_credited_with_its_frame():
    """An oblique candidate at an earth-frame yaw gets exactly its frame's evidence (a grid
    fed its one pose); the same pitch following the vehicle's yaw gets the least over the
    headings: nothing (the footprints of opposite headings do not meet)."""
    from pdcov.planning.vantage import candidate_evidence

    sc = scene(GimbalMount())
    one = replace(GREEDY, alts_agl_m=(10.0,), hover_s=(1.0,), lattice_m=20.0)
    locked = replace(one, gimbal_pitches_deg=(-45.0,), gimbal_yaws=4)
    pts, ev, _ = candidate_evidence(sc, locked)
    assert {round(math.degrees(p.pointing.yaw_rad)) for p in pts} == {0, 90, 180, 270}
    for j in (0, len(pts) // 2, len(pts) - 1):
        p = pts[j]
        at_rest = Flight(np.zeros(1), np.array([[p.x_enu_m, p.y_enu_m, 10.0]]),
                         np.eye(3)[None], np.zeros(1), 0.0, 0.0)
        grid = sc.new_grid()
        (pose,) = camera_poses(at_rest, sc.mount, pointing=[p.pointing])
        grid.update(pose)
        expected = -p.looks * grid.log_miss_d[sc.mask].astype(float)
        assert expected.sum() > 0
        np.testing.assert_allclose(ev[:, j].toarray().ravel(), expected, rtol=1e-6)
    follow = replace(one, gimbal_pitches_deg=(-45.0,), gimbal_yaws=0)
    assert candidate_evidence(sc, follow)[1].nnz == 0


@pytest.mark.parametrize("mount, settings, message", [
    (GimbalMount(pitch_limits_deg=(-90.0, -50.0)), dict(gimbal_pitches_deg=(-90.0, -45.0)),
     r"--gimbal-pitches-deg -45: outside the mount's pitch_limits_deg \[-90.0, -50.0\]"),
    (GimbalMount(pitch_limits_deg=(-80.0, 0.0)), {},
     r"planning.gimbal_pitch_deg -90: outside the mount's pitch_limits_deg"),
    (FixedMount(), dict(gimbal_pitches_deg=(-90.0, -60.0)),
     r"--gimbal-pitches-deg -90 -60: a fixed mount points at its own pitch \(-90 deg\)"),
    (FixedMount(pitch_rad=math.radians(-60)), dict(gimbal_yaws=8),
     r"--gimbal-yaws 8: a fixed mount turns with the vehicle"),
    (GimbalMount(yaw_limits_deg=(-30.0, 30.0)), dict(gimbal_pitches_deg=(-45.0,),
                                                      gimbal_yaws=8),
     r"--gimbal-yaws 8: the mount's yaw_limits_deg \[-30.0, 30.0\] cannot hold"),
    (GimbalMount(), dict(gimbal_pitches_deg=(-100.0,)),
     r"--gimbal-pitches-deg: expected pitches in \[-90, 90\] deg"),
])
def test_pointings_the_mount_cannot_hold_are_refused(mount, settings, message):
    with pytest.raises(ConfigError, match=message):
        plan_vantage_missions(scene(mount), replace(GREEDY, **settings), routing_time_s=0.5)


def test_the_mount_command_refuses_earth_frame_yaws():
    with pytest.raises(ConfigError, match=r"--gimbal-yaws 8: MAV_CMD_DO_MOUNT_CONTROL takes "
                                          r"the yaw relative to the vehicle"):
        plan_vantage_missions(scene(GimbalMount()),
                              replace(GREEDY, gimbal_pitches_deg=(-45.0,), gimbal_yaws=8),
                              gimbal_command=GimbalCommand.MOUNT, routing_time_s=0.5)


@pytest.mark.parametrize("mode, axes", [("stabilised", 3), ("servo", 3), ("stabilised", 2)])
def test_the_simulated_gimbal_holds_a_locked_yaw_while_the_vehicle_turns(mode, axes):
    """Commanded -45 deg at 30 deg from north with YAW_LOCK, the vehicle turning at 60 deg/s:
    a stabilised gimbal's optical axis stays at 30 deg (within its tracking noise), a servo
    mount's within the lag of its servos behind the turn (60 deg/s x tau_s); a 2-axis
    gimbal has no yaw motor and turns with the vehicle."""
    from pdcov_sitl.gimbal import GimbalConfig, GimbalModel, _Rz

    cfg = GimbalConfig(mode=mode, axes=axes)
    g = GimbalModel(cfg, seed=1)
    g.command(math.radians(-45.0), math.radians(30.0), earth_yaw=True)
    dt = 1 / 120
    bearings, headings = [], []
    for k in range(600):
        yaw = math.radians(-90.0 + 60.0 * k * dt)
        g.step(dt, 0.0, 0.0, yaw)
        axis = g.R_ned_gimbal(_Rz(yaw))[:, 0]
        if k >= 240:  # slewed from -90 deg at 90 deg/s, and settled
            bearings.append(math.degrees(math.atan2(axis[1], axis[0])))
            headings.append(math.degrees(yaw))
    err = np.array(bearings) - (30.0 if axes == 3 else np.array(headings))
    err = (err + 180) % 360 - 180
    lag_deg = 60.0 * cfg.tau_s if mode == "servo" else 0.0
    assert np.abs(err).max() < lag_deg + (1.0 if axes == 3 else 0.5), np.abs(err).max()
