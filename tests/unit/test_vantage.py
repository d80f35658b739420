"""Vantage-point plans (planning/cover.py, vantage.py, tours.py, vantage_missions.py): the
covering program against brute force, the hover frames against the per-pixel reference,
free-space transits, the fleet's balance, sorties, mission items and bad input."""

from __future__ import annotations

import itertools
import math
import sys
from dataclasses import replace

import numpy as np
import pytest
import shapely
from scipy import sparse
from shapely.geometry import LineString, Point, Polygon

from pdcov.cli import main as pdcov_main
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.geodesy import Origin
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
from pdcov.extras import ROUTING
from pdcov.planning.cover import CoverProblem, exact_cover, greedy_cover
from pdcov.planning.optimise import Scenario, flight_poses, predict
from pdcov.planning.plan import (
    GimbalPointing,
    Plan,
    Waypoint,
    mission_items,
    plan_from_mission_items,
    read_plan,
    write_plan,
)
from pdcov.planning.tours import Fleet
from pdcov.planning.trajectory import Flight, camera_poses, fly
from pdcov.planning.vantage import VantageSettings, hover_looks, lattice_enu_m
from pdcov.planning.vantage_missions import plan_vantage_missions
from tests.support.references import ReferenceGrid, pixel_rays, r1_update

OBSTACLE = [(4, -4), (12, -4), (12, 5), (4, 5)]
TARGET_PD = 0.9
SETTINGS = VantageSettings(TARGET_PD, (8.0, 12.0), (1.0, 2.0), lattice_m=5.0,
                           exact_time_limit_s=10.0)
GREEDY = VantageSettings(TARGET_PD, (8.0, 12.0), (1.0, 2.0), lattice_m=8.0,
                         exact_time_limit_s=0.0)
ROUTING_S = 1.0


def scene(mount=None) -> Scenario:
    """40 x 30 m around home with an 8 x 9 m obstacle east of it, 1 m cells, a nadir 70 deg
    camera at 2 frames/s, the illustrative detector."""
    dom = Domain.from_enu([(-20, -15), (20, -15), (20, 15), (-20, 15)], [OBSTACLE])
    geo = dom.grid_geometry(1.0)
    return Scenario(dom.free_space, geo, dom.free_mask(geo), CameraModel.from_fov(640, 480, 70),
                    DetectorModel.illustrative(), mount or FixedMount(), frame_rate_hz=2.0)


@pytest.fixture(scope="module")
def single():
    return plan_vantage_missions(scene(), SETTINGS, routing_time_s=ROUTING_S)


OBLIQUE_SETTINGS = replace(SETTINGS, gimbal_pitches_deg=(-90.0, -60.0, -45.0), gimbal_yaws=8,
                           exact_time_limit_s=0.0)


@pytest.fixture(scope="module")
def oblique():
    """SETTINGS on a gimbal at -90, -60 and -45 deg, the oblique ones at 8 earth-frame yaws
    (greedy: the integer program finds no better cover of ~4,500 candidates in 10 s)."""
    return plan_vantage_missions(scene(GimbalMount()), OBLIQUE_SETTINGS,
                                 routing_time_s=ROUTING_S)


# -- the covering program ------------------------------------------------------------------

def brute_force(problem: CoverProblem) -> float:
    """The least cost of a subset reaching n_required cells, by trying them all."""
    n = problem.evidence.shape[1]
    best = math.inf
    for k in range(n + 1):
        for subset in itertools.combinations(range(n), k):
            if problem.reached(np.array(subset, dtype=int)).sum() >= problem.n_required:
                best = min(best, float(problem.cost[list(subset)].sum()))
    return best


