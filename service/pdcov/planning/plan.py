"""Flight plans: waypoints in ENU with altitude above ground, speed and hover time, and their
mission files (QGroundControl ``.plan`` JSON and the ``QGC WPL 110`` text format).

A plan is converted to MAVLink mission items once (``mission_items``); both file formats and
the uploader carry those items. Items (MAVLink common.xml):

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

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pdcov.atomic import write_text_atomic
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
from pdcov.yaml_file import read_text

T = TypeVar("T")

ZOOM_TYPE_HORIZONTAL_FOV = 4  # CAMERA_ZOOM_TYPE (common.xml): param2 the field of view, deg
_SKIPPED_NAV = (MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH,
                MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)  # 1000: a DO command outside 176..252
_FIRST_DO_COMMAND = 176  # MAV_CMD_DO_* occupy 176..252 in common.xml
_LAST_DO_COMMAND = 252
QGC_FIRMWARE_ARDUPILOT = 3
QGC_VEHICLE_MULTIROTOR = 2


@dataclass(frozen=True, slots=True)
class GimbalPointing:
    """Where a gimbal points: pitch against the horizon (rad, -pi/2: nadir) and yaw (rad,
    clockwise) from the vehicle's heading, or from north when ``earth_yaw``."""

    pitch_rad: float
    yaw_rad: float = 0.0
    earth_yaw: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pitch_rad) and math.isfinite(self.yaw_rad)):
            raise ValueError(f"gimbal pointing must be finite, got {self}")

    def item(self, command: GimbalCommand) -> MissionItem:
        """The mission item commanding it; yaw written in (-180, 180] deg."""
        yaw_deg = math.degrees(math.remainder(self.yaw_rad, 2 * math.pi))
        return command.item(math.degrees(self.pitch_rad), yaw_deg, self.earth_yaw)


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


@dataclass(frozen=True, slots=True)
class Waypoint:
    """One waypoint: ENU metres, altitude above ground (m; above the terrain when the plan
    follows it), speed to fly towards it (m/s), and the time to hover on reaching it (s).

    z_enu_m: ENU height of the path at the waypoint (m; default ``alt_agl_m``: the flat
    ground z = 0). terrain_added: a point added along a leg to follow the terrain, not a
    turn of the pattern (a MAV_FRAME_GLOBAL_TERRAIN_ALT mission leaves it out). gimbal:
    the pointing commanded on leaving the previous waypoint, held on the way here and
    while here (None: the one in force). zoom_hfov_deg: the camera's zoom commanded there
    too, as a horizontal field of view (deg; None: the one in force, at first the
    configured camera)."""

    x_enu_m: float
    y_enu_m: float
    alt_agl_m: float
    speed_mps: float
    hover_s: float = 0.0
    z_enu_m: float = math.nan
    terrain_added: bool = False
    gimbal: GimbalPointing | None = None
    zoom_hfov_deg: float | None = None

    def __post_init__(self) -> None:
        if math.isnan(self.z_enu_m):
            object.__setattr__(self, "z_enu_m", self.alt_agl_m)
        if not all(math.isfinite(v) for v in (self.x_enu_m, self.y_enu_m, self.alt_agl_m,
                                              self.z_enu_m)):
            raise ValueError(f"waypoint position must be finite, got {self}")
        if not self.alt_agl_m > 0:
            raise ValueError(f"alt_agl_m must be > 0 m, got {self.alt_agl_m}")
        if not (self.speed_mps > 0 and math.isfinite(self.speed_mps)):
            raise ValueError(f"speed_mps must be > 0, got {self.speed_mps}")
        if not (self.hover_s >= 0 and math.isfinite(self.hover_s)):
            raise ValueError(f"hover_s must be >= 0 s, got {self.hover_s}")
        if self.zoom_hfov_deg is not None and not 0 < self.zoom_hfov_deg < 180:
            raise ValueError(f"zoom_hfov_deg must be in (0, 180) deg, got {self.zoom_hfov_deg}")


