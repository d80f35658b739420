"""Mission upload to a vehicle over the MAVLink mission protocol (mavlink.io/en/services/
mission.html): MISSION_COUNT, then one MISSION_ITEM_INT per MISSION_REQUEST_INT or older
MISSION_REQUEST, until the vehicle's MISSION_ACK.

Items are always MISSION_ITEM_INT (latitude and longitude in degE7), as QGroundControl
sends them: the float MISSION_ITEM carries float32 degrees, which moves a waypoint by up to
half a metre (-35.36308075 becomes -35.3630784). ArduCopter 4.7 asks with MISSION_REQUEST
and accepts MISSION_ITEM_INT in answer.

``MissionUpload`` is the ground-station side as a state machine with no I/O: messages and
the time come in, messages to send go out (as pymavlink message objects). ``upload_mission``
is the adapter that runs it over a pymavlink connection (UDP, TCP or serial).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.mission import MissionItem
from pdcov.errors import PdcovError, TelemetryError
from pdcov.telemetry.link_params import wait_autopilot_heartbeat

MAV_MISSION_TYPE_MISSION = 0


class UploadError(PdcovError):
    """The link could not be opened or no vehicle answered."""


@dataclass(frozen=True, slots=True)
class UploadResult:
    """Outcome of an upload: accepted, or what the vehicle refused (and at which item)."""

    accepted: bool
    n_items: int
    result: str
    detail: str
    refused_seq: int | None = None
    refused_command: int | None = None

    def report(self) -> str:
        if self.accepted:
            return f"uploaded {self.n_items} mission items: vehicle accepted ({self.result})"
        where = ""
        if self.refused_seq is not None:
            where = f" at item {self.refused_seq} (command {self.refused_command})"
        return f"vehicle refused the mission{where}: {self.result}: {self.detail}"


def _result_text(code: int) -> tuple[str, str]:
    entry = mavlink2.enums["MAV_MISSION_RESULT"].get(code)
    if entry is None:
        return f"MAV_MISSION_RESULT {code}", "unknown result code"
    return entry.name, entry.description


class MissionUpload:
    """Ground-station side of a mission upload; no I/O, time passed in as ``now_s``.

    ``start`` returns the MISSION_COUNT to send; feed every message from the target vehicle
    to ``receive`` and call ``poll`` regularly: both return messages to send. ``result`` is
    set when the upload has ended (accepted, refused, or timed out after ``max_retries``
    resends of the last message, each after ``retry_s`` of silence)."""

    def __init__(self, items: tuple[MissionItem, ...], target_system: int,
                 target_component: int, mav: mavlink2.MAVLink, retry_s: float = 1.5,
                 max_retries: int = 5):
        self.items = items
        self.target = (target_system, target_component)
        self._mav = mav
        self._retry_s = retry_s
        self._max_retries = max_retries
        self._last_sent: list[mavlink2.MAVLink_message] = []
        self._last_seq: int | None = None
        self._deadline = math.inf
        self._retries = 0
        self.result: UploadResult | None = None

    def _send(self, msgs: list[mavlink2.MAVLink_message], now_s: float
              ) -> list[mavlink2.MAVLink_message]:
        self._last_sent = msgs
        self._deadline = now_s + self._retry_s
        self._retries = 0
        return msgs

    def start(self, now_s: float) -> list[mavlink2.MAVLink_message]:
        return self._send([self._mav.mission_count_encode(
            *self.target, len(self.items), MAV_MISSION_TYPE_MISSION)], now_s)

    def _item(self, seq: int) -> mavlink2.MAVLink_message:
        """MISSION_ITEM_INT ``seq``, whichever request asked for it (module docstring)."""
        it = self.items[seq]
        return self._mav.mission_item_int_encode(
            *self.target, seq, it.frame, it.command, 0, int(it.autocontinue), it.param1,
            it.param2, it.param3, it.param4, round(it.lat_deg * 1e7), round(it.lon_deg * 1e7),
            it.z_m, MAV_MISSION_TYPE_MISSION)

    def _fail(self, result: str, detail: str) -> list[mavlink2.MAVLink_message]:
        seq = self._last_seq
        self.result = UploadResult(False, len(self.items), result, detail, seq,
                                   self.items[seq].command if seq is not None else None)
        return []

    def receive(self, msg: mavlink2.MAVLink_message, now_s: float
                ) -> list[mavlink2.MAVLink_message]:
        if self.result is not None or msg.get_srcSystem() != self.target[0]:
            return []
        kind = msg.get_type()
        if getattr(msg, "mission_type", MAV_MISSION_TYPE_MISSION) != MAV_MISSION_TYPE_MISSION:
            return []
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if not 0 <= msg.seq < len(self.items):
                return self._fail("MAV_MISSION_INVALID_SEQUENCE",
                                  f"vehicle asked for item {msg.seq} of {len(self.items)}")
            self._last_seq = msg.seq
            return self._send([self._item(msg.seq)], now_s)
        if kind == "MISSION_ACK":
            name, description = _result_text(msg.type)
            if msg.type == mavlink2.MAV_MISSION_ACCEPTED:
                if self._last_seq == len(self.items) - 1 or not self.items:
                    self.result = UploadResult(True, len(self.items), name, description)
                    return []
                return self._fail(name, f"vehicle acknowledged before receiving all items "
                                        f"(last sent: {self._last_seq})")
            return self._fail(name, description)
        return []

    def poll(self, now_s: float) -> list[mavlink2.MAVLink_message]:
        if self.result is not None or now_s < self._deadline:
            return []
        if self._retries >= self._max_retries:
            what = ("MISSION_COUNT" if self._last_seq is None
                    else f"item {self._last_seq}")
            return self._fail("TIMEOUT", f"no answer to {what} after {self._retries} resends")
        self._retries += 1
        self._deadline = now_s + self._retry_s
        return self._last_sent


def mavlink2_connection(url: str, source_system: int, source_component: int
                        ) -> mavutil.mavfile:
    """A pymavlink connection that speaks MAVLink 2 (common dialect), whatever dialect
    pymavlink's global default is; URLs as mavutil takes them (udpin:, udpout:, tcp:,
    serial device)."""
    try:
        conn = mavutil.mavlink_connection(url, source_system=source_system,
                                          source_component=source_component)
    except OSError as exc:
        raise UploadError(f"cannot open {url}: {exc}") from None
    conn.mav = mavlink2.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # keep pymavlink from switching the dialect on the first byte
    return conn


def upload_mission(items: tuple[MissionItem, ...], url: str, home: MissionItem,
                   timeout_s: float = 10.0, retry_s: float = 1.5,
                   source_system: int = 255, source_component: int = 190) -> UploadResult:
    """Upload ``items`` to the first vehicle heard on ``url``; ArduPilot vehicles get
    ``home`` as item 0 first (ArduPilot keeps home at seq 0, PX4 does not).

    Waits for the autopilot's HEARTBEAT as ``link_params.wait_autopilot_heartbeat`` does
    (sending ours each second, as a udpout: link needs; ignoring ground stations and
    components that are no autopilot, such as a gimbal or camera).
    Raises UploadError when no vehicle answers within ``timeout_s``."""
    conn = mavlink2_connection(url, source_system, source_component)
    try:
        try:
            vehicle = wait_autopilot_heartbeat(conn, timeout_s)
        except TelemetryError as exc:
            raise UploadError(f"no vehicle HEARTBEAT on {url} to upload to: {exc}") from None
        if vehicle.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
            items = (home, *items)
        upload = MissionUpload(items, vehicle.get_srcSystem(), vehicle.get_srcComponent(),
                               conn.mav, retry_s=retry_s)
        for m in upload.start(time.monotonic()):
            conn.mav.send(m)
        while upload.result is None:
            msg = conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST",
                                        "MISSION_ACK"], blocking=True, timeout=0.1)
            now = time.monotonic()
            out = upload.receive(msg, now) if msg is not None else []
            for m in out + upload.poll(now):
                conn.mav.send(m)
        return upload.result
    finally:
        conn.close()
