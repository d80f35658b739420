"""Terrain-following plans: constant height above a tilted plane (closed form), climb and
descent limits over a ridge, the tolerance over hills, the frames written, the clearance
and rate warnings, flat terrain giving today's plan, and the planning keys and outputs of
the commands."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pdcov import cli
from pdcov.commands.plan_output import terrain_warnings, write_prediction
from pdcov.config.load import load_mission
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.ground_cover import CoverKind, GroundCover
from pdcov.core.mission import (
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    AltitudeFrame,
)
from pdcov.core.pose import FixedMount
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import ConfigError
from pdcov.planning.optimise import PlanParams, Scenario, build_plan, predict
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import read_plan, write_plan
from pdcov.planning.plan_items import mission_items
from pdcov.planning.scenario import scenario_of
from pdcov.planning.terrain_follow import (
    TERRAIN_ALT_PROFILE_M,
    TerrainFollowing,
    clearance_intrusions,
    follow_terrain,
    steep_legs,
)
from pdcov.planning.trajectory import fly

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"
ORIGIN = Origin(46.5, 8.0, 1200.0)
GEO = GridGeometry(-20.0, -20.0, 1.0, 160, 160)  # x, y in [-20, 140] m
AMSL = TerrainFollowing(AltitudeFrame.AMSL)
TERRAIN_ALT = TerrainFollowing(AltitudeFrame.TERRAIN_ALT)
H = 15.0  # height above terrain, m


def surface(z_of_xy, geometry: GridGeometry = GEO) -> TerrainSurface:
    x = geometry.x0_m + geometry.cell_size_m * np.arange(geometry.n_cols + 1)
    y = geometry.y0_m + geometry.cell_size_m * np.arange(geometry.n_rows + 1)
    xx, yy = np.meshgrid(x, y)
    return TerrainSurface(geometry, z_of_xy(xx, yy), "test")


def plane(x, y):
    return 0.05 * x + 0.02 * y


def hills(x, y):
    return 12.0 * np.sin(x / 15.0) * np.cos(y / 20.0) + 0.03 * x


LAWNMOWER = Plan((Waypoint(0, 0, H, 5), Waypoint(0, 100, H, 5), Waypoint(20, 100, H, 5),
                  Waypoint(20, 0, H, 5), Waypoint(100, 80, H, 5)), "lawnmower")


def along(plan: Plan, step_m=0.1) -> np.ndarray:
    """(K, 3) points every ``step_m`` on the straight path between the plan's waypoints."""
    xyz = plan.xyz_enu_m
    out = [xyz[:1]]
    for p, q in zip(xyz[:-1], xyz[1:], strict=True):
        n = max(1, math.ceil(np.linalg.norm(q[:2] - p[:2]) / step_m))
        out.append(p + (np.arange(1, n + 1) / n)[:, None] * (q - p))
    return np.concatenate(out)


def test_constant_height_over_a_tilted_plane():
    terrain = surface(plane)
    followed = follow_terrain(LAWNMOWER, terrain, AMSL)
    # The plane is linear along every leg: nothing is added, each waypoint is at H above it.
    assert [(w.x_enu_m, w.y_enu_m) for w in followed.waypoints] == \
        [(w.x_enu_m, w.y_enu_m) for w in LAWNMOWER.waypoints]
    for w in followed.waypoints:
        assert w.z_enu_m == pytest.approx(0.05 * w.x_enu_m + 0.02 * w.y_enu_m + H, abs=1e-9)
    pts = along(followed)
    assert np.abs(pts[:, 2] - plane(pts[:, 0], pts[:, 1]) - H).max() < 1e-9
    # Steepest leg: 0.05 * 80 + 0.02 * 80 = 5.6 m over 113 m at 5 m/s: 0.25 m/s, in limits.
    assert followed.altitude_frame is AltitudeFrame.AMSL


def test_the_flight_flies_the_profile_and_the_prediction_uses_it():
    dom = Domain.from_enu([(0, 0), (100, 0), (100, 100), (0, 100)])
    g = dom.grid_geometry(1.0)
    terrain = surface(plane, g)  # the grid's terrain: the kernel reads it per cell
    sc = Scenario(dom.free_space, g, dom.free_mask(g), CameraModel.from_fov(640, 480, 70),
                  DetectorModel.illustrative(), FixedMount(), 2.0, terrain=terrain,
                  following=AMSL)
    pred = predict(sc, LAWNMOWER)
    assert pred.plan.altitude_frame is AltitudeFrame.AMSL
    r = pred.flight.r_body_enu
    # Corners are cut by at most 2 m (corner_cut_m): 0.05 * 2 m off the plane's height.
    assert np.abs(r[:, 2] - plane(r[:, 0], r[:, 1]) - H).max() < 0.15


