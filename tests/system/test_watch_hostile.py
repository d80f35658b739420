"""`pdcov watch` as a process on the default (open) bus with a rogue Zenoh session beside a
vehicle's publisher, through a real router on loopback: forged tiles leave the vehicle's map
equal to what its daemon says, and the operator is told; a second session answering the
snapshot leaves the vehicle untrusted, shown; the open bus itself is always named."""

from __future__ import annotations

import re
import subprocess
import sys
import time

import numpy as np
import pytest

from pdcov.bus.keys import VehicleKeys
from pdcov.bus.sources import source_session
from tests.support.watch_fixtures import (
    TinyPublisher,
    ZenohTinyDaemon,
    forged_tiles,
    load,
    start_watcher,
    stop_watcher,
    zenoh_conf,
)

zenoh = pytest.importorskip("zenoh")


@pytest.fixture
def rogue(router):
    session = zenoh.open(zenoh_conf("client", connect=router))
    try:
        yield session
    finally:
        session.close()


def fly(d: ZenohTinyDaemon, steps: int) -> None:
    for _ in range(steps):
        d.publish_step()
        time.sleep(0.05)


def test_forged_tiles_from_a_rogue_session_do_not_reach_the_map(router, processes, daemons,
                                                                 rogue, tmp_path):
    d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
    daemons.append(d)
    w = start_watcher(processes, router, "--record", tmp_path / "rec")
    fly(d, 20)
    keys = VehicleKeys("uav1")
    # The red team's message: the vehicle's next seq, every cell at P_D 1, sent twice: as
    # a plain put (no source) and from a declared publisher stamped with the rogue's id.
    payload = forged_tiles(d.pub, d.pub.seq + 1)
    rogue.put(keys.tiles, payload)
    pub = rogue.declare_publisher(keys.tiles)
    pub.put(payload, source_info=zenoh.SourceInfo(pub.id, 0))
    time.sleep(0.5)
    fly(d, 20)
    for _ in range(6):
        d.pub_status.put(d.pub.status())
        time.sleep(0.25)
    out = stop_watcher(w)
    got = load(tmp_path / "rec" / "uav1" / "grid.npz")
    np.testing.assert_array_equal(got["log_miss_d"], d.pub.grid.log_miss_d)
    share = d.pub.grid.metrics([0.8]).proportion_at_or_above[0.8]
    assert f"coverage {100 * share:.1f}% of free cells at P_D >= 0.8" in out, out
    assert "also claims this vehicle" in out, out
    assert "bus not secured" in out, out


def test_a_second_session_answering_the_snapshot_leaves_the_vehicle_untrusted(
        router, processes, daemons, rogue):
    d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
    daemons.append(d)
    fly(d, 10)
    liar = TinyPublisher("uav1")
    liar.step(60)
    keys = VehicleKeys("uav1")
    q = rogue.declare_queryable(keys.snapshot,
                                lambda query: query.reply(keys.snapshot, liar.snapshot()))
    try:
        w = start_watcher(processes, router)
        fly(d, 30)
        out = stop_watcher(w)
    finally:
        q.undeclare()
    assert "all answer as this vehicle" in out, out
    # Neither session's grid is shown as the vehicle's coverage.
    assert not any(line.startswith("pdcov watch: coverage") for line in out.splitlines()), out


def test_the_watchers_queries_name_its_session(router, daemons):
    # So that the daemon's snapshot rate limit gives each watcher its own share
    # (service/query_limit.py) instead of the bucket every anonymous querier shares.
    d = ZenohTinyDaemon(TinyPublisher("uav1"), router)
    daemons.append(d)
    seen: list[str | None] = []
    spy = d.session.declare_queryable(VehicleKeys("uav1").mission,
                                      lambda query: seen.append(source_session(query)))
    try:
        fly(d, 4)
        out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--once", "--mode",
                              "client", "--zenoh-connect", router, "--no-multicast-scouting",
                              "--wait-s", "3"], capture_output=True, text=True, timeout=60)
    finally:
        spy.undeclare()
    assert out.returncode == 0, out.stderr
    # A Zenoh id prints as up to 32 hex digits, without leading zeros (1 in 16 has 31).
    assert seen and all(isinstance(s, str) and re.fullmatch("[0-9a-f]{1,32}", s)
                        for s in seen), seen
    assert len(set(seen)) == 1 and seen[0] != str(d.session.zid())
