"""The watcher's asyncio/Zenoh shell: subscribes, queries, times, and feeds the Watcher.

Zenoh calls back on its own threads; every callback only hands the raw payload and the
session it came from (``source_info`` of a sample, ``replier_id`` of a query reply: the
Watcher pins each vehicle to one session) to the event loop (``call_soon_threadsafe``),
where it is decoded and given to the Watcher, so the Watcher is only ever touched by one
thread. Queries (``get``) block until their replies or timeout, so they run in the loop's
default thread pool; they collect every reply (no consolidation), so that a second session
answering as the vehicle is seen. A payload is recorded after it was decoded and given to
the Watcher: a failing recorder never costs the live view a message.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from pdcov.bus.detections import decode_detections
from pdcov.bus.errors import BusPayloadError
from pdcov.bus.footprint import decode_footprint
from pdcov.bus.keys import VehicleKeys, parse_key
from pdcov.bus.mission import decode_mission
from pdcov.bus.retask import RetaskReply, decode_retask_reply
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.sources import SessionId, reply_session, source_info, source_session
from pdcov.bus.status import decode_status
from pdcov.bus.tiled_snapshot import decode_grid_snapshot
from pdcov.bus.tiles import decode_tiles
from pdcov.ground.queries import QueryCandidates, QueryMission, QuerySnapshot
from pdcov.ground.watcher import Watcher

log = logging.getLogger("pdcov.watch")

Recorder = Callable[[str, str, bytes], None]
"""Called with (vehicle_id, kind, payload) for every status, tiles, detections, snapshot,
mission and candidates reply that decoded (ground/record.py: it never raises)."""


class WatchShell:
    """Runs a Watcher on a Zenoh session until ``stop`` is set.

    vehicle: one vehicle id, or None for every vehicle. record: called with each raw
    payload received (see Recorder). ``version`` grows with every input the watcher took,
    so views redraw only when something changed.
    """

    def __init__(self, watcher: Watcher, bus: BusConfig, *, record: Recorder | None = None,
                 query_timeout_s: float = 5.0, footprint_period_s: float = 1.0,
                 poll_period_s: float = 0.2, connect_timeout_s: float | None = None) -> None:
        self.watcher = watcher
        self.bus = bus
        self.connect_timeout_s = connect_timeout_s
        """How long a client session waits for a router at open (None: for ever)."""
        self.record = record
        self.query_timeout_s = query_timeout_s
        self.footprint_period_s = footprint_period_s
        self.poll_period_s = poll_period_s
        self.version = 0
        self.connected = asyncio.Event()
        self._session: Any = None
        self._queries: dict[tuple[str, str], asyncio.Task[None]] = {}
        self._query_sn = 0

    @staticmethod
    def now_s() -> float:
        return time.monotonic()

    async def run(self, stop: asyncio.Event) -> None:
        """Open the session, follow the vehicles until ``stop``, close everything."""
        import zenoh

        loop = asyncio.get_running_loop()
        sel = self.watcher.vehicle or "*"
        self._session = session = await loop.run_in_executor(None, open_session, self.bus,
                                                             self.connect_timeout_s)
        entities = []
        try:
            def on_sample(sample: Any) -> None:
                loop.call_soon_threadsafe(self._received, str(sample.key_expr),
                                          sample.payload.to_bytes(), source_session(sample))

            def on_alive(sample: Any) -> None:
                loop.call_soon_threadsafe(self._alive, str(sample.key_expr),
                                          sample.kind == zenoh.SampleKind.PUT)

            # Tiles first: whatever is published after the snapshot query must reach us.
            entities.append(session.declare_subscriber(f"pdcov/{sel}/tiles", on_sample))
            entities.append(session.declare_subscriber(f"pdcov/{sel}/status", on_sample))
            entities.append(session.declare_subscriber(f"pdcov/{sel}/detections", on_sample))
            entities.append(session.liveliness().declare_subscriber(
                f"pdcov/{sel}/alive", on_alive, history=True))
            self.watcher.on_connected(self.now_s())
            self.connected.set()
            next_footprint = 0.0
            while not stop.is_set():
                now = self.now_s()
                self._do(self.watcher.poll(now))
                self._do(self.watcher.missions_due(now))
                self._do(self.watcher.candidates_due(now))
                if now >= next_footprint:
                    next_footprint = now + self.footprint_period_s
                    for vid, feed in self.watcher.feeds.items():
                        if feed.alive:
                            self._start_query(vid, "footprint")
                try:
                    await asyncio.wait_for(stop.wait(), self.poll_period_s)
                except asyncio.TimeoutError:
                    pass
        finally:
            for task in self._queries.values():
                task.cancel()
            for e in entities:
                e.undeclare()
            await asyncio.gather(*self._queries.values(), return_exceptions=True)
            await loop.run_in_executor(None, session.close)

    async def refresh_snapshots(self) -> None:
        """Query every known vehicle's snapshot now and wait for the replies."""
        for vid in list(self.watcher.feeds):
            self._start_query(vid, "snapshot")
        await asyncio.gather(*self._queries.values(), return_exceptions=True)

    # -- inputs (event loop thread) -----------------------------------------------------

    def _received(self, key: str, payload: bytes, source: SessionId) -> None:
        now = self.now_s()
        try:
            vid, kind = parse_key(key)
        except BusPayloadError as exc:
            log.warning("%s", exc)
            return
        try:
            if kind == "status":
                actions = self.watcher.on_status(vid, decode_status(payload, key, vid), now,
                                                 source)
            elif kind == "tiles":
                actions = self.watcher.on_tiles(vid, decode_tiles(payload, key), now, source)
            elif kind == "detections":
                self.watcher.on_detections(vid, decode_detections(payload, key, vid), now,
                                           source)
                actions = []
            else:
                return
        except BusPayloadError as exc:
            self.watcher.on_bad_payload(vid, exc)
            log.warning("%s", exc)
            return
        self.version += 1
        self._do(actions)
        self._record(vid, kind, payload)

    def _record(self, vehicle_id: str, kind: str, payload: bytes) -> None:
        if self.record is not None and self.watcher.roster.admits(vehicle_id):
            self.record(vehicle_id, kind, payload)

    def _alive(self, key: str, alive: bool) -> None:
        try:
            vid, _ = parse_key(key)
        except BusPayloadError as exc:
            log.warning("%s", exc)
            return
        self.version += 1
        self._do(self.watcher.on_alive(vid, alive, self.now_s()))

    def _do(self, actions: list[QuerySnapshot] | list[QueryMission] | list[QueryCandidates]
            ) -> None:
        for a in actions:
            self._start_query(a.vehicle_id, "mission" if isinstance(a, QueryMission)
                              else "candidates" if isinstance(a, QueryCandidates)
                              else "snapshot")

    # -- queries ------------------------------------------------------------------------

    def _start_query(self, vehicle_id: str, kind: str) -> None:
        task = self._queries.get((vehicle_id, kind))
        if task is not None and not task.done():
            return
        self._queries[(vehicle_id, kind)] = asyncio.get_running_loop().create_task(
            self._query(vehicle_id, kind))

    def _get(self, key: str, payload: bytes | None = None, timeout_s: float | None = None
             ) -> list[tuple[SessionId, bytes]]:
        """Blocking: every ok reply of ``get key`` (with ``payload``) with its replier's
        session (worker thread)."""
        import zenoh

        out = []
        # Named as this session, so that the daemon's snapshot rate limit gives this
        # watcher its own share (service/query_limit.py) rather than the anonymous one.
        self._query_sn += 1
        for reply in self._session.get(key, payload=payload,
                                       timeout=timeout_s or self.query_timeout_s,
                                       consolidation=zenoh.ConsolidationMode.NONE,
                                       source_info=source_info(self._session.id, self._query_sn)):
            if reply.ok is not None:
                out.append((reply_session(reply), reply.ok.payload.to_bytes()))
        return out

    @property
    def session_id(self) -> str | None:
        """This ground station's Zenoh session id (hex), once open (printed at start: what
        a vehicle's status and the logs name it by)."""
        return None if self._session is None else str(self._session.zid())

    async def retask(self, vehicle_id: str, payload: bytes, timeout_s: float = 60.0
                     ) -> RetaskReply | None:
        """Send a re-tasking request to the vehicle's daemon and wait for its answer (the
        upload takes a few seconds): the reply of the session the vehicle is pinned to
        (ground/claims.py), None when that session did not answer within ``timeout_s``.
        Replies of other sessions are refused and logged."""
        key = VehicleKeys(vehicle_id).retask
        trusted = self.watcher.taken_from(vehicle_id, "snapshot")
        try:
            replies = await asyncio.get_running_loop().run_in_executor(
                None, self._get, key, payload, timeout_s)
        except Exception as exc:  # noqa: BLE001 - Zenoh raises ZError for a closed session
            log.warning("%s: query failed: %s", key, exc)
            return None
        answer = None
        for source, data in replies:
            if source != trusted:
                log.warning("%s: reply from session %s refused: the vehicle is session %s's",
                            key, source, trusted or "nobody's yet")
                continue
            try:
                answer = decode_retask_reply(data, key, vehicle_id)
            except BusPayloadError as exc:
                self.watcher.on_bad_payload(vehicle_id, exc)
                log.warning("%s", exc)
        return answer

    async def _query(self, vehicle_id: str, kind: str) -> None:
        key = VehicleKeys(vehicle_id).key(kind)
        try:
            replies = await asyncio.get_running_loop().run_in_executor(None, self._get, key)
        except Exception as exc:  # noqa: BLE001 - Zenoh raises ZError for a closed session
            log.warning("%s: query failed: %s", key, exc)
            replies = []
        now = self.now_s()
        def decode(payload: bytes, key: str) -> Any:
            if kind == "mission":
                return decode_mission(payload, key, vehicle_id)
            if kind == "candidates":
                return decode_detections(payload, key, vehicle_id)
            return (decode_grid_snapshot if kind == "snapshot" else decode_footprint)(payload, key)

        decoded = []
        for source, payload in replies:
            try:
                decoded.append((source, decode(payload, key), payload))
            except BusPayloadError as exc:
                self.watcher.on_bad_payload(vehicle_id, exc)
                log.warning("%s", exc)
        if kind == "snapshot":
            self._do(self.watcher.on_snapshot_replies(
                vehicle_id, [(source, state) for source, state, _ in decoded], now))
        elif kind == "candidates":
            self.watcher.on_candidates_replies(
                vehicle_id, [(source, doc) for source, doc, _ in decoded], now)
        elif not decoded and kind == "mission":
            self.watcher.on_mission_failed(vehicle_id, now)
        for source, doc, _ in decoded:
            if kind == "mission":
                self.watcher.on_mission(vehicle_id, doc, now, source)
            elif kind == "footprint":
                self.watcher.on_footprint(vehicle_id, doc, now, source)
        self.version += 1
        if kind != "footprint":
            trusted = self.watcher.taken_from(vehicle_id, kind)
            for source, _, payload in decoded:
                if source != trusted:
                    continue
                self._record(vehicle_id, kind, payload)
                break
