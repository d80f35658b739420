"""A MAVLink zoom camera (component 100, MAV_COMP_ID_CAMERA; HEARTBEAT type MAV_TYPE_CAMERA)
as the camera protocol describes it (mavlink.io camera protocol v2, common.xml).

It answers MAV_CMD_SET_CAMERA_ZOOM (ZOOM_TYPE_RANGE: param2 the zoom level, 0..100 % of the
range; ZOOM_TYPE_HORIZONTAL_FOV: param2 the horizontal field of view, deg) with COMMAND_ACK
and CAMERA_SETTINGS, and MAV_CMD_REQUEST_MESSAGE for CAMERA_INFORMATION (259),
CAMERA_SETTINGS (260) and CAMERA_FOV_STATUS (271); it streams HEARTBEAT and CAMERA_SETTINGS
at 1 Hz and CAMERA_FOV_STATUS at 10 Hz, stamped in the autopilot's boot clock (the fly
loop's). The zoom level maps linearly to the focal length between the widest and the
narrowest field of view, and the lens moves towards a new level at ``zoom_rate_per_s``
(|d ln f / dt|), so a zoom takes time as a real one does. Sans-I/O: the fly loop feeds
messages and time, and sends what it returns.
"""

from __future__ import annotations

import math
import random

from pymavlink.dialects.v20 import common as mav

from .protocol import StreamSchedule

CAMERA_COMPONENT = mav.MAV_COMP_ID_CAMERA  # 100
CAMERA_STREAMS_HZ = {"HEARTBEAT": 1.0, "CAMERA_SETTINGS": 1.0, "CAMERA_FOV_STATUS": 10.0}
SENSOR_WIDTH_MM = 6.17
"""A 1/2.3" sensor: CAMERA_INFORMATION's focal length (mm) = f_px * this / width_px."""
_REQUESTABLE = {mav.MAVLINK_MSG_ID_CAMERA_INFORMATION: "CAMERA_INFORMATION",
                mav.MAVLINK_MSG_ID_CAMERA_SETTINGS: "CAMERA_SETTINGS",
                mav.MAVLINK_MSG_ID_CAMERA_FOV_STATUS: "CAMERA_FOV_STATUS"}


