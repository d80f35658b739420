"""Snapshot replies rate-limited per requester, with no I/O: token buckets fed ``now_s``
(the daemon's monotonic clock, s) that say whether a query is answered (docs/service.md
"Snapshot rate limits").

Why: a snapshot is the whole grid (tens to hundreds of kB over the radio, and an encoding
on the daemon's loop); 8 threads querying it took a core and 0.76 MB/s. Each requester (the
Zenoh session id a querier declares in its query's source info) has a bucket of ``burst``
replies refilled at ``per_requester_hz``; queries without source info share one bucket, as
do newcomers once ``max_requesters`` are followed. All replies together draw on a bucket of
``max_bytes_per_s`` bytes (one second's worth): a query is answered while it holds any
bytes, and the reply's size is then taken from it (it may go below zero, so one snapshot
larger than a second's worth still goes, and the average stays within the cap).

A querier declares its own source info: separate buckets keep well-behaved ground stations
from starving each other, and the byte cap bounds what any number of hostile ones get.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from enum import Enum

from pdcov.errors import ConfigError


class QueryRefusal(str, Enum):
    """Why a query is not answered."""

    REQUESTER_RATE = "requester rate"
    BYTE_RATE = "byte rate"


@dataclass(frozen=True, slots=True)
class QueryLimits:
    """per_requester_hz: replies/s each requester gets on average; burst: replies it may
    take at once; max_bytes_per_s: all replies together, bytes/s on average;
    max_requesters: requesters with a bucket of their own (the rest share the anonymous
    one)."""

    per_requester_hz: float = 1.0
    burst: int = 3
    max_bytes_per_s: int = 128 * 1024
    max_requesters: int = 64

    def __post_init__(self) -> None:
        if not (math.isfinite(self.per_requester_hz) and self.per_requester_hz > 0):
            raise ConfigError(f"per_requester_hz: expected replies/s > 0, got "
                              f"{self.per_requester_hz!r}")
        for name in ("burst", "max_bytes_per_s", "max_requesters"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}: expected an integer >= 1, got "
                                  f"{getattr(self, name)!r}")

    def reason(self, refusal: QueryRefusal) -> str:
        """The reply_err text of a refused query."""
        if refusal is QueryRefusal.REQUESTER_RATE:
            return (f"rate limited: at most {self.per_requester_hz:g} snapshot/s per "
                    f"requester (burst {self.burst}); retry later")
        return (f"rate limited: snapshot replies are capped at {self.max_bytes_per_s} B/s in "
                "all; retry later")


@dataclass(slots=True)
class _Bucket:
    tokens: float
    t_s: float

    def refill(self, now_s: float, rate: float, capacity: float) -> None:
        if now_s > self.t_s:
            self.tokens = min(capacity, self.tokens + rate * (now_s - self.t_s))
            self.t_s = now_s


@dataclass(slots=True)
class QueryLimiter:
    """``admit(requester, now_s)`` before building a reply (None: answer it), ``sent(n)``
    once it is built; ``refused`` counts the refusals by reason."""

    limits: QueryLimits = field(default_factory=QueryLimits)
    refused: Counter[QueryRefusal] = field(default_factory=Counter)
    _buckets: dict[str | None, _Bucket] = field(default_factory=dict)
    _bytes: _Bucket | None = None

    def admit(self, requester: str | None, now_s: float) -> QueryRefusal | None:
        """Whether a query from ``requester`` (a Zenoh session id; None: anonymous) is
        answered at ``now_s``: None, and one reply is taken from its bucket; else why not
        (counted)."""
        lim = self.limits
        if self._bytes is None:
            self._bytes = _Bucket(float(lim.max_bytes_per_s), now_s)
        self._bytes.refill(now_s, lim.max_bytes_per_s, lim.max_bytes_per_s)
        bucket = self._bucket(requester, now_s)
        bucket.refill(now_s, lim.per_requester_hz, lim.burst)
        refusal = (QueryRefusal.REQUESTER_RATE if bucket.tokens < 1.0
                   else QueryRefusal.BYTE_RATE if self._bytes.tokens <= 0.0 else None)
        if refusal is None:
            bucket.tokens -= 1.0
        else:
            self.refused[refusal] += 1
        return refusal

    def sent(self, n_bytes: int) -> None:
        """An admitted reply of ``n_bytes`` bytes went out."""
        if self._bytes is not None:
            self._bytes.tokens -= n_bytes

    def _bucket(self, requester: str | None, now_s: float) -> _Bucket:
        lim = self.limits
        if requester is not None and requester not in self._buckets:
            if len(self._buckets) >= lim.max_requesters:
                # Full buckets are as good as new ones: forget them to make room.
                for key, b in list(self._buckets.items()):
                    b.refill(now_s, lim.per_requester_hz, lim.burst)
                    if b.tokens >= lim.burst and key is not None:
                        del self._buckets[key]
            if len(self._buckets) >= lim.max_requesters:
                requester = None  # still full: a newcomer shares the anonymous bucket
        return self._buckets.setdefault(requester, _Bucket(float(lim.burst), now_s))
