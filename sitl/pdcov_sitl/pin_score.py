"""Pins scored by person identity (issue 35, docs/simulator.md "Pins scored by identity"):
pure rules over what a flight's tracker made of the simulated detector's boxes, whose
person each box was is known (``SimulatedDetection.person_id``, FALSE_ALARM_ID for a false
alarm).

The record of a flight is one row per detection (``DetectionOwners``: the candidate it
joined, its frame's index, its person) and the final candidates; every rule here reads only
those and the true people. Definitions:

* a pin *holds* a person when at least one of its boxes is theirs; it *is a person* when
  more than half of its boxes are people's (then its person is the one holding most of them);
* a person is *found* when a pin holds them and lies within FOUND_WITHIN_M of them
  (horizontal distance);
* the prediction is each person's cumulative P_D at their cell; the number found is then a
  Poisson-binomial sum whose sd is sqrt(sum p (1 - p)): the share found is *as predicted*
  when within Z_MAX of those sds of the mean prediction;
* calibration of ``p_person``: among pins at or above HIGH_P the share that are people,
  among pins at or below LOW_P the same, and the Brier score mean (p_person - is_person)^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdcov.core.detections import Candidate

from .detector import FALSE_ALARM_ID

__all__ = ["FOUND_WITHIN_M", "HIGH_P", "LOW_P", "MAX_BRIER", "MAX_LOW_PEOPLE",
           "MAX_TWO_PEOPLE_SHARE", "MIN_HIGH_PEOPLE", "Z_MAX", "Calibration", "DetectionOwners",
           "FoundShare", "Merges", "calibration", "found_people", "found_share", "merges",
           "pin_people", "true_pin_errors_m"]

FOUND_WITHIN_M = 2.0
"""A pin finds a person it holds when it lies within this horizontal distance of them (m)."""
Z_MAX = 3.0
"""The share found is as predicted within this many Poisson-binomial sds."""
HIGH_P, LOW_P = 0.9, 0.1
"""p_person at or above HIGH_P: a pin the operator trusts; at or below LOW_P: one ignored."""
MIN_HIGH_PEOPLE, MAX_LOW_PEOPLE, MAX_BRIER = 0.85, 0.15, 0.10
"""Calibrated (issue 35): of the pins at >= HIGH_P at least MIN_HIGH_PEOPLE are people, of
those at <= LOW_P at most MAX_LOW_PEOPLE, and the Brier score over all pins <= MAX_BRIER."""
MAX_TWO_PEOPLE_SHARE = 0.05
"""Groups 1.5 m apart stay distinct: at most this share of the pins hold two people."""


@dataclass(frozen=True, slots=True)
class DetectionOwners:
    """One row per detection of a flight: ``candidate_id`` it joined, ``frame`` (index of
    its frame in the flight) and ``person_id`` (index into the people; FALSE_ALARM_ID for a
    false alarm). Equal-length int arrays."""

    candidate_id: np.ndarray
    frame: np.ndarray
    person_id: np.ndarray

    def __post_init__(self) -> None:
        arrays = [np.asarray(getattr(self, k), dtype=np.int64).reshape(-1)
                  for k in ("candidate_id", "frame", "person_id")]
        if len({len(a) for a in arrays}) != 1:
            raise ValueError(f"detection owners: arrays of lengths {[len(a) for a in arrays]}: "
                             "expected one length")
        for k, a in zip(("candidate_id", "frame", "person_id"), arrays, strict=True):
            object.__setattr__(self, k, a)

    @classmethod
    def concat(cls, parts: list[DetectionOwners]) -> DetectionOwners:
        """The rows of ``parts`` one after the other."""
        return cls(*(np.concatenate([getattr(p, k) for p in parts] or [np.zeros(0, int)])
                     for k in ("candidate_id", "frame", "person_id")))


def pin_people(owners: DetectionOwners, candidate_ids: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per candidate of ``candidate_ids``: (is a person, its person -- the one holding most
    of its boxes, FALSE_ALARM_ID when none --, the number of distinct people it holds)."""
    n = len(candidate_ids)
    is_person = np.zeros(n, dtype=bool)
    person = np.full(n, FALSE_ALARM_ID, dtype=np.int64)
    n_people = np.zeros(n, dtype=np.int64)
    for k, cid in enumerate(candidate_ids):
        pids = owners.person_id[owners.candidate_id == cid]
        real = pids[pids != FALSE_ALARM_ID]
        if len(real) == 0:
            continue
        ids, counts = np.unique(real, return_counts=True)
        n_people[k] = len(ids)
        person[k] = ids[np.argmax(counts)]
        is_person[k] = 2 * len(real) > len(pids)
    return is_person, person, n_people


