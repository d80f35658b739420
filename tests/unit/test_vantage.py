"""Vantage-point plans (planning/cover.py, vantage.py, tours.py, vantage_missions.py): the
covering program against brute force, lattices and hover looks, refusals, bad input of the
command line and vantage over terrain. The gimbal's pointing: test_vantage_pointing.py;
whole plans of the scene: tests/slow/test_vantage_plans.py."""

from __future__ import annotations

import itertools
import math
import sys
from dataclasses import replace

import numpy as np
import pytest
import shapely
from scipy import sparse
from shapely.geometry import Polygon

from pdcov.cli import main as pdcov_main
from pdcov.core.mission import HoverItem
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError
from pdcov.extras import ROUTING
from pdcov.planning.cover import CoverProblem, exact_cover, greedy_cover
from pdcov.planning.plan_items import mission_items
from pdcov.planning.tours import Fleet
from pdcov.planning.vantage import VantageSettings, hover_looks, lattice_enu_m
from pdcov.planning.vantage_missions import plan_vantage_missions
from tests.support.vantage_scene import GREEDY, MISSION_YAML, ORIGIN, TARGET_PD, pointed_plan, scene

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


# -- mission items ----------------------------------------------------------------------------


# -- bad input --------------------------------------------------------------------------------

def test_a_target_no_candidate_reaches_names_the_cells_and_why():
    with pytest.raises(ConfigError, match=r"cannot reach P_D 0.9.*too small in the picture at "
                                          r"every height"):
        plan_vantage_missions(scene(), VantageSettings(TARGET_PD, (150.0,), (1.0,),
                                                       lattice_m=8.0, exact_time_limit_s=0))


def test_a_flight_time_too_short_for_one_point_is_refused():
    with pytest.raises(ConfigError, match=r"--max-flight-time-s 5: the vantage point at .* "
                                          r"alone takes"):
        plan_vantage_missions(scene(), GREEDY, Fleet(1, 5.0), routing_time_s=0.5)


def test_routing_without_ortools_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "ortools", None)
    assert ROUTING.message() == ("pdcov plan --pattern vantage needs ortools: "
                                 "pip install 'pdcov[routing]'")


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
    err = [line for line in capsys.readouterr().err.strip().splitlines()
           if not line.startswith("vantage candidates:")]  # its progress, then the error
    assert rc != 0
    assert len(err) == 1 and message in err[0], err


def test_cli_oblique_pitches_default_to_eight_earth_frame_yaws(tmp_path, capsys):
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
    err = capsys.readouterr().err  # a long command shows where it is: its candidates, then
    assert "vantage candidates" in err and "frames" in err  # the predicted mission


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
