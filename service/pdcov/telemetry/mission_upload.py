"""The mission upload as a state machine with no I/O (mavlink.io/en/services/mission.html):
MISSION_COUNT, then one MISSION_ITEM_INT per MISSION_REQUEST_INT or older MISSION_REQUEST,
until the vehicle's MISSION_ACK. Messages and the time come in, messages to send go out (as
pymavlink message objects); ``pdcov upload`` (telemetry/upload.py) and the daemon's
re-tasking (service/retask.py) drive it over their links.

Items are always MISSION_ITEM_INT (latitude and longitude in degE7), as QGroundControl
sends them: the float MISSION_ITEM carries float32 degrees, which moves a waypoint by up to
half a metre. ArduCopter 4.7 asks with MISSION_REQUEST and accepts MISSION_ITEM_INT in
answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from pdcov.core.mission import MissionItem, mission_item_int_xy

MAV_MISSION_TYPE_MISSION = 0


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
                 max_retries: int = 5, own_ids: tuple[int, int] | None = None):
        self.items = items
        self.target = (target_system, target_component)
        # On a link shared with a ground station (the daemon's), the autopilot's requests
        # and acknowledgements of the other's upload name the other as their target.
        self._own = own_ids
        self._mav = mav
        self._retry_s = retry_s
        self._max_retries = max_retries
        self._last_sent: list[mavlink2.MAVLink_message] = []
        self._last_seq: int | None = None
        self._deadline = math.inf
        self._retries = 0
        self.result: UploadResult | None = None

    @property
    def deadline_s(self) -> float:
        """When ``poll`` next has something to do (the caller's clock, s; inf once ended)."""
        return self._deadline if self.result is None else math.inf

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
            it.param2, it.param3, it.param4, *mission_item_int_xy(it), it.z_m,
            MAV_MISSION_TYPE_MISSION)

    def _fail(self, result: str, detail: str) -> list[mavlink2.MAVLink_message]:
        seq = self._last_seq
        self.result = UploadResult(False, len(self.items), result, detail, seq,
                                   self.items[seq].command if seq is not None else None)
        return []

    def receive(self, msg: mavlink2.MAVLink_message, now_s: float
                ) -> list[mavlink2.MAVLink_message]:
        if self.result is not None or msg.get_srcSystem() != self.target[0]:
            return []
        if self._own is not None and not _addressed_to(msg, self._own):
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


def _addressed_to(msg: mavlink2.MAVLink_message, ids: tuple[int, int]) -> bool:
    """Whether ``msg`` targets system and component ``ids`` (0: broadcast)."""
    system = getattr(msg, "target_system", 0)
    component = getattr(msg, "target_component", 0)
    return system in (0, ids[0]) and component in (0, ids[1])


def with_home(items: tuple[MissionItem, ...], home: MissionItem, autopilot: int
              ) -> tuple[MissionItem, ...]:
    """The items to upload to an autopilot of MAV_AUTOPILOT ``autopilot``: ArduPilot keeps
    home at seq 0, so it gets ``home`` first; PX4 and others get ``items`` as they are."""
    if autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return (home, *items)
    return items
