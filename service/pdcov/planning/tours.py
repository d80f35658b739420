"""The order in which vehicles visit vantage points: a vehicle routing problem solved by
OR-Tools (``pip install 'pdcov[routing]'``), with transits through the flight space.

Every pair of stops (home and the points) is joined by the shortest path through the flight
space (planning/routing.py: the free space kept clear of obstacles and the domain's edge);
its time is that of a stop-to-stop leg of that length (accelerating at the kinematics'
limit to the transit speed and braking again: d / v + v / a, or 2 sqrt(d / a) when too short
to reach v), and a stop adds its hover. Routes start and end at home.

* one vehicle: a tour (travelling salesman) of least time;
* ``n_vehicles``: that many routes, minimising the longest (OR-Tools' global span cost) and
  then the total;
* ``max_flight_time_s``: sorties that each return home within it, counting the climb to the
  first point and the descent at home (climb and descent rates of the terrain-following
  limits); as few as the solver finds feasible (routes = vehicles x sorties each).

OR-Tools' guided local search runs for ``time_limit_s``; the result may differ a little
between runs on a loaded machine, never in feasibility.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from shapely.geometry import MultiPolygon, Polygon

from pdcov.errors import ConfigError
from pdcov.extras import ROUTING
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.routing import FreeSpaceRouter
from pdcov.planning.trajectory import slew_time_s
from pdcov.planning.vantage import VantagePoint

_MS = 1000.0  # OR-Tools works in integers: milliseconds


@dataclass(frozen=True, slots=True)
class Fleet:
    """How many vehicles fly, and each sortie's time limit (s; None: one sortie each)."""

    n_vehicles: int = 1
    max_flight_time_s: float | None = None

    def __post_init__(self) -> None:
        if self.n_vehicles < 1:
            raise ConfigError(f"--vehicles: expected at least 1, got {self.n_vehicles}")
        if self.max_flight_time_s is not None and not self.max_flight_time_s > 0:
            raise ConfigError(f"--max-flight-time-s: expected > 0 s, got "
                              f"{self.max_flight_time_s}")


@dataclass(frozen=True, slots=True)
class Route:
    """One mission: its vehicle and sortie (from 1), the stops (indices of the points, in
    order) and the routing's estimate of its time from the first climb to the landing (s)."""

    vehicle: int
    sortie: int
    stops: tuple[int, ...]
    time_s: float


def leg_time_s(length_m: np.ndarray, speed_mps: float, accel_mps2: float) -> np.ndarray:
    """Time (s) of stop-to-stop legs of ``length_m`` (module doc)."""
    d = np.asarray(length_m, dtype=float)
    full = d / speed_mps + speed_mps / accel_mps2
    return np.where(d >= speed_mps**2 / accel_mps2, full, 2.0 * np.sqrt(d / accel_mps2))


