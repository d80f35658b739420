"""benchmarks.live_path at its tiny CI size: the three recordings are made (the simulator
flies twice), replayed through the daemon's decisions and evaluated offline, and the live
grids equal the offline ones cell for cell (the command exits 1 otherwise). Run as the
documented command, ``python -m benchmarks.live_path --smoke``. No timing is asserted."""

import subprocess
import sys

from tests.support.harness import ROOT


def test_smoke_run_live_equals_offline():
    done = subprocess.run([sys.executable, "-m", "benchmarks.live_path", "--smoke"], cwd=ROOT,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    out = done.stdout
    for name in ("gimbal", "fixed", "S1"):
        assert f"| {name} | live grid = offline grid | equal | cell for cell | pass |" in out
        assert f"| {name} | live (daemon decisions): CPU ms/frame |" in out
    assert "DIFFERENT" not in out
