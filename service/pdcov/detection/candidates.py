"""Detections of one target across frames grouped into one candidate, with no I/O: the one
rule the daemon and ``pdcov evaluate`` both run (``DetectionTracker``), so that the
detections and candidates of a flight are the same live and offline.

``DetectionTracker.frame`` takes one decided frame's pose and boxes, geolocates the boxes
(core/geolocate.py) and groups each: it joins the nearest candidate of its class whose
mean lies within the gate -- ``gate_sigmas`` times the combined 1-sigma (sqrt(sigma_d^2 +
sigma_c^2)), and never less than one cell -- else it starts a new candidate (ids 0, 1, 2,
... in order; of equally near candidates the oldest). A candidate's position is the
inverse-variance weighted mean of its detections' ground points (weights 1 / sigma^2,
sigma at least 1 mm), its sigma sqrt(1 / sum of weights). Looks, P_D and P_FA are the
grid's at the candidate's cell when ``candidates`` is called (0 outside the grid): the
operator sees "seen 14 times, detected 9". Deterministic: the same frames in the same order
give the same candidates.

Budgeted: at most MAX_CANDIDATES_PER_CLASS candidates of one class and
MAX_TRACKED_CANDIDATES in all. When a box would start one more, the stalest unconfirmed
candidate (fewer than CONFIRMED_HITS hits, the oldest last detection) of its class -- or of
any class when the whole table is full -- is evicted for it (``Skip.EVICTED``); a confirmed
candidate is never evicted for a new one: with none to evict, the box is counted
(``Skip.TOO_MANY_CANDIDATES``). 10,000 invented classes thus cannot keep a real person's
detection from making a candidate.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TypeGuard

import numpy as np

from pdcov.config import Mission
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, Candidate, Detection, valid_class_name
from pdcov.core.geolocate import Geolocation, locate_boxes
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface

__all__ = ["CONFIRMED_HITS", "MAX_CANDIDATES_PER_CLASS", "MAX_TRACKED_CANDIDATES",
           "DetectionTracker", "Skip"]

MAX_TRACKED_CANDIDATES = 10_000
"""Most candidates held at once (bus.detections.MAX_CANDIDATES)."""
MAX_CANDIDATES_PER_CLASS = 2_000
"""Most candidates of one class held at once."""
CONFIRMED_HITS = 2
"""A candidate detected this many times is confirmed: never evicted for a new one."""
_MIN_SIGMA_M = 1e-3


class Skip:
    """Why a box was not made a detection (counted in ``DetectionTracker.skipped``)."""

    OFF_GROUND = "box off the ground"
    """Its ray, or one of its +-1 sigma perturbations, does not meet the ground."""
    TOO_MANY_CANDIDATES = "too many candidates"
    """Its class's budget (or the table) is full of confirmed candidates."""
    EVICTED = "candidates evicted"
    """Not a box: a stale unconfirmed candidate dropped to make room for a new one."""


@dataclass(slots=True)
class _Group:
    class_name: str
    sum_w: float
    sum_wr: np.ndarray  # (3,) sum of weight * ground point
    hits: int
    confidence: float
    first_t_boot_s: float
    last_t_boot_s: float

    @property
    def r_enu_m(self) -> np.ndarray:
        return self.sum_wr / self.sum_w

    @property
    def sigma_m(self) -> float:
        return math.sqrt(1.0 / self.sum_w)