def ridge(x, y):
    return np.maximum(0.0, 20.0 - 0.8 * np.abs(y - 50.0))


def test_climb_and_descent_limits_over_a_ridge():
    # A 20 m ridge at y = 50 with 0.8 slopes, flown north at 5 m/s: 4 m/s up, then down.
    terrain = surface(ridge)
    plan = Plan((Waypoint(60, 0, H, 5), Waypoint(60, 100, H, 5)))
    rates = TerrainFollowing(AltitudeFrame.AMSL, tolerance_m=0.5, max_climb_mps=1.0,
                             max_descent_mps=0.5)
    followed = follow_terrain(plan, terrain, rates)
    xyz = followed.xyz_enu_m
    dt = np.linalg.norm(np.diff(xyz[:, :2], axis=0), axis=1) / 5.0
    rate = np.diff(xyz[:, 2]) / dt
    assert rate.max() <= 1.0 + 1e-9 and rate.min() >= -0.5 - 1e-9
    # Closed form: 1 m/s at 5 m/s is a 0.2 slope, so the top (20 + H at y = 50) is reached
    # from H + 20 - 0.2 * 50 = H + 10 at the start; 0.1 down after it: H + 15 at the end.
    assert xyz[0, 2] == pytest.approx(H + 10.0, abs=1e-9)
    assert xyz[-1, 2] == pytest.approx(H + 15.0, abs=1e-9)
    assert xyz[:, 2].max() == pytest.approx(H + 20.0, abs=1e-9)
    # The path only rises above the profile: never lower than H - tolerance above ground.
    pts = along(followed)
    assert (pts[:, 2] - ridge(pts[:, 0], pts[:, 1])).min() >= H - 0.5 - 1e-9
    # Without limits the path holds H above the ridge within the tolerance.
    free = follow_terrain(plan, terrain, TerrainFollowing(AltitudeFrame.AMSL, 0.5, 0.0, 0.0))
    pts = along(free)
    assert np.abs(pts[:, 2] - ridge(pts[:, 0], pts[:, 1]) - H).max() <= 0.5 + 1e-9
    assert len(free.waypoints) == 5  # start, foot, top, foot, end: the tent's kinks


def test_tolerance_over_hills_with_few_waypoints():
    terrain = surface(hills)
    loose = TerrainFollowing(AltitudeFrame.AMSL, tolerance_m=1.0, max_climb_mps=0.0,
                             max_descent_mps=0.0)
    followed = follow_terrain(LAWNMOWER, terrain, loose)
    pts = along(followed)
    height = pts[:, 2] - terrain.height_m(pts[:, 0], pts[:, 1])
    # Within the tolerance at the half-cell samples; between them the bilinear surface
    # bends a little more.
    assert np.abs(height - H).max() <= 1.0 + 0.02
    added = [w for w in followed.waypoints if w.terrain_added]
    assert 10 < len(followed.waypoints) < 100 and len(added) == len(followed.waypoints) - 5
    assert all(w.alt_agl_m == pytest.approx(H) for w in followed.waypoints)
    # A tighter tolerance keeps more points.
    tight = follow_terrain(LAWNMOWER, terrain, TerrainFollowing(AltitudeFrame.AMSL, 0.2, 0, 0))
    assert len(tight.waypoints) > len(followed.waypoints)


def test_terrain_frame_prediction_flies_the_height_the_autopilot_holds():
    # The autopilot holds H above the terrain along the whole leg; the file carries only the
    # pattern's waypoints, so the tolerance does not apply to the predicted path: it stays
    # within TERRAIN_ALT_PROFILE_M, where an amsl plan at the same tolerance strays 1 m.
    terrain = surface(hills)
    loose = dict(tolerance_m=1.0, max_climb_mps=0.0, max_descent_mps=0.0)
    followed = follow_terrain(LAWNMOWER, terrain, TerrainFollowing(AltitudeFrame.TERRAIN_ALT,
                                                                   **loose))
    pts = along(followed)
    height = pts[:, 2] - terrain.height_m(pts[:, 0], pts[:, 1])
    assert np.abs(height - H).max() <= TERRAIN_ALT_PROFILE_M + 0.02  # bilinear bends
    assert followed.written().sum() == len(LAWNMOWER.waypoints)
    amsl = along(follow_terrain(LAWNMOWER, terrain, TerrainFollowing(AltitudeFrame.AMSL,
                                                                     **loose)))
    assert np.abs(amsl[:, 2] - terrain.height_m(amsl[:, 0], amsl[:, 1]) - H).max() > 0.9


