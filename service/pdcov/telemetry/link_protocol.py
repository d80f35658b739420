"""The daemon's side of the MAVLink conversation with the autopilot, with no I/O.

``LinkProtocol`` is fed every decoded message (``receive``) and the time (``poll``); it
returns the telemetry samples (stamped in the autopilot's clock, s) and the messages to send.
The daemon feeds it its links; the .tlog reader (telemetry/logs/tlog.py) replays a log's
messages through it, so that a log gives the samples the link gave.
It: follows one autopilot (the configured system id, else the first HEARTBEAT of a real
autopilot); identifies as that system's component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) --
never system 255, which ArduPilot takes for its ground station (its HEARTBEAT would mask the
GCS-loss failsafe); sends an onboard-controller HEARTBEAT at 1 Hz; asks for the streams it
needs with MAV_CMD_SET_MESSAGE_INTERVAL and reads COMMAND_ACK (refused: the autopilot's
SRx_/MAVn_ stream rates must deliver; unanswered: resent 3 times); asks for HOME_POSITION
(MAV_CMD_REQUEST_MESSAGE); reads the mount parameters by name (PARAM_REQUEST_READ), and takes
any PARAM_VALUE of them that passes; and does it all again after the autopilot reboots
(its time_boot_ms falls back: clocks.BootClock).

It never arms, takes off or changes the flight mode: it sends only HEARTBEAT, COMMAND_LONG
with SET_MESSAGE_INTERVAL or REQUEST_MESSAGE, PARAM_REQUEST_READ, NAMED_VALUE_FLOAT,
STATUSTEXT, and for a ground station's re-tasking (service/retask.py) MISSION_COUNT and
MISSION_ITEM_INT (``ALLOWED_COMMANDS`` / ``ALLOWED_MESSAGES``, checked in ``checked``).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pdcov.core.mission import MAV_AUTOPILOT_ARDUPILOTMEGA
from pdcov.telemetry.adapters import (
    MAV_AUTOPILOT_INVALID,
    MAVLINK_TYPES,
    is_autopilot_heartbeat,
    mavlink_boot_time_s,
    sample_from_mavlink,
)
from pdcov.telemetry.clocks import VehicleClock
from pdcov.telemetry.frame_policy import AUTOPILOT_ONLY, AttitudeSource, TextEnum
from pdcov.telemetry.samples import HeartbeatSample, ParamSample, Sample

MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_STATE_ACTIVE = 4
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_IN_PROGRESS = 5
MAV_SEVERITY_NOTICE = 5
MAV_SEVERITY_INFO = 6
STATUSTEXT_CHARS = 50
# Message ids (common.xml; EKF_STATUS_REPORT: ardupilotmega.xml).
ATTITUDE, GLOBAL_POSITION_INT, HOME_POSITION, GPS_RAW_INT = 30, 33, 242, 24
SYSTEM_TIME = 2
GIMBAL_DEVICE_ATTITUDE_STATUS = 285
EKF_STATUS_REPORT, ESTIMATOR_STATUS = 193, 230
ZOOM_MESSAGES = {"hfov_rad": 271, "zoom_level": 260, "focal_length_mm": 259}
"""The message of each zoom report (core/zoom.py LensQuantity): CAMERA_FOV_STATUS,
CAMERA_SETTINGS, CAMERA_INFORMATION."""
ALLOWED_COMMANDS = frozenset({MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE})
ALLOWED_MESSAGES = frozenset({"HEARTBEAT", "COMMAND_LONG", "PARAM_REQUEST_READ",
                              "NAMED_VALUE_FLOAT", "STATUSTEXT", "MISSION_COUNT",
                              "MISSION_ITEM_INT"})
HEARTBEAT_PERIOD_S = 1.0
RETRY_S = 1.0
MAX_TRIES = 4
HELD_MESSAGES = 5000
"""Messages kept from before the autopilot's first HEARTBEAT (a few seconds of streams)."""


