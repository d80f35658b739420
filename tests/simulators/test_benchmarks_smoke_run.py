"""`python -m benchmarks --smoke` runs every step at its tiny size (simulator flights
included) and writes its report, run as the documented command (tests/slow/
test_benchmarks_smoke.py: the references)."""

import subprocess
import sys

from tests.support.harness import ROOT

R1_FRAMES = 6
"""benchmarks/__main__.py SMOKE.r1_frames: the frames R1 is cast through at the smoke size."""


def test_smoke_run_completes():
    done = subprocess.run([sys.executable, "-m", "benchmarks", "--smoke", "--scenarios", "S1",
                           "S2", "S5", "canopy"], cwd=ROOT, capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    out = done.stdout
    for figure in ("update: frames/s", "floor passes", "R1 / pdcov", "R2 vs pdcov grid",
                   "offline evaluate (tlog)", "planner: plans/min",
                   "update with the DEM / flat S1", "R3 / pdcov with the DEM",
                   "R3 vs flat pdcov grid", "R3 vs pdcov grid with the DEM",
                   "update with the cover / the terrain alone, CPU per frame, 20 deg off nadir",
                   "update with the cover / the terrain alone, CPU per frame, 0 deg off nadir"):
        assert figure in out
    assert f"{R1_FRAMES} frames" in out
