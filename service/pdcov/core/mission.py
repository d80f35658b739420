"""MAVLink mission items: the vocabulary that plan files, planning and the uploader share
(MAV_CMD and MAV_FRAME values from common.xml)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_SET_CAMERA_ZOOM = 531  # param1 CAMERA_ZOOM_TYPE, param2 its value (common.xml)
MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_TERRAIN_ALT = 10


@dataclass(frozen=True, slots=True)
class MissionItem:
    """One MAVLink mission item (MISSION_ITEM_INT fields; lat/lon in degrees, z in metres)."""

    command: int
    frame: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    lat_deg: float = 0.0
    lon_deg: float = 0.0
    z_m: float = 0.0
    autocontinue: bool = True


class AltitudeFrame(str, Enum):  # StrEnum from 3.11; pdcov runs on 3.10
    """How a plan's altitudes are written (``planning.terrain_frame``), named for the
    MAV_FRAME of its waypoints; prints as its text."""

    RELATIVE = "relative"
    """MAV_FRAME_GLOBAL_RELATIVE_ALT: metres above home; a constant altitude over terrain."""
    AMSL = "amsl"
    """MAV_FRAME_GLOBAL: metres above mean sea level, waypoints added along the terrain."""
    TERRAIN_ALT = "terrain_alt"
    """MAV_FRAME_GLOBAL_TERRAIN_ALT: metres above the terrain the autopilot knows."""

    def __str__(self) -> str:
        return str(self.value)

    @property
    def mav_frame(self) -> int:
        return {AltitudeFrame.RELATIVE: MAV_FRAME_GLOBAL_RELATIVE_ALT,
                AltitudeFrame.AMSL: MAV_FRAME_GLOBAL,
                AltitudeFrame.TERRAIN_ALT: MAV_FRAME_GLOBAL_TERRAIN_ALT}[self]
