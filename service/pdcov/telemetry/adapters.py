"""The adapters from autopilot messages to samples: MAVLink messages and DataFlash records.

The one place where MAVLink and DataFlash units (degE7, mm, cdeg, deg) become SI
(``samples``); everything downstream sees only samples. They do not decide the time base:
the caller passes ``t_s`` in the autopilot clock (see ``clocks.BootClock``), because several
messages (HEARTBEAT, PARAM_VALUE, HOME_POSITION) carry no boot time of their own. Also the
MAVLink enum values and status-flag bits the adapters read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pdcov.core.rotations import quat_wxyz_from_euler_zyx
from pdcov.core.utc_clock import gps_week_to_unix_s
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    HeartbeatSample,
    HomeSample,
    LensSample,
    MountTargetSample,
    ParamSample,
    PositionSample,
    RangefinderSample,
    Sample,
    TerrainReportSample,
    UtcSample,
    usable_quaternion,
)

MAV_AUTOPILOT_INVALID = 8  # common.xml MAV_AUTOPILOT: not a flight controller (GCS, gimbal)
MAV_TYPE_GCS = 6


def is_autopilot_heartbeat(msg: Any, system_id: int | None) -> bool:
    """Whether a HEARTBEAT is an autopilot's (of ``system_id``, None: any): not a ground
    station's (MAV_TYPE_GCS) nor of a component that is no autopilot (MAV_AUTOPILOT_INVALID:
    gimbals, cameras, companions). The one rule of which autopilot is followed: the link
    (LinkProtocol, which a .tlog replays through) and a parameter read (link_params)."""
    return (msg.autopilot != MAV_AUTOPILOT_INVALID and msg.type != MAV_TYPE_GCS
            and (system_id is None or msg.get_srcSystem() == system_id))
MAV_MODE_FLAG_SAFETY_ARMED = 128


# --- MAVLink -------------------------------------------------------------------------------

MAX_ANGLE_RAD = 2.0 * math.pi + 0.01
"""Largest Euler angle magnitude accepted from ATTITUDE (rad); beyond it the message is
corrupt, whatever rotation the number would give."""


def valid_lat_lon_e7(lat_e7: int, lon_e7: int) -> bool:
    """WGS84 latitude within +-90 deg and longitude within +-180 deg (degE7 integers)."""
    return abs(lat_e7) <= 900_000_000 and abs(lon_e7) <= 1_800_000_000


def mavlink_boot_time_s(msg: Any) -> float | None:
    """The sender's boot time of a MAVLink message in seconds, if it carries time_boot_ms."""
    ms = getattr(msg, "time_boot_ms", None)
    return None if ms is None else ms * 1e-3


def _quat(q: Sequence[float] | np.ndarray) -> tuple[float, float, float, float]:
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def _attitude(msg: Any, t_s: float) -> AttitudeSample | None:
    # ATTITUDE: roll, pitch, yaw in rad, body FRD -> NED (common.xml), z-y-x Euler.
    angles = (msg.roll, msg.pitch, msg.yaw)
    if not all(math.isfinite(a) and abs(a) <= MAX_ANGLE_RAD for a in angles):
        return None  # common.xml: -pi..pi (yaw 0..2pi by some autopilots); else corrupt
    return AttitudeSample(t_s, _quat(quat_wxyz_from_euler_zyx(*angles)))


def _attitude_quaternion(msg: Any, t_s: float) -> AttitudeSample | None:
    q = (msg.q1, msg.q2, msg.q3, msg.q4)  # ATTITUDE_QUATERNION: w, x, y, z
    if not usable_quaternion(q):
        return None
    return AttitudeSample(t_s, _quat(q))


def _global_position_int(msg: Any, t_s: float) -> PositionSample | None:
    # lat/lon degE7, alt mm MSL, relative_alt mm above home (common.xml). ArduPilot sends
    # all zeros before it has a position estimate: not a position.
    if msg.lat == 0 and msg.lon == 0 or not valid_lat_lon_e7(msg.lat, msg.lon):
        return None
    return PositionSample(t_s, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3,
                          msg.relative_alt * 1e-3)


def _gimbal_status(msg: Any, t_s: float) -> GimbalSample:
    src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
    return GimbalSample(t_s, _quat(msg.q), int(msg.flags), int(msg.failure_flags or 0),
                        src_sys, src_comp, int(getattr(msg, "gimbal_device_id", 0) or 0))


