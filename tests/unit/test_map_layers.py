"""The web map's layers in lat/lon (ground/map_layers.py): the heat map resampled onto web
Mercator is the grid itself at mission scale and the warp over tens of kilometres, checked
against pymap3d and the OpenStreetMap tile formula; the error of not warping, as the docs
quote it; the threshold outline by hand."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin
from pdcov.ground.fleet_merge import block_max_pd
from pdcov.ground.map_layers import (
    MAX_OUTLINE_SEGMENTS,
    OFF_GRID,
    mercator_raster,
    outline_segments_xy,
    overlay_error_m,
)
from pdcov.ground.web import blocks_payload

ZURICH = Origin(47.397742, 8.545594, 488.0)


def test_at_mission_scale_the_raster_is_the_grid():
    q = np.arange(300 * 400, dtype=np.int64).reshape(300, 400) % 250
    bounds, raster = mercator_raster(q.astype(np.uint8), -200.0, -150.0, 1.0, ZURICH)
    assert raster.shape == (300, 400)
    np.testing.assert_array_equal(raster, np.flipud(q))  # rows from the north
    # The bounds are the grid's corners (pymap3d): SW and NE, to 2 cm (they enclose the
    # west edge, which the meridians cross at a slant).
    sw = pymap3d.enu2geodetic(-200, -150, 0, ZURICH.lat_deg, ZURICH.lon_deg, 488.0)[:2]
    ne = pymap3d.enu2geodetic(200, 150, 0, ZURICH.lat_deg, ZURICH.lon_deg, 488.0)[:2]
    assert bounds[0] == pytest.approx(list(sw), abs=2e-7)
    assert bounds[1] == pytest.approx(list(ne), abs=2e-7)


@pytest.mark.parametrize("lat_deg", [0.0, 47.4, 65.0, -60.0])
def test_over_tens_of_kilometres_each_cell_is_drawn_where_it_lies(lat_deg):
    origin = Origin(lat_deg, 10.0, 0.0)
    n, cell = 200, 200.0  # 40 km a side: a plain overlay would be metres off
    q = (np.arange(n * n) % 250).reshape(n, n).astype(np.uint8)
    bounds, raster = mercator_raster(q, -20_000.0, -20_000.0, cell, origin)
    # Every pixel shows the cell its centre lies in: the centre by the slippy-map formula,
    # the cell by pymap3d.
    h, w = raster.shape
    (south, west), (north, east) = bounds

    def merc(lat):  # the slippy-map formula's northing, in units of the sphere's radius
        return np.log(np.tan(np.radians(lat)) + 1 / np.cos(np.radians(lat)))

    py, px = np.mgrid[0:h, 0:w] + 0.5
    lon = west + px / w * (east - west)
    lat = np.degrees(np.arctan(np.sinh(merc(north) - py / h * (merc(north) - merc(south)))))
    x, y, _ = pymap3d.geodetic2enu(lat, lon, 0 * lat, origin.lat_deg, origin.lon_deg, 0.0)
    fcol, frow = (x + 20_000) / cell, (y + 20_000) / cell
    col, row = np.floor(fcol), np.floor(frow)
    inside = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    expected = np.full(raster.shape, OFF_GRID)
    expected[inside] = q[row[inside].astype(int), col[inside].astype(int)]
    # Only a centre on a cell's edge (to rounding) may go to the cell on either side.
    to_edge = np.minimum(abs(fcol - np.round(fcol)), abs(frow - np.round(frow)))
    assert np.all(to_edge[raster != expected] < 1e-9)
    assert abs(h - n) <= 2 and abs(w - n) <= 2 * n * math.tan(math.radians(abs(lat_deg))) \
        * 20_000 / 6.4e6 + 2  # the grid turned by the meridians' convergence


def test_the_error_of_not_warping_is_as_the_docs_say():
    for side_m, most_m in ((200.0, 0.004), (1000.0, 0.09), (10_000.0, 9.0)):
        err = overlay_error_m(-side_m / 2, -side_m / 2, side_m, side_m, ZURICH)
        assert most_m / 3 < err < most_m, (side_m, err)


def test_the_outline_of_an_l_shape_by_hand():
    hit = np.zeros((4, 5), bool)
    hit[1:3, 1:4] = True  # rows 1-2 (from the south), columns 1-3
    hit[3, 2] = True
    segs = outline_segments_xy(hit, 10.0, 20.0, 2.0)
    got = sorted(tuple(map(tuple, s)) for s in segs.tolist())
    want = sorted([
        ((12.0, 22.0), (18.0, 22.0)), ((12.0, 26.0), (14.0, 26.0)), ((16.0, 26.0), (18.0, 26.0)),
        ((14.0, 28.0), (16.0, 28.0)), ((12.0, 22.0), (12.0, 26.0)), ((18.0, 22.0), (18.0, 26.0)),
        ((14.0, 26.0), (14.0, 28.0)), ((16.0, 26.0), (16.0, 28.0))])
    assert got == want
    perimeter = sum(math.dist(*s) for s in segs.tolist())
    assert perimeter == 2 * (6 + 4) + 2 * 2


def test_an_outline_too_detailed_is_not_sent_and_says_so():
    n = 300  # noise: edges in every direction, few to join
    pd = np.random.default_rng(1).random((n, n))
    g = blocks_payload(block_max_pd(pd, np.ones((n, n), bool), 1), 1,
                       GridGeometry(0, 0, 1.0, n, n), ZURICH, 0.8)
    assert g["outline_lat_lon"] is None
    assert f"more than {MAX_OUTLINE_SEGMENTS}" in g["outline_note"]
    g = blocks_payload(block_max_pd(np.ones((4, 4)), np.ones((4, 4), bool), 1), 1,
                       GridGeometry(0, 0, 1.0, 4, 4), ZURICH, 0.8)
    assert len(g["outline_lat_lon"]) == 4 and g["outline_note"] is None
    assert (g["w"], g["h"]) == (4, 4)
