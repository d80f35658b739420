"""Frame times ``pdcov serve`` took from its onboard detector (Zenoh ``pdcov/<id>/frames``),
written into its recording as MAVLink so that ``pdcov evaluate`` of the recording evaluates
the same frames (docs/service.md, "Durability").

Each frame time the daemon accepted becomes, in the order it accepted them, one
CAMERA_IMAGE_CAPTURED (common.xml, id 263) of the followed vehicle's system from the
daemon's own component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) with ``file_url`` MARK,
capture_result 1 and image_index counting the recorded frames. Both the component and the
mark tell it from a camera's own CAMERA_IMAGE_CAPTURED (``is_recorded_frame``).

Clock: its time_boot_ms is the frame time in the AUTOPILOT's boot clock (the frames
payload's clock, to the millisecond), not a clock of component 191's own: a reader places
it with the autopilot clock's offset at that point of the log
(``clocks.VehicleClock.autopilot_boot_s``), as the daemon placed it when it arrived.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

RECORDED_FRAME_COMPONENT = 191
"""MAV_COMP_ID_ONBOARD_COMPUTER: the component the daemon speaks as."""
MARK = "pdcov:detector-frame"
SOURCE = "pdcov serve: detector frames"
"""CaptureSample.source of the frames read back."""
MAX_BOOT_MS = 0xFFFFFFFF
"""time_boot_ms is a uint32: frame times from 49.7 days of boot on cannot be recorded."""


def boot_ms(t_boot_s: float) -> int:
    """A frame time (s of the autopilot's boot clock) to the millisecond, as recorded."""
    return round(t_boot_s * 1000.0)


def boot_s(t_boot_ms: int) -> float:
    """Milliseconds of boot back to seconds, exactly as samples.mavlink_boot_time_s."""
    return t_boot_ms * 1e-3


class FrameEncoder:
    """The recording's frame messages of one daemon: ``encode`` gives one MAVLink 2 frame
    (bytes) per accepted frame time, numbered and sequenced."""

    def __init__(self) -> None:
        self._mav = mavlink.MAVLink(None, srcComponent=RECORDED_FRAME_COMPONENT)
        self.count = 0

    def encode(self, system_id: int, t_boot_ms: int) -> bytes:
        """The frame at ``t_boot_ms`` (autopilot boot clock, 0..MAX_BOOT_MS) of the vehicle
        ``system_id``."""
        mav = self._mav
        mav.srcSystem = system_id
        msg = mav.camera_image_captured_encode(t_boot_ms, 0, 0, 0, 0, 0, 0, [1.0, 0, 0, 0],
                                               self.count & 0x7FFFFFFF, 1, MARK.encode())
        data = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        self.count += 1
        return data


def is_recorded_frame(msg: Any) -> bool:
    """A frame time the daemon recorded (module docstring), not a camera's capture."""
    if msg.get_type() != "CAMERA_IMAGE_CAPTURED" or \
            msg.get_srcComponent() != RECORDED_FRAME_COMPONENT:
        return False
    url = msg.file_url
    if isinstance(url, bytes):
        url = url.decode("ascii", "replace")
    return str(url).rstrip("\x00") == MARK
