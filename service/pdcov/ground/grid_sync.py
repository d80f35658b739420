"""Rebuilding a vehicle's grid exactly as its daemon holds it, with no I/O
(docs/protocol.md "Joining late"), in its ``VehicleFeed`` (ground/feed.py) for the
Watcher (ground/watcher.py); ``now_s`` the watcher's monotonic clock (s):

* first contact (liveliness, status or tiles) asks for the snapshot; tiles received
  while the reply is awaited are kept;
* a snapshot holding ``frames = F`` already contains every tiles message the daemon
  published with ``frames <= F`` (tiles carry current values of whole tiles, not
  increments, and a grid only changes when a frame is added), so the kept messages with
  ``frames <= F`` are dropped and the rest applied in sequence order;
* from then on tiles apply in order; a jump in ``seq``, a ``seq`` going back (the daemon
  restarted) or another grid hash asks for the snapshot again, and so does a status whose
  ``tiles_seq`` stays ahead of the last applied message for ``trailing_gap_s`` (the last
  messages of a flight were lost, so no later one reveals the gap).

A status of the pinned session is checked against the grid rebuilt from its tiles whenever
both describe the same frames; a disagreement beyond rounding is counted, shown and
answered by a fresh snapshot.
"""

from __future__ import annotations

from typing import Any

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState
from pdcov.bus.sources import SessionId
from pdcov.bus.tiles import TileUpdate, apply_tiles, tile_bounds
from pdcov.ground.feed import VehicleFeed
from pdcov.ground.fleet_report import status_agrees
from pdcov.ground.queries import QuerySnapshot

__all__ = ["apply_in_order", "ensure_grid", "replay_pending", "requery", "sync_status",
           "take_snapshot"]


def ensure_grid(feed: VehicleFeed, now_s: float) -> list[QuerySnapshot]:
    """The snapshot query of a vehicle whose grid is neither held nor awaited."""
    if feed.state is None and feed.awaiting_since_s is None:
        feed.awaiting_since_s = now_s
        return [QuerySnapshot(feed.vehicle_id)]
    return []


def requery(feed: VehicleFeed, now_s: float) -> list[QuerySnapshot]:
    """Ask for the snapshot again (the tiles kept dropped), unless one is awaited."""
    if feed.awaiting_since_s is not None:
        return []
    feed.awaiting_since_s = now_s
    feed.behind_since_s = None
    feed.pending = []
    return [QuerySnapshot(feed.vehicle_id)]


def sync_status(feed: VehicleFeed, previous: dict[str, Any] | None, doc: dict[str, Any],
                now_s: float) -> list[QuerySnapshot]:
    """Follow the vehicle's status ``doc`` (``previous``: the one it was merged into): a
    snapshot query when the daemon runs another grid or restarted, or when the status
    disagrees with the grid holding the same frames; the trailing gap's clock otherwise."""
    state = feed.state
    if state is not None and doc["grid"]["hash"] != feed.grid_hash:
        return requery(feed, now_s)  # the daemon now runs another mission
    if previous is not None and doc["uptime_s"] < previous["uptime_s"]:
        return requery(feed, now_s)  # the daemon restarted
    announced = doc["tiles_seq"]
    if feed.awaiting_since_s is not None:
        return []
    if state is not None and announced == feed.last_seq:
        # Caught up: the grid holds every tiles message this status counts.
        frames = doc["frames"]
        n = frames.get("grid", frames.get("used"))
        if isinstance(n, int) and n == state.frames and doc.get("tiles_behind") == 0:
            summary = feed.summary(tuple(map(float, doc["proportion_at_or_above"])))
            if summary is None or not status_agrees(summary, doc):
                feed.status_disagreements += 1
                feed.status_agrees = False
                return requery(feed, now_s)
            feed.status_agrees = True
        elif isinstance(n, int) and n > state.frames:
            # Frames added since the last tiles changed no cell, or their tiles are
            # still to come: either way the next status tells.
            state.frames = n
    if feed.last_seq is None and feed.seq_floor is None:
        feed.seq_floor = announced  # first status since the snapshot: no tiles owed yet
    known = feed.last_seq if feed.last_seq is not None else feed.seq_floor
    if known is not None and announced > known:
        if feed.behind_since_s is None:
            feed.behind_since_s = now_s
    else:
        feed.behind_since_s = None
    return []


def take_snapshot(feed: VehicleFeed, state: GridState) -> None:
    """Hold the snapshot reply ``state`` as the vehicle's grid, its tiles followed anew."""
    feed.take_state(state)
    feed.snapshots += 1
    feed.awaiting_since_s = None
    feed.behind_since_s = None
    feed.last_seq = None
    feed.seq_floor = None
    feed.status_agrees = None


def replay_pending(feed: VehicleFeed, state: GridState, session: SessionId, now_s: float
                   ) -> list[QuerySnapshot]:
    """Apply the tiles kept while the snapshot ``state`` of ``session`` was awaited: those
    it holds already dropped, the rest in sequence order."""
    pending, feed.pending = sorted(feed.pending, key=lambda u: u[0].seq), []
    for update, source in pending:
        if source != session or update.grid_hash != state.hash:
            continue  # another session's, or for another grid (before a restart)
        if update.frames <= state.frames:
            feed.last_seq = update.seq  # already inside the snapshot
            continue
        actions = apply_in_order(feed, update, now_s, after_snapshot=True)
        if actions:
            return actions
    return []


def apply_in_order(feed: VehicleFeed, update: TileUpdate, now_s: float, *,
                   after_snapshot: bool = False) -> list[QuerySnapshot]:
    """Apply the next tiles message in sequence; a gap or a message for another grid
    asks for the snapshot and keeps the message for after it, but one that fails
    against the snapshot just taken (``after_snapshot``) is dropped, never replayed."""
    state = feed.state
    if state is None:
        raise RuntimeError("apply_in_order without a grid")  # callers check; a bug if reached
    if feed.last_seq is not None:
        if update.seq == feed.last_seq:
            return []  # a duplicate
        if update.seq != feed.last_seq + 1:
            feed.gaps += 1
            actions = requery(feed, now_s)
            feed.pending.append((update, feed.claim.session))
            return actions
    try:
        apply_tiles(state, update, key=f"pdcov/{feed.vehicle_id}/tiles",
                    state_hash=feed.grid_hash)
    except BusPayloadError:
        feed.bad_payloads += 1  # another grid: the daemon restarted with a new mission
        if after_snapshot:
            return []
        actions = requery(feed, now_s)
        feed.pending.append((update, feed.claim.session))
        return actions
    feed.mark_changed([tile_bounds(t.tile_row, t.tile_col, update.tile_size,
                                   *state.geometry.shape) for t in update.tiles])
    feed.last_seq = update.seq
    status = feed.status
    if status is not None and status["tiles_seq"] <= update.seq:
        feed.behind_since_s = None
    return []
