"""Per-cell arrays stored in fixed square tiles, each allocated when first written.

A coverage grid over a county (9 x 10^8 cells of 1 m) holds only the tiles its frames
touched: memory, snapshots and checkpoints grow with the cells seen, not with the domain.
Tile (i, j) holds cells rows ``i * size .. (i + 1) * size``, columns ``j * size ..``
(the last row and column of tiles clipped at the grid's edge). Windows are
(r0, r1, c0, c1): rows r0:r1, columns c0:c1 of the grid.

Every write gives the tile a new version (``TiledLayer.changed_since``, from the grid's
``TileClock``): a reader that keeps the version it saw (the bus, a checkpoint, a dense copy)
reads again only the tiles changed since.

Pure numeric core: no I/O.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

TILE_CELLS = 256
"""Cells per tile side: 256 x 256 cells of float32 are 256 KiB, a tile of 1 m cells 6.5 ha."""

MAX_DENSE_CELLS = 2**26
"""Largest grid (cells) read whole as one array (``TiledLayer.dense``): 64 Mi cells, a
256 MiB float32 array. Larger grids are read by window or by tile."""

Window = tuple[int, int, int, int]
TileKey = tuple[int, int]


@dataclass(frozen=True, slots=True)
class TilePart:
    """The cells a tile shares with a window: ``key`` (tile row, tile column), ``in_tile``
    and ``in_window`` (the same cells as slices of the tile's and of the window's arrays)
    and ``cells`` (them as a grid window)."""

    key: TileKey
    in_tile: tuple[slice, slice]
    in_window: tuple[slice, slice]
    cells: Window


@dataclass(frozen=True, slots=True)
class TileLayout:
    """How a grid of ``n_rows`` x ``n_cols`` cells is cut into tiles of ``size`` cells."""

    n_rows: int
    n_cols: int
    size: int = TILE_CELLS

    @property
    def n_tile_rows(self) -> int:
        return -(-self.n_rows // self.size)

    @property
    def n_tile_cols(self) -> int:
        return -(-self.n_cols // self.size)

    def window_of(self, key: TileKey) -> Window:
        """The grid cells (r0, r1, c0, c1) of tile ``key``."""
        s = self.size
        i, j = key
        return i * s, min((i + 1) * s, self.n_rows), j * s, min((j + 1) * s, self.n_cols)

    def shape_of(self, key: TileKey) -> tuple[int, int]:
        r0, r1, c0, c1 = self.window_of(key)
        return r1 - r0, c1 - c0

    def keys(self, window: Window | None = None) -> Iterator[TileKey]:
        """The tiles holding cells of ``window`` (None: the whole grid), row by row."""
        r0, r1, c0, c1 = window or (0, self.n_rows, 0, self.n_cols)
        s = self.size
        for i in range(r0 // s, -(-r1 // s)):
            for j in range(c0 // s, -(-c1 // s)):
                yield i, j

    def parts(self, window: Window) -> Iterator[TilePart]:
        """Each tile's share of ``window``, row by row."""
        r0, r1, c0, c1 = window
        s = self.size
        for i, j in self.keys(window):
            a0, a1 = max(r0, i * s), min(r1, (i + 1) * s)
            b0, b1 = max(c0, j * s), min(c1, (j + 1) * s)
            yield TilePart((i, j), (slice(a0 - i * s, a1 - i * s), slice(b0 - j * s, b1 - j * s)),
                           (slice(a0 - r0, a1 - r0), slice(b0 - c0, b1 - c0)),
                           (a0, a1, b0, b1))


class TileClock:
    """The write counter the layers of one grid share: ``now`` grows by one at every tile
    written, in any layer, so one version says what a reader saw of all of them."""

    def __init__(self) -> None:
        self.now = 0

    def tick(self) -> int:
        self.now += 1
        return self.now


