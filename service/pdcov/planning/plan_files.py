"""A plan's mission files: QGroundControl ``.plan`` JSON (file version 1, mission version
2, simple items only) and the ``QGC WPL 110`` text format, both carrying the items of
``plan_items.mission_items``; ``write_plan``, ``read_mission`` (a ``MissionFile``) and
``read_plan`` (a Plan in ENU)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pdcov.atomic import write_text_atomic
from pdcov.core.geodesy import Origin
from pdcov.core.mission import (
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT,
    NAV_POSITION_COMMANDS,
    Firmware,
    MissionItem,
)
from pdcov.errors import ConfigError, InputFileError
from pdcov.planning.plan import Plan
from pdcov.planning.plan_items import home_item, mission_items, plan_from_mission_items
from pdcov.yaml_file import read_text

QGC_VEHICLE_MULTIROTOR = 2


# -- QGroundControl .plan ------------------------------------------------------------------

# QGroundControlQmlGlobal::AltMode per MAV_FRAME: 1 relative, 2 absolute (AMSL), 4 terrain
# frame; 0 is "mixed" (the plan's global mode only). QGC's 3, "calculated above terrain", is
# its own survey's AMSL heights, which it recomputes from its terrain tiles.
_QGC_ALTITUDE_MODE = {MAV_FRAME_GLOBAL: 2, MAV_FRAME_GLOBAL_RELATIVE_ALT: 1,
                      MAV_FRAME_GLOBAL_TERRAIN_ALT: 4}


def _json_number(v: float) -> float | None:
    return None if math.isnan(v) else v


def qgc_plan_document(items: tuple[MissionItem, ...], origin: Origin,
                      cruise_speed_mps: float, firmware: Firmware) -> dict[str, Any]:
    """A QGroundControl plan (file version 1, mission version 2) of simple mission items,
    its ``firmwareType`` the firmware's MAV_AUTOPILOT (QGC's own numbering)."""
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
        "mission": {"version": 2, "firmwareType": firmware.mav_autopilot,
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
WPL_NAN = "NaN"
"""An unset parameter (NaN: the autopilot keeps its own value) in a WPL file, as Mission
Planner writes it and reads it back (.NET's float.Parse takes exactly "NaN"), and as
pymavlink (MAVProxy) and ``mission_from_wpl_text`` read it (Python's float takes any case).
0.0 would mean yaw north or a gimbal rate of zero. QGC's WPL import reads only "nan" (Qt's
toDouble) and takes "NaN" as 0.0: for QGC use the .plan, whose null it reads as NaN."""


def wpl_text(items: tuple[MissionItem, ...], origin: Origin) -> str:
    """QGC WPL 110: a header, then home as item 0, then one tab-separated line per item:
    seq current frame command p1 p2 p3 p4 lat lon alt autocontinue; an unset parameter is
    WPL_NAN."""
    lines = [WPL_HEADER]
    for seq, it in enumerate((home_item(origin), *items)):
        params = [WPL_NAN if math.isnan(v) else repr(float(v))
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


def write_plan(path: str | Path, plan: Plan, origin: Origin,
               firmware: Firmware = Firmware.ARDUPILOT) -> Path:
    """Write ``plan`` (atomically) for ``firmware`` as QGC ``.plan`` JSON, or WPL 110 for
    .waypoints/.txt/.mission; ConfigError, before writing, naming the items the firmware's
    mission would refuse (``Firmware.refused_items``)."""
    path = Path(path)
    items = mission_items(plan, origin)
    refused = firmware.refused_items(items)
    if refused:
        raise ConfigError(f"{path}: a {firmware} plan cannot hold {'; '.join(refused[:1])}"
                          + (f" (and {len(refused) - 1} more)" if len(refused) > 1 else ""))
    if path.suffix == ".plan":
        doc = qgc_plan_document(items, origin, plan.waypoints[0].speed_mps, firmware)
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
