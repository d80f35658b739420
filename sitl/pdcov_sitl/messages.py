"""The vehicle's telemetry as ArduPilot-like or PX4-like firmware sends it: stream tables,
parameters, and the builders of each message from the simulated state.

Units on the wire (common.xml): lat/lon degE7, altitudes mm, speeds cm/s, headings cdeg,
attitude rad (ATTITUDE yaw in [-pi, pi]), quaternions (w, x, y, z). Frames: attitude body
FRD -> NED; LOCAL_POSITION_NED about home; GIMBAL_DEVICE_ATTITUDE_STATUS per gimbal mode:

* ``ardupilot-servo``: from the autopilot (component 1, gimbal_device_id 1), flags 44
  (ROLL_LOCK | PITCH_LOCK | YAW_IN_VEHICLE_FRAME) yet the quaternion is the body-frame servo
  demand ``Quaternion::from_euler(roll, pitch, yaw)``, as ArduPilot's AP_Mount_Servo sends
  it (docs/autopilots.md); MNT1_TYPE 1.
* ``ardupilot-device``: from the autopilot (component 1, gimbal_device_id 1), flags 44; the
  quaternion is what the flags say: roll/pitch against the horizon, yaw from the vehicle's
  heading (the vehicle frame, NED turned by the heading); MNT1_TYPE 7 (BrushlessPWM).
* ``device-earth``: from the gimbal itself (component 154, MAV_COMP_ID_GIMBAL, its own
  HEARTBEAT and boot clock, gimbal_device_id 0), flags 76 (ROLL_LOCK | PITCH_LOCK |
  YAW_IN_EARTH_FRAME): the quaternion is R_ned_gimbal; MNT1_TYPE 6 (a MAVLink gimbal).
* ``fixed``: no gimbal messages; MNT1_TYPE 0.

Over terrain (a ground model): TERRAIN_REPORT (ArduPilot-like only; PX4 has no terrain
protocol) as AP_Terrain::send_terrain_report fills it for the vehicle's position, and
DISTANCE_SENSOR from a downward rangefinder (MAV_SENSOR_ROTATION_PITCH_270) measuring along
the body's down axis to the ground, as GCS_MAVLINK::send_distance_sensor (ArduPilot) or
PX4's DISTANCE_SENSOR stream fill it.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mav

from .dynamics import VehicleState, local_scales
from .gimbal import _Rx, _Ry, _Rz, quat_from_euler_zyx, quat_from_R
from .protocol import AUTOPILOTS, Autopilot
from .terrain import GroundModel, slant_range_m

GimbalMode = Literal["ardupilot-servo", "ardupilot-device", "device-earth", "fixed"]
"""How the simulated gimbal reports itself (docs/simulator.md)."""
GIMBAL_MODES: tuple[GimbalMode, ...] = get_args(GimbalMode)
GIMBAL_COMPONENT = mav.MAV_COMP_ID_GIMBAL  # 154
GIMBAL_CLOCK_OFFSET_S = 1.234
"""The gimbal's own boot clock runs this far ahead of the autopilot's (it boots faster)."""

FLAGS_AUTOPILOT = (mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                   | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)  # 44
FLAGS_DEVICE_EARTH = (mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
                      | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)  # 76
GIMBAL_FAILED_FLAGS = mav.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR
ESTIMATOR_OK_FLAGS = 831
"""Attitude, horizontal and vertical velocity, relative and absolute horizontal position,
vertical position, predicted relative and absolute horizontal position: the same bits in
EKF_STATUS_FLAGS and ESTIMATOR_STATUS_FLAGS."""
MNT1_TYPE = {"ardupilot-servo": 1, "ardupilot-device": 7, "device-earth": 6, "fixed": 0}

# Default stream rates in Hz. ArduPilot: what a ground station's usual stream-rate request
# gives (EXTRA1 20 Hz: ATTITUDE, ATTITUDE_QUATERNION; POSITION 10 Hz; EXTENDED_STATUS 2 Hz;
# EXTRA3 2 Hz: EKF_STATUS_REPORT; the mount's status at 20 Hz as on the real servo-gimbal
# log). PX4: its "onboard" link mode (ESTIMATOR_STATUS 0.5 Hz, mavlink_main.cpp).
STREAMS_HZ = {
    "ardupilot": {"HEARTBEAT": 1.0, "SYS_STATUS": 2.0, "SYSTEM_TIME": 1.0, "ATTITUDE": 20.0,
                  "ATTITUDE_QUATERNION": 20.0, "GLOBAL_POSITION_INT": 10.0,
                  "LOCAL_POSITION_NED": 10.0, "GPS_RAW_INT": 5.0, "HOME_POSITION": 1.0,
                  "GIMBAL_DEVICE_ATTITUDE_STATUS": 20.0, "EKF_STATUS_REPORT": 2.0},
    "px4": {"HEARTBEAT": 1.0, "SYS_STATUS": 5.0, "SYSTEM_TIME": 1.0, "ATTITUDE": 50.0,
            "ATTITUDE_QUATERNION": 50.0, "GLOBAL_POSITION_INT": 50.0,
            "LOCAL_POSITION_NED": 30.0, "GPS_RAW_INT": 5.0, "HOME_POSITION": 0.5,
            "GIMBAL_DEVICE_ATTITUDE_STATUS": 10.0, "ESTIMATOR_STATUS": 0.5},
}
# Over terrain: ArduPilot sends both in its EXTRA3 stream group (GCS_Mavlink.cpp), with
# EKF_STATUS_REPORT; PX4's onboard mode sends DISTANCE_SENSOR at 10 Hz and no TERRAIN_REPORT.
TERRAIN_STREAMS_HZ = {
    "ardupilot": {"TERRAIN_REPORT": 2.0, "DISTANCE_SENSOR": 2.0},
    "px4": {"DISTANCE_SENSOR": 10.0},
}
TERRAIN_SPACING_M = 100
"""TERRAIN_SPACING's default: the grid spacing TERRAIN_REPORT names when it has data."""
TERRAIN_LOADED_BLOCKS = 12 * 56
"""TERRAIN_REPORT.loaded: a full cache (TERRAIN_CACHE_SZ 12 grids of 56 4x4 blocks)."""
GIMBAL_DEVICE_STREAMS_HZ = {"HEARTBEAT": 1.0, "GIMBAL_DEVICE_ATTITUDE_STATUS": 20.0}

