"""The command path of issue 34, measured for ``python -m benchmarks.hostile_bus``: the
red team's re-tasking requests sent to the daemon's decisions (``ServiceCore`` with
``service.retask: true`` and one operator key, tests/support/retask_harness.py) with an autopilot
stand-in answering the mission protocol. Each case returns (finding, red team's figure,
now, holds): holds when the daemon refused with the expected reason and not one mission
message reached the autopilot, or, for the signed in-bounds plan, when the autopilot got
it and the pilot's STATUSTEXT.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

from pdcov.bus.retask import decode_retask_reply
from pdcov.core.mission import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_MISSION,
    MissionItem,
)
from pdcov.service.retask_auth import RetaskRefusal
from tests.support.retask_harness import FAR, ITEMS, WP, Autopilot, core_with, fly, heard
from tests.support.retask_keys import OTHER, UNIX_S, signed

Case = tuple[str, str, str, bool]
ACCEPTED = "ACCEPTED"


def _up(z_m: float) -> MissionItem:
    return MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                       lat_deg=WP.lat_deg, lon_deg=WP.lon_deg, z_m=z_m)


def _send(tmp: Path, payload: bytes, key_expr: str = "pdcov/fuzz/retask",
          core=None) -> tuple[str, Autopilot]:
    """The reply's reason (ACCEPTED when taken) and what the autopilot got."""
    core = core or core_with(tmp, retask=True)
    heard(core)
    autopilot = Autopilot()
    replies, _logs = fly(core, autopilot, payload, "e7" * 16, key_expr=key_expr)
    reply = decode_retask_reply(replies[0][1])
    return (ACCEPTED if reply.accepted else reply.reason), autopilot


def _mission_messages(autopilot: Autopilot) -> int:
    """MISSION_* messages the daemon sent the autopilot."""
    return sum(m.get_type().startswith("MISSION") for m in autopilot.sent)


def _refused(name: str, before: str, payload: bytes, expected: RetaskRefusal,
             key_expr: str = "pdcov/fuzz/retask") -> Case:
    with tempfile.TemporaryDirectory() as d:
        why, autopilot = _send(Path(d), payload, key_expr)
    to_autopilot = _mission_messages(autopilot)
    return (name, before, f"refused {why}, {to_autopilot} mission messages to the autopilot",
            why == expected and to_autopilot == 0)


def retask_cases() -> Iterator[Case]:
    yield _refused("re-task through a wildcard key (pdcov/**)",
                   "accepted: the autopilot took a take-off to 5,000 m, 5 km away",
                   signed(ITEMS), RetaskRefusal.WILDCARD, "pdcov/**")
    yield _refused("re-task through a wildcard key (pdcov/uav1/ret$*)", "accepted",
                   signed(ITEMS), RetaskRefusal.WILDCARD, "pdcov/fuzz/ret$*")
    yield _refused("unsigned request (any session on an open bus)", "uploaded",
                   b'{"schema":"pdcov.retask","version":1}', RetaskRefusal.UNSIGNED)
    yield _refused("request signed by a key the vehicle does not list",
                   "uploaded (the allow-list named the ground station's session id)",
                   signed(ITEMS, key=OTHER), RetaskRefusal.UNKNOWN_KEY)
    yield _refused("signed request 10 min old", "(no time in requests)",
                   signed(ITEMS, unix_s=UNIX_S - 600), RetaskRefusal.STALE)
    yield _refused("items 100 km away", "uploaded", signed((WP, FAR)),
                   RetaskRefusal.OUT_OF_BOUNDS)
    yield _refused("a waypoint at 20,000 m", "uploaded", signed((_up(20000.0),)),
                   RetaskRefusal.OUT_OF_BOUNDS)
    yield _refused("a waypoint at -1,000 m", "uploaded", signed((_up(-1000.0),)),
                   RetaskRefusal.OUT_OF_BOUNDS)
    yield _refused("a take-off to 5,000 m", "accepted by the autopilot", signed(
        (MissionItem(MAV_CMD_NAV_TAKEOFF, MAV_FRAME_GLOBAL_RELATIVE_ALT, z_m=5000.0),)),
        RetaskRefusal.OUT_OF_BOUNDS)
    yield _refused("a speed of 1e7 m/s", "uploaded", signed(
        (MissionItem(MAV_CMD_DO_CHANGE_SPEED, MAV_FRAME_MISSION, 1.0, 1e7, -1.0), WP)),
        RetaskRefusal.OUT_OF_BOUNDS)
    with tempfile.TemporaryDirectory() as d:
        core = core_with(Path(d), retask=True)
        payload = signed(ITEMS)
        first, autopilot = _send(Path(d), payload, core=core)
        notice = [m.text for m in autopilot.sent if m.get_type() == "STATUSTEXT"]
        yield ("signed in-bounds plan", "(no signatures)",
               f"{first}, {len(autopilot.items)} items to the autopilot, pilot told "
               f"{notice[:1]}", first == ACCEPTED and bool(autopilot.items) and bool(notice))
        again, replayed = _send(Path(d), payload, core=core)
        yield ("the same signed request again (replay)", "uploaded again",
               f"refused {again}, {_mission_messages(replayed)} mission messages to the "
               "autopilot", again == RetaskRefusal.REPLAYED and not _mission_messages(replayed))
