"""The queries the watcher's decisions (ground/watcher.py) ask its shell (ground/live.py)
to make, each for one vehicle; the shell hands the replies back to the Watcher."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["QueryCandidates", "QueryMission", "QuerySnapshot"]


@dataclass(frozen=True, slots=True)
class QuerySnapshot:
    """Action: query ``pdcov/<vehicle_id>/snapshot`` and hand the reply to on_snapshot
    (or on_snapshot_failed)."""

    vehicle_id: str


@dataclass(frozen=True, slots=True)
class QueryMission:
    """Action: query ``pdcov/<vehicle_id>/mission`` and hand the reply to on_mission (or
    on_mission_failed)."""

    vehicle_id: str


@dataclass(frozen=True, slots=True)
class QueryCandidates:
    """Action: query ``pdcov/<vehicle_id>/candidates`` and hand the replies to
    on_candidates_replies."""

    vehicle_id: str
