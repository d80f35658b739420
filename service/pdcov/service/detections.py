"""What the daemon does with the detector's boxes, with no I/O (docs/service.md
"Detections"): ``LiveDetections`` holds the boxes of the frames taken until each frame is
decided, gives a used frame's boxes with its pose (the one the grid took) to the
``DetectionTracker`` that ``pdcov evaluate`` runs too, and says when to publish.

Publishing (``pdcov/<id>/detections``): at most one message every DETECTIONS_PERIOD_S,
holding the detections new since the last one (at most bus.detections.MAX_DETECTIONS: the
rest go in the next) and the current state of the candidates they touched (their ids go
with it: the journal keeps them first, service/candidate_store.py); on a clean stop every
pending detection at once (``poll(..., force=True)``). The candidates query answers every
candidate.

Counted in the status's faults: ``boxes_of_skipped_frames`` (a frame taken, then skipped:
a telemetry gap, below min height, untrusted, ...), ``boxes_dropped_waiting`` (more than
MAX_HELD_BOXES boxes waiting for their frames: the oldest frame's go), and the tracker's
``boxes_off_ground`` and ``boxes_over_candidates``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pdcov.bus.detections import MAX_DETECTIONS, detections_document, encode_detections
from pdcov.bus.faults import Fault
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, Candidate, Detection
from pdcov.core.geodesy import Origin
from pdcov.core.geolocate import PositionAccuracy
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.core.utc_clock import UtcClock
from pdcov.detection.candidates import DetectionTracker

if TYPE_CHECKING:
    from pdcov.config.mission import Mission

DETECTIONS_PERIOD_S = 1.0
"""At most one detections message in this long (daemon's monotonic clock, s)."""
MAX_HELD_BOXES = 100_000
"""Boxes kept for frames not decided yet (a detector's frames from a clock the telemetry
never reaches are never decided)."""


@dataclass(frozen=True, slots=True)
class Publication:
    """A detections message to publish and the ids of the candidates it carries."""

    payload: bytes
    candidate_ids: tuple[int, ...]


class LiveDetections:
    """The daemon's boxes (module docstring). ``faults``: the counter the status reports;
    ``uid_prefix``: the candidates' (ids.candidate_uid_prefix)."""

    def __init__(self, mission: Mission, grid: CoverageGrid, faults: Counter,
                 uid_prefix: str) -> None:
        """``grid``: the published grid (the candidates' P_D and P_FA)."""
        self.vehicle_id = mission.vehicle_id
        self.grid = grid
        self.tracker = DetectionTracker.for_mission(mission, uid_prefix)
        self.faults = faults
        self._held: dict[float, tuple[float, tuple[Box, ...]]] = {}  # frame t_s -> boxes
        self._n_held = 0
        self._new: list[Detection] = []
        self.latest: dict[int, Candidate] = {}
        """Each candidate as last published or answered (the status's pins summary)."""
        self._next_s = -math.inf
        self.utc = UtcClock()
        """The autopilot's real-time clock (its UTC samples), which stamps each frame's
        detections as ``pdcov evaluate`` stamps them from the log."""

    def hold(self, t_s: float, t_boot_s: float, boxes: tuple[Box, ...]) -> None:
        """The boxes of a frame taken at ``t_s`` (the grid's frame time, s), which the
        detector stamped ``t_boot_s``."""
        if not boxes:
            return
        self._held[t_s] = (t_boot_s, boxes)
        self._n_held += len(boxes)
        while self._n_held > MAX_HELD_BOXES:
            oldest = min(self._held)
            dropped = len(self._held.pop(oldest)[1])
            self._n_held -= dropped
            self.faults[Fault.BOXES_DROPPED_WAITING] += dropped

    def frame(self, pose: CameraPose, camera: CameraModel | None = None,
              accuracy: PositionAccuracy | None = None, *, grid: CoverageGrid) -> None:
        """``grid`` (the primary camera's own) took the frame at ``pose.t_s`` with ``pose``
        (and ``camera``, a zoomed lens; None: the mission's; ``accuracy``: the position
        accuracy the autopilot reported, None: unknown): its boxes geolocated, its looks
        counted for the candidates (a frame without boxes too: its looks are misses)."""
        held = self._held.pop(pose.t_s, None)
        if held is not None:
            self._n_held -= len(held[1])
        t_boot_s, boxes = held if held is not None else (pose.t_s, ())
        before = Counter(self.tracker.skipped)
        self._new += self.tracker.frame(pose, t_boot_s, boxes, camera=camera,
                                        accuracy=accuracy, grid=grid,
                                        unix_s=self.utc.unix_s(pose.t_s))
        self.faults.update(self.tracker.skipped - before)

    def decided(self, last_frame_t_s: float) -> None:
        """Frames up to ``last_frame_t_s`` are decided: the boxes still held for them were
        of frames skipped."""
        for t in [t for t in self._held if t <= last_frame_t_s]:
            n = len(self._held.pop(t)[1])
            self._n_held -= n
            self.faults[Fault.BOXES_OF_SKIPPED_FRAMES] += n

    def poll(self, now_s: float, origin: Origin | None, force: bool = False
             ) -> Publication | None:
        """The detections message due at ``now_s`` (monotonic s), or None; ``force``: one
        now whatever the period (a clean stop: call until None)."""
        if not self._new or origin is None or (now_s < self._next_s and not force):
            return None
        self._next_s = now_s + DETECTIONS_PERIOD_S
        sent, self._new = self._new[:MAX_DETECTIONS], self._new[MAX_DETECTIONS:]
        touched = self.tracker.candidates(self.grid, (d.candidate_id for d in sent))
        self.latest.update((c.candidate_id, c) for c in touched)
        return Publication(
            encode_detections(detections_document(sent, touched, origin, self.vehicle_id,
                                                  self.tracker.uid_of)),
            tuple(c.candidate_id for c in touched))

    def restored(self) -> None:
        """The tracker's candidates were restored (a restart): they are the latest the
        status summarises until the next publish or answer."""
        self.latest = {c.candidate_id: c for c in self.tracker.candidates(self.grid)}

    def candidates_payload(self, origin: Origin | None) -> bytes:
        """The candidates query's answer: every candidate, no detection."""
        cands = self.tracker.candidates(self.grid) if origin is not None else []
        self.latest.update((c.candidate_id, c) for c in cands)
        return encode_detections(detections_document(
            [], cands, origin or Origin(0.0, 0.0), self.vehicle_id))
