"""One camera's frames in the daemon, with no I/O: ``CameraFrames``.

Each camera of the mission (the single camera, or each entry of a ``cameras`` list) has
its own PoseTracker (its mount or gimbal device, the gimbal reading of that device's
parameters, the zoom reports of its own camera component), its own ``FrameSchedule`` (its
frame rate's lattice) and its own grid, as ``pdcov evaluate`` builds one per camera. Every
tracked sample of the link is given to every camera; what one camera takes of them (its
gimbal device, its zoom reports) is its tracker's choice, offline as live. Each batch of
decidable frames is decided by ``frame_decision.decide_frames``, as offline.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from pdcov.bus.faults import Fault
from pdcov.core.grid import CoverageGrid
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import CameraPose
from pdcov.flight.frame_decision import FrameCounts, Framing, decide_frames
from pdcov.flight.frame_schedule import FrameSchedule
from pdcov.telemetry.frame_policy import FrameSource
from pdcov.telemetry.gimbal import GimbalInterpretation, resolve_interpretation
from pdcov.telemetry.lens_reports import LensReports
from pdcov.telemetry.pose_tracker import PoseTracker
from pdcov.telemetry.samples import (
    AttitudeSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    LensSample,
    PositionSample,
)

if TYPE_CHECKING:
    from collections import Counter

    from pdcov.config.mission import MissionCamera
    from pdcov.core.camera import CameraModel
    from pdcov.core.geodesy import Origin
    from pdcov.core.geolocate import PositionAccuracy

__all__ = ["BATCH_OF_HISTORY", "MAX_WAITING_SAMPLES", "PARAMS_ORIGIN", "CameraFrames",
           "FrameSink", "TrackedSample", "tracker_history_s"]

PARAMS_ORIGIN = "the autopilot's parameters over MAVLink"
MAX_WAITING_SAMPLES = 2_000_000
"""Samples kept while the origin or gimbal reading is unknown (about 10 h of telemetry)."""
TrackedSample = (AttitudeSample | PositionSample | GimbalSample | EstimatorSample | LensSample
                 | GnssAccuracySample)
"""The samples the PoseTracker takes (the others are read by LiveCoverage itself)."""
FrameSink = Callable[["CameraFrames", CameraPose, "CameraModel | None",
                      "PositionAccuracy | None"], None]
"""Told of every frame a camera's grid took (after ``grid.update_with``), with its zoomed
camera (None: the configured one) and the GNSS accuracy in force at it (gnss_accuracy.py;
None: unknown)."""


BATCH_OF_HISTORY = 0.25
"""Frames evaluated at once span at most this share of the tracker's history."""


def tracker_history_s(max_gap_s: float) -> float:
    """Telemetry a camera's tracker keeps (s): max(20 s, 8 x max_gap_s)."""
    return max(20.0, 8.0 * max_gap_s)