def test_a_cell_may_need_two_candidates():
    """tau(0.9) = 2.303: cell 0 gets 1.2 from each of A and B (only both reach it), cell 1
    2.5 from C alone; one candidate D reaches both cells but costs 3. Plain set cover (one
    candidate per cell) would call A or B enough for cell 0."""
    e = sparse.csc_matrix(np.array([[1.2, 1.2, 0.0, 2.5], [0.0, 0.0, 2.5, 2.5]]))
    p = CoverProblem.of(e, np.array([1.0, 1.0, 1.0, 3.5]), TARGET_PD)
    exact = exact_cover(p, 5.0)
    assert exact is not None and sorted(exact.chosen.tolist()) == [0, 1, 2]
    assert exact.cost == pytest.approx(3.0) and exact.optimal
    assert not p.reached(np.array([0, 2])).all() and p.reached(np.array([0, 1, 2])).all()


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("share", [1.0, 0.7])
def test_exact_cover_is_brute_forces_optimum_and_greedy_is_feasible(seed, share):
    rng = np.random.default_rng(seed)
    e = sparse.random(12, 9, density=0.35, random_state=rng) * 3.0
    cost = rng.uniform(0.5, 2.0, 9)
    full = CoverProblem.of(e, cost, TARGET_PD)
    n_ok = int(full.reachable().sum())
    p = CoverProblem.of(e, cost, TARGET_PD, max(1, math.floor(share * n_ok)))
    best = brute_force(p)
    exact, greedy = exact_cover(p, 10.0), greedy_cover(p)
    assert exact is not None and greedy is not None
    assert exact.cost == pytest.approx(best)
    assert p.reached(greedy.chosen).sum() >= p.n_required
    assert greedy.cost >= exact.cost - 1e-9


def test_unreachable_cells_make_greedy_refuse():
    e = sparse.csc_matrix(np.array([[3.0, 0.0], [0.5, 0.5]]))
    p = CoverProblem.of(e, np.ones(2), TARGET_PD)
    assert p.reachable().tolist() == [True, False]
    assert greedy_cover(p) is None and exact_cover(p, 5.0) is None


def test_hover_looks_count_the_frames_sure_to_fall_in_the_hover():
    sc = scene()
    assert hover_looks(sc, 2.0) == 4 and hover_looks(sc, 1.9) == 3
    slow = replace(sc, frame_rate_hz=5.0, min_revisit_s=1.0)
    assert hover_looks(slow, 2.0) == 2  # 10 frames, one a second counts


def test_lattice_points_lie_in_the_space_and_reach_its_corners():
    space = Polygon([(0, 0), (10, 0), (10, 7), (0, 7)])
    xy = lattice_enu_m(space, 3.0)
    assert shapely.covers(space.buffer(1e-9), shapely.points(xy)).all()
    for corner in space.exterior.coords[:-1]:
        assert np.min(np.linalg.norm(xy - corner, axis=1)) < 1e-9


# -- the plan -----------------------------------------------------------------------------

def hover_poses(sc: Scenario, missions):
    """Camera poses of the predicted flights' hover frames (at rest on a hover point), the
    gimbal pointed as the missions command it."""
    poses = []
    for m in missions.missions:
        f = m.prediction.flight
        stops = np.array([[w.x_enu_m, w.y_enu_m] for w in m.prediction.plan.waypoints
                          if w.hover_s > 0])
        d = np.linalg.norm(f.r_body_enu[:, None, :2] - stops[None], axis=2).min(axis=1)
        at = (d < 1e-6) & (f.speed_mps < 1e-6)
        poses += [p for p, keep in zip(flight_poses(sc, m.prediction.plan, f), at,
                                       strict=True) if keep]
    return poses


@pytest.mark.parametrize("which", ["single", "oblique"])
def test_hover_frames_reach_the_target_by_the_per_pixel_reference(which, request):
    """R1 (tests/support/references.py: one ray per pixel, the cell's area = rays landing in
    it), fed only the hover frames, finds P_D >= target on >= 98 % of the free cells: with
    the nadir fixed camera, and with the gimbal's oblique views at earth-frame yaws."""
    missions = request.getfixturevalue(which)
    sc = scene(None if which == "single" else GimbalMount())
    grid = sc.new_grid()
    ref = ReferenceGrid(sc.geometry, sc.mask, sc.camera, sc.detector, grid.max_range_m)
    rays = pixel_rays(sc.camera)
    poses = hover_poses(sc, missions)
    looks = sum(p.looks for p in missions.cover.points)
    assert len(poses) >= looks
    for pose in poses:
        r1_update(ref, rays, pose)
        grid.update(pose)
    share_ref = float((ref.pd[sc.mask] >= TARGET_PD).mean())
    share_grid = float((grid.pd[sc.mask] >= TARGET_PD).mean())
    c = missions.cover
    exact = ("not tried" if c.exact is None else
             f"exact {len(c.exact.chosen)}, gap {c.greedy_gap:.1%}")
    print(f"{which}: {len(c.points)} points of {c.n_candidates} candidates (greedy "
          f"{len(c.greedy.chosen)}, {exact}); hover frames {len(poses)}: share at P_D "
          f"{TARGET_PD} {share_grid:.4f} (grid), {share_ref:.4f} (R1); flight "
          f"{missions.longest_s:.1f} s")
    if which == "oblique":
        assert any(p.pointing.earth_yaw for p in c.points)  # oblique views chosen
    assert share_grid == 1.0
    assert share_ref >= 0.98


