"""Which detector frames and boxes the daemon admits (service/frame_admission.py): a window
of the autopilot's clock in both directions, the detector model's classes."""

from __future__ import annotations

import math

from pdcov.core.detections import Box
from pdcov.core.detector import DetectorModel
from pdcov.service.frame_admission import (
    FUTURE_TOLERANCE_S,
    FrameRefusal,
    known_classes,
    refusal_of_time,
    split_by_class,
)


def test_frame_times_are_admitted_only_within_the_clocks_window():
    now, history = 100.0, 20.0
    assert refusal_of_time(100.0, now, history) is None
    assert refusal_of_time(now - history, now, history) is None
    assert refusal_of_time(now + FUTURE_TOLERANCE_S, now, history) is None
    assert refusal_of_time(now - history - 0.001, now, history) is FrameRefusal.TOO_OLD
    assert refusal_of_time(now + FUTURE_TOLERANCE_S + 0.001, now, history) is FrameRefusal.AHEAD
    assert refusal_of_time(1e9, now, history) is FrameRefusal.AHEAD
    assert refusal_of_time(1e9, math.nan, history) is None  # no clock yet: held, not judged


def test_boxes_of_classes_the_detector_model_does_not_name_are_refused():
    model = DetectorModel.illustrative()
    assert known_classes(model) is None  # names none: every class admitted
    fitted = DetectorModel.from_dict({**model.to_dict(), "fit": {"classes": ["person"]}})
    assert known_classes(fitted) == {"person"}
    boxes = (Box("person", 0.9, 0, 0, 5, 5), Box("invented7", 0.9, 0, 0, 5, 5))
    assert split_by_class(boxes, known_classes(fitted)) == (boxes[:1], 1)
    assert split_by_class(boxes, None) == (boxes, 0)
