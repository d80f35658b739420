"""Telemetry samples: the value types everything downstream of the adapters sees.

SI units and radians: times ``t_s`` in s of the autopilot clock (the caller's, see
``clocks.BootClock``), latitude/longitude in degrees, altitudes in m (AMSL, or above home
where named so), angles in rad. Frames: attitudes are body FRD -> NED quaternions (w, x, y,
z; MAVLink ATTITUDE); gimbal quaternions are in the frame their flags (or the configured
interpretation, gimbal.py) say. The adapters from messages are ``adapters``, the
time-sorted arrays ``series``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

MIN_QUAT_NORM = 0.5
"""A quaternion shorter than this (zero, or nearly) gives no rotation: refused."""


def usable_quaternion(q: Sequence[float]) -> bool:
    """Finite and not (nearly) zero, so that normalising it gives a rotation."""
    if not all(math.isfinite(v) for v in q):
        return False
    norm = math.sqrt(sum(float(v) * float(v) for v in q))
    return math.isfinite(norm) and norm > MIN_QUAT_NORM


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """Vehicle attitude at ``t_s``: unit quaternion (w, x, y, z) of R_ned_body (FRD -> NED)."""

    t_s: float
    q_ned_body_wxyz: tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class PositionSample:
    """Vehicle position: WGS84 degrees, altitude metres above mean sea level, and height
    above home in metres (NaN when the message has none)."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    relative_alt_m: float = float("nan")


@dataclass(frozen=True, slots=True)
class GimbalSample:
    """One GIMBAL_DEVICE_ATTITUDE_STATUS (or its DataFlash equivalent).

    q_wxyz: gimbal attitude quaternion as sent (frame per ``flags`` or per the configured
    interpretation; not normalised, so that a bad norm can be reported). flags:
    GIMBAL_DEVICE_FLAGS bits. failure_flags: GIMBAL_DEVICE_ERROR_FLAGS bits. The source is
    (system_id, component_id, device_id); device_id 0 = the gimbal reporting for itself.
    """

    t_s: float
    q_wxyz: tuple[float, float, float, float]
    flags: int
    failure_flags: int = 0
    system_id: int = 1
    component_id: int = 1
    device_id: int = 0

    @property
    def source(self) -> tuple[int, int, int]:
        return (self.system_id, self.component_id, self.device_id)


@dataclass(frozen=True, slots=True)
class HomeSample:
    """Home (or EKF origin) position: degrees, metres MSL; ``source`` names the message."""

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    source: str


@dataclass(frozen=True, slots=True)
class CaptureSample:
    """A camera capture (trigger) event at ``t_s``."""

    t_s: float
    image_index: int
    source: str


@dataclass(frozen=True, slots=True)
class ParamSample:
    """An autopilot parameter value (PARAM_VALUE, DataFlash PARM, ULog parameter)."""

    t_s: float
    name: str
    value: float


@dataclass(frozen=True, slots=True)
class MountTargetSample:
    """The mount's desired earth-frame target as DataFlash MNT logs it (DRoll, DPitch,
    DYawB, DYawE), radians; yaw_earth_rad is NaN when yaw is not earth-locked."""

    t_s: float
    roll_rad: float
    pitch_rad: float
    yaw_body_rad: float
    yaw_earth_rad: float


@dataclass(frozen=True, slots=True)
class HeartbeatSample:
    """Who is on the link: MAVLink HEARTBEAT source, autopilot (MAV_AUTOPILOT), MAV_TYPE."""

    t_s: float
    system_id: int
    component_id: int
    autopilot: int
    vehicle_type: int
    armed: bool


@dataclass(frozen=True, slots=True)
class EstimatorSample:
    """What the autopilot's position estimator says of its horizontal position at ``t_s``
    (EKF_STATUS_REPORT, ESTIMATOR_STATUS, DataFlash XKF4/NKF4 SS, ULog estimator_status),
    as three verdicts: pos_horiz_abs (the absolute horizontal position is good),
    const_pos_mode (no position aiding: the position is held, not measured), gps_glitch
    (the estimator takes its GPS for faulty). pose_tracker.estimator_reason reads them."""

    t_s: float
    pos_horiz_abs: bool
    const_pos_mode: bool
    gps_glitch: bool


