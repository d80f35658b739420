"""Truth and detections of one image by hand, and match settings at IoU 0.5, for the tests of
the detector statistics' matching."""

from __future__ import annotations

import numpy as np

from pdcov.detection.annotations import Boxes
from pdcov.detection.matching import MatchSettings
from pdcov.detection.truth_set import ImageTruth


def truth_image(gt, labels=None, ignore=None, regions=()):
    labels = labels or ["person"] * len(gt)
    return ImageTruth("a", 100, 100, Boxes.from_rows(gt, labels, ignore=ignore),
                      np.asarray(regions, float).reshape(-1, 4))


def dets_of(rows, scores, labels=None):
    return Boxes.from_rows(rows, labels or ["person"] * len(rows), scores)


S = MatchSettings(0.5, 0.5, None, None)
