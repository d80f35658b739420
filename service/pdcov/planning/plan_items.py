"""A plan's MAVLink mission items, both ways. A plan (planning/plan.py) is converted to
mission items once (``mission_items``); both file formats (plan_files.py) and the uploader
carry those items, and ``plan_from_mission_items`` reads a mission back. Items (MAVLink
common.xml):

* MAV_CMD_NAV_TAKEOFF (22) to the first waypoint's altitude, at the origin;
* MAV_CMD_DO_CHANGE_SPEED (178) before the first waypoint and wherever the speed changes
  (param1 = 1: ground speed, param2 = m/s, param3 = -1: throttle unchanged);
* the camera's zoom before the first waypoint and wherever it changes (as the pointing:
  commanded on leaving the previous waypoint): MAV_CMD_SET_CAMERA_ZOOM (531), param1 4 =
  ZOOM_TYPE_HORIZONTAL_FOV, param2 the horizontal field of view in deg;
* a gimbal plan's pointing before the first waypoint and wherever it changes (the pointing
  a waypoint carries is commanded on leaving the previous one):
  MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000; param5 GIMBAL_MANAGER_FLAGS_YAW_LOCK for an
  earth-frame yaw) or, for older firmware, MAV_CMD_DO_MOUNT_CONTROL (205)
  (``GimbalCommand``);
* MAV_CMD_NAV_WAYPOINT (16) per waypoint, param1 = hold time in s; or, for a hover of a
  ``HoverItem.LOITER_TIME`` plan, MAV_CMD_NAV_LOITER_TIME (19), param1 = the hover in s;
* MAV_CMD_NAV_RETURN_TO_LAUNCH (20) at the end.

Waypoint altitudes are written in the plan's ``altitude_frame``:
MAV_FRAME_GLOBAL_RELATIVE_ALT (3), metres above home (home is the mission origin on the
ground, so on the flat earth of the paper relative altitude = altitude above ground);
MAV_FRAME_GLOBAL (0), metres above mean sea level of the path's ENU height (a
terrain-following plan densified along the terrain: planning/terrain_follow.py); or
MAV_FRAME_GLOBAL_TERRAIN_ALT (10), metres above the terrain, without the points added along
the terrain (the autopilot follows its own terrain data between waypoints). The take-off
climbs to the first waypoint's height above home, at least its altitude above ground.

Reading accepts frames 0 (MSL, converted with the origin's ground altitude), 3 and 10
(terrain), waypoints and loiter-time hovers, takes the gimbal items as the pointing and the
ZOOM_TYPE_HORIZONTAL_FOV zoom items as the zoom of the waypoint after them, ignores take-off,
landing, return and other DO commands than the speed change, and refuses other navigation
commands and a field of view outside 0-180 deg, naming the file and item. A zoom item of
another zoom type (step, continuous, range, focal length) is kept as
``Plan.zoom_not_predicted``: the prediction refuses such a plan (it cannot know the field
of view), the simulator carries it out.
"""

from __future__ import annotations

import math

import numpy as np

from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from pdcov.core.mission import (
    GIMBAL_MANAGER_FLAGS_YAW_LOCK,
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    MAV_CMD_DO_MOUNT_CONTROL,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_LOITER_TIME,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_CMD_SET_CAMERA_ZOOM,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    MAV_FRAME_MISSION,
    NAV_POSITION_COMMANDS,
    AltitudeFrame,
    GimbalCommand,
    HoverItem,
    MissionItem,
)
from pdcov.errors import InputFileError
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint

ZOOM_TYPE_HORIZONTAL_FOV = 4  # CAMERA_ZOOM_TYPE (common.xml): param2 the field of view, deg
_SKIPPED_NAV = (MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH,
                MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)  # 1000: a DO command outside 176..252
_FIRST_DO_COMMAND = 176  # MAV_CMD_DO_* occupy 176..252 in common.xml
_LAST_DO_COMMAND = 252


