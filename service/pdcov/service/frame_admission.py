"""Which of a detector's frames and boxes the daemon admits, with no I/O (docs/service.md
"Detector frames"): a frame time within a window of the autopilot's clock, a box of a class
the detector model names.

The window is on the autopilot's clock as the daemon knows it (its newest time, s): a frame
older than the tracker's history can never be placed (its telemetry is gone), and one more
than FUTURE_TOLERANCE_S ahead of it was not taken yet -- a forged or broken stamp that would
otherwise wait in the queues for telemetry that never comes (a far-future flood stalled the
status for 17.5 s and evicted real candidates). Refused frames and boxes are counted in the
status's faults under ``FrameRefusal``'s names.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Collection

from pdcov.bus.faults import Fault
from pdcov.core.detections import Box
from pdcov.core.detector import DetectorModel

__all__ = ["FUTURE_TOLERANCE_S", "FrameRefusal", "known_classes", "refusal_of_time",
           "split_by_class"]

FUTURE_TOLERANCE_S = 2.0
"""How far (s) a frame time may lie ahead of the autopilot's newest time: the detector's
stamp is read off the same clock, and telemetry arrives some 100 ms late at most."""


class FrameRefusal(enum.Enum):
    """Why a detector frame or box was refused; the value is its fault in the status."""

    TOO_OLD = Fault.FRAMES_REFUSED_TOO_OLD
    AHEAD = Fault.FRAMES_REFUSED_AHEAD_OF_CLOCK
    UNKNOWN_CLASS = Fault.BOXES_REFUSED_UNKNOWN_CLASS


def refusal_of_time(t_s: float, clock_now_s: float, history_s: float) -> FrameRefusal | None:
    """Why a frame at ``t_s`` (autopilot clock, s) is refused when the autopilot's newest time
    is ``clock_now_s`` and the tracker keeps ``history_s`` of telemetry; None: admitted (also
    while the clock is unknown, NaN)."""
    if not math.isfinite(clock_now_s):
        return None
    if t_s < clock_now_s - history_s:
        return FrameRefusal.TOO_OLD
    if t_s > clock_now_s + FUTURE_TOLERANCE_S:
        return FrameRefusal.AHEAD
    return None


def known_classes(model: DetectorModel) -> frozenset[str] | None:
    """The classes the detector model was fitted on (``fit.classes``), None when it names
    none (then every class is admitted)."""
    fit = model.extra.get("fit")
    classes = fit.get("classes") if isinstance(fit, dict) else None
    if not isinstance(classes, list) or not classes:
        return None
    return frozenset(str(c) for c in classes)


def split_by_class(boxes: tuple[Box, ...], classes: Collection[str] | None
                   ) -> tuple[tuple[Box, ...], int]:
    """The boxes of ``classes`` (all when None) and how many others were refused."""
    if classes is None:
        return boxes, 0
    kept = tuple(b for b in boxes if b.class_name in classes)
    return kept, len(boxes) - len(kept)