def _home_position(msg: Any, t_s: float) -> HomeSample | None:
    # latitude/longitude degE7, altitude mm MSL (common.xml HOME_POSITION).
    if not valid_lat_lon_e7(msg.latitude, msg.longitude):
        return None
    return HomeSample(t_s, msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3,
                      "HOME_POSITION")


def _param_value(msg: Any, t_s: float) -> ParamSample:
    name = msg.param_id
    if isinstance(name, bytes):
        name = name.decode("ascii", "replace")
    return ParamSample(t_s, name.rstrip("\x00"), float(msg.param_value))


def _image_captured(msg: Any, t_s: float) -> CaptureSample | None:
    # capture_result 1 = success (common.xml CAMERA_IMAGE_CAPTURED).
    if msg.capture_result != 1:
        return None
    return CaptureSample(t_s, int(msg.image_index), "CAMERA_IMAGE_CAPTURED")


def _camera_feedback(msg: Any, t_s: float) -> CaptureSample:
    return CaptureSample(t_s, int(msg.img_idx), "CAMERA_FEEDBACK")


# EKF_STATUS_FLAGS (ardupilotmega.xml) and ESTIMATOR_STATUS_FLAGS (common.xml): the same
# low bits, different high ones (1024 is EKF_UNINITIALIZED in one, ESTIMATOR_GPS_GLITCH in
# the other). ArduPilot sets bit 15 (EKF_GPS_GLITCHING) from nav_filter_status.gps_glitching
# (AP_NavEKF3_Outputs.cpp send_status_report); PX4 sends estimator_status.
# solution_status_flags (mavlink streams/ESTIMATOR_STATUS.hpp). Other bits are not read.
POS_HORIZ_ABS = 16
CONST_POS_MODE = 128
EKF_GPS_GLITCHING = 32768
ESTIMATOR_GPS_GLITCH = 1024


def _ekf_status_report(msg: Any, t_s: float) -> EstimatorSample | None:
    # ArduPilot sends an all-zero report when its AHRS runs no EKF (DCM, or the simulator's
    # own AHRS: AP_AHRS::send_ekf_status_report): that says nothing about the position.
    flags = int(msg.flags)
    if flags == 0:
        return None
    return EstimatorSample(t_s, bool(flags & POS_HORIZ_ABS), bool(flags & CONST_POS_MODE),
                           bool(flags & EKF_GPS_GLITCHING))


def _estimator_status(msg: Any, t_s: float) -> EstimatorSample:
    flags = int(msg.flags)
    return EstimatorSample(t_s, bool(flags & POS_HORIZ_ABS), bool(flags & CONST_POS_MODE),
                           bool(flags & ESTIMATOR_GPS_GLITCH))


def _heartbeat(msg: Any, t_s: float) -> HeartbeatSample:
    return HeartbeatSample(t_s, msg.get_srcSystem(), msg.get_srcComponent(), int(msg.autopilot),
                           int(msg.type), bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED))


def _terrain_report(msg: Any, t_s: float) -> TerrainReportSample | None:
    # lat/lon degE7, terrain_height m AMSL, current_height m above it; spacing 0: no
    # terrain data at that point (common.xml TERRAIN_REPORT; ArduPilot then sends its last
    # extrapolated height, AP_Terrain::send_terrain_report).
    if not valid_lat_lon_e7(msg.lat, msg.lon):
        return None
    return TerrainReportSample(t_s, msg.lat * 1e-7, msg.lon * 1e-7, float(msg.terrain_height),
                               float(msg.current_height), int(msg.spacing) != 0)


DISTANCE_SENSOR_QUALITY_INVALID = 1
"""DISTANCE_SENSOR signal_quality: 0 unknown, 1 invalid, 100 perfect (common.xml)."""


def _distance_sensor(msg: Any, t_s: float) -> RangefinderSample:
    # current/min/max_distance cm (common.xml DISTANCE_SENSOR); orientation
    # MAV_SENSOR_ORIENTATION; signal_quality is a MAVLink 2 extension (0 when absent).
    d_cm = int(msg.current_distance)
    valid = (int(msg.min_distance) <= d_cm <= int(msg.max_distance)
             and int(getattr(msg, "signal_quality", 0) or 0) != DISTANCE_SENSOR_QUALITY_INVALID)
    return RangefinderSample(t_s, d_cm / 100.0, int(msg.orientation), valid, int(msg.id))