# ArduCopter custom modes (mode numbers) and PX4 main/sub modes, per flight phase.
_ARDUCOPTER_MODE = {"ground": 0, "takeoff": 3, "waypoint": 3, "return": 6, "land": 9}
_PX4_MODE = {"ground": (3, 0), "takeoff": (4, 2), "waypoint": (4, 4), "return": (4, 5),
             "land": (4, 6)}


@dataclass(frozen=True, slots=True)
class Rangefinder:
    """The downward rangefinder: the distances it measures (m) and its noise (m, 1 sigma of
    a Gaussian added to each reading; 0: exact). Beyond max_m it reads max_m + 1 m (no
    return, out of range high)."""

    min_m: float = 0.2
    max_m: float = 40.0
    noise_m: float = 0.0

    def __post_init__(self) -> None:
        if not (0 <= self.min_m < self.max_m <= 650 and self.noise_m >= 0):
            raise ValueError(f"rangefinder: expected 0 <= min_m < max_m <= 650 m and "
                             f"noise_m >= 0, got {self}")


def autopilot_params(autopilot: Autopilot, gimbal_mode: GimbalMode, system_id: int,
                     limits_deg: tuple[tuple[float, float], ...],
                     rangefinder: Rangefinder | None = None) -> dict[str, float]:
    """Parameters the endpoint answers: the mount's type and limits (ArduPilot names, which
    pdcov reads; ArduPilot hides the limits while MNT1_TYPE is 0), the return to launch
    (ArduCopter's RTL_*, read when the flight starts: mission.ReturnRule), the rangefinder
    when fitted, and a few others."""
    if autopilot == "px4":
        params = {"MAV_SYS_ID": float(system_id), "MPC_XY_CRUISE": 5.0,
                  "MNT_MODE_OUT": 2.0 if gimbal_mode != "fixed" else -1.0}
        return params
    params = {"SYSID_THISMAV": float(system_id), "MAV_GCS_SYSID": 255.0, "FRAME_CLASS": 1.0,
              "FRAME_TYPE": 1.0, "WPNAV_SPEED": 500.0, "MNT1_TYPE": float(MNT1_TYPE[gimbal_mode])}
    if gimbal_mode != "fixed":
        for axis, (lo, hi) in zip(("ROLL", "PITCH", "YAW"), limits_deg, strict=True):
            params[f"MNT1_{axis}_MIN"] = float(lo)
            params[f"MNT1_{axis}_MAX"] = float(hi)
    # ArduCopter's defaults (Parameters.cpp, config.h): cm, cm, slope, 0 above home /
    # 1 above terrain, ms.
    params.update({"RTL_ALT": 1500.0, "RTL_CLIMB_MIN": 0.0, "RTL_CONE_SLOPE": 3.0,
                   "RTL_ALT_TYPE": 0.0, "RTL_LOITER_TIME": 5000.0})
    if rangefinder is not None:
        # RNGFND1_TYPE 100: SITL; ORIENT 25: down (PITCH_270); MIN/MAX in m (4.6 and later).
        params.update({"RNGFND1_TYPE": 100.0, "RNGFND1_ORIENT": 25.0,
                       "RNGFND1_MIN": rangefinder.min_m, "RNGFND1_MAX": rangefinder.max_m,
                       "TERRAIN_ENABLE": 1.0, "TERRAIN_SPACING": float(TERRAIN_SPACING_M)})
    return params


