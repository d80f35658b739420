"""Sorties of one search as tlogs, and the map `pdcov evaluate` must make of them: each
log evaluated alone, the grids merged with CoverageGrid.merge in log order (the oracle of
tests/slow/test_many_logs.py and tests/integration/test_many_logs_dask.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pdcov.config.load import load_mission
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_snapshot import read_snapshot
from pdcov.core.rotations import R_from_euler_zyx_many
from tests.support.evaluate_inputs import ORIGIN, RATE_HZ, run
from tests.support.mavlink_fixtures import KnownFlight, samples_from_flight, write_tlog


def sortie(k: int, origin: Origin = ORIGIN) -> KnownFlight:
    """Sortie ``k``: a 16 s pass north along x = 8 + 9 k m (the passes overlap) at 9-12 m,
    some roll, pitch and yaw, starting 100 k s after boot (the autopilot rebooted between
    flights or not: each log's own clock)."""
    t = 100.0 * k + np.arange(0.0, 16.0 + 1e-9, 1 / RATE_HZ)
    s = t - t[0]
    r = np.c_[8 + 9 * k + 2 * np.sin(s / 3), 2.5 * s, 10 + 1.5 * np.sin(s / 4 + k)]
    R = R_from_euler_zyx_many(0.04 * np.sin(s + k), -0.08 + 0.03 * np.cos(s),
                              0.1 * np.sin(s / 4) + 0.2 * k)
    return KnownFlight(origin, t, R, r)


def write_sorties(folder: Path, n: int, origins: list[Origin] | None = None) -> list[Path]:
    """Sorties 0 .. n-1 as folder/sortie_<k>.tlog (each with its home at its origin)."""
    folder.mkdir(parents=True, exist_ok=True)
    return [write_tlog(folder / f"sortie_{k}.tlog",
                       samples_from_flight(sortie(k, (origins or [ORIGIN] * n)[k])))
            for k in range(n)]


def one_by_one(config: Path, logs: list[Path], work: Path) -> CoverageGrid:
    """Each log through `pdcov evaluate` alone, the grid.npz files merged in log order."""
    mission = load_mission(config)
    merged = None
    for k, log in enumerate(logs):
        out = work / f"alone_{k}"
        assert run("evaluate", "--config", str(config), "--log", str(log), "--out", str(out),
                   "--no-progress") == 0
        grid = mission.new_mission_grid()
        read_snapshot(out / "grid.npz").restore(grid)
        if merged is None:
            merged = grid
        else:
            merged.merge(grid)
    assert merged is not None
    return merged


def assert_same_map(run_dir: Path, grid: CoverageGrid) -> None:
    """The run's grid.npz holds ``grid`` bit for bit (pd, pfa, n_obs, limiting, sums)."""
    with np.load(run_dir / "grid.npz") as z:
        np.testing.assert_array_equal(z["pd"], grid.pd)
        np.testing.assert_array_equal(z["pfa"], grid.pfa)
        np.testing.assert_array_equal(z["n_obs"], grid.n_obs)
        np.testing.assert_array_equal(z["limiting"], grid.limiting)
        np.testing.assert_array_equal(z["log_miss_d"], grid.log_miss_d)
        assert int(z["frames"]) == grid.frames
