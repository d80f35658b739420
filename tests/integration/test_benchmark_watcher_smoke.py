"""`python -m benchmarks.watcher --smoke --json PATH` runs as documented and finds the live
merged map equal to the offline merge of the vehicles' grids (its timings mean nothing at
this size)."""

import json
import subprocess
import sys

from tests.support.harness import ROOT


def test_watcher_benchmark_smoke_run(tmp_path):
    out = tmp_path / "watcher.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.watcher", "--smoke", "--json",
                           str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "| live map = offline merge (CoverageGrid.merge) | same | same | pass |" \
        in done.stdout
    figures = json.loads(out.read_text())
    assert figures["equal_offline"] and figures["equal_merge_fleet"]
    assert figures["messages"] > 0 and figures["tiles"] >= figures["messages"]
    assert figures["vehicles"] == 3 and figures["cpu_per_s"] > 0
