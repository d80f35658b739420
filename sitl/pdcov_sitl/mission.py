"""The flight plan the simulator flies: its legs from take-off to landing.

Mission items (of a QGC ``.plan`` or WPL 110 file as ``pdcov plan`` writes them, or uploaded)
are read with ``pdcov.planning.plan``: take-off at home, the waypoints (MAV_CMD_NAV_WAYPOINT
16 with its hold time, or MAV_CMD_NAV_LOITER_TIME 19: fly to its position and hover there
for param1 s) with their speeds, return to launch. The gimbal commands of the mission
(MAV_CMD_DO_MOUNT_CONTROL 205 and MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW 1000, read by
``plan_items.pointing_of_item``) set the camera's pitch/yaw from the next waypoint on: the yaw
relative to the vehicle's heading, or to north with 1000's GIMBAL_MANAGER_FLAGS_YAW_LOCK
(param5 16), as ArduPilot's AP_Mission passes it to AP_Mount; without any the camera looks
straight down. MAV_CMD_SET_CAMERA_ZOOM items (531: param1
CAMERA_ZOOM_TYPE, param2 its value) zoom the camera (camera.py) from the next waypoint on.

The legs: climb vertically at home to the first waypoint's altitude, the waypoints with their
speeds and hold times, the return to launch (``ReturnRule``: ArduCopter's RTL altitude), descend
to land. ``guidance.py`` turns them into the reference the controller follows. NED metres
about home; times in seconds.

Altitude frames (common.xml MAV_FRAME): GLOBAL (0, 5: AMSL), GLOBAL_RELATIVE_ALT (3, 6: above
home) and GLOBAL_TERRAIN_ALT (10, 11: above the terrain under the vehicle). A terrain-frame leg
is flown as ArduCopter flies it with terrain data: its height above the terrain runs linearly
from the leg's start (the previous waypoint, converted to the terrain frame) to its waypoint,
and the terrain under the vehicle is added (``Leg.above_terrain``; ``guidance.py``). Home is
on the ground, so over flat ground (no DEM) the terrain frame is the relative one.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

from pdcov.core.geodesy import Origin
from pdcov.core.mission import (
    MAV_CMD_SET_CAMERA_ZOOM,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    NAV_POSITION_COMMANDS,
    MissionItem,
)
from pdcov.errors import InputFileError
from pdcov.planning.plan import GimbalPointing
from pdcov.planning.plan_items import plan_from_mission_items

from .terrain import LocalGround

NADIR_PITCH_RAD = -math.pi / 2
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6
MAV_FRAME_GLOBAL_TERRAIN_ALT_INT = 11
_FRAME_OF_INT = {MAV_FRAME_GLOBAL_INT: MAV_FRAME_GLOBAL,
                 MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: MAV_FRAME_GLOBAL_RELATIVE_ALT,
                 MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: MAV_FRAME_GLOBAL_TERRAIN_ALT}
"""The deprecated ``*_INT`` frames mean the same altitudes as their plain twins."""
RTL_ALT_MIN_M = 0.3
RTL_MIN_CONE_SLOPE = 0.5
"""ArduCopter config.h: RTL_ALT_MIN (30 cm) and the shallowest cone slope honoured."""


@dataclass(frozen=True, slots=True)
class ReturnRule:
    """How high the vehicle returns home: ArduCopter's ModeRTL::compute_return_target.

    alt_m: RTL_ALT (cm on the wire, default 1500); climb_min_m: RTL_CLIMB_MIN (cm, 0);
    cone_slope: RTL_CONE_SLOPE (3; below 0.5 no cone); above_terrain: RTL_ALT_TYPE 1
    (terrain) rather than 0 (above home); loiter_s: RTL_LOITER_TIME (ms, 5000) hovered above
    home before the descent.
    """

    alt_m: float = 15.0
    climb_min_m: float = 0.0
    cone_slope: float = 3.0
    above_terrain: bool = False
    loiter_s: float = 5.0

    @classmethod
    def from_params(cls, params: Mapping[str, float]) -> ReturnRule:
        """The rule of ArduPilot parameters (absent ones keep their defaults)."""
        d = cls()
        return cls(alt_m=params.get("RTL_ALT", d.alt_m * 100) / 100,
                   climb_min_m=params.get("RTL_CLIMB_MIN", d.climb_min_m * 100) / 100,
                   cone_slope=params.get("RTL_CONE_SLOPE", d.cone_slope),
                   above_terrain=params.get("RTL_ALT_TYPE", 0.0) == 1.0,
                   loiter_s=params.get("RTL_LOITER_TIME", d.loiter_s * 1000) / 1000)

    def return_alt_m(self, current_alt_m: float, distance_m: float) -> float:
        """The altitude (m, in the rule's frame: above home, or above terrain) to return at
        from ``current_alt_m`` (same frame) at ``distance_m`` horizontally from home: at
        least RTL_ALT and the current altitude + RTL_CLIMB_MIN, lowered within the cone
        (distance * slope) near home, and never below the current altitude (no descent)."""
        min_alt = max(RTL_ALT_MIN_M, current_alt_m + max(0.0, self.climb_min_m))
        target = max(0.0, self.alt_m, min_alt)
        if self.cone_slope >= RTL_MIN_CONE_SLOPE:
            target = min(target, max(distance_m * self.cone_slope, min_alt))
        return max(target, current_alt_m)


AT_CURRENT_ALTITUDE = ReturnRule(alt_m=0.0, cone_slope=0.0, loiter_s=1.0)
"""Return at the altitude of the last waypoint (RTL_ALT 0), hovering 1 s above home."""


@dataclass(frozen=True, slots=True)
class Leg:
    """A straight segment from ``start`` to ``end`` (NED m about home) flown at
    ``speed_mps``, then ``hover_s`` seconds of hover at its end; gimbal pitch/yaw (rad; yaw
    relative to the vehicle's heading, or to north with ``gimbal_earth_yaw``) commanded
    from its start."""

    start_ned_m: tuple[float, float, float]
    end_ned_m: tuple[float, float, float]
    speed_mps: float
    hover_s: float = 0.0
    gimbal_pitch_rad: float = NADIR_PITCH_RAD
    gimbal_yaw_rad: float = 0.0
    gimbal_earth_yaw: bool = False
    kind: str = "waypoint"   # takeoff | waypoint | return | land
    camera_zoom: tuple[int, float] | None = None
    """The camera zoom in force from the leg's start (CAMERA_ZOOM_TYPE, value); None: none
    commanded yet."""
    above_terrain: bool = False
    """Flown at a height above the terrain under the vehicle (module docstring)."""


@dataclass(frozen=True, slots=True)
class FlightPlan:
    """Home (lat, lon, ground altitude m MSL) and the legs from take-off to landing."""

    home: Origin
    legs: tuple[Leg, ...]

    @property
    def survey_legs(self) -> tuple[Leg, ...]:
        return tuple(leg for leg in self.legs if leg.kind == "waypoint")


def _zoom_commands(items: tuple[MissionItem, ...]) -> list[tuple[int, float] | None]:
    """Per navigation waypoint: the (zoom type, value) of the MAV_CMD_SET_CAMERA_ZOOM just
    before it, or None where none precedes it."""
    out: list[tuple[int, float] | None] = []
    pending: tuple[int, float] | None = None
    for it in items:
        if it.command == MAV_CMD_SET_CAMERA_ZOOM:
            zoom_type = it.param1 if math.isfinite(it.param1) else -1.0  # refused by the camera
            pending = (int(zoom_type), float(it.param2))
        elif it.command in NAV_POSITION_COMMANDS:
            out.append(pending)
            pending = None
    return out


def flight_plan_from_items(items: tuple[MissionItem, ...] | list[MissionItem], origin: Origin,
                           source: str, default_speed_mps: float = 5.0, *,
                           takeoff_speed_mps: float = 1.5, land_speed_mps: float = 0.7,
                           ground: LocalGround | None = None,
                           rtl: ReturnRule = AT_CURRENT_ALTITUDE) -> FlightPlan:
    """The legs of mission items (no home item), home at ``origin`` (on the ground).

    ground: the terrain about home, for terrain-frame waypoints and a terrain RTL (None:
    level ground, where the terrain frame is the relative one). rtl: the return's altitude.
    """
    items = tuple(dataclasses.replace(it, frame=_FRAME_OF_INT.get(it.frame, it.frame))
                  for it in items)
    plan = plan_from_mission_items(items, origin, source, default_speed_mps)
    zooms = _zoom_commands(items)
    nav = [(k, it) for k, it in enumerate(items) if it.command in NAV_POSITION_COMMANDS]

    def terrain_m(n_m: float, e_m: float, what: str) -> float:
        """Terrain height above home (m) at NED (n, e); 0 on level ground."""
        if ground is None:
            return 0.0
        h = float(ground.height_m(n_m, e_m))
        if not math.isfinite(h):
            lat, lon = ground.geodetic(n_m, e_m)
            raise InputFileError(f"{source}: {what} at ({float(lat):.7f}, {float(lon):.7f}) "
                                 "lies outside the DEM (no terrain height there)")
        return h

    legs: list[Leg] = []
    alt0 = plan.waypoints[0].alt_agl_m
    legs.append(Leg((0.0, 0.0, 0.0), (0.0, 0.0, -alt0), takeoff_speed_mps, 1.0, kind="takeoff"))
    here = (0.0, 0.0, -alt0)
    aim = GimbalPointing(NADIR_PITCH_RAD)
    zoom: tuple[int, float] | None = None
    for k, (w, (seq, it), now) in enumerate(zip(plan.waypoints, nav, plan.pointings(),
                                                strict=True)):
        aim = now or aim
        zoom = zooms[k] if k < len(zooms) and zooms[k] is not None else zoom
        terrain = it.frame == MAV_FRAME_GLOBAL_TERRAIN_ALT
        n, e = w.y_enu_m, w.x_enu_m
        up = w.alt_agl_m + (terrain_m(n, e, f"item {seq}: the terrain-frame waypoint")
                            if terrain else 0.0)
        end = (n, e, -up)
        legs.append(Leg(here, end, w.speed_mps, w.hover_s, aim.pitch_rad, aim.yaw_rad,
                        aim.earth_yaw, above_terrain=terrain, camera_zoom=zoom))
        here = end
    rtl_speed = plan.waypoints[-1].speed_mps
    under = terrain_m(here[0], here[1], "the start of the return") if rtl.above_terrain else 0.0
    alt = rtl.return_alt_m(-here[2] - under, math.hypot(here[0], here[1]))
    climbed = (here[0], here[1], -(alt + under))
    if climbed != here:  # climb first, unless already at the return altitude
        legs.append(Leg(here, climbed, rtl_speed, 0.0, aim.pitch_rad, aim.yaw_rad,
                        aim.earth_yaw, kind="return"))
    top = (0.0, 0.0, -alt)
    legs.append(Leg(climbed, top, rtl_speed, rtl.loiter_s, aim.pitch_rad, aim.yaw_rad,
                    aim.earth_yaw, kind="return", above_terrain=rtl.above_terrain))
    legs.append(Leg(top, (0.0, 0.0, 0.0), land_speed_mps, 0.0, aim.pitch_rad, aim.yaw_rad,
                    aim.earth_yaw, kind="land"))
    return FlightPlan(origin, tuple(legs))