class DetectionTracker:
    """Geolocates and groups the boxes of decided frames (module docstring): ``camera``,
    ``geolocation`` and ``terrain`` (None: the plane z = 0) as the coverage grid's;
    ``cell_size_m`` the grid's (the least gate)."""

    def __init__(self, camera: CameraModel, geolocation: Geolocation, cell_size_m: float,
                 terrain: TerrainSurface | None = None, gate_sigmas: float = 3.0,
                 uid_prefix: str = "c") -> None:
        if not (math.isfinite(gate_sigmas) and gate_sigmas > 0):
            raise ValueError(f"gate_sigmas {gate_sigmas!r}: expected a positive number")
        self.camera = camera
        self.geolocation = geolocation
        self.cell_size_m = float(cell_size_m)
        self.terrain = terrain
        self.gate_sigmas = float(gate_sigmas)
        self.uid_prefix = uid_prefix
        self._groups: dict[int, _Group] = {}  # by candidate id, in id order
        self._per_class: Counter[str] = Counter()
        self._next_id = 0
        self.skipped: Counter[str] = Counter()

    @classmethod
    def for_mission(cls, mission: Mission, uid_prefix: str = "c") -> DetectionTracker:
        """The tracker of ``mission``'s camera, terrain, cells and ``detections`` section;
        ``uid_prefix``: its candidates' uids are it and their id."""
        return cls(mission.camera, mission.geolocation, mission.cell_size_m, mission.terrain,
                   mission.gate_sigmas, uid_prefix)

    def __len__(self) -> int:
        return len(self._groups)

    def frame(self, pose: CameraPose, t_boot_s: float, boxes: Iterable[Box],
              camera: CameraModel | None = None) -> list[Detection]:
        """The detections of one decided frame's ``boxes`` (its time ``t_boot_s``, autopilot
        boot clock, s; ``pose`` the one the grid took; ``camera`` the frame's own, a zoomed
        lens, None: the tracker's), each grouped into a candidate; the boxes not geolocated
        are counted in ``skipped``."""
        boxes = tuple(boxes)
        points, sigmas = locate_boxes(camera or self.camera, pose, boxes, self.geolocation,
                                      self.terrain)
        out = []
        for box, r, sigma in zip(boxes, points, sigmas, strict=True):
            if not np.isfinite(sigma):
                self.skipped[Skip.OFF_GROUND] += 1
                continue
            cid = self._group(box, r, float(sigma), t_boot_s)
            if cid is None:
                self.skipped[Skip.TOO_MANY_CANDIDATES] += 1
                continue
            out.append(Detection(t_boot_s, box, r, float(sigma), cid))
        return out

    def _group(self, box: Box, r: np.ndarray, sigma_m: float, t_boot_s: float) -> int | None:
        best, best_d = None, math.inf
        for i, g in self._groups.items():
            if g.class_name != box.class_name:
                continue
            d = float(np.hypot(*(g.r_enu_m[:2] - r[:2])))
            gate = max(self.gate_sigmas * math.hypot(sigma_m, g.sigma_m), self.cell_size_m)
            if d <= gate and d < best_d:
                best, best_d = i, d
        w = 1.0 / max(sigma_m, _MIN_SIGMA_M) ** 2
        if best is None:
            if not self._make_room(box.class_name):
                return None
            cid, self._next_id = self._next_id, self._next_id + 1
            self._groups[cid] = _Group(box.class_name, w, w * r, 1, box.confidence,
                                       t_boot_s, t_boot_s)
            self._per_class[box.class_name] += 1
            return cid
        g = self._groups[best]
        g.sum_w += w
        g.sum_wr = g.sum_wr + w * r
        g.hits += 1
        g.confidence = max(g.confidence, box.confidence)
        g.first_t_boot_s = min(g.first_t_boot_s, t_boot_s)
        g.last_t_boot_s = max(g.last_t_boot_s, t_boot_s)
        return best

    def _make_room(self, class_name: str) -> bool:
        """Room for one more candidate of ``class_name`` (module docstring), evicting the
        stalest unconfirmed one if needed; False when only confirmed ones are left."""
        class_full = self._per_class[class_name] >= MAX_CANDIDATES_PER_CLASS
        if not class_full and len(self._groups) < MAX_TRACKED_CANDIDATES:
            return True
        stale = [(g.last_t_boot_s, i) for i, g in self._groups.items()
                 if g.hits < CONFIRMED_HITS and (not class_full or g.class_name == class_name)]
        if not stale:
            return False
        evicted = self._groups.pop(min(stale)[1])
        self._per_class[evicted.class_name] -= 1
        if not self._per_class[evicted.class_name]:
            del self._per_class[evicted.class_name]
        self.skipped[Skip.EVICTED] += 1
        return True

    def candidates(self, grid: CoverageGrid, ids: Iterable[int] | None = None
                   ) -> list[Candidate]:
        """The candidates ``ids`` (all when None; an evicted one is left out), in id order,
        with the looks, P_D and P_FA ``grid`` holds at their cells now."""
        chosen = (list(self._groups) if ids is None
                  else sorted(i for i in set(ids) if i in self._groups))
        g_ = grid.geometry
        out = []
        for i in chosen:
            g = self._groups[i]
            r = g.r_enu_m
            row, col = (int(v) for v in g_.cell_of(r[0], r[1]))
            inside = 0 <= row < g_.n_rows and 0 <= col < g_.n_cols
            looks = int(grid.n_obs[row, col]) if inside else 0
            pd = float(-np.expm1(float(grid.log_miss_d[row, col]))) if inside else 0.0
            pfa = float(-np.expm1(float(grid.log_miss_fa[row, col]))) if inside else 0.0
            out.append(Candidate(i, g.class_name, r, g.sigma_m, g.hits, looks,
                                 min(max(pd, 0.0), 1.0), min(max(pfa, 0.0), 1.0),
                                 g.confidence, g.first_t_boot_s, g.last_t_boot_s,
                                 f"{self.uid_prefix}{i}", 0.0))
        return out

    # --- state, for checkpoints and the journal (service/candidate_store.py) -------------

    @property
    def next_id(self) -> int:
        """The id the next new candidate gets (ids are never reused)."""
        return self._next_id

    def to_doc(self) -> dict:
        """The whole state as JSON-able values (``load_doc`` reads it back)."""
        return {"version": STATE_VERSION, "next_id": self._next_id,
                "candidates": self.candidate_docs(self._groups)}

    def candidate_docs(self, ids: Iterable[int]) -> list[dict]:
        """The states of candidates ``ids`` (an evicted one left out), in id order."""
        return [{"id": i, "class": g.class_name, "sum_w": g.sum_w,
                 "sum_wr": [float(v) for v in g.sum_wr], "hits": g.hits,
                 "confidence": g.confidence, "first_t_boot_s": g.first_t_boot_s,
                 "last_t_boot_s": g.last_t_boot_s}
                for i in sorted(set(ids)) if (g := self._groups.get(i)) is not None]

    def load_doc(self, doc: object) -> None:
        """Replace the state with ``doc`` (``to_doc``'s); ValueError naming the field."""
        if not isinstance(doc, dict) or doc.get("version") != STATE_VERSION:
            raise ValueError(f"version: expected {STATE_VERSION}")
        groups = _groups_of(doc.get("candidates"))
        next_id = _next_id_of(doc.get("next_id"), groups)
        self._groups, self._next_id = {}, 0
        self._per_class.clear()
        self._put(groups, next_id)

    def apply_candidate_docs(self, docs: object, next_id: object) -> None:
        """Add or replace the candidates ``docs`` (``candidate_docs``'s) and continue the
        ids from ``next_id`` at least; ValueError naming the field, nothing changed."""
        groups = _groups_of(docs)
        self._put(groups, max(_next_id_of(next_id, groups), self._next_id))

    def _put(self, groups: dict[int, _Group], next_id: int) -> None:
        for i, g in groups.items():
            old = self._groups.pop(i, None)
            if old is not None:
                self._per_class[old.class_name] -= 1
            self._groups[i] = g
            self._per_class[g.class_name] += 1
        self._groups = dict(sorted(self._groups.items()))
        self._next_id = next_id


