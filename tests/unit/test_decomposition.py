"""Boustrophedon decomposition of a Fig. 3-like domain: exact cover, no overlap, full walk."""

from __future__ import annotations

import math

import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Polygon

from pdcov.core.domain import Domain
from pdcov.planning.decomposition import boustrophedon_decomposition

# Non-convex outer boundary with notches on three sides, one non-convex obstacle (Fig. 3).
OUTER = [(0, 0), (30, 0), (30, 10), (45, 5), (60, 12), (60, 40), (40, 45), (35, 30),
         (25, 45), (0, 40), (8, 20)]
OBSTACLE = [(20, 15), (32, 12), (38, 22), (28, 28), (24, 22)]
FREE = Domain.from_enu(OUTER, [OBSTACLE]).free_space


def check_decomposition(free, angle_rad):
    d = boustrophedon_decomposition(free, angle_rad)
    areas = [c.area for c in d.cells]
    assert all(a > 0 for a in areas)
    assert sum(areas) == pytest.approx(free.area, rel=1e-6)
    assert shapely.union_all(d.cells).symmetric_difference(free).area < 1e-6 * free.area
    for i in range(len(d.cells)):
        for j in range(i + 1, len(d.cells)):
            assert d.cells[i].intersection(d.cells[j]).area < 1e-9 * free.area
    # The walk visits every cell and only steps between adjacent cells.
    assert set(d.walk) == set(range(len(d.cells)))
    edges = set(d.adjacency)
    for a, b in zip(d.walk[:-1], d.walk[1:], strict=True):
        assert (min(a, b), max(a, b)) in edges
    assert d.walk[0] == d.walk[-1]
    return d


@pytest.mark.parametrize("angle_deg", [0, 30, 90, 135, 200])
def test_fig3_domain_cells_cover_free_space_exactly(angle_deg):
    check_decomposition(FREE, math.radians(angle_deg))


def test_fig3_h_equals_x_has_critical_cells_and_monotone_slices():
    d = check_decomposition(FREE, 0.0)
    # The obstacle splits the slices (a split and a merge), the notches add more: more than
    # one cell, and the cells around the obstacle are not all adjacent to each other.
    assert len(d.cells) >= 5
    assert len(d.adjacency) >= len(d.cells) - 1
    # Every slice h = x through a cell is one interval (what makes back-and-forth tracks
    # possible).
    for cell in d.cells:
        x0, y0, x1, y1 = cell.bounds
        for k in range(1, 20):
            x = x0 + (x1 - x0) * k / 20
            cut = cell.intersection(LineString([(x, y0 - 1), (x, y1 + 1)]))
            assert cut.geom_type == "LineString", (x, cut)


def test_convex_square_is_one_cell():
    sq = Polygon([(-60, -60), (-60, -20), (-20, -20), (-20, -60)])
    d = boustrophedon_decomposition(sq, 0.4)
    assert len(d.cells) == 1 and d.walk == (0,)
    assert d.cells[0].area == pytest.approx(1600.0)


def test_obstacle_in_square_splits_into_four_cells():
    d = boustrophedon_decomposition(
        Domain.from_enu([(0, 0), (10, 0), (10, 10), (0, 10)],
                        [[(4, 4), (6, 4), (6, 6), (4, 6)]]).free_space, 0.0)
    # Left of the obstacle, below, above, right: the textbook boustrophedon example.
    assert len(d.cells) == 4
    assert sorted(d.adjacency) == [(0, 1), (0, 2), (1, 3), (2, 3)]


@settings(max_examples=30, deadline=None)
@given(st.floats(0, 2 * math.pi))
def test_any_sweep_direction_covers_exactly(angle_rad):
    check_decomposition(FREE, angle_rad)
