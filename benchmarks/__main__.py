"""``python -m benchmarks``: run the scenarios, print the results table, optionally write it
into the README. ``--smoke`` runs every step at a tiny size (CI); its timings mean nothing."""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.core.looks import LooksConfig, LooksRule
from tests.support.grid_agreement import (
    R1_MIN_SHARE,
    R1_TOLERANCE_PD,
    R2_MIN_SHARE,
    R2_TOLERANCE_PD,
    Agreement,
    agreement,
)
from tests.support.references import ReferenceGrid, pixel_rays, r1_update, r2_update
from tests.support.scenarios import Scenario, scenarios, spaced, strided
from tests.support.terrain_site import TerrainSite

from .blur import blur_rows
from .canopy import cost_rows as canopy_cost_rows
from .canopy import r4_rows
from .measure import floor_pass_s, peak_update_memory_bytes, time_frames, time_updates
from .offline import evaluate_run, optimise_run
from .report import Row, machine, markdown, write_readme_block
from .terrain import cost_rows, s5_rows, valley_rows

README = Path(__file__).resolve().parent.parent / "README.md"


@dataclass(frozen=True)
class Sizes:
    """How much of each scenario a run measures."""

    max_timed_frames: int   # pdcov frames timed (strided over the flight); S1 always all
    r1_frames: int
    r2_frames: int
    memory_frames: int
    r3_frames: int          # S5: R3 and pdcov on frames from the middle of the flight
    valley_frames: int      # S5 valley: frames of its flight (strided), all at full size
    canopy_frames: int      # canopy: survey frames timed with and without the cover
    planner_altitudes_m: tuple[float, ...]
    planner_speeds_mps: tuple[float, ...]


FULL = Sizes(3000, 20, 3, 200, 6, 10**6, 400, (8.0, 10.0, 12.0), (3.0, 5.0))
SMOKE = Sizes(200, 6, 4, 20, 4, 6, 12, (10.0,), (5.0,))


def compare_reference(sc: Scenario, frames: list, which: str, rays: np.ndarray,
                      tolerance: float) -> tuple[float, float, Agreement, int]:
    """(reference s/frame, pdcov s/frame, agreement, observed cells the reference could not
    compute) over the same ``frames``, each in a fresh grid."""
    grid = sc.new_grid()
    mine = time_updates(grid, frames)
    ref = ReferenceGrid(grid.geometry, grid.mask, grid.camera, grid.detector, grid.max_range_m)
    if which == "R1":
        times = time_frames(lambda p: r1_update(ref, rays, p), frames)
    else:
        times = time_frames(lambda p: r2_update(ref, p), frames)
    return float(times.mean()), mine.mean_s, agreement(grid, ref, tolerance), ref.not_comparable