@dataclass(frozen=True, slots=True)
class Snapshot:
    """What the messages of one instant are built from.

    state: the true vehicle state. time_boot_ms / unix_us: the autopilot's clocks.
    gps_offset_ned_m: a GPS glitch to add to reported positions. phase: the guidance leg kind
    ('ground' before take-off and after landing). armed. gimbal_q_wxyz / gimbal_flags /
    gimbal_failure: the gimbal report (None: no gimbal). battery_fraction: 0..1.
    gps_glitching: the estimator takes its GPS for faulty (faults.FaultSpec.gps_glitching).
    """

    state: VehicleState
    time_boot_ms: int
    unix_us: int
    gps_offset_ned_m: tuple[float, float, float]
    phase: str
    armed: bool
    gimbal_q_wxyz: tuple[float, float, float, float] | None
    gimbal_flags: int
    gimbal_failure: int
    gimbal_delta_yaw_rad: float
    battery_fraction: float
    gps_glitching: bool = False


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


GNSS_ACCURACY_M = 0.3
"""The GPS receiver's default 1-sigma horizontal error per axis (m, ``--gnss-accuracy-m``)."""
GNSS_ACCURACY_RANGE_M = (0.001, 100.0)
"""The receiver errors the simulator takes (m): at least 1 mm, the unit h_acc is sent in."""
GNSS_VERTICAL_PER_HORIZONTAL = 5.0 / 3.0
"""Its vertical error per horizontal one (a receiver's vertical is the worse)."""
GNSS_WALK_PHI = 0.95
"""The receiver's error is a first-order random walk per message: e <- phi e + w, w Gaussian;
its steady 1-sigma is sd(w) / sqrt(1 - phi^2) (20 messages, 4 s at 5 Hz, to forget)."""