def pointing_of_item(it: MissionItem) -> GimbalPointing | None:
    """The pointing a gimbal item (1000 or 205) commands; None for other items and for one
    without a pitch angle (rates only: not predicted)."""
    if not math.isfinite(it.param1):
        return None
    if it.command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:  # p1 pitch, p2 yaw, p5 flags
        lock = math.isfinite(it.lat_deg) and int(it.lat_deg) & GIMBAL_MANAGER_FLAGS_YAW_LOCK
        return GimbalPointing(math.radians(it.param1), math.radians(_or_zero(it.param2)),
                              bool(lock))
    if it.command == MAV_CMD_DO_MOUNT_CONTROL:  # p1 pitch, p3 yaw (body frame)
        return GimbalPointing(math.radians(it.param1), math.radians(_or_zero(it.param3)))
    return None


def _or_zero(v: float) -> float:
    return v if math.isfinite(v) else 0.0


def home_item(origin: Origin) -> MissionItem:
    """The home position item (seq 0 in WPL files and on ArduPilot): origin on the ground."""
    return MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, lat_deg=origin.lat_deg,
                       lon_deg=origin.lon_deg, z_m=origin.ground_alt_msl_m)



def takeoff_alt_m(plan: Plan) -> float:
    """Height above home (m) the take-off climbs to: the first waypoint's ENU height, at
    least its altitude above ground (home is the origin, ENU z = 0)."""
    first = plan.waypoints[0]
    return max(first.alt_agl_m, first.z_enu_m)


def mission_items(plan: Plan, origin: Origin) -> tuple[MissionItem, ...]:
    """Take-off, the camera zoom (MAV_CMD_SET_CAMERA_ZOOM, ZOOM_TYPE_HORIZONTAL_FOV), gimbal
    pointings and speed changes where they change, waypoints (or loiter-time hovers) and
    return to launch (no home item); waypoint altitudes in the plan's frame (module doc)."""
    frame = plan.altitude_frame
    amsl = frame is AltitudeFrame.AMSL
    enu = plan.xyz_enu_m
    if not amsl:
        enu[:, 2] = 0.0  # positions on the ground plane; the altitude is written apart
    geo = enu_to_geodetic(enu, origin)
    items = [MissionItem(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                         param4=math.nan, lat_deg=origin.lat_deg, lon_deg=origin.lon_deg,
                         z_m=takeoff_alt_m(plan))]
    speed = math.nan
    pointing: GimbalPointing | None = None
    zoom: float | None = None
    loiter = plan.hover_item is HoverItem.LOITER_TIME
    for w, (lat, lon, alt_msl), written, now, zoom_now in zip(
            plan.waypoints, geo, plan.written(), plan.pointings(), plan.zooms_hfov_deg(),
            strict=True):
        if zoom_now != zoom and zoom_now is not None:  # a skipped waypoint's passes on
            zoom = zoom_now
            items.append(zoom_item(zoom_now))
        if now != pointing and now is not None:  # a skipped waypoint's passes to the next
            pointing = now
            items.append(now.item(plan.gimbal_command))
        if not written:
            continue
        if w.speed_mps != speed:
            speed = w.speed_mps
            items.append(MissionItem(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, param1=1.0,
                                     param2=speed, param3=-1.0))
        cmd = MAV_CMD_NAV_LOITER_TIME if loiter and w.hover_s > 0 else MAV_CMD_NAV_WAYPOINT
        items.append(MissionItem(cmd, frame.mav_frame,
                                 param1=w.hover_s, param4=math.nan, lat_deg=float(lat),
                                 lon_deg=float(lon),
                                 z_m=float(alt_msl) if amsl else w.alt_agl_m))
    items.append(MissionItem(MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_FRAME_MISSION))
    return tuple(items)


def zoom_item(hfov_deg: float) -> MissionItem:
    """MAV_CMD_SET_CAMERA_ZOOM to a horizontal field of view (deg)."""
    return MissionItem(MAV_CMD_SET_CAMERA_ZOOM, MAV_FRAME_MISSION,
                       param1=float(ZOOM_TYPE_HORIZONTAL_FOV), param2=float(hfov_deg))


