"""The ENU origin's ground altitude on the link (m MSL), and how it was found: ``GroundAltitude``.

Told the autopilot's homes, armed state and first position (times in the autopilot clock,
s), it gives the configured altitude, else the home in force at arming, else -- after
``home_wait_s`` of autopilot time -- the latest home, else the first position's altitude
minus its height above home (``frame_policy``'s fallbacks); None while it waits. The daemon
feeds it the link's HOME_POSITIONs, HEARTBEATs and positions and asks it until it answers;
``pdcov evaluate`` feeds it a log's the same way (flight/log_frames.ground_alt_of_log).
"""

from __future__ import annotations

import math

from pdcov.telemetry.frame_policy import HOME_SOURCES, home_ground_alt, position_ground_alt
from pdcov.telemetry.samples import HeartbeatSample, HomeSample, PositionSample

__all__ = ["DEFAULT_HOME_WAIT_S", "GroundAltitude"]

DEFAULT_HOME_WAIT_S = 5.0
"""Autopilot seconds to wait for a home (service.home_wait_s's default)."""


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
        self.add_armed_state(hb.t_s, hb.armed)

    def add_armed_state(self, t_s: float, armed: bool) -> None:
        """The autopilot's armed state at ``t_s`` (a HEARTBEAT's base_mode, a log's arming
        records): from now on it says whether the vehicle armed."""
        self.heartbeats = True
        if armed and self.armed_t_s is None:
            self.armed_t_s = t_s

    def add_position(self, p: PositionSample) -> None:
        if self.first_position is None and math.isfinite(p.relative_alt_m):
            self.first_position = p

    def ground_alt(self, newest_t_s: float, *, ended: bool = False
                   ) -> tuple[float | None, str]:
        """The ground altitude (m MSL) and how it was found, or None while waiting;
        ``newest_t_s``: the newest sample waiting for the tracker (-inf: none); ``ended``:
        no more evidence will come (a log's end): no more waiting.

        ArduPilot resets home at arming, so the home in force at arming is taken: the
        latest HOME_POSITION sent from 2 s before the first armed HEARTBEAT on, waiting
        home_wait_s (autopilot clock) for it; samples wait until the vehicle arms (a log
        that ended first: as after the wait). No such home, or no HEARTBEAT
        at all (a bare replay): after home_wait_s the latest home, else the first
        position's altitude minus its height above home. Several homes at arming: the
        latest of the best source (frame_policy.HOME_SOURCES)."""
        if self.configured_m is not None:
            return self.configured_m, self.configured_how
        wait = self.home_wait_s
        now = max(newest_t_s, self.homes[-1].t_s if self.homes else -math.inf)
        armed = self.armed_t_s
        if armed is not None:
            at_arming = [h for h in self.homes if h.t_s >= armed - 2.0]
            if at_arming:
                source = min((h.source for h in at_arming), key=_source_rank)
                home = [h for h in at_arming if h.source == source][-1]
                return home.alt_msl_m, f"the autopilot's home at arming ({source})"
            if now < armed + wait and not ended:
                return None, ""
        elif not ended and (self.heartbeats or self.first_position is None
                            or now < self.first_position.t_s + wait):
            return None, ""
        latest = home_ground_alt(self.homes)
        if latest is not None:
            return latest
        p = self.first_position
        if p is None:
            return None, ""
        return position_ground_alt(p.alt_msl_m, p.relative_alt_m)


def _source_rank(source: str) -> int:
    """A home source's rank, best first (frame_policy.HOME_SOURCES; others last)."""
    return HOME_SOURCES.index(source) if source in HOME_SOURCES else len(HOME_SOURCES)