class CameraFrames:
    """One camera's tracker, schedule and grid (module docstring), its frames decided by
    ``framing`` (frame_decision.framing_of; frame_source set). ``skipped`` / ``faults``:
    the daemon's counters (counted into); ``took``: called with each frame taken."""

    def __init__(self, cam: MissionCamera, grid: CoverageGrid, *, framing: Framing,
                 reorder_s: float, skipped: Counter, faults: Counter,
                 took: FrameSink) -> None:
        if framing.frame_source is None:
            raise ValueError("the daemon's framing has a frame source")
        self.cam = cam
        self.grid = grid
        self.framing = framing
        self.frame_source = framing.frame_source
        self.history_s = tracker_history_s(framing.max_gap_s)
        self.skipped, self.faults = skipped, faults
        self._counts = FrameCounts(skipped, faults)
        self._took = took
        self.used = 0  # frames this camera's grid took
        self.dem_refused = False  # the DEM is refused (terrain_check.home_refused): no frame
        self.interpretation: GimbalInterpretation | None = None
        self.tracker: PoseTracker | None = None
        self.waiting: deque[TrackedSample] = deque()  # not yet given to the tracker
        needed = ("attitude", "position") + (
            ("gimbal",) if isinstance(cam.mount, GimbalMount) else ())
        self.schedule = FrameSchedule(framing.frame_source, framing.frame_rate_hz,
                                      framing.max_gap_s, reorder_s, needed, self.waiting,
                                      skipped)
        self.last_pose: CameraPose | None = None
        self.last_R_ned_body = np.eye(3)  # the body attitude at last_pose (once there is one)
        self.last_accuracy: PositionAccuracy | None = None  # the GNSS's at last_pose

    def add(self, sample: TrackedSample) -> None:
        """A tracked sample of the link (checked by LiveCoverage), kept until fed."""
        if len(self.waiting) >= MAX_WAITING_SAMPLES:
            self.waiting.popleft()
            self.faults[Fault.SAMPLES_DROPPED_WAITING] += 1
        self.waiting.append(sample)

    def set_params(self, params: dict[str, float], done: bool) -> None:
        """The mount parameters read so far; ``done`` when no more will come."""
        mount = self.cam.mount
        if self.interpretation is None and isinstance(mount, GimbalMount) and done:
            self.interpretation = resolve_interpretation(mount, params, PARAMS_ORIGIN)

    def start(self, origin: Origin) -> bool:
        """Start the tracker once the origin (and for a gimbal its reading) is known."""
        if self.tracker is None and not (isinstance(self.cam.mount, GimbalMount)
                                         and self.interpretation is None):
            f = self.framing
            zoom = f.zoom
            self.tracker = PoseTracker(origin, f.mount, interpretation=self.interpretation,
                                       max_gap_s=f.max_gap_s, history_s=self.history_s,
                                       use_estimator=f.estimator_status,
                                       lens=None if zoom is None else LensReports(zoom))
        return self.tracker is not None

    def _feed(self, tr: PoseTracker, until_s: float) -> None:
        """Give the tracker the waiting samples up to ``until_s`` (all when live; a backlog
        bit by bit, so that its history window never drops what a frame needs)."""
        w = self.waiting
        while w and w[0].t_s <= until_s:
            s = w.popleft()
            if isinstance(s, AttitudeSample):
                tr.add_attitude(s)
                stream = "attitude"
            elif isinstance(s, PositionSample):
                tr.add_position(s)
                stream = "position"
            elif isinstance(s, EstimatorSample):
                # Not a stream a frame waits for: a report carries no time of its own and is
                # stamped at arrival, so none can come for a frame whose attitude is in.
                tr.add_estimator(s)
                continue
            elif isinstance(s, LensSample):  # lens_reports.py: the estimator's rule
                tr.add_lens(s)
                continue
            elif isinstance(s, GnssAccuracySample):  # gnss_accuracy.py: likewise
                tr.add_gnss_accuracy(s)
                continue
            else:
                before = tr.gimbal_source
                tr.add_gimbal(s)
                if tr.gimbal_source != before:
                    self.schedule.forget("gimbal")
                if s.source != tr.gimbal_source:
                    continue
                stream = "gimbal"
            self.schedule.saw(stream, s.t_s)

    @property
    def zoom_reports_other_camera(self) -> int:
        """Zoom reports of other cameras this camera's lens refused (0 without a zoom)."""
        tr = self.tracker
        return tr.lens.other_camera if tr is not None and tr.lens is not None else 0

    def process(self) -> int:
        """Decide every frame that can be decided; returns how many were added. Frames are
        evaluated in batches (one vectorised PoseTracker call) spanning at most a quarter
        of the tracker's history."""
        tr = self.tracker
        if tr is None:
            return 0
        sched = self.schedule
        added = 0
        while True:
            t = sched.next_frame_t()
            if t is None and self.frame_source == FrameSource.RATE:
                t = sched.start_lattice(tr)
            if t is None:
                if not self.waiting:
                    return added
                self._feed(tr, self.waiting[0].t_s + 0.5 * self.history_s)
                continue
            if sched.skip_hole(t):  # before deciding a long hole batch by batch
                continue
            first_t = t
            batch: list[float] = []
            span_s = BATCH_OF_HISTORY * self.history_s
            while t is not None and t - (batch[0] if batch else t) <= span_s:
                self._feed(tr, t + 0.5 * self.history_s)
                if not sched.decidable(t):
                    break
                batch.append(t)
                sched.advance()
                t = sched.next_frame_t()
            if not batch:
                if not sched.skip_hole(first_t):
                    return added
                continue
            added += self._evaluate(tr, np.array(batch))

    def _evaluate(self, tr: PoseTracker, t_s: np.ndarray) -> int:
        """Add the frames at times ``t_s`` (increasing) that frame_decision.decide_frames
        uses and are high enough; it counts the others."""
        self.schedule.last_frame_t_s = float(t_s[-1])
        d = decide_frames(tr, t_s, self.framing, self._counts, home_off_dem=self.dem_refused)
        if self.dem_refused:
            return 0
        sel = d.selected
        added = 0
        for pose, low, R_body, camera, accuracy in zip(
                sel.poses, sel.low, d.R_ned_body, sel.cameras, sel.accuracies, strict=True):
            self.last_pose, self.last_R_ned_body = pose, R_body
            self.last_accuracy = accuracy
            if low:
                continue
            self.grid.update_with(pose, camera)
            self._took(self, pose, camera, accuracy)
            added += 1
        self.used += added
        return added
