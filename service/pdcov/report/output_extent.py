"""Which cells a run's outputs cover, and at what resolution they are drawn.

One rule (docs/outputs.md "Extent"): a grid of at most ``CROP_ABOVE_CELLS`` cells has its
outputs over the whole grid, as always; a larger one (a county at 1 m) over the extent its
frames touched: the bounding window of the grid's written tiles, grown by
``CROP_MARGIN_CELLS`` on each side and clipped to the grid. The metrics stay over the
whole domain (``CoverageGrid.metrics``).

The figures, outline.geojson and the exports are drawn from a raster of at most
``DRAW_MAX_SIDE`` cells a side: over a larger window each drawn cell is a block of
``stride`` x ``stride`` grid cells holding its free cells' smallest P_D (an outline of
P_D >= t then holds only cells that reach t; a gap holds every cell below the target).
pd.tif always holds every cell of the window (report/gis.py writes it block by block).

Reads the grid by window or tile only: never the whole grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import CellSource, Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.terrain import TerrainSurface
from pdcov.core.tiles import MAX_DENSE_CELLS, TILE_CELLS, TileKey, TileLayout, Window
from pdcov.errors import PdcovError

CROP_ABOVE_CELLS = MAX_DENSE_CELLS
"""Grids of more cells (64 Mi: 8 x 8 km of 1 m cells) have their outputs cropped to the
touched extent; smaller ones cover the whole grid."""
CROP_MARGIN_CELLS = TILE_CELLS
"""Cells added on each side of the touched tiles' window (256: one tile)."""
DRAW_MAX_SIDE = 4096
"""Drawn cells a side at most (figures, outline.geojson, exports): 16 Mi cells, about
150 MB of P_D and mask; a larger window is drawn in blocks of cells."""
_STRIP_BLOCKS = 16  # block rows read at once when drawing in blocks


class TiledSource(CellSource, Protocol):
    """A grid read by window whose written tiles are known: the coverage grid, or a
    ground station's copy of it (``bus.grid_state.GridState``)."""

    @property
    def layout(self) -> TileLayout: ...

    def tile_keys(self) -> list[TileKey]:
        """The tiles written, row by row."""
        ...


@dataclass(frozen=True, slots=True)
class OutputExtent:
    """The cells a run's outputs cover: ``window`` (r0, r1, c0, c1 of the grid),
    ``geometry`` (the window's own grid: ENU m, the same cells), ``cropped`` (False: the
    whole grid) and ``stride`` (grid cells a side per drawn cell, 1: every cell)."""

    window: Window
    geometry: GridGeometry
    cropped: bool
    stride: int

    def document(self, origin: Origin) -> dict[str, Any]:
        """metrics.json's "extent": the window in grid cells (rows and columns, end
        excluded), in ENU metres and as WGS84 south-west and north-east corners."""
        r0, r1, c0, c1 = self.window
        x0, x1, y0, y1 = self.geometry.extent_enu
        corners = enu_to_geodetic(np.array([[x0, y0, 0.0], [x1, y1, 0.0]]), origin)
        return {"cropped": self.cropped, "rows": [r0, r1], "cols": [c0, c1],
                "x_enu_m": [x0, x1], "y_enu_m": [y0, y1],
                "sw_lat_lon_deg": [round(float(corners[0, 0]), 9),
                                   round(float(corners[0, 1]), 9)],
                "ne_lat_lon_deg": [round(float(corners[1, 0]), 9),
                                   round(float(corners[1, 1]), 9)],
                "drawn_stride_cells": self.stride}


def check_prior_fits(geometry: GridGeometry) -> None:
    """PdcovError unless a prior (a whole-grid array) fits ``geometry``: at most
    ``CROP_ABOVE_CELLS`` cells."""
    n = geometry.n_rows * geometry.n_cols
    if n > CROP_ABOVE_CELLS:
        raise PdcovError(f"a prior needs a grid of at most {CROP_ABOVE_CELLS:,} cells; this "
                         f"one has {n:,} (use larger cells, or a smaller domain)")


def window_geometry(geometry: GridGeometry, window: Window) -> GridGeometry:
    """The grid of the cells of ``window`` (r0, r1, c0, c1) of ``geometry``."""
    r0, r1, c0, c1 = window
    c = geometry.cell_size_m
    return GridGeometry(geometry.x0_m + c * c0, geometry.y0_m + c * r0, c, r1 - r0, c1 - c0)


def output_extent(grid: TiledSource) -> OutputExtent:
    """The extent of ``grid``'s outputs (module docstring); a large grid no frame touched
    gets its south-west tile."""
    g = grid.geometry
    whole = (0, g.n_rows, 0, g.n_cols)
    cropped = g.n_rows * g.n_cols > CROP_ABOVE_CELLS
    window = _touched_window(grid) if cropped else whole
    r0, r1, c0, c1 = window
    stride = max(1, math.ceil(max(r1 - r0, c1 - c0) / DRAW_MAX_SIDE))
    return OutputExtent(window, window_geometry(g, window), cropped, stride)


