"""What ``pdcov serve`` writes into its recording, beside the messages it received, so that
``pdcov evaluate`` of the recording evaluates the frames it did (docs/service.md,
"Durability"): the frame times it took from its onboard detector (Zenoh
``pdcov/<id>/frames``), and the capture events it did not take (late).

Each frame time the daemon accepted becomes, in the order it accepted them, one
CAMERA_IMAGE_CAPTURED (common.xml, id 263) of the followed vehicle's system from the
daemon's own component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) with ``file_url`` MARK,
capture_result 1 and image_index counting the recorded frames. Both the component and the
mark tell it from a camera's own CAMERA_IMAGE_CAPTURED (``is_recorded_frame``).

Clock: its time_boot_ms is the frame time in the AUTOPILOT's boot clock (the frames
payload's clock, to the millisecond), not a clock of component 191's own: a reader places
it with the autopilot clock's offset at that point of the log
(``clocks.VehicleClock.autopilot_boot_s``), as the daemon placed it when it arrived.

The boxes of a frame (frames payload version 2) follow its mark, one CAMERA_IMAGE_CAPTURED
each from component 191, with the frame's time_boot_ms and image_index, capture_result 1
and ``file_url`` ``pdcov:box <confidence> <left> <top> <width> <height> <class>``: the
numbers as Python's shortest exact text (repr: they read back bit-identical), pixels as
the payload's (core/detections.py), the class name last (it may hold spaces; at most 64
characters, so the text fits file_url's 205). A reader gives each box to the frame mark
of the same system and image_index before it (``box_of``).

A capture event (CAMERA_IMAGE_CAPTURED) the daemon did not take because it came after a
later frame was decided (``frames.skipped."late frame time"``) is followed in the recording
by a CAMERA_IMAGE_CAPTURED from component 191 with ``file_url`` NOT_TAKEN, capture_result
0 (no image), and the capture's source component (camera_id), time_boot_ms and
image_index: a reader drops the nearest such capture event before it.

``frame_source_for`` decides which frames ``pdcov evaluate`` of a log uses: the recorded
frames when the user chose no frame source (docs/logs.md, "Frames, interpolation, gaps").
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.core.detections import Box

RECORDED_FRAME_COMPONENT = 191
"""MAV_COMP_ID_ONBOARD_COMPUTER: the component the daemon speaks as."""
MARK = "pdcov:detector-frame"
NOT_TAKEN = "pdcov:capture-not-taken"
BOX = "pdcov:box"
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
    """The messages one daemon adds to its recording, as MAVLink 2 frames (bytes),
    sequenced: ``encode`` one per detector frame time taken (numbered), ``not_taken`` one
    per capture event not taken."""

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
        self.count += 1
        return self._packed(msg)

    def box(self, system_id: int, t_boot_ms: int, box: Box) -> bytes:
        """A box of the frame last ``encode``d (at ``t_boot_ms``)."""
        mav = self._mav
        mav.srcSystem = system_id
        url = " ".join([BOX, *(repr(float(v)) for v in (box.confidence, *box.box_px)),
                        box.class_name])
        msg = mav.camera_image_captured_encode(t_boot_ms, 0, 0, 0, 0, 0, 0, [1.0, 0, 0, 0],
                                               (self.count - 1) & 0x7FFFFFFF, 1, url.encode())
        return self._packed(msg)

    def not_taken(self, system_id: int, capture: Any) -> bytes:
        """The mark that the CAMERA_IMAGE_CAPTURED ``capture`` just recorded was not taken."""
        mav = self._mav
        mav.srcSystem = system_id
        return self._packed(mav.camera_image_captured_encode(
            capture.time_boot_ms, 0, capture.get_srcComponent(), 0, 0, 0, 0, [1.0, 0, 0, 0],
            capture.image_index, 0, NOT_TAKEN.encode()))

    def _packed(self, msg: Any) -> bytes:
        data = bytes(msg.pack(self._mav))
        self._mav.seq = (self._mav.seq + 1) % 256
        return data


def _file_url(msg: Any) -> str:
    url = msg.file_url
    if isinstance(url, bytes):
        url = url.decode("ascii", "replace")
    return str(url).rstrip("\x00")


def recorded_mark(msg: Any) -> str | None:
    """MARK for a frame time the daemon recorded, BOX for one of its boxes, NOT_TAKEN for its
    mark of a capture it did not take (module docstring), None for anything else (a
    camera's own capture)."""
    if msg.get_type() != "CAMERA_IMAGE_CAPTURED" or \
            msg.get_srcComponent() != RECORDED_FRAME_COMPONENT:
        return None
    url = _file_url(msg)
    if url.startswith(BOX + " "):
        return BOX
    return url if url in (MARK, NOT_TAKEN) else None


def box_of(msg: Any) -> Box | None:
    """The box a BOX mark records, None when its text is not one (a damaged log)."""
    parts = _file_url(msg).split(" ", 6)
    try:
        confidence, left, top, width, height = (float(v) for v in parts[1:6])
        return Box(parts[6], confidence, left, top, width, height)
    except (IndexError, ValueError):
        return None


class NotTakenCaptures:
    """A reader's bookkeeping of NOT_TAKEN marks, fed the log in order: ``capture`` for each
    CAMERA_IMAGE_CAPTURED capture event, ``mark`` for each mark; ``dropped`` holds the
    message indices of the capture events the daemon did not take."""

    def __init__(self) -> None:
        self._seen: dict[tuple[int, int, int, int], list[int]] = defaultdict(list)
        self.dropped: set[int] = set()

    def capture(self, msg: Any, index: int) -> None:
        self._seen[(msg.get_srcSystem(), msg.get_srcComponent(), msg.time_boot_ms,
                    msg.image_index)].append(index)

    def mark(self, msg: Any) -> None:
        seen = self._seen.get((msg.get_srcSystem(), msg.camera_id, msg.time_boot_ms,
                               msg.image_index))
        if seen:
            self.dropped.add(seen.pop())


@dataclass(frozen=True, slots=True)
class RecordedBox:
    """A box read back from a recording: ``t_s`` the time of its frame in the log's
    autopilot clock (as the frame's capture event), ``t_boot_s`` the frame time the
    detector gave (to the millisecond), the ``box``."""

    t_s: float
    t_boot_s: float
    box: Box


@dataclass(frozen=True, slots=True)
class FrameSourceChoice:
    """The frame source a log is evaluated with ('rate' or 'capture'), and what to say:
    a summary line and a warning ("" for none)."""

    source: str
    line: str = ""
    warning: str = ""


def frame_source_for(requested: str | None, n_recorded: int) -> FrameSourceChoice:
    """The frame source for a log holding ``n_recorded`` detector frames the daemon recorded.

    ``requested``: what the user chose ('rate' or 'capture', by --frame-source or the
    config's log.frame_source), None when neither was given. Not chosen: the recorded
    frames when there are any (the grid the daemon built in flight), else 'rate'. A chosen
    'rate' is kept, with a warning when the log holds recorded frames (its grid is not the
    daemon's); a chosen 'capture' uses them (the reader made them the capture events).
    """
    if requested is None:
        if not n_recorded:
            return FrameSourceChoice("rate")
        return FrameSourceChoice("capture", (
            f"frame source: the {n_recorded} detector frames pdcov serve recorded, as it "
            "evaluated them in flight (no frame source chosen: log.frame_source not set, no "
            "--frame-source; 'rate' chooses frames every 1/camera.frame_rate_hz s instead)"))
    if requested == "rate" and n_recorded:
        return FrameSourceChoice("rate", warning=(
            f"frame source 'rate' was chosen (--frame-source or log.frame_source), so frames "
            f"every 1/camera.frame_rate_hz s are evaluated, not the {n_recorded} detector "
            "frames pdcov serve recorded in this log and evaluated in flight: this grid is "
            "not the daemon's. Choose no frame source, or 'capture', for the daemon's grid"))
    return FrameSourceChoice(requested)
