"""One camera's frames decided, with no I/O: ``decide_frames``, the one decision both drivers
make (the daemon's flight/camera_frames.py per batch of decidable frames, ``pdcov
evaluate``'s flight/log_frames.py per chunk of a whole log), and ``Framing``, the options it
decides by, built once from the mission by ``framing_of``.

A batch of frame times goes to the camera's PoseTracker (``frames_at``), its frames to
``frame_selection.select_frames`` (valid, trust policy, quaternion rebuild, min height), and
every frame not used is counted under the daemon's keys (the status's ``frames.skipped``
and ``faults``, evaluate's ``frames_skipped`` and ``telemetry_faults``): the tracker's skip
reasons, ``gimbal untrusted: <reason>`` (frame_policy.UNTRUSTED_PREFIX) when untrusted
frames are skipped, ``below min height``, ``home off DEM``; the faults ``frames_untrusted``
and ``frames_without_estimator_status``. Times are the autopilot clock, s.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pdcov.bus.faults import Fault
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.flight.frame_selection import SelectedFrames, select_frames
from pdcov.telemetry.frame_policy import (
    UNTRUSTED_PREFIX,
    FrameSource,
    SkipReason,
    untrusted_policy,
)

if TYPE_CHECKING:
    from pdcov.config.mission import Mission, MissionCamera
    from pdcov.core.zoom import Zoom
    from pdcov.telemetry.pose_tracker import FrameBatch, PoseTracker

__all__ = ["DecidedFrames", "FrameCounts", "Framing", "decide_frames", "framing_of"]


@dataclass(frozen=True, slots=True)
class Framing:
    """How one camera's frames are placed and judged. mount: its mount or gimbal device;
    frame_rate_hz: the rate frames (Hz); zoom: its zoom lens and reports (None: the
    configured camera for every frame); frame_source: where frame times come from (None:
    not chosen, offline: recorded_frames.frame_source_for); max_gap_s: a telemetry gap (s)
    that skips frames; min_height_m: frames with the camera lower (m above the origin's
    ground) are not evaluated (-inf: none); estimator_status: skip frames the autopilot's
    estimator calls bad (telemetry/estimator.py)."""

    mount: FixedMount | GimbalMount
    frame_rate_hz: float
    zoom: Zoom | None = None
    frame_source: FrameSource | None = FrameSource.RATE
    max_gap_s: float = 1.0
    min_height_m: float = -math.inf
    estimator_status: bool = True


def framing_of(cam: MissionCamera, mission: Mission, frame_source: str | None) -> Framing:
    """The framing of the mission's camera ``cam`` (one of ``Mission.cameras``) with
    ``frame_source`` ('rate', 'capture', 'zenoh'; None: not chosen)."""
    return Framing(cam.mount, cam.frame_rate_hz, cam.zoom,
                   None if frame_source is None else FrameSource(frame_source),
                   mission.max_gap_s, mission.min_height_m, mission.estimator_status)


@dataclass(slots=True)
class FrameCounts:
    """Where the frames not used are counted: ``skipped`` by reason (str), ``faults`` by
    ``Fault`` (the daemon's status counters; evaluate's own)."""

    skipped: Counter
    faults: Counter

    @classmethod
    def new(cls) -> FrameCounts:
        return cls(Counter(), Counter())


@dataclass(frozen=True, slots=True)
class DecidedFrames:
    """A batch decided: ``batch`` (N frames, pose_tracker.FrameBatch) and ``selected`` (the
    F used, frame_selection.SelectedFrames, ``low`` among them: counted, added to no grid);
    ``R_ned_body`` and ``judged`` (an estimator status was in force) per used frame."""

    batch: FrameBatch
    selected: SelectedFrames

    @property
    def R_ned_body(self) -> np.ndarray:
        return self.batch.R_ned_body[self.selected.use]

    @property
    def judged(self) -> np.ndarray:
        return self.batch.estimator_judged[self.selected.use]


def decide_frames(tracker: PoseTracker, t_s: np.ndarray, framing: Framing,
                  counts: FrameCounts, *, home_off_dem: bool = False) -> DecidedFrames:
    """The frames at times ``t_s`` (increasing, s) of ``tracker``'s camera decided by
    ``framing``, the frames not used counted into ``counts`` (module docstring).
    home_off_dem: the DEM is refused (terrain_check.home_refused): every frame that would
    be used is counted as such and none is (``selected.use`` then still says which)."""
    b = tracker.frames_at(t_s)
    mount = framing.mount
    sel = select_frames(b, mount, framing.zoom, framing.min_height_m)
    skipped, faults = counts.skipped, counts.faults
    valid = b.valid
    skipped.update(map(str, b.skip_reason[~valid]))
    untrusted = valid & ~b.trusted
    faults[Fault.FRAMES_UNTRUSTED] += int(untrusted.sum())
    if untrusted_policy(mount) != "use":
        skipped.update(f"{UNTRUSTED_PREFIX}{r}" for r in b.untrusted_reason[untrusted])
    if home_off_dem:
        skipped[SkipReason.HOME_OFF_DEM] += int(sel.use.sum())
        return DecidedFrames(b, sel)
    low = int(sel.low.sum())
    if low:
        skipped[SkipReason.BELOW_MIN_HEIGHT] += low
    unjudged = int((~sel.low & ~b.estimator_judged[sel.use]).sum())
    if unjudged and framing.estimator_status:
        faults[Fault.FRAMES_WITHOUT_ESTIMATOR_STATUS] += unjudged
    return DecidedFrames(b, sel)