def found_people(owners: DetectionOwners, candidates: list[Candidate], r_people_enu_m: np.ndarray
                 ) -> np.ndarray:
    """Per person (bool): a pin among ``candidates`` holds one of their boxes and lies within
    FOUND_WITHIN_M of them (horizontal)."""
    found = np.zeros(len(r_people_enu_m), dtype=bool)
    xy = {c.candidate_id: c.r_enu_m[:2] for c in candidates}
    for cid, pid in zip(owners.candidate_id, owners.person_id, strict=True):
        if pid == FALSE_ALARM_ID or found[pid] or cid not in xy:
            continue
        found[pid] = float(np.hypot(*(xy[cid] - r_people_enu_m[pid, :2]))) <= FOUND_WITHIN_M
    return found


@dataclass(frozen=True, slots=True)
class FoundShare:
    """People found against the prediction: ``n_found`` of ``n_people``, the mean predicted
    cumulative P_D ``predicted`` and the Poisson-binomial sd of the share ``sd``."""

    n_found: int
    n_people: int
    predicted: float
    sd: float

    @property
    def share(self) -> float:
        return self.n_found / self.n_people if self.n_people else math.nan

    @property
    def z(self) -> float:
        """(share - predicted) / sd; 0 when both agree with no spread."""
        d = self.share - self.predicted
        return d / self.sd if self.sd > 0 else (0.0 if d == 0 else math.copysign(math.inf, d))

    @property
    def as_predicted(self) -> bool:
        return abs(self.z) <= Z_MAX


def found_share(found: np.ndarray, p_predicted: np.ndarray) -> FoundShare:
    """The share of people found (bool per person) against their predicted P_D (per person)."""
    p = np.asarray(p_predicted, dtype=float)
    n = len(p)
    return FoundShare(int(np.count_nonzero(found)), n, float(p.mean()) if n else math.nan,
                      math.sqrt(float((p * (1 - p)).sum())) / n if n else math.nan)


@dataclass(frozen=True, slots=True)
class Merges:
    """Pins holding people: ``n_pins`` hold at least one, ``n_two_people`` two or more;
    ``n_two_boxes_one_frame`` pins (of all) hold two boxes of one frame."""

    n_pins: int
    n_two_people: int
    n_two_boxes_one_frame: int

    @property
    def two_people_share(self) -> float:
        return self.n_two_people / self.n_pins if self.n_pins else 0.0


def merges(owners: DetectionOwners, candidate_ids: np.ndarray) -> Merges:
    """Pins among ``candidate_ids`` that merged people, or boxes of one frame."""
    _, _, n_people = pin_people(owners, candidate_ids)
    one_frame = 0
    for cid in candidate_ids:
        frames = owners.frame[owners.candidate_id == cid]
        one_frame += len(np.unique(frames)) < len(frames)
    return Merges(int(np.count_nonzero(n_people)), int(np.count_nonzero(n_people >= 2)),
                  one_frame)


@dataclass(frozen=True, slots=True)
class Calibration:
    """``p_person`` against the truth over ``n`` pins: ``n_high`` at or above HIGH_P of which
    ``people_high`` are people, ``n_low`` at or below LOW_P of which ``people_low``, and the
    Brier score."""

    n: int
    n_high: int
    people_high: int
    n_low: int
    people_low: int
    brier: float

    @property
    def high_share(self) -> float:
        return self.people_high / self.n_high if self.n_high else math.nan

    @property
    def low_share(self) -> float:
        return self.people_low / self.n_low if self.n_low else math.nan

    @property
    def calibrated(self) -> bool:
        """The targets (MIN_HIGH_PEOPLE, MAX_LOW_PEOPLE, MAX_BRIER) met; a side with no pins
        meets its target."""
        return (not self.high_share < MIN_HIGH_PEOPLE and not self.low_share > MAX_LOW_PEOPLE
                and self.brier <= MAX_BRIER)


def calibration(p_person: np.ndarray, is_person: np.ndarray) -> Calibration:
    """Calibration of the pins' ``p_person`` against whether each is a person."""
    p = np.asarray(p_person, dtype=float)
    y = np.asarray(is_person, dtype=bool)
    high, low = p >= HIGH_P, p <= LOW_P
    return Calibration(len(p), int(high.sum()), int((high & y).sum()), int(low.sum()),
                       int((low & y).sum()),
                       float(np.mean((p - y) ** 2)) if len(p) else math.nan)


def true_pin_errors_m(candidates: list[Candidate], person: np.ndarray, is_person: np.ndarray,
                      r_people_enu_m: np.ndarray) -> np.ndarray:
    """Horizontal distance (m) from each pin that is a person to its person (``person`` and
    ``is_person`` per candidate, as ``pin_people`` gives them)."""
    k = np.flatnonzero(is_person)
    if len(k) == 0:
        return np.zeros(0)
    xy = np.array([candidates[i].r_enu_m[:2] for i in k])
    return np.hypot(*(xy - r_people_enu_m[person[k], :2]).T)
