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
MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
MAV_MOUNT_MODE_MAVLINK_TARGETING = 2
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


class GimbalCommand(str, Enum):
    """Which mission item points the gimbal; prints as its text.

    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000, gimbal protocol v2: ArduPilot 4.3+, PX4):
    param1 pitch deg (positive up), param2 yaw deg (positive right; relative to the vehicle
    with no lock flag), param3/4 rates (NaN: none), param5 GIMBAL_MANAGER_FLAGS (0: follow
    the vehicle's yaw), param7 gimbal device id (0: the primary gimbal).
    MAV_CMD_DO_MOUNT_CONTROL (205, older firmware): param1 pitch deg, param2 roll deg,
    param3 yaw deg, param7 MAV_MOUNT_MODE (2: MAVLINK_TARGETING)."""

    MANAGER = "manager"
    MOUNT = "mount"

    def __str__(self) -> str:
        return str(self.value)

    def item(self, pitch_deg: float, yaw_deg: float = 0.0) -> MissionItem:
        """The item pointing the gimbal at ``pitch_deg`` (-90: nadir) and ``yaw_deg`` from
        the vehicle's heading."""
        if self is GimbalCommand.MANAGER:
            return MissionItem(MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, MAV_FRAME_MISSION,
                               param1=pitch_deg, param2=yaw_deg, param3=float("nan"),
                               param4=float("nan"))
        return MissionItem(MAV_CMD_DO_MOUNT_CONTROL, MAV_FRAME_MISSION, param1=pitch_deg,
                           param3=yaw_deg, z_m=float(MAV_MOUNT_MODE_MAVLINK_TARGETING))