class Transits:
    """Shortest paths through ``space`` between the nodes (home first, then the points)
    and their lengths (m)."""

    def __init__(self, space: Polygon | MultiPolygon, nodes_enu_m: np.ndarray):
        router = FreeSpaceRouter(space)
        n = len(nodes_enu_m)
        self.paths: dict[tuple[int, int], np.ndarray] = {}
        self.length_m = np.zeros((n, n))
        for i in range(n):
            for j in range(i + 1, n):
                p = router.path(nodes_enu_m[i], nodes_enu_m[j])
                self.paths[(i, j)], self.paths[(j, i)] = p, p[::-1]
                self.length_m[i, j] = self.length_m[j, i] = float(
                    np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def path(self, i: int, j: int) -> np.ndarray:
        return self.paths[(i, j)] if i != j else np.zeros((0, 2))


def _solve(time_ms: np.ndarray, n_routes: int, capacity_ms: int | None,
           time_limit_s: float) -> list[list[int]] | None:
    """OR-Tools routes over nodes 1..n from node 0 (``time_ms[i, j]``: i to j, with j's
    hover); None when no solution was found (infeasible within the capacity)."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    n = len(time_ms)
    manager = pywrapcp.RoutingIndexManager(n, n_routes, 0)
    model = pywrapcp.RoutingModel(manager)
    table = time_ms.tolist()

    def cost(a: int, b: int) -> int:
        return table[manager.IndexToNode(a)][manager.IndexToNode(b)]

    cb = model.RegisterTransitCallback(cost)
    model.SetArcCostEvaluatorOfAllVehicles(cb)
    cap = capacity_ms if capacity_ms is not None else int(time_ms.sum()) + 1
    model.AddDimension(cb, 0, cap, True, "time")
    if n_routes > 1:
        model.GetDimensionOrDie("time").SetGlobalSpanCostCoefficient(100)
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH)
    params.time_limit.FromMilliseconds(max(1, int(time_limit_s * 1000)))
    solution = model.SolveWithParameters(params)
    if solution is None:
        return None
    routes = []
    for v in range(n_routes):
        idx = model.Start(v)
        stops = []
        while not model.IsEnd(idx):
            node = manager.IndexToNode(idx)
            if node != 0:
                stops.append(node)
            idx = solution.Value(model.NextVar(idx))
        routes.append(stops)
    return routes


def plan_routes(points: Sequence[VantagePoint], home_enu_m: np.ndarray, transits: Transits,
                fleet: Fleet, speed_mps: float, accel_mps2: float, sortie_overhead_s: float,
                time_limit_s: float = 2.0) -> list[Route]:
    """The routes (module doc); ConfigError naming the limit when none exist."""
    ROUTING.require("pdcov plan --pattern vantage needs")
    n = len(points)
    if fleet.n_vehicles > n:
        raise ConfigError(f"--vehicles {fleet.n_vehicles}: more vehicles than vantage points "
                          f"({n}); use at most {n}")
    hover = np.concatenate([[0.0], [p.hover_s for p in points]])
    t = leg_time_s(transits.length_m, speed_mps, accel_mps2) + hover[None, :]
    np.fill_diagonal(t, 0.0)
    time_ms = np.rint(t * _MS).astype(np.int64)
    if fleet.max_flight_time_s is None:
        routes = _solve(time_ms, fleet.n_vehicles, None, time_limit_s)
        if routes is None:
            raise ConfigError("vantage routing: OR-Tools found no route (raise "
                              "--routing-time-s)")
    else:
        budget_s = fleet.max_flight_time_s - sortie_overhead_s
        round_trip = t[0, 1:] + t[1:, 0]
        worst = int(np.argmax(round_trip))
        if round_trip[worst] > budget_s:
            p = points[worst]
            raise ConfigError(
                f"--max-flight-time-s {fleet.max_flight_time_s:g}: the vantage point at "
                f"({p.x_enu_m:.1f}, {p.y_enu_m:.1f}) m alone takes "
                f"{round_trip[worst] + sortie_overhead_s:.0f} s there, hovering and back "
                f"(with {sortie_overhead_s:.0f} s of climb and descent); raise it")
        # At least the hovers' share of the budgets; more until the solver finds routes.
        sorties = max(1, math.ceil(hover.sum() / (fleet.n_vehicles * budget_s)))
        routes = None
        while routes is None and sorties <= n:
            routes = _solve(time_ms, fleet.n_vehicles * sorties, int(budget_s * _MS),
                            time_limit_s)
            sorties += 1
        if routes is None:
            raise ConfigError(f"--max-flight-time-s {fleet.max_flight_time_s:g}: no set of "
                              "sorties found within it; raise it or --routing-time-s")
    out = []
    for r, stops in enumerate(routes):
        if not stops:
            continue  # a sortie, or a vehicle, left over
        nodes = [0, *stops, 0]
        time_s = float(sum(t[a, b] for a, b in zip(nodes[:-1], nodes[1:], strict=True)))
        out.append(Route(r % fleet.n_vehicles + 1, r // fleet.n_vehicles + 1,
                         tuple(s - 1 for s in stops), time_s + sortie_overhead_s))
    return _renumber(out)


def _renumber(routes: list[Route]) -> list[Route]:
    """Sorties numbered 1, 2, ... per vehicle, in the order found."""
    seen: dict[int, int] = {}
    out = []
    for r in routes:
        seen[r.vehicle] = seen.get(r.vehicle, 0) + 1
        out.append(Route(r.vehicle, seen[r.vehicle], r.stops, r.time_s))
    return out


def route_plan(route: Route, points: Sequence[VantagePoint], transits: Transits,
               speed_mps: float, accel_mps2: float, gimbal_rate_rad_s: float,
               description: str) -> Plan:
    """The waypoints of a route: the transit corners and the hover points (from home's first
    corner to the last corner before home; the take-off and the return to launch fly the
    straight ends, which lie in the flight space); the transit to a point and the point
    carry its gimbal pointing and zoom (commanded on leaving the previous point). A hover
    holds longer by the part of the gimbal's slew from the previous point's pointing
    (``slew_time_s``) that the transit's stop-to-stop time does not cover, so that its
    frames are the ones it was chosen for."""
    nodes = [0, *(s + 1 for s in route.stops), 0]
    wps: list[Waypoint] = []
    for a, b in zip(nodes[:-1], nodes[1:], strict=True):
        path = transits.path(a, b)
        last = b == 0
        p = points[(b if not last else a) - 1]
        corners = path[1:-1] if last else path[1:]
        hover_s = p.hover_s
        if not last and a != 0:
            transit_s = float(leg_time_s(np.array([transits.length_m[a, b]]), speed_mps,
                                         accel_mps2)[0])
            hover_s += max(0.0, slew_time_s(points[a - 1].pointing, p.pointing,
                                            gimbal_rate_rad_s) - transit_s)
        for k, (x, y) in enumerate(corners):
            stop = not last and k == len(corners) - 1
            wps.append(Waypoint(float(x), float(y), p.alt_agl_m, speed_mps,
                                hover_s if stop else 0.0, gimbal=p.pointing,
                                zoom_hfov_deg=p.zoom_hfov_deg))
    return Plan(tuple(wps), description)
