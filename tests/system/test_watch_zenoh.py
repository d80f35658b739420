"""`pdcov watch` over real Zenoh on loopback (router in the test process), fed by small
publishers that speak docs/protocol.md through pdcov.bus: fleet merge, late join, lost
tiles, --once. Every session and process is closed in teardown; each wait is bounded."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from pdcov.ground.app import QUIET_AFTER_S
from tests.support.watch_fixtures import (
    TinyPublisher,
    ZenohTinyDaemon,
    free_port,
    load,
    start_watcher,
    stop_watcher,
)

zenoh = pytest.importorskip("zenoh")


def fly(daemons, steps: int, period_s: float = 0.05) -> None:
    for _ in range(steps):
        for d in daemons:
            d.publish_step()
        time.sleep(period_s)


def settle(daemons, seconds: float = 1.5) -> None:
    """Status only (nothing new flies), so watchers catch up and check the last seq."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for d in daemons:
            d.pub_status.put(d.pub.status())
        time.sleep(0.25)


def test_fleet_grid_is_the_sum_of_the_two_vehicles(router, processes, daemons, tmp_path):
    daemons += [ZenohTinyDaemon(TinyPublisher("uav1", y_m=-45.0), router),
                ZenohTinyDaemon(TinyPublisher("uav2", y_m=-37.0), router)]
    w = start_watcher(processes, router, "--record", tmp_path / "rec")
    fly(daemons, 40)
    settle(daemons)
    out = stop_watcher(w)
    assert "coverage" in out
    a, b = (d.pub.grid for d in daemons)
    fleet = load(tmp_path / "rec" / "fleet" / "grid.npz")
    np.testing.assert_array_equal(fleet["log_miss_d"], a.log_miss_d + b.log_miss_d)
    np.testing.assert_array_equal(fleet["log_miss_fa"], a.log_miss_fa + b.log_miss_fa)
    np.testing.assert_array_equal(fleet["n_obs"], a.n_obs + b.n_obs)
    np.testing.assert_array_equal(fleet["limiting"], np.maximum(a.limiting, b.limiting))
    for d in daemons:
        mine = load(tmp_path / "rec" / d.pub.vehicle_id / "grid.npz")
        np.testing.assert_array_equal(mine["log_miss_d"], d.pub.grid.log_miss_d)
        np.testing.assert_array_equal(mine["limiting"], d.pub.grid.limiting)
        assert (tmp_path / "rec" / d.pub.vehicle_id / "tiles.bin").stat().st_size > 0
        assert len((tmp_path / "rec" / d.pub.vehicle_id / "status.jsonl").read_text()
                   .splitlines()) >= 40


def test_late_and_gap_watchers_end_with_the_daemons_grid(router, processes, daemons,
                                                         tmp_path):
    # The publisher loses tiles 12 and 13 (seen by every watcher) and the last one.
    d = ZenohTinyDaemon(TinyPublisher("uav1"), router, drop={12, 13, 55})
    daemons.append(d)
    early = start_watcher(processes, router, "--vehicle", "uav1", "--record",
                          tmp_path / "early")
    fly(daemons, 25)
    late = start_watcher(processes, router, "--record", tmp_path / "late")
    fly(daemons, 30)
    assert d.pub.seq == 55
    settle(daemons, 5.0)  # > the watcher's trailing_gap_s: the lost last tiles are fetched
    for name, p in (("early", early), ("late", late)):
        stop_watcher(p)
        got = load(tmp_path / name / "uav1" / "grid.npz")
        np.testing.assert_array_equal(got["log_miss_d"], d.pub.grid.log_miss_d)
        np.testing.assert_array_equal(got["n_obs"], d.pub.grid.n_obs)
        snapshots = sorted((tmp_path / name / "uav1").glob("snapshot-*.npz"))
        assert len(snapshots) >= (3 if name == "early" else 2), snapshots


def test_once_prints_one_report(router, daemons):
    d = ZenohTinyDaemon(TinyPublisher("uav7"), router)
    daemons.append(d)
    fly(daemons, 12)
    out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--once", "--mode",
                          "client", "--zenoh-connect", router, "--no-multicast-scouting",
                          "--wait-s", "3"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert max(map(len, lines)) <= 80
    share = d.pub.grid.metrics([0.8]).proportion_at_or_above[0.8]
    assert f"coverage {100 * share:.1f}% of free cells at P_D >= 0.8" in lines[0]
    assert any(line.startswith("|uav7 ") for line in lines)


def test_with_no_daemon_the_watcher_says_so_once_and_keeps_waiting(router, processes):
    w = start_watcher(processes, router)
    time.sleep(QUIET_AFTER_S + 2.5)
    assert w.poll() is None  # still waiting
    said = [line for line in stop_watcher(w).splitlines() if "no vehicle heard" in line]
    assert len(said) == 1, said
    assert (f"no vehicle heard {QUIET_AFTER_S:g} s after connecting; this session: client, "
            f"connect [{router}]") in said[0]
    assert "is a daemon running" in said[0] and "(still waiting for pdcov/*/)" in said[0]


def test_a_router_nobody_runs_is_one_line_saying_what_to_do():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--plain",
                          "--zenoh-connect", endpoint], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and out.stdout == "" and out.stderr.count("\n") == 1, out.stderr
    assert "pdcov watch: error: bus: cannot open the Zenoh session" in out.stderr
    assert f"nothing answers at {endpoint} (refused or unreachable): check that the " \
           "router (zenohd)" in out.stderr
    assert ".rs" not in out.stderr and "Unable to connect" not in out.stderr


def test_watch_refuses_bad_arguments(tmp_path):
    (tmp_path / "old.txt").write_text("another run")
    out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--record",
                          str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "not empty" in out.stderr, out.stderr
    out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--vehicle", "a/b"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--vehicle 'a/b'" in out.stderr
    out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--web", "nowhere"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "HOST:PORT" in out.stderr and "Traceback" not in out.stderr