def test_hover_points_and_transits_stay_in_free_space(single):
    sc = scene()
    obstacle = Polygon(OBSTACLE)
    for p in single.cover.points:
        assert shapely.covers(sc.free_space, Point(p.x_enu_m, p.y_enu_m))
    for m in single.missions:
        planned = np.vstack([[0.0, 0.0], m.prediction.plan.xy_enu_m, [0.0, 0.0]])
        assert not LineString(planned).intersects(obstacle)  # take-off, waypoints, return
        flown = m.prediction.flight.r_body_enu[:, :2]  # corners rounded by the kinematics
        assert not LineString(flown).intersects(obstacle)


def test_two_vehicles_each_fly_at_most_60_percent_of_one(single):
    two = plan_vantage_missions(scene(), SETTINGS, Fleet(2), routing_time_s=ROUTING_S)
    one_s = single.missions[0].flight_time_s
    times = [m.flight_time_s for m in two.missions]
    print(f"one vehicle {one_s:.1f} s; two: {', '.join(f'{t:.1f}' for t in times)} s")
    assert len(two.missions) == 2 and {m.route.vehicle for m in two.missions} == {1, 2}
    assert max(times) <= 0.6 * one_s
    stops = sorted(s for m in two.missions for s in m.route.stops)
    assert stops == list(range(len(two.cover.points)))


def test_sorties_keep_to_the_flight_time_and_visit_every_point(single):
    limit = 0.4 * single.missions[0].flight_time_s
    split = plan_vantage_missions(scene(), SETTINGS, Fleet(1, limit), routing_time_s=ROUTING_S)
    assert len(split.missions) >= 3
    assert [m.route.sortie for m in split.missions] == list(range(1, len(split.missions) + 1))
    assert max(m.flight_time_s for m in split.missions) <= limit
    stops = sorted(s for m in split.missions for s in m.route.stops)
    assert stops == list(range(len(split.cover.points)))
    pd = split.grid.pd[scene().mask]
    assert (pd >= TARGET_PD).all()


# -- mission items ----------------------------------------------------------------------------

ORIGIN = Origin(39.35, -76.33, 5.0)


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


OBLIQUE_A = GimbalPointing(math.radians(-45.0), math.radians(45.0), earth_yaw=True)
OBLIQUE_B = GimbalPointing(math.radians(-60.0), math.radians(225.0), earth_yaw=True)


def pointed_plan(hover_item: HoverItem) -> Plan:
    """Nadir to the first waypoint, then OBLIQUE_A for a corner and a hover, OBLIQUE_B for
    the last hover."""
    return Plan((Waypoint(5.0, 0.0, 10.0, 3.0, gimbal=GimbalPointing(-math.pi / 2)),
                 Waypoint(5.0, 8.0, 10.0, 3.0, gimbal=OBLIQUE_A),
                 Waypoint(-5.0, 8.0, 10.0, 3.0, hover_s=4.0, gimbal=OBLIQUE_A),
                 Waypoint(-5.0, -5.0, 12.0, 3.0, hover_s=2.0, gimbal=OBLIQUE_B)),
                hover_item=hover_item)


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


def test_a_gimbal_mission_commands_the_scenarios_pitch():
    sc = scene(GimbalMount())
    m = plan_vantage_missions(sc, GREEDY, routing_time_s=0.5)
    items = mission_items(m.missions[0].prediction.plan, ORIGIN)
    assert items[1].command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    assert items[1].param1 == pytest.approx(-90.0)


# -- bad input --------------------------------------------------------------------------------

def test_a_target_no_candidate_reaches_names_the_cells_and_why():
    with pytest.raises(ConfigError, match=r"cannot reach P_D 0.9.*too small in the picture at "
                                          r"every height"):
        plan_vantage_missions(scene(), VantageSettings(TARGET_PD, (150.0,), (1.0,),
                                                       lattice_m=8.0, exact_time_limit_s=0))


