"""Re-tasking from the ground station, with no I/O: a re-fly of the gaps of the live merged
grid for one vehicle, proposed to the operator, and, once confirmed, the request sent to
the vehicle's daemon on ``pdcov/<id>/retask`` (bus/retask.py; the sending is the shell's:
ground/live.py ``WatchShell.retask``).

The re-fly is ``pdcov refly``'s (planning/refly.py ``refly_of_grid``): the same settings,
over the fleet's merged grid (ground/fleet_report.py) instead of a grid.npz, starting where
the vehicle is now (its last status's pose) instead of home. The mission items are the
ones ``pdcov plan`` files carry (planning/plan_items.py ``mission_items``). pdcov never arms,
takes off or changes the flight mode: the pilot flies the new mission (docs/operations.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pdcov.bus.operator_keys import OperatorKey
from pdcov.bus.retask import RetaskReply, encode_signed_retask, plan_hash
from pdcov.config.mission import Mission
from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from pdcov.core.mission import MissionItem
from pdcov.core.tiles import MAX_DENSE_CELLS
from pdcov.errors import PdcovError
from pdcov.ground.watcher import Watcher
from pdcov.planning.mission_bounds import RetaskLimits, check_mission_bounds
from pdcov.planning.optimise import Scenario
from pdcov.planning.plan_items import mission_items
from pdcov.planning.refly import Refly, ReflySettings, independent_grid, refly_of_grid

__all__ = ["ReflyError", "ReflyInputs", "ReflyProposal", "RetaskNotSent", "propose_refly",
           "refly_inputs", "reply_line", "signed_request"]

LatLon = tuple[float, float]


class ReflyError(PdcovError):
    """No re-fly can be proposed now (the message says why and what to wait for)."""


class RetaskNotSent(PdcovError):
    """The ground station refuses to send a mission: no operator key, or items outside
    the mission's bounds (the message names them)."""


def signed_request(key: OperatorKey | None, vehicle_id: str, items: tuple[MissionItem, ...],
                   description: str, mission: Mission, home: Origin, unix_s: float,
                   nonce: str) -> bytes:
    """The signed request for ``items`` once they pass the bounds the vehicle enforces
    (the mission's ``service.retask_limits`` around its domain, home ``home``): the same
    rule as the daemon's (planning/mission_bounds.py). ``unix_s``: now, UTC s; ``nonce``:
    32 fresh random hex digits. RetaskNotSent saying why otherwise."""
    if key is None:
        raise RetaskNotSent(f"mission for {vehicle_id} not sent: no operator key (give "
                            "--operator-key KEYFILE; `pdcov keys new` makes one): the vehicle "
                            "obeys signed requests only")
    limits = RetaskLimits.from_service(mission.raw.get("service"))
    verdict = check_mission_bounds(items, mission.domain.boundary, home, limits)
    if not verdict.ok:
        raise RetaskNotSent(f"mission for {vehicle_id} not sent: out of the mission's bounds "
                            f"(service.retask_limits): {verdict.text()}")
    return encode_signed_retask(key, vehicle_id, items, description, unix_s, nonce)


@dataclass(frozen=True, slots=True)
class ReflyProposal:
    """A re-fly shown to the operator before it is sent. ``id``: the plan hash of its
    items (what the daemon's reply and log name); waypoints and gap rings (closed) as
    (lat, lon) degrees WGS84; gap cells before and predicted after; ``home``: the origin
    the items are written about (its ground altitude the vehicle's)."""

    id: str
    vehicle_id: str
    description: str
    items: tuple[MissionItem, ...]
    waypoints_lat_lon: tuple[LatLon, ...]
    gaps_lat_lon: tuple[tuple[LatLon, ...], ...]
    target_pd: float
    gap_cells_before: int
    gap_cells_after: int
    flight_time_s: float
    path_length_m: float
    start_enu_m: tuple[float, float]
    home: Origin

    def lines(self) -> list[str]:
        """What the operator reads before confirming."""
        return [f"re-fly for {self.vehicle_id} (mission {self.id}): {self.description}",
                f"gaps below P_D {self.target_pd:g}: {self.gap_cells_before} cells now, "
                f"{self.gap_cells_after} predicted after; {len(self.gaps_lat_lon)} gap areas",
                f"{len(self.waypoints_lat_lon)} waypoints, {len(self.items)} mission items, "
                f"about {self.flight_time_s:.0f} s and {self.path_length_m:.0f} m from where "
                f"the vehicle is now (ENU {self.start_enu_m[0]:.0f}, "
                f"{self.start_enu_m[1]:.0f} m)",
                "the autopilot's mission is replaced; pdcov does not arm, take off or "
                "change the mode: the pilot does"]

    def map_state(self) -> dict[str, Any]:
        """The web map's ``refly`` field ([lat, lon] pairs)."""
        return {"id": self.id, "vehicle": self.vehicle_id, "description": self.description,
                "target_pd": self.target_pd, "lines": self.lines(),
                "waypoints": [list(p) for p in self.waypoints_lat_lon],
                "gaps": [[list(p) for p in ring] for ring in self.gaps_lat_lon]}


