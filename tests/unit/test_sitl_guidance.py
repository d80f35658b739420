"""pdcov-sitl guidance (pure, in memory): pass-through corners at the speed the turn allows,
stops only where the mission says, a smooth (jerk-limited) reference, and agreement with the
planner's kinematic model (planning/trajectory.py) on what a pattern costs in time."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint
from pdcov.planning.plan_items import mission_items
from pdcov.planning.trajectory import fly as planner_fly
from pdcov_sitl.guidance import Guidance
from pdcov_sitl.mission import flight_plan_from_items

ORIGIN = Origin(39.35, -76.33, 5.0)
RATE_HZ = 50.0


def _plan(xy: list[tuple[float, float]], speed_mps: float = 5.0, hover: dict | None = None
          ) -> Plan:
    hover = hover or {}
    return Plan(tuple(Waypoint(x, y, 10.0, speed_mps, hover.get(i, 0.0))
                      for i, (x, y) in enumerate(xy)))


def _reference(plan: Plan) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """t (N,), position ENU xy + height (N, 3), velocity (N, 3) NED, leg kinds: the
    setpoints at RATE_HZ from start to disarm."""
    g = Guidance(flight_plan_from_items(mission_items(plan, ORIGIN), ORIGIN, "test"),
                 start_s=0.0)
    t, r, v, kinds = [], [], [], []
    k = 0
    while not g.done:
        sp = g.setpoint(k / RATE_HZ)
        t.append(k / RATE_HZ)
        r.append((sp.r_ned_m[1], sp.r_ned_m[0], -sp.r_ned_m[2]))
        v.append(sp.v_ned_mps)
        kinds.append(g.leg.kind if g.leg is not None else "ground")
        k += 1
        assert k < 10_000 * RATE_HZ
    return np.array(t), np.array(r), np.array(v), kinds


def _near(r: np.ndarray, xy: tuple[float, float], within_m: float) -> np.ndarray:
    return np.linalg.norm(r[:, :2] - np.asarray(xy), axis=1) < within_m


def test_gentle_corner_at_speed_sharp_corner_slower_stop_only_at_the_end() -> None:
    # A 10 deg bend at (0, 40), a 90 deg corner at (6.9, 80), the last waypoint (46.9, 80).
    xy = [(0.0, 10.0), (0.0, 40.0), (6.95, 79.4), (46.95, 79.4)]
    t, r, v, kinds = _reference(_plan(xy))
    speed = np.linalg.norm(v[:, :2], axis=1)
    survey = np.array([k == "waypoint" for k in kinds])
    bend = survey & _near(r, xy[1], 2.0)
    corner = survey & _near(r, xy[2], 2.5)
    # Planner's law: radius min(v^2/a, min(cut, half a leg) / tan(delta/2)), speed sqrt(a r).
    v_corner = math.sqrt(2.5 * 2.0 / math.tan(math.radians(90.0 - 10.0) / 2))
    print(f"bend: min {speed[bend].min():.2f} m/s; 80 deg corner: min "
          f"{speed[corner].min():.2f} m/s (law {v_corner:.2f})")
    assert speed[bend].min() > 0.95 * 5.0
    assert abs(speed[corner].min() - v_corner) < 0.35
    # No stop from passing the first waypoint to arriving at the last one.
    first = int(np.argmax(survey & _near(r, xy[0], 0.5)))
    last = int(np.argmax(survey & _near(r, xy[-1], 0.01)))
    assert speed[first + 2 * int(RATE_HZ):last - 2 * int(RATE_HZ)].min() > 2.0
    assert speed[survey & _near(r, xy[-1], 0.01)].min() < 0.01  # stops at the last one


def test_hold_time_stops_and_holds_there() -> None:
    xy = [(0.0, 10.0), (0.0, 30.0), (20.0, 30.0)]
    t, r, v, _ = _reference(_plan(xy, hover={1: 3.0}))
    speed = np.linalg.norm(v, axis=1)
    held = _near(r, xy[1], 0.02) & (speed < 0.02)
    assert held.sum() / RATE_HZ >= 2.9


def test_reference_is_smooth_and_stays_near_the_legs() -> None:
    xy = [(x, y) for k in range(4) for x, y in (((10 * k, 0), (10 * k, 40)) if k % 2 == 0
                                               else ((10 * k, 40), (10 * k, 0)))]
    t, r, v, kinds = _reference(_plan(xy))
    a = np.gradient(v, t, axis=0)
    jerk = np.gradient(a, t, axis=0)
    a_h, jerk_h = np.linalg.norm(a[:, :2], axis=1), np.linalg.norm(jerk[:, :2], axis=1)
    print(f"max horizontal acceleration {a_h.max():.2f} m/s^2, jerk {jerk_h.max():.2f} m/s^3")
    assert a_h.max() < 2.5 * math.sqrt(2) + 0.1  # along + across the path at the limit
    assert jerk_h.max() < 12.0  # ~accel / smooth_s per axis; both axes at a corner
    survey = np.array([k == "waypoint" for k in kinds])
    pts = np.array(xy, float)
    d = np.full(survey.sum(), np.inf)
    for p, q in zip(pts[:-1], pts[1:], strict=True):
        s = np.clip((r[survey, :2] - p) @ (q - p) / ((q - p) @ (q - p)), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(r[survey, :2] - (p + s[:, None] * (q - p)), axis=1))
    first = int(np.argmax(_near(r[survey], xy[0], 1.0)))
    assert d[first:].max() < 1.0  # rounded corners cut at most ~0.6 m inside a 90 deg turn


@pytest.mark.parametrize("speed_mps", [3.0, 5.0, 8.0])
def test_pattern_time_agrees_with_the_planner(speed_mps: float) -> None:
    """The same corner law and acceleration: the pattern (first to last waypoint) takes
    about the planner's kinematic time (the planner starts at rest at the first waypoint
    and slows for its heading rate; guidance rounds the first waypoint and smooths)."""
    xy = [(x, y) for k in range(5) for x, y in (((10 * k, 0), (10 * k, 40)) if k % 2 == 0
                                               else ((10 * k, 40), (10 * k, 0)))]
    plan = _plan(xy, speed_mps)
    t, r, v, kinds = _reference(plan)
    survey = np.array([k == "waypoint" for k in kinds])
    d0 = np.where(survey, np.linalg.norm(r[:, :2] - np.asarray(xy[0]), axis=1), np.inf)
    start = int(np.argmin(d0))
    end = int(np.argmax(survey & _near(r, xy[-1], 0.01)))
    flown_s = t[end] - t[start]
    predicted_s = planner_fly(plan, 5.0).duration_s
    print(f"{speed_mps} m/s: guidance {flown_s:.1f} s, planner {predicted_s:.1f} s")
    assert abs(flown_s - predicted_s) < 0.1 * predicted_s


def test_a_second_hover_at_the_same_point_holds_its_own_pointing() -> None:
    """Two hovers at one point with other gimbal pointings (a vantage point seen at two
    yaws): the leg of no length keeps its own hold and pointing. Before, its hold was added
    to the previous leg's, which kept the gimbal at the first yaw through both hovers."""
    south, north_west = (GimbalPointing(-math.pi / 4, math.pi, True),
                         GimbalPointing(-math.pi / 4, -math.pi / 4, True))
    plan = Plan((Waypoint(0.0, 10.0, 10.0, 4.0, 6.0, gimbal=south),
                 Waypoint(0.0, 10.0, 10.0, 4.0, 3.0, gimbal=north_west),
                 Waypoint(10.0, 10.0, 10.0, 4.0)))
    g = Guidance(flight_plan_from_items(mission_items(plan, ORIGIN), ORIGIN, "test"),
                 start_s=0.0)
    held: dict[float, float] = {}  # gimbal yaw (deg) -> seconds at the point in force
    k = 0
    while not g.done:
        sp = g.setpoint(k / RATE_HZ)
        leg = g.leg
        if leg is not None and math.hypot(sp.r_ned_m[0] - 10.0, sp.r_ned_m[1]) < 0.05 \
                and np.linalg.norm(sp.v_ned_mps) < 0.05:
            yaw = round(math.degrees(leg.gimbal_yaw_rad))
            held[yaw] = held.get(yaw, 0.0) + 1 / RATE_HZ
        k += 1
    assert set(held) == {180, -45}
    assert held[180] >= 6.0 and held[-45] >= 3.0
    assert held[-45] < 6.0  # its own hold, not the first one's again
