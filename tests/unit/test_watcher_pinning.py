"""The watcher against a hostile participant on an open bus, in memory (ground/watcher.py,
ground/claims.py): each vehicle pinned to the session that answers its snapshot, forged
tiles and statuses from other sessions refused, contested vehicles not trusted, the status
cross-checked against the rebuilt grid, bounded vehicles, counts that cannot overflow, and
the ground station's headline threshold. Sessions are hex ids as Zenoh gives them."""

from __future__ import annotations

import numpy as np

from pdcov.bus.errors import BusPayloadError, Refusal
from pdcov.bus.grid_state import GridState, decode_snapshot, grid_hash
from pdcov.bus.status import decode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles
from pdcov.core.grid_layer import Layer
from pdcov.ground.watcher import QuerySnapshot, Watcher
from tests.support.watch_fixtures import TinyPublisher, forged_tiles

DAEMON = "a1" * 16
ROGUE = "e7" * 16
RESTARTED = "b2" * 16


class Bus:
    """One vehicle's daemon (session DAEMON) and a watcher; snapshot queries are answered
    by the sessions in ``answering`` (the daemon's by default)."""

    def __init__(self, watcher: Watcher | None = None, vehicle_id: str = "uav1") -> None:
        self.pub = TinyPublisher(vehicle_id)
        self.w = watcher or Watcher()
        self.session = DAEMON
        self.answering: dict[str, TinyPublisher] = {}
        self.now_s = 0.0
        self.queries = 0

    def do(self, actions) -> None:
        for a in actions:
            assert isinstance(a, QuerySnapshot)
            self.queries += 1
            answers = self.answering or {self.session: self.pub}
            replies = [(s, decode_snapshot(p.snapshot())) for s, p in answers.items()]
            self.do(self.w.on_snapshot_replies(a.vehicle_id, replies, self.now_s))

    def fly(self, frames: int) -> None:
        for k in range(frames):
            self.pub.step()
            self.now_s += 0.25
            payload = self.pub.tiles()
            if payload is not None:
                self.tiles(payload, self.session)
            if k % 4 == 0:
                self.status(self.pub.status(), self.session)
            self.do(self.w.poll(self.now_s))

    def tiles(self, payload: bytes, session: str | None) -> None:
        self.do(self.w.on_tiles(self.pub.vehicle_id, decode_tiles(payload), self.now_s,
                                session))

    def status(self, payload: bytes, session: str | None) -> None:
        self.do(self.w.on_status(self.pub.vehicle_id, decode_status(payload), self.now_s,
                                 session))

    @property
    def feed(self):
        return self.w.feeds[self.pub.vehicle_id]


def same_grid(state: GridState, pub: TinyPublisher) -> bool:
    g = pub.grid
    return (np.array_equal(state.log_miss_d, g.log_miss_d)
            and np.array_equal(state.n_obs, g.n_obs))


def test_forged_tiles_from_another_session_are_refused_and_shown():
    bus = Bus()
    bus.fly(20)
    # The rogue's message is the vehicle's next one: same hash, next seq, every cell 1.
    for session in (ROGUE, None):
        bus.tiles(forged_tiles(bus.pub, bus.pub.seq + 1), session)
    assert same_grid(bus.feed.state, bus.pub)
    bus.fly(10)  # the daemon's own next tiles still apply (the forged seq did not take it)
    assert same_grid(bus.feed.state, bus.pub)
    v = bus.w.report(bus.now_s).vehicles[0]
    assert v.session == DAEMON[:8] and v.refused == 2 and not v.contested
    assert set(v.rivals) == {ROGUE[:8], "?"}
    assert any("also claims" in line for line in bus.w.report(bus.now_s).warnings)
    assert v.proportion_at_or_above == v.status_proportion_at_or_above


def test_a_rogue_status_is_refused_and_rechecks_are_rate_limited():
    bus = Bus(Watcher(snapshot_timeout_s=5.0))
    bus.fly(8)
    queries = bus.queries
    lie = TinyPublisher("uav1")  # claims an empty grid, another uptime
    for _ in range(40):  # 10 s of rogue statuses at 4 Hz
        bus.now_s += 0.25
        bus.status(lie.status(), ROGUE)
    # One claim check per recheck_s (10 s), each answered by the daemon alone: kept.
    assert bus.queries - queries == 1
    assert bus.feed.claim.session == DAEMON and bus.feed.status_session == DAEMON
    assert same_grid(bus.feed.state, bus.pub)


