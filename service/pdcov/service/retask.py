"""Re-tasking decisions of the daemon, with no I/O: a ground station's signed mission
request (queryable ``pdcov/<id>/retask``, bus/retask.py) is refused or uploaded to the
autopilot over the daemon's own link, and answered once the autopilot has said yes or no.

What is decided here: whether a request is taken (``service.retask`` enabled; who sent it
and when: service/retask_auth.py; its items inside ``service.retask_limits``:
planning/mission_bounds.py; the autopilot known, no upload already running: otherwise
refused with a ``RetaskRefusal``, logged and counted); the upload itself
(``MissionUpload``, the machine ``pdcov upload`` runs; ArduPilot gets the home item first:
``with_home``); once the autopilot accepted it, a STATUSTEXT (NOTICE) to the pilot naming
the key and the item count; the reply and the status's ``retask`` object. The messages go
out through ``LinkProtocol.checked``, which lets only MISSION_COUNT, MISSION_ITEM_INT and
STATUSTEXT through for this: the daemon never arms, takes off or changes the flight mode;
the pilot does.

Requests are named by a ``ticket`` the shell chooses (it keeps the Zenoh query under it
until ``replies()`` hands back the answer for it).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from shapely.geometry import Polygon

from pdcov.bus.retask import RetaskRequest, encode_retask_reply
from pdcov.core.geodesy import Origin
from pdcov.planning.mission_bounds import RetaskLimits, check_mission_bounds
from pdcov.planning.plan_items import home_item
from pdcov.service.retask_auth import NonceBook, Refused, RetaskAuthority, RetaskRefusal
from pdcov.telemetry.link_protocol import LinkProtocol
from pdcov.telemetry.mission_upload import MissionUpload, with_home

__all__ = ["MISSION_MESSAGES", "RetaskPolicy", "RetaskRefusal", "Retasker", "pilot_notice"]

MISSION_MESSAGES = frozenset({"MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"})
"""What the autopilot answers an upload with (the rest of the link is not the upload's)."""


@dataclass(frozen=True, slots=True)
class RetaskPolicy:
    """Who may re-task and where to: ``enabled`` (service.retask), ``authority`` (the keys
    and the window; None only when disabled), the limits and the domain boundary they grow
    (ENU m)."""

    enabled: bool
    authority: RetaskAuthority | None
    limits: RetaskLimits = field(default_factory=RetaskLimits)
    boundary_enu_m: Polygon = field(default_factory=Polygon)


def pilot_notice(n_items: int, key_id: str) -> str:
    """The STATUSTEXT the pilot gets for a mission uploaded (at most 50 characters)."""
    return f"pdcov: mission {n_items} items key {key_id[:8]} ok"[:50]


@dataclass(slots=True)
class _Running:
    ticket: int
    request: RetaskRequest
    session: str | None
    upload: MissionUpload
    started_uptime_s: float
    started_unix_s: float


class Retasker:
    """One daemon's re-tasking (module docstring). ``vehicle_id``: the key's vehicle;
    ``started_s``: the daemon's start on its monotonic clock (the status gives times as
    uptime s); ``nonces``: the nonces seen (read back at start); ``retry_s``: silence before
    the upload resends its last message."""

    def __init__(self, vehicle_id: str, policy: RetaskPolicy, started_s: float,
                 nonces: NonceBook | None = None, retry_s: float = 1.5) -> None:
        self.vehicle_id = vehicle_id
        self.policy = policy
        self.nonces = nonces or NonceBook()
        self._started_s = started_s
        self._retry_s = retry_s
        self._running: _Running | None = None
        self._replies: list[tuple[int, bytes]] = []
        self.logs: list[tuple[int, str]] = []
        self.refused: Counter[RetaskRefusal] = Counter()
        self.last: dict[str, Any] | None = None

    @property
    def busy(self) -> bool:
        return self._running is not None

    def request(self, ticket: int, payload: bytes, key_expr: str, session: str | None,
                now_s: float, unix_s: float, protocol: LinkProtocol, home: Origin
                ) -> list[Any]:
        """A query's payload on ``key_expr`` (its own key expression) from Zenoh session
        ``session`` (None: it named none; for the log only) at ``now_s`` (monotonic) and
        ``unix_s`` (UTC); ``home``: the origin with the ground altitude in use. The
        messages to send to the autopilot (none when refused: the reply is ready)."""
        who = f"session {session or 'unnamed'}"
        policy = self.policy
        if not policy.enabled or policy.authority is None:
            return self._refuse(ticket, Refused(RetaskRefusal.DISABLED,
                                                _WHY[RetaskRefusal.DISABLED]), who)
        req = policy.authority.admit(payload, key_expr, unix_s, self.nonces)
        if isinstance(req, Refused):
            return self._refuse(ticket, req, who)
        bounds = check_mission_bounds(req.items, policy.boundary_enu_m, home, policy.limits)
        if not bounds.ok:
            return self._refuse(ticket, Refused(RetaskRefusal.OUT_OF_BOUNDS, bounds.text(),
                                                req.plan_hash), who)
        if (protocol.system_id is None or protocol.autopilot_component is None
                or protocol.autopilot_type is None):
            return self._refuse(ticket, Refused(RetaskRefusal.NO_AUTOPILOT,
                                                _WHY[RetaskRefusal.NO_AUTOPILOT],
                                                req.plan_hash), who)
        if self._running is not None:
            return self._refuse(ticket, Refused(
                RetaskRefusal.BUSY, f"{_WHY[RetaskRefusal.BUSY]} "
                f"({self._running.request.plan_hash})", req.plan_hash), who)
        items = with_home(req.items, home_item(home), protocol.autopilot_type)
        upload = MissionUpload(items, protocol.system_id, protocol.autopilot_component,
                               protocol.mav, retry_s=self._retry_s,
                               own_ids=(protocol.mav.srcSystem, protocol.mav.srcComponent))
        self._running = _Running(ticket, req, session, upload, self._uptime(now_s), unix_s)
        self.logs.append((logging.WARNING, (
            f"re-tasking: uploading mission {req.plan_hash} ({len(items)} items: "
            f"{req.description}) signed by key {req.key_id}, from {who}, to the autopilot; "
            "the pilot keeps the mode")))
        return protocol.checked(upload.start(now_s))

    def receive(self, msg: Any, now_s: float, protocol: LinkProtocol) -> list[Any]:
        """A message from the link; what the upload sends in answer."""
        run = self._running
        if run is None or msg.get_type() not in MISSION_MESSAGES:
            return []
        return protocol.checked(run.upload.receive(msg, now_s)) + self._finish(now_s, protocol)

    def poll(self, now_s: float, protocol: LinkProtocol) -> list[Any]:
        """Resends due at ``now_s`` (and the timeout's end)."""
        run = self._running
        if run is None:
            return []
        return protocol.checked(run.upload.poll(now_s)) + self._finish(now_s, protocol)

    def next_timer_s(self) -> float:
        run = self._running
        return run.upload.deadline_s if run is not None else float("inf")

    def replies(self) -> list[tuple[int, bytes]]:
        """(ticket, reply payload) of the requests answered since the last call."""
        out, self._replies = self._replies, []
        return out

    def describe(self) -> dict[str, Any] | None:
        """The status's ``retask`` object (None until a request came): whether enabled,
        an upload running, refusals by reason, the last request's outcome."""
        if self.last is None and not self.refused and self._running is None:
            return None
        return {"enabled": self.policy.enabled, "uploading": self._running is not None,
                "refused": {str(k): n for k, n in sorted(self.refused.items())},
                "last": self.last}

    def _uptime(self, now_s: float) -> float:
        return round(now_s - self._started_s, 3)

    def _refuse(self, ticket: int, refused: Refused, who: str) -> list[Any]:
        why = refused.reason
        self.refused[why] += 1
        name = "" if refused.plan_hash is None else f" {refused.plan_hash}"
        self.logs.append((logging.WARNING, f"re-tasking request{name} from {who} refused "
                          f"({why}): {refused.detail}"))
        self._replies.append((ticket, encode_retask_reply(
            self.vehicle_id, refused.plan_hash, False, str(why), refused.detail, 0)))
        return []

    def _finish(self, now_s: float, protocol: LinkProtocol) -> list[Any]:
        """Once the upload ended: the reply, the status, the log, and for a mission
        accepted, the pilot's STATUSTEXT."""
        run = self._running
        if run is None or run.upload.result is None:
            return []
        r, req = run.upload.result, run.request
        self._running = None
        self.last = {"plan_hash": req.plan_hash, "key_id": req.key_id, "session": run.session,
                     "started_uptime_s": run.started_uptime_s,
                     "started_unix_s": round(run.started_unix_s, 3),
                     "ended_uptime_s": self._uptime(now_s), "items": r.n_items,
                     "accepted": r.accepted, "result": r.result}
        self.logs.append((logging.WARNING if r.accepted else logging.ERROR,
                          f"re-tasking: mission {req.plan_hash} (key {req.key_id}): "
                          f"{r.report()}"))
        self._replies.append((run.ticket, encode_retask_reply(
            self.vehicle_id, req.plan_hash, r.accepted, r.result, r.report(), r.n_items)))
        return protocol.notice(pilot_notice(r.n_items, req.key_id)) if r.accepted else []


_WHY = {RetaskRefusal.DISABLED: "re-tasking is off on this vehicle (service.retask: false)",
        RetaskRefusal.NO_AUTOPILOT: "no autopilot heard on the link yet",
        RetaskRefusal.BUSY: "an upload is in progress"}