def test_amsl_waypoints_are_written_msl_and_read_back(tmp_path):
    terrain = surface(hills)
    followed = follow_terrain(LAWNMOWER, terrain, AMSL)
    items = mission_items(followed, ORIGIN)
    wps = [it for it in items if it.command == MAV_CMD_NAV_WAYPOINT]
    assert len(wps) == len(followed.waypoints)
    assert {it.frame for it in wps} == {MAV_FRAME_GLOBAL}
    # MSL altitude of each ENU point: back to ENU with pymap3d gives the path's height.
    enu = geodetic_to_enu(np.array([it.lat_deg for it in wps]),
                          np.array([it.lon_deg for it in wps]),
                          np.array([it.z_m for it in wps]), ORIGIN)
    assert np.allclose(enu, followed.xyz_enu_m, atol=1e-6)
    # Hand check: 1200 m at the origin; the first waypoint is at terrain(0, 0) + H = H.
    assert wps[0].z_m == pytest.approx(1200.0 + H, abs=1e-6)
    takeoff = items[0]
    assert takeoff.command == MAV_CMD_NAV_TAKEOFF
    assert takeoff.frame == MAV_FRAME_GLOBAL_RELATIVE_ALT and takeoff.z_m == pytest.approx(H)
    write_plan(tmp_path / "p.plan", followed, ORIGIN)
    doc = json.loads((tmp_path / "p.plan").read_text())
    assert doc["mission"]["globalPlanAltitudeMode"] == 2
    assert {e["AltitudeMode"] for e in doc["mission"]["items"]
            if e["command"] == MAV_CMD_NAV_WAYPOINT} == {2}
    back = read_plan(tmp_path / "p.plan", ORIGIN)
    assert np.allclose([w.alt_agl_m for w in back.waypoints], followed.xyz_enu_m[:, 2],
                       atol=0.01)  # MSL less the origin's ground, up to the earth's curve


def test_terrain_frame_written_in_plan_and_wpl(tmp_path):
    terrain = surface(hills)
    followed = follow_terrain(LAWNMOWER, terrain, TERRAIN_ALT)
    assert followed.altitude_frame is AltitudeFrame.TERRAIN_ALT
    assert any(w.terrain_added for w in followed.waypoints)  # the profile to predict
    items = mission_items(followed, ORIGIN)
    wps = [it for it in items if it.command == MAV_CMD_NAV_WAYPOINT]
    # Only the pattern's waypoints, at H above the terrain: the autopilot does the rest.
    assert len(wps) == len(LAWNMOWER.waypoints)
    assert all(it.frame == MAV_FRAME_GLOBAL_TERRAIN_ALT and it.z_m == H for it in wps)
    write_plan(tmp_path / "p.plan", followed, ORIGIN)
    write_plan(tmp_path / "p.waypoints", followed, ORIGIN)
    doc = json.loads((tmp_path / "p.plan").read_text())
    entries = [e for e in doc["mission"]["items"] if e["command"] == MAV_CMD_NAV_WAYPOINT]
    assert doc["mission"]["globalPlanAltitudeMode"] == 4  # QGC AltitudeModeTerrainFrame
    assert all(e["frame"] == 10 and e["AltitudeMode"] == 4 and e["Altitude"] == H
               and e["params"][6] == H for e in entries)
    lines = (tmp_path / "p.waypoints").read_text().splitlines()
    wpl = [f.split("\t") for f in lines[2:] if f.split("\t")[3] == "16"]
    assert len(wpl) == 5 and all(f[2] == "10" and float(f[10]) == H for f in wpl)
    for path in ("p.plan", "p.waypoints"):
        back = read_plan(tmp_path / path, ORIGIN, default_speed_mps=5.0)
        assert [w.alt_agl_m for w in back.waypoints] == [H] * 5


