"""``python -m benchmarks.scale``: what ``pdcov serve``'s live path costs against the size of
the domain (issue 37, "County scale").

Section "domain": one recorded flight (the S1 survey's camera, 480x270 fixed 20 deg off
nadir at 30 frames/s, a lawnmower 15 m up over a ``--flight-m`` square; written as a tlog
by benchmarks.offline.write_tlog) is run live (benchmarks.live_path.live_pass: every
message through the daemon's decisions, with its tiles and status) over square domains of
200 m, 2 km, 10 km and 30 km at 1 m cells, all centred on the flight, the same ENU origin.
Each domain runs in a fresh process (``--child``), which reports:

* peak RSS: that process's VmHWM (imports included; not ``getrusage``'s ru_maxrss, which
  Linux carries across fork and exec from the benchmark's own process);
* CPU ms/frame (the frames' work) and CPU ms per second of flight of the periodic work
  (tiles and status), and the start's CPU seconds (the grid, hashes, the daemon's core);
* the grid's tile bytes (what the tiles allocated hold) and tiles;
* the flown cells: the smallest domain's whole grid against the same cells of each larger
  one (cell (r, c) of the 200 m grid is cell (r + k, c + k) of a grid k metres wider each
  side), equal cell for cell (counts, log-miss sums, limiting factors), and no look outside
  them.

Target (issue 37's Done-when): RSS(30 x 30 km) <= 1.5 x RSS(200 x 200 m). ``--smoke``: a
3 s flight over domains of 200 m and 2 km (CI; the figures mean little). ``--json PATH``
writes the figures and each row's verdict.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_store import frozen_update
from tests.support.scenarios import scenarios

from .daemon import memory_bytes
from .live_path import Recording, live_pass, write_config
from .offline import write_tlog
from .report import Row, machine, markdown

SIDES_M = (200, 2_000, 10_000, 30_000)
SMOKE_SIDES_M = (200, 2_000)
RSS_RATIO = 1.5  # the target: RSS of the largest domain at most this times the smallest's
LONGEST_CALL_MS = 50.0  # the target: no call holds the daemon's loop longer
LAYERS = (Layer.N_OBS, Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.LIMITING)


def record(folder: Path, flight_m: float, seconds: float) -> tuple[dict[str, Any], Path]:
    """The flight: the S1 survey's camera and rate, a lawnmower 15 m up over the square
    [0, flight_m]^2 (ENU m), its first ``seconds``; (its mission config mapping, the tlog)."""
    sc = dataclasses.replace(scenarios(True)["S1"], side_m=flight_m, alt_m=15.0,
                             duration_s=seconds)
    return sc.mission_doc(), write_tlog(folder / "flight.tlog", sc)


def domain_config(folder: Path, doc: dict[str, Any], side_m: int, flight_m: float) -> Path:
    """The mission of ``doc`` over a ``side_m`` square domain centred on the flight."""
    lo = (flight_m - side_m) / 2
    hi = lo + side_m
    folder.mkdir(parents=True)
    return write_config(folder, {**doc, "vehicle_id": "bench_scale", "domain": {
        "polygon_enu_m": [[lo, lo], [hi, lo], [hi, hi], [lo, hi]], "cell_size_m": 1.0}})


def child(config: Path, tlog: Path, inner_m: int, out: Path) -> None:
    """Run the flight live over ``config``'s domain and write the figures (``out``, JSON)
    and the grid's cells of the central ``inner_m`` square (``out`` .npz)."""
    cpu0 = time.process_time()
    run = live_pass(Recording("scale", config, tlog))
    start_cpu_s = time.process_time() - cpu0 - run.cpu_s
    grid = run.grid
    g = grid.geometry
    k = (g.n_rows - inner_m) // 2  # the inner square's first row and column
    inner = (k, k + inner_m, k, k + inner_m)
    outside = [key for key in grid.tile_keys() if not _overlaps(grid.layout.window_of(key),
                                                                inner)]
    np.savez(out.with_suffix(".npz"), **{lay.value: grid.read(lay, inner) for lay in LAYERS})
    out.write_text(json.dumps({
        "cells": g.n_rows * g.n_cols,
        "rss_mb": memory_bytes(os.getpid())["VmHWM"] / 2**20, "frames": run.frames,
        "ms_per_frame": run.ms_per_frame, "periodic_ms_per_s": run.periodic_ms_per_s,
        "start_cpu_s": start_cpu_s, "tile_bytes": grid.nbytes,
        "longest_call_ms": 1e3 * run.longest_call_s, "checkpoint_take_ms": _take_ms(grid),
        "tiles": len(grid.tile_keys()), "tiles_outside": len(outside)}))


def _take_ms(grid: CoverageGrid) -> float:
    """Wall ms the loop spends taking a checkpoint of all of ``grid`` (its tiles frozen,
    service/checkpoint.py)."""
    t0 = time.perf_counter()
    update = frozen_update(grid)
    taken = time.perf_counter() - t0
    update.release()
    return 1e3 * taken


