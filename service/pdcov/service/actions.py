"""What the daemon's shell should do now: ``Actions``, what ``ServiceCore.actions()``
returns (service/core.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pdcov.service.checkpoint_meta import CheckpointMeta

__all__ = ["Actions"]


@dataclass(slots=True)
class Actions:
    """What the shell should do now, in this order: send these MAVLink messages on every
    link; write these bytes to the recording; publish these tiles; append ``journal`` to
    the candidates journal, flushed and fsynced, and report it back (``journal_written``),
    then publish these detections messages (on pdcov/<id>/detections); if ``status_due``,
    flush
    the recording and publish ``ServiceCore.status``; write this checkpoint (grid and meta)
    and report it back; empty the candidates journal (``journal_reset``, atomically);
    answer these re-tasking queries (ticket, reply payload); write the
    re-tasking nonces seen (``nonces``, to read back at start); log these (level, text)
    lines."""

    send: list[Any] = field(default_factory=list)
    record: list[bytes] = field(default_factory=list)
    tiles: bytes | None = None
    journal: bytes | None = None
    detections: list[bytes] = field(default_factory=list)
    status_due: bool = False
    checkpoint: CheckpointMeta | None = None
    journal_reset: bool = False
    replies: list[tuple[int, bytes]] = field(default_factory=list)
    nonces: bytes | None = None
    logs: list[tuple[int, str]] = field(default_factory=list)
