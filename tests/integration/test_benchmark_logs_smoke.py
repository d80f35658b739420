"""`python -m benchmarks.scale_logs --smoke` runs as documented and finds the map of every
core equal to the map of one process (its timings mean nothing at this size)."""

import subprocess
import sys

from tests.support.harness import ROOT


def test_logs_benchmark_smoke_run():
    done = subprocess.run([sys.executable, "-m", "benchmarks.scale_logs", "--smoke"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "| logs | evaluate 2 logs, --jobs 1 |" in done.stdout
    assert "map = --jobs 1 map | same | same | pass |" in done.stdout
    assert "differs" not in done.stdout