def scenario_rows(sc: Scenario, sizes: Sizes, smoke: bool) -> list[Row]:
    """pdcov's update, the floor, memory and the references for one scenario."""
    name = sc.name
    poses = sc.poses()
    timed = poses if name == "S1" and not smoke else strided(poses, sizes.max_timed_frames)
    grid = sc.new_grid()
    t = time_updates(grid, timed)
    floor = floor_pass_s(int(t.cells.mean()))
    passes = t.mean_s / floor
    peak, grid_bytes = peak_update_memory_bytes(sc.new_grid, timed[:sizes.memory_frames])
    per_cell = grid_bytes / grid.mask.size
    rows = [
        Row(name, "setup", sc.describe()),
        Row(name, "update: frames/s", f"{t.frames_per_s:,.0f} ({len(timed)} frames)"),
        Row(name, "update: cell-updates/s", f"{t.cell_updates_per_s / 1e6:,.1f} M "
            f"({t.cells.mean():,.0f} cells/frame)"),
        Row(name, "update: per frame p50 / p99", f"{t.percentile_s(50) * 1e3:.3f} / "
            f"{t.percentile_s(99) * 1e3:.3f} ms"),
        Row(name, "update: floor passes per frame", f"{passes:,.0f} (floor pass "
            f"{floor * 1e6:.1f} us)", "<= 30" if name in ("S1", "S3") else "",
            passes <= 30 if name in ("S1", "S3") else None),
        Row(name, "grid memory", f"{per_cell:.0f} B/cell", "<= 24 B/cell", per_cell <= 24),
        Row(name, "peak memory: camera, grid, updates", f"{peak / 2**20:,.0f} MB (tracemalloc)"),
    ]
    rows += looks_rows(sc, timed, t.mean_s)
    stride = max(1, round(sc.rate_hz * 0.5))
    rays = pixel_rays(sc.camera)
    for which, n, need, tol, share in (("R1", sizes.r1_frames, 20, R1_TOLERANCE_PD,
                                        R1_MIN_SHARE),
                                       ("R2", sizes.r2_frames, 10, R2_TOLERANCE_PD,
                                        R2_MIN_SHARE)):
        ref_s, mine_s, agree, skipped = compare_reference(sc, spaced(poses, n, stride), which,
                                                          rays, tol)
        ratio = ref_s / mine_s
        is_s1 = name == "S1"
        rows.append(Row(name, f"{which} / pdcov time per frame",
                        f"{ratio:,.1f}x ({ref_s * 1e3:,.1f} vs {mine_s * 1e3:.2f} ms, "
                        f"{n} frames)", f">= {need}x" if is_s1 else "",
                        ratio >= need if is_s1 else None))
        note = f"; {skipped} looks R2 could not compute" if skipped else ""
        ok = agree.share_within >= share
        rows.append(Row(name, f"{which} vs pdcov grid",
                        f"{agree.share_within:.2%} of {agree.cells_compared:,} cells within "
                        f"{tol:g}; max abs dP_D {agree.max_abs_dpd:.2g}; p99 relative "
                        f"log-miss difference {agree.p99_rel_log_miss:.2g}; "
                        f"{agree.looks_differ} cells seen a different number of times{note}",
                        f">= {share:.1%} within {tol:g}",
                        ok if (is_s1 or which == "R2") else None))
    return rows


LOOKS_COST_MAX = 1.5  # per-frame update with correlated or viewpoint looks over independent


def looks_rows(sc: Scenario, poses: list, independent_s: float) -> list[Row]:
    """coverage.looks correlated and viewpoint beside independent (``independent_s``, the
    mean update of the same ``poses`` just timed): per-frame update, and the read that
    derives P_D (the first ``pd`` after the flight: every cell seen)."""
    rows = []
    for rule in (LooksRule.CORRELATED, LooksRule.VIEWPOINT):
        grid = sc.new_grid(LooksConfig(rule))
        t = time_updates(grid, poses)
        t0 = time.perf_counter()
        grid.refresh()
        read_s = time.perf_counter() - t0
        seen = int((grid.n_obs > 0).sum())
        ratio = t.mean_s / independent_s
        rows += [
            Row(sc.name, f"update, looks {rule} / independent, per frame",
                f"{ratio:.2f}x ({t.mean_s * 1e3:.3f} vs {independent_s * 1e3:.3f} ms)",
                f"<= {LOOKS_COST_MAX}x", ratio <= LOOKS_COST_MAX),
            Row(sc.name, f"read P_D, looks {rule}",
                f"{read_s * 1e3:,.0f} ms for {seen:,} seen cells "
                f"({read_s / max(seen, 1) * 1e9:,.0f} ns/cell)"),
        ]
    return rows