def test_more_vehicles_than_points_is_refused(single):
    n = len(single.cover.points)
    with pytest.raises(ConfigError, match=f"--vehicles {n + 1}: more vehicles than vantage "
                                          f"points \\({n}\\)"):
        plan_vantage_missions(scene(), SETTINGS, Fleet(n + 1), routing_time_s=ROUTING_S)


def test_a_flight_time_too_short_for_one_point_is_refused():
    with pytest.raises(ConfigError, match=r"--max-flight-time-s 5: the vantage point at .* "
                                          r"alone takes"):
        plan_vantage_missions(scene(), GREEDY, Fleet(1, 5.0), routing_time_s=0.5)


def test_routing_without_ortools_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ortools", None)
    assert ROUTING.message() == ("pdcov plan --pattern vantage needs ortools: "
                                 "pip install 'pdcov[routing]'")


MISSION_YAML = """\
vehicle_id: vt
origin: {lat_deg: 39.35, lon_deg: -76.33, ground_alt_msl_m: 5.0}
domain:
  polygon_enu_m: [[-20, -15], [20, -15], [20, 15], [-20, 15]]
  obstacles_enu_m: [[[4, -4], [12, -4], [12, 5], [4, 5]]]
  cell_size_m: 1.0
camera:
  width_px: 640
  height_px: 480
  K: [[457.0, 0.0, 319.5], [0.0, 457.0, 239.5], [0.0, 0.0, 1.0]]
  frame_rate_hz: 2
mount: {type: fixed, roll_deg: 0, pitch_deg: -90, yaw_deg: 0}
detector: illustrative
thresholds: [0.5, 0.9]
"""


@pytest.mark.parametrize("extra, message", [
    (["--target-pd", "0.9", "--altitudes-m", "150", "--lattice-m", "8"],
     "too small in the picture at every height"),
    (["--target-pd", "0.9", "--lattice-m", "8", "--vehicles", "500"],
     "more vehicles than vantage points"),
    (["--target-pd", "0.9", "--lattice-m", "8", "--max-flight-time-s", "3"],
     "alone takes"),
    (["--lattice-m", "8"], "--pattern vantage needs --target-pd"),
    (["--target-pd", "0.9", "--spacing-m", "5"], "--spacing-m does not apply to the vantage"),
    (["--target-pd", "0.9", "--lattice-m", "8", "--gimbal-pitches-deg", "-60"],
     "--gimbal-pitches-deg -60: a fixed mount points at its own pitch (-90 deg)"),
    (["--target-pd", "0.9", "--lattice-m", "8", "--gimbal-yaws", "-1"],
     "--gimbal-yaws: expected a count >= 0, got -1"),
])
def test_cli_bad_vantage_input_is_one_line_and_fails(tmp_path, capsys, extra, message):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(MISSION_YAML)
    rc = pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--ilp-time-limit-s",
                     "0", "--routing-time-s", "0.5", "--out", str(tmp_path / "out"), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and message in err[0], err


def test_cli_vantage_writes_one_mission_per_vehicle(tmp_path, capsys):
    import json

    cfg = tmp_path / "m.yaml"
    cfg.write_text(MISSION_YAML)
    out = tmp_path / "out"
    assert pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--target-pd",
                       "0.9", "--altitudes-m", "8", "12", "--hover-s", "1", "2", "--lattice-m",
                       "5", "--ilp-time-limit-s", "0", "--routing-time-s", "0.5",
                       "--vehicles", "2", "--no-figures", "--out", str(out)]) == 0
    doc = json.loads((out / "vantage.json").read_text())
    assert [m["file"] for m in doc["missions"]] == ["vehicle-1-sortie-1.plan",
                                                    "vehicle-2-sortie-1.plan"]
    for name in ("vehicle-1-sortie-1", "vehicle-2-sortie-1"):
        assert (out / f"{name}.plan").is_file() and (out / f"{name}.waypoints").is_file()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["proportion_at_or_above"]["0.9"] == 1.0
    assert "vantage:" in capsys.readouterr().out


