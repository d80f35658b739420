"""The autopilot's clock -> UTC: ``UtcClock`` fed the autopilot's real-time clock beside its
boot clock, and ``utc_text``, the one way pdcov writes a UTC time.

The pairs come from MAVLink SYSTEM_TIME (time_unix_usec beside time_boot_ms; ArduPilot sets
it from GPS time, 0 means unknown), DataFlash GPS records (GWk, GMS beside TimeUS:
``gps_week_to_unix_s``) and ULog vehicle_gps_position (time_utc_usec beside timestamp). The
adapters turn them into (t_s, boot_s, unix_s): t_s the autopilot clock every sample is
stamped in (monotonic across reboots, telemetry/clocks.BootClock), boot_s the boot time the
message carried. t_s - boot_s is where that boot began on the clock, so each boot keeps an
offset of its own, and a time of a boot that never knew UTC maps to none.

Pure: nothing here reads a clock; times are passed in.
"""

from __future__ import annotations

import math
import re
import statistics
from collections import deque
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

__all__ = ["GPS_EPOCH_UNIX_S", "GPS_LEAP_S", "MAX_BOOTS", "MAX_UNIX_S", "MIN_UNIX_S",
           "UTC_TEXT", "WINDOW_PAIRS", "UtcClock", "gps_week_to_unix_s", "utc_text"]

MIN_UNIX_S = 1_420_070_400.0
"""2015-01-01T00:00:00Z: an earlier real-time clock is not set (an autopilot without GPS
time counts from 1970 or from the GPS epoch of 1980)."""
MAX_UNIX_S = 4_102_444_800.0
"""2100-01-01T00:00:00Z: a later one is garbage."""
GPS_EPOCH_UNIX_S = 315_964_800.0
"""1980-01-06T00:00:00Z, week 0 of GPS time."""
GPS_LEAP_S = ((1_136_073_600.0, 14.0), (1_230_768_000.0, 15.0), (1_341_100_800.0, 16.0),
              (1_435_708_800.0, 17.0), (1_483_228_800.0, 18.0))
"""GPS time minus UTC (s) from each UTC instant (s since 1970) on: 2006-01-01 14,
2009-01-01 15, 2012-07-01 16, 2015-07-01 17, 2017-01-01 18 (IERS Bulletin C: no leap
second announced since). Earlier times take the first."""
WINDOW_PAIRS = 15
"""Recent pairs per boot whose median offset is taken: one outlier (a late message, a GPS
glitch) moves nothing, and a clock that is corrected (ArduPilot's from each GPS fix) is
followed within ~15 s at SYSTEM_TIME's 1 Hz."""
STEP_S = 0.02
"""The median offset moving more than this (s) starts a new offset: the jitter of
millisecond stamps never does; a clock drifting 50 ppm does every ~7 minutes."""
MAX_KNOTS = 256
"""Offsets kept per boot (the oldest forgotten: its times then take the oldest kept)."""
MAX_BOOTS = 16
"""Boots remembered (the oldest forgotten): bounded memory in a daemon that runs for days."""
BOOT_MATCH_S = 0.5
"""Two pairs whose boot starts (t_s - boot_s) differ by less than this are of one boot."""
BACKSTEP_S = 2.0
"""A t_s this far behind its boot's latest is a new boot (as telemetry/clocks.BootClock)."""


UTC_TEXT = re.compile(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}\.\d{3}Z")
"""What ``utc_text`` writes (datetime.fromisoformat reads it)."""


def gps_week_to_unix_s(week: int, ms_of_week: float) -> float:
    """UTC (s since 1970) of a GPS week number and milliseconds into the week (GPS time,
    ahead of UTC by the leap seconds of GPS_LEAP_S)."""
    gps_s = GPS_EPOCH_UNIX_S + week * 604_800.0 + ms_of_week * 1e-3
    leap_s = GPS_LEAP_S[0][1]
    for start_unix_s, leap in GPS_LEAP_S:
        if gps_s - leap >= start_unix_s:
            leap_s = leap
    return gps_s - leap_s


