"""Re-tasking decisions of the daemon, with no I/O: a ground station's mission request
(queryable ``pdcov/<id>/retask``, bus/retask.py) is refused or uploaded to the autopilot
over the daemon's own link, and answered once the autopilot has said yes or no.

What is decided here: whether a request is taken (``service.retask`` enabled, its Zenoh
session on ``service.retask_sessions`` when that list is given, the payload valid and for
this vehicle, the autopilot known, no upload already running: otherwise refused with a
``RetaskRefusal``, logged and counted); the upload itself (``MissionUpload``, the machine
``pdcov upload`` runs; ArduPilot gets the home item first: ``with_home``); the reply and
the status's ``retask`` object. The messages go out through ``LinkProtocol.checked``, which
lets only MISSION_COUNT and MISSION_ITEM_INT through for this: the daemon never arms,
takes off or changes the flight mode; the pilot does.

Requests are named by a ``ticket`` the shell chooses (it keeps the Zenoh query under it
until ``replies()`` hands back the answer for it).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.retask import RetaskRequest, decode_retask, encode_retask_reply
from pdcov.core.mission import MissionItem
from pdcov.service.link_protocol import LinkProtocol
from pdcov.telemetry.frame_policy import TextEnum
from pdcov.telemetry.mission_upload import MissionUpload, with_home

MISSION_MESSAGES = frozenset({"MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"})
"""What the autopilot answers an upload with (the rest of the link is not the upload's)."""


class RetaskRefusal(TextEnum):
    """Why the daemon refused a request without asking the autopilot (the reply's
    ``reason``; docs/protocol.md "retask")."""

    DISABLED = "PDCOV_RETASK_DISABLED"
    """service.retask is false (the default)."""
    NOT_ALLOWED = "PDCOV_SESSION_NOT_ALLOWED"
    """The query's session is not on service.retask_sessions."""
    BAD_REQUEST = "PDCOV_BAD_REQUEST"
    """The payload does not decode (bus/retask.py), or is another vehicle's."""
    NO_AUTOPILOT = "PDCOV_NO_AUTOPILOT"
    """No autopilot heard on the link yet."""
    BUSY = "PDCOV_UPLOAD_IN_PROGRESS"
    """An upload is running: one at a time."""


@dataclass(frozen=True, slots=True)
class RetaskPolicy:
    """Who may re-task: ``enabled`` (service.retask), and ``sessions`` (Zenoh session ids
    as hex text; empty: any session the bus delivers a query from)."""

    enabled: bool = False
    sessions: frozenset[str] = frozenset()

    def refusal(self, session: str | None) -> RetaskRefusal | None:
        if not self.enabled:
            return RetaskRefusal.DISABLED
        if self.sessions and session not in self.sessions:
            return RetaskRefusal.NOT_ALLOWED
        return None


@dataclass(slots=True)
class _Running:
    ticket: int
    request: RetaskRequest
    session: str | None
    upload: MissionUpload
    started_uptime_s: float


class Retasker:
    """One daemon's re-tasking (module docstring). ``vehicle_id``: the key's vehicle;
    ``started_s``: the daemon's start on its monotonic clock (the status gives times as
    uptime s); ``retry_s``: silence before the upload resends its last message."""

    def __init__(self, vehicle_id: str, policy: RetaskPolicy, started_s: float,
                 retry_s: float = 1.5) -> None:
        self.vehicle_id = vehicle_id
        self.policy = policy
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

    def request(self, ticket: int, payload: bytes, session: str | None, now_s: float,
                protocol: LinkProtocol, home: MissionItem) -> list[Any]:
        """A query's payload from Zenoh session ``session`` (None: it named none); the
        messages to send to the autopilot (none when refused: the reply is ready)."""
        who = f"session {session or 'unnamed'}"
        refusal = self.policy.refusal(session)
        if refusal is not None:
            return self._refuse(ticket, None, refusal, f"re-tasking request from {who} "
                                f"refused: {_WHY[refusal]}")
        try:
            req = decode_retask(payload, f"pdcov/{self.vehicle_id}/retask", self.vehicle_id)
        except BusPayloadError as exc:
            return self._refuse(ticket, None, RetaskRefusal.BAD_REQUEST,
                                f"re-tasking request from {who} refused: {exc}", str(exc))
        if (protocol.system_id is None or protocol.autopilot_component is None
                or protocol.autopilot_type is None):
            return self._refuse(ticket, req.plan_hash, RetaskRefusal.NO_AUTOPILOT,
                                f"re-tasking request {req.plan_hash} from {who} refused: "
                                f"{_WHY[RetaskRefusal.NO_AUTOPILOT]}")
        if self._running is not None:
            return self._refuse(ticket, req.plan_hash, RetaskRefusal.BUSY,
                                f"re-tasking request {req.plan_hash} from {who} refused: "
                                f"{_WHY[RetaskRefusal.BUSY]} ({self._running.request.plan_hash}"
                                ")")
        items = with_home(req.items, home, protocol.autopilot_type)
        upload = MissionUpload(items, protocol.system_id, protocol.autopilot_component,
                               protocol.mav, retry_s=self._retry_s,
                               own_ids=(protocol.mav.srcSystem, protocol.mav.srcComponent))
        self._running = _Running(ticket, req, session, upload, self._uptime(now_s))
        self.logs.append((logging.WARNING, (
            f"re-tasking: uploading mission {req.plan_hash} ({len(items)} items: "
            f"{req.description}) from {who} to the autopilot; the pilot keeps the mode")))
        return protocol.checked(upload.start(now_s))

    def receive(self, msg: Any, now_s: float, protocol: LinkProtocol) -> list[Any]:
        """A message from the link; what the upload sends in answer."""
        run = self._running
        if run is None or msg.get_type() not in MISSION_MESSAGES:
            return []
        out = protocol.checked(run.upload.receive(msg, now_s))
        self._finish(now_s)
        return out

    def poll(self, now_s: float, protocol: LinkProtocol) -> list[Any]:
        """Resends due at ``now_s`` (and the timeout's end)."""
        run = self._running
        if run is None:
            return []
        out = protocol.checked(run.upload.poll(now_s))
        self._finish(now_s)
        return out

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

    def _refuse(self, ticket: int, plan: str | None, why: RetaskRefusal, text: str,
                detail: str | None = None) -> list[Any]:
        self.refused[why] += 1
        self.logs.append((logging.WARNING, text))
        self._replies.append((ticket, encode_retask_reply(
            self.vehicle_id, plan, False, str(why), detail or _WHY[why], 0)))
        return []

    def _finish(self, now_s: float) -> None:
        run = self._running
        if run is None or run.upload.result is None:
            return
        r = run.upload.result
        self._running = None
        self.last = {"plan_hash": run.request.plan_hash, "session": run.session,
                     "started_uptime_s": run.started_uptime_s,
                     "ended_uptime_s": self._uptime(now_s), "items": r.n_items,
                     "accepted": r.accepted, "result": r.result}
        self.logs.append((logging.WARNING if r.accepted else logging.ERROR,
                          f"re-tasking: mission {run.request.plan_hash}: {r.report()}"))
        self._replies.append((run.ticket, encode_retask_reply(
            self.vehicle_id, run.request.plan_hash, r.accepted, r.result,
            r.report(), r.n_items)))


_WHY = {RetaskRefusal.DISABLED: "re-tasking is off on this vehicle (service.retask: false)",
        RetaskRefusal.NOT_ALLOWED: "the session is not on service.retask_sessions",
        RetaskRefusal.BAD_REQUEST: "the request does not decode",
        RetaskRefusal.NO_AUTOPILOT: "no autopilot heard on the link yet",
        RetaskRefusal.BUSY: "an upload is in progress"}
