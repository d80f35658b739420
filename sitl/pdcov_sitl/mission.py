"""The flight plan the simulator flies, and the guidance that turns it into setpoints.

A plan file (QGC ``.plan`` or WPL 110, as ``pdcov plan`` writes them) is read with
``pdcov.planning.plan``: take-off at home, the waypoints with their speeds and hover times,
return to launch. The gimbal commands of the mission (MAV_CMD_DO_MOUNT_CONTROL 205 and
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW 1000) set the camera's pitch/yaw from the next waypoint
on; without any the camera looks straight down.

Guidance flies it like a multicopter autopilot in AUTO: climb vertically at home to the
first waypoint's altitude, then each leg on a straight line with a trapezoidal speed profile
(accelerate at ``accel_mps2`` to the leg's speed, decelerate to stop at the waypoint), the
heading turned towards the leg at ``yaw_rate_rps`` while it starts, hover where the plan says,
then return home at altitude and descend to land. All in NED metres about home; times in
simulated seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pdcov.core.geodesy import Origin
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MissionItem
from pdcov.planning.plan import plan_from_mission_items, read_mission

from .control import Setpoint

MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
NADIR_PITCH_RAD = -math.pi / 2


@dataclass(frozen=True, slots=True)
class Leg:
    """A straight segment from ``start`` to ``end`` (NED m about home) flown at
    ``speed_mps``, then ``hover_s`` seconds of hover at its end; gimbal pitch/yaw (rad; yaw
    relative to the vehicle's heading) commanded from its start."""

    start_ned_m: tuple[float, float, float]
    end_ned_m: tuple[float, float, float]
    speed_mps: float
    hover_s: float = 0.0
    gimbal_pitch_rad: float = NADIR_PITCH_RAD
    gimbal_yaw_rad: float = 0.0
    kind: str = "waypoint"   # takeoff | waypoint | return | land


@dataclass(frozen=True, slots=True)
class FlightPlan:
    """Home (lat, lon, ground altitude m MSL) and the legs from take-off to landing."""

    home: Origin
    legs: tuple[Leg, ...]

    @property
    def survey_legs(self) -> tuple[Leg, ...]:
        return tuple(leg for leg in self.legs if leg.kind == "waypoint")


def _gimbal_commands(items: tuple[MissionItem, ...]) -> list[tuple[float, float] | None]:
    """Per navigation waypoint: the (pitch, yaw) rad commanded by the DO items just before
    it, or None where none precedes it."""
    out: list[tuple[float, float] | None] = []
    pending: tuple[float, float] | None = None
    for it in items:
        if it.command == MAV_CMD_DO_MOUNT_CONTROL:  # param1 pitch, param3 yaw, deg
            pending = (math.radians(it.param1), math.radians(it.param3 or 0.0))
        elif it.command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:  # param1 pitch, param2 yaw
            pending = (math.radians(it.param1), math.radians(it.param2 or 0.0))
        elif it.command == MAV_CMD_NAV_WAYPOINT:
            out.append(pending)
            pending = None
    return out


def load_flight_plan(path: str | Path, origin: Origin, default_speed_mps: float = 5.0
                     ) -> FlightPlan:
    """The legs of a plan file (.plan or WPL 110), home at ``origin`` (the take-off point on
    the ground). Raises pdcov's InputFileError naming the file for a plan it cannot fly."""
    mission = read_mission(path)
    speed = (default_speed_mps if math.isnan(mission.default_speed_mps)
             else mission.default_speed_mps)
    return flight_plan_from_items(mission.items, origin, str(path), speed)


def flight_plan_from_items(items: tuple[MissionItem, ...] | list[MissionItem], origin: Origin,
                           source: str, default_speed_mps: float = 5.0, *,
                           takeoff_speed_mps: float = 1.5, land_speed_mps: float = 0.7
                           ) -> FlightPlan:
    """The legs of mission items (no home item), home at ``origin``."""
    items = tuple(items)
    plan = plan_from_mission_items(items, origin, source, default_speed_mps)
    gimbal = _gimbal_commands(items)
    legs: list[Leg] = []
    alt0 = plan.waypoints[0].alt_agl_m
    legs.append(Leg((0.0, 0.0, 0.0), (0.0, 0.0, -alt0), takeoff_speed_mps, 1.0, kind="takeoff"))
    here = (0.0, 0.0, -alt0)
    pitch, yaw = NADIR_PITCH_RAD, 0.0
    for k, w in enumerate(plan.waypoints):
        if k < len(gimbal) and gimbal[k] is not None:
            pitch, yaw = gimbal[k]  # type: ignore[misc]
        end = (w.y_enu_m, w.x_enu_m, -w.alt_agl_m)
        legs.append(Leg(here, end, w.speed_mps, w.hover_s, pitch, yaw))
        here = end
    rtl_speed = plan.waypoints[-1].speed_mps
    top = (0.0, 0.0, here[2])
    legs.append(Leg(here, top, rtl_speed, 1.0, pitch, yaw, kind="return"))
    legs.append(Leg(top, (0.0, 0.0, 0.0), land_speed_mps, 0.0, pitch, yaw, kind="land"))
    return FlightPlan(origin, tuple(legs))


@dataclass(frozen=True, slots=True)
class _Profile:
    """Trapezoidal speed profile over a distance: accelerate, cruise, decelerate."""

    length_m: float
    speed_mps: float
    accel_mps2: float
    t_accel_s: float
    t_total_s: float

    @classmethod
    def make(cls, length_m: float, speed_mps: float, accel_mps2: float) -> _Profile:
        v = min(speed_mps, math.sqrt(max(length_m, 0.0) * accel_mps2))
        if v <= 0:
            return cls(0.0, 0.0, accel_mps2, 0.0, 0.0)
        ta = v / accel_mps2
        cruise = (length_m - v * ta) / v
        return cls(length_m, v, accel_mps2, ta, 2 * ta + cruise)

    def at(self, t: float) -> tuple[float, float, float]:
        """(distance m, speed m/s, acceleration m/s^2) at time t into the profile."""
        v, a, ta, tt = self.speed_mps, self.accel_mps2, self.t_accel_s, self.t_total_s
        if t <= 0 or tt == 0:
            return 0.0, 0.0, 0.0
        if t >= tt:
            return self.length_m, 0.0, 0.0
        if t < ta:
            return 0.5 * a * t * t, a * t, a
        if t > tt - ta:
            r = tt - t
            return self.length_m - 0.5 * a * r * r, a * r, -a
        return 0.5 * v * ta + v * (t - ta), v, 0.0


class Guidance:
    """Setpoints along a FlightPlan, by simulated time. Pure: no I/O, no clock of its own.

    ``setpoint(t_s)`` gives the Setpoint at t_s (call with non-decreasing times);
    ``leg`` is the leg in force, ``done`` True once landed and disarmed.
    """

    def __init__(self, plan: FlightPlan, *, start_s: float = 1.0, accel_mps2: float = 1.5,
                 yaw_rate_rps: float = math.radians(60), heading_rad: float = 0.0) -> None:
        self.plan = plan
        self.accel_mps2 = accel_mps2
        self.yaw_rate_rps = yaw_rate_rps
        self._k = -1
        self._leg_t0 = start_s
        self._profile: _Profile | None = None
        self._yaw = heading_rad
        self._yaw_target = heading_rad
        self._last_t = start_s
        self.done = False
        self.landed_s = math.inf

    @property
    def leg(self) -> Leg | None:
        return self.plan.legs[self._k] if 0 <= self._k < len(self.plan.legs) else None

    def _start_leg(self, k: int, t0: float) -> None:
        self._k, self._leg_t0 = k, t0
        if k >= len(self.plan.legs):
            return
        leg = self.plan.legs[k]
        d = [b - a for a, b in zip(leg.start_ned_m, leg.end_ned_m, strict=True)]
        length = math.sqrt(sum(x * x for x in d))
        accel = self.accel_mps2 if leg.kind == "waypoint" or leg.kind == "return" else 1.0
        self._profile = _Profile.make(length, leg.speed_mps, accel)
        self._dir = tuple(x / length for x in d) if length > 0 else (0.0, 0.0, 0.0)
        if math.hypot(d[0], d[1]) > 1.0:
            self._yaw_target = math.atan2(d[1], d[0])

    def setpoint(self, t_s: float) -> Setpoint:
        legs = self.plan.legs
        if self._k < 0:
            if t_s < self._leg_t0:
                return Setpoint((0.0, 0.0, 0.0), yaw_rad=self._yaw, armed=False)
            self._start_leg(0, self._leg_t0)
        while self._k < len(legs):
            leg, prof = legs[self._k], self._profile
            if t_s - self._leg_t0 < prof.t_total_s + leg.hover_s:  # type: ignore[union-attr]
                break
            self._start_leg(self._k + 1, self._leg_t0 + prof.t_total_s + leg.hover_s)  # type: ignore[union-attr]
        dt = max(0.0, t_s - self._last_t)
        self._last_t = t_s
        step = self.yaw_rate_rps * dt
        err = (self._yaw_target - self._yaw + math.pi) % (2 * math.pi) - math.pi
        self._yaw += max(-step, min(step, err))
        if self._k >= len(legs):
            self.done = True
            return Setpoint(legs[-1].end_ned_m, yaw_rad=self._yaw, armed=False)
        leg, prof = legs[self._k], self._profile
        s, v, a = prof.at(t_s - self._leg_t0)  # type: ignore[union-attr]
        u = self._dir
        r = tuple(p + s * ui for p, ui in zip(leg.start_ned_m, u, strict=True))
        if leg.kind == "land" and s >= prof.length_m:  # type: ignore[union-attr]
            # Keep pushing down gently until the controller has settled on the gear.
            r = (r[0], r[1], r[2] + 0.5)
        return Setpoint(r, tuple(v * ui for ui in u), tuple(a * ui for ui in u),  # type: ignore[arg-type]
                        self._yaw)
