"""The fleet's merged grid kept tile by tile (``FleetMerge``), for the watcher
(ground/watcher.py), with its figures and the web map's P_D blocks. No I/O.

Each vehicle's feed (ground/feed.py) says which windows of its grid the tiles applied since
the last merge wrote (``VehicleFeed.unmerged``; None: all of it, a new grid). When the fleet
is the same vehicles on the same grid as at the last merge, only the windows any of them
wrote are merged again; otherwise (a vehicle joining, leaving, taking a snapshot or
changing grid, the fleet's grid choice changing, a vehicle's limiting factors becoming
unknown) the whole grid is. Either way a window's cells are the fleet's vehicles' cells
added in vehicle-id order with the same float32, int64 and maximum operations as
``fleet_report.merge_states``, so the merged grid is merge_fleet's bit for bit; the cost
follows the windows written, not the grid.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from pdcov.bus.grid_state import GridState
from pdcov.bus.tile_metrics import GridSummary, TileMetrics
from pdcov.core.grid_layer import CellSource, Layer, Window
from pdcov.ground.feed import VehicleFeed, metrics_for
from pdcov.ground.fleet_report import fleet_group, merge_states

__all__ = ["FleetMerge", "PdBlocks"]

MAX_SIDE = 400
"""The web map's P_D blocks: at most this many a side (ground/web.py)."""


class PdBlocks:
    """The maximum P_D (clipped to 0..1) of each block of ``stride`` x ``stride`` cells of
    ``source`` (blocks of no free cell: -1), rows and columns from the grid's south-west
    corner; ``stride`` the least giving at most ``max_side`` blocks a side. Kept by window:
    ``mark`` a window written, ``values`` recomputes the blocks it touches."""

    def __init__(self, source: CellSource, max_side: int = MAX_SIDE) -> None:
        self.source = source
        n_rows, n_cols = source.geometry.shape
        self.stride = max(1, math.ceil(max(n_rows, n_cols) / max_side))
        self._values = np.full((math.ceil(n_rows / self.stride),
                                math.ceil(n_cols / self.stride)), -1.0)
        self._stale: set[Window] = {(0, n_rows, 0, n_cols)}

    def mark(self, window: Window) -> None:
        """Cells rows r0:r1, columns c0:c1 may have changed."""
        self._stale.add(window)

    def values(self) -> np.ndarray:
        """The blocks now (the array kept: read, do not write), those of the windows marked
        recomputed first."""
        s = self.stride
        n_rows, n_cols = self.source.geometry.shape
        for r0, r1, c0, c1 in self._stale:
            b0, b1, d0, d1 = r0 // s, -(-r1 // s), c0 // s, -(-c1 // s)
            self._values[b0:b1, d0:d1] = block_max_pd(
                self.source.read(Layer.PD, win := (b0 * s, min(b1 * s, n_rows), d0 * s,
                                                   min(d1 * s, n_cols))),
                self.source.read(Layer.MASK, win), s)
        self._stale.clear()
        return self._values


def block_max_pd(pd: np.ndarray, mask: np.ndarray, stride: int) -> np.ndarray:
    """The maximum of ``pd`` clipped to 0..1 over the free cells (``mask``) of each block of
    ``stride`` x ``stride`` cells from the first (the last ones may be partial); -1 where a
    block has no free cell."""
    n_rows, n_cols = mask.shape
    h, w = math.ceil(n_rows / stride), math.ceil(n_cols / stride)
    padded = np.full((h * stride, w * stride), -1.0)
    padded[:n_rows, :n_cols] = np.where(mask, np.clip(pd, 0.0, 1.0), -1.0)
    return padded.reshape(h, stride, w, stride).max(axis=(1, 3))


class FleetMerge:
    """The fleet's merged grid (``state``, of the vehicles ``ids``, on grid ``grid_hash``),
    its figures and its map blocks, brought up to date by ``update``. ``state`` is kept and
    written in place: a copy is the caller's to take (``GridState.copy``)."""

    def __init__(self) -> None:
        self.state: GridState | None = None
        self.ids: tuple[str, ...] = ()
        self.grid_hash: str | None = None
        self.merged_whole = 0  # times the whole grid was merged; the windows merged since
        self.windows_merged = 0
        self._group: list[tuple[str, GridState, bool]] = []
        self._metrics: TileMetrics | None = None
        self._blocks: PdBlocks | None = None

    def update(self, feeds: Iterable[VehicleFeed], grid_hash: str | None) -> None:
        """Merge what the vehicles' tiles wrote since the last update (module docstring);
        every feed's unmerged windows are taken."""
        feeds = list(feeds)
        group = fleet_group(feeds, grid_hash)
        members = [(f.vehicle_id, f.state, f.state.limiting is None)
                   for f in group if f.state is not None]
        same = (self.state is not None and len(members) == len(self._group)
                and all(a[0] == b[0] and a[1] is b[1] and a[2] == b[2]
                        for a, b in zip(members, self._group, strict=True))
                and all(f.unmerged is not None for f in group))
        windows = set().union(*(f.unmerged or () for f in group)) if same else set()
        for f in feeds:
            f.unmerged = set()
        self._group = members
        self.ids = tuple(vid for vid, _, _ in members)
        self.grid_hash = group[0].grid_hash if group else None
        states = [s for _, s, _ in members]
        if not states:
            self.state, self._metrics, self._blocks = None, None, None
        elif not same or self.state is None:
            self.state, self._metrics, self._blocks = merge_states(states), None, None
            self.merged_whole += 1
        else:
            self._merge_windows(self.state, states, windows)

    def _merge_windows(self, merged: GridState, states: list[GridState],
                       windows: set[Window]) -> None:
        merged.frames = sum(s.frames for s in states)
        for window in windows:
            r0, r1, c0, c1 = window
            cells = np.s_[r0:r1, c0:c1]
            for name in ("log_miss_d", "log_miss_fa", "n_obs"):
                out = getattr(merged, name)
                out[cells] = getattr(states[0], name)[cells]
                for s in states[1:]:
                    out[cells] += getattr(s, name)[cells]
            if merged.limiting is not None:
                merged.limiting[cells] = np.maximum.reduce(
                    [s.limiting[cells] for s in states if s.limiting is not None])
            if self._metrics is not None:
                self._metrics.mark(window)
            if self._blocks is not None:
                self._blocks.mark(window)
        self.windows_merged += len(windows)

    def summary(self, thresholds: tuple[float, ...]) -> GridSummary | None:
        """The merged grid's figures at ``thresholds`` among others (None: no grid),
        recomputing only the tiles merged since the last call."""
        if self.state is None:
            return None
        self._metrics = metrics_for(self._metrics, self.state, thresholds)
        return self._metrics.summary()

    def blocks(self) -> PdBlocks | None:
        """The merged grid's map blocks (None: no grid)."""
        if self.state is None:
            return None
        if self._blocks is None:
            self._blocks = PdBlocks(self.state)
        return self._blocks