def _camera_id(msg: Any) -> dict[str, int]:
    # camera_device_id: a MAVLink 2 extension (0 when absent: the component is the camera).
    return {"system_id": msg.get_srcSystem(), "component_id": msg.get_srcComponent(),
            "camera_device_id": int(getattr(msg, "camera_device_id", 0) or 0)}


def _finite_or_nan(v: float) -> float:
    v = float(v)
    return v if math.isfinite(v) else math.nan


def _camera_fov_status(msg: Any, t_s: float) -> LensSample:
    # hfov, vfov: deg, NaN if unknown (common.xml CAMERA_FOV_STATUS).
    return LensSample(t_s, math.radians(_finite_or_nan(msg.hfov)),
                      math.radians(_finite_or_nan(msg.vfov)), **_camera_id(msg))


def _camera_settings(msg: Any, t_s: float) -> LensSample:
    # zoomLevel: "Current zoom level as a percentage of the full range (0.0 to 100.0, NaN if
    # not known)" (common.xml CAMERA_SETTINGS, a MAVLink 2 extension: NaN when absent).
    return LensSample(t_s, zoom_level=_finite_or_nan(getattr(msg, "zoomLevel", math.nan)),
                      **_camera_id(msg))


def _camera_information(msg: Any, t_s: float) -> LensSample:
    # focal_length: mm, NaN if not known (common.xml CAMERA_INFORMATION).
    return LensSample(t_s, focal_length_mm=_finite_or_nan(msg.focal_length), **_camera_id(msg))


GPS_FIX_TYPE_3D_FIX = 3
"""GPS_FIX_TYPE (common.xml): 0 no GPS, 1 no fix, 2 2D fix, 3 3D fix, 4 DGPS, 5 RTK float,
6 RTK fixed, 7 static, 8 PPP. Below a 3D fix a reported accuracy is not the position's."""


def _gps_raw_int(msg: Any, t_s: float) -> GnssAccuracySample:
    # h_acc, v_acc: mm, MAVLink 2 extensions (common.xml GPS_RAW_INT "Position uncertainty",
    # "Altitude uncertainty"): 0 when absent (MAVLink 1, or a sender of an older dialect)
    # and when the receiver reports none (ArduPilot AP_GPS::send_mavlink_gps_raw sends 0
    # when its driver has no accuracy). eph is HDOP * 100, not an accuracy: never read.
    if int(msg.fix_type) < GPS_FIX_TYPE_3D_FIX:
        return GnssAccuracySample(t_s, math.nan, math.nan)
    return GnssAccuracySample(t_s, int(getattr(msg, "h_acc", 0) or 0) * 1e-3,
                              int(getattr(msg, "v_acc", 0) or 0) * 1e-3)


def _system_time(msg: Any, t_s: float) -> UtcSample:
    # time_unix_usec: "Timestamp (UNIX epoch time)", 0 when unknown (common.xml SYSTEM_TIME;
    # ArduPilot sends AP_RTC's, set from GPS time). core/utc_clock refuses other unset values.
    us = int(msg.time_unix_usec)
    return UtcSample(t_s, msg.time_boot_ms * 1e-3, us * 1e-6 if us > 0 else math.nan)


_MAVLINK = {
    "ATTITUDE": _attitude,
    "ATTITUDE_QUATERNION": _attitude_quaternion,
    "GLOBAL_POSITION_INT": _global_position_int,
    "GIMBAL_DEVICE_ATTITUDE_STATUS": _gimbal_status,
    "HOME_POSITION": _home_position,
    "PARAM_VALUE": _param_value,
    "CAMERA_IMAGE_CAPTURED": _image_captured,
    "CAMERA_FEEDBACK": _camera_feedback,
    "HEARTBEAT": _heartbeat,
    "EKF_STATUS_REPORT": _ekf_status_report,
    "ESTIMATOR_STATUS": _estimator_status,
    "TERRAIN_REPORT": _terrain_report,
    "DISTANCE_SENSOR": _distance_sensor,
    "CAMERA_FOV_STATUS": _camera_fov_status,
    "CAMERA_SETTINGS": _camera_settings,
    "CAMERA_INFORMATION": _camera_information,
    "GPS_RAW_INT": _gps_raw_int,
    "SYSTEM_TIME": _system_time,
}
MAVLINK_TYPES = tuple(_MAVLINK)


def sample_from_mavlink(msg: Any, t_s: float) -> Sample | None:
    """The sample a pymavlink message carries, stamped ``t_s`` (autopilot clock, s), or None
    for message types pdcov does not use and for messages that carry no valid value."""
    adapter = _MAVLINK.get(msg.get_type())
    return None if adapter is None else adapter(msg, t_s)


