"""The fleet's merged grid kept tile by tile (``FleetMerge``), for the watcher
(ground/watcher.py), with its figures and the web map's P_D blocks. No I/O.

Each vehicle's feed (ground/feed.py) says which windows of its grid the tiles applied since
the last merge wrote (``VehicleFeed.unmerged``). Only the windows whose merged cells may
have changed are merged again: those written; for a vehicle joining the fleet, the tiles
its grid wrote (elsewhere it adds zeros); for one leaving, the tiles its grid had written;
for a new grid of a vehicle (a snapshot), the tiles where it differs from the one merged.
The fleet's grid choice changing, or the limiting factors becoming known or unknown,
merges the whole grid. Either way a window's cells are the fleet's vehicles' cells added in
vehicle-id order with the same float32, int64 and maximum operations as
``fleet_report.merge_states``, so the merged grid is merge_fleet's bit for bit: an added
+0.0 leaves a float32 sum as it is unless every other term is -0.0, which no grid holds
(its sums start at +0.0 and only add), and zeros and differences are told by their bits.
The cost follows the windows written, and a vehicle's joining, leaving or snapshot one
pass over its grid, not the fleet's.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from pdcov.bus.grid_state import GridState
from pdcov.bus.tile_metrics import GridSummary, TileMetrics
from pdcov.core.grid_layer import CellSource, Layer, Window
from pdcov.core.tiles import TileKey
from pdcov.ground.feed import VehicleFeed, metrics_for
from pdcov.ground.fleet_report import fleet_group, merge_states, merge_window

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
        self.stride = s = max(1, math.ceil(max(n_rows, n_cols) / max_side))
        # P_D 0 where a block holds a free cell, -1 elsewhere; then the written windows'.
        # The mask is read a band of blocks at a time (a county's is never read whole).
        self._values = np.empty((math.ceil(n_rows / s), math.ceil(n_cols / s)))
        band = max(1, (1 << 24) // (n_cols * s))  # block rows per read: about 16 M cells
        for b0 in range(0, len(self._values), band):
            r0, r1 = b0 * s, min((b0 + band) * s, n_rows)
            free = source.read(Layer.MASK, (r0, r1, 0, n_cols))
            self._values[b0:b0 + band] = block_max_pd(np.zeros(free.shape), free, s)
        self._stale: set[Window] = set(source.written_windows())

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


def _layers(state: GridState) -> list[dict[TileKey, np.ndarray]]:
    """The state's stored layers' tiles (the limiting factors' when known)."""
    layers = [Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS]
    return [state.tiles(lay) for lay in
            (layers + [Layer.LIMITING] if state.limiting_known else layers)]


def written(state: GridState) -> set[Window]:
    """The windows of the tiles ``state`` wrote (elsewhere every layer is zero)."""
    return set(state.written_windows())


def differs(a: GridState, b: GridState) -> set[Window]:
    """The windows of the tiles where any layer of ``a`` and ``b`` (of one grid) differs in
    its bits (-0.0 is not +0.0); a tile one of them never wrote reads as zeros."""
    layout = a.free.layout
    out: set[Window] = set()
    for x, y in zip(_layers(a), _layers(b), strict=True):
        for key in x.keys() | y.keys():
            if key in out:
                continue
            tx, ty = x.get(key), y.get(key)
            if tx is None:
                tx = np.zeros_like(ty)  # a tile never written: zero bits
            if ty is None:
                ty = np.zeros_like(tx)
            same = tx.tobytes() == ty.tobytes()
            if not same:
                out.add(layout.window_of(key))
    return out


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
        self._members: dict[str, GridState] = {}  # by id, as merged
        self._metrics: TileMetrics | None = None
        self._blocks: PdBlocks | None = None

    def update(self, feeds: Iterable[VehicleFeed], grid_hash: str | None) -> None:
        """Merge what changed since the last update (module docstring); every feed's
        unmerged windows are taken."""
        feeds = list(feeds)
        group = fleet_group(feeds, grid_hash)
        members = {f.vehicle_id: f.state for f in group if f.state is not None}
        top = group[0].grid_hash if group else None
        windows = self._changed(feeds, members, top)
        for f in feeds:
            f.unmerged = set()
        self._members, self.ids, self.grid_hash = members, tuple(members), top
        states = list(members.values())
        if not states:
            self.state, self._metrics, self._blocks = None, None, None
        elif windows is None or self.state is None:
            self.state, self._metrics, self._blocks = merge_states(states), None, None
            self.merged_whole += 1
        else:
            self._merge_windows(self.state, states, windows)

    def _changed(self, feeds: list[VehicleFeed], members: dict[str, GridState],
                 top: str | None) -> set[Window] | None:
        """The windows whose merged cells may differ from the last merge's, or None for the
        whole grid (another grid, the limiting factors' knowledge changed, a vehicle
        unaccounted for). A vehicle joining counts the tiles its grid wrote (elsewhere it
        adds +0), one leaving those its grid wrote and the windows written since the last
        merge, a new grid of a vehicle the tiles where it differs from the one merged."""
        merged = self.state
        if merged is None or not members or top != self.grid_hash or (
                merged.limiting_known != all(s.limiting_known for s in members.values())):
            return None
        by_id = {f.vehicle_id: f for f in feeds}
        windows: set[Window] = set()
        for vid in self._members.keys() | members.keys():
            old, new, feed = self._members.get(vid), members.get(vid), by_id.get(vid)
            if feed is None:
                return None
            windows |= feed.unmerged
            if old is None and new is not None:
                windows |= written(new)
            elif new is None and old is not None:
                windows |= written(old)
            elif old is not new and old is not None and new is not None:
                if old.limiting_known != new.limiting_known:
                    return None
                windows |= differs(old, new)
        return windows

    def _merge_windows(self, merged: GridState, states: list[GridState],
                       windows: set[Window]) -> None:
        merged.frames = sum(s.frames for s in states)
        for window in windows:
            merge_window(merged, states, window)
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
