"""Planners fly over roofs: with terrain.surface the cells under solid cover are obstacles
of the searched domain (not free, not scored), yet plans fly the domain as configured
(``Mission.flight_domain``), keeping planning.terrain_clearance_m above the tops of what
stands on the ground. The scene is tests/support/canopy_config.py's: a 100 x 100 m domain
of 10 m cells with a 10 m house (ENU 10-30 x 10-30 m), a shed and unclassed trees (roofs
too) and 15 m trees, on real GeoTIFFs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import shapely

from pdcov.cli import main
from pdcov.planning.plan_files import read_plan
from pdcov.planning.scenario import scenario_of
from pdcov.planning.vantage import VantageSettings, candidate_evidence
from tests.support.evaluate_inputs import write_config

pytest.importorskip("rasterio")
from tests.support.canopy_config import OBJECTS, doc, load

(HOUSE_BOX, HOUSE_M, _), *_ = OBJECTS
HOUSE = shapely.box(HOUSE_BOX[0], HOUSE_BOX[2], HOUSE_BOX[1], HOUSE_BOX[3])
ROOF_CELLS = [(6, 6), (6, 7), (7, 6), (7, 7), (1, 8), (5, 1)]  # house, shed, unclassed
SEARCHED = np.ones((10, 10), dtype=bool)
SEARCHED[tuple(np.transpose(ROOF_CELLS))] = False
NO_SURFACE = {"with_dsm": False, "with_landcover": False}


def test_plans_fly_the_configured_domain_and_are_scored_on_the_searched_cells(tmp_path):
    mission = load(tmp_path, doc(tmp_path))
    assert len(mission.domain.obstacles) == 3  # the house, the shed, the unclassed trees
    assert not mission.flight_domain.obstacles  # the config gives none
    assert shapely.equals(mission.flight_domain.boundary, mission.domain.boundary)
    sc = scenario_of(mission)
    assert shapely.equals(sc.free_space, mission.flight_domain.free_space)
    assert sc.free_space.contains(HOUSE)
    assert sc.geometry == mission.domain.grid_geometry(mission.cell_size_m)
    np.testing.assert_array_equal(sc.mask, SEARCHED)
    np.testing.assert_array_equal(sc.new_grid().free.dense(), SEARCHED)


@pytest.mark.parametrize("terrain", [NO_SURFACE, {"search_under_roofs": True}])
def test_without_roofs_as_obstacles_the_two_domains_are_one(tmp_path, terrain):
    mission = load(tmp_path, doc(tmp_path, **terrain))
    assert mission.configured_domain is None and mission.flight_domain is mission.domain
    assert scenario_of(mission).mask.all()


def _plan(folder, clearance_m: float, **terrain) -> tuple[dict, str]:
    """``pdcov plan`` lawnmower at 30 m over the scene (``doc(**terrain)``) written in
    ``folder``: metrics.json and plan.waypoints."""
    folder.mkdir()
    config = write_config(folder, doc(folder, **terrain))
    out = folder / "out"
    assert main(["plan", "--config", str(config), "--pattern", "lawnmower", "--altitude-m",
                 "30", "--terrain-clearance-m", str(clearance_m), "--no-figures", "--out",
                 str(out)]) == 0
    return json.loads((out / "metrics.json").read_text()), (out / "plan.waypoints").read_text()


def test_a_lawnmower_flies_over_the_house_as_without_the_dsm(tmp_path):
    metrics, waypoints = _plan(tmp_path / "dsm", 10.0)
    bare_metrics, bare_waypoints = _plan(tmp_path / "dem", 10.0, **NO_SURFACE)
    assert waypoints == bare_waypoints  # the same plan: the roofs are no obstacle to it
    plan = read_plan(tmp_path / "dsm" / "out" / "plan.waypoints",
                     load(tmp_path / "dsm", doc(tmp_path / "dsm")).origin())
    legs = shapely.LineString(plan.xy_enu_m)
    assert legs.intersection(HOUSE).length == pytest.approx(HOUSE_BOX[3] - HOUSE_BOX[2])
    # Scored on the searched cells: the roofs are not free.
    assert (metrics["cells_free"], bare_metrics["cells_free"]) == (94, 100)
    with np.load(tmp_path / "dsm" / "out" / "grid.npz") as grid:
        np.testing.assert_array_equal(grid["mask"], SEARCHED)
    # 30 m up: the house (10 m) and the trees (15 m) keep 10 m below the path.
    assert metrics["plan"]["terrain_warnings"] == []


def test_the_clearance_is_kept_above_the_roof(tmp_path):
    # 25 m of clearance over a 10 m roof: the path at 30 m is 5 m too low over the house,
    # which the DEM alone does not know.
    metrics, _ = _plan(tmp_path / "dsm", 25.0)
    bare, _ = _plan(tmp_path / "dem", 25.0, **NO_SURFACE)
    assert bare["plan"]["terrain_warnings"] == []
    found = [(tuple(map(float, where.groups())), float(above.group(1)))
             for w in metrics["plan"]["terrain_warnings"]
             if (where := re.search(r"at ENU \((-?[\d.]+), (-?[\d.]+)\) m", w))
             and (above := re.search(r"the path is ([\d.]+) m above the terrain", w))]
    over_house = [above for xy, above in found if HOUSE.covers(shapely.Point(xy))]
    assert over_house == [pytest.approx(30.0 - HOUSE_M, abs=0.5)]


def test_vantage_candidates_hover_over_the_roof(tmp_path):
    sc = scenario_of(load(tmp_path, doc(tmp_path)))
    points, evidence, _ = candidate_evidence(sc, VantageSettings(0.8, (40.0,), lattice_m=10.0))
    assert (20.0, 20.0) in {(p.x_enu_m, p.y_enu_m) for p in points}  # the house's centre
    assert evidence.shape == (94, len(points))  # rows: the searched cells only
