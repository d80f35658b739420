"""Detections of one target across frames grouped into one candidate (a pin), with no
I/O: the one rule the daemon and ``pdcov evaluate`` both run (``DetectionTracker``), so that
the detections and candidates of a flight are the same live and offline (docs/service.md
"Detections").

``DetectionTracker.frame`` takes one decided frame's pose, boxes and the grid that just
took it (``CoverageGrid.last_look``), geolocates the boxes (core/geolocate.py, with the
position accuracy the autopilot reported for the frame when known) and:

1. **Distinct.** Assigns the frame's boxes to candidates jointly (detection/association.py:
   ``scipy.optimize.linear_sum_assignment`` on ground distance; pairs of different classes
   or beyond the gate forbidden): at most one box of a frame joins a candidate; the boxes
   left start new candidates (ids continue from ``next_id``, in box order).
2. **Gate** (detection/association.py). ``gate_sigmas`` * hypot(sigma_box,
   sigma_candidate), at least GATE_FLOOR_M. A candidate's position is the inverse-variance
   weighted mean of its detections' ground points (weights 1 / sigma^2, sigma at least
   1 mm), its sigma sqrt(1 / sum of weights).
3. **Hits per look.** ``looks``: the counted looks (the grid's revisit clock) of the
   candidate's cell: the cell's ``n_obs`` when it is born (its birth frame's look included
   when counted), then one per frame that counts a look of its cell. ``hits``: a box in a
   frame that counted a look of its cell is a hit; a box in a frame between counted looks
   turns the last counted look into a hit if it was a miss; never more: hits <= looks.
4. **p_person.** Prior log-odds (``PeoplePrior`` at its cell over the gate's area
   pi gate_m^2, gate_m = ``gate_sigmas`` * sqrt(2) * the first box's sigma, fixed at birth)
   plus the evidence of each look (detection/pin_evidence.py): a miss log(1 - p), a hit
   log((1 - (1 - p) e^-lambda) / (1 - e^-lambda)) plus the box's confidence evidence
   (``DetectorModel.confidence_log_lr``); p the look's P_D (the grid's per-look table at the
   cell's size and blur), lambda the look's -log(1 - P_FA) of the cell times
   A_gate / A_cell. The looks before birth are misses: the cell's cumulative log P_miss
   before the birth frame's look. With correlated looks (``coverage.looks: correlated``)
   the looks' log LR is kept per ``core.looks.QUADRATURE`` node and combined with the
   weights; with viewpoint looks the looks after birth are weighed as independent (the
   looks before, the grid's viewpoint rule). A box between counted looks turns the last
   look's miss into a hit with that look's P_D and lambda; a candidate born between looks
   takes its cell's last look (before it was born) to have had the birth frame's P_D (by
   size only: the grid finds no blur for an uncounted look).
5. **Durable ids.** ``uid`` = ``uid_prefix`` + candidate id; ``to_doc`` / ``load_doc``
   (and ``candidate_docs`` / ``apply_candidate_docs`` for a journal; the documents of
   detection/candidate_state.py) carry the whole state across a restart: a restored
   tracker continues exactly as the one it was saved from.

Without a grid (``frame(grid=None)``) a frame is a look of the candidates it gives a box
(each a hit) and no evidence: looks and hits but no P_D to weigh.

Budgeted: at most MAX_CANDIDATES_PER_CLASS candidates of one class and
MAX_TRACKED_CANDIDATES in all. When a box would start one more, the stalest unconfirmed
candidate (fewer than CONFIRMED_HITS hits, the oldest last detection) of its class -- or of
any class when the whole table is full -- is evicted for it (``Skip.EVICTED``); a confirmed
candidate is never evicted for a new one: with none to evict, the box is counted
(``Skip.TOO_MANY_CANDIDATES``). 10,000 invented classes thus cannot keep a real person's
detection from making a candidate. Deterministic: the same frames in the same order give
the same candidates.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pdcov.bus.faults import Fault
from pdcov.config.mission import Mission
from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, Candidate, Detection
from pdcov.core.geolocate import Geolocation, PositionAccuracy, locate_boxes
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.last_look import LastLook
from pdcov.core.looks import CorrelatedLooks
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface
from pdcov.detection.association import GATE_FLOOR_M, assign_boxes
from pdcov.detection.candidate_state import (
    MIN_SIGMA_M,
    N_NODES,
    CandidateState,
    CountedLook,
    candidate_docs,
    candidates_of_docs,
    next_id_of,
    state_doc,
    state_of_doc,
)
from pdcov.detection.pin_evidence import (
    PeoplePrior,
    hit_log_lr,
    miss_log_lr,
    p_person,
    prior_log_odds,
)

__all__ = ["CONFIRMED_HITS", "MAX_CANDIDATES_PER_CLASS", "MAX_TRACKED_CANDIDATES",
           "DetectionTracker", "Skip"]

MAX_TRACKED_CANDIDATES = 10_000
"""Most candidates held at once (bus.detections.MAX_CANDIDATES)."""
MAX_CANDIDATES_PER_CLASS = 2_000
"""Most candidates of one class held at once."""
CONFIRMED_HITS = 2
"""A candidate detected this many times is confirmed: never evicted for a new one."""


class Skip:
    """Why a box was not made a detection (counted in ``DetectionTracker.skipped`` under its
    fault key: the daemon adds them to the status's faults)."""

    OFF_GROUND = Fault.BOXES_OFF_GROUND
    """Its ray, or one of its +-1 sigma perturbations, does not meet the ground."""
    TOO_MANY_CANDIDATES = Fault.BOXES_OVER_CANDIDATES
    """Its class's budget (or the table) is full of confirmed candidates."""
    EVICTED = Fault.CANDIDATES_EVICTED
    """Not a box: a stale unconfirmed candidate dropped to make room for a new one."""


@dataclass(frozen=True, slots=True)
class _FrameLooks:
    """The grid's look of one frame, as the tracker weighs it: the grid, its look, and the
    correlated looks state (None: independent or viewpoint looks)."""

    grid: CoverageGrid
    look: LastLook | None
    nodes: CorrelatedLooks | None

    def node_log1m(self, index: int) -> np.ndarray:
        """log(1 - Q(q_j)) (J,) of a look at table ``index``: 0 outside the size bins."""
        assert self.nodes is not None
        slot = int(self.nodes.slot[index])
        return self.nodes.log1m_nodes[slot] if slot >= 0 else np.zeros(N_NODES)


class DetectionTracker:
    """Geolocates and groups the boxes of decided frames (module docstring): ``camera``,
    ``geolocation`` and ``terrain`` (None: the plane z = 0) as the coverage grid's;
    ``cell_size_m`` the grid's; ``uid_prefix`` the candidates' uid before their id
    ("<vehicle_id>.<epoch>."); ``prior_people_per_m2`` people per m^2 before any look:
    a number, or per grid cell an (n_rows, n_cols) array (``PeoplePrior``)."""

    def __init__(self, camera: CameraModel, geolocation: Geolocation, cell_size_m: float,
                 terrain: TerrainSurface | None = None, gate_sigmas: float = 3.0,
                 uid_prefix: str = "", prior_people_per_m2: float | np.ndarray = 1e-6
                 ) -> None:
        if not (math.isfinite(gate_sigmas) and gate_sigmas > 0):
            raise ValueError(f"gate_sigmas {gate_sigmas!r}: expected a positive number")
        self.camera = camera
        self.geolocation = geolocation
        self.cell_size_m = float(cell_size_m)
        self.terrain = terrain
        self.gate_sigmas = float(gate_sigmas)
        self.uid_prefix = uid_prefix
        self.prior = PeoplePrior(prior_people_per_m2)
        self._groups: dict[int, CandidateState] = {}  # by candidate id, in id order
        self._per_class: Counter[str] = Counter()
        self._next_id = 0
        self.skipped: Counter[Fault] = Counter()

    @classmethod
    def for_mission(cls, mission: Mission, uid_prefix: str = "",
                    poa: np.ndarray | None = None) -> DetectionTracker:
        """The tracker of ``mission``'s first camera (whose frames carry the boxes),
        terrain, cells, ``detections`` and ``search`` sections; ``poa``: a probability of
        area per cell (``pdcov evaluate --prior``) for the prior instead of
        ``search.prior_people_per_km2``."""
        prior = (mission.prior_people_per_km2 / 1e6 if poa is None
                 else PeoplePrior.from_poa(poa, mission.cell_size_m).per_m2)
        return cls(mission.first_camera.camera, mission.geolocation, mission.cell_size_m,
                   mission.terrain, mission.gate_sigmas, uid_prefix, prior)

    def __len__(self) -> int:
        return len(self._groups)

    @property
    def next_id(self) -> int:
        """The id the next new candidate takes."""
        return self._next_id

    def uid_of(self, candidate_id: int) -> str:
        """The uid of candidate ``candidate_id`` (held or evicted since)."""
        return f"{self.uid_prefix}{candidate_id}"

    # -- frames -----------------------------------------------------------------------------

    def frame(self, pose: CameraPose, t_boot_s: float, boxes: Iterable[Box],
              camera: CameraModel | None = None, accuracy: PositionAccuracy | None = None,
              grid: CoverageGrid | None = None, unix_s: float = math.nan) -> list[Detection]:
        """The detections of one decided frame's ``boxes`` (its time ``t_boot_s``, autopilot
        boot clock, s, and ``unix_s``, UTC s since 1970, NaN unknown: core/utc_clock.py;
        ``pose`` the one the grid took; ``camera`` the frame's own, a zoomed
        lens, None: the tracker's; ``accuracy`` the position accuracy the autopilot
        reported, None: the configured sigmas), each grouped into a candidate; the boxes
        not geolocated are counted in ``skipped``. ``grid``: the grid that just took this
        frame (its ``last_look``): the looks, hits and evidence of the candidates it had in
        view; give every frame it takes, with boxes or none (a look without a box is a
        miss)."""
        boxes = tuple(boxes)
        camera = camera or self.camera
        points, sigmas = locate_boxes(camera, pose, boxes, self.geolocation.with_accuracy(
            accuracy), self.terrain)
        located = [k for k in range(len(boxes)) if np.isfinite(sigmas[k])]
        self.skipped[Skip.OFF_GROUND] += len(boxes) - len(located)
        ids = np.fromiter(self._groups, dtype=np.int64, count=len(self._groups))
        held = list(self._groups.values())
        pos = np.array([g.r_enu_m[:2] for g in held]).reshape(-1, 2)
        assigned = assign_boxes([boxes[k] for k in located], points[located],
                                sigmas[located], ids, held, pos, self.gate_sigmas)
        looks = None if grid is None else _FrameLooks(
            grid, grid.last_look,
            grid.looks_model if isinstance(grid.looks_model, CorrelatedLooks) else None)
        scale = (1.0 if grid is None else
                 grid.detector.image_to_input_scale(camera.width_px, camera.height_px))
        hit_by: dict[int, Box] = {}
        found: dict[int, int] = {}  # box index -> candidate id
        for k, cid in zip(located, assigned, strict=True):  # joins first: births may evict
            if cid is None:
                continue
            box, g = boxes[k], self._groups[cid]
            g.add_point(points[k], float(sigmas[k]))
            g.confidence = max(g.confidence, box.confidence)
            g.detected_at(t_boot_s, unix_s)
            hit_by[cid] = box
            found[k] = cid
            pos[int(np.searchsorted(ids, cid))] = g.r_enu_m[:2]  # ids ascending
        for k, cid in zip(located, assigned, strict=True):
            if cid is not None:
                continue
            new = self._start(boxes[k], points[k], float(sigmas[k]), t_boot_s, looks, scale,
                              unix_s)
            if new is None:
                self.skipped[Skip.TOO_MANY_CANDIDATES] += 1
            else:
                found[k] = new
        out = [Detection(t_boot_s, boxes[k], points[k], float(sigmas[k]), found[k], unix_s)
               for k in located if k in found]
        if looks is None:
            for g in (self._groups[cid] for cid in hit_by if cid in self._groups):
                g.looks += 1
                g.hits += 1
        else:
            self._weigh_looks(looks, hit_by, scale, ids, pos)
        return out

    def _start(self, box: Box, r: np.ndarray, sigma_m: float, t_boot_s: float,
               looks: _FrameLooks | None, scale: float, unix_s: float) -> int | None:
        """A new candidate of one box (None: no room), with the looks of its cell so far:
        the cell's counted looks all misses (its cumulative log P_miss), then the box makes
        the last of them a hit (this frame's when counted, else the last before, taken to
        have had this frame's P_D)."""
        if not self._make_room(box.class_name):
            return None
        w = 1.0 / max(sigma_m, MIN_SIGMA_M) ** 2
        gate_m = max(self.gate_sigmas * math.sqrt(2.0) * sigma_m, GATE_FLOOR_M)
        g = CandidateState(box.class_name, w, w * r, 0, 0, box.confidence, t_boot_s, t_boot_s,
                           gate_m, 0.0, None, None, unix_s, unix_s)
        cid, self._next_id = self._next_id, self._next_id + 1
        self._groups[cid] = g
        self._per_class[box.class_name] += 1
        if looks is None:
            g.looks = g.hits = 1
            return cid
        grid = looks.grid
        geo = grid.geometry
        row, col = (int(v) for v in geo.cell_of(r[0], r[1]))
        if not (0 <= row < geo.n_rows and 0 <= col < geo.n_cols):
            return cid
        cell = (row, row + 1, col, col + 1)
        g.looks = int(grid.read(Layer.N_OBS, cell)[0, 0])
        if not g.looks:  # no look yet: nothing to make a hit
            return cid
        log_miss_d, lam, index = 0.0, 0.0, 0
        if looks.look is not None:
            _, _, at, log_fa = looks.look.look_at(np.array([row]), np.array([col]))
            index = int(at[0])
            log_miss_d = float(looks.look.log_miss_d(np.array([row]), np.array([col]), at)[0])
            lam = -float(log_fa[0]) * math.pi * gate_m**2 / geo.cell_size_m**2
        if looks.nodes is not None:
            g.log_lr_nodes = grid.log_miss_nodes(cell)[0, 0].copy()
        else:
            g.log_lr = float(grid.read(Layer.LOG_MISS_D, cell)[0, 0])
        g.look = CountedLook(False, log_miss_d, lam, index)
        self._hit(looks, g, box, scale)
        return cid

    def _weigh_looks(self, looks: _FrameLooks, hit_by: Mapping[int, Box], scale: float,
                     ids: np.ndarray, pos: np.ndarray) -> None:
        """Count this frame's looks of the cells of the candidates ``ids`` held before it
        (at ``pos`` (n, 2), ENU m) and weigh them: a counted look a miss, then each box
        (``hit_by``, by candidate) makes its candidate's last counted look a hit if it was
        a miss (module docstring)."""
        last = looks.look
        if last is not None and len(ids):
            geo = looks.grid.geometry
            rows, cols = geo.cell_of(pos[:, 0], pos[:, 1])
            counted, _, index, log_fa = last.look_at(rows, cols)
            at = np.flatnonzero(counted)
            log_miss_d = last.log_miss_d(rows[at], cols[at], index[at])
            lam_per_m2 = -log_fa[at] * (math.pi / geo.cell_size_m**2)
            for k, cid in enumerate(ids[at].tolist()):
                g = self._groups.get(cid)  # None: evicted for a box of this frame
                if g is None:
                    continue
                g.looks += 1
                g.look = CountedLook(False, float(log_miss_d[k]),
                               float(lam_per_m2[k]) * g.gate_m**2, int(index[at[k]]))
                self._add_evidence(looks, g, g.look, miss=True)
        for cid, box in hit_by.items():
            hit = self._groups.get(cid)  # None: evicted for a box of this frame
            if hit is not None:
                self._hit(looks, hit, box, scale)

    def _hit(self, looks: _FrameLooks, g: CandidateState, box: Box, scale: float) -> None:
        """A box in ``g``'s gate: its last counted look becomes a hit if it was a miss
        (its miss evidence replaced by a hit's, and the box's confidence evidence)."""
        look = g.look
        if look is None or look.hit:
            return
        self._add_evidence(looks, g, look, miss=False)
        look.hit = True
        g.hits += 1
        size_px = scale * math.sqrt(box.width_px * box.height_px)
        g.log_lr += float(looks.grid.detector.confidence_log_lr(
            np.array([size_px]), np.array([box.confidence]))[0])

    @staticmethod
    def _add_evidence(looks: _FrameLooks, g: CandidateState, look: CountedLook, miss: bool) -> None:
        """Add a miss's log LR of ``look`` (``miss``), or turn its miss into a hit."""
        if looks.nodes is not None:
            log1m = looks.node_log1m(look.index)
            if g.log_lr_nodes is None:
                g.log_lr_nodes = np.zeros(N_NODES)
            p = -np.expm1(log1m)
            g.log_lr_nodes = g.log_lr_nodes + (
                miss_log_lr(p) if miss else hit_log_lr(p, look.lam) - miss_log_lr(p))
            return
        p = -math.expm1(look.log_miss_d)
        g.log_lr += float(miss_log_lr(p) if miss else hit_log_lr(p, look.lam) - miss_log_lr(p))

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

    # -- results ----------------------------------------------------------------------------

    def candidates(self, grid: CoverageGrid, ids: Iterable[int] | None = None
                   ) -> list[Candidate]:
        """The candidates ``ids`` (all when None; an evicted one is left out), in id order:
        their own looks and hits, p_person, and the cumulative P_D and P_FA ``grid`` (the
        published one) holds at their cells now (0 outside it)."""
        chosen = (list(self._groups) if ids is None
                  else sorted(i for i in set(ids) if i in self._groups))
        geo = grid.geometry
        out = []
        for i in chosen:
            g = self._groups[i]
            r = g.r_enu_m
            row, col = (int(v) for v in geo.cell_of(r[0], r[1]))
            inside = 0 <= row < geo.n_rows and 0 <= col < geo.n_cols
            cell = (row, row + 1, col, col + 1)
            pd = float(grid.read(Layer.PD, cell)[0, 0]) if inside else 0.0
            pfa = float(grid.read(Layer.PFA, cell)[0, 0]) if inside else 0.0
            log_odds = (prior_log_odds(self.prior.at(row, col), math.pi * g.gate_m**2)
                        + g.log_odds_evidence())
            out.append(Candidate(i, g.class_name, r, g.sigma_m, g.hits, g.looks,
                                 min(max(pd, 0.0), 1.0), min(max(pfa, 0.0), 1.0),
                                 g.confidence, g.first_t_boot_s, g.last_t_boot_s,
                                 self.uid_of(i), p_person(log_odds), g.first_unix_s,
                                 g.last_unix_s))
        return out

    # -- state ------------------------------------------------------------------------------

    def to_doc(self) -> dict[str, Any]:
        """The whole state, JSON-able (floats exact through ``json``): {"version",
        "next_id", "candidates": [``candidate_docs``]} (detection/candidate_state.py)."""
        return state_doc(self._groups, self._next_id)

    def candidate_docs(self, ids: Iterable[int]) -> list[dict[str, Any]]:
        """The states of the candidates ``ids`` held (an evicted one left out), in id
        order."""
        return candidate_docs(self._groups, ids)

    def load_doc(self, doc: Any) -> None:
        """Replace the state with ``to_doc``'s document (ValueError naming the field that is
        wrong; nothing changed then)."""
        groups, next_id = state_of_doc(doc)
        self._groups = dict(sorted(groups.items()))
        self._per_class = Counter(g.class_name for g in self._groups.values())
        self._next_id = next_id

    def apply_candidate_docs(self, docs: list[dict[str, Any]], next_id: int) -> None:
        """Set the candidates of ``docs`` (``candidate_docs``: a journal's entry) and the
        next id (ValueError naming the field that is wrong; nothing changed then)."""
        if not isinstance(docs, list):
            raise ValueError("candidate docs: expected a list")
        groups = candidates_of_docs(docs, "candidate docs")
        next_id = next_id_of(next_id, {**self._groups, **groups})
        for i, g in groups.items():
            old = self._groups.get(i)
            if old is not None:
                self._per_class[old.class_name] -= 1
            self._groups[i] = g
            self._per_class[g.class_name] += 1
        self._groups = dict(sorted(self._groups.items()))
        self._per_class = +self._per_class
        self._next_id = next_id