class ZoomCamera:
    """The camera's zoom state and its MAVLink answers (module docstring).

    width_px, height_px: the image; wide_hfov_deg / narrow_hfov_deg: the field of view at
    zoom level 0 and 100. ``level`` is the lens's current zoom level (0..100)."""

    def __init__(self, m: mav.MAVLink, *, system_id: int, width_px: int, height_px: int,
                 wide_hfov_deg: float, narrow_hfov_deg: float, zoom_rate_per_s: float = 1.0,
                 seed: int = 0) -> None:
        if not 0 < narrow_hfov_deg < wide_hfov_deg < 180:
            raise ValueError(f"camera fields of view: expected 0 < narrow ({narrow_hfov_deg}) "
                             f"< wide ({wide_hfov_deg}) < 180 deg")
        self._mav = m
        self.system_id = system_id
        self.width_px, self.height_px = width_px, height_px
        self.f_wide_px = (width_px / 2) / math.tan(math.radians(wide_hfov_deg) / 2)
        self.f_narrow_px = (width_px / 2) / math.tan(math.radians(narrow_hfov_deg) / 2)
        self.zoom_rate_per_s = zoom_rate_per_s
        self.level = 0.0
        self.target_level = 0.0
        self.schedule = StreamSchedule(CAMERA_STREAMS_HZ, random.Random(f"{seed}:camera"))

    # --- the lens ---------------------------------------------------------------------------

    def focal_px(self, level: float | None = None) -> float:
        z = self.level if level is None else level
        return self.f_wide_px + (z / 100.0) * (self.f_narrow_px - self.f_wide_px)

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2 * math.atan((self.width_px / 2) / self.focal_px()))

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2 * math.atan((self.height_px / 2) / self.focal_px()))

    def level_for_hfov(self, hfov_deg: float) -> float | None:
        """The zoom level of a field of view (deg), None outside the lens's range."""
        if not math.isfinite(hfov_deg) or hfov_deg <= 0 or hfov_deg >= 180:
            return None
        f = (self.width_px / 2) / math.tan(math.radians(hfov_deg) / 2)
        level = 100.0 * (f - self.f_wide_px) / (self.f_narrow_px - self.f_wide_px)
        return level if -1e-6 <= level <= 100.0 + 1e-6 else None

    def zoom(self, zoom_type: int, value: float) -> bool:
        """Start zooming (CAMERA_ZOOM_TYPE, value); False when refused."""
        if zoom_type == mav.ZOOM_TYPE_RANGE and math.isfinite(value) and 0 <= value <= 100:
            level: float | None = float(value)
        elif zoom_type == mav.ZOOM_TYPE_HORIZONTAL_FOV:
            level = self.level_for_hfov(value)
        else:
            level = None
        if level is None:
            return False
        self.target_level = min(max(level, 0.0), 100.0)
        return True

    def step(self, dt_s: float) -> None:
        """Move the lens towards the target level for ``dt_s`` seconds."""
        if self.level == self.target_level:
            return
        ln_now, ln_to = math.log(self.focal_px()), math.log(self.focal_px(self.target_level))
        step = self.zoom_rate_per_s * dt_s
        ln_f = ln_to if abs(ln_to - ln_now) <= step else ln_now + math.copysign(step,
                                                                               ln_to - ln_now)
        f = math.exp(ln_f)
        self.level = (self.target_level if ln_f == ln_to else
                      100.0 * (f - self.f_wide_px) / (self.f_narrow_px - self.f_wide_px))

    # --- MAVLink ----------------------------------------------------------------------------

    def receive(self, msg: mav.MAVLink_message, time_boot_ms: int) -> list[mav.MAVLink_message]:
        """The answers to one message (commands addressed to the camera component)."""
        if msg.get_type() not in ("COMMAND_LONG", "COMMAND_INT"):
            return []
        if getattr(msg, "target_system", 0) not in (0, self.system_id) or getattr(
                msg, "target_component", 0) != CAMERA_COMPONENT:
            return []
        extra: list[mav.MAVLink_message] = []
        if msg.command == mav.MAV_CMD_SET_CAMERA_ZOOM:
            zoom_type = msg.param1 if math.isfinite(msg.param1) else -1.0  # NaN: refused
            ok = self.zoom(int(zoom_type), float(msg.param2))
            result = mav.MAV_RESULT_ACCEPTED if ok else mav.MAV_RESULT_DENIED
            if ok:  # common.xml: "Camera must respond with a CAMERA_SETTINGS message"
                extra.append(self.message("CAMERA_SETTINGS", time_boot_ms))
        elif msg.command == mav.MAV_CMD_REQUEST_MESSAGE:
            name = _REQUESTABLE.get(int(msg.param1))
            result = mav.MAV_RESULT_ACCEPTED if name else mav.MAV_RESULT_UNSUPPORTED
            if name:
                extra.append(self.message(name, time_boot_ms))
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
        ack = self._mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(),
                                           msg.get_srcComponent())
        return [ack, *extra]

    def due(self, t_s: float, time_boot_ms: int) -> list[mav.MAVLink_message]:
        """The stream messages due at simulated time ``t_s``."""
        return [self.message(name, time_boot_ms) for name in self.schedule.due(t_s)]

    def message(self, name: str, time_boot_ms: int) -> mav.MAVLink_message:
        m = self._mav
        if name == "HEARTBEAT":
            return m.heartbeat_encode(mav.MAV_TYPE_CAMERA, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                      mav.MAV_STATE_ACTIVE)
        if name == "CAMERA_SETTINGS":
            return m.camera_settings_encode(time_boot_ms, mav.CAMERA_MODE_IMAGE, self.level,
                                            math.nan, 0)
        if name == "CAMERA_FOV_STATUS":
            unknown = 2**31 - 1  # INT32_MAX: the position fields are not simulated here
            return m.camera_fov_status_encode(time_boot_ms, unknown, unknown, unknown, unknown,
                                              unknown, unknown, [math.nan] * 4, self.hfov_deg,
                                              self.vfov_deg, 0)
        if name == "CAMERA_INFORMATION":
            mm = self.focal_px() * SENSOR_WIDTH_MM / self.width_px
            flags = mav.CAMERA_CAP_FLAGS_CAPTURE_IMAGE | mav.CAMERA_CAP_FLAGS_HAS_BASIC_ZOOM
            return m.camera_information_encode(
                time_boot_ms, b"pdcov_sitl".ljust(32, b"\0"), b"zoom camera".ljust(32, b"\0"),
                0, mm, SENSOR_WIDTH_MM, SENSOR_WIDTH_MM * self.height_px / self.width_px,
                self.width_px, self.height_px, 0, flags, 0, b"", 0, 0)
        raise ValueError(f"camera message {name!r}: not sent by the camera")
