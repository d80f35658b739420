"""The optional sections of a detector model (core/detector.py): P_D and P_FA by motion
blur (``BlurModel``), the evidence of a box's confidence (``ConfidenceModel``), how one
person's looks are correlated (``LooksModel``) and the counts behind each size bin
(``BinCounts``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class BlurModel:
    """P_D and P_FA by motion-blur bin and size bin (version 3's ``blur`` section).

    edges_px: M + 1 strictly increasing blur lengths in detector-input pixels (scaled from
    image pixels as sizes are), the first 0; blur bin j is [edges_px[j], edges_px[j + 1]).
    p_detect, p_false_alarm: M rows (blur bins) of N values (the model's size bins). A blur
    at or above the last edge has P_D = P_FA = 0 (the model claims nothing there).
    ``extra``: the fit's other keys (intervals, counts), kept as written.
    """

    edges_px: tuple[float, ...]
    p_detect: tuple[tuple[float, ...], ...]
    p_false_alarm: tuple[tuple[float, ...], ...]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_bins(self) -> int:
        return len(self.edges_px) - 1


@dataclass(frozen=True, slots=True)
class ConfidenceModel:
    """How a box's confidence tells a person from a false alarm (version 5's ``confidence``
    section), per size bin of the model (the box's own size, detector-input px).

    edges: K + 1 strictly increasing confidences in [0, 1], the last 1 (a fit's: K equal bins
    over [confidence_threshold, 1]); bin k is [edges[k], edges[k + 1]), the last one closed.
    tp_density, fp_density: N rows (size bins) of K histogram densities (per unit confidence)
    of the confidences of true and of false boxes, finite and > 0; each row is rescaled to
    integrate to 1 where it is used (``probabilities``), so rounding does not bias the ratio.
    ``extra``: the fit's other keys (counts, smoothing), kept as written.
    """

    edges: tuple[float, ...]
    tp_density: tuple[tuple[float, ...], ...]
    fp_density: tuple[tuple[float, ...], ...]
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def n_bins(self) -> int:
        return len(self.edges) - 1

    def probabilities(self, true_positive: bool) -> np.ndarray:
        """(N, K): per size bin, the probability of each confidence bin for a true box
        (``true_positive``) or a false one."""
        d = np.asarray(self.tp_density if true_positive else self.fp_density, dtype=float)
        mass = d * np.diff(np.asarray(self.edges))
        return mass / mass.sum(axis=1, keepdims=True)

    def log_lr_table(self) -> np.ndarray:
        """(N, K): per size bin and confidence bin, log(f_TP / f_FP), the evidence of a box
        of that confidence for a person."""
        return np.log(self.probabilities(True)) - np.log(self.probabilities(False))

    def bin_index(self, confidence: np.ndarray) -> np.ndarray:
        """Confidence bin 0..K-1 of each confidence; outside the edges the nearest bin."""
        k = np.searchsorted(np.asarray(self.edges), np.asarray(confidence, dtype=float),
                            side="right") - 1
        return np.clip(k, 0, self.n_bins - 1)


@dataclass(frozen=True, slots=True)
class LooksModel:
    """How one person's looks are correlated (version 2's ``looks`` section).

    Each person has a latent detectability: in size bin i it is Beta distributed with the
    bin's mean P_D and intra-person correlation ``correlation[i]`` (rho = 1 / (a + b + 1));
    rho = 0 is the paper's independent looks. ``extra``: the fit's other keys (intervals,
    tests), kept as written.
    """

    correlation: tuple[float, ...]
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class BinCounts:
    """The counts behind each bin: ground-truth objects, those detected, all detections."""

    n_true: tuple[int, ...]
    n_detected: tuple[int, ...]
    n_detections: tuple[int, ...]
