"""The autopilot's MAVLink endpoint: what a flight controller answers and when it sends.

Two cores, messages and times in, messages out, no I/O (the shell that owns the link, the
tlog and the fault injector and feeds them is ``endpoint.py``):

* ``StreamSchedule`` decides which telemetry streams are due at a simulated time, with the
  jitter of a real autopilot's scheduler, and holds the rates ground stations set;
* ``AutopilotProtocol`` answers ground stations: commands (SET_MESSAGE_INTERVAL,
  GET_MESSAGE_INTERVAL, REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES) with COMMAND_ACK,
  the parameter protocol with PARAM_VALUE, and the mission protocol (``MissionServer``).

Hand-written rather than MAVSDK's server plugins (mission_raw_server, param_server,
telemetry_server): every byte the vehicle sends must go through the tlog and the fault
injector, stamped in simulated time and reproducible for a seed, and MAVSDK, as the
independent client the tests use, should not be checked against itself (docs/simulator.md).
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from typing import Literal, get_args

from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink2

from .mission_server import MissionServer

Autopilot = Literal["ardupilot", "px4"]
"""Which flight controller the endpoint behaves like (mission requests, capabilities)."""
AUTOPILOTS: tuple[Autopilot, ...] = get_args(Autopilot)
AUTOPILOT_COMPONENT = 1
# Stream names of the ArduPilot dialect (common.xml and ardupilotmega.xml: EKF_STATUS_REPORT).
_MESSAGE_MAP = ardupilotmega.mavlink_map
_MESSAGE_IDS = {cls.msgname: msg_id for msg_id, cls in _MESSAGE_MAP.items()}
_JITTER_SIGMA_S = 0.002
_LATE_PROBABILITY = 0.02
_LATE_MAX_S = 0.02


def message_id(name: str) -> int:
    """The MAVLink message id of a message name (``ATTITUDE`` -> 30); KeyError if none."""
    return _MESSAGE_IDS[name]


class StreamSchedule:
    """When each telemetry stream is next sent, in simulated seconds.

    Sends follow a fixed grid of the stream's period (so the mean rate is exact), each send
    late by |N(0, sigma)| with sigma = min(2 ms, 5 % of the period), and 2 % of sends by up
    to another 20 ms more (a busy scheduler loop), never earlier than the previous send. A
    loop that fell more than a period behind resumes from now instead of bursting."""

    def __init__(self, default_hz: Mapping[str, float], rng: random.Random):
        for name, hz in default_hz.items():
            if name not in _MESSAGE_IDS:
                raise ValueError(f"stream {name!r}: no such MAVLink message")
            if not (math.isfinite(hz) and hz >= 0):
                raise ValueError(f"stream {name}: rate {hz!r} Hz must be finite and >= 0")
        self.default_hz = dict(default_hz)
        self._rng = rng
        self._hz = dict(default_hz)
        self._nominal_s: dict[str, float] = {}
        self._next_s: dict[str, float] = {}
        self._once: list[str] = []
        self._start_s: float | None = None
        self._earliest_s = -math.inf  # no stream is due before this

    def rate_hz(self, name: str) -> float:
        return self._hz.get(name, 0.0)

    def _jitter_s(self, period_s: float) -> float:
        jitter = abs(self._rng.gauss(0.0, min(_JITTER_SIGMA_S, 0.05 * period_s)))
        if self._rng.random() < _LATE_PROBABILITY:
            jitter += self._rng.uniform(0.0, min(_LATE_MAX_S, 0.3 * period_s))
        return jitter

    def _plan(self, name: str, nominal_s: float) -> None:
        period_s = 1.0 / self._hz[name]
        self._nominal_s[name] = nominal_s
        self._next_s[name] = nominal_s + self._jitter_s(period_s)

    def _start(self, t_s: float) -> None:
        """Streams start at random phases within their first period."""
        self._start_s = t_s
        self._earliest_s = -math.inf
        self._nominal_s.clear()
        self._next_s.clear()
        for name, hz in self._hz.items():
            if hz > 0:
                self._plan(name, t_s + self._rng.uniform(0.0, 1.0 / hz))

    def due(self, t_s: float) -> list[str]:
        """Stream names to send now (each at most once per call), one-shot requests first."""
        if self._start_s is None:
            self._start(t_s)
        if t_s < self._earliest_s and not self._once:
            return []
        out, self._once = self._once, []
        for name, next_s in self._next_s.items():
            if t_s < next_s:
                continue
            if name not in out:
                out.append(name)
            period_s = 1.0 / self._hz[name]
            nominal_s = self._nominal_s[name] + period_s
            if nominal_s < t_s - period_s:
                nominal_s = t_s
            self._plan(name, nominal_s)
            self._next_s[name] = max(self._next_s[name], next_s)
        self._earliest_s = min(self._next_s.values(), default=math.inf)
        return out

    def set_rate(self, name: str, hz: float | None, t_s: float) -> None:
        """Set a stream's rate (0 stops it; None restores its default), from ``t_s``."""
        self._hz[name] = self.default_hz.get(name, 0.0) if hz is None else hz
        self._nominal_s.pop(name, None)
        self._next_s.pop(name, None)
        if self._hz[name] > 0 and self._start_s is not None:
            self._plan(name, t_s)
        self._earliest_s = -math.inf

    def request_once(self, name: str) -> None:
        """Send ``name`` once at the next ``due`` (MAV_CMD_REQUEST_MESSAGE)."""
        if name not in self._once:
            self._once.append(name)

    def reset(self) -> None:
        """Forget every rate set since start (a reboot); streams restart at the next due."""
        self._hz = dict(self.default_hz)
        self._once.clear()
        self._start_s = None


