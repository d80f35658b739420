"""The daemon benchmark at its tiny size: simulator -> pdcov serve -> Zenoh subscriber runs,
and every figure is measured (no timing is asserted)."""

import math

from benchmarks.daemon import rows, run
from benchmarks.scenarios import scenarios


def test_daemon_benchmark_smoke_measures_every_figure(tmp_path):
    sc = scenarios(smoke=True)["S1"]
    r = run(tmp_path, sc, window_s=2.0, start_timeout_s=120.0)
    assert r.frames_used > 0 and r.autopilot_s > 0
    assert r.bytes_per_s["status"] > 0 and r.bytes_per_s["tiles"] > 0
    assert all(math.isfinite(v) for pair in r.latency_ms.values() for v in pair)
    assert 0 < r.cpu_share < 2.0
    assert r.memory["VmHWM"] >= r.memory["VmRSS"] > 0
    table = rows(r, sc)
    assert [row.ok is None for row in table] == [True] + [False] * 7
