"""The daemon's decisions over a county (30 x 30 km at 1 m, 9 x 10^8 cells): frames, tiles
and status follow the cells the flight touched, never the domain, in memory as over a small
square, and its flown cells equal the small square's grid."""

from __future__ import annotations

import tracemalloc

import numpy as np

from pdcov.core.grid_layer import Layer
from pdcov.service.coverage import LiveCoverage
from tests.support.service_feed import SQUARE_ENU_M, feed, serve_cfg

SIDE_M = 30_000
X0_M, Y0_M = -14_968, -14_968  # the county's corner: the square's cells at a whole offset
COUNTY = ((X0_M, Y0_M), (X0_M + SIDE_M, Y0_M), (X0_M + SIDE_M, Y0_M + SIDE_M),
          (X0_M, Y0_M + SIDE_M))
LAYERS = (Layer.N_OBS, Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.LIMITING)


def flown(polygon_enu_m) -> tuple[LiveCoverage, list[bytes], dict]:
    """A 4 s flight over ``polygon_enu_m``, polled every 0.25 s: the live coverage, the
    tiles messages and the last status's fields."""
    cfg = serve_cfg(polygon_enu_m)
    live = LiveCoverage(cfg, cfg.mission.new_mission_grid(), 0.0)
    tiles = []
    for k in range(16):
        feed(live, 0.25 * k, 0.25 * (k + 1))
        live.process()
        due = live.poll(0.25 * (k + 1))
        if due.tiles is not None:
            tiles.append(due.tiles)
    return live, tiles, live.status_fields(uptime_s=4.0, seq=0, link={}, checkpoint={})


def test_a_county_flight_costs_what_a_small_one_does():
    small, small_tiles, small_status = flown(SQUARE_ENU_M)
    tracemalloc.start()
    try:
        county, county_tiles, status = flown(COUNTY)
        peak_b = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak_b < 40e6  # a dense float32 layer of the county: 3.6 GB; its mask 900 MB
    assert status["cells_free"] == SIDE_M * SIDE_M
    g = county.grid
    assert g.frames == small.grid.frames > 10 and county_tiles and small_tiles
    assert g.nbytes < 4e6 and len(g.tile_keys()) <= 4
    # The square's cells (16..48 east, 0..64 north) in the county's grid.
    r0, c0 = -Y0_M, 16 - X0_M
    window = (r0, r0 + 64, c0, c0 + 32)
    for layer in LAYERS:
        np.testing.assert_array_equal(g.read(layer, window), small.grid.read(layer))
    observed = sum(int(np.count_nonzero(g.read(Layer.N_OBS, w))) for w in g.written_windows())
    assert status["cells_observed"] == observed > small_status["cells_observed"] > 0
