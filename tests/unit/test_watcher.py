"""The watcher's decisions in memory (ground/watcher.py): payloads from a real CoverageGrid
through the bus codecs, time stepped by hand. Grids must come out equal cell for cell."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.bus.grid_state import decode_snapshot
from pdcov.bus.tiles import decode_tiles
from pdcov.ground.watcher import QuerySnapshot, Watcher
from tests.support.watch_fixtures import Link, TinyPublisher


def assert_same_grid(state, grid) -> None:
    np.testing.assert_array_equal(state.log_miss_d, grid.log_miss_d)
    np.testing.assert_array_equal(state.log_miss_fa, grid.log_miss_fa)
    np.testing.assert_array_equal(state.n_obs, grid.n_obs)
    np.testing.assert_array_equal(state.mask, grid.mask)
    assert state.frames == grid.frames


def test_watcher_from_the_start_rebuilds_the_grid_from_tiles():
    pub = TinyPublisher()
    link = Link(pub, Watcher())
    link.fly(60)
    assert link.queries == 1  # the first tiles message asked for the (empty) snapshot
    assert pub.grid.frames == 60 and (pub.grid.n_obs > 0).sum() > 100
    assert_same_grid(link.w.feeds["demo"].state, pub.grid)
    assert link.w.feeds["demo"].gaps == 0


def test_late_joiner_keeps_tiles_while_awaiting_the_snapshot():
    pub = TinyPublisher()
    pub.step(20)
    pub.tiles()  # published before the watcher existed
    w = Watcher()
    now = 10.0
    # The first tiles it sees starts a snapshot query. Before the reply: one message lost
    # and one received, both older than the snapshot (no gap to chase: the snapshot holds
    # them), then one newer than it, received before the older one.
    pub.step(3)
    assert w.on_tiles("demo", decode_tiles(pub.tiles()), now) == [QuerySnapshot("demo")]
    pub.step(2)
    pub.tiles()  # lost
    pub.step(2)
    older = decode_tiles(pub.tiles())
    pub.step(1)
    snap = decode_snapshot(pub.snapshot())
    pub.step(2)
    newer = decode_tiles(pub.tiles())
    assert w.on_tiles("demo", newer, now + 0.1) == []
    assert w.on_tiles("demo", older, now + 0.2) == []
    assert w.on_snapshot("demo", snap, now + 0.3) == []
    feed = w.feeds["demo"]
    assert feed.gaps == 0 and feed.snapshots == 1 and feed.last_seq == newer.seq
    assert_same_grid(feed.state, pub.grid)


def test_late_watcher_ends_with_the_same_grid_as_one_there_from_the_start():
    pub = TinyPublisher()
    early, late = Watcher(), Watcher()
    a, b = Link(pub, early), Link(pub, late)
    for k in range(80):
        pub.step()
        payload = pub.tiles()
        for link in (a, b) if k >= 37 else (a,):
            link.now_s += 0.25
            if payload is not None:
                link.do(link.w.on_tiles("demo", decode_tiles(payload), link.now_s))
            if k % 4 == 0:
                link.status()
    assert_same_grid(late.feeds["demo"].state, pub.grid)
    assert_same_grid(early.feeds["demo"].state, pub.grid)


def test_a_gap_in_tiles_is_recovered_by_snapshot():
    pub = TinyPublisher()
    link = Link(pub, Watcher(), drop={7, 8, 15})
    link.fly(50)
    feed = link.w.feeds["demo"]
    assert feed.gaps == 2 and link.queries == 3
    assert_same_grid(feed.state, pub.grid)


def test_lost_last_tiles_are_noticed_from_the_status_and_recovered():
    pub = TinyPublisher()
    link = Link(pub, Watcher(trailing_gap_s=2.5))
    link.fly(30)
    pub.step(3)
    pub.tiles()  # the flight's last tiles message is lost; nothing follows it
    assert not np.array_equal(link.w.feeds["demo"].state.log_miss_d, pub.grid.log_miss_d)
    link.idle(2.0)
    assert link.queries == 1  # not yet: the status may simply be ahead of the tiles
    link.idle(2.0)
    assert link.queries == 2
    assert_same_grid(link.w.feeds["demo"].state, pub.grid)


def test_restarted_daemon_is_followed_by_a_new_snapshot():
    pub = TinyPublisher()
    link = Link(pub, Watcher())
    link.fly(20)
    fresh = TinyPublisher()  # restarted with no checkpoint: seq and uptime from 0
    link.pub = fresh
    link.fly(6)
    assert_same_grid(link.w.feeds["demo"].state, fresh.grid)


def test_fleet_grid_is_the_sum_of_the_vehicles_log_miss_sums():
    pubs = [TinyPublisher("uav1", y_m=-45.0), TinyPublisher("uav2", y_m=-38.0)]
    w = Watcher()
    links = [Link(p, w) for p in pubs]
    for _ in range(40):
        for link in links:
            link.fly(1)
    merged, ids = w.fleet_state()
    assert ids == ("uav1", "uav2")
    a, b = pubs[0].grid, pubs[1].grid
    np.testing.assert_array_equal(merged.log_miss_d, a.log_miss_d + b.log_miss_d)
    np.testing.assert_array_equal(merged.n_obs, a.n_obs + b.n_obs)
    report = w.report(links[0].now_s)
    assert report.target == 0.8 and [v.vehicle_id for v in report.vehicles] == ["uav1", "uav2"]
    pd = 0.0 - np.expm1((a.log_miss_d + b.log_miss_d).astype(np.float64))
    for t in (0.5, 0.8):
        assert report.proportion_at_or_above[t] == pytest.approx(
            (pd[a.mask] >= t).mean(), abs=0)
    # Each vehicle alone covers less than the fleet.
    for v in report.vehicles:
        assert v.proportion_at_or_above[0.5] < report.proportion_at_or_above[0.5]
        assert v.proportion_at_or_above == v.status_proportion_at_or_above
        assert v.age_s == pytest.approx(0.0) and v.link == "up" and v.frames_used == 40


def test_one_vehicle_only_and_ages():
    pub = TinyPublisher("uav2")
    w = Watcher(vehicle="uav1")
    link = Link(pub, w)
    link.fly(5)
    assert w.feeds == {}
    w2 = Watcher()
    assert w2.on_alive("uav3", True, 1.0) == [QuerySnapshot("uav3")]
    assert w2.report(5.0).vehicles[0].age_s is None
    w2.on_snapshot_failed("uav3", 2.0)
    assert w2.poll(2.1) == [QuerySnapshot("uav3")]  # failed replies are asked again
    assert w2.poll(2.2) == []


def test_no_vehicle_after_connecting_says_why_once_then_not_once_one_is_heard():
    from pdcov.ground.watcher import Watcher

    w = Watcher(quiet_hint="this session: client", quiet_after_s=10.0)
    assert not w.report(100.0).station  # not connected yet
    w.on_connected(100.0)
    assert not w.report(109.9).station
    assert w.report(110.0).station == (
        "no vehicle heard 10 s after connecting; this session: client (still waiting for "
        "pdcov/*/)",)
    assert w.report(300.0).station == w.report(110.0).station  # one line: --plain says it once
    w.on_alive("uav1", True, 111.0)
    assert not w.report(120.0).station