STATE_VERSION = 1
"""The version of ``DetectionTracker.to_doc``'s document."""


def _groups_of(docs: object) -> dict[int, _Group]:
    """The candidates of ``candidate_docs``'s list, checked; ValueError naming the field."""
    if not isinstance(docs, list):
        raise ValueError("candidates: expected a list")
    out = {}
    for k, d in enumerate(docs):
        def bad(field: str, d: object = d, k: int = k) -> ValueError:
            value = d.get(field) if isinstance(d, dict) else d
            return ValueError(f"candidates[{k}].{field} = {value!r}: not what pdcov writes")
        if not isinstance(d, dict):
            raise bad("")
        if not _count(d.get("id")) or d["id"] in out:
            raise bad("id")
        if not valid_class_name(d.get("class")):
            raise bad("class")
        for f in ("sum_w", "confidence", "first_t_boot_s", "last_t_boot_s"):
            if not _real(d.get(f)) or (f == "sum_w" and d[f] <= 0):
                raise bad(f)
        wr = d.get("sum_wr")
        if not (isinstance(wr, list) and len(wr) == 3 and all(_real(v) for v in wr)):
            raise bad("sum_wr")
        if not _count(d.get("hits")):
            raise bad("hits")
        out[d["id"]] = _Group(d["class"], float(d["sum_w"]), np.array(wr, dtype=float),
                              d["hits"], float(d["confidence"]), float(d["first_t_boot_s"]),
                              float(d["last_t_boot_s"]))
    return out


def _next_id_of(v: object, groups: dict[int, _Group]) -> int:
    if not _count(v) or any(i >= v for i in groups):
        raise ValueError(f"next_id = {v!r}: expected an integer above every candidate id")
    return v


def _count(v: object) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _real(v: object) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
