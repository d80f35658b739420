"""Faults the simulator injects (``--faults SPEC``): what goes wrong on the link and in the
autopilot, decided from the simulated time and a seeded random stream, with no I/O.

Grammar (docs/simulator.md, "Faults"): comma-separated ``NAME=VALUE`` items, times in
simulated seconds since the start of the flight::

    drop=P  corrupt=P  reorder=P  duplicate=P        probabilities in [0, 1]
    outage=START+DURATION                            no bytes either way
    gps_glitch=START+DURATION[:JUMP_M]               reported position jumps, then recovers;
                                                     the estimator status says GPS glitching
    reboot=START[+DOWN_S]                            autopilot restarts (silent DOWN_S, def. 2)
    gimbal_fail=START[+STALE_S]                      failure_flags for STALE_S (def. 2), silence
    nan=MESSAGE[.FIELD]@START[+DURATION]             NaN in a float field

Rates may be given once; timed events may repeat (``outage=30+5,outage=90+5``).

Two kinds of fault, and where they act:

* **link faults** (drop, corrupt, reorder, duplicate, outage) act on the packed bytes after
  the tlog has recorded them: ``FaultInjector.transmit``. ``drop`` and ``outage`` also act
  on what the endpoint receives (``FaultInjector.receive_ok``);
* **autopilot faults** (gps_glitch, reboot, gimbal_fail, nan) change what the autopilot
  sends, so the tlog shows them: ``FaultSpec.gps_offset_ned_m``, ``FaultSpec.gimbal_health``,
  ``FaultInjector.nan_field``, and the endpoint's reboot.
"""

from __future__ import annotations

import enum
import math
import random
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

RATE_NAMES = ("drop", "corrupt", "reorder", "duplicate")
DEFAULT_REBOOT_DOWN_S = 2.0
DEFAULT_GIMBAL_STALE_S = 2.0
DEFAULT_GPS_JUMP_M = 20.0
_FLOAT_TYPES = ("float", "double")
_MESSAGE_CLASSES = {cls.msgname: cls for cls in mavlink2.mavlink_map.values()}


class FaultSpecError(ValueError):
    """A ``--faults`` specification that cannot be parsed; the message names the bad item."""


class GimbalHealth(enum.Enum):
    """What the gimbal reports at a time: normally, with failure_flags set, or nothing."""

    OK = "ok"
    FAILED = "failed"
    SILENT = "silent"


@dataclass(frozen=True, slots=True)
class Window:
    """A time interval [start_s, start_s + duration_s) in simulated seconds."""

    start_s: float
    duration_s: float

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s


@dataclass(frozen=True, slots=True)
class GpsGlitch:
    """The reported position is ``jump_m`` north of the truth during ``window``."""

    window: Window
    jump_m: float


@dataclass(frozen=True, slots=True)
class NanFault:
    """NaN in ``field`` of every ``message`` sent during ``window``; with a zero duration,
    in the first such message sent at or after its start only."""

    message: str
    field: str
    window: Window


