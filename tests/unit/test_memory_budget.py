"""`pdcov serve --check` refuses what would fail later (service/memory_budget.py), and the
config bounds camera.frame_rate_hz."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pdcov.config.load import mission_from_dict
from pdcov.core.ground_cover import GroundCover
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import ConfigError
from pdcov.service.memory_budget import (
    MemoryCheck,
    estimate_bytes,
    memory_check,
    memory_limit_bytes,
)
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
    assert estimate_bytes(10**6, 10**6, [5.0], 1.0) < estimate_bytes(10**6, 10**6, [1000.0],
                                                                     1.0)
    limit = (200 << 20, "memory.max (the unit's MemoryMax)")
    assert memory_check(m, 10_000, 10_000, limit) == MemoryCheck(None, None)
    # 4 M cells of 1 m: 1 km2 searched x 32 B and the snapshot's 64 B a domain cell.
    why = memory_check(m, 4_000_000, 4_000_000, limit).refusal
    assert why is not None and why.startswith("the daemon would need about ")
    assert ("to search 1 km2 (1,000,000 cells of the 4,000,000 per grid, 1000 frames/s), "
            "more than the 200 MiB of memory.max") in why
    assert memory_check(m, 4_000_000, 4_000_000, None) == MemoryCheck(None, None)


def test_the_terrain_and_what_stands_on_it_count_as_loaded():
    m = _mission(5.0)
    g = m.domain.grid_geometry(m.cell_size_m)
    cover = GroundCover(g, np.full(g.shape, 15.0), np.full(g.shape, 1, np.uint8))
    covered = dataclasses.replace(m, terrain=TerrainSurface(
        g, np.zeros((g.n_rows + 1, g.n_cols + 1)), "test", cover=cover))
    held = covered.terrain.nbytes
    # Corners (8 B), block ranges, the cover's height, kind, code and clearance (10 B) and
    # its tops (8 B and 3 x 4 B): about 38 B a cell.
    assert held >= 38 * g.n_rows * g.n_cols
    cells = g.n_rows * g.n_cols
    need = estimate_bytes(cells, cells, [5.0], m.max_gap_s)
    assert memory_check(m, cells, cells, (need, "memory.max")) == MemoryCheck(None, None)
    assert memory_check(covered, cells, cells, (need + held, "memory.max")).refusal is None
    assert memory_check(covered, cells, cells, (need + held - 1, "memory.max")).refusal


def test_a_county_is_not_refused_but_told_how_much_of_it_the_memory_holds():
    # 30 x 30 km at 1 m: no snapshot (over what a ground station accepts), the grid grows
    # with the cells seen: 600 MiB hold about 14 km2 searched, not 900 km2.
    m = _mission(5.0)
    check = memory_check(m, 900_000_000, 900_000_000, (600 << 20, "memory.max"))
    assert check.refusal is None and check.warning is not None
    fits_km2 = ((600 << 20) - estimate_bytes(0, 900_000_000, [5.0], m.max_gap_s)) / 32 / 1e6
    assert f"hold about {fits_km2:,.1f} km2 searched at 1 m cells, of the domain's 900.0 " \
        "km2" in check.warning
    assert 10 < fits_km2 < 20


def test_the_limit_is_the_least_of_the_cgroup_and_available_memory(tmp_path):
    cg, mi = tmp_path / "memory.max", tmp_path / "meminfo"
    cg.write_text("629145600\n")  # MemoryMax=600M
    mi.write_text("MemTotal: 4000000 kB\nMemAvailable: 2000000 kB\n")
    assert memory_limit_bytes(cg, mi) == (629145600, f"{cg} (the unit's MemoryMax)")
    cg.write_text("max\n")
    assert memory_limit_bytes(cg, mi) == (2000000 * 1024, f"MemAvailable in {mi}")
    assert memory_limit_bytes(tmp_path / "none", tmp_path / "none") is None
