"""``python -m benchmarks.watcher``: the ground station's fleet merge (issue 37, "The watcher
merges incrementally"): 20 vehicles of 4 km² each at 1 m on one map.

A Watcher (ground/watcher.py) in this process follows N vehicles flying one mission grid (a
square of ``side_m`` m at 1 m cells, all free). Each vehicle's daemon is stood in for by a
tiled CoverageGrid and the daemon's own TileSender (service/tile_sender.py): a lawnmower in
the vehicle's strip of the square, frames at 5 Hz writing a 40 m footprint (log-miss sums
down, counts up), the changed tiles sent every 0.2 s within bus.tiles_max_bytes_per_s. The
watcher decodes and applies every tiles message and reports every 0.5 s (its figures, the
fleet's, and the web map's heat map payload), on simulated time, as fast as the machine
goes.

Figures: the watcher's CPU seconds per simulated second, and beside it, in the same run,
the whole-grid work it replaces (merge_fleet, the figures over the whole merged grid and
every vehicle's, the heat map from the whole grid, the mask hashed at every tiles message),
timed on every ``old_every``-th report; the joining cost (every vehicle's first snapshot
merged and figured) and that of one vehicle's snapshot taken again mid-flight; and whether
the live merged map equals the offline merge of the vehicles' final grids
(``CoverageGrid.merge`` in vehicle-id order, and merge_fleet).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pdcov.bus.grid_state import GridState, grid_hash
from pdcov.bus.session import BusConfig
from pdcov.bus.tiles import decode_tiles
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer, Window
from pdcov.ground.fleet_merge import block_max_pd
from pdcov.ground.fleet_report import merge_fleet
from pdcov.ground.watcher import Watcher
from pdcov.ground.web import blocks_payload
from pdcov.planning.progress import progress
from pdcov.service.tile_sender import TileSender
from tests.support.square_grid import DETECTOR, PINHOLE, square_grid

from .report import Row, machine, markdown

ORIGIN = Origin(47.397742, 8.545594, 488.0)
THRESHOLDS = (0.5, 0.8, 0.95)
STEP_S = 0.1
FRAME_EVERY, TILES_EVERY, REPORT_EVERY = 2, 2, 5  # steps: 5 Hz, 0.2 s, 0.5 s
SPEED_MPS, SWATH_M = 10.0, 40
TARGET_CORE = 0.25


@dataclass(frozen=True)
class Setting:
    vehicles: int
    side_m: int  # the grid: side_m x side_m cells of 1 m
    duration_s: float  # simulated: the flight, then catch_up_s of tiles only
    catch_up_s: float
    old_every: int  # the whole-grid work is timed on every old_every-th report


FULL = Setting(20, 2000, 60.0, 5.0, 10)
SMOKE = Setting(3, 256, 6.0, 2.0, 1)


@dataclass(frozen=True)
class Figures:
    vehicles: int
    cells_per_vehicle: int
    simulated_s: float
    messages: int
    tiles: int
    tiles_bytes_per_s_per_vehicle: float
    join_cpu_s: float
    resent_cpu_s: float  # one vehicle's snapshot taken again mid-flight, merged and figured
    apply_cpu_s: float  # decode + apply of every tiles message
    report_cpu_s: float  # every report, its figures and its heat map
    old_report_cpu_s: float  # one whole-grid report, mean
    old_hash_cpu_s: float  # one whole-mask hash, mean
    reports: int
    equal_offline: bool
    equal_merge_fleet: bool

    @property
    def cpu_per_s(self) -> float:
        """The watcher's CPU seconds per simulated second (a share of a core)."""
        return (self.apply_cpu_s + self.report_cpu_s) / self.simulated_s

    @property
    def old_cpu_per_s(self) -> float:
        """The whole-grid work per simulated second: every report, and a hash per message."""
        return (self.apply_cpu_s + self.reports * self.old_report_cpu_s
                + self.messages * self.old_hash_cpu_s) / self.simulated_s


