"""A watcher joining late over real Zenoh gets a county's map (30 x 30 km at 1 m, 9 x 10^8
cells) from the daemon's tiled snapshot within 10 s (issue 37's Done-when), in the memory of
the cells flown: the daemon's decisions fly in this process (tests/support/service_feed.py)
and answer as the daemon's bus endpoints do (liveliness, status, snapshot queryable)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from pdcov.bus.keys import VehicleKeys
from pdcov.bus.sources import SourcedPublisher
from pdcov.bus.status import encode_status
from pdcov.bus.tiled_snapshot import encode_grid_snapshot
from tests.support.service_feed import COUNTY, SIDE_M, flown
from tests.support.watch_fixtures import zenoh_conf

zenoh = pytest.importorskip("zenoh")

LATE_JOIN_S = 10.0  # the Done-when: the whole map within this long


def test_a_late_watcher_has_the_county_map_within_10_s(router):
    live, _tiles, fields = flown(COUNTY)
    vid = fields["vehicle_id"]
    keys = VehicleKeys(vid)
    snapshot = encode_grid_snapshot(live.grid, live.tile_size, live.grid_hash)
    status = encode_status({**fields, "tiles_seq": live.tiles_seq - 1, "tiles_behind": 0})
    session = zenoh.open(zenoh_conf("client", connect=router))
    stop = threading.Event()
    try:
        token = session.liveliness().declare_token(keys.alive)
        queryable = session.declare_queryable(
            keys.snapshot, lambda q: q.reply(keys.snapshot, snapshot))
        pub = SourcedPublisher(session.declare_publisher(keys.status))

        def statuses() -> None:
            while not stop.wait(0.25):
                pub.put(status)

        threading.Thread(target=statuses, daemon=True).start()
        t0 = time.monotonic()
        out = subprocess.run([sys.executable, "-m", "pdcov.cli", "watch", "--once", "--mode",
                              "client", "--zenoh-connect", router,
                              "--no-multicast-scouting", "--wait-s", str(LATE_JOIN_S)],
                             capture_output=True, text=True, timeout=120)
        elapsed_s = time.monotonic() - t0
    finally:
        stop.set()
        queryable.undeclare()
        token.undeclare()
        session.close()
    assert out.returncode == 0, out.stderr
    print(f"late watcher: the county's map in {elapsed_s:.1f} s (process start included), "
          f"snapshot {len(snapshot):,} bytes")
    # The report's free cells are the rebuilt grid's (0 without it): the county's, whole.
    assert f"free cells {SIDE_M * SIDE_M}" in out.stdout, out.stdout
    assert elapsed_s < LATE_JOIN_S, out.stdout