def offline_rows(sc: Scenario) -> list[Row]:
    """``pdcov evaluate`` of the scenario's flight, from a pose CSV and from a tlog."""
    rows = []
    for source in ("csv", "tlog"):
        with tempfile.TemporaryDirectory(prefix="pdcov-bench-") as tmp:
            run = evaluate_run(Path(tmp), sc, source)
        speed = sc.duration_s / run.wall_s
        rss = run.peak_rss_bytes / 2**20
        rows += [
            Row(sc.name, f"offline evaluate ({source}): x real time",
                f"{speed:,.1f}x ({run.wall_s:,.1f} s for {sc.duration_s:g} s of flight)",
                ">= 50x", speed >= 50),
            Row(sc.name, f"offline evaluate ({source}): peak memory", f"{rss:,.0f} MB (RSS)",
                "< 300 MB", rss < 300),
        ]
    return rows


def terrain_rows(found: dict[str, Scenario], sizes: Sizes) -> list[Row]:
    """S5 (its cost against flat S1's, timed in this run over as many frames, at S5's tilt
    and at nadir) and the whole valley flight against R3."""
    rows = []
    for name in ("S5", "S5 valley"):
        print(f"{name}: {found[name].describe()}", file=sys.stderr)
        with tempfile.TemporaryDirectory(prefix="pdcov-bench-") as tmp:
            site = TerrainSite.prepare(Path(tmp), found[name])
            if name == "S5":
                rows += s5_rows(site, sizes.max_timed_frames, sizes.r3_frames)
                rows += cost_rows(found["S1"], found[name], Path(tmp), sizes.max_timed_frames)
            else:
                rows += valley_rows(site, sizes.valley_frames)
    return rows


def planner_rows(sc: Scenario, sizes: Sizes) -> list[Row]:
    with tempfile.TemporaryDirectory(prefix="pdcov-bench-") as tmp:
        run = optimise_run(Path(tmp), sc, list(sizes.planner_altitudes_m),
                           list(sizes.planner_speeds_mps))
    return [Row(sc.name, "planner: plans/min (pdcov optimise, 1 process)",
                f"{run.plans_per_min:,.0f} ({run.plans} plans in {run.sweep_s:.1f} s)")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    parser.add_argument("--smoke", action="store_true",
                        help="tiny sizes, every step once (CI; timings meaningless)")
    parser.add_argument("--scenarios", nargs="+",
                        default=["S1", "S2", "S3", "S4", "S5", "canopy"],
                        choices=["S1", "S2", "S3", "S4", "S5", "canopy"],
                        help="S5: the terrain scenario and the valley flight (issue 21); "
                             "canopy: trees and buildings over hills (issue 38)")
    parser.add_argument("--no-offline", action="store_true",
                        help="skip pdcov evaluate (S1) and pdcov optimise (S2)")
    parser.add_argument("--sitl", action="store_true",
                        help="also time pdcov-sitl fly --speed 0 over a 10-minute survey")
    parser.add_argument("--write-readme", action="store_true",
                        help="write the table into README.md between the benchmark markers")
    args = parser.parse_args(argv)
    sizes = SMOKE if args.smoke else FULL
    found = scenarios(args.smoke)
    rows: list[Row] = []
    for name in args.scenarios:
        if name == "S5":
            rows += terrain_rows(found, sizes)
            continue
        if name == "canopy":
            rows += canopy_cost_rows(sizes.canopy_frames)
            rows += r4_rows() if not args.smoke else []
            continue
        sc = found[name]
        print(f"{name}: {sc.describe()}", file=sys.stderr)
        rows += scenario_rows(sc, sizes, args.smoke)
        if name in ("S1", "S4"):
            rows += blur_rows(sc, sizes.max_timed_frames)
        if not args.no_offline and name == "S1":
            rows += offline_rows(sc)
        if not args.no_offline and name == "S2":
            rows += planner_rows(sc, sizes)
    if args.sitl:
        from .sitl import sitl_rows
        rows += sitl_rows(args.smoke)
    command = ("python -m benchmarks" + (" --smoke" if args.smoke else "")
               + (" --sitl" if args.sitl else "") + " --write-readme")
    table = markdown(rows, machine(), command)
    print(table)
    if args.write_readme:
        write_readme_block(README, table)
        print(f"wrote the results into {README}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