def test_two_sessions_answering_one_snapshot_query_contest_the_vehicle():
    bus = Bus()
    bus.answering = {DAEMON: bus.pub, ROGUE: TinyPublisher("uav1")}
    bus.fly(4)
    report = bus.w.report(bus.now_s)
    v = report.vehicles[0]
    assert v.contested and not v.grid_ready and set(v.rivals) == {DAEMON[:8], ROGUE[:8]}
    assert report.merged == () and bus.w.fleet_state() == (None, ())
    assert any("not trusted" in line for line in report.warnings)
    # While contested, nobody's tiles or status apply; the query is made again.
    bus.answering = {}  # the rogue went away: the next query has one answer
    bus.now_s += 5.0
    bus.fly(4)
    v = bus.w.report(bus.now_s).vehicles[0]
    assert not v.contested and v.grid_ready and v.session == DAEMON[:8]
    assert same_grid(bus.feed.state, bus.pub)


def test_a_rogue_answering_first_is_replaced_only_by_contest_not_silently():
    bus = Bus()
    rogue = TinyPublisher("uav1")
    bus.answering = {ROGUE: rogue}
    bus.fly(1)
    assert bus.feed.claim.session == ROGUE  # nobody else answered: the rogue is pinned
    bus.answering = {ROGUE: rogue, DAEMON: bus.pub}
    bus.fly(60)  # the daemon's samples are refused, and the recheck finds two sessions
    v = bus.w.report(bus.now_s).vehicles[0]
    assert v.contested and not v.grid_ready


def test_a_restarted_daemon_in_a_new_session_is_followed():
    bus = Bus()
    bus.fly(20)
    bus.pub, bus.session = TinyPublisher("uav1"), RESTARTED  # new process, new session
    bus.fly(60)
    assert bus.feed.claim.session == RESTARTED
    assert same_grid(bus.feed.state, bus.pub)
    assert bus.w.report(bus.now_s).vehicles[0].session == RESTARTED[:8]


def test_forged_tiles_in_the_daemons_session_are_caught_by_the_status_check():
    # A modified Zenoh can stamp the daemon's session id: the pin does not see it, the
    # daemon's own status does, within a few statuses (the forged seq makes the daemon's
    # next tiles look like a duplicate, so the frames only meet again after it).
    bus = Bus()
    bus.fly(20)
    bus.tiles(forged_tiles(bus.pub, bus.pub.seq + 1, frames=bus.pub.grid.frames), DAEMON)
    assert not same_grid(bus.feed.state, bus.pub)
    assert bus.w.report(bus.now_s).vehicles[0].proportion_at_or_above[0.8] == 1.0
    queries = bus.queries
    bus.fly(12)
    v = bus.w.report(bus.now_s).vehicles[0]
    assert v.status_disagreements == 1 and bus.queries == queries + 1
    assert same_grid(bus.feed.state, bus.pub) and v.status_agrees is True
    assert v.proportion_at_or_above == v.status_proportion_at_or_above


def test_a_status_ahead_of_its_tiles_is_not_a_disagreement():
    bus = Bus()
    bus.fly(12)
    bus.pub.step(2)  # frames added, tiles not yet sent
    bus.status(bus.pub.status(), DAEMON)
    assert bus.feed.status_disagreements == 0
    bus.tiles(bus.pub.tiles(), DAEMON)
    bus.status(bus.pub.status(), DAEMON)
    assert bus.feed.status_disagreements == 0 and bus.feed.status_agrees is True


def test_an_update_that_fails_against_a_fresh_snapshot_is_dropped_not_replayed():
    # The red team's 83 bytes: the vehicle's hash, another geometry, frames 2^32 - 1, sent
    # before the snapshot. It used to be replayed after every snapshot, forever.
    bus = Bus()
    g = bus.pub.grid
    other = GridState.empty(type(g.geometry)(g.geometry.x0_m, g.geometry.y0_m,
                                             g.geometry.cell_size_m, 30, 30),
                            np.ones((30, 30), bool))
    other.frames = 2**32 - 1
    payload = encode_tiles(other, [(0, 0)], seq=1, t_s=0.0, tile_size=8,
                           grid_hash=grid_hash(g.geometry, g.mask))
    bus.tiles(payload, DAEMON)  # asks for the snapshot; kept while the reply is awaited
    assert bus.queries == 1 and bus.feed.state is not None
    assert bus.feed.awaiting_since_s is None and bus.feed.bad_payloads == 1
    bus.fly(20)
    assert bus.queries == 1 and same_grid(bus.feed.state, bus.pub)


