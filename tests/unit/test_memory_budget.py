"""`pdcov serve --check` refuses what would fail later (service/memory_budget.py), and the
config bounds camera.frame_rate_hz."""

from __future__ import annotations

import pytest

from pdcov.config.load import mission_from_dict
from pdcov.errors import ConfigError
from pdcov.service.memory_budget import estimate_bytes, memory_limit_bytes, memory_refusal
from tests.support.evaluate_inputs import mission_doc


def _mission(rate_hz: float):
    doc = mission_doc()
    doc["camera"]["frame_rate_hz"] = rate_hz
    return mission_from_dict(doc, source="m.yaml")


def test_a_frame_rate_beyond_the_bound_is_a_config_error():
    with pytest.raises(ConfigError, match=r"m.yaml: camera.frame_rate_hz: 1e\+06 Hz, more "
                                          r"than the 1000 Hz"):
        _mission(1e6)


def test_a_mission_beyond_the_memory_it_may_use_is_refused_naming_the_figures():
    m = _mission(1000.0)  # 1000 frames/s: a 5 s batch of 5,000 frames, ~10 MiB
    assert estimate_bytes(10**6, [5.0], 1.0) < estimate_bytes(10**6, [1000.0], 1.0)
    limit = (200 << 20, "memory.max (the unit's MemoryMax)")
    assert memory_refusal(m, 10_000, limit) is None
    why = memory_refusal(m, 4_000_000, limit)  # 4 M cells x 64 B: 244 MiB of grid
    assert why is not None and why.startswith("the daemon would need about ")
    assert "(4,000,000 cells per grid, 1000 frames/s), more than the 200 MiB of memory.max" \
        in why
    assert memory_refusal(m, 4_000_000, None) is None  # the limit unknown: not refused


def test_the_limit_is_the_least_of_the_cgroup_and_available_memory(tmp_path):
    cg, mi = tmp_path / "memory.max", tmp_path / "meminfo"
    cg.write_text("629145600\n")  # MemoryMax=600M
    mi.write_text("MemTotal: 4000000 kB\nMemAvailable: 2000000 kB\n")
    assert memory_limit_bytes(cg, mi) == (629145600, f"{cg} (the unit's MemoryMax)")
    cg.write_text("max\n")
    assert memory_limit_bytes(cg, mi) == (2000000 * 1024, f"MemAvailable in {mi}")
    assert memory_limit_bytes(tmp_path / "none", tmp_path / "none") is None