def utc_text(unix_s: float | None) -> str | None:
    """``unix_s`` (UTC s since 1970) as ISO 8601 to the millisecond with a 'Z':
    '2026-12-06T21:42:01.250Z'; None for None or a non-finite time."""
    if unix_s is None or not math.isfinite(unix_s):
        return None
    ms = round(unix_s * 1000.0)
    t = datetime.fromtimestamp(ms // 1000, tz=timezone.utc)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{ms % 1000:03d}Z"


@dataclass(slots=True)
class _Boot:
    start_t_s: float  # where the boot began on the autopilot clock (t_s - boot_s)
    last_t_s: float  # its latest pair's t_s
    offsets_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW_PAIRS))
    knots: deque[tuple[float, float]] = field(  # (from t_s, offset s): unix = t + offset
        default_factory=lambda: deque(maxlen=MAX_KNOTS))

    def offset_s(self, t_s: float) -> float:
        """The offset in force at ``t_s`` (the first before the first knot; NaN: none)."""
        for from_t_s, offset_s in reversed(self.knots):
            if from_t_s <= t_s:
                return offset_s
        return self.knots[0][1] if self.knots else math.nan


class UtcClock:
    """Maps autopilot-clock times (t_s) to UTC (s since 1970), fed (t_s, boot_s, unix_s)
    pairs in arrival order (module docstring).

    Each boot's offset (unix_s - t_s) is the median of its last WINDOW_PAIRS valid pairs,
    taken from a pair's t_s on when it moves more than STEP_S from the one in force (the
    first pair's from the boot's start): one outlier moves nothing, a clock corrected or
    drifting is followed in steps, and a daemon (which maps each frame as it is decided)
    and a reading of its whole log map every time alike. A pair whose unix_s is outside
    [MIN_UNIX_S, MAX_UNIX_S] (0: unknown) says only that its boot exists, so that the
    boot's times map to none rather than to another boot's. A t_s more than BACKSTEP_S
    behind its boot's latest (a caller feeding raw boot times) starts a new boot too.
    Times before the first boot, or of a boot with no valid pair, are unknown (NaN).
    """

    __slots__ = ("_boots", "unset")

    def __init__(self) -> None:
        self._boots: deque[_Boot] = deque(maxlen=MAX_BOOTS)
        self.unset = 0
        """Pairs without a real-time clock (unix_s unset or out of range)."""

    def add(self, t_s: float, boot_s: float, unix_s: float) -> None:
        """One pair: autopilot-clock time ``t_s`` (s), the boot time it carried ``boot_s``
        (s) and the real-time clock's ``unix_s`` (UTC s since 1970; 0 or NaN: unknown)."""
        if not (math.isfinite(t_s) and math.isfinite(boot_s)):
            return
        start = t_s - boot_s
        boot = self._boots[-1] if self._boots else None
        if (boot is None or abs(start - boot.start_t_s) >= BOOT_MATCH_S
                or t_s < boot.last_t_s - BACKSTEP_S):
            boot = _Boot(start, t_s)
            self._boots.append(boot)
        boot.last_t_s = max(boot.last_t_s, t_s)
        if not (math.isfinite(unix_s) and MIN_UNIX_S <= unix_s <= MAX_UNIX_S):
            self.unset += 1
            return
        boot.offsets_s.append(unix_s - t_s)
        median = statistics.median(boot.offsets_s)
        if not boot.knots or abs(median - boot.knots[-1][1]) > STEP_S:
            boot.knots.append((t_s, median))

    @property
    def known(self) -> bool:
        """True once any boot has an offset."""
        return any(b.knots for b in self._boots)

    def _boot_of(self, t_s: float) -> _Boot | None:
        for b in reversed(self._boots):
            if b.start_t_s <= t_s + BOOT_MATCH_S:
                return b
        return None

    def unix_s(self, t_s: float) -> float:
        """UTC (s since 1970) of autopilot-clock time ``t_s`` (s), by the latest boot begun
        at or before it; NaN when unknown."""
        boot = self._boot_of(t_s)
        return math.nan if boot is None else t_s + boot.offset_s(t_s)

    def unix_s_many(self, t_s: np.ndarray) -> np.ndarray:
        """``unix_s`` of each of ``t_s`` (N,) (s): (N,) UTC s since 1970, NaN unknown."""
        return np.array([self.unix_s(float(t)) for t in np.asarray(t_s, float).ravel()],
                        dtype=float).reshape(np.shape(t_s))

    def text(self, t_s: float) -> str | None:
        """``unix_s`` as ``utc_text``: ISO 8601 UTC, None when unknown."""
        return utc_text(self.unix_s(t_s))
