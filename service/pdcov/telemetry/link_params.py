"""Autopilot parameters over a live MAVLink link: find the autopilot, read parameters by name.

Edge module: blocking pymavlink I/O on a connection the caller opened (UDP, TCP, serial)
and the monotonic clock for timeouts. The parameter protocol (mavlink.io/en/services/
parameter.html): PARAM_REQUEST_READ with param_index -1 asks for one parameter by its name
(param_id, at most 16 characters); the autopilot answers with PARAM_VALUE, or with nothing
when it has no such parameter (ArduPilot), so a name without a reply is only "missing".

Values are returned as PARAM_VALUE carries them: ArduPilot casts every parameter to float
(MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT). PX4 packs integers bytewise; the ArduPilot mount
parameters read here do not exist there.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from pdcov.errors import TelemetryError
from pdcov.telemetry.adapters import is_autopilot_heartbeat
from pdcov.telemetry.gimbal import (
    legacy_mount_param_names,
    mount_param_names,
    mount_params_to_read,
)

PARAM_ID_MAX_CHARS = 16
MAV_COMP_ID_ALL = 0
HEARTBEAT_PERIOD_S = 1.0
"""How often ``wait_autopilot`` sends the ground station's HEARTBEAT (MAVLink: 1 Hz)."""

__all__ = ["ParamRead", "legacy_mount_param_names", "mount_param_names", "read_mount_params",
           "read_params", "wait_autopilot", "wait_autopilot_heartbeat"]
"""(the mount parameter names are gimbal.py's, re-exported for the callers of this module)"""


@dataclass(frozen=True, slots=True)
class ParamRead:
    """Parameters asked for by name and the values the autopilot answered with."""

    requested: tuple[str, ...]
    values: Mapping[str, float]

    @property
    def missing(self) -> tuple[str, ...]:
        """The names asked for that got no reply, in the order asked."""
        return tuple(n for n in self.requested if n not in self.values)


def wait_autopilot(conn: mavutil.mavfile, timeout_s: float, *,
                   system_id: int | None = None) -> tuple[int, int]:
    """(system id, component id) of the first autopilot HEARTBEAT on ``conn``
    (``wait_autopilot_heartbeat``)."""
    msg = wait_autopilot_heartbeat(conn, timeout_s, system_id=system_id)
    return msg.get_srcSystem(), msg.get_srcComponent()


def wait_autopilot_heartbeat(conn: mavutil.mavfile, timeout_s: float, *,
                             system_id: int | None = None) -> mavlink2.MAVLink_heartbeat_message:
    """The first autopilot HEARTBEAT on ``conn``, from ``system_id`` if given. Heartbeats of
    ground stations (MAV_TYPE_GCS) and of components that are no autopilot
    (MAV_AUTOPILOT_INVALID: gimbals, cameras, companions) are ignored.
    Sends our own ground-station HEARTBEAT each second meanwhile: on a udpout: link the
    vehicle learns our address from it. Raises TelemetryError after ``timeout_s`` seconds."""
    t_end = time.monotonic() + timeout_s
    next_beat = 0.0
    ignored: set[tuple[int, int]] = set()
    while (now := time.monotonic()) < t_end:
        if now >= next_beat:
            conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID,
                                    0, 0, 0)
            next_beat = now + HEARTBEAT_PERIOD_S
        msg = conn.recv_match(type="HEARTBEAT", blocking=True,
                              timeout=min(t_end, next_beat) - now)
        if msg is None:
            continue
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if not is_autopilot_heartbeat(msg, system_id):
            ignored.add(source)
            continue
        return msg
    of_system = f" of system {system_id}" if system_id is not None else ""
    heard = ", ".join(f"system {s} component {c}" for s, c in sorted(ignored))
    raise TelemetryError(f"no HEARTBEAT of an autopilot{of_system} on {conn.address} within "
                         f"{timeout_s:g} s" + (f" (ignored: {heard})" if heard else ""))


def read_params(conn: mavutil.mavfile, names: Iterable[str], *, target_system: int,
                target_component: int = 1, timeout_s: float = 3.0,
                retries: int = 2) -> dict[str, float]:
    """Read parameters by name: {name: value} of those the autopilot answered.

    Sends PARAM_REQUEST_READ (param_index -1) for each name, then collects PARAM_VALUE from
    ``target_system`` (and ``target_component`` unless it is 0) matched by param_id, ignoring
    all other traffic. The read takes at most ``timeout_s`` seconds, split into
    ``retries + 1`` equal rounds: each round resends the names still unanswered (a request
    or reply lost on the link). Returns early once every name is answered; what a missing
    name means is for the caller to decide.
    """
    wanted = tuple(dict.fromkeys(names))
    for name in wanted:
        if not 1 <= len(name) <= PARAM_ID_MAX_CHARS or not name.isascii():
            raise ValueError(f"parameter name {name!r}: expected 1..{PARAM_ID_MAX_CHARS} "
                             f"ASCII characters (MAVLink param_id)")
    if retries < 0 or not timeout_s > 0:
        raise ValueError(f"expected timeout_s > 0 and retries >= 0, got {timeout_s!r}, "
                         f"{retries!r}")
    got: dict[str, float] = {}
    t_start = time.monotonic()
    for round_ in range(1, retries + 2):
        for name in wanted:
            if name not in got:
                conn.mav.param_request_read_send(target_system, target_component,
                                                 name.encode("ascii"), -1)
        t_end = t_start + timeout_s * round_ / (retries + 1)
        while len(got) < len(wanted) and (left := t_end - time.monotonic()) > 0:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=left)
            if (msg is None or msg.get_srcSystem() != target_system
                    or target_component not in (MAV_COMP_ID_ALL, msg.get_srcComponent())):
                continue
            if msg.param_id in wanted:
                got.setdefault(msg.param_id, float(msg.param_value))
        if len(got) == len(wanted):
            break
    return got


def read_mount_params(conn: mavutil.mavfile, instance: int, *, target_system: int,
                      target_component: int = 1, timeout_s: float = 3.0,
                      retries: int = 2) -> ParamRead:
    """The mount parameters ``gimbal.resolve_interpretation`` uses, as the autopilot has them:
    ``gimbal.mount_params_to_read(instance)``, the list the daemon asks for too: the 4.3+
    names first; when MNTn_TYPE is unanswered, a second read of the names of older
    firmware. Each read as ``read_params`` (at most ``timeout_s`` seconds)."""
    names, legacy = mount_params_to_read(instance)
    values = read_params(conn, names, target_system=target_system,
                         target_component=target_component, timeout_s=timeout_s,
                         retries=retries)
    if f"MNT{instance}_TYPE" in values or not legacy:
        return ParamRead(names, values)
    values |= read_params(conn, legacy, target_system=target_system,
                          target_component=target_component, timeout_s=timeout_s,
                          retries=retries)
    return ParamRead((*names, *legacy), values)
