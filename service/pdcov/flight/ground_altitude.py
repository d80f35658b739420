"""The ENU origin's ground altitude on the link (m MSL), and how it was found: ``GroundAltitude``.

Told the autopilot's HOME_POSITIONs, HEARTBEATs and first position (times in the autopilot
clock, s), it gives the configured altitude, else the home in force at arming, else -- after
``home_wait_s`` of autopilot time -- the latest home, else the first position's altitude
minus its height above home (``frame_policy``'s fallbacks, which ``pdcov evaluate`` applies
to a whole log); None while it waits.
"""

from __future__ import annotations

import math

from pdcov.telemetry.frame_policy import home_ground_alt, position_ground_alt
from pdcov.telemetry.samples import HeartbeatSample, HomeSample, PositionSample

__all__ = ["GroundAltitude"]


class GroundAltitude:
    """The ground altitude's evidence so far. configured_m: the mission's value (None: from
    the autopilot), configured_how: where it came from ('configured', 'the DEM at the
    origin'); home_wait_s: how long (autopilot clock, s) to wait for a home."""

    def __init__(self, configured_m: float | None, home_wait_s: float,
                 configured_how: str = "configured") -> None:
        self.configured_m = configured_m
        self.configured_how = configured_how
        self.home_wait_s = home_wait_s
        self.homes: list[HomeSample] = []
        self.first_position: PositionSample | None = None
        self.armed_t_s: float | None = None
        self.heartbeats = False

    def add_home(self, home: HomeSample) -> None:
        self.homes.append(home)

    def add_heartbeat(self, hb: HeartbeatSample) -> None:
        self.heartbeats = True
        if hb.armed and self.armed_t_s is None:
            self.armed_t_s = hb.t_s

    def add_position(self, p: PositionSample) -> None:
        if self.first_position is None and math.isfinite(p.relative_alt_m):
            self.first_position = p

    def ground_alt(self, newest_t_s: float) -> tuple[float | None, str]:
        """The ground altitude (m MSL) and how it was found, or None while waiting;
        ``newest_t_s``: the newest sample waiting for the tracker (-inf: none).

        ArduPilot resets home at arming, and ``pdcov evaluate`` takes a log's last
        HOME_POSITION; live, the home in force at arming is taken: the latest HOME_POSITION
        sent from 2 s before the first armed HEARTBEAT on, waiting home_wait_s (autopilot
        clock) for it; samples wait until the vehicle arms. No such home, or no HEARTBEAT
        at all (a bare replay): after home_wait_s the latest home, else the first
        position's altitude minus its height above home."""
        if self.configured_m is not None:
            return self.configured_m, self.configured_how
        wait = self.home_wait_s
        now = max(newest_t_s, self.homes[-1].t_s if self.homes else -math.inf)
        armed = self.armed_t_s
        if armed is not None:
            at_arming = [h for h in self.homes if h.t_s >= armed - 2.0]
            if at_arming:
                return at_arming[-1].alt_msl_m, ("the autopilot's home at arming "
                                                 "(HOME_POSITION)")
            if now < armed + wait:
                return None, ""
        elif (self.heartbeats or self.first_position is None
              or now < self.first_position.t_s + wait):
            return None, ""
        home = home_ground_alt(self.homes)
        if home is not None:
            return home
        p = self.first_position
        if p is None:
            return None, ""
        return position_ground_alt(p.alt_msl_m, p.relative_alt_m)
