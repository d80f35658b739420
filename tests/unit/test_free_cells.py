"""The free cells found tile by tile (core/free_cells.py) are the whole mask's cell for cell:
tiles the free space covers, tiles it misses and tiles its boundary crosses."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.free_cells import FreeCells

DOMAINS = {
    # Edges on tile borders (cells of 1 m, tiles of 256): covered tiles touch the boundary.
    "aligned square": ([[0, 0], [512, 0], [512, 768], [0, 768]], []),
    "L with an obstacle": ([[-300, -280], [300, -280], [300, 0], [0, 0], [0, 280],
                            [-300, 280]],
                           [[[-100, -100], [-60, -100], [-60, -60], [-100, -60]]]),
    "skewed, off the cell lattice": ([[0.3, 0.2], [700.7, 5.1], [650, 690.2], [10, 640]],
                                     [[[200.5, 200.5], [300.25, 210], [260, 330]]]),
    # A boundary through cell centres: a centre on it is not inside (as contains_xy).
    "edge through centres": ([[0, 0], [600.5, 0], [600.5, 300.5], [0, 300.5]], []),
}


@pytest.mark.parametrize("name", list(DOMAINS))
def test_tiles_equal_the_whole_mask(name):
    polygon, obstacles = DOMAINS[name]
    domain = Domain.from_enu(polygon, obstacles)
    g = domain.grid_geometry(1.0)
    whole = domain.free_mask(g)
    free = FreeCells(g, free_space=domain.free_space)
    assert free.n_free == int(whole.sum())
    np.testing.assert_array_equal(free.window((37, 301, 5, 290)), whole[37:301, 5:290])
    np.testing.assert_array_equal(free.dense(), whole)
    assert free.same_as(FreeCells(g, mask=whole))


def test_a_county_is_counted_without_its_mask():
    domain = Domain.from_enu([[0, 0], [30_000, 0], [30_000, 30_000], [0, 30_000]],
                             [[[1000.5, 1000.5], [2000, 1000.5], [1500, 2500]]])
    g = domain.grid_geometry(1.0)
    tracemalloc.start()
    free = FreeCells(g, free_space=domain.free_space)
    n = free.n_free
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    corner = domain.free_mask(GridGeometry(0.0, 0.0, 1.0, 3000, 3000))  # the obstacle's
    assert n == 900_000_000 - int((~corner).sum())
    assert peak < 20e6  # a dense mask would be 900 MB
