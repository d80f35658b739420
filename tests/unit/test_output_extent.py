"""The cells a run's outputs cover (report/output_extent.py): the whole of a small grid,
the touched tiles of a large one; drawing in blocks; the whole domain's threshold curve;
pd.tif written block by block (report/gis.py)."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.core.grid_layer import Layer
from pdcov.report import output_extent
from pdcov.report.output_extent import (
    drawn_raster,
    grid_proportion_curve,
)
from pdcov.report.output_extent import (
    output_extent as extent_of,
)
from pdcov.report.plots import proportion_curve
from tests.support.evaluate_inputs import ORIGIN
from tests.support.square_grid import pose, square_grid


def seen_grid():
    """A 300 x 300 grid (cells of 1 m about ENU 0) with a few frames near its middle."""
    grid = square_grid(half_m=150.0)
    for x in (-10.0, 0.0, 10.0):
        grid.update(pose(xyz=(x, 20.0, 15.0)))
    return grid


def test_a_small_grid_is_covered_whole():
    grid = seen_grid()
    extent = extent_of(grid)
    assert extent.window == (0, 300, 0, 300) and not extent.cropped and extent.stride == 1
    assert extent.geometry == grid.geometry
    doc = extent.document(ORIGIN)
    assert doc["rows"] == [0, 300] and doc["x_enu_m"] == [-150.0, 150.0]
    assert doc["cropped"] is False and doc["drawn_stride_cells"] == 1


def test_a_large_grid_is_covered_where_its_frames_touched(monkeypatch):
    monkeypatch.setattr(output_extent, "CROP_ABOVE_CELLS", 1000)
    monkeypatch.setattr(output_extent, "CROP_MARGIN_CELLS", 7)
    grid = seen_grid()
    keys = grid.tile_keys()
    assert keys == [(0, 0)]  # the frames near ENU (0, 20) m: cells 125..175
    extent = extent_of(grid)
    # The tile's window (0..256), grown by 7 cells and clipped to the grid.
    assert extent.window == (0, 263, 0, 263) and extent.cropped
    grid = square_grid(half_m=600.0)  # 1200 x 1200: tiles 0..4 a side
    grid.update(pose(xyz=(0.0, 0.0, 15.0)))
    extent = extent_of(grid)
    r0, r1, c0, c1 = extent.window
    assert (r0, r1, c0, c1) == (512 - 7, 768 + 7, 512 - 7, 768 + 7)
    g = extent.geometry
    assert (g.x0_m, g.y0_m, g.n_rows, g.n_cols) == (-600.0 + 505, -600.0 + 505, 270, 270)
    np.testing.assert_array_equal(drawn_raster(grid, extent, hidden=False).pd,
                                  grid.read(Layer.PD, extent.window))


def test_an_untouched_large_grid_is_covered_by_its_south_west_tile(monkeypatch):
    monkeypatch.setattr(output_extent, "CROP_ABOVE_CELLS", 1000)
    assert extent_of(square_grid(half_m=600.0)).window == (0, 512, 0, 512)


def test_a_large_window_is_drawn_in_blocks_of_the_smallest_pd(monkeypatch):
    monkeypatch.setattr(output_extent, "DRAW_MAX_SIDE", 40)
    grid = seen_grid()
    extent = extent_of(grid)
    assert extent.stride == 8  # ceil(300 / 40)
    drawn = drawn_raster(grid, extent, hidden=True)
    assert drawn.pd.shape == (38, 38) and drawn.geometry.cell_size_m == 8.0
    assert (drawn.geometry.x0_m, drawn.geometry.y0_m) == (-150.0, -150.0)
    pd, free = grid.pd, grid.mask
    padded = np.ones((304, 304))
    padded[:300, :300] = np.where(free, pd, 1.0)
    expected = padded.reshape(38, 8, 38, 8).min(axis=(1, 3))
    np.testing.assert_array_equal(drawn.pd, expected)
    assert drawn.mask.all() and drawn.hidden is not None and not drawn.hidden.any()
    assert drawn.pd.max() > 0.5


def test_the_threshold_curve_is_the_whole_grids():
    grid = seen_grid()
    t, p = grid_proportion_curve(grid)
    t_dense, p_dense = proportion_curve(grid.pd, grid.mask)
    np.testing.assert_array_equal(t, t_dense)
    np.testing.assert_allclose(p, p_dense, rtol=0, atol=1e-15)
    assert 0 < p[100] < 1


@pytest.mark.parametrize("shape", [(300, 520), (40, 40), (256, 512)])
def test_geotiff_is_written_block_by_block(tmp_path, shape):
    rasterio = pytest.importorskip("rasterio")
    from pdcov.core.domain import GridGeometry
    from pdcov.report.gis import array_band, write_geotiff

    g = GridGeometry(10.0, -20.0, 2.0, *shape)
    rng = np.random.default_rng(1)
    values, free = rng.random(shape), rng.random(shape) > 0.2
    reads = []

    def band(w):
        reads.append((w[1] - w[0]) * (w[3] - w[2]))
        return values[w[0]:w[1], w[2]:w[3]]

    write_geotiff(tmp_path / "x.tif", {"v": band}, g, ORIGIN, array_band(free),
                  exact_grid=True)
    write_geotiff(tmp_path / "utm.tif", {"v": band}, g, ORIGIN, array_band(free))
    assert max(reads) <= 256 * 256
    with rasterio.open(tmp_path / "x.tif") as src:
        assert tuple(src.transform)[:6] == (2.0, 0.0, 10.0, 0.0, -2.0, -20.0 + 2.0 * shape[0])
        back = np.flipud(src.read(1))
    np.testing.assert_array_equal(back, np.where(free, values, np.nan).astype(np.float32))
    for name in ("x.tif", "utm.tif"):
        with rasterio.open(tmp_path / name) as src:
            assert src.profile["tiled"] and src.block_shapes == [(256, 256)]
            assert src.profile["compress"] == "deflate"


def test_terrain_and_hidden_cells_are_drawn_by_block(monkeypatch):
    from pdcov.core.domain import Domain
    from pdcov.core.grid import CoverageGrid
    from pdcov.core.limiting import LimitingFactor
    from pdcov.core.terrain import TerrainSurface
    from tests.support.square_grid import DETECTOR, PINHOLE

    monkeypatch.setattr(output_extent, "DRAW_MAX_SIDE", 20)
    dom = Domain.from_enu([[-30, -30], [30, -30], [30, 30], [-30, 30]])
    g = dom.grid_geometry(1.0)
    x = np.arange(g.n_cols + 1) - 30.0
    ridge = np.tile(12.0 * np.exp(-0.5 * (x / 2.0) ** 2), (g.n_rows + 1, 1))  # along x = 0
    grid = CoverageGrid(g, dom.free_mask(g), PINHOLE, DETECTOR,
                        terrain=TerrainSurface(g, ridge))
    for y in (-10.0, 0.0, 10.0):
        grid.update(pose(yaw_deg=90.0, xyz=(-15.0, y, 16.0), cam_pitch_deg=-50.0))
    hidden = grid.limiting == LimitingFactor.HIDDEN
    assert hidden.any()
    drawn = drawn_raster(grid, extent_of(grid), hidden=True, terrain=grid.terrain)
    assert drawn.pd.shape == (20, 20) and drawn.terrain_z_m is not None
    z = grid.terrain.centre_z_m(0, 60, 0, 60)
    np.testing.assert_allclose(drawn.terrain_z_m, z.reshape(20, 3, 20, 3).mean(axis=(1, 3)))
    np.testing.assert_array_equal(drawn.hidden, hidden.reshape(20, 3, 20, 3).any(axis=(1, 3)))
