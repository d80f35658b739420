"""One vehicle's MAVLink clocks -> the autopilot's clock (s): the one rule that the tlog
reader (``pdcov evaluate``) and the daemon (``pdcov serve``) both apply, message by message
in arrival order, so that they stamp every sample identically.

* The autopilot's ``time_boot_ms`` goes through a ``BootClock`` (restarts shifted forward;
  defined here, used by every reader of a boot time).
* A message without a boot time (HEARTBEAT, PARAM_VALUE, HOME_POSITION) gets the
  autopilot's latest time.
* Another component with a boot clock of its own (a gimbal device on component 154, a
  camera on 100) is mapped onto the autopilot's by ``ComponentClock``: causal (each message
  is mapped with what arrived up to it), so live and offline agree, and measured against
  the simulator's truth (both clocks known) to its millisecond stamps (docs/logs.md "Clock").

Pure: times are passed in; nothing here reads a clock of its own.
"""

from __future__ import annotations

import math
from collections import deque

REBOOT_BACKSTEP_S = 2.0
"""A boot time this far behind the latest one means the autopilot restarted (messages of
different types may arrive slightly out of order, never by seconds)."""

REBOOT_GAP_S = 60.0
"""Clock gap inserted at a restart so that no interpolation bridges the reboot."""


class BootClock:
    """Turns a source's boot time (time_boot_ms, TimeUS) into one monotonic clock in seconds.

    The first boot segment keeps its own time (t_s = time since boot). When the boot time
    falls back by more than REBOOT_BACKSTEP_S the source restarted: later segments are
    shifted to start REBOOT_GAP_S after the previous one ended, so that sorting and
    interpolation never mix two boots. ``restarts_t_s`` records where each began;
    ``offset_s`` is the current boot's shift (offline readers subtract it at the end so that
    the last boot, normally the flight, keeps its own time_boot_ms).
    """

    __slots__ = ("offset_s", "_max_boot_s", "restarts_t_s")

    def __init__(self) -> None:
        self.offset_s = 0.0
        self._max_boot_s = -math.inf
        self.restarts_t_s: list[float] = []

    def to_s(self, boot_s: float) -> float:
        if boot_s < self._max_boot_s - REBOOT_BACKSTEP_S:
            self.offset_s += self._max_boot_s + REBOOT_GAP_S
            self._max_boot_s = boot_s
            self.restarts_t_s.append(boot_s + self.offset_s)
        self._max_boot_s = max(self._max_boot_s, boot_s)
        return boot_s + self.offset_s

    @property
    def now_s(self) -> float:
        """The latest time seen (NaN before the first)."""
        return self._max_boot_s + self.offset_s if math.isfinite(self._max_boot_s) else math.nan


COMPONENT_CLOCK_WINDOW_S = 5.0
"""How far back (in the component's own clock, s) ``ComponentClock`` looks for its offset:
bounds what a drifting crystal (100 ppm: 0.5 ms) or one delayed message can do to it."""


class ComponentClock:
    """Maps one component's boot times onto the autopilot's clock, causally.

    For each message with a boot time, the apparent offset d = ap_now_s - own_t_s, where
    own_t_s is the component's time (its own BootClock, s) and ap_now_s the autopilot
    clock's latest time when the message arrived: the arrival time read on the autopilot's
    clock, which needs neither the receiver's clock nor real-time pacing (a log replayed
    25x, a tlog stamped in simulated time). ap_now_s only ever lags the true autopilot time
    at arrival (its newest message is some milliseconds old: staleness >= 0), and the
    component stamped its message before it arrived (latency >= 0), so
    d = offset + latency - staleness. The estimate is the largest d over the last
    COMPONENT_CLOCK_WINDOW_S of the component's clock: the message whose reference was
    freshest, as NTP keeps the sample of least delay. A median of d is biased early by the
    typical staleness (25 ms in the simulator: up to 1.5 deg of image rotation in a
    60 deg/s turn); the maximum is off by the component's latency only.

    The window restarts when the component's clock restarts (it reboots: its BootClock
    shifts it 60 s on). An autopilot restart moves ap_now forward, which the maximum takes
    at once; while the autopilot is silent, the stale d values are smaller and change
    nothing. Until the first autopilot time there is no offset: NaN (the message is not
    used).
    """

    __slots__ = ("window_s", "clock", "_window")

    def __init__(self, window_s: float = COMPONENT_CLOCK_WINDOW_S) -> None:
        self.window_s = window_s
        self.clock = BootClock()
        self._window: deque[tuple[float, float]] = deque()  # (own_t_s, d), d decreasing

    def to_autopilot_s(self, boot_s: float, ap_now_s: float) -> float:
        """The autopilot-clock time (s) of a message stamped ``boot_s`` (the component's
        boot time, s) that arrived when the autopilot's latest time was ``ap_now_s`` (NaN
        before any); NaN while no offset is known."""
        restarts = len(self.clock.restarts_t_s)
        own_t = self.clock.to_s(boot_s)
        w = self._window
        if len(self.clock.restarts_t_s) != restarts:
            w.clear()
        if math.isfinite(ap_now_s):
            d = ap_now_s - own_t
            while w and w[-1][1] <= d:
                w.pop()
            w.append((own_t, d))
        while w and w[0][0] < own_t - self.window_s:
            w.popleft()
        return own_t + w[0][1] if w else math.nan

    @property
    def offset_s(self) -> float:
        """The current estimate (autopilot time = component time + offset_s), NaN if none."""
        return self._window[0][1] if self._window else math.nan


class VehicleClock:
    """Times (s, the autopilot's clock) of one vehicle's messages, fed in arrival order.

    ``autopilot_component``: the MAVLink component of the autopilot (normally 1)."""

    __slots__ = ("autopilot_component", "autopilot", "components")

    def __init__(self, autopilot_component: int) -> None:
        self.autopilot_component = autopilot_component
        self.autopilot = BootClock()
        self.components: dict[int, ComponentClock] = {}

    def time_s(self, component: int, boot_s: float | None) -> float:
        """The time of a message from ``component`` with boot time ``boot_s`` (s; None for a
        message that carries none). NaN when it cannot be placed yet."""
        if boot_s is None:
            return self.autopilot.now_s
        if component == self.autopilot_component:
            return self.autopilot.to_s(boot_s)
        clock = self.components.get(component)
        if clock is None:
            clock = self.components[component] = ComponentClock()
        return clock.to_autopilot_s(boot_s, self.autopilot.now_s)

    def autopilot_boot_s(self, boot_s: float) -> float:
        """A time another party read off the autopilot's boot clock (``boot_s``, s: a
        detector's frame time, recorded_frames), placed with the current boot's offset as
        the autopilot's own times are. The clock does not move: such a time says nothing of
        when it was sent."""
        return boot_s + self.autopilot.offset_s
