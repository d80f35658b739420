"""The illustrative detector model with motion-blur bins, for the tests of blur and the blur
benchmark (benchmarks/blur.py)."""

from __future__ import annotations

from pdcov.core.detector import DetectorModel


def blur_detector(edges_px: tuple[float, ...] = (0.0, 1.0, 2.0, 4.0, 64.0),
                  factors: tuple[float, ...] = (1.0, 0.8, 0.5, 0.2)) -> DetectorModel:
    """The illustrative model with blur bins ``edges_px`` (detector-input px) whose P_D is
    its own times ``factors`` (one per blur bin), P_FA unchanged."""
    doc = DetectorModel.illustrative().to_dict()
    doc.update(blur={
        "edges_px": list(edges_px),
        "p_detect": [[p * k for p in doc["p_detect"]] for k in factors],
        "p_false_alarm": [doc["p_false_alarm"]] * len(factors)})
    return DetectorModel.from_dict(doc)