# --- DataFlash (ArduPilot onboard logs) ----------------------------------------------------

def dataflash_boot_time_s(msg: Any) -> float | None:
    """Boot time in seconds of a DataFlash message (TimeUS; TimeMS in old layouts)."""
    us = getattr(msg, "TimeUS", None)
    if us is not None:
        return us * 1e-6
    ms = getattr(msg, "TimeMS", None)
    return None if ms is None else ms * 1e-3


def _df_att(msg: Any, t_s: float) -> AttitudeSample | None:
    # ATT Roll, Pitch, Yaw in degrees (AP_Logger LogStructure.h), same z-y-x convention.
    angles = np.radians([msg.Roll, msg.Pitch, msg.Yaw])
    if not np.all(np.isfinite(angles)):
        return None
    return AttitudeSample(t_s, _quat(quat_wxyz_from_euler_zyx(*angles)))


def _df_pos(msg: Any, t_s: float) -> PositionSample | None:
    # POS Lat/Lng degrees, Alt m MSL; height above home is RelHomeAlt (4.x) or RelAlt (3.x).
    if msg.Lat == 0 and msg.Lng == 0:
        return None
    rel: Any = getattr(msg, "RelHomeAlt", None)
    if rel is None:
        rel = getattr(msg, "RelAlt", float("nan"))
    return PositionSample(t_s, float(msg.Lat), float(msg.Lng), float(msg.Alt), float(rel))


# The DataFlash MNT message logs the roll/pitch/body-yaw Euler angles of the same quaternion
# the autopilot sends in GIMBAL_DEVICE_ATTITUDE_STATUS (AP_Mount_Backend::write_log); ArduPilot
# sends that message with these flags (ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME).
DATAFLASH_MNT_FLAGS = 4 | 8 | 32


def _df_mnt(msg: Any, t_s: float) -> tuple[GimbalSample, MountTargetSample] | None:
    fields = ("Roll", "Pitch", "YawB", "DRoll", "DPitch", "DYawB", "DYawE")
    if not all(hasattr(msg, f) for f in fields):
        return None  # older MNT layouts log no body-frame yaw
    q = quat_wxyz_from_euler_zyx(*np.radians([msg.Roll, msg.Pitch, msg.YawB]))
    instance = int(getattr(msg, "I", 0))
    gimbal = GimbalSample(t_s, _quat(q), DATAFLASH_MNT_FLAGS, 0, 1, 1, instance + 1)
    target = MountTargetSample(t_s, *(math.radians(v) for v in
                                      (msg.DRoll, msg.DPitch, msg.DYawB, msg.DYawE)))
    return gimbal, target


def _df_parm(msg: Any, t_s: float) -> ParamSample:
    return ParamSample(t_s, str(msg.Name), float(msg.Value))


def _df_orgn(msg: Any, t_s: float) -> HomeSample:
    # ORGN Type 0 = EKF origin, 1 = AHRS home (AP_Logger LogOriginType).
    source = "ORGN home" if int(msg.Type) == 1 else "ORGN EKF origin"
    return HomeSample(t_s, float(msg.Lat), float(msg.Lng), float(msg.Alt), source)


def _df_cam(msg: Any, t_s: float) -> CaptureSample:
    return CaptureSample(t_s, int(getattr(msg, "Img", getattr(msg, "I", 0)) or 0),
                         msg.get_type())


def _df_gps(msg: Any, t_s: float) -> tuple[Sample, ...] | None:
    # GPS Status >= 3 is a 3D fix (AP_GPS::GPS_Status); Lat/Lng deg, Alt m MSL. Used only
    # when a log has no POS (ArduCopter before 3.3), first receiver only. GWk, GMS: the
    # fix's GPS week and ms of week (0 before the receiver knows them), UTC beside TimeUS.
    if int(getattr(msg, "I", 0)) != 0:
        return None
    week = int(getattr(msg, "GWk", 0) or 0)
    boot_s = dataflash_boot_time_s(msg)
    utc = (() if boot_s is None else (UtcSample(t_s, boot_s, gps_week_to_unix_s(
        week, float(msg.GMS)) if week > 0 and msg.Status >= 3 else math.nan),))
    if msg.Status < 3:
        return utc
    return (PositionSample(t_s, float(msg.Lat), float(msg.Lng), float(msg.Alt)), *utc)


