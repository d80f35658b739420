"""What the watcher reports (ground/watcher.py ``Watcher.report``): each vehicle's figures,
the fleet's merged grid and figures, and the lines the operator must be told. Values and
pure functions: the terminal view, the web map and the recording read them."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pdcov.bus.detections import LIKELY_P_PERSON
from pdcov.bus.grid_state import GridState
from pdcov.bus.tile_metrics import GridSummary
from pdcov.core.grid_layer import Layer, Window
from pdcov.ground.claims import short_session
from pdcov.ground.feed import VehicleFeed

__all__ = ["FleetReport", "VehicleReport", "fleet_group", "merge_fleet", "merge_states",
           "merge_window", "union_thresholds", "vehicle_report"]


@dataclass(frozen=True, slots=True)
class VehicleReport:
    """One vehicle's figures. proportion_at_or_above / mean_pd come from the rebuilt grid
    when it is ready, else from the last status; age_s: seconds since its last message
    (None: nothing yet); link: the daemon's link state ("" unknown)."""

    vehicle_id: str
    alive: bool | None
    grid_ready: bool
    thresholds: tuple[float, ...]
    proportion_at_or_above: dict[float, float]
    mean_pd: float | None
    frames_used: int | None
    frames_skipped: int | None
    link: str
    age_s: float | None
    status_proportion_at_or_above: dict[float, float]
    gaps: int
    snapshots: int
    bad_payloads: int
    session: str | None = None
    rivals: tuple[str, ...] = ()
    contested: bool = False
    refused: int = 0
    status_disagreements: int = 0
    status_agrees: bool | None = None
    candidates: int = 0
    candidates_likely: int = 0
    """Candidates with p_person >= bus.detections.LIKELY_P_PERSON."""
    candidates_dropped: int = 0
    best_candidate: str | None = None
    """The most probable candidate: 'person uav1.3fa2c1.3: p_person 0.973, detected 9 of 14
    looks'."""

    @property
    def warnings(self) -> tuple[str, ...]:
        """What the operator must be told about this vehicle, one line each."""
        out = []
        if self.contested:
            out.append(f"{self.vehicle_id}: sessions {', '.join(self.rivals)} all answer as "
                       "this vehicle: its map is not trusted until one remains")
        elif self.rivals:
            out.append(f"{self.vehicle_id}: session {', '.join(self.rivals)} also claims this "
                       f"vehicle ({self.refused} samples refused; trusted: {self.session})")
        if self.status_agrees is False:
            out.append(f"{self.vehicle_id}: its status disagrees with the grid rebuilt from "
                       f"its tiles ({self.status_disagreements} times): grid fetched again")
        if self.candidates_dropped:
            out.append(f"{self.vehicle_id}: {self.candidates_dropped} weakest detection "
                       f"candidates forgotten (more than {self.candidates} to keep)")
        return tuple(out)


@dataclass(frozen=True, slots=True)
class FleetReport:
    """The fleet's merged figures over the vehicles in ``merged`` (those sharing one grid),
    and each vehicle's. target: the threshold shown large (the highest configured)."""

    vehicles: tuple[VehicleReport, ...]
    merged: tuple[str, ...]
    thresholds: tuple[float, ...]
    target: float | None
    proportion_at_or_above: dict[float, float]
    mean_pd: float | None
    cells_free: int
    refused: dict[str, int] = field(default_factory=dict)
    station: tuple[str, ...] = ()
    """The ground station's own warnings (its bus, its recording)."""
    unknown: dict[str, str] = field(default_factory=dict)
    """Vehicles heard but not merged (not on the roster), with why."""
    notes: tuple[str, ...] = ()
    """What the views say without warning (there is no fleet roster)."""

    @property
    def warnings(self) -> tuple[str, ...]:
        """The station's warnings, the unknown vehicles, every vehicle's, then the payloads
        refused."""
        out = [*self.station, *(f"unknown vehicle {vid}: {why}"
                                for vid, why in self.unknown.items()),
               *(w for v in self.vehicles for w in v.warnings)]
        if self.refused:
            out.append("refused: " + ", ".join(f"{n} {why}" for why, n in
                                               sorted(self.refused.items())))
        return tuple(out)


def vehicle_report(feed: VehicleFeed, now_s: float, default_thresholds: tuple[float, ...]
               ) -> VehicleReport:
    """One vehicle's figures as of ``now_s``: from its rebuilt grid when ready, else from
    its last status; ``default_thresholds`` until its status lists its own."""
    status = feed.status or {}
    claim = feed.claim
    thresholds = tuple(float(t) for t in status.get("thresholds", default_thresholds))
    status_props = {float(k): float(v)
                    for k, v in (status.get("proportion_at_or_above") or {}).items()}
    ready = feed.state is not None and feed.awaiting_since_s is None
    summary = feed.summary(thresholds) if ready else None
    if summary is not None:
        props = {t: summary.proportion_at_or_above(t) for t in thresholds}
        mean_pd: float | None = summary.mean_pd
    else:
        props = status_props
        mean_pd = status.get("mean_pd")
    frames = status.get("frames") or {}
    skipped = frames.get("skipped")
    link = status.get("link") or {}
    return VehicleReport(
        vehicle_id=feed.vehicle_id, alive=feed.alive, grid_ready=ready,
        thresholds=thresholds, proportion_at_or_above=props, mean_pd=mean_pd,
        frames_used=frames.get("used"),
        frames_skipped=(sum(v for v in skipped.values() if isinstance(v, int))
                        if isinstance(skipped, dict) else skipped),
        link=str(link.get("state", "")) if isinstance(link, dict) else str(link),
        age_s=None if feed.last_msg_s is None else max(0.0, now_s - feed.last_msg_s),
        status_proportion_at_or_above=status_props, gaps=feed.gaps,
        snapshots=feed.snapshots, bad_payloads=feed.bad_payloads,
        session=short_session(claim.session) if claim.pinned else None,
        rivals=tuple(short_session(s) for s in (claim.contested or claim.rivals(now_s))),
        contested=bool(claim.contested), refused=claim.refused,
        status_disagreements=feed.status_disagreements, status_agrees=feed.status_agrees,
        candidates=len(feed.candidates), candidates_dropped=feed.candidates_dropped,
        candidates_likely=sum(c["p_person"] >= LIKELY_P_PERSON
                              for c in feed.candidates.values()),
        best_candidate=_best_candidate(feed))


