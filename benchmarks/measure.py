"""Timing, memory, the numpy floor, and grid comparisons for the benchmarks."""

from __future__ import annotations

import gc
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from tests.support.references import ReferenceGrid
from tests.support.terrain_reference import TerrainReferenceGrid


@dataclass(frozen=True)
class UpdateTiming:
    """Per-frame times (s) of ``CoverageGrid.update`` and the cells each frame updated."""

    frame_s: np.ndarray
    cells: np.ndarray

    @property
    def mean_s(self) -> float:
        return float(self.frame_s.mean())

    @property
    def frames_per_s(self) -> float:
        return 1.0 / self.mean_s

    @property
    def cell_updates_per_s(self) -> float:
        return float(self.cells.sum() / self.frame_s.sum())

    def percentile_s(self, q: float) -> float:
        return float(np.percentile(self.frame_s, q))


def time_updates(grid: CoverageGrid, poses: Sequence[CameraPose]) -> UpdateTiming:
    """Update ``grid`` with every pose, timing each call."""
    times = np.empty(len(poses))
    cells = np.empty(len(poses), dtype=np.int64)
    clock = time.perf_counter
    gc.collect()
    for k, pose in enumerate(poses):
        t0 = clock()
        cells[k] = grid.update(pose)
        times[k] = clock() - t0
    return UpdateTiming(times, cells)


def time_frames(step: Callable[[CameraPose], None], poses: Sequence[CameraPose]) -> np.ndarray:
    """Seconds per call of ``step`` for each pose."""
    times = np.empty(len(poses))
    for k, pose in enumerate(poses):
        t0 = time.perf_counter()
        step(pose)
        times[k] = time.perf_counter() - t0
    return times


def floor_pass_s(n_cells: int, repeats: int = 2000) -> float:
    """The floor: seconds of one numpy pass reading and writing ``n_cells`` float32 values
    (``a += 1`` in place), the least any per-frame update of that many cells could cost in
    numpy. Median of ``repeats`` passes."""
    a = np.zeros(max(n_cells, 1), dtype=np.float32)
    times = np.empty(repeats)
    clock = time.perf_counter
    for k in range(repeats):
        t0 = clock()
        np.add(a, 1.0, out=a)
        times[k] = clock() - t0
    return float(np.median(times))


def peak_update_memory_bytes(new_grid: Callable[[], CoverageGrid],
                             poses: Sequence[CameraPose]) -> tuple[int, int]:
    """(peak bytes traced while building a grid and updating it with ``poses``, the grid's
    own array bytes). tracemalloc sees numpy's allocations."""
    gc.collect()
    tracemalloc.start()
    try:
        grid = new_grid()
        for pose in poses:
            grid.update(pose)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    arrays = [grid.log_miss_d, grid.log_miss_fa, grid.n_obs, grid.mask, grid.limiting]
    if grid.last_obs_s is not None:
        arrays.append(grid.last_obs_s)
    return peak, sum(a.nbytes for a in arrays)


@dataclass(frozen=True)
class Agreement:
    """How a reference grid compares with pdcov's over the free cells.

    max_abs_dpd: largest |P_D difference| over all free cells. share_within: share, of the
    cells both observed equally often, whose |P_D difference| is at most ``tolerance``.
    cells_compared: those cells. p99_rel_log_miss: 99th percentile over them of the relative
    difference of the log-miss sums (which, unlike P_D, do not saturate at 1).
    looks_differ: free cells observed a different number of times (the references decide
    differently at the picture's edge: R1 counts a cell when any pixel's ray lands in it,
    pdcov when the ray through its centre reaches the picture).
    """

    max_abs_dpd: float
    share_within: float
    tolerance: float
    cells_compared: int
    p99_rel_log_miss: float
    looks_differ: int


def agreement(grid: CoverageGrid, ref: ReferenceGrid, tolerance: float) -> Agreement:
    """Compare the cumulative P_D of ``grid`` and ``ref``."""
    free = grid.mask
    dpd = np.abs(grid.pd - ref.pd)
    same = free & (grid.n_obs == ref.n_obs) & (grid.n_obs > 0)
    n_same = int(same.sum())
    mine, theirs = grid.log_miss_d[same].astype(np.float64), ref.log_miss_d[same]
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(mine == theirs, 0.0, np.abs(mine - theirs) / np.abs(theirs))
    return Agreement(
        max_abs_dpd=float(dpd[free].max(initial=0.0)),
        share_within=float((dpd[same] <= tolerance).mean()) if n_same else 1.0,
        tolerance=tolerance,
        cells_compared=n_same,
        p99_rel_log_miss=float(np.nanpercentile(rel, 99)) if n_same else 0.0,
        looks_differ=int((grid.n_obs != ref.n_obs)[free].sum()),
    )


@dataclass(frozen=True)
class TerrainAgreement:
    """How pdcov's grid compares with R3's (the terrain truth) over all free cells.

    share_within: share of the free cells whose P_D differs by at most ``tolerance``;
    share_within_observed: the same share of the free cells either grid observed
    (cells_observed of them). never_seen: free cells no ray of R3 reached in any frame;
    never_seen_counted: those of them pdcov observed. hidden: free cells whose centre was in
    some frame's picture and range but always behind terrain (R3's ``hidden``);
    hidden_counted: those of them pdcov observed.
    """

    share_within: float
    share_within_observed: float
    tolerance: float
    cells_free: int
    cells_observed: int
    never_seen: int
    never_seen_counted: int
    hidden: int
    hidden_counted: int


def terrain_agreement(grid: CoverageGrid, ref: TerrainReferenceGrid,
                      tolerance: float) -> TerrainAgreement:
    """Compare ``grid`` (flat or with terrain) with R3's ``ref`` over the same frames."""
    free = grid.mask
    seen = grid.n_obs > 0
    never = free & (ref.n_obs == 0)
    hidden = ref.hidden
    close = np.abs(grid.pd - ref.pd) <= tolerance
    observed = free & (seen | (ref.n_obs > 0))
    return TerrainAgreement(
        share_within=float(close[free].mean()),
        share_within_observed=float(close[observed].mean()) if observed.any() else 1.0,
        tolerance=tolerance,
        cells_free=int(free.sum()),
        cells_observed=int(observed.sum()),
        never_seen=int(never.sum()),
        never_seen_counted=int((never & seen).sum()),
        hidden=int(hidden.sum()),
        hidden_counted=int((hidden & seen).sum()),
    )