@dataclass(frozen=True, slots=True)
class FaultSpec:
    """A parsed ``--faults`` specification (see the module docstring)."""

    drop: float = 0.0
    corrupt: float = 0.0
    reorder: float = 0.0
    duplicate: float = 0.0
    outages: tuple[Window, ...] = ()
    gps_glitches: tuple[GpsGlitch, ...] = ()
    reboots: tuple[Window, ...] = ()
    gimbal_failures: tuple[Window, ...] = ()
    nans: tuple[NanFault, ...] = field(default=())

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """Parse SPEC; raises FaultSpecError naming the item that is wrong and why."""
        rates: dict[str, float] = {}
        lists: dict[str, list] = {"outage": [], "gps_glitch": [], "reboot": [],
                                  "gimbal_fail": [], "nan": []}
        for item in (s.strip() for s in text.split(",")):
            if not item:
                continue
            name, sep, value = item.partition("=")
            name = name.strip()
            if not sep or not value.strip():
                raise FaultSpecError(f"fault {item!r}: expected NAME=VALUE")
            value = value.strip()
            if name in RATE_NAMES:
                if name in rates:
                    raise FaultSpecError(f"fault {item!r}: {name} given twice")
                rates[name] = _probability(item, value)
            elif name == "outage":
                lists[name].append(_window(item, value, default_duration=None))
            elif name == "gps_glitch":
                times, colon, jump = value.partition(":")
                jump_m = _number(item, jump, "JUMP_M") if colon else DEFAULT_GPS_JUMP_M
                lists[name].append(GpsGlitch(_window(item, times, None), jump_m))
            elif name == "reboot":
                lists[name].append(_window(item, value, DEFAULT_REBOOT_DOWN_S))
            elif name == "gimbal_fail":
                lists[name].append(_window(item, value, DEFAULT_GIMBAL_STALE_S))
            elif name == "nan":
                lists[name].append(_nan(item, value))
            else:
                raise FaultSpecError(
                    f"fault {item!r}: unknown fault {name!r}; expected one of "
                    f"{', '.join((*RATE_NAMES, *lists))}")
        return cls(**rates, outages=tuple(lists["outage"]),
                   gps_glitches=tuple(lists["gps_glitch"]), reboots=tuple(lists["reboot"]),
                   gimbal_failures=tuple(lists["gimbal_fail"]), nans=tuple(lists["nan"]))

    def in_outage(self, t_s: float) -> bool:
        return any(w.contains(t_s) for w in self.outages)

    def gps_offset_ned_m(self, t_s: float) -> tuple[float, float, float]:
        """Offset to add to the reported GPS and fused position at ``t_s`` (north, east,
        down, metres): a jump north at each glitch's start, gone at its end."""
        north_m = sum(g.jump_m for g in self.gps_glitches if g.window.contains(t_s))
        return (north_m, 0.0, 0.0)

    def gps_glitching(self, t_s: float) -> bool:
        """True during a glitch: the estimator's status reports it (EKF_STATUS_REPORT
        EKF_GPS_GLITCHING, ESTIMATOR_STATUS ESTIMATOR_GPS_GLITCH) for the glitch's window.

        What a glitch models: an EKF that took the bad GPS in (as ArduPilot's EKF3 resets
        to the GPS when a glitch outlasts its innovation gate and EK3_GLITCH_RAD), so the
        fused position it sends (GLOBAL_POSITION_INT) is off by JUMP_M for the whole window,
        jumping at both ends, while it flags the GPS as glitching: the worst case for
        coverage, wrong all along and not only across the jumps. An EKF that rejects the GPS
        and holds its dead-reckoned position is not modelled."""
        return any(g.window.contains(t_s) for g in self.gps_glitches)

    def gimbal_health(self, t_s: float) -> GimbalHealth:
        """OK until a gimbal_fail start; FAILED (report failure_flags) for its stale time;
        SILENT (send no gimbal messages) from then on."""
        health = GimbalHealth.OK
        for w in self.gimbal_failures:
            if w.contains(t_s):
                return GimbalHealth.FAILED
            if t_s >= w.start_s + w.duration_s:
                health = GimbalHealth.SILENT
        return health


