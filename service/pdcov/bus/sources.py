"""Which Zenoh session sent a sample, a query or a reply (docs/protocol.md "Sources").

The daemon stamps each status and tiles put with its session's id (``SourcedPublisher``),
a watcher names its session in each query (so that the daemon's rate limit is per watcher),
and every query reply carries its replier's id. Session ids are Zenoh session ids as hex
text; None where the sender named none. Zenoh is imported only where a stamp is made.
"""

from __future__ import annotations

from typing import Any

__all__ = ["SOURCE_SN_MODULO", "SessionId", "SourcedPublisher", "reply_session",
           "source_info", "source_session"]

SessionId = str | None
SOURCE_SN_MODULO = 1 << 32
"""Zenoh's source sequence numbers are 32-bit: a sender's wrap after 2^32 stamps."""


def source_session(item: Any) -> SessionId:
    """The session a sample or a query names in its source info (None: it names none)."""
    info = item.source_info
    return None if info is None else str(info.source_id.zid)


def reply_session(reply: Any) -> SessionId:
    """The session that sent query reply ``reply``."""
    replier = reply.replier_id
    return None if replier is None else str(replier.zid)


def source_info(entity_id: Any, sn: int) -> Any:  # -> zenoh.SourceInfo
    """A source stamp for the entity ``entity_id`` (a publisher's or session's ``id``)."""
    import zenoh

    return zenoh.SourceInfo(entity_id, sn % SOURCE_SN_MODULO)


class SourcedPublisher:
    """A declared Zenoh publisher whose every put carries ``SourceInfo(publisher id, sn)``,
    sn = 0, 1, 2, ... per publisher: the watcher pins a vehicle to the session that publishes
    it (``sample.source_info.source_id.zid`` is this daemon's session, as is the
    ``replier_id`` of its query replies)."""

    def __init__(self, publisher: Any) -> None:
        self.publisher = publisher
        self.sn = 0

    def put(self, payload: bytes) -> None:
        sn, self.sn = self.sn, (self.sn + 1) % SOURCE_SN_MODULO
        self.publisher.put(payload, source_info=source_info(self.publisher.id, sn))

    def undeclare(self) -> None:
        self.publisher.undeclare()
