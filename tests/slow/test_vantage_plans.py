"""Whole vantage plans of the test scene (module-scoped, a few seconds each): hover frames
reach the target by the per-pixel reference, transits stay in free space, the fleet's
balance, sorties within the flight time, the gimbal's pitch, and the command line and
`pdcov optimise` writing them."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point, Polygon

from pdcov.cli import main as pdcov_main
from pdcov.core.mission import MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError
from pdcov.planning.optimise import Scenario, flight_poses
from pdcov.planning.plan_items import mission_items
from pdcov.planning.tours import Fleet
from pdcov.planning.vantage_missions import plan_vantage_missions
from tests.support.references import ReferenceGrid, pixel_rays, r1_update
from tests.support.vantage_scene import (
    GREEDY,
    MISSION_YAML,
    OBLIQUE_SETTINGS,
    OBSTACLE,
    ORIGIN,
    ROUTING_S,
    SETTINGS,
    TARGET_PD,
    scene,
)


@pytest.fixture(scope="module")
def single():
    return plan_vantage_missions(scene(), SETTINGS, routing_time_s=ROUTING_S)


@pytest.fixture(scope="module")
def oblique():
    """SETTINGS on a gimbal at -90, -60 and -45 deg, the oblique ones at 8 earth-frame yaws
    (greedy: the integer program finds no better cover of ~4,500 candidates in 10 s)."""
    return plan_vantage_missions(scene(GimbalMount()), OBLIQUE_SETTINGS,
                                 routing_time_s=ROUTING_S)


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


def test_a_gimbal_mission_commands_the_scenarios_pitch():
    sc = scene(GimbalMount())
    m = plan_vantage_missions(sc, GREEDY, routing_time_s=0.5)
    items = mission_items(m.missions[0].prediction.plan, ORIGIN)
    assert items[1].command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    assert items[1].param1 == pytest.approx(-90.0)


def test_more_vehicles_than_points_is_refused(single):
    n = len(single.cover.points)
    with pytest.raises(ConfigError, match=f"--vehicles {n + 1}: more vehicles than vantage "
                                          f"points \\({n}\\)"):
        plan_vantage_missions(scene(), SETTINGS, Fleet(n + 1), routing_time_s=ROUTING_S)


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
