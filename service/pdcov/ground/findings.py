"""A vehicle's findings as the watcher keeps them, with no I/O: its detection candidates
(pins) and its recent detections (docs/protocol.md "detections"), held in its
``VehicleFeed`` (ground/feed.py) for the Watcher (ground/watcher.py).

A candidate is kept by its ``uid`` (durable across the daemon's restarts), so a candidate
seen again, in a put or in a candidates reply, is updated in place, and the pins survive
the vehicle's session changing (a restarted daemon's restored candidates merge with those
held). At most ``max_candidates`` candidates per vehicle are kept (beyond, the least
probable, then the one with the fewest hits, then the oldest last detection, is forgotten
and counted). Every detection taken goes to ``detection_log`` (the recording's, on disk:
ground/record_exports.py) and the latest ``max_detections`` stay in memory for the views.
Findings taken before the vehicle's first snapshot reply pinned a session are provisional:
kept when the pin is their session's (their detections then logged, the latest
``max_detections`` of them), dropped otherwise.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from pdcov.bus.sources import SessionId
from pdcov.ground.feed import VehicleFeed

__all__ = ["MAX_CANDIDATES_KEPT", "MAX_DETECTIONS_KEPT", "DetectionLog",
           "settle_provisional", "take_findings"]

MAX_CANDIDATES_KEPT = 2000
"""Candidates kept per vehicle, fewer than a daemon may hold (bus/detections.py
MAX_CANDIDATES) because a ground station follows up to MAX_VEHICLES: a flight over a crowd,
or a detector gone wrong, must not grow it without end; the operator is told how many
were forgotten."""
MAX_DETECTIONS_KEPT = 500
"""Recent detections kept in memory per vehicle, for the views (every one goes to the
detection log: module docstring)."""

DetectionLog = Callable[[str, Sequence[dict[str, Any]]], None]
"""Called with (vehicle_id, detection entries) for every detection the watcher takes, in
the order taken; it must not raise (ground/record_exports.py DetectionLog)."""


def take_findings(feed: VehicleFeed, doc: dict[str, Any], max_candidates: int,
                  max_detections: int, detection_log: DetectionLog | None) -> None:
    """Keep a detections document's candidates (by uid, the latest) and detections
    (logged; the newest max_detections in memory), forgetting the least probable
    candidates beyond max_candidates; provisional before the first pin."""
    provisional = not feed.claim.pinned
    for c in doc.get("candidates") or ():
        feed.candidates[c["uid"]] = c
        if provisional:
            feed.provisional_uids.add(c["uid"])
    detections = doc.get("detections") or ()
    feed.detections.extend(detections)
    while len(feed.detections) > max_detections:
        feed.detections.popleft()
    if provisional:
        feed.unlogged = min(feed.unlogged + len(detections), len(feed.detections))
    elif detections and detection_log is not None:
        detection_log(feed.vehicle_id, detections)
    extra = len(feed.candidates) - max_candidates
    if extra > 0:
        weakest = sorted(feed.candidates.values(), key=lambda c: (
            c["p_person"], c["hits"], c["last_t_boot_s"]))[:extra]
        for c in weakest:
            del feed.candidates[c["uid"]]
        feed.candidates_dropped += extra


def settle_provisional(feed: VehicleFeed, session: SessionId,
                       detection_log: DetectionLog | None) -> None:
    """A snapshot reply pinned ``session``: the findings taken before are kept (and
    their detections logged) when they are its, else dropped."""
    if feed.detections_session == session:
        if feed.unlogged and detection_log is not None:
            held = list(feed.detections)
            detection_log(feed.vehicle_id, held[len(held) - feed.unlogged:])
    elif feed.provisional_uids or feed.unlogged:
        dropped = feed.provisional_uids
        for uid in dropped:
            feed.candidates.pop(uid, None)
        feed.detections = deque(d for d in feed.detections if d["uid"] not in dropped)
    feed.provisional_uids, feed.unlogged = set(), 0
