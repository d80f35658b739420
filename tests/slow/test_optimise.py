"""Prediction and parameter sweep: a real sweep on a small domain, and the Pareto front."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.pose import FixedMount
from pdcov.planning.optimise import (
    PlanParams,
    Scenario,
    Score,
    best_index,
    build_plan,
    candidates,
    pareto_front,
    predict,
    sweep,
)


def small_scenario(size_m=16.0):
    dom = Domain.from_enu([(0, 0), (size_m, 0), (size_m, size_m), (0, size_m)])
    geo = dom.grid_geometry(1.0)
    return Scenario(dom.free_space, geo, dom.free_mask(geo), CameraModel.from_fov(640, 480, 70),
                    DetectorModel.illustrative(), FixedMount(), frame_rate_hz=2.0)


def dominates(a: Score, b: Score) -> bool:
    return (a.proportion >= b.proportion and a.flight_time_s <= b.flight_time_s
            and (a.proportion > b.proportion or a.flight_time_s < b.flight_time_s))


def test_swath_of_a_nadir_camera():
    sc = small_scenario()
    # 70 deg horizontal field of view, image x across the track: 2 h tan(35 deg).
    assert sc.swath_width_m(10.0) == pytest.approx(20 * math.tan(math.radians(35)), rel=1e-3)


def test_sweep_front_is_non_dominated_and_complete():
    sc = small_scenario()
    params = candidates(["lawnmower", "spiral"], [6.0, 12.0], [3.0, 8.0], [0.0, math.pi / 2],
                        None, [0.0, 0.4])
    assert len(params) == 2 * 2 * 2 * 2 + 2 * 2 * 2  # the spiral has no heading
    scores, failures = sweep(sc, params, target_pd=0.8, processes=2)
    assert failures == [] and len(scores) == len(params)
    assert [s.params for s in scores] == params
    front = pareto_front(scores)
    assert front
    for i in front:
        assert not any(dominates(scores[j], scores[i]) for j in range(len(scores)))
    for j in set(range(len(scores))) - set(front):
        assert any(dominates(scores[i], scores[j]) or (
            scores[i].proportion == scores[j].proportion
            and scores[i].flight_time_s == scores[j].flight_time_s) for i in front)
    # Slower and lower flights see more; the sweep must not give every plan the same score.
    assert len({round(s.proportion, 6) for s in scores}) > 1
    assert len({round(s.flight_time_s, 3) for s in scores}) > 1


def test_prediction_matches_sweep_score():
    sc = small_scenario()
    p = PlanParams("lawnmower", 8.0, 4.0, 0.0, None, 0.2)
    plan, spacing = build_plan(sc, p)
    assert spacing == pytest.approx(0.8 * sc.swath_width_m(8.0))
    pred = predict(sc, plan, p)
    (s,), _ = sweep(sc, [p], 0.5, processes=1)
    assert s.flight_time_s == pytest.approx(pred.flight.duration_s)
    assert s.proportion == pytest.approx((pred.grid.pd[sc.mask] >= 0.5).mean())
    assert pred.grid.frames == len(pred.flight.t_s) > 0


score_st = st.builds(lambda p, t: Score(PlanParams("spiral", 10, 5), 5.0, p, t, 0.0, 0.0),
                     st.floats(0, 1), st.floats(1, 100))


@settings(max_examples=200, deadline=None)
@given(st.lists(score_st, min_size=1, max_size=30))
def test_pareto_front_property(scores):
    front = pareto_front(scores)
    for i in front:
        assert not any(dominates(s, scores[i]) for s in scores)
    times = [scores[i].flight_time_s for i in front]
    assert times == sorted(times)


def test_best_is_shortest_reaching_the_minimum():
    mk = [Score(PlanParams("spiral", 10, 5), 5.0, p, t, 0.0, 0.0)
          for p, t in [(0.99, 300), (0.96, 200), (0.90, 100)]]
    assert best_index(mk, 0.95) == 1
    assert best_index(mk, 0.999) == 0


def test_refly_finds_the_gaps_and_lifts_them_to_the_target():
    import numpy as np

    from pdcov.planning.refly import find_gaps, plan_refly

    dom = Domain.from_enu([(0, 0), (40, 0), (40, 40), (0, 40)])
    geo = dom.grid_geometry(1.0)
    sc = Scenario(dom.free_space, geo, dom.free_mask(geo), CameraModel.from_fov(1280, 720, 60),
                  DetectorModel.illustrative(), FixedMount(), frame_rate_hz=1.0)
    first = predict(sc, build_plan(sc, PlanParams("lawnmower", 12.0, 8.0, spacing_m=20.0))[0])
    gaps = find_gaps(first.grid.pd, sc, 0.8)
    assert 0 < gaps.n_cells < sc.mask.sum()
    assert sum(r.area for r in gaps.regions) == pytest.approx(gaps.n_cells * 1.0)
    assert np.all(first.grid.pd[gaps.mask] < 0.8) and np.all(first.grid.pd[~gaps.mask] >= 0.8)
    r = plan_refly(sc, first.grid, 0.8, 10.0, 3.0, 8.0, start_enu_m=(20.0, 20.0))
    assert r.gaps_before.n_cells == gaps.n_cells
    assert r.gaps_after.n_cells <= 0.01 * gaps.n_cells
    # P_D only grows with a second flight; the follow-up stays in the free space, and beats
    # re-surveying the square with the same tracks spacing, which leaves gaps.
    assert np.all(r.pd_after >= first.grid.pd - 1e-6)
    assert dom.free_space.buffer(1e-4).covers(LineString(r.plan.xy_enu_m))
    full = predict(sc, build_plan(sc, PlanParams("lawnmower", 10.0, 3.0, spacing_m=8.0))[0])
    full_after = -np.expm1(first.grid.log_miss_d + full.grid.log_miss_d)
    assert find_gaps(full_after, sc, 0.8).n_cells > r.gaps_after.n_cells


def test_cli_plan_writes_plan_and_prediction(tmp_path):
    import json
    from importlib import resources

    from pdcov.cli import main
    from pdcov.config.load import load_mission
    from pdcov.planning.plan_files import read_plan

    cfg = resources.files("pdcov") / "data" / "demo_mission.yaml"
    out = tmp_path / "plan"
    assert main(["plan", "--config", str(cfg), "--pattern", "spiral", "--altitude-m", "10",
                 "--speed-mps", "6", "--out", str(out), "--no-figures"]) == 0
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["plan"]["flight_time_s"] > doc["plan"]["path_length_m"] / 6.0
    assert doc["plan"]["waypoints"] > 10
    mission = load_mission(cfg)
    plan = read_plan(out / "plan.plan", mission.origin())
    wpl = read_plan(out / "plan.waypoints", mission.origin())
    assert len(plan.waypoints) == len(wpl.waypoints) == doc["plan"]["waypoints"]
    assert all(abs(a.x_enu_m - b.x_enu_m) < 1e-3 and abs(a.y_enu_m - b.y_enu_m) < 1e-3
               for a, b in zip(plan.waypoints, wpl.waypoints, strict=True))
    assert all(w.speed_mps == 6.0 and w.alt_agl_m == 10.0 for w in plan.waypoints)
    assert (out / "grid.npz").exists()


@pytest.mark.parametrize("pattern, extra, flag", [
    ("sector", ["--spacing-m", "10"], "--spacing-m"),
    ("sector-2", ["--overlap", "0.3"], "--overlap"),
    ("expanding-square", ["--radius-m", "30"], "--radius-m"),
    ("lawnmower", ["--radius-m", "30"], "--radius-m"),
    ("lawnmower", ["--centre-enu-m", "-40", "-40"], "--centre-enu-m"),
    ("spiral", ["--heading-deg", "45"], "--heading-deg"),
])
def test_cli_plan_refuses_options_the_pattern_does_not_use(tmp_path, capsys, pattern, extra,
                                                            flag):
    from importlib import resources

    from pdcov.cli import main

    cfg = resources.files("pdcov") / "data" / "demo_mission.yaml"
    out = tmp_path / "plan"
    assert main(["plan", "--config", str(cfg), "--pattern", pattern, "--altitude-m", "10",
                 *extra, "--out", str(out), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert f"{flag} does not apply to the {pattern} pattern" in err
    assert "Traceback" not in err and not out.exists()


def test_cli_sector_plan_has_no_spacing_and_names_its_coverage(tmp_path):
    import json
    from importlib import resources

    from pdcov.cli import main

    cfg = resources.files("pdcov") / "data" / "demo_mission.yaml"
    out = tmp_path / "plan"
    assert main(["plan", "--config", str(cfg), "--pattern", "sector-2", "--altitude-m", "10",
                 "--heading-deg", "10", "--out", str(out), "--no-figures"]) == 0
    plan = json.loads((out / "metrics.json").read_text())["plan"]
    assert plan["spacing_m"] is None
    assert "second pattern turned 30 deg" in plan["description"]
    assert "of the free space" in plan["description"]