class MessageBuilder:
    """Builds the autopilot's messages by stream name. ``mavlink`` is the endpoint's MAVLink
    object (``.X_encode``); home: (lat_deg, lon_deg, alt_msl_m). ground: the world's ground
    (TERRAIN_REPORT, DISTANCE_SENSOR; None: neither is built); rangefinder: its sensor.
    gnss_accuracy_m: the GPS receiver's 1-sigma horizontal error per axis (m), the h_acc
    GPS_RAW_INT reports (its vertical GNSS_VERTICAL_PER_HORIZONTAL times it, v_acc)."""

    def __init__(self, mavlink: mav.MAVLink, autopilot: Autopilot,
                 home: tuple[float, float, float], seed: int,
                 ground: GroundModel | None = None,
                 rangefinder: Rangefinder = Rangefinder(),
                 gnss_accuracy_m: float = GNSS_ACCURACY_M) -> None:
        if autopilot not in AUTOPILOTS:
            raise ValueError(f"autopilot {autopilot!r}: expected one of {AUTOPILOTS}")
        lo, hi = GNSS_ACCURACY_RANGE_M
        if not lo <= gnss_accuracy_m <= hi:
            raise ValueError(f"gnss_accuracy_m {gnss_accuracy_m!r}: expected {lo:g}..{hi:g} m")
        self.gnss_sigma_m = (gnss_accuracy_m, gnss_accuracy_m,
                             gnss_accuracy_m * GNSS_VERTICAL_PER_HORIZONTAL)
        self.m = mavlink
        self.autopilot = autopilot
        self.home = home
        self._m_per_rad = local_scales(home[0])
        self._gps_rng = random.Random(f"{seed}:gps")
        self._gps_noise = [0.0, 0.0, 0.0]
        self.ground = ground
        self.rangefinder = rangefinder
        self._range_rng = random.Random(f"{seed}:rangefinder")
        self._home_terrain_msl_m = (float(ground.height_msl_m(home[0], home[1]))
                                    if ground is not None else math.nan)

    def _reported_position(self, s: Snapshot) -> tuple[float, float, float, float, float, float]:
        """(lat_deg, lon_deg, alt_msl_m, north, east, down m about home) with the glitch."""
        dn, de, dd = s.gps_offset_ned_m
        st = s.state
        lat = st.lat_deg + math.degrees(dn / self._m_per_rad[0])
        lon = st.lon_deg + math.degrees(de / self._m_per_rad[1])
        n, e, d = st.r_ned_m
        return lat, lon, st.alt_msl_m - dd, n + dn, e + de, d + dd

    def build(self, name: str, s: Snapshot) -> mav.MAVLink_message | None:
        """The message of stream ``name`` at snapshot ``s`` (None: nothing to send)."""
        return getattr(self, "_" + name.lower())(s)

    def _heartbeat(self, s: Snapshot) -> mav.MAVLink_message:
        phase = s.phase
        state = mav.MAV_STATE_ACTIVE if s.armed else mav.MAV_STATE_STANDBY
        armed = mav.MAV_MODE_FLAG_SAFETY_ARMED if s.armed else 0
        if self.autopilot == "ardupilot":
            base = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
                    | mav.MAV_MODE_FLAG_GUIDED_ENABLED | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED)
            return self.m.heartbeat_encode(mav.MAV_TYPE_QUADROTOR,
                                           mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base | armed,
                                           _ARDUCOPTER_MODE[phase], state)
        main, sub = _PX4_MODE[phase]
        base = (mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
                | (mav.MAV_MODE_FLAG_AUTO_ENABLED | mav.MAV_MODE_FLAG_GUIDED_ENABLED
                   if main == 4 else mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED))
        return self.m.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4,
                                       base | armed, (main << 16) | (sub << 24), state)

    def _system_time(self, s: Snapshot) -> mav.MAVLink_message:
        return self.m.system_time_encode(s.unix_us, s.time_boot_ms)

    def _attitude(self, s: Snapshot) -> mav.MAVLink_message:
        st = s.state
        return self.m.attitude_encode(s.time_boot_ms, st.roll_rad, st.pitch_rad,
                                      _wrap(st.yaw_rad), st.p_rps, st.q_rps, st.r_rps)

    def _attitude_quaternion(self, s: Snapshot) -> mav.MAVLink_message:
        st = s.state
        w, x, y, z = quat_from_euler_zyx(st.roll_rad, st.pitch_rad, st.yaw_rad)
        return self.m.attitude_quaternion_encode(s.time_boot_ms, w, x, y, z, st.p_rps,
                                                 st.q_rps, st.r_rps)

    def _global_position_int(self, s: Snapshot) -> mav.MAVLink_message:
        lat, lon, alt, _n, _e, _d = self._reported_position(s)
        vn, ve, vd = s.state.v_ned_mps
        hdg = round(math.degrees(s.state.yaw_rad % (2 * math.pi)) * 100) % 36000
        return self.m.global_position_int_encode(
            s.time_boot_ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
            round((alt - self.home[2]) * 1000), round(vn * 100), round(ve * 100),
            round(vd * 100), hdg)

    def _local_position_ned(self, s: Snapshot) -> mav.MAVLink_message:
        _lat, _lon, _alt, n, e, d = self._reported_position(s)
        vn, ve, vd = s.state.v_ned_mps
        return self.m.local_position_ned_encode(s.time_boot_ms, n, e, d, vn, ve, vd)

    def _gps_raw_int(self, s: Snapshot) -> mav.MAVLink_message:
        lat, lon, alt, _n, _e, _d = self._reported_position(s)
        # The receiver's own error: a slow random walk (GNSS_WALK_PHI) whose steady 1-sigma
        # is gnss_sigma_m, which h_acc / v_acc report (mm). The EKF output,
        # GLOBAL_POSITION_INT, is the truth: docs/simulator.md.
        g = self._gps_rng.gauss
        noise = self._gps_noise
        step = math.sqrt(1.0 - GNSS_WALK_PHI ** 2)
        for i, sigma in enumerate(self.gnss_sigma_m):
            noise[i] = GNSS_WALK_PHI * noise[i] + sigma * step * g(0.0, 1.0)
        lat += math.degrees(noise[0] / self._m_per_rad[0])
        lon += math.degrees(noise[1] / self._m_per_rad[1])
        vn, ve, _vd = s.state.v_ned_mps
        vel = math.hypot(vn, ve)
        cog = round(math.degrees(math.atan2(ve, vn) % (2 * math.pi)) * 100) % 36000
        return self.m.gps_raw_int_encode(
            s.time_boot_ms * 1000, mav.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7), round(lon * 1e7),
            round((alt + noise[2]) * 1000), 70, 110, round(vel * 100),
            cog if vel > 0.5 else 65535, 14, round((alt + noise[2]) * 1000),
            round(self.gnss_sigma_m[0] * 1000), round(self.gnss_sigma_m[2] * 1000), 100, 0, 0)

    def _home_position(self, s: Snapshot) -> mav.MAVLink_message:
        lat, lon, alt = self.home
        return self.m.home_position_encode(round(lat * 1e7), round(lon * 1e7),
                                           round(alt * 1000), 0.0, 0.0, 0.0, [1.0, 0, 0, 0],
                                           0.0, 0.0, 0.0, s.unix_us)

    def _sys_status(self, s: Snapshot) -> mav.MAVLink_message:
        sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
                   | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav.MAV_SYS_STATUS_SENSOR_GPS
                   | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
                   | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
                   | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                   | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
                   | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mav.MAV_SYS_STATUS_SENSOR_BATTERY)
        frac = min(1.0, max(0.0, s.battery_fraction))
        volts = 14.0 + 2.8 * frac  # 4S LiPo
        current_ca = 1200 if s.armed else 50
        return self.m.sys_status_encode(sensors, sensors, sensors, 250, round(volts * 1000),
                                        current_ca, round(100 * frac), 0, 0, 0, 0, 0, 0)

    def _ekf_status_report(self, s: Snapshot) -> mav.MAVLink_message:
        # ArduPilot EKF3 in flight with GPS: the flags of the real servo-gimbal log (831);
        # bit 15 (EKF_GPS_GLITCHING) while glitching. The "variances" are test ratios
        # (sqrt of innovation / gate): above 1 the EKF rejects the measurement.
        flags = ESTIMATOR_OK_FLAGS | (ardupilotmega.EKF_GPS_GLITCHING if s.gps_glitching
                                      else 0)
        pos_ratio = 1.5 if s.gps_glitching else 0.1
        return ardupilotmega.MAVLink_ekf_status_report_message(flags, 0.1, pos_ratio, 0.1,
                                                               0.05, 0.0, 0.0)

    def _estimator_status(self, s: Snapshot) -> mav.MAVLink_message:
        # PX4 ekf2 solution_status_flags: the same good bits (831), ESTIMATOR_GPS_GLITCH
        # (1024) while glitching.
        flags = ESTIMATOR_OK_FLAGS | (mav.ESTIMATOR_GPS_GLITCH if s.gps_glitching else 0)
        pos_ratio = 1.5 if s.gps_glitching else 0.1
        return self.m.estimator_status_encode(s.time_boot_ms * 1000, flags, 0.1, pos_ratio,
                                              0.1, 0.05, 0.0, 0.0, 0.5, 0.8)

    def _terrain_report(self, s: Snapshot) -> mav.MAVLink_message | None:
        # AP_Terrain::send_terrain_report at the vehicle's (reported) position: terrain
        # height AMSL there; current_height = height above home + home's terrain height -
        # the terrain height (above the terrain, home being on it); no data: spacing 0 and
        # both heights 0.
        if self.ground is None:
            return None
        lat, lon, alt, _n, _e, _d = self._reported_position(s)
        terrain = float(self.ground.height_msl_m(lat, lon))
        spacing, current = 0, 0.0
        if math.isfinite(terrain) and math.isfinite(self._home_terrain_msl_m):
            spacing = TERRAIN_SPACING_M
            current = (alt - self.home[2]) + self._home_terrain_msl_m - terrain
        else:
            terrain = 0.0
        return self.m.terrain_report_encode(round(lat * 1e7), round(lon * 1e7), spacing,
                                            terrain, current, 0, TERRAIN_LOADED_BLOCKS)

    def range_m(self, st: VehicleState) -> float:
        """The rangefinder's reading (m) in the true state: the slant distance along the
        body's down axis to the ground, noise added; max_m + 1 without a return."""
        if self.ground is None:
            return math.nan
        rf = self.rangefinder
        R = _Rz(st.yaw_rad) @ _Ry(st.pitch_rad) @ _Rx(st.roll_rad)
        down = R[:, 2]
        d = slant_range_m(self.ground, st.lat_deg, st.lon_deg, st.alt_msl_m,
                          (float(down[0]), float(down[1]), float(down[2])), rf.max_m)
        if not math.isfinite(d):
            return rf.max_m + 1.0
        if rf.noise_m > 0:
            d = max(0.0, d + self._range_rng.gauss(0.0, rf.noise_m))
        return d

    def _distance_sensor(self, s: Snapshot) -> mav.MAVLink_message | None:
        # ArduPilot (GCS_MAVLINK::send_distance_sensor): cm clipped to 65535, type of the
        # backend (SITL: laser), id = instance 0, covariance 0, no FOV or quaternion, signal
        # quality 0 (unknown). PX4 (DISTANCE_SENSOR.hpp): covariance = variance in cm^2.
        if self.ground is None:
            return None
        rf = self.rangefinder
        d = self.range_m(s.state)

        def cm(m: float) -> int:
            return min(65535, round(m * 100))

        covariance = 0
        if self.autopilot == "px4":
            covariance = min(255, round(rf.noise_m ** 2 * 1e4))
        return self.m.distance_sensor_encode(
            s.time_boot_ms, cm(rf.min_m), cm(rf.max_m), cm(d), mav.MAV_DISTANCE_SENSOR_LASER,
            0, mav.MAV_SENSOR_ROTATION_PITCH_270, covariance)

    def _gimbal_device_attitude_status(self, s: Snapshot) -> mav.MAVLink_message | None:
        if s.gimbal_q_wxyz is None:
            return None
        return self.m.gimbal_device_attitude_status_encode(
            0, 0, s.time_boot_ms, s.gimbal_flags, list(s.gimbal_q_wxyz), math.nan, math.nan,
            math.nan, s.gimbal_failure, s.gimbal_delta_yaw_rad, math.nan, 1)