def plan_from_mission_items(items: tuple[MissionItem, ...] | list[MissionItem],
                            origin: Origin, source: str = "mission",
                            default_speed_mps: float | None = None) -> Plan:
    """The waypoints of a mission, in ENU about ``origin``; see the module doc for what is
    accepted. ``default_speed_mps`` applies before the first speed change."""
    speed = default_speed_mps
    rows: list[tuple[float, float, float, float, float]] = []
    gimbals: list[GimbalPointing | None] = []
    zooms: list[float | None] = []
    pending: GimbalPointing | None = None
    pending_zoom: float | None = None
    command, hover_item = GimbalCommand.MANAGER, HoverItem.WAYPOINT
    not_predicted = ""
    for k, it in enumerate(items):
        pointing = pointing_of_item(it)
        if pointing is not None:
            pending = pointing
            command = (GimbalCommand.MANAGER if it.command == MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
                       else GimbalCommand.MOUNT)
            continue
        if it.command == MAV_CMD_SET_CAMERA_ZOOM:
            if it.param1 != ZOOM_TYPE_HORIZONTAL_FOV:
                not_predicted = not_predicted or (
                    f"{source}: item {k}: MAV_CMD_SET_CAMERA_ZOOM of zoom type {it.param1:g} "
                    f"(only {ZOOM_TYPE_HORIZONTAL_FOV}, ZOOM_TYPE_HORIZONTAL_FOV, gives the "
                    "field of view a prediction needs)")
                continue
            if not (math.isfinite(it.param2) and 0 < it.param2 < 180):
                raise InputFileError(f"{source}: item {k}: MAV_CMD_SET_CAMERA_ZOOM to a "
                                     f"horizontal field of view of {it.param2!r} deg "
                                     "(expected 0-180)")
            pending_zoom = float(it.param2)  # the next waypoint's, as mission_items writes
            continue
        if it.command == MAV_CMD_DO_CHANGE_SPEED:
            if it.param2 > 0:
                speed = it.param2
            continue
        if it.command in _SKIPPED_NAV or _FIRST_DO_COMMAND <= it.command <= _LAST_DO_COMMAND:
            continue
        if it.command not in NAV_POSITION_COMMANDS:
            raise InputFileError(f"{source}: item {k}: command {it.command} is not supported "
                                 f"(waypoints, loiter-time hovers, take-off, landing, return, "
                                 "DO commands and MAV_CMD_SET_CAMERA_ZOOM are)")
        if it.command == MAV_CMD_NAV_LOITER_TIME:
            hover_item = HoverItem.LOITER_TIME
        if it.frame == MAV_FRAME_GLOBAL:
            alt_agl = it.z_m - origin.ground_alt_msl_m
        elif it.frame in (MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_TERRAIN_ALT):
            alt_agl = it.z_m
        else:
            raise InputFileError(f"{source}: item {k}: frame {it.frame} is not supported "
                                 f"(expected 0 global, 3 relative or 10 terrain)")
        if speed is None:
            raise InputFileError(f"{source}: item {k}: no speed before the first waypoint "
                                 f"(add MAV_CMD_DO_CHANGE_SPEED or give a default speed)")
        rows.append((it.lat_deg, it.lon_deg, alt_agl, speed, it.param1))
        gimbals.append(pending)
        zooms.append(pending_zoom)
        pending, pending_zoom = None, None
    if not rows:
        raise InputFileError(f"{source}: no waypoints (MAV_CMD_NAV_WAYPOINT) found")
    a = np.array(rows, dtype=float)
    enu = geodetic_to_enu(a[:, 0], a[:, 1], np.full(len(a), origin.ground_alt_msl_m), origin)
    try:
        return Plan(tuple(Waypoint(float(e), float(n), float(r[2]), float(r[3]), float(r[4]),
                                   gimbal=g, zoom_hfov_deg=z)
                          for (e, n, _), r, g, z in zip(enu, a, gimbals, zooms, strict=True)),
                    f"read from {source}", gimbal_command=command, hover_item=hover_item,
                    zoom_not_predicted=not_predicted)
    except ValueError as exc:
        raise InputFileError(f"{source}: {exc}") from None
