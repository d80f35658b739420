"""The watcher's decisions, with no I/O: decoded payloads and ``now_s`` in, grids and
actions out (the asyncio/Zenoh shell in ground/live.py does the I/O).

Per vehicle it rebuilds the daemon's grid exactly (docs/protocol.md "Joining late";
ground/grid_sync.py): it asks for the snapshot on first contact and again after a gap, a
restart or a status that disagrees, and applies the tiles in sequence.

Each vehicle's mission geometry (docs/protocol.md "mission") is asked for once its grid
hash is known (first status, or snapshot) and again whenever that hash changes; a failed or
stale reply is asked again after ``mission_retry_s``.

Each vehicle's detections (docs/protocol.md "detections") add and update its pins, kept
by ``uid`` (ground/findings.py). The whole candidate list (queryable ``candidates``) is
asked for whenever a snapshot is taken (first contact, and after every gap or restart:
detections carry no sequence number, so the snapshot's resynchronisation is theirs too),
again after ``mission_retry_s`` when it did not come, and every ``candidates_refresh_s``
after an answer: a put carries only the candidates its detections touched, so a pin looked
at again without a hit shows its p_person falling with the next refresh.

Each vehicle is pinned to the Zenoh session that answers its snapshot (ground/claims.py):
status, tiles, mission, footprint and detections from any other session are refused and
counted, and a snapshot query answered by two sessions leaves the vehicle contested (not
trusted, shown).

The fleet grid adds the log-miss sums of the vehicles that share one grid (DESIGN.md: grids
merge by adding): the ground station's mission grid when it has one, else the grid most
vehicles share (ties: the vehicle heard first). ``now_s`` is the watcher's own monotonic
clock in seconds. What it holds per vehicle is ground/feed.py, what it reports
ground/fleet_report.py, who speaks for a vehicle ground/claims.py, the queries it asks its
shell to make ground/queries.py.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Any

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState
from pdcov.bus.mission import MissionGeometry
from pdcov.bus.sources import SessionId
from pdcov.bus.status import merge_status
from pdcov.bus.tiles import TileUpdate
from pdcov.ground.claims import ClaimVerdict
from pdcov.ground.feed import VehicleFeed
from pdcov.ground.findings import (
    MAX_CANDIDATES_KEPT,
    MAX_DETECTIONS_KEPT,
    DetectionLog,
    settle_provisional,
    take_findings,
)
from pdcov.ground.fleet_merge import FleetMerge, PdBlocks
from pdcov.ground.fleet_report import FleetReport, union_thresholds, vehicle_report
from pdcov.ground.grid_sync import (
    apply_in_order,
    ensure_grid,
    replay_pending,
    requery,
    sync_status,
    take_snapshot,
)
from pdcov.ground.queries import QueryCandidates, QueryMission, QuerySnapshot
from pdcov.ground.roster import NOT_ON_ROSTER, Roster

__all__ = ["MAX_VEHICLES", "Watcher"]

MAX_VEHICLES = 64
"""Vehicles a watcher follows at most; ids beyond it are refused and counted (a rogue on an
open bus could otherwise invent vehicles without end)."""
MEMORY_WARNING_SHARE = 0.5
"""The grids held may take this share of the memory the ground station may use before the
report warns (``Watcher.memory_limit``)."""


class Watcher:
    """Per-vehicle grids rebuilt from status, tiles and snapshot replies, and the fleet.

    vehicle: the one vehicle id to follow, or None for all. thresholds: the ground
    station's (the mission config's): shown until a vehicle's status gives its own, and the
    largest is the headline target whatever a vehicle says. grid_hash: the ground station's
    mission grid (bus.grid_state.grid_hash), which the fleet map shows when vehicles fly
    several grids. snapshot_timeout_s: ask again when a snapshot reply has not come in this
    long. trailing_gap_s: how long a status may announce a tiles sequence number not yet
    received before the snapshot is asked again. candidates_refresh_s: how often the candidates are
    asked again once answered (module docstring). mission_retry_s: when to ask again for a
    mission that did not come or describes another grid than the vehicle's. max_vehicles:
    vehicles followed at most. bus_warning: what the operator must always be told about the
    bus (bus.session.BusSecurity.warning), or None. quiet_hint: why no vehicle may be heard
    on this session (bus.session.quiet_hint), shown once the session has been connected
    quiet_after_s without any vehicle. max_candidates, max_detections: kept per vehicle
    (module docstring). roster: the vehicles merged (ground/roster.py; None: all).
    detection_log: where every detection taken goes (module docstring; None: nowhere).

    Every input takes the Zenoh session it came from (``source``: hex session id, None
    when the sample named none; ground/claims.py).
    """

    def __init__(self, vehicle: str | None = None, *, thresholds: tuple[float, ...] = (),
                 grid_hash: str | None = None, snapshot_timeout_s: float = 5.0,
                 trailing_gap_s: float = 3.0, max_track_points: int = 20_000,
                 mission_retry_s: float = 10.0, candidates_refresh_s: float = 30.0,
                 max_vehicles: int = MAX_VEHICLES,
                 bus_warning: str | None = None, quiet_hint: str | None = None,
                 quiet_after_s: float = 10.0, max_candidates: int = MAX_CANDIDATES_KEPT,
                 max_detections: int = MAX_DETECTIONS_KEPT, roster: Roster | None = None,
                 detection_log: DetectionLog | None = None,
                 memory_limit: tuple[int, str] | None = None) -> None:
        self.vehicle = vehicle
        self.memory_limit = memory_limit
        self.thresholds = tuple(thresholds)
        self.grid_hash = grid_hash
        self.snapshot_timeout_s = snapshot_timeout_s
        self.trailing_gap_s = trailing_gap_s
        self.mission_retry_s = mission_retry_s
        self.candidates_refresh_s = candidates_refresh_s
        self.max_track_points = max_track_points
        self.max_vehicles = max_vehicles
        self.bus_warning = bus_warning
        self.max_candidates = max_candidates
        self.max_detections = max_detections
        self.detection_log = detection_log
        self.quiet_hint = quiet_hint
        self.quiet_after_s = quiet_after_s
        self.connected_s: float | None = None
        """When the session was open and subscribed (on_connected), None before."""
        self.feeds: dict[str, VehicleFeed] = {}
        self.refused: Counter[str] = Counter()
        """Payloads refused before reaching a vehicle, by reason."""
        self.roster, self.unknown = roster or Roster(), Counter[str]()  # ids not on it
        self.fleet = FleetMerge()
        """The fleet's merged grid as of the last report (ground/fleet_merge.py)."""

    # -- inputs -------------------------------------------------------------------------

    def on_connected(self, now_s: float) -> None:
        """The session is open and subscribed: vehicles can be heard from now on."""
        self.connected_s = now_s

    def wants(self, vehicle_id: str) -> bool:
        return self.vehicle is None or vehicle_id == self.vehicle

    def on_alive(self, vehicle_id: str, alive: bool, now_s: float) -> list[QuerySnapshot]:
        """A liveliness token appeared (alive) or went away."""
        feed = self._feed(vehicle_id, now_s) if self.wants(vehicle_id) else None
        if feed is None:
            return []
        feed.alive = alive
        return ensure_grid(feed, now_s) if alive else []

    def on_status(self, vehicle_id: str, doc: dict[str, Any], now_s: float,
                  source: SessionId = None) -> list[QuerySnapshot]:
        """A decoded status (bus.status.decode_status) from session ``source``."""
        feed, refused = self._take(vehicle_id, "status", source, now_s)
        if feed is None:
            return refused
        previous = feed.status
        feed.status = doc = merge_status(previous, doc)
        feed.status_session = source
        pose = doc.get("pose")
        if isinstance(pose, dict):
            self._add_track_point(feed, pose)
        return ensure_grid(feed, now_s) or sync_status(feed, previous, doc, now_s)

    def on_tiles(self, vehicle_id: str, update: TileUpdate, now_s: float,
                 source: SessionId = None) -> list[QuerySnapshot]:
        """A decoded tiles message (bus.tiles.decode_tiles) from session ``source``."""
        feed, refused = self._take(vehicle_id, "tiles", source, now_s)
        if feed is None:
            return refused
        if feed.state is None or feed.awaiting_since_s is not None:
            feed.pending.append((update, source))
            return ensure_grid(feed, now_s)
        return apply_in_order(feed, update, now_s)

    def on_snapshot(self, vehicle_id: str, state: GridState, now_s: float,
                    source: SessionId = None) -> list[QuerySnapshot]:
        """A decoded snapshot reply (bus.grid_state.decode_snapshot), the only one its
        query received."""
        return self.on_snapshot_replies(vehicle_id, [(source, state)], now_s)

    def on_snapshot_replies(self, vehicle_id: str,
                            replies: Sequence[tuple[SessionId, GridState]], now_s: float
                            ) -> list[QuerySnapshot]:
        """Every decoded reply one snapshot query received, with its replier's session.
        Replies from two or more sessions contest the vehicle: no grid is trusted and the
        query is made again after snapshot_timeout_s."""
        feed = self._feed(vehicle_id, now_s) if self.wants(vehicle_id) else None
        if feed is None or not replies:
            return [] if feed is None else self.on_snapshot_failed(vehicle_id, now_s)
        self._touch(feed, "snapshot", now_s)
        if not feed.claim.on_answers({s for s, _ in replies}, now_s):
            feed.take_state(None)
            feed.pending = []
            feed.awaiting_since_s = now_s
            return []
        session, state = replies[0]
        take_snapshot(feed, state)
        # What came before the pin from another session was provisional: dropped.
        if feed.status_session != session:
            feed.status = None
        if feed.mission_session != session:
            feed.mission, feed.mission_asked_for = None, None
        if feed.footprint_session != session:
            feed.footprint = None
        settle_provisional(feed, session, self.detection_log)
        return replay_pending(feed, state, session, now_s)

    def on_snapshot_failed(self, vehicle_id: str, now_s: float) -> list[QuerySnapshot]:
        """No usable snapshot reply came (timeout, no queryable, bad payload): ask again at
        the next poll after snapshot_timeout_s."""
        feed = self.feeds.get(vehicle_id)
        if feed is not None and feed.awaiting_since_s is not None:
            feed.awaiting_since_s = min(feed.awaiting_since_s, now_s - self.snapshot_timeout_s)
        return []

    def on_footprint(self, vehicle_id: str, doc: dict[str, Any], now_s: float,
                     source: SessionId = None) -> None:
        """A decoded footprint reply (bus.footprint.decode_footprint)."""
        feed = self._trusted(vehicle_id, source, now_s)
        if feed is not None:
            self._touch(feed, "footprint", now_s).footprint = doc
            feed.footprint_session = source

    def on_mission(self, vehicle_id: str, mission: MissionGeometry, now_s: float,
                   source: SessionId = None) -> None:
        """A decoded mission reply (bus.mission.decode_mission). Kept even when it describes
        another grid than the vehicle's (the daemon may be restarting): ``mission_for``
        matches by grid hash, and such a reply is asked again after mission_retry_s."""
        feed = self._trusted(vehicle_id, source, now_s)
        if feed is None:
            if vehicle_id in self.feeds:
                self.on_mission_failed(vehicle_id, now_s)
            return
        self._touch(feed, "mission", now_s)
        feed.mission, feed.mission_session = mission, source
        stale = mission.grid_hash != self._grid_hash(feed)
        feed.mission_retry_at_s = now_s + self.mission_retry_s if stale else None

    def on_mission_failed(self, vehicle_id: str, now_s: float) -> None:
        """No usable mission reply (timeout, no queryable: an older daemon, bad payload):
        ask again after mission_retry_s."""
        feed = self.feeds.get(vehicle_id)
        if feed is not None:
            feed.mission_retry_at_s = now_s + self.mission_retry_s

    def on_detections(self, vehicle_id: str, doc: dict[str, Any], now_s: float,
                      source: SessionId = None) -> None:
        """A decoded detections payload (bus.detections.decode_detections): its new
        detections and the candidates they touched. Refused (counted in the claim) from a
        session other than the pinned one."""
        feed = self._trusted(vehicle_id, source, now_s)
        if feed is None:
            return
        self._touch(feed, "detections", now_s)
        feed.detections_session = source
        take_findings(feed, doc, self.max_candidates, self.max_detections,
                      self.detection_log)

    def on_candidates_replies(self, vehicle_id: str,
                              replies: Sequence[tuple[SessionId, dict[str, Any]]],
                              now_s: float) -> None:
        """Every decoded reply of one candidates query (a detections document holding all
        the vehicle's candidates): the trusted session's update the pins held (by uid); none
        (timeout, an older daemon, only other sessions) asks again after mission_retry_s, an
        answer after candidates_refresh_s."""
        feed = self.feeds.get(vehicle_id) if self.wants(vehicle_id) else None
        if feed is None:
            return
        feed.candidates_done_at = feed.candidates_asked_at
        for source, doc in replies:
            if self._trusted(vehicle_id, source, now_s) is None:
                continue
            self._touch(feed, "candidates", now_s)
            feed.detections_session = source
            feed.candidates_retry_at_s = now_s + self.candidates_refresh_s
            take_findings(feed, doc, self.max_candidates, self.max_detections,
                          self.detection_log)
            return
        feed.candidates_retry_at_s = now_s + self.mission_retry_s

    def candidates_due(self, now_s: float) -> list[QueryCandidates]:
        """Candidates queries to make now: once after each snapshot taken, again every
        mission_retry_s until one is answered, then every candidates_refresh_s."""
        due = []
        for feed in self.feeds.values():
            if feed.state is None or feed.awaiting_since_s is not None:
                continue
            retry = feed.candidates_retry_at_s
            if feed.candidates_asked_at != feed.snapshots or (
                    retry is not None and now_s >= retry):
                feed.candidates_asked_at, feed.candidates_retry_at_s = feed.snapshots, None
                due.append(QueryCandidates(feed.vehicle_id))
        return due

    def missions_due(self, now_s: float) -> list[QueryMission]:
        """Mission queries to make now: for a vehicle whose grid hash is known and whose
        mission does not describe it, once per hash, then every mission_retry_s."""
        due = []
        for feed in self.feeds.values():
            want = self._grid_hash(feed)
            if want is None or (feed.mission is not None and feed.mission.grid_hash == want):
                continue
            retry = feed.mission_retry_at_s
            if feed.mission_asked_for != want or (retry is not None and now_s >= retry):
                feed.mission_asked_for, feed.mission_retry_at_s = want, None
                due.append(QueryMission(feed.vehicle_id))
        return due

    def taken_from(self, vehicle_id: str, kind: str) -> SessionId | tuple[()]:
        """The session whose snapshot, mission or candidates reply the watcher holds for the
        vehicle, or () when it holds none (unknown, contested, refused)."""
        feed = self.feeds.get(vehicle_id)
        if feed is None:
            return ()
        if kind == "mission":
            return feed.mission_session if feed.mission is not None else ()
        if kind == "candidates":
            return feed.detections_session
        return feed.claim.session if feed.claim.pinned and feed.state is not None else ()

    def mission_for(self, grid_hash: str | None) -> MissionGeometry | None:
        """The mission geometry describing grid ``grid_hash`` (the first vehicle's by id),
        or with None any vehicle's; None when no vehicle sent one."""
        for feed in sorted(self.feeds.values(), key=lambda f: f.vehicle_id):
            m = feed.mission
            if m is not None and (grid_hash is None or m.grid_hash == grid_hash):
                return m
        return None

    def on_bad_payload(self, vehicle_id: str, error: BusPayloadError) -> None:
        """A payload that did not decode: counted by its reason, never applied, and no
        vehicle row is made for it."""
        feed = self.feeds.get(vehicle_id) if self.wants(vehicle_id) else None
        if feed is not None:
            feed.bad_payloads += 1
        self.refused[f"payloads: {error.reason.value}"] += 1

    def poll(self, now_s: float) -> list[QuerySnapshot]:
        """Timers: a snapshot reply overdue, or announced tiles that never came."""
        actions: list[QuerySnapshot] = []
        for feed in self.feeds.values():
            if feed.awaiting_since_s is not None:
                if now_s - feed.awaiting_since_s >= self.snapshot_timeout_s:
                    feed.awaiting_since_s = now_s
                    actions.append(QuerySnapshot(feed.vehicle_id))
            elif (feed.behind_since_s is not None
                  and now_s - feed.behind_since_s >= self.trailing_gap_s):
                feed.gaps += 1
                actions += requery(feed, now_s)
        return actions

    # -- outputs ------------------------------------------------------------------------

    def fleet_state(self) -> tuple[GridState | None, tuple[str, ...]]:
        """A copy of the merged grid of the ready vehicles that share the fleet's grid
        (log-miss sums added as float32, as the daemons hold them; counts added in int64,
        which cannot overflow; limiting factors by the maximum), and their ids (sorted). The
        fleet's grid is the ground station's (grid_hash) when a vehicle flies it, else the
        one most vehicles fly (ties: the vehicle heard first). The copy reads the whole
        grid: the report and the map read the merge kept (``fleet``) instead."""
        self.fleet.update(self.feeds.values(), self.grid_hash)
        merged = self.fleet.state
        return (None if merged is None else merged.copy()), self.fleet.ids

    def fleet_blocks(self) -> PdBlocks | None:
        """The merged grid's map blocks (ground/fleet_merge.py), brought up to date."""
        self.fleet.update(self.feeds.values(), self.grid_hash)
        return self.fleet.blocks()

    def report(self, now_s: float) -> FleetReport:
        """Every vehicle's figures and the fleet's, as of ``now_s``."""
        vehicles = tuple(vehicle_report(f, now_s, self.thresholds)
                         for f in sorted(self.feeds.values(), key=lambda f: f.vehicle_id))
        thresholds = union_thresholds([self.thresholds, *(v.thresholds for v in vehicles)])
        self.fleet.update(self.feeds.values(), self.grid_hash)
        summary = self.fleet.summary(thresholds)
        props: dict[float, float] = {}
        mean_pd = None
        cells_free = 0
        if summary is not None:
            props = {t: summary.proportion_at_or_above(t) for t in thresholds}
            cells_free = summary.cells_free
            mean_pd = summary.mean_pd
        target = max(self.thresholds or thresholds) if thresholds else None
        quiet = None
        if (self.quiet_hint and not self.feeds and self.connected_s is not None
                and now_s - self.connected_s >= self.quiet_after_s):
            # Its text never changes: --plain prints it once, and the watcher keeps waiting.
            quiet = (f"no vehicle heard {self.quiet_after_s:g} s after connecting; "
                     f"{self.quiet_hint} (still waiting for pdcov/{self.vehicle or '*'}/)")
        return FleetReport(vehicles, self.fleet.ids, thresholds, target, props, mean_pd, cells_free,
                           dict(self.refused),
                           tuple(w for w in (self.bus_warning, quiet, self._memory_warning())
                                 if w),
                           {vid: f"{NOT_ON_ROSTER} ({n} samples refused, not merged)"
                            for vid, n in sorted(self.unknown.items())},
                           tuple(n for n in (self.roster.notice,) if n))

    def grid_bytes(self) -> int:
        """Bytes the grids held take: every vehicle's tiles and the fleet's merge."""
        states = [f.state for f in self.feeds.values()] + [self.fleet.state]
        return sum(s.nbytes for s in states if s is not None)

    def _memory_warning(self) -> str | None:
        """What the operator must know before the grids outgrow this machine: there is no
        cap per vehicle but memory (``memory_limit``: what it may hold, and whence)."""
        if self.memory_limit is None:
            return None
        limit, whence = self.memory_limit
        held = self.grid_bytes()
        if held <= MEMORY_WARNING_SHARE * limit:
            return None
        return (f"the vehicles' grids take {held / 1e6:,.0f} MB, more than "
                f"{MEMORY_WARNING_SHARE:.0%} of the {limit / 1e6:,.0f} MB this ground station "
                f"may use ({whence}): as the search grows it may run out of memory; follow "
                "fewer vehicles (--vehicle) or a coarser grid")

    # -- internals ----------------------------------------------------------------------

    def _feed(self, vehicle_id: str, now_s: float) -> VehicleFeed | None:
        """The vehicle's feed, made on first contact; None (counted) when not on the roster
        or beyond max_vehicles."""
        feed = self.feeds.get(vehicle_id)
        if feed is None:
            if not self.roster.admits(vehicle_id):  # at most max_vehicles ids listed
                if vehicle_id in self.unknown or len(self.unknown) < self.max_vehicles:
                    self.unknown[vehicle_id] += 1
                else:
                    self.refused[f"{NOT_ON_ROSTER}, beyond {self.max_vehicles} ids"] += 1
                return None
            if len(self.feeds) >= self.max_vehicles:
                self.refused[f"vehicles beyond the limit of {self.max_vehicles}"] += 1
                return None
            feed = self.feeds[vehicle_id] = VehicleFeed(vehicle_id, first_heard_s=now_s)
        return feed

    def _take(self, vehicle_id: str, kind: str, source: SessionId, now_s: float
              ) -> tuple[VehicleFeed | None, list[QuerySnapshot]]:
        """The feed to apply a status or tiles sample to, or None when it is not wanted or
        refused (another session's); then the snapshot query a rival's sample may call
        for."""
        feed = self._feed(vehicle_id, now_s) if self.wants(vehicle_id) else None
        if feed is None:
            return None, []
        if feed.claim.verdict(source, now_s) is ClaimVerdict.REFUSE:
            if feed.claim.recheck_due(now_s):
                return None, requery(feed, now_s)
            return None, []
        return self._touch(feed, kind, now_s), []

    def _trusted(self, vehicle_id: str, source: SessionId, now_s: float) -> VehicleFeed | None:
        """The feed when a query reply (mission, footprint) from ``source`` may be taken:
        the pinned session's, or any uncontested one's before a snapshot pinned one."""
        feed = self.feeds.get(vehicle_id) if self.wants(vehicle_id) else None
        if feed is None or feed.claim.verdict(source, now_s) is ClaimVerdict.REFUSE:
            return None
        return feed

    @staticmethod
    def _touch(feed: VehicleFeed, kind: str, now_s: float) -> VehicleFeed:
        feed.last_msg_s = now_s
        feed.received[kind] += 1
        return feed

    @staticmethod
    def _grid_hash(feed: VehicleFeed) -> str | None:
        """The vehicle's grid hash as last announced (status), else of the grid held."""
        if feed.status is not None:
            return str(feed.status["grid"]["hash"])
        return feed.state.hash if feed.state is not None else None

    def _add_track_point(self, feed: VehicleFeed, pose: dict[str, Any]) -> None:
        try:
            lat, lon = float(pose["lat_deg"]), float(pose["lon_deg"])
            alt = float(pose.get("alt_msl_m") or 0.0)
            t = pose.get("t_s")
        except (KeyError, TypeError, ValueError):
            return
        if not (math.isfinite(lat) and math.isfinite(lon)) or (
                t is not None and t == feed.last_pose_t_s):
            return
        feed.last_pose_t_s = t
        feed.track_lat_lon_alt.append((lat, lon, alt))
        if len(feed.track_lat_lon_alt) > self.max_track_points:
            del feed.track_lat_lon_alt[: len(feed.track_lat_lon_alt) // 2: 2]  # thin the old
