"""Choosing what a log follows: the vehicle (system and autopilot component) among those
seen, and the gimbal (system, component, gimbal_device_id) among those reporting, by the rule
``gimbal.preferred_gimbal_source`` the live tracker applies.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from pdcov.errors import TelemetryError
from pdcov.telemetry.gimbal import preferred_gimbal_source
from pdcov.telemetry.logs.flight_log import FlightLog
from pdcov.telemetry.samples import GimbalSample
from pdcov.telemetry.series import GimbalSeries


def choose_system(autopilots: Mapping[int, int], n_att: Mapping[int, int],
                  seen: list[int], system_id: int | None, path: Path) -> tuple[int, int, str]:
    """(system, autopilot component, note): the configured system, else the one whose
    HEARTBEAT names a real autopilot (``autopilots``: {system: its component}, as
    LinkProtocol follows one), the one sending the most attitude messages (``n_att``) among
    several, else the one sending the most attitudes; ties and alternatives are named in
    the note. ``seen``: every system of the log, sorted."""
    if system_id is not None:
        if system_id not in seen:
            raise TelemetryError(f"{path}: system id {system_id} does not appear in the log; "
                                 f"systems seen: {seen}")
        return system_id, autopilots.get(system_id, 1), (
            f"following system {system_id} (configured); systems seen: {seen}")
    if autopilots:
        sysid = max(autopilots, key=lambda s: (n_att[s], -s))
        how = "its HEARTBEAT names an autopilot"
        if len(autopilots) > 1:
            how += (f"; other autopilots {sorted(set(autopilots) - {sysid})} ignored "
                    "(set the system id to choose)")
        return sysid, autopilots[sysid], f"following system {sysid}: {how}; systems seen: {seen}"
    if not n_att or max(n_att.values()) == 0:
        raise TelemetryError(f"{path}: no autopilot HEARTBEAT and no attitude messages; "
                             f"systems seen: {seen}")
    sysid = max(n_att, key=lambda s: (n_att[s], -s))
    return sysid, 1, (f"following system {sysid}: no autopilot HEARTBEAT, it sends the most "
                      f"attitude messages; systems seen: {seen}")


def choose_gimbal(samples: list[GimbalSample], ap_comp: int, instance: int
                  ) -> tuple[GimbalSeries, tuple[int, int, int] | None, str]:
    if not samples:
        return GimbalSeries.from_samples([]), None, ""
    flags_seen: dict[tuple[int, int, int], int] = defaultdict(int)
    for s in samples:
        flags_seen[s.source] |= s.flags
    source = preferred_gimbal_source(flags_seen, ap_comp, instance)
    chosen = [s for s in samples if s.source == source]
    note = ""
    if len(flags_seen) > 1:
        note = (f"gimbal status from {sorted(flags_seen)} (system, component, device id); "
                f"following {source}")
    return GimbalSeries.from_samples(chosen), source, note


def for_gimbal(log: FlightLog, instance: int) -> FlightLog:
    """``log`` following the gimbal device ``instance`` (a camera's mount.instance) among its
    gimbal reports, by the rule it was read with (``choose_gimbal``): each camera of a
    mission from one reading of the log."""
    gimbal, source, _note = choose_gimbal(list(log.gimbal_reports), log.autopilot_component,
                                          instance)
    return replace(log, gimbal=gimbal, gimbal_source=source)