def _number(item: str, text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FaultSpecError(f"fault {item!r}: {what} {text!r} is not a number") from None
    if not math.isfinite(value) or value < 0:
        raise FaultSpecError(f"fault {item!r}: {what} {text!r} must be finite and >= 0")
    return value


def _probability(item: str, text: str) -> float:
    p = _number(item, text, "probability")
    if p > 1:
        raise FaultSpecError(f"fault {item!r}: probability {text!r} must be in [0, 1]")
    return p


def _window(item: str, text: str, default_duration: float | None) -> Window:
    start, plus, duration = text.partition("+")
    if not plus:
        if default_duration is None:
            raise FaultSpecError(f"fault {item!r}: expected START+DURATION (seconds)")
        return Window(_number(item, start, "START"), default_duration)
    return Window(_number(item, start, "START"), _number(item, duration, "DURATION"))


def _nan(item: str, text: str) -> NanFault:
    target, at, times = text.partition("@")
    if not at:
        raise FaultSpecError(f"fault {item!r}: expected MESSAGE[.FIELD]@START[+DURATION]")
    message, dot, field_name = target.strip().upper().partition(".")
    cls = _MESSAGE_CLASSES.get(message)
    if cls is None:
        raise FaultSpecError(f"fault {item!r}: {message!r} is no MAVLink message")
    floats = [n for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True)
              if t in _FLOAT_TYPES]
    if not floats:
        raise FaultSpecError(f"fault {item!r}: {message} has no float field")
    if dot:
        field_name = field_name.lower()
        if field_name not in floats:
            raise FaultSpecError(f"fault {item!r}: {message} has no float field "
                                 f"{field_name!r}; float fields: {', '.join(floats)}")
    else:
        field_name = floats[0]
    return NanFault(message, field_name, _window(item, times, 0.0))


class FaultInjector:
    """Applies a FaultSpec to the packets of one link, deterministically for a seed: the
    random draws depend only on the seed and the order of the calls."""

    def __init__(self, spec: FaultSpec, seed: int):
        self.spec = spec
        self._rng = random.Random(f"{seed}:faults:tx")
        self._rx_rng = random.Random(f"{seed}:faults:rx")
        self._held: bytes | None = None
        self._bytes_to_corruption = self._next_corruption_gap()
        self._nans_done: set[int] = set()

    def _next_corruption_gap(self) -> float:
        p = self.spec.corrupt
        if p <= 0:
            return math.inf
        if p >= 1:
            return 0
        # bytes until the next corrupted one: geometric, so each byte is hit with p
        return int(math.log(1.0 - self._rng.random()) / math.log(1.0 - p))

    def _corrupt(self, packet: bytes) -> bytes:
        if self._bytes_to_corruption >= len(packet):
            self._bytes_to_corruption -= len(packet)
            return packet
        buf = bytearray(packet)
        i = self._bytes_to_corruption  # a whole number of bytes, or inf: no more corruption
        while i < len(buf):
            buf[int(i)] ^= self._rng.randrange(1, 256)
            i += 1 + self._next_corruption_gap()
        self._bytes_to_corruption = i - len(buf)
        return bytes(buf)

    def transmit(self, packet: bytes, t_s: float) -> list[bytes]:
        """The datagrams to put on the wire for one packed message, in order: none (dropped
        or in an outage), one, two (duplicated), or the previously held one as well
        (reordered: a held packet goes out after the next one)."""
        spec = self.spec
        if spec.in_outage(t_s):
            self._held = None  # lost with the link
            return []
        if spec.drop and self._rng.random() < spec.drop:
            return []
        packet = self._corrupt(packet)
        out = [packet]
        if spec.duplicate and self._rng.random() < spec.duplicate:
            out.append(packet)
        if spec.reorder and self._held is None and self._rng.random() < spec.reorder:
            self._held = packet
            return out[1:]
        if self._held is not None:
            out.append(self._held)
            self._held = None
        return out

    def receive_ok(self, t_s: float) -> bool:
        """Whether a message from the ground station gets through (outage, drop)."""
        if self.spec.in_outage(t_s):
            return False
        return not (self.spec.drop and self._rx_rng.random() < self.spec.drop)

    def nan_field(self, message: str, t_s: float) -> str | None:
        """The field of ``message`` (a MAVLink name) to send as NaN at ``t_s``, if any."""
        for i, f in enumerate(self.spec.nans):
            if f.message != message or t_s < f.window.start_s:
                continue
            if f.window.duration_s > 0:
                if f.window.contains(t_s):
                    return f.field
            elif i not in self._nans_done:
                self._nans_done.add(i)
                return f.field
        return None
