"""Timing, memory and the numpy floor for the benchmarks (the grid comparisons are
tests.support.grid_agreement's)."""

from __future__ import annotations

import gc
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose


@dataclass(frozen=True)
class UpdateTiming:
    """Per-frame times (s) of ``CoverageGrid.update``, wall clock and the process's CPU
    time, and the cells each frame updated."""

    frame_s: np.ndarray
    cells: np.ndarray
    frame_cpu_s: np.ndarray

    @property
    def mean_s(self) -> float:
        return float(self.frame_s.mean())

    @property
    def mean_cpu_s(self) -> float:
        """Mean CPU time per frame (s): what other work on a shared machine leaves alone."""
        return float(self.frame_cpu_s.mean())

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
    cpu = np.empty(len(poses))
    cells = np.empty(len(poses), dtype=np.int64)
    clock, cpu_clock = time.perf_counter, time.process_time
    gc.collect()
    for k, pose in enumerate(poses):
        c0 = cpu_clock()
        t0 = clock()
        cells[k] = grid.update(pose)
        times[k] = clock() - t0
        cpu[k] = cpu_clock() - c0
    return UpdateTiming(times, cells, cpu)


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
