"""Which cells of a grid are free (searchable), tile by tile.

A cell is free when its centre lies in the domain's free space (``core/domain.py``). Over a
county the mask is not built whole: a tile whose area the free space covers is all free,
one that misses it all blocked, and only the tiles the boundary or an obstacle
crosses test their cell centres (the same test as a whole mask, so the same cells). A grid
made from a mask array (a snapshot, a test) reads its tiles from that array.

Pure numeric core: no I/O.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon

from pdcov.core.domain import GridGeometry
from pdcov.core.tiles import TileKey, TileLayout, Window


class FreeCells:
    """The free cells of ``geometry`` in tiles: from ``mask`` (bool, the grid's shape) or
    from ``free_space`` (ENU metres, ``Domain.free_space``), exactly one of them."""

    def __init__(self, geometry: GridGeometry, *, mask: np.ndarray | None = None,
                 free_space: Polygon | MultiPolygon | None = None) -> None:
        if (mask is None) == (free_space is None):
            raise ValueError("FreeCells: give a mask or a free space, not both")
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != geometry.shape:
                raise ValueError(f"mask shape {mask.shape} != grid shape {geometry.shape}")
            mask = mask.view()
            mask.flags.writeable = False
        else:
            shapely.prepare(free_space)
        self.geometry = geometry
        self.layout = TileLayout(geometry.n_rows, geometry.n_cols)
        self._mask = mask
        self._free_space = free_space
        self._tiles: dict[TileKey, np.ndarray] = {}
        self._n_free: int | None = None
        self._constants: dict[tuple[tuple[int, int], bool], np.ndarray] = {}

    @property
    def free_space(self) -> Polygon | MultiPolygon | None:
        """The free space the cells were found in (ENU metres); None for a mask array."""
        return self._free_space

    def tile(self, key: TileKey) -> np.ndarray:
        """Tile ``key``'s free cells (bool, read-only), kept once computed."""
        found = self._tiles.get(key)
        if found is None:
            r0, r1, c0, c1 = self.layout.window_of(key)
            found = (self._mask[r0:r1, c0:c1] if self._mask is not None
                     else self._tile_of_space(key))
            self._tiles[key] = found
        return found

    def window(self, window: Window) -> np.ndarray:
        """The free cells of ``window`` (bool, read-only where it is one array's view)."""
        r0, r1, c0, c1 = window
        if self._mask is not None:
            return self._mask[r0:r1, c0:c1]
        out = np.empty((r1 - r0, c1 - c0), dtype=bool)
        for p in self.layout.parts(window):
            out[p.in_window] = self.tile(p.key)[p.in_tile]
        return out

    def dense(self) -> np.ndarray:
        """The whole mask (bool, read-only)."""
        if self._mask is None:
            self._mask = self.window((0, self.layout.n_rows, 0, self.layout.n_cols))
            self._mask.flags.writeable = False
        return self._mask

    def packed_rows(self) -> Iterator[np.ndarray]:
        """The whole mask, row-major, as ``np.packbits`` (uint8) of bands of ``layout.size``
        rows, one band built at a time (tiles not kept): their concatenation is
        ``np.packbits`` of the whole mask, as a band's cells are a multiple of 8."""
        n_rows, n_cols, s = self.layout.n_rows, self.layout.n_cols, self.layout.size
        for r0 in range(0, n_rows, s):
            window = (r0, min(r0 + s, n_rows), 0, n_cols)
            if self._mask is not None:
                band = self._mask[r0:window[1]]
            else:
                band = np.empty((window[1] - r0, n_cols), dtype=bool)
                for p in self.layout.parts(window):
                    found = self._tiles.get(p.key)
                    band[p.in_window] = (self._tile_of_space(p.key) if found is None
                                         else found)[p.in_tile]
            yield np.packbits(band)

    @property
    def n_free(self) -> int:
        """Free cells in the whole grid."""
        if self._n_free is None:
            self._n_free = (int(np.count_nonzero(self._mask)) if self._mask is not None else
                            sum(int(np.count_nonzero(self._tile_of_space(k)))
                                for k in self.layout.keys()))
        return self._n_free

    def same_as(self, other: FreeCells) -> bool:
        """Whether both mark the same cells free (the same grid, and the same free space
        or equal masks)."""
        if self is other:
            return True
        if self.geometry != other.geometry:
            return False
        if self._free_space is not None and other._free_space is not None:
            return bool(shapely.equals(self._free_space, other._free_space))
        return bool(np.array_equal(self.dense(), other.dense()))

    def _tile_of_space(self, key: TileKey) -> np.ndarray:
        """Tile ``key`` of the free space (read-only): all free or all blocked by the tile's
        area, else by its cell centres. Whole tiles share one array per shape and value."""
        free = self._free_space
        assert free is not None
        g = self.geometry
        cs = g.cell_size_m
        r0, r1, c0, c1 = self.layout.window_of(key)
        area = shapely.box(g.x0_m + cs * c0, g.y0_m + cs * r0, g.x0_m + cs * c1,
                           g.y0_m + cs * r1)
        # Covered (touching the boundary allowed): the boundary cannot cross the tile's
        # interior, where the centres lie, so every centre is inside.
        if shapely.covers(free, area):
            return self._constant(self.layout.shape_of(key), True)
        if shapely.disjoint(free, area):
            return self._constant(self.layout.shape_of(key), False)
        xs = g.x0_m + cs * (np.arange(c0, c1) + 0.5)
        ys = g.y0_m + cs * (np.arange(r0, r1) + 0.5)
        X, Y = np.meshgrid(xs, ys)
        tested = shapely.contains_xy(free, X, Y)
        tested.flags.writeable = False
        return tested

    def _constant(self, shape: tuple[int, int], value: bool) -> np.ndarray:
        """One shared read-only array of ``shape`` all ``value``."""
        found = self._constants.get((shape, value))
        if found is None:
            found = np.full(shape, value)
            found.flags.writeable = False
            self._constants[(shape, value)] = found
        return found
