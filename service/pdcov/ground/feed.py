"""What the watcher holds about one vehicle: its rebuilt grid, its last status, the tiles
awaiting a snapshot, the session that speaks for it (ground/claims.py), its track and
mission, and the counts the reports show. Mutable, owned by the Watcher."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from pdcov.bus.grid_state import GridState
from pdcov.bus.mission import MissionGeometry
from pdcov.bus.sources import SessionId
from pdcov.bus.tiles import TileUpdate
from pdcov.ground.claims import SessionClaim

__all__ = ["VehicleFeed"]


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
