"""A minimal vehicle for the endpoint tests: an AutopilotEndpoint in a thread, stepped in
real time, sending a fixed hover's messages (the fly loop's stand-in), stopped by ``stop``."""

from __future__ import annotations

import threading
import time

from pymavlink.dialects.v20 import common as mavlink2

from pdcov_sitl.endpoint import AutopilotEndpoint
from pdcov_sitl.faults import GimbalHealth

LAT_DEG, LON_DEG, ALT_MSL_M = -35.363261, 149.165230, 584.0

STREAMS_HZ = {"HEARTBEAT": 1.0, "SYS_STATUS": 2.0, "SYSTEM_TIME": 1.0, "ATTITUDE": 25.0,
              "ATTITUDE_QUATERNION": 25.0, "GLOBAL_POSITION_INT": 10.0,
              "LOCAL_POSITION_NED": 10.0, "GPS_RAW_INT": 5.0, "HOME_POSITION": 0.5,
              "GIMBAL_DEVICE_ATTITUDE_STATUS": 0.0, "EXTENDED_SYS_STATE": 1.0}
PARAMS = {"MNT1_TYPE": 1.0, "MNT1_PITCH_MIN": -90.0, "MNT1_PITCH_MAX": 20.0,
          "MNT1_ROLL_MIN": -30.0, "MNT1_ROLL_MAX": 30.0, "MNT1_YAW_MIN": -180.0,
          "MNT1_YAW_MAX": 180.0, "SYSID_THISMAV": 1.0}


def hover_message(endpoint: AutopilotEndpoint, name: str, t_s: float, autopilot: str
                  ) -> mavlink2.MAVLink_message | None:
    """The message ``name`` of a vehicle hovering 10 m over home, heading north."""
    mav, boot_ms = endpoint.mav, endpoint.time_boot_ms(t_s)
    north_m = endpoint.gps_offset_ned_m(t_s)[0]
    lat_e7 = round((LAT_DEG + north_m / 111_320.0) * 1e7)
    lon_e7 = round(LON_DEG * 1e7)
    if name == "HEARTBEAT":
        ap = (mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA if autopilot == "ardupilot"
              else mavlink2.MAV_AUTOPILOT_PX4)
        return mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, ap,
                                    mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                                    | mavlink2.MAV_MODE_FLAG_SAFETY_ARMED, 4,
                                    mavlink2.MAV_STATE_ACTIVE)
    if name == "SYS_STATUS":
        return mav.sys_status_encode(0, 0, 0, 500, 12600, -1, 80, 0, 0, 0, 0, 0, 0)
    if name == "SYSTEM_TIME":
        return mav.system_time_encode(endpoint.unix_time_us(t_s), boot_ms)
    if name == "ATTITUDE":
        return mav.attitude_encode(boot_ms, 0.01, -0.02, 0.0, 0.0, 0.0, 0.0)
    if name == "ATTITUDE_QUATERNION":
        return mav.attitude_quaternion_encode(boot_ms, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    if name == "GLOBAL_POSITION_INT":
        return mav.global_position_int_encode(boot_ms, lat_e7, lon_e7,
                                              round((ALT_MSL_M + 10) * 1000), 10_000, 0, 0,
                                              0, 0)
    if name == "LOCAL_POSITION_NED":
        return mav.local_position_ned_encode(boot_ms, north_m, 0.0, -10.0, 0.0, 0.0, 0.0)
    if name == "GPS_RAW_INT":
        return mav.gps_raw_int_encode(boot_ms * 1000, 3, lat_e7, lon_e7,
                                      round((ALT_MSL_M + 10) * 1000), 80, 120, 0, 0, 14)
    if name == "HOME_POSITION":
        return mav.home_position_encode(round(LAT_DEG * 1e7), lon_e7, round(ALT_MSL_M * 1000),
                                        0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    if name == "EXTENDED_SYS_STATE":
        return mav.extended_sys_state_encode(0, mavlink2.MAV_LANDED_STATE_IN_AIR)
    if name == "GIMBAL_DEVICE_ATTITUDE_STATUS":
        health = endpoint.gimbal_health(t_s)
        if health is GimbalHealth.SILENT:
            return None
        failure = (mavlink2.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR
                   if health is GimbalHealth.FAILED else 0)
        return mav.gimbal_device_attitude_status_encode(0, 0, boot_ms, 44, [1, 0, 0, 0],
                                                        0, 0, 0, failure)
    return None


class FeedThread(threading.Thread):
    """Runs ``endpoint`` at real-time pace: poll, then send the streams that are due."""

    def __init__(self, endpoint: AutopilotEndpoint, autopilot: str = "ardupilot",
                 step_s: float = 0.002):
        super().__init__(daemon=True)
        self.endpoint = endpoint
        self.autopilot = autopilot
        self.step_s = step_s
        self.stopping = threading.Event()
        self.error: BaseException | None = None
        self.t0 = time.monotonic()

    def now_s(self) -> float:
        return time.monotonic() - self.t0

    def run(self) -> None:
        try:
            while not self.stopping.is_set():
                t_s = self.now_s()
                self.endpoint.poll(t_s)
                for name in self.endpoint.due(t_s):
                    msg = hover_message(self.endpoint, name, t_s, self.autopilot)
                    if msg is not None:
                        self.endpoint.send(msg, t_s)
                time.sleep(self.step_s)
        except BaseException as exc:  # noqa: BLE001 - any end of the thread: stop() raises it
            self.error = exc

    def stop(self) -> None:
        self.stopping.set()
        self.join(timeout=5)
        self.endpoint.close()
        if self.error is not None:
            raise self.error