def gimbal_report(mode: str, R_ned_gimbal: np.ndarray, servo_demand: tuple[float, float, float],
                  angles: tuple[float, float, float]
                  ) -> tuple[tuple[float, float, float, float] | None, int, float]:
    """(quaternion w, x, y, z, flags, delta yaw rad) reported for a gimbal mode; quaternion
    None for a fixed mount. servo_demand: (roll, pitch, yaw) body-frame demand (servo).
    angles: the stabilised gimbal's (roll, pitch, yaw from heading)."""
    if mode == "ardupilot-servo":
        return quat_from_euler_zyx(*servo_demand), FLAGS_AUTOPILOT, servo_demand[2]
    if mode == "ardupilot-device":
        return quat_from_euler_zyx(*angles), FLAGS_AUTOPILOT, angles[2]
    if mode == "device-earth":
        return quat_from_R(R_ned_gimbal), FLAGS_DEVICE_EARTH, angles[2]
    return None, 0, 0.0


def gimbal_device_messages(m: mav.MAVLink, name: str, time_boot_ms: int,
                           q_wxyz: tuple[float, float, float, float], failure: int,
                           delta_yaw_rad: float) -> mav.MAVLink_message:
    """A gimbal device's own HEARTBEAT or GIMBAL_DEVICE_ATTITUDE_STATUS (device-earth)."""
    if name == "HEARTBEAT":
        return m.heartbeat_encode(mav.MAV_TYPE_GIMBAL, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                  mav.MAV_STATE_ACTIVE)
    return m.gimbal_device_attitude_status_encode(
        0, 0, time_boot_ms, FLAGS_DEVICE_EARTH, list(q_wxyz), math.nan, math.nan, math.nan,
        failure, delta_yaw_rad, math.nan, 0)


def camera_image_captured(m: mav.MAVLink, time_boot_ms: int, unix_us: int,
                          lat_deg: float, lon_deg: float, alt_msl_m: float, rel_alt_m: float,
                          q_ned_cam_wxyz: tuple[float, float, float, float], index: int
                          ) -> mav.MAVLink_message:
    """CAMERA_IMAGE_CAPTURED of frame ``index`` (capture_result 1 = success); q is the
    camera's gimbal-frame attitude in NED."""
    return m.camera_image_captured_encode(
        time_boot_ms, unix_us, 0, round(lat_deg * 1e7), round(lon_deg * 1e7),
        round(alt_msl_m * 1000), round(rel_alt_m * 1000), list(q_ned_cam_wxyz), index, 1, b"")