class AutopilotProtocol:
    """Answers a ground station as an ArduPilot-like or PX4-like autopilot would.

    ``receive(msg, t_s, wall_s)`` takes one decoded message (``t_s`` simulated seconds,
    ``wall_s`` the ground station's clock, for mission protocol retries) and returns the
    messages to send from the autopilot component. Messages addressed to another system or
    component are ignored. Unknown parameters get no answer (as on ArduPilot)."""

    def __init__(self, mav: mavlink2.MAVLink, *, system_id: int, autopilot: Autopilot,
                 params: Mapping[str, float], schedule: StreamSchedule):
        if autopilot not in AUTOPILOTS:
            raise ValueError(f"autopilot {autopilot!r}: expected one of {AUTOPILOTS}")
        for name in params:
            if not 1 <= len(name) <= 16 or not name.isascii():
                raise ValueError(f"parameter {name!r}: expected 1..16 ASCII characters")
        self._mav = mav
        self.system_id = system_id
        self.autopilot = autopilot
        self.params = dict(params)
        self._param_names = list(params)
        self.schedule = schedule
        self.missions = MissionServer(mav, request_int=autopilot == "px4")

    def _for_us(self, msg: mavlink2.MAVLink_message, component: bool) -> bool:
        if getattr(msg, "target_system", 0) not in (0, self.system_id):
            return False
        return not component or getattr(msg, "target_component", 0) in (0, AUTOPILOT_COMPONENT)

    def receive(self, msg: mavlink2.MAVLink_message, t_s: float, wall_s: float
                ) -> list[mavlink2.MAVLink_message]:
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            return self._command(msg, t_s) if self._for_us(msg, True) else []
        if kind.startswith("PARAM_"):
            return self._param(msg) if self._for_us(msg, True) else []
        if kind.startswith("MISSION_"):
            return self.missions.receive(msg, wall_s) if self._for_us(msg, False) else []
        return []

    def poll(self, wall_s: float) -> list[mavlink2.MAVLink_message]:
        """Messages due without a request (mission protocol resends)."""
        return self.missions.poll(wall_s)

    # Commands (mavlink.io/en/services/command.html). COMMAND_INT carries the same params.

    def _command(self, msg: mavlink2.MAVLink_message, t_s: float
                 ) -> list[mavlink2.MAVLink_message]:
        cmd = msg.command
        extra: list[mavlink2.MAVLink_message] = []
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(msg.param1), msg.param2, t_s)
        elif cmd == mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL:
            result, extra = self._get_interval(int(msg.param1))
        elif cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            result, extra = self._request_message(int(msg.param1))
        elif cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            result, extra = mavlink2.MAV_RESULT_ACCEPTED, [self.autopilot_version()]
        else:
            result = mavlink2.MAV_RESULT_UNSUPPORTED
        ack = self._mav.command_ack_encode(cmd, result, 0, 0, msg.get_srcSystem(),
                                           msg.get_srcComponent())
        return [ack, *extra]

    def _stream_name(self, msg_id: int) -> str | None:
        cls = _MESSAGE_MAP.get(msg_id)
        return cls.msgname if cls is not None else None

    def _set_interval(self, msg_id: int, interval_us: float, t_s: float) -> int:
        """param2: interval in microseconds; -1 stops the stream, 0 restores its default."""
        name = self._stream_name(msg_id)
        if name is None or not math.isfinite(interval_us) or interval_us < -1:
            return mavlink2.MAV_RESULT_DENIED
        if name not in self.schedule.default_hz:
            return mavlink2.MAV_RESULT_UNSUPPORTED
        if interval_us == 0:
            self.schedule.set_rate(name, None, t_s)
        else:
            self.schedule.set_rate(name, 0.0 if interval_us < 0 else 1e6 / interval_us, t_s)
        return mavlink2.MAV_RESULT_ACCEPTED

    def _get_interval(self, msg_id: int) -> tuple[int, list[mavlink2.MAVLink_message]]:
        name = self._stream_name(msg_id)
        if name is None:
            return mavlink2.MAV_RESULT_DENIED, []
        if name not in self.schedule.default_hz:
            return mavlink2.MAV_RESULT_UNSUPPORTED, []
        hz = self.schedule.rate_hz(name)
        interval_us = round(1e6 / hz) if hz > 0 else -1
        return mavlink2.MAV_RESULT_ACCEPTED, [self._mav.message_interval_encode(msg_id,
                                                                                interval_us)]

    def _request_message(self, msg_id: int) -> tuple[int, list[mavlink2.MAVLink_message]]:
        name = self._stream_name(msg_id)
        if name is None:
            return mavlink2.MAV_RESULT_DENIED, []
        if name == "AUTOPILOT_VERSION":
            return mavlink2.MAV_RESULT_ACCEPTED, [self.autopilot_version()]
        if name not in self.schedule.default_hz:
            return mavlink2.MAV_RESULT_UNSUPPORTED, []
        self.schedule.request_once(name)  # the fly loop builds it at its next due()
        return mavlink2.MAV_RESULT_ACCEPTED, []

    def autopilot_version(self) -> mavlink2.MAVLink_message:
        caps = (mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
        if self.autopilot == "ardupilot":
            caps |= (mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
                     | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT)
        else:
            caps |= mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        version = (4 << 24) | (7 << 16)  # major.minor.patch.type, as ArduPilot packs it
        return self._mav.autopilot_version_encode(caps, version, 0, 0, 0, [0] * 8, [0] * 8,
                                                  [0] * 8, 0, 0, self.system_id)

    # Parameters (mavlink.io/en/services/parameter.html). Every value is sent as REAL32,
    # as ArduPilot does (MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT).

    def _param_value(self, index: int) -> mavlink2.MAVLink_message:
        name = self._param_names[index]
        return self._mav.param_value_encode(name.encode("ascii"), self.params[name],
                                            mavlink2.MAV_PARAM_TYPE_REAL32,
                                            len(self._param_names), index)

    def _param(self, msg: mavlink2.MAVLink_message) -> list[mavlink2.MAVLink_message]:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self._param_value(i) for i in range(len(self._param_names))]
        if kind == "PARAM_REQUEST_READ":
            if msg.param_index >= 0:
                ok = msg.param_index < len(self._param_names)
                return [self._param_value(msg.param_index)] if ok else []
            if msg.param_id in self.params:
                return [self._param_value(self._param_names.index(msg.param_id))]
            return []
        if kind == "PARAM_SET" and msg.param_id in self.params:
            if math.isfinite(msg.param_value):
                self.params[msg.param_id] = float(msg.param_value)
            return [self._param_value(self._param_names.index(msg.param_id))]
        return []