def _vehicle_origin(watcher: Watcher, vehicle_id: str, mission: Mission) -> Origin:
    """The mission origin with the ground altitude the vehicle's daemon uses (its home),
    else the mission's: mission items in MSL are written from it."""
    status = watcher.feeds[vehicle_id].status or {}
    alt = ((status.get("grid") or {}).get("origin") or {}).get("ground_alt_msl_m")
    return mission.origin(alt if isinstance(alt, (int, float)) else None)


def _start_enu_m(watcher: Watcher, vehicle_id: str, origin: Origin) -> tuple[float, float]:
    """Where the vehicle is now (its last status's pose), ENU m; home (0, 0) without one."""
    pose = (watcher.feeds[vehicle_id].status or {}).get("pose")
    if not isinstance(pose, dict):
        return (0.0, 0.0)
    e, n, _ = geodetic_to_enu(pose["lat_deg"], pose["lon_deg"], origin.ground_alt_msl_m,
                              origin)
    return (round(float(e), 2), round(float(n), 2))


def _lat_lon(xy_enu_m: np.ndarray, origin: Origin) -> tuple[LatLon, ...]:
    xy = np.asarray(xy_enu_m, dtype=float).reshape(-1, 2)
    llh = enu_to_geodetic(np.column_stack([xy, np.zeros(len(xy))]), origin)
    return tuple((round(float(lat), 8), round(float(lon), 8)) for lat, lon, _ in llh)


@dataclass(frozen=True, slots=True)
class ReflyInputs:
    """What a re-fly is computed from, taken from the watcher at one moment (on its
    thread): the vehicle, the merged grid's log-miss sums (a copy), the origin its mission
    items are written about and where the vehicle is (ENU m)."""

    vehicle_id: str
    log_miss_d: np.ndarray
    origin: Origin
    start_enu_m: tuple[float, float]


def refly_inputs(watcher: Watcher, mission: Mission, config_grid_hash: str,
                 vehicle_id: str) -> ReflyInputs:
    """The inputs of a re-fly for ``vehicle_id``: the merged grid must be the mission's
    (``config_grid_hash``: the ground station's --config) and hold the vehicle's grid;
    ReflyError saying what to wait for or fix otherwise."""
    merged, members = watcher.fleet_state()
    if vehicle_id not in watcher.feeds:
        raise ReflyError(f"re-fly: vehicle {vehicle_id!r} not heard (vehicles: "
                         f"{', '.join(sorted(watcher.feeds)) or 'none yet'})")
    if merged is None:
        raise ReflyError("re-fly: no grid yet (wait for the vehicles' snapshots)")
    if merged.hash != config_grid_hash:
        raise ReflyError(f"re-fly: the fleet flies grid {merged.hash}, the mission config "
                         f"describes grid {config_grid_hash}: give the config of the mission "
                         "flown (--config)")
    if vehicle_id not in members:
        raise ReflyError(f"re-fly: vehicle {vehicle_id!r} has no grid of {merged.hash} in "
                         f"the merged grid ({', '.join(members)})")
    g = merged.geometry
    if g.n_rows * g.n_cols > MAX_DENSE_CELLS:
        raise ReflyError(f"re-fly: the grid's {g.n_rows * g.n_cols:,} cells are more than "
                         f"a re-fly plans over ({MAX_DENSE_CELLS:,}): plan it with pdcov "
                         "refly on a mission of the area to search again")
    origin = _vehicle_origin(watcher, vehicle_id, mission)
    return ReflyInputs(vehicle_id, merged.log_miss_d.copy(), origin,
                       _start_enu_m(watcher, vehicle_id, origin))


def propose_refly(inputs: ReflyInputs, scenario: Scenario, settings: ReflySettings
                  ) -> ReflyProposal:
    """The re-fly of the merged grid's gaps (``refly_of_grid``, as ``pdcov refly``) from
    where the vehicle is; ConfigError from the planner (no gaps, a plan too large). Pure:
    it may run off the event loop."""
    r: Refly = refly_of_grid(scenario, independent_grid(scenario, inputs.log_miss_d), settings,
                             inputs.start_enu_m)
    origin = inputs.origin
    items = mission_items(r.plan, origin)
    description = r.plan.description
    return ReflyProposal(
        id=plan_hash(items), vehicle_id=inputs.vehicle_id, description=description,
        items=items, waypoints_lat_lon=_lat_lon(r.plan.xy_enu_m, origin),
        gaps_lat_lon=tuple(_lat_lon(np.asarray(p.exterior.coords), origin)
                           for p in r.gaps_before.regions),
        target_pd=settings.target_pd, gap_cells_before=r.gaps_before.n_cells,
        gap_cells_after=r.gaps_after.n_cells,
        flight_time_s=r.prediction.flight.duration_s,
        path_length_m=r.prediction.flight.path_length_m, start_enu_m=inputs.start_enu_m,
        home=origin)


def reply_line(proposal: ReflyProposal, reply: RetaskReply | None) -> str:
    """The operator's line for the daemon's answer (None: no answer from the vehicle's
    trusted session in time)."""
    who = f"{proposal.vehicle_id} mission {proposal.id}"
    if reply is None:
        return (f"re-fly {who}: no answer from the vehicle's daemon (not reachable, or the "
                "bus's access control refused this ground station)")
    if reply.accepted:
        return (f"re-fly {who}: the autopilot accepted {reply.items} items ({reply.reason}); "
                "the pilot flies it (AUTO)")
    return f"re-fly {who}: NOT taken: {reply.reason}: {reply.detail}"
