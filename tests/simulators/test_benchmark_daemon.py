"""The daemon benchmark at its tiny size, run as documented (``python -m benchmarks.daemon
--smoke``): simulator -> pdcov serve -> Zenoh subscriber runs, and every figure is measured
(no timing is asserted)."""

import json
import math
import subprocess
import sys

from tests.support.harness import ROOT


def test_daemon_benchmark_smoke_measures_every_figure(tmp_path):
    out = tmp_path / "daemon.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.daemon", "--smoke", "--window-s",
                           "2", "--json", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(out.read_text())
    r = figures["run"]
    assert r["frames_used"] > 0 and r["autopilot_s"] > 0
    assert r["bytes_per_s"]["status"] > 0 and r["bytes_per_s"]["tiles"] > 0
    assert all(math.isfinite(v) for pair in r["latency_ms"].values() for v in pair)
    assert 0 < r["cpu_share"] < 2.0
    assert r["memory"]["VmHWM"] >= r["memory"]["VmRSS"] > 0
    assert [ok is None for ok in figures["rows_ok"]] == [True] + [False] * 7