def test_warning_for_a_hill_under_a_constant_altitude_plan_only():
    hill = surface(lambda x, y: 30.0 * np.exp(-((x - 60) ** 2 + (y - 50) ** 2) / 200.0))
    over = Plan((Waypoint(0, 50, 20, 5), Waypoint(120, 50, 20, 5)))  # 20 m above home
    found = clearance_intrusions(over, hill, clearance_m=10.0)
    assert [i.stretch for i in found] == ["leg from waypoint 1 to 2"]
    (i,) = found
    # The top of the hill: 30 m of terrain under a path at 20 m, 60 m along the leg.
    assert (i.x_enu_m, i.y_enu_m, i.along_m) == pytest.approx((60.0, 50.0, 60.0))
    assert i.terrain_z_enu_m == pytest.approx(30.0) and i.path_z_enu_m == pytest.approx(20.0)
    assert "the path is 10.0 m below the terrain, within the clearance 10 m" in i.message()
    # Following the terrain at 15 m clears the 10 m margin everywhere, transits included.
    followed = follow_terrain(over, hill, AMSL)
    assert clearance_intrusions(followed, hill, 10.0) == []
    # Without the hill the constant altitude clears it too.
    assert clearance_intrusions(over, surface(lambda x, y: 0.0 * x), 10.0) == []


def test_trees_and_roofs_rise_into_a_path_as_terrain_does():
    """With what stands on the ground (terrain.surface), the clearance is kept above its
    top: a 25 m block of flats under a path 20 m above flat ground is warned of."""
    flat = surface(lambda x, y: 0.0 * x)
    g = flat.geometry
    h = np.zeros(g.shape)
    kind = np.zeros(g.shape, np.uint8)
    x, _ = g.centres_enu()
    block = (x > 55) & (x < 65)
    h[:, block], kind[:, block] = 25.0, CoverKind.SOLID
    covered = TerrainSurface(g, flat.z_corner_m, "test", cover=GroundCover(g, h, kind))
    over = Plan((Waypoint(0, 50, 20, 5), Waypoint(120, 50, 20, 5)))
    assert clearance_intrusions(over, flat, 10.0) == []
    found = {i.stretch: i for i in clearance_intrusions(over, covered, 10.0)}
    assert sorted(found) == ["leg from waypoint 1 to 2", "return to launch"]
    i = found["leg from waypoint 1 to 2"]
    assert 55 <= i.x_enu_m < 65 and i.terrain_z_enu_m == pytest.approx(25.0)
    assert "the path is 5.0 m below the terrain" in i.message()


def test_takeoff_climbs_to_the_first_waypoint_at_least_its_height_above_ground():
    slope = surface(lambda x, y: -0.1 * y)  # falls 10 m over 100 m north, rises south
    for y, takeoff in ((100.0, H), (-20.0, H + 2.0)):
        plan = follow_terrain(Plan((Waypoint(0, y, H, 5), Waypoint(10, y, H, 5))), slope,
                              AMSL)
        assert mission_items(plan, ORIGIN)[0].z_m == pytest.approx(takeoff)


def test_transits_to_and_from_home_are_checked():
    # A wall at x in [20, 30] m, 25 m high: between home and the survey to the east.
    wall = surface(lambda x, y: np.where((x >= 20) & (x <= 30), 25.0, 0.0))
    plan = follow_terrain(Plan((Waypoint(60, 0, H, 5), Waypoint(60, 40, H, 5))), wall, AMSL)
    names = [i.stretch for i in clearance_intrusions(plan, wall, 10.0)]
    assert names == ["take-off to waypoint 1", "return to launch"]


def test_flat_terrain_gives_todays_plan_and_flight():
    flat = TerrainSurface.flat(GEO)
    for following in (AMSL, TERRAIN_ALT):
        followed = follow_terrain(LAWNMOWER, flat, following)
        assert followed.waypoints == LAWNMOWER.waypoints
        a, b = fly(followed, 5.0), fly(LAWNMOWER, 5.0)
        assert np.array_equal(a.r_body_enu, b.r_body_enu)
        assert np.array_equal(a.R_ned_body, b.R_ned_body) and a.duration_s == b.duration_s
    relative = follow_terrain(LAWNMOWER, flat, TerrainFollowing(AltitudeFrame.RELATIVE))
    assert relative is LAWNMOWER
    assert mission_items(relative, ORIGIN) == mission_items(LAWNMOWER, ORIGIN)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="terrain_tolerance_m must be > 0"):
        TerrainFollowing(tolerance_m=0.0)
    with pytest.raises(ValueError, match="terrain_max_climb_mps must be >= 0"):
        TerrainFollowing(max_climb_mps=-1.0)