class Flight:
    """One vehicle: its daemon's grid and tile sender, a lawnmower over its strip of the
    square (x from strip_x0_m, lanes SWATH_M apart along y, SPEED_MPS)."""

    def __init__(self, k: int, base: CoverageGrid, setting: Setting, bus: BusConfig) -> None:
        g = base.geometry
        self.vehicle_id = f"uav{k + 1:02d}"
        self.grid = CoverageGrid(g, base.free, PINHOLE, DETECTOR)
        self.sender = TileSender(self.grid, grid_hash(g, base.mask), bus.tile_size,
                                 bus.tiles_max_bytes_per_s, 0.0)
        self.strip_x0_m = k * setting.side_m / setting.vehicles
        self.strip_m = setting.side_m / setting.vehicles
        self.rng = np.random.default_rng(k)

    def footprint(self, t_s: float) -> Window | None:
        """The cells under the camera at ``t_s`` (None: the strip is done)."""
        n = self.grid.geometry.n_rows
        path_m = SPEED_MPS * t_s
        lane, along_m = divmod(path_m, float(n))
        x_m = self.strip_x0_m + SWATH_M / 2 + lane * SWATH_M
        if x_m > self.strip_x0_m + self.strip_m:
            return None
        y_m = along_m if lane % 2 == 0 else n - along_m
        r, c = int(y_m), int(x_m)
        h = SWATH_M // 2
        return max(0, r - h), min(n, r + h), max(0, c - h), min(n, c + h)

    def frame(self, t_s: float) -> None:
        """A frame's looks written into the grid (as CoverageGrid.update would)."""
        win = self.footprint(t_s)
        if win is None:
            return
        shape = (win[1] - win[0], win[3] - win[2])
        g = self.grid
        for layer, delta in ((Layer.LOG_MISS_D, self.rng.random(shape, np.float32) * 0.3),
                             (Layer.LOG_MISS_FA, self.rng.random(shape, np.float32) * 0.01)):
            g.layer(layer).write(win, g.read(layer, win) - delta)
        g.layer(Layer.N_OBS).write(win, g.read(Layer.N_OBS, win) + 1)
        g.layer(Layer.LIMITING).write(win, 3)
        g.frames += 1
        self.sender.touch(win)


def cpu_s() -> float:
    return time.process_time()


def run(setting: Setting, show_progress: bool = True) -> Figures:
    bus = BusConfig()
    half = setting.side_m / 2
    base = square_grid(half_m=half)
    flights = [Flight(k, base, setting, bus) for k in range(setting.vehicles)]
    w = Watcher(thresholds=THRESHOLDS)
    for f in flights:  # every vehicle heard from the start: its (empty) snapshot
        w.on_snapshot(f.vehicle_id, GridState.from_grid(f.grid), 0.0)
    t0 = cpu_s()
    heat_map(w)
    join = cpu_s() - t0
    apply_s = report_s = old_s = resent = 0.0
    messages = tiles = nbytes = reports = old_reports = 0
    steps = round(setting.duration_s / STEP_S)
    for step in progress(range(1, steps + 1), desc="watcher", unit="step",
                         enabled=show_progress):
        now = step * STEP_S
        flying = step < steps - setting.catch_up_s / STEP_S
        for f in flights:
            if flying and step % FRAME_EVERY == 0:
                f.frame(now)
            if step % TILES_EVERY == 0:
                payload = f.sender.send(now, now)
                if payload is None:
                    continue
                nbytes += len(payload)
                t = cpu_s()
                update = decode_tiles(payload)
                w.on_tiles(f.vehicle_id, update, now)
                apply_s += cpu_s() - t
                messages += 1
                tiles += len(update.tiles)
        if step == steps // 2:  # a vehicle's whole grid again (after a gap, say)
            state = GridState.from_grid(flights[0].grid)
            t = cpu_s()
            w.on_snapshot(flights[0].vehicle_id, state, now)
            heat_map(w)
            resent = cpu_s() - t
        if step % REPORT_EVERY == 0:
            t = cpu_s()
            heat_map(w)
            report_s += cpu_s() - t
            reports += 1
            if reports % setting.old_every == 0:
                t = cpu_s()
                old_heat_map(w)
                old_s += cpu_s() - t
                old_reports += 1
    behind = sum(f.sender.behind for f in flights)
    if behind:
        raise RuntimeError(f"{behind} tiles still unsent after the flight: lengthen the run")
    hash_s = mean_hash_s(w)
    kept, ids = w.fleet_state()
    offline = CoverageGrid(base.geometry, base.free, PINHOLE, DETECTOR)
    for f in flights:  # vehicle-id order
        offline.merge(f.grid)
    fresh, fresh_ids = merge_fleet(w.feeds.values(), w.grid_hash)
    return Figures(
        setting.vehicles, setting.side_m ** 2, steps * STEP_S, messages, tiles,
        nbytes / (steps * STEP_S) / setting.vehicles, join, resent, apply_s, report_s,
        old_s / max(old_reports, 1), hash_s, reports,
        kept is not None and ids == tuple(f.vehicle_id for f in flights)
        and same_as_grid(kept, offline),
        kept is not None and fresh is not None and ids == fresh_ids
        and same_state(kept, fresh))


