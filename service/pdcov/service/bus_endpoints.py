"""The daemon's Zenoh endpoints under pdcov/<vehicle id>/ (bus/keys.py, docs/protocol.md):
the status, tiles and detections publishers, the snapshot, footprint, mission, retask and
candidates queryables, the liveliness token and (``frame_source: zenoh``) the frames
subscriber; the replies, the rate-limited ones (query_limit) and re-tasking's.

Threads: Zenoh calls back on its own threads; each callback hands the payload (frames) or
the query to the loop with ``post`` (the shell's ``loop.call_soon_threadsafe``) and returns
at once. Everything else here runs on the loop: no grid is touched off the loop, and no
Zenoh thread waits for the loop (which may be waiting for Zenoh in a put: a deadlock).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from pdcov.bus.footprint import encode_footprint
from pdcov.bus.mission import encode_mission
from pdcov.bus.sources import SourcedPublisher, source_session
from pdcov.bus.tiled_snapshot import encode_grid_snapshot
from pdcov.service.core import ServiceCore
from pdcov.service.settings import ServeConfig
from pdcov.telemetry.frame_policy import FrameSource

__all__ = ["BusEndpoints", "Post"]

log = logging.getLogger("pdcov.serve")
Post = Callable[[Callable[[], object]], object]
"""Hands a call to the event loop from any thread (``loop.call_soon_threadsafe``)."""


class BusEndpoints:
    """The daemon's side of the bus once ``declare``d on a session: ``put`` (a failed one,
    or one before the session, counted by the core) and the queries, answered from ``core``
    with ``clock``'s time (s, monotonic); ``act()`` does what the core then decided."""

    def __init__(self, cfg: ServeConfig, core: ServiceCore, clock: Callable[[], float],
                 act: Callable[[], None]) -> None:
        self.cfg = cfg
        self.core = core
        self.keys = core.keys
        self._clock = clock
        self._act = act
        self.session: Any = None
        self._entities: list[Any] = []
        self.pub_status: SourcedPublisher | None = None
        self.pub_tiles: SourcedPublisher | None = None
        self.pub_detections: SourcedPublisher | None = None
        self._mission_reply: tuple[float | None, bytes] | None = None  # (ground alt, bytes)
        self._snapshot: tuple[int, bytes] | None = None  # (grid frames, bytes)
        self._retask_queries: dict[int, Any] = {}  # ticket -> Zenoh query awaiting its answer
        self._next_ticket = 0

    def declare(self, session: Any, post: Post) -> None:
        """Declare everything on the open ``session``; its callbacks ``post`` to the loop."""
        self.session = s = session
        log.info("zenoh session open")
        self.pub_status = SourcedPublisher(s.declare_publisher(self.keys.status))
        self.pub_tiles = SourcedPublisher(s.declare_publisher(self.keys.tiles))
        self.pub_detections = SourcedPublisher(s.declare_publisher(self.keys.detections))
        self._entities += [
            self.pub_status, self.pub_tiles, self.pub_detections,
            s.declare_queryable(self.keys.snapshot, _on_loop(post, self._reply_snapshot)),
            s.declare_queryable(self.keys.footprint, _on_loop(
                post, lambda q: self._reply(q, self._footprint_bytes))),
            s.declare_queryable(self.keys.mission, _on_loop(
                post, lambda q: self._reply(q, self._mission_bytes))),
            s.declare_queryable(self.keys.retask, _on_loop(post, self._on_retask)),
            s.declare_queryable(self.keys.candidates, _on_loop(post, self._reply_candidates)),
            s.liveliness().declare_token(self.keys.alive),
        ]
        if self.cfg.frame_source == FrameSource.ZENOH:
            self._entities.append(s.declare_subscriber(
                self.keys.frames, lambda sample: post(partial(
                    self.on_frames, sample.payload.to_bytes()))))

    def put(self, pub: SourcedPublisher | None, payload: bytes) -> None:
        if pub is None:  # no session yet (the shell opens it): nobody to publish to
            self.core.put_failed()
            return
        try:
            pub.put(payload)
        except Exception as exc:  # noqa: BLE001 - no peer or a closing session: keep going
            self.core.put_failed()
            log.debug("zenoh put failed: %s", exc)

    def on_frames(self, payload: bytes) -> None:
        """A detector's frames message (on the loop)."""
        self.core.receive_frames(payload)
        self._act()

    @staticmethod
    def _reply(query: Any, make: Callable[[], bytes], key: str | None = None) -> int:
        """On the loop: build the reply, send it (on ``key``, default the query's), finish
        the query; the bytes sent."""
        try:
            payload = make()
            query.reply(key or query.key_expr, payload)
            return len(payload)
        except Exception as exc:  # noqa: BLE001 - a failed reply must not stop the daemon
            log.warning("query %s not answered: %s", query.key_expr, exc)
            return 0
        finally:
            query.drop()

    def _reply_snapshot(self, query: Any) -> None:
        """On the loop: the snapshot, or a ``reply_err`` saying why when the requester or
        all snapshot replies together are over their rate (query_limit; counted in
        faults.snapshot_queries_refused)."""
        self._reply_limited(query, self.core.admit_snapshot, self.core.snapshot_sent,
                            self._snapshot_bytes)

    def _reply_candidates(self, query: Any) -> None:
        """On the loop: every candidate (bus.detections), rate-limited as the snapshot."""
        self._reply_limited(query, self.core.admit_candidates, self.core.candidates_sent,
                            self.core.candidates_payload)

    def _reply_limited(self, query: Any, admit: Callable[[str | None, float], str | None],
                       sent: Callable[[int], None], make: Callable[[], bytes]) -> None:
        refusal = admit(source_session(query), self._clock())
        if refusal is None:
            sent(self._reply(query, make))
            return
        try:
            query.reply_err(refusal)
        except Exception as exc:  # noqa: BLE001 - as _reply
            log.debug("query %s: refusal not sent: %s", query.key_expr, exc)
        finally:
            query.drop()

    def _on_retask(self, query: Any) -> None:
        """On the loop: a re-tasking request; the query is kept until the core answers it
        (refused at once, or once the autopilot has acknowledged the upload)."""
        ticket, self._next_ticket = self._next_ticket, self._next_ticket + 1
        self._retask_queries[ticket] = query
        payload = query.payload.to_bytes() if query.payload is not None else b""
        # query.key_expr is the query's own expression (a wildcard that reached this
        # queryable stays one): the core refuses anything but pdcov/<id>/retask.
        self.core.receive_retask(ticket, payload, str(query.key_expr), source_session(query),
                                 self._clock(), time.time())
        self._act()

    def reply_retask(self, ticket: int, payload: bytes) -> None:
        """The core's answer to re-tasking request ``ticket``."""
        query = self._retask_queries.pop(ticket, None)
        if query is not None:  # on the own key: a wildcard query's refusal is answered too
            self._reply(query, lambda: payload, self.keys.retask)

    def _snapshot_bytes(self) -> bytes:
        """The grid's snapshot, encoded again only once the grid took another frame."""
        live = self.core.coverage
        grid = live.grid
        if self._snapshot is None or self._snapshot[0] != grid.frames:
            self._snapshot = (grid.frames, encode_grid_snapshot(grid, live.tile_size,
                                                                live.grid_hash))
        return self._snapshot[1]

    def _footprint_bytes(self) -> bytes:
        live = self.core.coverage
        t = live.last_pose.t_s if live.last_pose is not None else math.nan
        return encode_footprint(self.cfg.mission.vehicle_id, t, live.footprint_lonlat())

    def _mission_bytes(self) -> bytes:
        """The mission payload; encoded again only when the ground altitude becomes known."""
        m, origin = self.cfg.mission, self.core.coverage.origin
        alt = origin.ground_alt_msl_m if origin is not None else None
        if self._mission_reply is None or self._mission_reply[0] != alt:
            live = self.core.coverage
            self._mission_reply = (alt, encode_mission(
                m.vehicle_id, m.origin(alt), m.domain, live.grid.geometry, live.grid_hash,
                ground_alt_known=alt is not None, thresholds=m.thresholds,
                target_pd=self.cfg.target_pd))
        return self._mission_reply[1]

    def close(self) -> None:
        """At the stop: pending re-tasking queries dropped (the ground station's get times
        out), everything undeclared, the session closed."""
        for query in self._retask_queries.values():
            query.drop()
        for e in reversed(self._entities):
            try:
                e.undeclare()
            except Exception:  # noqa: BLE001
                pass
        if self.session is not None:
            self.session.close()


def _on_loop(post: Post, handle: Callable[[Any], object]) -> Callable[[Any], object]:
    """A Zenoh callback that hands its query to the loop (``post``) and never waits for it
    there (the loop may itself be waiting for Zenoh in a put: a deadlock)."""
    return lambda query: post(partial(handle, query))
