"""Vantage-point missions: the cover (planning/vantage.py), the routes of the fleet
(planning/tours.py), each route's plan and its prediction, and their merged grid.

Each route is predicted as every plan is (``optimise.predict``: flown kinematically over the
scenario's terrain at the frame rate through a fresh grid); the routes' grids merge by adding
their log-miss sums. ``flight_time_s`` of a mission adds to its predicted flight (first to
last waypoint) the legs from home and back (``tours.leg_time_s``) and the climb and descent
(``sortie_overhead_s``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.mission import GimbalCommand, HoverItem
from pdcov.errors import ConfigError
from pdcov.planning.optimise import PlanParams, Prediction, Scenario, Score, predict
from pdcov.planning.tours import Fleet, Route, Transits, leg_time_s, plan_routes, route_plan
from pdcov.planning.vantage import (
    VantageCover,
    VantageSettings,
    choose_vantage_points,
    clearance_of,
    flight_space,
)

ONE_VEHICLE = Fleet()
_BUDGET_TRIES = 5
_DEFAULT_CLIMB_MPS = 2.5
_DEFAULT_DESCENT_MPS = 1.5
"""ArduCopter's WPNAV_SPEED_UP / WPNAV_SPEED_DN, where the terrain limits give none."""


@dataclass(frozen=True, slots=True)
class VantageMission:
    """One route: which vehicle and sortie, its prediction, and its time from take-off to
    landing (s)."""

    route: Route
    prediction: Prediction
    flight_time_s: float


@dataclass(frozen=True, slots=True)
class VantageMissions:
    """The settings, the cover, the missions, and the grid of all of them."""

    settings: VantageSettings
    cover: VantageCover
    missions: tuple[VantageMission, ...]
    grid: CoverageGrid

    @property
    def longest_s(self) -> float:
        return max(m.flight_time_s for m in self.missions)

    @property
    def path_length_m(self) -> float:
        return sum(m.prediction.flight.path_length_m for m in self.missions)


def sortie_overhead_s(sc: Scenario, alt_agl_m: float) -> float:
    """Climb to ``alt_agl_m`` and descent from it (s) at the terrain limits' rates."""
    f = sc.following
    return (alt_agl_m / (f.max_climb_mps or _DEFAULT_CLIMB_MPS)
            + alt_agl_m / (f.max_descent_mps or _DEFAULT_DESCENT_MPS))


def plan_vantage_missions(sc: Scenario, settings: VantageSettings, fleet: Fleet = ONE_VEHICLE,
                          gimbal_command: GimbalCommand = GimbalCommand.MANAGER,
                          routing_time_s: float = 2.0,
                          hover_item: HoverItem = HoverItem.WAYPOINT, *,
                          progress: bool = False) -> VantageMissions:
    """Choose the points, route the fleet from home (ENU 0, 0) and predict each mission:
    each point's gimbal pointing commanded with ``gimbal_command`` (the mount command has
    no earth-frame yaw: ConfigError), its hover written as ``hover_item``. ``progress``:
    bars on stderr over the candidate views and each mission's predicted frames."""
    if gimbal_command is GimbalCommand.MOUNT and settings.gimbal_yaws:
        raise ConfigError(f"--gimbal-yaws {settings.gimbal_yaws}: MAV_CMD_DO_MOUNT_CONTROL "
                          "takes the yaw relative to the vehicle (ArduPilot AP_Mount), so "
                          "earth-frame yaws need --gimbal-command manager (or give "
                          "--gimbal-yaws 0)")
    cover = choose_vantage_points(sc, settings, progress=progress)
    space = flight_space(sc.free_space, clearance_of(sc, settings))
    points = cover.points
    home = np.zeros(2)
    nodes = np.vstack([home, [[p.x_enu_m, p.y_enu_m] for p in points]])
    transits = Transits(space, nodes)
    accel = sc.kinematics.max_accel_mps2
    v = settings.speed_mps
    overhead = sortie_overhead_s(sc, max(settings.alts_agl_m))
    # The routing's leg times leave out the turns at the stops (the heading rate): when a
    # predicted sortie overruns the limit, route again within a budget shrunk by as much.
    budget = fleet
    for _ in range(_BUDGET_TRIES):
        routes = plan_routes(points, home, transits, budget, v, accel, overhead,
                             routing_time_s)
        missions = []
        for r in routes:
            what = (f"vantage: {len(r.stops)} of {len(points)} points, P_D "
                    f"{settings.target_pd:g} on {settings.target_share:.0%} of the cells"
                    + (f"; vehicle {r.vehicle} sortie {r.sortie}" if len(routes) > 1 else ""))
            plan = replace(route_plan(r, points, transits, v, accel,
                                      sc.kinematics.gimbal_rate_rad_s, what),
                           gimbal_command=gimbal_command, hover_item=hover_item)
            pred = predict(sc, plan, PlanParams("vantage", points[r.stops[0]].alt_agl_m, v),
                           progress=progress)
            ends = leg_time_s(np.linalg.norm(pred.plan.xy_enu_m[[0, -1]], axis=1), v, accel)
            missions.append(VantageMission(r, pred, pred.flight.duration_s
                                           + float(ends.sum()) + overhead))
        limit = fleet.max_flight_time_s
        longest = max(m.flight_time_s for m in missions)
        if limit is None or longest <= limit:
            break
        budget = Fleet(fleet.n_vehicles,
                       (budget.max_flight_time_s or limit) * 0.99 * limit / longest)
    else:
        raise ConfigError(f"--max-flight-time-s {fleet.max_flight_time_s:g}: a predicted "
                          f"sortie still takes {longest:.0f} s after {_BUDGET_TRIES} "
                          "routings; raise it")
    grid = sc.new_grid()
    for m in missions:
        grid.merge(m.prediction.grid)
    return VantageMissions(settings, cover, tuple(missions), grid)


def vantage_score(sc: Scenario, settings: VantageSettings, fleet: Fleet = ONE_VEHICLE,
                  routing_time_s: float = 2.0) -> Score:
    """The vantage missions on the axes of ``optimise.sweep``: the proportion of free cells
    at the target, the longest mission's predicted flight (first to last waypoint, as the
    sweep's plans are timed), the total path and the number of missions."""
    m = plan_vantage_missions(sc, settings, fleet, routing_time_s=routing_time_s)
    pd = m.grid.pd[sc.mask]
    params = PlanParams("vantage", min(settings.alts_agl_m), settings.speed_mps)
    longest = max(x.prediction.flight.duration_s for x in m.missions)
    return Score(params, math.nan, float((pd >= settings.target_pd).mean()), longest,
                 m.path_length_m, float(pd.mean()), len(m.missions))