class TiledLayer:
    """One per-cell quantity of a grid (``dtype``; ``depth`` values per cell, e.g. a
    looks state's bins), in tiles of ``layout`` allocated when first written; a cell of no
    tile holds ``fill``. ``clock``: the grid's (None: the layer's own)."""

    def __init__(self, layout: TileLayout, dtype: np.dtype | type, fill: float | bool = 0,
                 depth: tuple[int, ...] = (), clock: TileClock | None = None) -> None:
        self.layout = layout
        self.dtype = np.dtype(dtype)
        self.fill = fill
        self.depth = depth
        self.tiles: dict[TileKey, np.ndarray] = {}
        self._versions: dict[TileKey, int] = {}
        self.clock = TileClock() if clock is None else clock
        self._dense: np.ndarray | None = None  # ``dense``'s copy, and the version it holds
        self._dense_version = 0
        self.frozen: FrozenTiles | None = None  # tiles a reader on another thread is owed

    @property
    def nbytes(self) -> int:
        """Bytes held by the allocated tiles."""
        return sum(t.nbytes for t in self.tiles.values())

    def get(self, key: TileKey) -> np.ndarray | None:
        """Tile ``key``'s array, None when it was never written."""
        return self.tiles.get(key)

    def tile(self, key: TileKey) -> np.ndarray:
        """Tile ``key``'s array for writing now (allocated on first use, filled with
        ``fill``); its version is the clock's next: call it again for a later write."""
        t = self.tiles.get(key)
        if t is None:
            t = np.full((*self.layout.shape_of(key), *self.depth), self.fill, self.dtype)
            self.tiles[key] = t
        elif self.frozen is not None:
            self.frozen.before_write(self, key, t)
        self._versions[key] = self.clock.tick()
        return t

    def changed_since(self, version: int) -> list[TileKey]:
        """The tiles written after the clock was at ``version``."""
        return [k for k, v in self._versions.items() if v > version]

    def read(self, window: Window) -> np.ndarray:
        """The cells of ``window`` (a new array; ``fill`` where no tile)."""
        r0, r1, c0, c1 = window
        out = np.full((r1 - r0, c1 - c0, *self.depth), self.fill, self.dtype)
        for p in self.layout.parts(window):
            t = self.tiles.get(p.key)
            if t is not None:
                out[p.in_window] = t[p.in_tile]
        return out

    def write(self, window: Window, values: np.ndarray | float) -> None:
        """Set the cells of ``window`` to ``values`` (the window's shape, or one value);
        tiles that stay all ``fill`` and were never written are not allocated."""
        values = np.asarray(values, dtype=self.dtype)
        for p in self.layout.parts(window):
            v = values if values.ndim == 0 else values[p.in_window]
            if p.key not in self.tiles and not np.any(v != self.fill):
                continue
            self.tile(p.key)[p.in_tile] = v

    def dense(self) -> np.ndarray:
        """The whole grid as one read-only array, kept between calls: each call copies into
        it only the tiles written since the last. ValueError above ``MAX_DENSE_CELLS``
        cells (a grid that large is read by window or by tile)."""
        n = self.layout.n_rows * self.layout.n_cols
        if n > MAX_DENSE_CELLS:
            raise ValueError(f"a grid of {n:,} cells is read by window or by tile, not whole "
                             f"(at most {MAX_DENSE_CELLS:,} cells)")
        if self._dense is None:
            self._dense = np.full((self.layout.n_rows, self.layout.n_cols, *self.depth),
                                  self.fill, self.dtype)
            self._dense_version = 0
        if self._dense_version != self.clock.now:
            for key in self.changed_since(self._dense_version):
                r0, r1, c0, c1 = self.layout.window_of(key)
                self._dense[r0:r1, c0:c1] = self.tiles[key]
            self._dense_version = self.clock.now
        view = self._dense.view()
        view.flags.writeable = False
        return view


class FrozenTiles:
    """Tiles ``keys`` of ``layers`` as they are now, for a reader on another thread (a
    checkpoint's writer) while the grid goes on: nothing is copied now; a tile is copied
    when the grid first writes it after this moment (``TiledLayer.tile``), or when the
    reader takes it (``of``), whichever comes first, under one lock. ``release`` when
    read (on the grid's thread)."""

    def __init__(self, layers: Mapping[Any, TiledLayer], keys: list[TileKey]) -> None:
        self._lock = threading.Lock()
        self._layers = dict(layers)
        self._owed = {(name, k) for name, lay in self._layers.items() for k in keys
                      if k in lay.tiles}
        self._saved: dict[tuple[object, TileKey], np.ndarray] = {}
        self._name_of = {id(lay): name for name, lay in self._layers.items()}
        for lay in self._layers.values():
            if lay.frozen is not None:
                raise RuntimeError("a layer's tiles are frozen for another reader")
            lay.frozen = self

    def before_write(self, layer: TiledLayer, key: TileKey, tile: np.ndarray) -> None:
        """``layer``'s tile ``key`` (``tile``) is about to be written: keep it as it was."""
        at = (self._name_of[id(layer)], key)
        with self._lock:
            if at in self._owed:
                self._owed.discard(at)
                self._saved[at] = tile.copy()

    def of(self, name: object) -> Mapping[TileKey, np.ndarray]:
        """Layer ``name``'s tiles as they were frozen (each taken once)."""
        return _FrozenLayer(self, name)

    def take(self, name: object, key: TileKey) -> np.ndarray | None:
        """Tile ``key`` of layer ``name`` as it was frozen (None: it had none)."""
        at = (name, key)
        with self._lock:
            saved = self._saved.pop(at, None)
            if saved is not None:
                return saved
            if at not in self._owed:
                return None
            self._owed.discard(at)
            return self._layers[name].tiles[key].copy()

    def has(self, name: object, key: TileKey) -> bool:
        with self._lock:
            return (name, key) in self._owed or (name, key) in self._saved

    def release(self) -> None:
        """The reader is done: the layers write freely again."""
        for lay in self._layers.values():
            if lay.frozen is self:
                lay.frozen = None


class _FrozenLayer(Mapping[TileKey, np.ndarray]):
    """One layer's frozen tiles as a mapping (``FrozenTiles.of``)."""

    def __init__(self, frozen: FrozenTiles, name: object) -> None:
        self._frozen, self._name = frozen, name

    def __getitem__(self, key: TileKey) -> np.ndarray:
        tile = self._frozen.take(self._name, key)
        if tile is None:
            raise KeyError(key)
        return tile

    def __contains__(self, key: object) -> bool:
        return isinstance(key, tuple) and self._frozen.has(self._name, key)

    def __iter__(self) -> Iterator[TileKey]:
        raise TypeError("frozen tiles are taken by key")

    def __len__(self) -> int:
        raise TypeError("frozen tiles are taken by key")
