"""Which Zenoh session speaks for a vehicle (docs/ground-station.md "Who speaks for a
vehicle"), with no I/O: sessions and ``now_s`` in, verdicts out.

On a bus without access control anyone may publish on ``pdcov/<id>/...``. Zenoh tells a
subscriber which session a sample came from (the daemon puts ``source_info`` on its status
and tiles, and every query reply carries its replier's id), so the watcher pins each vehicle
to the one session that answered its snapshot query and refuses the status and tiles of any
other session. A session id is the Zenoh session id as hex text (None: the sample said
none, which the daemon never does).

* The first snapshot query answered by one session pins the vehicle to it.
* A sample from another session is refused and counted, that session is remembered as a
  rival for ``rival_memory_s``, and the claim is checked again (a new snapshot query) at
  most every ``recheck_s``: a daemon that restarted opens a new session, and the old one no
  longer answers.
* A query answered by two or more sessions is contested: no session is trusted for the
  vehicle until a later query is answered by one session only, and the operator is told.

This stops a forger using a stock Zenoh library (which stamps its own session id); a
modified library could stamp another's, and only TLS with access control stops that
(docs/reliability.md). The watcher's status cross-check (watcher.py) catches forged tiles
that pass the pin.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from pdcov.bus.sources import SessionId

__all__ = ["ClaimVerdict", "SessionClaim", "short_session"]


class ClaimVerdict(Enum):
    """What to do with a sample from a session."""

    TAKE = "take"  # from the pinned session, or nothing is pinned yet and nobody contests
    REFUSE = "refuse"  # another session's, or the vehicle is contested


def short_session(session: SessionId) -> str:
    """A session id as shown to the operator: its first 8 hex digits ("?" for none)."""
    return "?" if session is None else session[:8]


@dataclass(slots=True)
class SessionClaim:
    """The session pinned for one vehicle, its rivals and whether it is contested.

    recheck_s: least time between two claim checks caused by rival samples. rival_memory_s:
    how long a rival session is shown after its last sample."""

    recheck_s: float = 10.0
    rival_memory_s: float = 30.0
    pinned: bool = False
    session: SessionId = None
    contested: tuple[SessionId, ...] = ()
    refused: int = 0
    sessions_seen: set[SessionId] = field(default_factory=set)
    _rivals: dict[SessionId, float] = field(default_factory=dict)
    _recheck_at_s: float = float("-inf")

    def verdict(self, session: SessionId, now_s: float) -> ClaimVerdict:
        """Whether to take a status or tiles sample from ``session``. Before the first
        snapshot answer every session's samples are taken provisionally (the snapshot then
        decides which were right)."""
        if self.contested:
            self._refuse(session, now_s)
            return ClaimVerdict.REFUSE
        if not self.pinned or session == self.session:
            self.sessions_seen.add(session)
            return ClaimVerdict.TAKE
        self._refuse(session, now_s)
        return ClaimVerdict.REFUSE

    def recheck_due(self, now_s: float) -> bool:
        """A rival was heard and the last check is recheck_s old: ask the snapshot again
        (the caller does; this call starts the next recheck_s)."""
        if not self.pinned or not self._rivals or now_s < self._recheck_at_s:
            return False
        self._recheck_at_s = now_s + self.recheck_s
        return True

    def on_answers(self, sessions: set[SessionId], now_s: float) -> bool:
        """A snapshot query was answered by ``sessions`` (at least one). Returns whether
        exactly one answered, which is then the pinned session; two or more contest the
        vehicle until a query is answered by one."""
        self.sessions_seen.update(sessions)
        if len(sessions) > 1:
            self.pinned, self.session = False, None
            self.contested = tuple(sorted(sessions, key=lambda s: s or ""))
            for s in sessions:
                self._rivals[s] = now_s
            return False
        (only,) = sessions
        self.pinned, self.session, self.contested = True, only, ()
        self._rivals.pop(only, None)
        return True

    def rivals(self, now_s: float) -> tuple[SessionId, ...]:
        """Sessions other than the pinned one heard within rival_memory_s, sorted."""
        for s, t in list(self._rivals.items()):
            if now_s - t > self.rival_memory_s:
                del self._rivals[s]
        return tuple(sorted((s for s in self._rivals if s != self.session or not self.pinned),
                            key=lambda s: s or ""))

    def _refuse(self, session: SessionId, now_s: float) -> None:
        self.refused += 1
        self.sessions_seen.add(session)
        self._rivals[session] = now_s
