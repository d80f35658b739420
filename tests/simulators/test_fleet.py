"""Fleet load in CI (issue 15): simulators, their daemons and 2 watchers through one
in-process Zenoh router (loopback, no multicast scouting); every watcher ends with every
vehicle's exact grid, and each vehicle's status is measured on the daemon's own clock (its
statuses' ``uptime_s``), never per second of wall time, which a busy machine stretches: at
most one status per period, and a mean payload within the 1 kB/s budget. A smaller fleet
than the documented run (``python -m benchmarks.fleet --vehicles 10``, figures in
docs/reliability.md) so that it fits in about a minute on a 2-core machine; the same command,
run as a process, writes its figures as JSON."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

import pytest

from pdcov.bus.session import BusConfig
from tests.support.harness import ROOT

VEHICLES, SPEED = 4, 2.0
STATUS_BUDGET_B_PER_S = 1000.0  # issue 13
PERIOD_S = BusConfig().status_period_s


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> dict[str, Any]:
    """The figures ``python -m benchmarks.fleet`` wrote (its exit code: 1 on a mismatch)."""
    folder = tmp_path_factory.mktemp("fleet")
    out = folder / "fleet.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.fleet", "--vehicles", str(VEHICLES),
                           "--speed", str(SPEED), "--watchers", "2", "--keep", str(folder / "run"),
                           "--json", str(out)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert out.exists(), done.stdout[-3000:] + done.stderr[-3000:]
    figures = json.loads(out.read_text())
    figures["exit_code"] = done.returncode
    return figures


def test_every_watcher_holds_every_vehicles_exact_grid(fleet):
    table = fleet["table"]
    assert fleet["mismatches"] == [] and fleet["exit_code"] == 0, table
    assert len(fleet["vehicles"]) == VEHICLES
    for v in fleet["vehicles"]:
        assert v["frames"] > 100, table  # each flew its lawnmower and counted it
        assert v["tiles_messages"] > 10 and v["status_messages"] > 10, table
        # The schedule is anchored on the daemon's clock: one status per period after the
        # first, however late a tick comes (a late one is followed by an early one).
        assert v["status_messages"] - 1 <= v["status_uptime_s"] / PERIOD_S + 1, table
        assert v["status_bytes"] / v["status_messages"] < 1600, table  # what each cost when
        # all were full (docs/reliability.md); the budget itself: below


def test_status_fits_its_budget(fleet):
    for v in fleet["vehicles"]:
        assert v["status_bytes"] / v["status_messages"] < STATUS_BUDGET_B_PER_S * PERIOD_S, \
            fleet["table"]
