"""The status metrics of a grid kept per tile, so that the periodic cost follows the cells
written, not the size of the grid: the daemon's status (service/coverage.py) and the
watcher's figures of each vehicle and of the fleet (ground/feed.py, ground/fleet_merge.py),
one rule for both.

Each tile (the bus tiles' cut, ``tile_size`` cells a side) holds its counts of free cells at
or above each threshold, its observed free cells, and its float64 sums of P_D over free cells
and of P_FA over observed free cells; a tile is recomputed only after ``mark`` says cells in
it may have changed (``CoverageGrid.touched``, the tiles a watcher applied). Everything is
stale at first (a resumed grid).
The counts, so the proportions at a threshold and the cells observed, equal a whole-grid
count exactly (``CoverageGrid.metrics``); the float sums add the tiles' sums in a fixed order
(row-major), so they depend only on the grid's values, not on the order of the updates, and
differ from a whole-grid ``sum`` only by rounding (about 1e-16 relative).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from pdcov.bus.tiles import tile_bounds, tile_grid_shape
from pdcov.core.grid_layer import CellSource, Layer


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
        shape = tile_grid_shape(tile_size, *source.geometry.shape)
        self._at_or_above = np.zeros((len(self.thresholds), *shape), np.int64)
        self._observed = np.zeros(shape, np.int64)
        self._sum_pd = np.zeros(shape, np.float64)
        self._sum_pfa = np.zeros(shape, np.float64)
        self._stale = np.ones(shape, bool)
        self.cells_free = source.n_free  # the mask never changes

    def mark(self, window: tuple[int, int, int, int]) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed."""
        r0, r1, c0, c1 = window
        ts = self.tile_size
        self._stale[r0 // ts:(r1 - 1) // ts + 1, c0 // ts:(c1 - 1) // ts + 1] = True

    def summary(self) -> GridSummary:
        """The metrics now, recomputing the stale tiles first."""
        for tr, tc in zip(*np.nonzero(self._stale), strict=True):
            self._refresh(int(tr), int(tc))
        self._stale[:] = False
        return GridSummary(
            cells_free=self.cells_free, cells_observed=int(self._observed.sum()),
            at_or_above={t: int(n) for t, n in zip(self.thresholds,
                                                   self._at_or_above.sum(axis=(1, 2)),
                                                   strict=True)},
            sum_pd=float(self._sum_pd.sum()), expected_false_alarms=float(self._sum_pfa.sum()))

    def _refresh(self, tr: int, tc: int) -> None:
        ts, s = self.tile_size, self.source
        g = s.geometry
        win = tile_bounds(tr, tc, ts, g.n_rows, g.n_cols)
        free = s.read(Layer.MASK, win)
        pd = s.read(Layer.PD, win)[free]
        for i, t in enumerate(self.thresholds):
            self._at_or_above[i, tr, tc] = np.count_nonzero(pd >= t)
        observed = free & (s.read(Layer.N_OBS, win) > 0)
        self._observed[tr, tc] = np.count_nonzero(observed)
        self._sum_pd[tr, tc] = pd.sum()
        self._sum_pfa[tr, tc] = s.read(Layer.PFA, win)[observed].sum()