class RequestResult(TextEnum):
    """Where a command or parameter read stands (the status lists them by these names)."""

    PENDING = "pending"
    ACKED = "acked"
    REFUSED = "refused"
    UNANSWERED = "unanswered"


class LinkState(TextEnum):
    """A link's state as the status reports it (docs/protocol.md ``link.state``)."""

    NONE = "none"
    CONNECTING = "connecting"
    WAITING = "waiting"
    CONNECTED = "connected"
    LOST = "lost"
    CLOSED = "closed"


@dataclass(slots=True)
class _Request:
    """A command or parameter read awaiting its answer."""

    tries: int = 0
    next_s: float = 0.0
    result: RequestResult = RequestResult.PENDING


@dataclass(slots=True)
class LinkStats:
    messages: int = 0
    bad: int = 0  # BAD_DATA: bytes pymavlink could not parse (checksum, signature, junk)
    other_systems: int = 0
    unknown: int = 0  # of message ids the dialect does not know (e.g. a corrupted id)
    rejected: Counter = field(default_factory=Counter)  # message type -> refused values
    last_message_s: float | None = None  # the caller's monotonic now_s


class LinkProtocol:
    """One autopilot's link, as decisions. ``mav`` is a pymavlink MAVLink object used only
    to encode messages (its srcSystem is set to the vehicle's when the autopilot is known).
    intervals: {message id: rate Hz} to ask for. param_names: the mount parameters to read
    (empty for a fixed mount). params_complete(values): whether the values read so far are
    all that is needed (default: every one of param_names; names of older firmware may be
    asked too and never answered). estimator_hz: the rate to ask the position estimator's
    status at (EKF_STATUS_REPORT from ArduPilot, ESTIMATOR_STATUS from others; None: not
    asked). Every ``now_s`` is the caller's monotonic clock, s."""

    def __init__(self, mav: Any, *, system_id: int | None, intervals: dict[int, float],
                 param_names: tuple[str, ...], param_timeout_s: float,
                 estimator_hz: float | None = None,
                 params_complete: Callable[[Mapping[str, float]], bool] | None = None
                 ) -> None:
        self.mav = mav
        self.mav.srcComponent = MAV_COMP_ID_ONBOARD_COMPUTER
        self.system_id = system_id
        self.autopilot_component: int | None = None
        self.autopilot_type: int | None = None
        self._intervals = dict(intervals)
        self._estimator_hz = estimator_hz
        self._param_names = tuple(param_names)
        self._params_complete = params_complete or (
            lambda values: all(n in values for n in self._param_names))
        self._param_timeout_s = param_timeout_s
        self._clock: VehicleClock | None = None
        self.stats = LinkStats()
        self.params: dict[str, float] = {}
        self._reset_requests(0.0)
        self._next_heartbeat_s = 0.0
        self._armed = False
        self._primed: tuple[float, float] | None = None
        self._held: deque = deque(maxlen=HELD_MESSAGES)
        self._attitude_source = AttitudeSource()

    def _reset_requests(self, now_s: float) -> None:
        self.interval_requests = {mid: _Request(next_s=now_s) for mid in self._intervals}
        self.home_request = _Request(next_s=now_s)
        self.param_request = _Request(next_s=now_s)
        self._params_deadline_s: float | None = None

    # --- state ----------------------------------------------------------------------------

    @property
    def autopilot_known(self) -> bool:
        return self.autopilot_component is not None

    @property
    def params_done(self) -> bool:
        """All mount parameters answered, or their time is up (resolve without the rest)."""
        return self.param_request.result != RequestResult.PENDING

    @property
    def reboots(self) -> int:
        return len(self.restarts_t_s)

    @property
    def restarts_t_s(self) -> tuple[float, ...]:
        """The autopilot clock's times (s) at which its boot clock restarted (reboots)."""
        return tuple(self._clock.autopilot.restarts_t_s) if self._clock else ()

    def follow(self, system_id: int, autopilot_component: int) -> None:
        """Follow this vehicle without waiting for its autopilot's HEARTBEAT: a log that
        recorded none (the .tlog reader names the vehicle, telemetry/logs/choose.py)."""
        self.system_id, self.autopilot_component = system_id, autopilot_component

    def from_autopilot(self, msg: Any) -> bool:
        """Whether ``msg`` (received) is the followed autopilot's own: its system and
        component (a UDP link answers only the addresses such messages come from)."""
        return (self.autopilot_known and not msg.get_type().startswith(("BAD_DATA", "UNKNOWN"))
                and (msg.get_srcSystem(), msg.get_srcComponent())
                == (self.system_id, self.autopilot_component))

    def clock_state(self) -> tuple[float, float]:
        """(offset_s, latest boot s) of the autopilot's clock, for a checkpoint."""
        clock = self._clock.autopilot if self._clock else None
        if clock is None or clock.now_s != clock.now_s:
            return 0.0, float("nan")
        return clock.offset_s, clock.now_s - clock.offset_s

    @property
    def clock_now_s(self) -> float:
        """The autopilot clock's newest time (s; NaN before any timed message)."""
        return self._clock.autopilot.now_s if self._clock is not None else math.nan

    def autopilot_boot_s(self, boot_s: float) -> float:
        """``boot_s`` (s of the autopilot's boot clock, read by another party: a detector's
        frame time) in the autopilot clock: clocks.VehicleClock.autopilot_boot_s, the rule
        the tlog reader applies to the frames the daemon records (offset 0 before any
        message of the autopilot, as a reader's fresh clock)."""
        return boot_s if self._clock is None else self._clock.autopilot_boot_s(boot_s)

    def prime_clock(self, offset_s: float, boot_s: float) -> None:
        """Continue a checkpointed clock: times after a daemon restart never go back (an
        autopilot that rebooted meanwhile is placed after the old times, as BootClock
        does)."""
        self._primed = (offset_s, boot_s)

    def describe(self) -> dict[str, Any]:
        def results(reqs: dict[int, _Request]) -> dict[str, list[int]]:
            out: dict[str, list[int]] = {}
            for mid, r in reqs.items():
                out.setdefault(str(r.result), []).append(mid)
            return out
        return {"system_id": self.system_id, "component_id": self.autopilot_component,
                "autopilot": self.autopilot_type, "messages": self.stats.messages,
                "other_systems": self.stats.other_systems, "unknown": self.stats.unknown,
                "rejected": dict(self.stats.rejected),
                "reboots": self.reboots, "intervals": results(self.interval_requests),
                "home_request": str(self.home_request.result),
                "params": dict(sorted(self.params.items()))}

    # --- input ----------------------------------------------------------------------------

    def receive(self, msg: Any, now_s: float) -> list[Sample]:
        """The samples in ``msg`` (autopilot clock); updates what the link knows."""
        mtype = msg.get_type()
        if mtype == "BAD_DATA":  # counted here only (the status's bad_messages)
            self.stats.bad += 1
            return []
        if mtype.startswith("UNKNOWN"):
            # No checksum can catch a corrupted message id: its CRC_EXTRA is unknown too.
            self.stats.unknown += 1
            return []
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        early: list[Sample] = []
        if mtype == "HEARTBEAT" and not self.autopilot_known:
            if is_autopilot_heartbeat(msg, self.system_id):
                self.system_id, self.autopilot_component = src_sys, src_comp
                self.autopilot_type = int(msg.autopilot)
                self.mav.srcSystem = src_sys
                if self._estimator_hz:
                    self._intervals[EKF_STATUS_REPORT if self.autopilot_type
                                    == MAV_AUTOPILOT_ARDUPILOTMEGA
                                    else ESTIMATOR_STATUS] = self._estimator_hz
                self._reset_requests(now_s)
                # What the autopilot sent before its first HEARTBEAT counts too (as
                # offline, where the whole log is read).
                held, self._held = self._held, deque(maxlen=HELD_MESSAGES)
                for m, t in held:
                    early += self.receive(m, t)
        autopilot_component = self.autopilot_component
        if autopilot_component is None:  # everything else (a gimbal's HEARTBEAT too) waits
            self._held.append((msg, now_s))
            return []
        if self.system_id is None or src_sys != self.system_id:
            self.stats.other_systems += 1
            return []
        self.stats.messages += 1
        self.stats.last_message_s = now_s
        t_s = self._time_s(msg, src_comp, autopilot_component)
        if mtype == "COMMAND_ACK":
            self._ack(msg)
            return early
        autopilot = src_comp == autopilot_component
        if ((mtype == "ATTITUDE" and autopilot) or mtype == "ATTITUDE_QUATERNION") \
                and not self._attitude_source.takes(mtype):
            return early  # frame_policy.AttitudeSource: the tlog reader's rule too
        sample = sample_from_mavlink(msg, t_s)
        if sample is None and mtype in MAVLINK_TYPES and not _no_value_yet(msg):
            self.stats.rejected[mtype] += 1  # NaN, out of range: samples.py's adapters
        if isinstance(sample, AUTOPILOT_ONLY) and not autopilot:
            # frame_policy.AUTOPILOT_ONLY: the autopilot's own (the tlog reader's rule too).
            return early
        if isinstance(sample, ParamSample) and sample.name in self._param_names:
            self.params[sample.name] = sample.value
            if self._params_complete(self.params):
                self.param_request.result = RequestResult.ACKED
        if isinstance(sample, HeartbeatSample):
            if not autopilot:
                return early
            if sample.armed and not self._armed:
                self.home_request = _Request(next_s=now_s)  # home is set at arming
            self._armed = sample.armed
        return early if sample is None else [*early, sample]

    def _time_s(self, msg: Any, src_comp: int, autopilot_component: int) -> float:
        """The message's time in the autopilot clock (clocks.VehicleClock: the rule the tlog
        reader applies too; a component with a clock of its own is mapped causally)."""
        if self._clock is None:
            self._clock = VehicleClock(autopilot_component)
            if self._primed is not None:
                self._clock.autopilot.offset_s = self._primed[0]
                self._clock.autopilot.to_s(self._primed[1])
        before = len(self._clock.autopilot.restarts_t_s)
        t_s = self._clock.time_s(src_comp, mavlink_boot_time_s(msg))
        if len(self._clock.autopilot.restarts_t_s) > before:
            self._reset_requests(self.stats.last_message_s or 0.0)
        return t_s

    def _ack(self, msg: Any) -> None:
        if msg.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            # COMMAND_ACK carries no message id: the oldest pending request takes it.
            pending = [r for r in self.interval_requests.values()
                       if r.result == RequestResult.PENDING and r.tries]
            req = pending[0] if pending else None
        elif msg.command == MAV_CMD_REQUEST_MESSAGE:
            req = self.home_request
        else:
            return
        if req is None or msg.result == MAV_RESULT_IN_PROGRESS:
            return
        req.result = (RequestResult.ACKED if msg.result == MAV_RESULT_ACCEPTED
                      else RequestResult.REFUSED)

    # --- output ---------------------------------------------------------------------------

    def poll(self, now_s: float) -> list[Any]:
        """Messages due at ``now_s`` (the caller's monotonic clock, s): heartbeat, retries,
        parameter reads."""
        if not self.autopilot_known:
            return []
        out = []
        if now_s >= self._next_heartbeat_s:
            self._next_heartbeat_s = now_s + HEARTBEAT_PERIOD_S
            out.append(self.mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER,
                                                 MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE))
        target = (self.system_id, self.autopilot_component)
        for mid, req in self.interval_requests.items():
            if self._due(req, now_s):
                out.append(self.mav.command_long_encode(
                    *target, MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid,
                    round(1e6 / self._intervals[mid]), 0, 0, 0, 0, 0))
        if self._due(self.home_request, now_s):
            out.append(self.mav.command_long_encode(*target, MAV_CMD_REQUEST_MESSAGE, 0,
                                                    HOME_POSITION, 0, 0, 0, 0, 0, 0))
        if self._param_names and self.param_request.result == RequestResult.PENDING:
            if self._params_deadline_s is None:
                self._params_deadline_s = now_s + self._param_timeout_s
            if now_s >= self._params_deadline_s:
                self.param_request.result = RequestResult.UNANSWERED
            elif now_s >= self.param_request.next_s:
                self.param_request.next_s = now_s + RETRY_S
                out += [self.mav.param_request_read_encode(*target, n.encode("ascii"), -1)
                        for n in self._param_names if n not in self.params]
        elif not self._param_names:
            self.param_request.result = RequestResult.ACKED
        return self.checked(out)

    def next_timer_s(self) -> float:
        """When ``poll`` next has something to send (monotonic s; inf: nothing planned)."""
        if not self.autopilot_known:
            return math.inf
        times = [self._next_heartbeat_s]
        times += [r.next_s for r in self.interval_requests.values()
                  if r.result == RequestResult.PENDING]
        if self.home_request.result == RequestResult.PENDING:
            times.append(self.home_request.next_s)
        if self._param_names and self.param_request.result == RequestResult.PENDING:
            times.append(self.param_request.next_s)
            if self._params_deadline_s is not None:
                times.append(self._params_deadline_s)
        return min(times)

    @staticmethod
    def _due(req: _Request, now_s: float) -> bool:
        if req.result != RequestResult.PENDING or now_s < req.next_s:
            return False
        if req.tries >= MAX_TRIES:
            req.result = RequestResult.UNANSWERED
            return False
        req.tries += 1
        req.next_s = now_s + RETRY_S
        return True

    def coverage_messages(self, value: float | None, text: str | None, t_boot_ms: int
                          ) -> list[Any]:
        """NAMED_VALUE_FLOAT 'PDCOV' with ``value`` and/or a STATUSTEXT (INFO) ``text``."""
        if not self.autopilot_known:
            return []
        out = []
        if value is not None:
            out.append(self.mav.named_value_float_encode(t_boot_ms & 0xFFFFFFFF, b"PDCOV",
                                                         float(value)))
        if text is not None:
            out.append(self.mav.statustext_encode(MAV_SEVERITY_INFO,
                                                  text.encode()[:STATUSTEXT_CHARS]))
        return self.checked(out)

    def notice(self, text: str) -> list[Any]:
        """A STATUSTEXT of severity NOTICE (the ground station shows it to the pilot),
        ``text`` cut to 50 characters."""
        if not self.autopilot_known:
            return []
        return self.checked([self.mav.statustext_encode(
            MAV_SEVERITY_NOTICE, text.encode()[:STATUSTEXT_CHARS])])

    @staticmethod
    def checked(msgs: list[Any]) -> list[Any]:
        """``msgs``, refusing as a bug anything but the messages the daemon may send (module
        docstring): every message the daemon sends passes here."""
        for msg in msgs:
            name = msg.get_type()
            if name not in ALLOWED_MESSAGES or (name == "COMMAND_LONG"
                                                and msg.command not in ALLOWED_COMMANDS):
                raise RuntimeError(f"the daemon never sends {name}")
        return msgs


def _no_value_yet(msg: Any) -> bool:
    """Messages that carry no value by design, not by damage: GLOBAL_POSITION_INT all zero
    (ArduPilot before its first position estimate), a failed CAMERA_IMAGE_CAPTURED, an
    EKF_STATUS_REPORT with no flags (ArduPilot's AHRS runs no EKF)."""
    mtype = msg.get_type()
    return ((mtype == "GLOBAL_POSITION_INT" and msg.lat == 0 and msg.lon == 0)
            or (mtype == "CAMERA_IMAGE_CAPTURED" and msg.capture_result != 1)
            or (mtype == "EKF_STATUS_REPORT" and msg.flags == 0))