@dataclass(frozen=True, slots=True)
class Plan:
    """An ordered list of waypoints, a one-line description of how it was made, and the
    frame its altitudes are written in (RELATIVE: the flat ground, or a constant altitude
    above home). gimbal_command: the item the waypoints' gimbal pointings are written as.
    hover_item: how hovers are written. zoom_not_predicted: a plan read from a mission
    with a zoom item of another type than the field of view, that item ('' none: module
    doc)."""

    waypoints: tuple[Waypoint, ...]
    description: str = ""
    altitude_frame: AltitudeFrame = AltitudeFrame.RELATIVE
    gimbal_command: GimbalCommand = GimbalCommand.MANAGER
    hover_item: HoverItem = HoverItem.WAYPOINT
    zoom_not_predicted: str = ""

    def __post_init__(self) -> None:
        if len(self.waypoints) < 1:
            raise ValueError("a plan needs at least one waypoint")

    @property
    def xy_enu_m(self) -> np.ndarray:
        """(N, 2) waypoint positions, ENU metres."""
        return np.array([[w.x_enu_m, w.y_enu_m] for w in self.waypoints], dtype=float)

    @property
    def path_length_m(self) -> float:
        """Length of the polyline through the waypoints in 3-D, metres."""
        return float(np.linalg.norm(np.diff(self.xyz_enu_m, axis=0), axis=1).sum())

    @property
    def xyz_enu_m(self) -> np.ndarray:
        """(N, 3) waypoint positions with the path's height (z_enu_m), ENU metres."""
        return np.array([[w.x_enu_m, w.y_enu_m, w.z_enu_m] for w in self.waypoints],
                        dtype=float)

    def pointings(self) -> list[GimbalPointing | None]:
        """Per waypoint, the gimbal pointing in force on the way to it and at it (None:
        before any is commanded)."""
        return _held([w.gimbal for w in self.waypoints])

    def zooms_hfov_deg(self) -> list[float | None]:
        """Per waypoint, the camera zoom (horizontal field of view, deg) in force on the way
        to it and at it (None: before any is commanded, the configured camera)."""
        return _held([w.zoom_hfov_deg for w in self.waypoints])

    def written(self) -> np.ndarray:
        """bool (N,): the waypoints a mission carries; a MAV_FRAME_GLOBAL_TERRAIN_ALT one
        leaves out the points added along the terrain."""
        return np.array([not (w.terrain_added
                              and self.altitude_frame is AltitudeFrame.TERRAIN_ALT)
                         for w in self.waypoints], dtype=bool)

    @classmethod
    def from_xy(cls, xy_enu_m: np.ndarray, alt_agl_m: float, speed_mps: float,
                description: str = "") -> Plan:
        """A plan at one altitude and speed through (N, 2) ENU points; repeated points are
        dropped."""
        pts = np.asarray(xy_enu_m, dtype=float).reshape(-1, 2)
        keep = np.ones(len(pts), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-6
        return cls(tuple(Waypoint(float(x), float(y), alt_agl_m, speed_mps)
                         for x, y in pts[keep]), description)


def home_item(origin: Origin) -> MissionItem:
    """The home position item (seq 0 in WPL files and on ArduPilot): origin on the ground."""
    return MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, lat_deg=origin.lat_deg,
                       lon_deg=origin.lon_deg, z_m=origin.ground_alt_msl_m)


def _held(commanded: list[T | None]) -> list[T | None]:
    """Per waypoint, what a mission item commanded there or before it is in force (None:
    nothing yet): each value, or the last one given before it."""
    out: list[T | None] = []
    now: T | None = None
    for value in commanded:
        now = now if value is None else value
        out.append(now)
    return out


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


# -- QGroundControl .plan ------------------------------------------------------------------

# QGroundControlQmlGlobal::AltMode per MAV_FRAME: 1 relative, 2 absolute (AMSL), 4 terrain
# frame; 0 is "mixed" (the plan's global mode only). QGC's 3, "calculated above terrain", is
# its own survey's AMSL heights, which it recomputes from its terrain tiles.
_QGC_ALTITUDE_MODE = {MAV_FRAME_GLOBAL: 2, MAV_FRAME_GLOBAL_RELATIVE_ALT: 1,
                      MAV_FRAME_GLOBAL_TERRAIN_ALT: 4}


