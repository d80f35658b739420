"""Fleet load in CI (issue 15): simulators, their daemons and 2 watchers through one
in-process Zenoh router (loopback, no multicast scouting); every watcher ends with every
vehicle's exact grid, and each vehicle's status stays within its 1 kB/s budget. A smaller
fleet than the documented run (``python -m benchmarks.fleet --vehicles 10``, figures in
docs/reliability.md) so that it fits in about a minute on a 2-core machine."""

from __future__ import annotations

from benchmarks.fleet import markdown, run

VEHICLES, SPEED = 4, 2.0


def test_every_watcher_holds_every_vehicles_exact_grid(tmp_path):
    r = run(tmp_path, VEHICLES, SPEED, watchers=2, timeout_s=240.0)
    table = markdown(r, "test_fleet")
    assert r.mismatches == (), table
    assert len(r.vehicles) == VEHICLES
    for v in r.vehicles:
        assert v.frames > 100, table  # each flew its lawnmower and counted it
        assert v.tiles_messages > 10 and v.status_messages > 10, table
        assert v.status_bytes / v.status_messages < 1600, table
        assert v.status_bytes / r.window_s < 1000, table  # issue 13: status < 1 kB/s