def _best_candidate(feed: VehicleFeed) -> str | None:
    if not feed.candidates:
        return None
    c = max(feed.candidates.values(), key=lambda c: (c["p_person"], c["hits"],
                                                     c["confidence"]))
    return (f"{c['class']} {c['uid']}: p_person {c['p_person']:.3f}, detected {c['hits']} "
            f"of {c['looks']} looks")


def union_thresholds(groups: Any) -> tuple[float, ...]:
    """The sorted union of threshold groups."""
    out: set[float] = set()
    for g in groups:
        out.update(g)
    return tuple(sorted(out))


def fleet_group(feeds: Iterable[VehicleFeed], grid_hash: str | None) -> list[VehicleFeed]:
    """The ready vehicles that share the fleet's grid, by id: ``grid_hash`` (the ground
    station's) when a vehicle flies it, else the one most vehicles fly (ties: the vehicle
    heard first)."""
    ready = [f for f in feeds
             if f.state is not None and f.awaiting_since_s is None]
    if not ready:
        return []
    hashes = Counter(f.grid_hash for f in ready)
    if grid_hash in hashes:
        top = grid_hash
    else:
        first = {f.grid_hash: f.first_heard_s for f in
                 sorted(ready, key=lambda f: f.first_heard_s, reverse=True)}
        top = max(hashes, key=lambda h: (hashes[h], -first[h]))
    return sorted((f for f in ready if f.grid_hash == top), key=lambda f: f.vehicle_id)


def merge_states(states: list[GridState]) -> GridState:
    """Grids of one geometry and mask added in the order given (``merge_window`` over every
    tile any of them wrote)."""
    base = states[0]
    merged = GridState(base.geometry, base.free, frames=sum(s.frames for s in states),
                       limiting_known=all(s.limiting_known for s in states),
                       n_obs_dtype=np.int64)
    keys = sorted({k for s in states for k in s.tile_keys()})
    for key in keys:
        merge_window(merged, states, base.free.layout.window_of(key))
    return merged


def merge_window(merged: GridState, states: list[GridState], window: Window) -> None:
    """Write into ``merged`` the cells of ``window`` of ``states`` added in the order given:
    log-miss sums as float32, as the daemons hold them; counts in int64, which cannot
    overflow; the limiting factor the maximum (as CoverageGrid.merge), when known."""
    for layer in (Layer.LOG_MISS_D, Layer.LOG_MISS_FA, Layer.N_OBS):
        out = states[0].read(layer, window)
        if layer is Layer.N_OBS:
            out = out.astype(np.int64)
        for s in states[1:]:
            out += s.read(layer, window)
        merged.write(layer, window, out)
    if merged.limiting_known:
        merged.write(Layer.LIMITING, window,
                     np.maximum.reduce([s.read(Layer.LIMITING, window) for s in states]))


def merge_fleet(feeds: Iterable[VehicleFeed], grid_hash: str | None
                ) -> tuple[GridState | None, tuple[str, ...]]:
    """The merged grid of the fleet's vehicles (``fleet_group``), their grids added in id
    order (``merge_states``), and their ids; the whole grid each time (the watcher keeps
    it tile by tile: ground/fleet_merge.py)."""
    group = fleet_group(feeds, grid_hash)
    if not group:
        return None, ()
    return (merge_states([f.state for f in group if f.state is not None]),
            tuple(f.vehicle_id for f in group))


STATUS_PD_TOLERANCE = 1e-6
"""How far a status's mean P_D may be from the rebuilt grid's (the daemon sums per tile in
float64: about 1e-16 apart; the status carries full float64 digits)."""


def status_agrees(grid: GridSummary, doc: dict[str, Any]) -> bool:
    """Whether a status's figures are those of the rebuilt grid's (``grid``: its figures at
    the status's thresholds at least; same frames, every changed tile sent): each share at a
    threshold within half a cell, mean P_D within STATUS_PD_TOLERANCE."""
    free = grid.cells_free
    if doc["cells_free"] != free:
        return False
    if not free:
        return True
    shares = doc["proportion_at_or_above"]
    if any(abs(grid.proportion_at_or_above(float(name)) - share) > 0.5 / free
           for name, share in shares.items()):
        return False
    return abs(grid.mean_pd - doc["mean_pd"]) <= STATUS_PD_TOLERANCE
