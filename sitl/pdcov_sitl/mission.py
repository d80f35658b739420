"""The flight plan the simulator flies: its legs from take-off to landing.

A plan file (QGC ``.plan`` or WPL 110, as ``pdcov plan`` writes them) is read with
``pdcov.planning.plan``: take-off at home, the waypoints with their speeds and hover times,
return to launch. The gimbal commands of the mission (MAV_CMD_DO_MOUNT_CONTROL 205 and
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW 1000) set the camera's pitch/yaw from the next waypoint
on; without any the camera looks straight down.

The legs: climb vertically at home to the first waypoint's altitude, the waypoints with their
speeds and hold times, return home at altitude, descend to land. ``guidance.py`` turns them
into the reference the controller follows. NED metres about home; times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from pdcov.core.geodesy import Origin
from pdcov.core.mission import MAV_CMD_NAV_WAYPOINT, MissionItem
from pdcov.planning.plan import plan_from_mission_items, read_mission

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