def _overlaps(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def run_domain(folder: Path, doc: dict[str, Any], tlog: Path, side_m: int, flight_m: float,
               inner_m: int) -> dict[str, Any]:
    """One domain's figures, measured in a fresh process, and its inner cells."""
    config = domain_config(folder / f"d{side_m}", doc, side_m, flight_m)
    out = config.parent / "figures.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.scale", "--child", str(config),
                           str(tlog), str(inner_m), str(out)], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the {side_m} m domain's run failed: {done.stderr[-3000:]}")
    figures = json.loads(out.read_text())
    with np.load(out.with_suffix(".npz")) as z:
        figures["inner"] = {name: z[name] for name in z.files}
    return figures


def rows_for(runs: dict[int, dict[str, Any]], flight: str) -> list[Row]:
    """The table: per domain its figures; then the memory target."""
    small_side = min(runs)
    small = runs[small_side]
    rows = [Row("domain", "recording", flight)]
    for side, r in runs.items():
        same = all(np.array_equal(small["inner"][n], r["inner"][n]) for n in small["inner"])
        label = f"{side / 1000:g} x {side / 1000:g} km ({r['cells']:,} cells)"
        rows += [
            Row(label, "peak RSS", f"{r['rss_mb']:,.0f} MiB"),
            Row(label, "CPU ms/frame; tiles and status CPU ms per s of flight; start CPU s",
                f"{r['ms_per_frame']:.2f}; {r['periodic_ms_per_s']:.1f}; "
                f"{r['start_cpu_s']:.1f}"),
            Row(label, "grid tile bytes (tiles)", f"{r['tile_bytes'] / 2**20:,.1f} MiB "
                f"({r['tiles']})"),
            Row(label, "longest call holding the loop (wall ms); taking a checkpoint of "
                "every tile (wall ms)", f"{r['longest_call_ms']:.1f}; "
                f"{r['checkpoint_take_ms']:.2f}", f"<= {LONGEST_CALL_MS:g}",
                max(r["longest_call_ms"], r["checkpoint_take_ms"]) <= LONGEST_CALL_MS),
            Row(label, f"flown cells = the {small_side} m domain's, none seen outside",
                "cell for cell" if same and not r["tiles_outside"] else
                f"DIFFERENT ({r['tiles_outside']} tiles outside)", "equal",
                same and not r["tiles_outside"])]
    big = runs[max(runs)]
    ratio = big["rss_mb"] / small["rss_mb"]
    rows.append(Row("domain", f"RSS {max(runs) / 1000:g} km / RSS {small_side / 1000:g} km",
                    f"{ratio:.2f}", f"<= {RSS_RATIO:g}", ratio <= RSS_RATIO))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scale", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true",
                        help="a 3 s flight over 200 m and 2 km domains (CI)")
    parser.add_argument("--flight-m", type=float, default=80.0,
                        help="side of the flight's square (m, default 80; inside 200 m)")
    parser.add_argument("--flight-s", type=float, default=60.0,
                        help="seconds of flight (default 60)")
    parser.add_argument("--json", type=Path, metavar="PATH",
                        help="also write the figures and each row's verdict (null: no "
                             "target) to PATH as JSON")
    parser.add_argument("--child", nargs=4, metavar=("CONFIG", "TLOG", "INNER_M", "OUT"),
                        help=argparse.SUPPRESS)  # one domain's run, in its own process
    args = parser.parse_args(argv)
    if args.child:
        config, tlog, inner_m, out = args.child
        child(Path(config), Path(tlog), int(inner_m), Path(out))
        return 0
    sides, seconds = (SMOKE_SIDES_M, 3.0) if args.smoke else (SIDES_M, args.flight_s)
    if not 0 < args.flight_m <= sides[0] - 40:
        parser.error(f"--flight-m {args.flight_m:g}: expected 0 < m <= {sides[0] - 40} "
                     f"(the flight and its footprints inside the {sides[0]} m domain)")
    runs: dict[int, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="pdcov-bench-scale-") as tmp:
        d = Path(tmp)
        doc, tlog = record(d, args.flight_m, seconds)
        for side in sides:
            print(f"domain {side} m", file=sys.stderr)
            runs[side] = run_domain(d, doc, tlog, side, args.flight_m, sides[0])
    flight = (f"S1 camera (480x270, 20 deg off nadir, 30 frames/s), lawnmower 15 m up over "
              f"{args.flight_m:g} m, {seconds:g} s: {runs[sides[0]]['frames']:,} frames")
    table = rows_for(runs, flight)
    command = "python -m benchmarks.scale" + (" --smoke" if args.smoke else "")
    print(markdown(table, machine(), command))
    if args.json:
        args.json.write_text(json.dumps({
            "domains": {str(s): {k: v for k, v in r.items() if k != "inner"}
                        for s, r in runs.items()},
            "rows_ok": [row.ok for row in table]}, indent=1))
    return 0 if all(row.ok is not False for row in table) else 1


if __name__ == "__main__":
    sys.exit(main())
