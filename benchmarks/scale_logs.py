"""``python -m benchmarks.scale_logs``: many flights into one map (issue 37, the "logs" part
of the scale benchmark): the wall time of ``pdcov evaluate`` over 1, 4 and 8 logs one after
the other in one process (``--jobs 1``) and on every core (``--jobs N``), side by side in the
same run, and whether both give the same map (they must: the grids merge in log order).

Each log is the same survey flight (a tlog written at benchmark time, never committed) under
its own name; each run is a child ``pdcov`` process, not pinned to a core.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tests.support.scenarios import MILD_PLUMB_BOB, Scenario

from .offline import write_mission, write_tlog
from .report import Row, machine, markdown

LOG_COUNTS = (1, 4, 8)
# A 90 s lawnmower at 40 m over 500 m x 500 m of 1 m cells, a 1920 x 1080 camera at 10 Hz:
# about 1.5 s per log on one core beside about 1.3 s of start-up and outputs per command.
SURVEY = Scenario("logs", "sortie", 500.0, 1.0, (1920, 1080, 80.0, "plumb_bob", MILD_PLUMB_BOB),
                  40.0, 0.0, 10.0, "lawnmower", 40.0, 10.0, 90.0)
SMOKE = Scenario("logs", "sortie", 60.0, 1.0, (320, 180, 80.0, "plumb_bob", MILD_PLUMB_BOB),
                 15.0, 0.0, 2.0, "lawnmower", 15.0, 5.0, 4.0)


def evaluate_s(mission: Path, logs: list[Path], jobs: int, out: Path) -> float:
    """Wall seconds of ``pdcov evaluate`` of ``logs`` with ``--jobs jobs`` into ``out``."""
    argv = [sys.executable, "-m", "pdcov.cli", "evaluate", "--config", str(mission),
            *(a for p in logs for a in ("--log", str(p))), "--out", str(out),
            "--jobs", str(jobs), "--no-progress"]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed ({proc.returncode}):\n{proc.stderr}")
    return wall


def same_map(a: Path, b: Path) -> bool:
    """Whether the runs ``a`` and ``b`` wrote the same grid.npz arrays."""
    with np.load(a / "grid.npz") as x, np.load(b / "grid.npz") as y:
        return x.files == y.files and all(np.array_equal(x[k], y[k]) for k in x.files)


def logs_rows(scenario: Scenario, counts: tuple[int, ...] = LOG_COUNTS) -> list[Row]:
    """For each count of logs: --jobs 1, --jobs (every core), the speed-up, the same map."""
    cores = len(os.sched_getaffinity(0))
    rows = []
    with tempfile.TemporaryDirectory(prefix="pdcov-bench-logs-") as tmp:
        folder = Path(tmp)
        mission = write_mission(folder / "mission.yaml", scenario)
        first = write_tlog(folder / "log_00.tlog", scenario)
        logs = [first] + [Path(shutil.copyfile(first, folder / f"log_{k:02d}.tlog"))
                          for k in range(1, max(counts))]
        for n in counts:
            one = evaluate_s(mission, logs[:n], 1, folder / f"one_{n}")
            many = evaluate_s(mission, logs[:n], cores, folder / f"all_{n}")
            flown_s = n * scenario.duration_s
            rows += [
                Row("logs", f"evaluate {n} log{'s' * (n > 1)}, --jobs 1",
                    f"{one:.2f} s ({flown_s / one:,.0f}x real time)"),
                Row("logs", f"evaluate {n} log{'s' * (n > 1)}, --jobs {cores}",
                    f"{many:.2f} s ({flown_s / many:,.0f}x real time; {one / many:.2f}x "
                    "--jobs 1)"),
                Row("logs", f"{n} log{'s' * (n > 1)}: --jobs {cores} map = --jobs 1 map",
                    "same" if same_map(folder / f"one_{n}", folder / f"all_{n}")
                    else "differs", "same", same_map(folder / f"one_{n}",
                                                     folder / f"all_{n}")),
            ]
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scale_logs",
                                     description=__doc__)
    parser.add_argument("--smoke", action="store_true",
                        help="a tiny flight, 1 and 2 logs (CI; timings meaningless)")
    args = parser.parse_args(argv)
    rows = (logs_rows(SMOKE, (1, 2)) if args.smoke else logs_rows(SURVEY))
    print(markdown(rows, machine(), "python -m benchmarks.scale_logs"
                   + (" --smoke" if args.smoke else "")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