def _json_number(v: float) -> float | None:
    return None if math.isnan(v) else v


def qgc_plan_document(items: tuple[MissionItem, ...], origin: Origin,
                      cruise_speed_mps: float) -> dict[str, Any]:
    """A QGroundControl plan (file version 1, mission version 2) of simple mission items."""
    simple = []
    wp_frames = {it.frame for it in items if it.command in NAV_POSITION_COMMANDS}
    plan_mode = _QGC_ALTITUDE_MODE.get(wp_frames.pop(), 0) if len(wp_frames) == 1 else 0
    for k, it in enumerate(items):
        entry: dict[str, Any] = {
            "autoContinue": it.autocontinue, "command": it.command, "doJumpId": k + 1,
            "frame": it.frame,
            "params": [_json_number(v) for v in (it.param1, it.param2, it.param3, it.param4,
                                                 it.lat_deg, it.lon_deg, it.z_m)],
            "type": "SimpleItem"}
        if it.frame in _QGC_ALTITUDE_MODE:
            entry.update({"AMSLAltAboveTerrain": None, "Altitude": it.z_m,
                          "AltitudeMode": _QGC_ALTITUDE_MODE[it.frame]})
        simple.append(entry)
    return {
        "fileType": "Plan", "groundStation": "pdcov", "version": 1,
        "geoFence": {"circles": [], "polygons": [], "version": 2},
        "rallyPoints": {"points": [], "version": 2},
        "mission": {"version": 2, "firmwareType": QGC_FIRMWARE_ARDUPILOT,
                    "vehicleType": QGC_VEHICLE_MULTIROTOR, "globalPlanAltitudeMode": plan_mode,
                    "cruiseSpeed": cruise_speed_mps, "hoverSpeed": cruise_speed_mps,
                    "plannedHomePosition": [origin.lat_deg, origin.lon_deg,
                                            origin.ground_alt_msl_m],
                    "items": simple},
    }


@dataclass(frozen=True, slots=True)
class MissionFile:
    """What a mission file holds: its items (no home), its home position item if any, and
    its default speed in m/s (QGC hoverSpeed; NaN when the file has none)."""

    items: tuple[MissionItem, ...]
    home: MissionItem | None
    default_speed_mps: float = math.nan


def mission_from_qgc_document(doc: Any, source: str) -> MissionFile:
    """The mission in a QGC plan document. Complex items (QGC's own surveys) are refused:
    convert them to simple items in QGC first."""
    mission = doc.get("mission") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan" or not isinstance(
            mission, dict) or not isinstance(mission.get("items"), list):
        raise InputFileError(f"{source}: not a QGroundControl plan (expected fileType 'Plan' "
                             f"and mission.items)")
    out = []
    for k, e in enumerate(mission["items"]):
        key = f"{source}: mission.items[{k}]"
        if not isinstance(e, dict) or e.get("type") != "SimpleItem":
            raise InputFileError(f"{key}: only SimpleItem is supported, got "
                                 f"{e.get('type') if isinstance(e, dict) else e!r}")
        params = e.get("params")
        if not isinstance(params, list) or len(params) != 7:
            raise InputFileError(f"{key}.params: expected 7 values, got {params!r}")
        try:
            p1, p2, p3, p4, lat, lon, z = [math.nan if v is None else float(v)
                                           for v in params]
            out.append(MissionItem(int(e["command"]), int(e["frame"]), p1, p2, p3, p4,
                                   lat, lon, z, autocontinue=bool(e.get("autoContinue", True))))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:  # inf: Overflow
            raise InputFileError(f"{key}: bad command, frame or params ({exc})") from None
    home = None
    planned = mission.get("plannedHomePosition")
    if isinstance(planned, list) and len(planned) == 3 and all(
            isinstance(v, (int, float)) for v in planned):
        home = MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL, lat_deg=planned[0],
                           lon_deg=planned[1], z_m=planned[2])
    hover = mission.get("hoverSpeed")
    speed = float(hover) if isinstance(hover, (int, float)) and hover > 0 else math.nan
    return MissionFile(tuple(out), home, speed)


