"""benchmarks.scale at its tiny CI size, run as documented (``python -m benchmarks.scale
--smoke --json PATH``): each domain runs live in its own process, its figures are measured
and its flown cells equal the smallest domain's (no timing or memory is asserted)."""

import json
import subprocess
import sys

from tests.support.harness import ROOT


def test_scale_benchmark_smoke_measures_every_domain(tmp_path):
    out = tmp_path / "scale.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.scale", "--smoke", "--json",
                           str(out)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    figures = json.loads(out.read_text())
    domains = figures["domains"]
    assert sorted(domains, key=int) == ["200", "2000"]
    for d in domains.values():
        assert d["rss_mb"] > 0 and d["frames"] > 0 and d["tile_bytes"] > 0
        assert d["tiles_outside"] == 0
        assert d["longest_call_ms"] > 0 and d["checkpoint_take_ms"] > 0
    assert domains["2000"]["cells"] == 100 * domains["200"]["cells"]
    # The rows with a target: per domain the longest call (a timing: not asserted) and its
    # flown cells equal, then the memory ratio; the exit status says whether all passed.
    oks = [ok for ok in figures["rows_ok"] if ok is not None]
    assert len(oks) == 5 and oks[1] is oks[3] is True, done.stdout
    assert done.returncode == (0 if all(oks) else 1), done.stderr[-3000:]
