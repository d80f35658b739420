"""What the watcher holds about one vehicle: its rebuilt grid (with its hash, its per-tile
metrics and the windows changed since the fleet's merge), its last status, the tiles
awaiting a snapshot, the session that speaks for it (ground/claims.py), its track and
mission, its detection candidates and recent detections, and the counts the reports show.
Mutable, owned by the Watcher."""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

from pdcov.bus.grid_state import GridState
from pdcov.bus.mission import MissionGeometry
from pdcov.bus.sources import SessionId
from pdcov.bus.tile_metrics import GridSummary, TileMetrics
from pdcov.bus.tiles import TileUpdate
from pdcov.core.geodesy import Origin
from pdcov.core.grid_layer import Window
from pdcov.ground.claims import SessionClaim

__all__ = ["METRICS_TILE_SIZE", "VehicleFeed"]

METRICS_TILE_SIZE = 32
"""Cells a side of the tiles the watcher keeps its metrics in (the daemons' bus.tile_size
by default: a tiles message marks whole tiles)."""


@dataclass(slots=True)
class VehicleFeed:
    """What the watcher holds about one vehicle (mutable, owned by the Watcher)."""

    vehicle_id: str
    state: GridState | None = None
    status: dict[str, Any] | None = None
    alive: bool | None = None
    last_msg_s: float | None = None
    awaiting_since_s: float | None = None
    pending: list[tuple[TileUpdate, SessionId]] = field(default_factory=list)
    status_session: SessionId = None  # the sessions the status, mission and footprint held
    mission_session: SessionId = None  # came from (ground/claims.py)
    footprint_session: SessionId = None
    last_seq: int | None = None
    seq_floor: int | None = None
    behind_since_s: float | None = None
    track_lat_lon_alt: list[tuple[float, float, float]] = field(default_factory=list)
    last_pose_t_s: float | None = None
    footprint: dict[str, Any] | None = None
    mission: MissionGeometry | None = None
    mission_asked_for: str | None = None  # the grid hash the last mission query was for
    mission_retry_at_s: float | None = None  # None while a query is out (or none needed)
    gaps: int = 0
    snapshots: int = 0
    bad_payloads: int = 0
    received: Counter[str] = field(default_factory=Counter)
    claim: SessionClaim = field(default_factory=SessionClaim)
    first_heard_s: float = 0.0
    status_disagreements: int = 0
    status_agrees: bool | None = None
    candidates: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Candidate entries of the detections payloads by uid (bus/detections.py), the latest
    of each, across the daemon's restarts; at most Watcher.max_candidates."""
    detections: deque[dict[str, Any]] = field(default_factory=deque)
    """The latest detection entries, at most Watcher.max_detections (oldest dropped; every
    one went to the Watcher's detection_log)."""
    detections_session: SessionId = None  # the session the latest findings came from
    provisional_uids: set[str] = field(default_factory=set)
    """Candidates taken before the first pin (Watcher: kept or dropped by it)."""
    unlogged: int = 0  # the newest detections held, taken before the first pin, not logged
    candidates_asked_at: int | None = None  # ``snapshots`` when candidates were last asked
    candidates_retry_at_s: float | None = None  # when to ask again; None while a query is out
    # ``snapshots`` when the last candidates query ended (answered or not): a report taken
    # after it holds the candidates the daemon had then.
    candidates_done_at: int | None = None
    candidates_dropped: int = 0  # candidates forgotten beyond max_candidates
    unmerged: set[Window] = field(default_factory=set, repr=False)
    """The windows written since the fleet merge last read them, of ``state`` or of the
    state it replaced (ground/fleet_merge.py)."""
    metrics: TileMetrics | None = field(default=None, repr=False)
    """``state``'s figures, per tile (None: none built yet)."""
    _hashed: tuple[GridState, str] | None = field(default=None, repr=False)
    """The state and its grid hash."""

    @property
    def grid_hash(self) -> str | None:
        """The hash of ``state`` (bus.grid_state.grid_hash; None without one), computed once
        per state held: it reads the whole mask, which never changes."""
        state = self.state
        if state is None:
            return None
        if self._hashed is None or self._hashed[0] is not state:
            self._hashed = (state, state.hash)
        return self._hashed[1]

    def take_state(self, state: GridState | None) -> None:
        """Hold ``state`` as the vehicle's grid, its metrics anew (the fleet merge tells the
        new grid by its identity)."""
        self.state, self.metrics, self._hashed = state, None, None

    def mark_changed(self, windows: list[Window]) -> None:
        """Cells of ``state`` in ``windows`` (r0, r1, c0, c1) were written (tiles applied)."""
        for window in windows:
            if self.metrics is not None:
                self.metrics.mark(window)
            self.unmerged.add(window)

    def summary(self, thresholds: tuple[float, ...]) -> GridSummary | None:
        """The figures of ``state`` (None without one) at ``thresholds`` among others,
        recomputing only the tiles written since the last call."""
        state = self.state
        if state is None:
            return None
        self.metrics = metrics_for(self.metrics, state, thresholds)
        return self.metrics.summary()

    def origin(self) -> Origin | None:
        """The origin of the vehicle's grid, as its last status gave it (None: none yet)."""
        o = ((self.status or {}).get("grid") or {}).get("origin") or {}
        try:
            return Origin(float(o["lat_deg"]), float(o["lon_deg"]),
                          float(o.get("ground_alt_msl_m") or 0.0))
        except (KeyError, TypeError, ValueError):
            return None


def metrics_for(metrics: TileMetrics | None, state: GridState, thresholds: tuple[float, ...]
                ) -> TileMetrics:
    """``metrics`` when they are of ``state`` and keep ``thresholds``, else new metrics of
    ``state`` (every tile to compute) for those and ``metrics``' thresholds."""
    if metrics is not None and metrics.source is state and \
            set(map(float, thresholds)) <= set(metrics.thresholds):
        return metrics
    kept = metrics.thresholds if metrics is not None else ()
    return TileMetrics(state, METRICS_TILE_SIZE, (*kept, *thresholds))