# -- QGC WPL 110 ---------------------------------------------------------------------------

WPL_HEADER = "QGC WPL 110"


def wpl_text(items: tuple[MissionItem, ...], origin: Origin) -> str:
    """QGC WPL 110: a header, then home as item 0, then one tab-separated line per item:
    seq current frame command p1 p2 p3 p4 lat lon alt autocontinue."""
    lines = [WPL_HEADER]
    for seq, it in enumerate((home_item(origin), *items)):
        params = [0.0 if math.isnan(v) else v
                  for v in (it.param1, it.param2, it.param3, it.param4)]
        fields = [seq, int(seq == 0), it.frame, it.command, *params,
                  f"{it.lat_deg:.8f}", f"{it.lon_deg:.8f}", f"{it.z_m:.6f}",
                  int(it.autocontinue)]
        lines.append("\t".join(str(f) for f in fields))
    return "\n".join(lines) + "\n"


def mission_from_wpl_text(text: str, source: str) -> MissionFile:
    """The mission in a WPL 110 file; line seq 0 is home."""
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines or not lines[0].startswith("QGC WPL 110"):
        raise InputFileError(f"{source}: line 1: expected the header '{WPL_HEADER}'")
    out = []
    for n, line in enumerate(lines[1:], start=2):
        f = line.split()
        if len(f) != 12:
            raise InputFileError(f"{source}: line {n}: expected 12 fields, got {len(f)}")
        try:
            seq, frame, cmd = int(f[0]), int(f[2]), int(f[3])
            p1, p2, p3, p4, lat, lon, z = (float(v) for v in f[4:11])
            auto = bool(int(f[11]))
        except ValueError as exc:
            raise InputFileError(f"{source}: line {n}: {exc}") from None
        if seq != n - 2:
            raise InputFileError(f"{source}: line {n}: expected seq {n - 2}, got {seq}")
        out.append(MissionItem(cmd, frame, p1, p2, p3, p4, lat, lon, z, autocontinue=auto))
    if not out:
        raise InputFileError(f"{source}: no items (not even the home line)")
    return MissionFile(tuple(out[1:]), out[0])


# -- files ---------------------------------------------------------------------------------

WPL_SUFFIXES = (".waypoints", ".txt", ".mission")


def write_plan(path: str | Path, plan: Plan, origin: Origin) -> Path:
    """Write ``plan`` (atomically) as QGC ``.plan`` JSON, or WPL 110 for
    .waypoints/.txt/.mission."""
    path = Path(path)
    items = mission_items(plan, origin)
    if path.suffix == ".plan":
        doc = qgc_plan_document(items, origin, plan.waypoints[0].speed_mps)
        write_text_atomic(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")
    elif path.suffix in WPL_SUFFIXES:
        write_text_atomic(path, wpl_text(items, origin))
    else:
        raise InputFileError(f"{path}: unknown plan format (use .plan or one of "
                             f"{', '.join(WPL_SUFFIXES)})")
    return path


def read_mission(path: str | Path) -> MissionFile:
    """The mission in a ``.plan`` (JSON) or WPL 110 file."""
    path = Path(path)
    text = read_text(path, "plan", InputFileError)
    if text.lstrip().startswith("{"):
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputFileError(f"{path}: not valid JSON ({exc})") from None
        return mission_from_qgc_document(doc, str(path))
    return mission_from_wpl_text(text, str(path))


def read_plan(path: str | Path, origin: Origin,
              default_speed_mps: float | None = None) -> Plan:
    """The plan in a ``.plan`` or WPL 110 file, in ENU about ``origin``; the file's own
    default speed, if any, takes precedence over ``default_speed_mps``."""
    mission = read_mission(path)
    speed = (default_speed_mps if math.isnan(mission.default_speed_mps)
             else mission.default_speed_mps)
    return plan_from_mission_items(mission.items, origin, str(path), speed)
