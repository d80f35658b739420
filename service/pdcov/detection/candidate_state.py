"""One candidate's state (a pin: the detections grouped by ``DetectionTracker``,
detection/candidates.py) and its JSON document, with no I/O: what a checkpoint and the
candidates' journal hold so that a restored tracker continues exactly as the one it was
saved from (floats exact through ``json``; reading raises ValueError naming the field)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pdcov.core.detections import valid_class_name
from pdcov.core.looks import QUADRATURE
from pdcov.detection.pin_evidence import log_lr_of_nodes

__all__ = ["MIN_SIGMA_M", "N_NODES", "STATE_VERSION", "CandidateState", "CountedLook",
           "candidate_docs", "candidates_of_docs", "next_id_of", "state_doc", "state_of_doc"]

STATE_VERSION = 1
"""Version of ``state_doc``'s document."""
MIN_SIGMA_M = 1e-3
"""The least sigma a ground point is weighed with (m)."""
N_NODES = len(QUADRATURE.q)
"""Quadrature nodes of correlated looks (``core.looks.QUADRATURE``)."""


@dataclass(slots=True)
class CountedLook:
    """A candidate's last counted look: whether it was a hit, and what a miss there is
    turned into a hit with: its per-look log(1 - P_D), lambda (false boxes expected in the
    gate) and table index (for the quadrature nodes)."""

    hit: bool
    log_miss_d: float
    lam: float
    index: int


@dataclass(slots=True)
class CandidateState:
    """One candidate: the inverse-variance weighted sums of its detections' ground points
    (ENU m), its looks and hits, and the evidence of its looks and boxes (log LR); its
    first and last detections' times (boot clock, and UTC s since 1970: NaN unknown)."""

    class_name: str
    sum_w: float
    sum_wr: np.ndarray  # (3,) sum of weight * ground point
    hits: int
    looks: int
    confidence: float
    first_t_boot_s: float
    last_t_boot_s: float
    gate_m: float  # the gate radius at birth: the area of its prior and lambda (m)
    log_lr: float  # evidence not per node: every look's without nodes, confidences' always
    log_lr_nodes: np.ndarray | None  # (J,) looks' log LR per quadrature node (correlated)
    look: CountedLook | None  # its last counted look
    first_unix_s: float = math.nan
    last_unix_s: float = math.nan
    r_enu_m: np.ndarray = field(init=False)  # sum_wr / sum_w: its position (ENU m)

    def __post_init__(self) -> None:
        self.r_enu_m = self.sum_wr / self.sum_w

    @property
    def sigma_m(self) -> float:
        return math.sqrt(1.0 / self.sum_w)

    def add_point(self, r: np.ndarray, sigma_m: float) -> None:
        w = 1.0 / max(sigma_m, MIN_SIGMA_M) ** 2
        self.sum_w += w
        self.sum_wr = self.sum_wr + w * r
        self.r_enu_m = self.sum_wr / self.sum_w

    def detected_at(self, t_boot_s: float, unix_s: float) -> None:
        """A detection of it at ``t_boot_s`` (boot clock, s), UTC ``unix_s`` (NaN:
        unknown, which leaves the UTC times as they are)."""
        self.first_t_boot_s = min(self.first_t_boot_s, t_boot_s)
        self.last_t_boot_s = max(self.last_t_boot_s, t_boot_s)
        if math.isfinite(unix_s):
            self.first_unix_s = min(self.first_unix_s, unix_s) if math.isfinite(
                self.first_unix_s) else unix_s
            self.last_unix_s = max(self.last_unix_s, unix_s) if math.isfinite(
                self.last_unix_s) else unix_s

    def log_odds_evidence(self) -> float:
        """The sum of its looks' and confidences' log LR."""
        nodes = 0.0 if self.log_lr_nodes is None else log_lr_of_nodes(self.log_lr_nodes)
        return self.log_lr + nodes


# -- documents ------------------------------------------------------------------------------

def state_doc(groups: Mapping[int, CandidateState], next_id: int) -> dict[str, Any]:
    """The whole state of a tracker holding ``groups`` (by id): {"version", "next_id",
    "candidates": [``candidate_docs``]}."""
    return {"version": STATE_VERSION, "next_id": next_id,
            "candidates": candidate_docs(groups, groups)}


def candidate_docs(groups: Mapping[int, CandidateState], ids: Iterable[int]
                   ) -> list[dict[str, Any]]:
    """The states of the candidates ``ids`` of ``groups`` (one not held left out), in id
    order."""
    return [_group_doc(i, groups[i]) for i in sorted(set(ids)) if i in groups]


def state_of_doc(doc: Any) -> tuple[dict[int, CandidateState], int]:
    """The candidates (by id) and next id of ``state_doc``'s document (ValueError naming
    the field that is wrong)."""
    if not isinstance(doc, Mapping):
        raise ValueError(f"candidates state: expected a mapping, got {type(doc).__name__}")
    if doc.get("version") != STATE_VERSION:
        raise ValueError(f"candidates state version {doc.get('version')!r}: expected "
                         f"{STATE_VERSION}")
    docs = doc.get("candidates")
    if not isinstance(docs, list):
        raise ValueError("candidates state candidates: expected a list")
    groups = candidates_of_docs(docs, "candidates state candidates")
    return groups, next_id_of(doc.get("next_id"), groups)