def heat_map(w: Watcher) -> None:
    """One report as the web map makes it: the figures and the heat map."""
    report = w.report(0.0)
    blocks = w.fleet_blocks()
    if blocks is not None:
        blocks_payload(blocks.values(), blocks.stride, blocks.source.geometry, ORIGIN,
                       report.target)


def old_heat_map(w: Watcher) -> None:
    """The same report over whole grids, as the watcher made it before (merge_fleet, the
    figures of every grid, the heat map of the whole merged grid)."""
    merged, _ = merge_fleet(w.feeds.values(), w.grid_hash)
    if merged is None:
        return
    for f in w.feeds.values():
        s = f.state
        if s is not None:
            s.proportions_at_or_above(THRESHOLDS)
            float(s.pd[s.mask].mean())
    merged.proportions_at_or_above(THRESHOLDS)
    float(merged.pd[merged.mask].mean())
    stride = max(1, math.ceil(max(merged.mask.shape) / 400))
    blocks_payload(block_max_pd(merged.pd, merged.mask, stride), stride, merged.geometry,
                   ORIGIN, max(THRESHOLDS))


def mean_hash_s(w: Watcher, n: int = 5) -> float:
    """CPU seconds of one whole-mask hash (the old watcher's at every tiles message)."""
    state = next(f.state for f in w.feeds.values() if f.state is not None)
    t = cpu_s()
    for _ in range(n):
        _ = state.hash
    return (cpu_s() - t) / n


def same_as_grid(state: GridState, grid: CoverageGrid) -> bool:
    return state.frames == grid.frames and all(
        np.array_equal(getattr(state, layer.value), grid.read(layer))
        for layer in (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS, Layer.LIMITING))


def same_state(a: GridState, b: GridState) -> bool:
    return a.frames == b.frames and all(
        np.array_equal(x, y) and x.dtype == y.dtype for x, y in (
            (a.log_miss_d, b.log_miss_d), (a.log_miss_fa, b.log_miss_fa),
            (a.n_obs, b.n_obs), (a.limiting, b.limiting)))


def rows(fig: Figures) -> list[Row]:
    scenario = f"{fig.vehicles} x {fig.cells_per_vehicle / 1e6:g} M cells"
    return [
        Row(scenario, "tiles received", f"{fig.messages} messages, {fig.tiles} tiles, "
            f"{fig.tiles_bytes_per_s_per_vehicle / 1024:.1f} KiB/s per vehicle"),
        Row(scenario, "watcher CPU per second (tiles applied, report and heat map every "
            "0.5 s)", f"{fig.cpu_per_s:.3f} core", f"<= {TARGET_CORE}",
            fig.cpu_per_s <= TARGET_CORE),
        Row(scenario, "of which applying the tiles", f"{fig.apply_cpu_s / fig.simulated_s:.3f}"
            " core"),
        Row(scenario, "the whole-grid merge it replaces, same run",
            f"{fig.old_cpu_per_s:.2f} core ({fig.old_report_cpu_s:.2f} s a report, "
            f"{fig.old_hash_cpu_s * 1e3:.1f} ms a message)"),
        Row(scenario, "joining: every vehicle's grid merged and figured once",
            f"{fig.join_cpu_s:.2f} s CPU"),
        Row(scenario, "a vehicle's snapshot taken again mid-flight, merged and figured",
            f"{fig.resent_cpu_s:.2f} s CPU"),
        Row(scenario, "live map = offline merge (CoverageGrid.merge)",
            "same" if fig.equal_offline else "differs", "same", fig.equal_offline),
        Row(scenario, "live map = merge_fleet of the final grids",
            "same" if fig.equal_merge_fleet else "differs", "same", fig.equal_merge_fleet),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.watcher", description=__doc__)
    parser.add_argument("--smoke", action="store_true",
                        help="3 vehicles of 256 x 256 cells for 6 s (CI; timings meaningless)")
    parser.add_argument("--json", type=Path, metavar="PATH",
                        help="also write the figures as JSON to PATH")
    args = parser.parse_args(argv)
    fig = run(SMOKE if args.smoke else FULL)
    print(markdown(rows(fig), machine(), "python -m benchmarks.watcher"
                   + (" --smoke" if args.smoke else "")))
    if args.json is not None:
        args.json.write_text(json.dumps({**asdict(fig), "cpu_per_s": fig.cpu_per_s,
                                         "old_cpu_per_s": fig.old_cpu_per_s}, indent=2))
    return 0 if fig.equal_offline and fig.equal_merge_fleet else 1


if __name__ == "__main__":
    sys.exit(main())