# nav_filter_status bits (AP_NavEKF/AP_Nav_Common.h), which XKF4/NKF4 log as SS
# (NavEKF3_core::Log_Write_XKF4: solution = filterStatus.value).
NAV_HORIZ_POS_ABS = 1 << 4
NAV_CONST_POS_MODE = 1 << 7
NAV_GPS_GLITCHING = 1 << 14


# ArduCopter 3.4's EKF2 logs have no core field: NKF4 is core 0, NKF9 the same layout for
# core 1 (DataFlash Log_Write_EKF2: pkt9 = getFilterStatus(1, ...), LOG_NKF9_MSG), both
# with PI, the primary core.
_CORE_OF_LOG = {"NKF4": 0, "NKF9": 1}


def _df_ekf_status(msg: Any, t_s: float) -> tuple[EstimatorSample, ...]:
    # One record per EKF core (C, else by message: _CORE_OF_LOG); only the primary core's
    # (PI) drives the vehicle, so a lane switch changes whose flags apply from then on.
    core = getattr(msg, "C", None)
    core = _CORE_OF_LOG.get(msg.get_type(), 0) if core is None else int(core)
    primary = getattr(msg, "PI", None)
    if core != (int(primary) if primary is not None and int(primary) >= 0 else 0):
        return ()
    ss = int(msg.SS)
    return (EstimatorSample(t_s, bool(ss & NAV_HORIZ_POS_ABS), bool(ss & NAV_CONST_POS_MODE),
                            bool(ss & NAV_GPS_GLITCHING)),)


# AP_Terrain::TerrainStatus (AP_Terrain.h): 0 disabled, 1 unhealthy (no data here), 2 OK.
TERR_STATUS_OK = 2


def _df_terr(msg: Any, t_s: float) -> TerrainReportSample:
    # TERR Lat/Lng deg (the vehicle's position), TerrH m AMSL there, CHeight m above it
    # (AP_Terrain::log_terrain_data, LogStructure "TERR").
    return TerrainReportSample(t_s, float(msg.Lat), float(msg.Lng), float(msg.TerrH),
                               float(msg.CHeight), int(msg.Status) == TERR_STATUS_OK)


# RangeFinder::Status (AP_RangeFinder.h): 0 not connected, 1 no data, 2 out of range low,
# 3 out of range high, 4 good.
RFND_STATUS_GOOD = 4


def _df_rfnd(msg: Any, t_s: float) -> RangefinderSample | None:
    # RFND Dist m (uint16 cm logged with multiplier 0.01, a float m since 4.4), Stat, Orient
    # MAV_SENSOR_ORIENTATION (RangeFinder::Log_RFND). Layouts before 3.6 (Dist1/Dist2, no
    # Orient) say no orientation: not read.
    if not hasattr(msg, "Orient") or not hasattr(msg, "Dist"):
        return None
    return RangefinderSample(t_s, float(msg.Dist), int(msg.Orient),
                             int(msg.Stat) == RFND_STATUS_GOOD, int(getattr(msg, "Instance", 0)))


def _df_gpa(msg: Any, t_s: float) -> GnssAccuracySample | None:
    # GPA HAcc, VAcc: m, the receiver's reported accuracy (AP_GPS::Write_GPS, "GPA"; 0 when
    # it reports none), first receiver only, as _df_gps.
    if int(getattr(msg, "I", 0)) != 0:
        return None
    return GnssAccuracySample(t_s, float(msg.HAcc), float(msg.VAcc))


_DATAFLASH = {"ATT": _df_att, "POS": _df_pos, "MNT": _df_mnt, "PARM": _df_parm,
              "ORGN": _df_orgn, "CAM": _df_cam, "TRIG": _df_cam, "GPS": _df_gps,
              "XKF4": _df_ekf_status, "NKF4": _df_ekf_status, "NKF9": _df_ekf_status,
              "TERR": _df_terr, "RFND": _df_rfnd, "GPA": _df_gpa}
DATAFLASH_TYPES = tuple(_DATAFLASH)


def samples_from_dataflash(msg: Any, t_s: float) -> tuple[Sample, ...]:
    """The samples a DataFlash message carries (MNT gives a gimbal sample and a target)."""
    adapter = _DATAFLASH.get(msg.get_type())
    out = None if adapter is None else adapter(msg, t_s)
    if out is None:
        return ()
    return out if isinstance(out, tuple) else (out,)