def test_provisional_samples_of_a_session_the_snapshot_did_not_pin_are_dropped():
    bus = Bus()
    rogue = TinyPublisher("uav1")
    rogue.step(30)
    bus.status(rogue.status(), ROGUE)  # first contact: asks for the snapshot ...
    assert bus.feed.claim.session == DAEMON  # ... which only the daemon answered
    assert bus.feed.status is None  # the rogue's figures are not shown as the vehicle's


def test_a_refused_payload_makes_no_vehicle_row_and_vehicles_are_bounded():
    w = Watcher(max_vehicles=3)
    w.on_bad_payload("ghost", BusPayloadError("pdcov/ghost/status: not JSON",
                                              Refusal.MALFORMED))
    assert w.feeds == {} and w.report(0.0).refused == {"payloads: malformed": 1}
    for k in range(10):
        w.on_alive(f"fake{k}", True, float(k))
    assert sorted(w.feeds) == ["fake0", "fake1", "fake2"]
    assert w.report(10.0).refused == {"payloads: malformed": 1,
                                      "vehicles beyond the limit of 3": 7}


def test_merged_counts_cannot_overflow():
    w = Watcher()
    pubs = [TinyPublisher("uav1"), TinyPublisher("uav2")]
    for p in pubs:
        state = decode_snapshot(p.snapshot())
        state.write(Layer.N_OBS, (0, state.geometry.n_rows, 0, state.geometry.n_cols), 2**31 - 1)
        w.on_snapshot(p.vehicle_id, state, 0.0, DAEMON + p.vehicle_id)
    merged, ids = w.fleet_state()
    assert ids == ("uav1", "uav2") and int(merged.n_obs.min()) == 2**32 - 2


def test_the_headline_threshold_is_the_ground_stations():
    w = Watcher(thresholds=(0.5, 0.8))
    bus = Bus(w)
    bus.fly(8)
    doc = decode_status(bus.pub.status())  # a vehicle (or a rogue) configured higher
    doc["thresholds"] = [0.5, 0.99]
    doc["proportion_at_or_above"] = {"0.5": 0.1, "0.99": 0.0}
    w.on_status("uav1", doc, bus.now_s, DAEMON)
    report = w.report(bus.now_s)
    assert report.target == 0.8 and 0.99 in report.thresholds


def test_fake_vehicles_on_another_grid_do_not_swing_the_fleet_map():
    real = TinyPublisher("uav9")
    w = Watcher(grid_hash=grid_hash(real.grid.geometry, real.grid.mask))
    w.on_snapshot("uav9", decode_snapshot(real.snapshot()), 0.0, DAEMON)
    g = real.grid.geometry
    fake = GridState.empty(type(g)(g.x0_m + 1000.0, g.y0_m, g.cell_size_m, g.n_rows, g.n_cols),
                           real.grid.mask)
    for k in range(3):  # more fakes than real vehicles, ids sorting first
        w.on_snapshot(f"aaa{k}", fake, 1.0 + k, ROGUE)
    assert w.fleet_state()[1] == ("uav9",)
    # Without the ground station's grid, most vehicles win; ties go to the first heard.
    w2 = Watcher()
    w2.on_snapshot("uav9", decode_snapshot(real.snapshot()), 0.0, DAEMON)
    w2.on_snapshot("aaa0", fake, 1.0, ROGUE)
    assert w2.fleet_state()[1] == ("uav9",)


def test_the_grids_nearing_the_memory_limit_are_warned_of():
    """No cap per vehicle but memory: past half of what the ground station may use, the
    report says how much the grids take, of what, and what to do."""
    pub = TinyPublisher("uav1")
    pub.step(5)
    state = decode_snapshot(pub.snapshot())
    w = Watcher(memory_limit=(5 * state.nbytes, "MemAvailable in /proc/meminfo"))
    w.on_snapshot("uav1", state, 0.0, DAEMON)
    assert not any("grids take" in line for line in w.report(1.0).warnings)
    assert w.grid_bytes() == state.nbytes + w.fleet.state.nbytes  # the vehicle's, the merge
    w.memory_limit = (3 * state.nbytes, "MemAvailable in /proc/meminfo")
    line, = (line for line in w.report(1.0).warnings if "grids take" in line)
    assert "of the" in line and "MemAvailable in /proc/meminfo" in line
    assert "--vehicle" in line