def test_terrain_frame_plans_warn_where_the_rates_cannot_hold_the_height():
    terrain = surface(ridge)
    north = Plan((Waypoint(60, 0, H, 5), Waypoint(60, 100, H, 5)))
    # 0.8 slopes at 5 m/s: 4 m/s up (limit 2.5) and 4 m/s down (limit 1.5, the worse).
    (line,) = steep_legs(follow_terrain(north, terrain, TERRAIN_ALT), TERRAIN_ALT)
    assert line.startswith("leg from waypoint 1 to 2, at ENU (60.0, 50.0) m: holding the "
                           "height above terrain at 5 m/s needs 4.0 m/s of descent, more "
                           "than terrain_max_descent_mps 1.5"), line
    slow = Plan(tuple(replace(w, speed_mps=1.0) for w in north.waypoints))
    assert steep_legs(follow_terrain(slow, terrain, TERRAIN_ALT), TERRAIN_ALT) == []
    # An AMSL plan keeps to the rates itself.
    assert steep_legs(follow_terrain(north, terrain, AMSL), AMSL) == []


def test_terrain_planning_keys_are_checked(tmp_path: Path, capsys) -> None:
    mission = load_mission(DEMO)
    # Without a terrain the plan keeps today's constant altitude above home; following a
    # terrain it does not have is refused, naming the key.
    assert str(scenario_of(mission).following.frame) == "relative"
    with pytest.raises(ConfigError, match=r"planning.terrain_frame: amsl follows the "
                                          r"terrain, but the mission has none"):
        scenario_of(mission, {"terrain_frame": "amsl"})
    config = tmp_path / "m.yaml"
    config.write_text(DEMO.read_text() + "\nplanning: {terrain_frame: agl}\n")
    with pytest.raises(ConfigError, match=r"m.yaml: planning.terrain_frame: expected one of "
                                          r"relative, amsl, terrain_alt, got 'agl'"):
        scenario_of(load_mission(config))
    config.write_text(DEMO.read_text() + "\nplanning: {terrain_tolerance_m: 0}\n")
    with pytest.raises(ConfigError, match=r"m.yaml: planning: terrain_tolerance_m must be > 0"):
        scenario_of(load_mission(config))
    assert cli.main(["plan", "--config", str(DEMO), "--altitude-m", "10", "--terrain-frame",
                     "terrain_alt", "--out", str(tmp_path / "p")]) == 2
    assert "planning.terrain_frame: terrain_alt follows the terrain" in capsys.readouterr().err


def test_terrain_warnings_go_to_stderr_and_metrics(tmp_path: Path, capsys) -> None:
    mission = load_mission(DEMO)
    g = mission.domain.grid_geometry(mission.cell_size_m)
    xx, yy = np.meshgrid(g.x0_m + np.arange(g.n_cols + 1), g.y0_m + np.arange(g.n_rows + 1))
    hill = TerrainSurface(g, 8.0 * np.exp(-((xx + 45) ** 2 + (yy + 30) ** 2) / 50.0), "hill")
    mission = dataclasses.replace(mission, terrain=hill)
    for frame, expected in (("relative", True), ("amsl", False)):
        sc = scenario_of(mission, {"terrain_frame": frame, "terrain_clearance_m": 5.0})
        plan, spacing = build_plan(sc, PlanParams("lawnmower", 12.0, 3.0))
        pred = predict(sc, plan)
        warned = terrain_warnings(sc, pred)
        write_prediction(tmp_path / frame, mission, pred, pred.grid, "t", spacing,
                         figures=False, terrain_warnings=warned)
        err = capsys.readouterr().err
        metrics = json.loads((tmp_path / frame / "metrics.json").read_text())["plan"]
        assert metrics["altitude_frame"] == frame and metrics["terrain_warnings"] == warned
        # The 8 m hill (off the take-off line) under a constant 12 m: within 5 m of the
        # path on the legs over it; the terrain-following path is 12 m above it.
        assert bool(warned) is expected
        assert ("WARNING: terrain: leg from waypoint" in err) is expected
