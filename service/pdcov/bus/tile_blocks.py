"""The bus's tiles (``tile_size`` cells a side, named (tile row, tile column)) read from a
grid a block at a time: ``TileBlock``.

The daemon's tiles and status compare, encode and summarise the tiles frames touched.
Reading each such tile by itself copies the grid's cells tile by tile; a block gathers the
bus tiles that fall in one of the grid's own tiles (``core.tiles.TILE_CELLS`` a side), so
each layer is read once per block and the per-tile figures are slices or reductions of that
one array.

Pure numeric code: no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import product

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.tiles import TILE_CELLS, TileKey, Window


def tiles_in(window: Window, tile_size: int) -> Iterator[TileKey]:
    """The bus tiles holding cells of ``window`` (r0, r1, c0, c1; none when empty)."""
    r0, r1, c0, c1 = window
    if r1 <= r0 or c1 <= c0:
        return iter(())
    return product(range(r0 // tile_size, (r1 - 1) // tile_size + 1),
                   range(c0 // tile_size, (c1 - 1) // tile_size + 1))


@dataclass(frozen=True, slots=True)
class TileBlock:
    """Bus tiles ``keys`` (row-major) read together: ``window`` the grid cells (r0, r1, c0,
    c1) of the tiles from ``first`` (tile row, column) to the last row and column of
    ``keys``, ``tile_size`` cells a side (the last clipped at the grid's edge)."""

    keys: tuple[TileKey, ...]
    first: TileKey
    window: Window
    tile_size: int

    def at(self, key: TileKey) -> tuple[int, int]:
        """Tile ``key``'s (row, column) in the block's tile arrays (``per_tile``)."""
        return key[0] - self.first[0], key[1] - self.first[1]

    def cells(self, key: TileKey) -> tuple[slice, slice]:
        """Tile ``key``'s cells in arrays of the block's window."""
        i, j = self.at(key)
        ts = self.tile_size
        return slice(i * ts, (i + 1) * ts), slice(j * ts, (j + 1) * ts)

    def per_tile(self, values: np.ndarray) -> np.ndarray:
        """The sums of ``values`` (the window's shape) over each tile of the block: (tile
        rows, tile columns) of the window."""
        ts = self.tile_size
        h, w = values.shape
        n_r, n_c = -(-h // ts), -(-w // ts)
        if (n_r * ts, n_c * ts) != (h, w):
            values = np.pad(values, ((0, n_r * ts - h), (0, n_c * ts - w)))
        return values.reshape(n_r, ts, n_c, ts).sum(axis=(1, 3))


def tile_blocks(keys: Iterable[TileKey], tile_size: int, geometry: GridGeometry
                ) -> Iterator[TileBlock]:
    """``keys`` (bus tiles of ``tile_size`` cells) by the grid tile holding them, each
    group's block (the window of its tiles' bounding rows and columns), in row-major
    order of the groups."""
    per = max(1, TILE_CELLS // tile_size)  # bus tiles a grid tile's side holds
    groups: dict[TileKey, list[TileKey]] = {}
    for key in sorted(keys):
        groups.setdefault((key[0] // per, key[1] // per), []).append(key)
    for _, found in sorted(groups.items()):
        rows = [k[0] for k in found]
        cols = [k[1] for k in found]
        first = (min(rows), min(cols))
        ts = tile_size
        window = (first[0] * ts, min((max(rows) + 1) * ts, geometry.n_rows),
                  first[1] * ts, min((max(cols) + 1) * ts, geometry.n_cols))
        yield TileBlock(tuple(found), first, window, ts)
