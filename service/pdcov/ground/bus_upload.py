"""``pdcov upload --bus``: a signed re-tasking request sent to one vehicle's daemon over
Zenoh, and its replies (the request is built by ground/retask.py ``signed_request``)."""

from __future__ import annotations

from dataclasses import dataclass

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.retask import RetaskReply, decode_retask_reply
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.sources import SessionId, reply_session


@dataclass(frozen=True, slots=True)
class BusUploadResult:
    """The replies to one request: decoded ones by session, and the refused ones' errors."""

    replies: tuple[tuple[SessionId, RetaskReply], ...]
    errors: tuple[str, ...]

    def verdict(self) -> tuple[bool, str]:
        """(accepted, the line to print): accepted only when exactly one daemon answered
        and its autopilot accepted (two answers: someone else answers for the vehicle)."""
        if not self.replies:
            return False, ("no answer from the vehicle's daemon (not reachable, or the bus's "
                           "access control refused this ground station)"
                           + (f": {'; '.join(self.errors)}" if self.errors else ""))
        lines = [f"session {s}: {'accepted' if r.accepted else 'NOT taken'}: {r.reason}: "
                 f"{r.detail}" for s, r in self.replies]
        if len(self.replies) > 1:
            return False, (f"{len(self.replies)} sessions answered for the vehicle (one is "
                           "not its daemon): " + " | ".join(lines))
        return self.replies[0][1].accepted, lines[0]


def send_retask(bus: BusConfig, vehicle_id: str, payload: bytes, timeout_s: float
                ) -> BusUploadResult:
    """Blocking: ``get pdcov/<vehicle_id>/retask`` with ``payload``, every reply."""
    import zenoh

    key = VehicleKeys(vehicle_id).retask
    session = open_session(bus)
    replies: list[tuple[SessionId, RetaskReply]] = []
    errors: list[str] = []
    try:
        for reply in session.get(key, payload=payload, timeout=timeout_s,
                                 consolidation=zenoh.ConsolidationMode.NONE):
            if reply.ok is None:
                errors.append(str(reply.err.payload.to_string()))
                continue
            try:
                replies.append((reply_session(reply), decode_retask_reply(
                    reply.ok.payload.to_bytes(), key, vehicle_id)))
            except BusPayloadError as exc:
                errors.append(str(exc))
    finally:
        session.close()
    return BusUploadResult(tuple(replies), tuple(errors))