def test_cli_oblique_pitches_default_to_eight_earth_frame_yaws(tmp_path):
    import json

    cfg = tmp_path / "m.yaml"
    cfg.write_text(MISSION_YAML.replace("mount: {type: fixed, roll_deg: 0, pitch_deg: -90, "
                                        "yaw_deg: 0}", "mount: {type: gimbal}"))
    out = tmp_path / "out"
    assert pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--target-pd",
                       "0.5", "--altitudes-m", "10", "--lattice-m", "10",
                       "--gimbal-pitches-deg", "-45", "--hover-item", "loiter-time",
                       "--ilp-time-limit-s", "0", "--routing-time-s", "0.5", "--no-figures",
                       "--out", str(out)]) == 0
    doc = json.loads((out / "vantage.json").read_text())
    assert {p["gimbal_pitch_deg"] for p in doc["points"]} == {-45.0}
    assert {p["gimbal_yaw_deg"] for p in doc["points"]} <= {45.0 * k for k in range(8)}
    items = json.loads((out / "plan.plan").read_text())["mission"]["items"]
    locked = [e["params"][4] for e in items if e["command"] == 1000]
    assert locked and set(locked) == {16}
    assert sum(e["command"] == 19 for e in items) == len(doc["points"])


def test_optimise_puts_vantage_beside_the_sweeps(tmp_path):
    import csv

    cfg = tmp_path / "m.yaml"
    cfg.write_text(MISSION_YAML)
    out = tmp_path / "opt"
    assert pdcov_main(["optimise", "--config", str(cfg), "--target-pd", "0.9",
                       "--min-proportion", "0.95", "--patterns", "lawnmower", "vantage",
                       "--altitudes-m", "12", "--speeds-mps", "4", "--headings-deg", "0",
                       "--overlaps", "0.2", "--processes", "1", "--out", str(out)]) == 0
    with open(out / "candidates.csv") as f:
        rows = {r["pattern"]: r for r in csv.DictReader(f)}
    assert set(rows) == {"lawnmower", "vantage"}
    v = rows["vantage"]
    assert float(v["proportion"]) >= 0.95 and int(v["missions"]) == 1
    assert float(v["flight_time_s"]) > 0 and float(v["path_length_m"]) > 0
    assert v["spacing_m"] == "" and rows["lawnmower"]["missions"] == "1"


def test_over_a_level_terrain_the_cover_is_the_flat_one_lifted():
    """Terrain at 3 m everywhere (amsl plans): a hover's height is 3 m + its altitude above
    ground, and the candidates' evidence is that of the flat ground (the same geometry)."""

    from pdcov.core.terrain import TerrainSurface
    from pdcov.planning.vantage import candidate_evidence, hover_z_enu_m

    flat = scene()
    lifted = replace(flat, terrain=TerrainSurface.flat(flat.geometry, 3.0))
    assert hover_z_enu_m(lifted, 1.0, 2.0, 10.0) == pytest.approx(13.0)
    assert hover_z_enu_m(flat, 1.0, 2.0, 10.0) == pytest.approx(10.0)
    pts_f, ev_f, _ = candidate_evidence(flat, GREEDY)
    pts_l, ev_l, _ = candidate_evidence(lifted, GREEDY)
    assert pts_f == pts_l
    np.testing.assert_allclose(ev_l.toarray(), ev_f.toarray(), rtol=1e-4, atol=1e-6)


def test_points_added_along_the_terrain_carry_their_legs_pointing():
    """Over waves (amsl), the points added along a leg hold the pointing of the waypoint
    the leg flies to, so the mission still commands each pointing once, before its leg."""
    from pdcov.core.mission import AltitudeFrame
    from pdcov.core.terrain import TerrainSurface
    from pdcov.planning.terrain_follow import TerrainFollowing

    flat = scene(GimbalMount())
    g = flat.geometry
    x = np.arange(g.n_cols + 1, dtype=float) * g.cell_size_m
    y = np.arange(g.n_rows + 1, dtype=float)[:, None] * g.cell_size_m
    bumps = 2.0 * np.sin(x / 3.0) * np.cos(y / 4.0)  # m: waves both ways
    hilly = replace(flat, terrain=TerrainSurface(g, bumps),
                    following=TerrainFollowing(AltitudeFrame.AMSL, 0.2))
    plan = pointed_plan(HoverItem.WAYPOINT)
    over = hilly.over_terrain(plan)
    assert sum(w.terrain_added for w in over.waypoints) >= 2
    seen = 0  # the plan's waypoints passed: an added point lies on the leg to the next
    for w in over.waypoints:
        if w.terrain_added:
            assert w.gimbal == plan.waypoints[seen].gimbal
        else:
            assert w.gimbal == plan.waypoints[seen].gimbal
            seen += 1
    assert [it.command for it in mission_items(over, ORIGIN)].count(1000) == 3
