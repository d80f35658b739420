"""Which candidate each box of one frame joins, with no I/O (the association step of
``DetectionTracker``, detection/candidates.py): the boxes are assigned to the candidates
held jointly (``scipy.optimize.linear_sum_assignment`` on ground distance, ENU m), pairs of
different classes or beyond the gate forbidden, so that at most one box of a frame joins a
candidate. The gate: ``gate_sigmas`` * hypot(sigma_box, sigma_candidate), at least
GATE_FLOOR_M."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from pdcov.core.detections import Box
from pdcov.detection.candidate_state import CandidateState

__all__ = ["GATE_FLOOR_M", "assign_boxes"]

GATE_FLOOR_M = 0.05
"""The least association gate (m): boxes of one person still join when every sigma is 0
(a floor of one cell, as before, merged people 1.5 m apart)."""


def assign_boxes(boxes: list[Box], points: np.ndarray, sigmas: np.ndarray, ids: np.ndarray,
                 groups: list[CandidateState], pos: np.ndarray, gate_sigmas: float
                 ) -> list[int | None]:
    """Per box, the candidate it joins (None: none): the assignment of least total
    ground distance among the pairs of one class within the gate, as many pairs as
    can be; ``points`` (n, 3) and ``sigmas`` (n,) the boxes' ground points (ENU m) and
    sigmas (m); ``ids``, ``groups``, ``pos`` (n, 2): the candidates held, in id order."""
    n = len(boxes)
    if not n or not groups:
        return [None] * n
    sig = np.array([g.sigma_m for g in groups])
    reach = gate_sigmas * math.hypot(float(sigmas.max()), float(sig.max()))
    lo, hi = points[:, :2].min(axis=0) - reach, points[:, :2].max(axis=0) + reach
    near = np.flatnonzero(((pos >= lo) & (pos <= hi)).all(axis=1))
    if not len(near):
        return [None] * n
    names = sorted({b.class_name for b in boxes})
    code = {c: i for i, c in enumerate(names)}
    box_class = np.array([code[b.class_name] for b in boxes])
    cand_class = np.array([code.get(groups[j].class_name, -1) for j in near])
    d = np.hypot(*(points[:, None, :2] - pos[None, near]).transpose(2, 0, 1))
    gate = np.maximum(gate_sigmas * np.hypot(sigmas[:, None], sig[None, near]),
                      GATE_FLOOR_M)
    ok = (d <= gate) & (box_class[:, None] == cand_class[None, :])
    out: list[int | None] = [None] * n
    if not ok.any():
        return out
    big = 1.0 + float(d[ok].sum())  # more than any set of allowed pairs costs
    rows, cols = linear_sum_assignment(np.where(ok, d, big))
    for i, j in zip(rows, cols, strict=True):
        if ok[i, j]:
            out[int(i)] = int(ids[near[j]])
    return out