def _touched_window(grid: TiledSource) -> Window:
    """The written tiles' bounding window, grown by CROP_MARGIN_CELLS, clipped."""
    layout, m = grid.layout, CROP_MARGIN_CELLS
    windows = [layout.window_of(k) for k in grid.tile_keys()] or [layout.window_of((0, 0))]
    r0, r1 = min(w[0] for w in windows), max(w[1] for w in windows)
    c0, c1 = min(w[2] for w in windows), max(w[3] for w in windows)
    return (max(0, r0 - m), min(layout.n_rows, r1 + m), max(0, c0 - m),
            min(layout.n_cols, c1 + m))


@dataclass(frozen=True, slots=True)
class DrawnRaster:
    """The extent as drawn: ``pd`` (float64) and ``mask`` (bool) per drawn cell (rows
    growing north), on ``geometry`` (drawn cells of ``stride`` grid cells a side; at
    stride > 1 its last row and column may reach past the window), ``hidden`` (bool: cells
    terrain hid from every frame; None when not asked) and ``terrain_z_m`` (the ground's
    height at the cell centres, m, a block's mean; None without terrain)."""

    pd: np.ndarray
    mask: np.ndarray
    geometry: GridGeometry
    hidden: np.ndarray | None = None
    terrain_z_m: np.ndarray | None = None


def drawn_raster(grid: CellSource, extent: OutputExtent, *, hidden: bool,
                 terrain: TerrainSurface | None = None) -> DrawnRaster:
    """``extent`` drawn from ``grid`` (module docstring) over ``terrain`` (the grid's; None:
    none): every cell at stride 1, else blocks of cells read a strip of blocks at a time
    (each block: its free cells' smallest P_D, free if any cell is, hidden if any free cell
    is, its mean height)."""
    w, s = extent.window, extent.stride
    if s == 1:
        mask = grid.read(Layer.MASK, w)
        return DrawnRaster(
            grid.read(Layer.PD, w), mask, extent.geometry,
            (grid.read(Layer.LIMITING, w) == LimitingFactor.HIDDEN) if hidden else None,
            None if terrain is None else terrain.centre_z_m(*w))
    r0, r1, c0, c1 = w
    h, n = -(-(r1 - r0) // s), -(-(c1 - c0) // s)
    pd, mask = np.zeros((h, n)), np.zeros((h, n), bool)
    hid = np.zeros((h, n), bool) if hidden else None
    z = None if terrain is None else np.zeros((h, n))
    step = s * _STRIP_BLOCKS
    for a in range(r0, r1, step):
        b = min(a + step, r1)
        strip = (a, b, c0, c1)
        rows = slice((a - r0) // s, (a - r0) // s + -(-(b - a) // s))
        free = _blocks(grid.read(Layer.MASK, strip), s, False)
        mask[rows] = free.any(axis=(1, 3))
        pd[rows] = np.where(free, _blocks(grid.read(Layer.PD, strip), s, 1.0),
                            1.0).min(axis=(1, 3))
        if hid is not None:
            hid[rows] = (free & _blocks(grid.read(Layer.LIMITING, strip)
                                        == LimitingFactor.HIDDEN, s, False)).any(axis=(1, 3))
        if z is not None and terrain is not None:
            z[rows] = np.nanmean(_blocks(terrain.centre_z_m(*strip), s, np.nan), axis=(1, 3))
    pd[~mask] = 0.0
    g = extent.geometry
    return DrawnRaster(pd, mask, GridGeometry(g.x0_m, g.y0_m, g.cell_size_m * s, h, n),
                       hid, z)


def _blocks(a: np.ndarray, s: int, fill: float | bool) -> np.ndarray:
    """``a`` padded with ``fill`` to whole s x s blocks, as (rows, s, cols, s)."""
    h, n = -(-a.shape[0] // s), -(-a.shape[1] // s)
    padded = np.full((h * s, n * s), fill, dtype=a.dtype)
    padded[:a.shape[0], :a.shape[1]] = a
    return padded.reshape(h, s, n, s)


def grid_proportion_curve(grid: CoverageGrid, n: int = 201) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds 0..1 and the proportion of the whole grid's free cells with P_D at or
    above each, tile by tile (the free cells of no tile: P_D 0)."""
    t = np.linspace(0.0, 1.0, n)
    n_free = grid.free.n_free
    if n_free == 0:
        return t, np.zeros_like(t)
    below = np.zeros(n, dtype=np.int64)  # free cells with P_D < t, of the written tiles
    untouched = n_free
    for key in grid.tile_keys():
        values = np.sort(grid.read(Layer.PD, grid.layout.window_of(key))[grid.free.tile(key)])
        untouched -= len(values)
        below += np.searchsorted(values, t, side="left")
    below += np.where(t > 0.0, untouched, 0)
    return t, 1.0 - below / n_free
