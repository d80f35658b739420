"""MAVLink mission items: the vocabulary that plan files, planning and the uploader share
(MAV_CMD and MAV_FRAME values from common.xml)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LOITER_TIME = 19  # param1 seconds to hover at the item's position
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
MAV_MOUNT_MODE_MAVLINK_TARGETING = 2
GIMBAL_MANAGER_FLAGS_YAW_LOCK = 16  # param5 of 1000: the yaw is relative to north
MAV_CMD_SET_CAMERA_ZOOM = 531  # param1 CAMERA_ZOOM_TYPE, param2 its value (common.xml)
MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_TERRAIN_ALT = 10
NAV_POSITION_COMMANDS = (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LOITER_TIME)
"""The navigation items a plan's waypoints are written as (a hover: either)."""
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12


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


def mission_item_int_xy(it: MissionItem) -> tuple[int, int]:
    """MISSION_ITEM_INT x, y of an item: degrees * 1e7 for a position, but param5 and
    param6 themselves for a MAV_FRAME_MISSION item (e.g. the gimbal manager's flags), as
    ArduPilot (AP_Mission) and PX4 read them."""
    if it.frame == MAV_FRAME_MISSION:
        return round(it.lat_deg), round(it.lon_deg)
    return round(it.lat_deg * 1e7), round(it.lon_deg * 1e7)


def mission_item_int_params56(frame: int, x: int, y: int) -> tuple[float, float]:
    """MissionItem lat_deg, lon_deg (param5, param6) of MISSION_ITEM_INT x, y: the inverse
    of ``mission_item_int_xy``."""
    if frame == MAV_FRAME_MISSION:
        return float(x), float(y)
    return x * 1e-7, y * 1e-7


class AltitudeFrame(str, Enum):
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


class HoverItem(str, Enum):
    """How a hover is written; prints as its text. WAYPOINT: MAV_CMD_NAV_WAYPOINT with
    param1 the hold time (s); LOITER_TIME: MAV_CMD_NAV_LOITER_TIME, param1 the time (s)."""

    WAYPOINT = "waypoint"
    LOITER_TIME = "loiter-time"

    def __str__(self) -> str:
        return str(self.value)


class GimbalCommand(str, Enum):
    """Which mission item points the gimbal; prints as its text.

    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000, gimbal protocol v2: ArduPilot 4.3+, PX4):
    param1 pitch deg (positive up), param2 yaw deg (positive right; relative to the vehicle
    without the lock flag, to north with it), param3/4 rates (NaN: none), param5
    GIMBAL_MANAGER_FLAGS (0: the yaw follows the vehicle; 16 YAW_LOCK: an earth-frame yaw),
    param7 gimbal device id (0: the primary gimbal).
    MAV_CMD_DO_MOUNT_CONTROL (205, older firmware): param1 pitch deg, param2 roll deg,
    param3 yaw deg (relative to the vehicle: ArduPilot's AP_Mount takes it in the body
    frame, so it cannot hold an earth-frame yaw), param7 MAV_MOUNT_MODE (2:
    MAVLINK_TARGETING)."""

    MANAGER = "manager"
    MOUNT = "mount"

    def __str__(self) -> str:
        return str(self.value)

    def item(self, pitch_deg: float, yaw_deg: float = 0.0, earth_yaw: bool = False
             ) -> MissionItem:
        """The item pointing the gimbal at ``pitch_deg`` (-90: nadir) and ``yaw_deg``
        (clockwise) from the vehicle's heading, or from north with ``earth_yaw`` (the
        manager's YAW_LOCK; ValueError for the mount command, which has no such flag)."""
        if self is GimbalCommand.MANAGER:
            return MissionItem(MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, MAV_FRAME_MISSION,
                               param1=pitch_deg, param2=yaw_deg, param3=float("nan"),
                               param4=float("nan"),
                               lat_deg=float(GIMBAL_MANAGER_FLAGS_YAW_LOCK if earth_yaw else 0))
        if earth_yaw:
            raise ValueError("MAV_CMD_DO_MOUNT_CONTROL has no earth-frame yaw")
        return MissionItem(MAV_CMD_DO_MOUNT_CONTROL, MAV_FRAME_MISSION, param1=pitch_deg,
                           param3=yaw_deg, z_m=float(MAV_MOUNT_MODE_MAVLINK_TARGETING))


class Firmware(str, Enum):
    """The autopilot firmware a plan is written for; prints as its text. Its MAV_AUTOPILOT
    number is the HEARTBEAT's ``autopilot`` field and a QGC .plan's ``firmwareType``."""

    ARDUPILOT = "ardupilot"
    PX4 = "px4"

    def __str__(self) -> str:
        return str(self.value)

    @property
    def mav_autopilot(self) -> int:
        return {Firmware.ARDUPILOT: MAV_AUTOPILOT_ARDUPILOTMEGA,
                Firmware.PX4: MAV_AUTOPILOT_PX4}[self]

    @classmethod
    def of_mav_autopilot(cls, autopilot: int) -> Firmware | None:
        """The firmware of a HEARTBEAT's MAV_AUTOPILOT; None for any other autopilot."""
        return next((f for f in cls if f.mav_autopilot == autopilot), None)

    def refused_items(self, items: tuple[MissionItem, ...]) -> list[str]:
        """One line per item this firmware's mission refuses (seq from 0, home not counted).
        Every command pdcov writes is taken by both (docs/planning.md); PX4 answers
        MAV_MISSION_UNSUPPORTED_FRAME to MAV_FRAME_GLOBAL_TERRAIN_ALT (it keeps no terrain
        database)."""
        if self is not Firmware.PX4:
            return []
        return [f"item {k}: MAV_FRAME_GLOBAL_TERRAIN_ALT ({it.frame}), which PX4 missions "
                f"do not take: plan with --terrain-frame amsl or relative"
                for k, it in enumerate(items) if it.frame == MAV_FRAME_GLOBAL_TERRAIN_ALT]