@dataclass(frozen=True, slots=True)
class TerrainReportSample:
    """The autopilot's own terrain database at a point (TERRAIN_REPORT, DataFlash TERR):
    terrain_alt_msl_m, the ground's height (m AMSL) at lat_deg/lon_deg (WGS84 degrees);
    height_above_terrain_m, the vehicle's height above that ground (m). has_data: the
    autopilot has terrain data there (TERRAIN_REPORT spacing != 0, TERR Status OK); without
    it the heights are placeholders."""

    t_s: float
    lat_deg: float
    lon_deg: float
    terrain_alt_msl_m: float
    height_above_terrain_m: float
    has_data: bool


MAX_GNSS_ACCURACY_M = 1000.0
"""A reported position accuracy above this (m) is no accuracy (a receiver without a fix
reports thousands of km): unknown, as are negative and non-finite ones."""


def gnss_accuracy_m(value_m: float) -> float:
    """``value_m`` (a reported accuracy, m) if it is one, else NaN (unknown): 0 (MAVLink's
    GPS_RAW_INT says 0 when the receiver reports none), negative, non-finite or above
    MAX_GNSS_ACCURACY_M."""
    v = float(value_m)
    return v if math.isfinite(v) and 0.0 < v <= MAX_GNSS_ACCURACY_M else math.nan


@dataclass(frozen=True, slots=True)
class GnssAccuracySample:
    """The 1-sigma position accuracy the autopilot's GNSS receiver reports at ``t_s``
    (GPS_RAW_INT h_acc/v_acc, DataFlash GPA HAcc/VAcc, ULog vehicle_gps_position eph/epv):
    horizontal_m, vertical_m in m as reported; a value that is none (gnss_accuracy_m) is
    unknown. A report of an unknown accuracy is a report too: from its time on the accuracy
    is unknown (telemetry/gnss_accuracy.py)."""

    t_s: float
    horizontal_m: float
    vertical_m: float


@dataclass(frozen=True, slots=True)
class UtcSample:
    """The autopilot's real-time clock beside its boot clock (MAVLink SYSTEM_TIME, DataFlash
    GPS GWk/GMS, ULog vehicle_gps_position time_utc_usec): at ``t_s`` (the autopilot clock)
    the message carried boot time ``boot_s`` (s) and UTC ``unix_s`` (s since 1970; NaN
    when the autopilot did not know it). core/utc_clock.UtcClock takes them."""

    t_s: float
    boot_s: float
    unix_s: float


MAV_SENSOR_ROTATION_PITCH_270 = 25
"""MAV_SENSOR_ORIENTATION (common.xml) of a downward-facing sensor (PX4 distance_sensor
ROTATION_DOWNWARD_FACING, ArduPilot RNGFNDx_ORIENT 25)."""


@dataclass(frozen=True, slots=True)
class RangefinderSample:
    """One rangefinder reading (DISTANCE_SENSOR, DataFlash RFND, ULog distance_sensor):
    distance_m along the sensor's axis (m); orientation: MAV_SENSOR_ORIENTATION (25 = down,
    the body's +z axis); in_range: the sender calls the reading valid (within its min/max
    distance and not flagged invalid; DataFlash: Stat Good); sensor_id: its instance."""

    t_s: float
    distance_m: float
    orientation: int
    in_range: bool
    sensor_id: int = 0


@dataclass(frozen=True, slots=True)
class LensSample:
    """A camera's zoom report: CAMERA_FOV_STATUS (hfov_rad, vfov_rad: fields of view, rad),
    CAMERA_SETTINGS (zoom_level: zoomLevel as sent) or CAMERA_INFORMATION (focal_length_mm);
    the fields a message does not carry are NaN. The camera is (system_id, component_id,
    camera_device_id): a MAVLink camera component (100-105) with device id 0, or an
    autopilot-attached camera (ArduPilot AP_Camera: the autopilot's component, device id =
    instance, 1 for the first)."""

    t_s: float
    hfov_rad: float = float("nan")
    vfov_rad: float = float("nan")
    zoom_level: float = float("nan")
    focal_length_mm: float = float("nan")
    system_id: int = 1
    component_id: int = 100
    camera_device_id: int = 0

    @property
    def camera_id(self) -> tuple[int, int]:
        """(component_id, camera_device_id)."""
        return (self.component_id, self.camera_device_id)


Sample = (AttitudeSample | PositionSample | GimbalSample | HomeSample | CaptureSample
          | ParamSample | MountTargetSample | HeartbeatSample | EstimatorSample
          | TerrainReportSample | RangefinderSample | LensSample | GnssAccuracySample
          | UtcSample)
