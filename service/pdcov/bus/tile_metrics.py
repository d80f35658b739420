"""The status metrics of a grid kept per tile, so that the periodic cost follows the cells
written, not the size of the grid: the daemon's status (service/coverage.py) and the
watcher's figures of each vehicle and of the fleet (ground/feed.py, ground/fleet_merge.py),
one rule for both.

Each tile (the bus tiles' cut, ``tile_size`` cells a side) that may hold a look keeps its
counts of free cells at or above each positive threshold, its observed free cells, and its
float64 sums of P_D over free cells and of P_FA over observed free cells; a tile is
recomputed only after ``mark`` says cells in it may have changed (``CoverageGrid.touched``,
the tiles a watcher applied), the touched tiles a block at a time (``tile_blocks``). At
first the tiles the grid holds are stale (``CellSource.written_windows``: a resumed grid's,
a ground station's copy whole); a tile never written has P_D 0
and no look, so its free cells count only at thresholds <= 0, where every free cell of the
grid counts (``n_free``). The counts, so the proportions at a threshold and the cells
observed, equal a whole-grid count exactly (``CoverageGrid.metrics``); the float sums are
the tiles' sums added exactly rounded (``math.fsum``), so they depend only on the grid's
values, not on the order of the updates, and differ from a whole-grid ``sum`` only by
rounding (about 1e-16 relative).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pdcov.bus.tile_blocks import TileBlock, tile_blocks, tiles_in
from pdcov.core.grid_layer import CellSource, Layer
from pdcov.core.tiles import TileKey


@dataclass(frozen=True, slots=True)
class GridSummary:
    """A grid's status metrics: counts of free cells (all, observed, at or above each
    threshold) and the sums of P_D over free cells and P_FA over observed free cells."""

    cells_free: int
    cells_observed: int
    at_or_above: dict[float, int]
    sum_pd: float
    expected_false_alarms: float

    def proportion_at_or_above(self, threshold: float) -> float:
        """Share of free cells with P_D >= threshold (a threshold the metrics were kept for)."""
        n = self.cells_free
        return self.at_or_above[float(threshold)] / n if n else 0.0

    @property
    def mean_pd(self) -> float:
        return self.sum_pd / self.cells_free if self.cells_free else 0.0


class TileMetrics:
    """Per-tile status metrics of ``source`` (a grid read by window) for
    ``thresholds`` (P_D values)."""

    def __init__(self, source: CellSource, tile_size: int, thresholds: Iterable[float]
                 ) -> None:
        self.source = source
        self.tile_size = tile_size
        self.thresholds = tuple(sorted({float(t) for t in thresholds}))
        self._positive = tuple(t for t in self.thresholds if t > 0)  # others: every free cell
        # Per tile holding a look, its slot in the arrays below (grown as tiles are seen).
        self._slot: dict[TileKey, int] = {}
        self._at_or_above = np.zeros((0, len(self._positive)), np.int64)
        self._observed = np.zeros(0, np.int64)
        self._sum_pd = np.zeros(0, np.float64)
        self._sum_pfa = np.zeros(0, np.float64)
        self._stale: set[TileKey] = set()
        self.cells_free = source.n_free  # the mask never changes
        for window in source.written_windows():
            self.mark(window)

    def mark(self, window: tuple[int, int, int, int]) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed."""
        self._stale.update(tiles_in(window, self.tile_size))

    def summary(self) -> GridSummary:
        """The metrics now, recomputing the stale tiles first."""
        for block in tile_blocks(self._stale, self.tile_size, self.source.geometry):
            self._refresh(block)
        self._stale.clear()
        n = len(self._slot)
        counts = iter(self._at_or_above[:n].sum(axis=0).tolist())
        return GridSummary(
            cells_free=self.cells_free, cells_observed=int(self._observed[:n].sum()),
            at_or_above={t: next(counts) if t > 0 else self.cells_free
                         for t in self.thresholds},
            sum_pd=math.fsum(self._sum_pd[:n]),
            expected_false_alarms=math.fsum(self._sum_pfa[:n]))

    def _refresh(self, block: TileBlock) -> None:
        """Recompute the tiles of ``block``, its layers read once."""
        s, win = self.source, block.window
        free = s.read(Layer.MASK, win)
        pd = np.where(free, s.read(Layer.PD, win), 0.0)
        observed = free & (s.read(Layer.N_OBS, win) > 0)
        figures = [block.per_tile(free & (pd >= t)) for t in self._positive]
        n_observed = block.per_tile(observed)
        sum_pd = block.per_tile(pd)
        sum_pfa = block.per_tile(np.where(observed, s.read(Layer.PFA, win), 0.0))
        at = tuple(np.array([block.at(k) for k in block.keys]).T)
        slots = np.array([self._slot_of(k) for k in block.keys])
        for i, per_tile in enumerate(figures):
            self._at_or_above[slots, i] = per_tile[at]
        self._observed[slots] = n_observed[at]
        self._sum_pd[slots] = sum_pd[at]
        self._sum_pfa[slots] = sum_pfa[at]

    def _slot_of(self, key: TileKey) -> int:
        """Tile ``key``'s slot in the per-tile arrays, a new one (zeros) at first."""
        slot = self._slot.get(key)
        if slot is None:
            slot = self._slot[key] = len(self._slot)
            if slot == len(self._observed):  # full: double the room
                room = max(64, 2 * slot)
                self._at_or_above = _grown(self._at_or_above, room)
                self._observed = _grown(self._observed, room)
                self._sum_pd = _grown(self._sum_pd, room)
                self._sum_pfa = _grown(self._sum_pfa, room)
        return slot


def _grown(a: np.ndarray, rows: int) -> np.ndarray:
    """``a`` with ``rows`` rows, the new ones zero."""
    out = np.zeros((rows, *a.shape[1:]), a.dtype)
    out[:len(a)] = a
    return out