def _group_doc(cid: int, g: CandidateState) -> dict[str, Any]:
    look = g.look
    return {
        "id": cid, "class_name": g.class_name, "sum_w": float(g.sum_w),
        "sum_wr": [float(v) for v in g.sum_wr], "hits": g.hits, "looks": g.looks,
        "confidence": float(g.confidence), "first_t_boot_s": float(g.first_t_boot_s),
        "last_t_boot_s": float(g.last_t_boot_s), "gate_m": float(g.gate_m),
        "first_unix_s": _or_none(g.first_unix_s), "last_unix_s": _or_none(g.last_unix_s),
        "log_lr": float(g.log_lr),
        "log_lr_nodes": (None if g.log_lr_nodes is None
                         else [float(v) for v in g.log_lr_nodes]),
        "look": None if look is None else {
            "hit": look.hit, "log_miss_d": float(look.log_miss_d), "lam": float(look.lam),
            "index": look.index},
    }


def candidates_of_docs(docs: list[Any], where: str) -> dict[int, CandidateState]:
    """The candidates of ``candidate_docs`` documents (ValueError naming the field)."""
    out: dict[int, CandidateState] = {}
    for k, d in enumerate(docs):
        at = f"{where}[{k}]"
        if not isinstance(d, Mapping):
            raise ValueError(f"{at}: expected a mapping")
        cid = _int(d, "id", at)
        if cid in out:
            raise ValueError(f"{at}.id {cid}: given twice")
        name = d.get("class_name")
        if not isinstance(name, str) or not valid_class_name(name):
            raise ValueError(f"{at}.class_name {name!r}: expected a class name")
        sum_w = _num(d, "sum_w", at)
        if not sum_w > 0:
            raise ValueError(f"{at}.sum_w {sum_w!r}: expected a number > 0")
        sum_wr = _nums(d, "sum_wr", at, 3)
        hits, looks = _int(d, "hits", at), _int(d, "looks", at)
        if hits > looks:
            raise ValueError(f"{at}.hits {hits}: more than its looks {looks}")
        confidence = _num(d, "confidence", at)
        if not 0 <= confidence <= 1:
            raise ValueError(f"{at}.confidence {confidence!r}: expected a number in [0, 1]")
        first, last = _num(d, "first_t_boot_s", at), _num(d, "last_t_boot_s", at)
        if not 0 <= first <= last:
            raise ValueError(f"{at}.first_t_boot_s {first!r}, last_t_boot_s {last!r}: "
                             "expected 0 <= first <= last (s)")
        gate_m = _num(d, "gate_m", at)
        if not gate_m > 0:
            raise ValueError(f"{at}.gate_m {gate_m!r}: expected a number > 0 (m)")
        nodes = (None if d.get("log_lr_nodes") is None
                 else _nums(d, "log_lr_nodes", at, N_NODES))
        out[cid] = CandidateState(name, sum_w, sum_wr, hits, looks, confidence, first, last,
                                  gate_m, _num(d, "log_lr", at), nodes,
                                  _look_of(d.get("look"), at), _unix(d, "first_unix_s", at),
                                  _unix(d, "last_unix_s", at))
    return out


def _look_of(doc: Any, at: str) -> CountedLook | None:
    if doc is None:
        return None
    at = f"{at}.look"
    if not isinstance(doc, Mapping):
        raise ValueError(f"{at}: expected a mapping or null")
    hit = doc.get("hit")
    if not isinstance(hit, bool):
        raise ValueError(f"{at}.hit {hit!r}: expected true or false")
    log_miss_d, lam = _num(doc, "log_miss_d", at), _num(doc, "lam", at)
    if log_miss_d > 0 or lam < 0:
        raise ValueError(f"{at}: expected log_miss_d <= 0 and lam >= 0, got {log_miss_d!r}, "
                         f"{lam!r}")
    return CountedLook(hit, log_miss_d, lam, _int(doc, "index", at))


def next_id_of(v: Any, groups: Mapping[int, CandidateState]) -> int:
    """``v`` as the next candidate id after ``groups`` (ValueError when it is not one)."""
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ValueError(f"candidates next_id {v!r}: expected an integer >= 0")
    if groups and v <= max(groups):
        raise ValueError(f"candidates next_id {v}: not above the candidate id {max(groups)}")
    return v


def _or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _unix(d: Mapping[str, Any], key: str, at: str) -> float:
    """An optional UTC time (s): absent or null (a state saved before they were kept, or
    unknown) is NaN."""
    return math.nan if d.get(key) is None else _num(d, key, at)


def _int(d: Mapping[str, Any], key: str, at: str) -> int:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise ValueError(f"{at}.{key} {v!r}: expected an integer >= 0")
    return v


def _num(d: Mapping[str, Any], key: str, at: str) -> float:
    v = d.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{at}.{key} {v!r}: expected a finite number")
    return float(v)


def _nums(d: Mapping[str, Any], key: str, at: str, n: int) -> np.ndarray:
    v = d.get(key)
    if not (isinstance(v, list) and len(v) == n and all(
            not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x)
            for x in v)):
        raise ValueError(f"{at}.{key}: expected a list of {n} finite numbers")
    return np.array(v, dtype=np.float64)
