"""The asyncio shell of ``pdcov serve``: it owns the MAVLink links, the Zenoh session, the
timers, the signals, the files and the one clock, and does what ``ServiceCore`` (core.py)
decides (docs/service.md). It decides nothing itself: every event goes to the core with the
time, and the core's actions come back to be done.

Clock: one monotonic clock (``time.monotonic`` unless a test hands another) stamps every
event, the links' silence and the snapshot rate limits; wall-clock time (``time.time``) is
only written into recordings and checkpoints, as a value.

Threads: everything runs on the event loop's thread. MAVLink is read with
``loop.add_reader`` (mavlink_io); Zenoh calls its callbacks on its own threads, which hand
the payload (frames) or the query (snapshot, footprint, mission, candidates) to the loop with
``loop.call_soon_threadsafe`` and return at once: no grid is touched off the loop, and no
Zenoh thread waits for the loop (which may be waiting for Zenoh in a put). Checkpoints and
snapshots are encoded on the loop (milliseconds for a mission-sized grid), and the
candidates journal is appended and fsynced there too (one short line at most once every
DETECTIONS_PERIOD_S, before the detections message it protects: the put must wait for it).

Files in service.state_dir: checkpoint.npz, the candidates journal (candidate_store.py),
``epoch``, the re-tasking nonces (state_files.py), recordings/.
"""

from __future__ import annotations

import asyncio
import logging
import math
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pdcov.bus.footprint import encode_footprint
from pdcov.bus.grid_state import encode_snapshot
from pdcov.bus.mission import encode_mission
from pdcov.bus.session import (
    BusSecurity,
    bus_security,
    describe_session,
    open_session,
    peer_warning,
    session_mode,
)
from pdcov.bus.sources import SourcedPublisher, source_session
from pdcov.bus.status import StatusEncoder
from pdcov.errors import ConfigError, PdcovError
from pdcov.service.actions import Actions
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
from pdcov.service.checkpoint_meta import CheckpointMeta, CheckpointState
from pdcov.service.core import ServiceCore
from pdcov.service.coverage import LiveCoverage
from pdcov.service.link_setup import LinkReport
from pdcov.service.mavlink_io import Connection
from pdcov.service.recorder import TlogRecorder
from pdcov.service.settings import ServeConfig, mission_hash
from pdcov.service.state_files import StateFiles
from pdcov.service.systemd_notify import SystemdNotifier
from pdcov.telemetry.frame_policy import FrameSource
from pdcov.telemetry.link_protocol import MAV_COMP_ID_ONBOARD_COMPUTER, LinkProtocol

log = logging.getLogger("pdcov.serve")
TICK_S = 0.05
OPEN_ATTEMPT_S = 2.0
"""Longest wait of one attempt to open a client session (for a router to answer)."""
OPEN_RETRY_S = 1.0
"""Pause between two attempts to open a client session."""
"""The longest the loop sleeps between ticks (the core's timer may wake it sooner): links'
silence is checked this often."""


class Daemon:
    """``pdcov serve`` once the config is checked: ``await run()`` until SIGTERM/SIGINT.
    ``clock``: the one monotonic clock (s) every decision is given."""

    def __init__(self, cfg: ServeConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self._clock = clock
        self.state_dir = Path(cfg.service.state_dir)
        self.stop_event: asyncio.Event | None = None
        self.links: list[Connection] = []
        self.session: Any = None
        self._zenoh_entities: list[Any] = []
        self.pub_status: SourcedPublisher | None = None
        self.pub_tiles: SourcedPublisher | None = None
        self.pub_detections: SourcedPublisher | None = None
        self._status_encoder = StatusEncoder()
        self.notifier = SystemdNotifier()
        self._next_watchdog_s = 0.0
        self.recorder: TlogRecorder | None = None
        self._process_scheduled = False
        self.state_dir.mkdir(parents=True, exist_ok=True)
        self.files = StateFiles(self.state_dir)
        self.core = self._start_core()  # a new or resumed grid: there before the loop runs
        self.keys = self.core.keys
        self._mission_reply: tuple[float | None, bytes] | None = None  # (ground alt, bytes)
        self._snapshot: tuple[int, bytes] | None = None  # (grid frames, bytes)
        self._retask_queries: dict[int, Any] = {}  # ticket -> Zenoh query awaiting its answer
        self._next_ticket = 0

    # --- start ----------------------------------------------------------------------------

    def _start_core(self) -> ServiceCore:
        """The core with the grid resumed from the state dir's checkpoint when it belongs
        to this mission, else a new one."""
        m = self.cfg.mission
        grid = m.new_mission_grid()
        mhash = mission_hash(m, grid)
        cameras = {c.name: m.new_grid(c) for c in m.cameras} if m.several_cameras else None
        r = resume(self.state_dir, mhash, grid, cameras)
        (log.warning if r.set_aside else log.info)("%s", r.message)
        state = CheckpointState(path=str(self.state_dir / CHECKPOINT_NAME),
                                resumed=r.grid is not None,
                                set_aside=str(r.set_aside) if r.set_aside else None)
        core = ServiceCore(self.cfg, r.grid or grid, self._clock(), mission_hash=mhash,
                           resumed=r.meta if r.grid is not None else None, checkpoint=state,
                           camera_grids=r.cameras, nonces=self.files.read_nonces(),
                           epoch=self.files.read_epoch())
        self._restore_candidates(core, r.grid is not None, r.candidates, r.candidates_error)
        return core

    def _restore_candidates(self, core: ServiceCore, resumed: bool, doc: Any,
                            error: str | None) -> None:
        """The candidates from the checkpoint and the journal (candidate_store.restore);
        the journal then cut to its valid lines, or set aside."""
        journal, unreadable = self.files.read_journal()
        r = core.restore_candidates(resumed=resumed, checkpoint=doc, checkpoint_error=error,
                                    journal=journal, journal_path=str(self.files.journal))
        for level, text in r.logs:
            log.log(level, "%s", text)
        log.info("candidates restored: %d (%d from the checkpoint, %d updated or added by "
                 "%d journal lines)", r.candidates, r.from_checkpoint, r.from_journal, r.lines)
        self.files.settle_journal(journal, r.keep_bytes, r.set_aside or unreadable)

    @property
    def live(self) -> LiveCoverage:
        """The core's frames and grid."""
        return self.core.coverage

    @property
    def protocol(self) -> LinkProtocol:
        return self.core.protocol

    @property
    def mission_hash(self) -> str:
        return self.core.mission_hash

    @property
    def _checkpoint_info(self) -> dict[str, Any]:
        return self.core.checkpoint.describe()

    def _ids(self) -> tuple[int, int]:
        return (self.protocol.system_id or self.cfg.link.system_id or 1,
                MAV_COMP_ID_ONBOARD_COMPUTER)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        self.stop_event = asyncio.Event()
        for w in self.cfg.mission.warnings:  # what loading the mission found (config.Mission)
            log.warning("%s", w)
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.stop_event.set)
        if self.cfg.service.record:
            self.recorder = TlogRecorder(self.state_dir / "recordings",
                                         self.cfg.service.record_max_bytes,
                                         self.cfg.service.record_keep_bytes)
        key = self.cfg.link.signing_key_bytes(self.cfg.base_dir)
        if (self.cfg.link.signing_key or self.cfg.link.signing_key_file) and key is None:
            raise ConfigError("link.signing_key_file: cannot read 64 hex digits from "
                              f"{self.cfg.link.signing_key_file}")
        for url in self.cfg.link.connect:
            c = Connection(url, on_messages=self._on_messages,
                           from_autopilot=self.protocol.from_autopilot, ids=self._ids,
                           signing_key=key, timeout_s=self.cfg.link.timeout_s,
                           reconnect_max_s=self.cfg.link.reconnect_max_s, clock=self._clock)
            c.start()
            self.links.append(c)
        log.info("zenoh session: %s; publishing under pdcov/%s/",
                 describe_session(self.cfg.bus), self.cfg.mission.vehicle_id)
        warning = peer_warning(self.cfg.bus)
        if warning is not None:
            log.warning("%s", warning)
        opening = None
        try:
            if session_mode(self.cfg.bus) == "client":  # waits for a router: in the background
                opening = asyncio.create_task(self._open_client(loop, self.stop_event))
            else:
                self._declare(loop, await loop.run_in_executor(None, open_session,
                                                               self.cfg.bus))
            if self.cfg.service.retask and bus_security(self.cfg.bus) \
                    is not BusSecurity.MUTUAL_TLS:
                log.warning("re-tasking is on (service.retask) but this bus is not mutual "
                            "TLS: requests are signed, but anyone on the bus sees the "
                            "missions and can flood the queryable (docs/ground-station.md "
                            "\"Securing the bus\")")
            self.notifier.ready("pdcov serve: running")
            while not self.stop_event.is_set():
                self._tick()
                wait_s = min(TICK_S, max(0.0, self.core.get_timer() - self._clock()))
                try:
                    await asyncio.wait_for(self.stop_event.wait(), wait_s)
                except asyncio.TimeoutError:
                    pass
            log.info("stopping: writing the checkpoint")
            self.notifier.stopping("pdcov serve: stopping")
        finally:
            self.stop_event.set()
            if opening is not None:
                await opening  # returns within OPEN_ATTEMPT_S once stop is set
            self._shutdown()
        return 0

    async def _open_client(self, loop: asyncio.AbstractEventLoop, stop: asyncio.Event) -> None:
        """Open the client session and declare everything on it, trying again every
        OPEN_RETRY_S while no router answers (a peer opens at once); until then the daemon
        computes and checkpoints, and publishes nothing. (The config itself was checked by
        describe_session before: what fails here is reaching a router.)"""
        failures = 0
        while not stop.is_set():
            try:
                session = await loop.run_in_executor(None, open_session, self.cfg.bus,
                                                     OPEN_ATTEMPT_S)
            except ConfigError as exc:
                failures += 1
                (log.warning if failures == 1 else log.debug)(
                    "%s; trying again every %.0f s", exc, OPEN_ATTEMPT_S + OPEN_RETRY_S)
                try:
                    await asyncio.wait_for(stop.wait(), OPEN_RETRY_S)
                except asyncio.TimeoutError:
                    pass
                continue
            self._declare(loop, session)
            return

    def _declare(self, loop: asyncio.AbstractEventLoop, session: Any) -> None:
        self.session = s = session
        log.info("zenoh session open")
        self.pub_status = SourcedPublisher(s.declare_publisher(self.keys.status))
        self.pub_tiles = SourcedPublisher(s.declare_publisher(self.keys.tiles))
        self.pub_detections = SourcedPublisher(s.declare_publisher(self.keys.detections))
        self._zenoh_entities += [
            self.pub_status, self.pub_tiles, self.pub_detections,
            s.declare_queryable(self.keys.snapshot,
                                lambda q: self._answer(loop, q, self._reply_snapshot)),
            s.declare_queryable(self.keys.footprint, lambda q: self._answer(
                loop, q, lambda q: self._reply(q, self._footprint_bytes))),
            s.declare_queryable(self.keys.mission, lambda q: self._answer(
                loop, q, lambda q: self._reply(q, self._mission_bytes))),
            s.declare_queryable(self.keys.retask, lambda q: self._answer(
                loop, q, self._on_retask)),
            s.declare_queryable(self.keys.candidates,
                                lambda q: self._answer(loop, q, self._reply_candidates)),
            s.liveliness().declare_token(self.keys.alive),
        ]
        if self.cfg.frame_source == FrameSource.ZENOH:
            self._zenoh_entities.append(s.declare_subscriber(
                self.keys.frames, lambda sample: loop.call_soon_threadsafe(
                    self._on_frames, sample.payload.to_bytes())))

    # --- Zenoh thread -> loop ---------------------------------------------------------------

    @staticmethod
    def _answer(loop: asyncio.AbstractEventLoop, query: Any,
                handle: Callable[[Any], object]) -> None:
        """On a Zenoh thread: hand the query to the loop, never wait for it there (the loop
        may itself be waiting for Zenoh in a put: a deadlock)."""
        loop.call_soon_threadsafe(handle, query)

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
        self._do(self.core.actions())

    def _reply_retask(self, ticket: int, payload: bytes) -> None:
        query = self._retask_queries.pop(ticket, None)
        if query is not None:  # on the own key: a wildcard query's refusal is answered too
            self._reply(query, lambda: payload, self.keys.retask)

    def _snapshot_bytes(self) -> bytes:
        """The grid's snapshot, encoded again only once the grid took another frame."""
        grid = self.live.grid
        if self._snapshot is None or self._snapshot[0] != grid.frames:
            self._snapshot = (grid.frames, encode_snapshot(grid))
        return self._snapshot[1]

    def _footprint_bytes(self) -> bytes:
        t = self.live.last_pose.t_s if self.live.last_pose is not None else math.nan
        return encode_footprint(self.cfg.mission.vehicle_id, t, self.live.footprint_lonlat())

    def _mission_bytes(self) -> bytes:
        """The mission payload; encoded again only when the ground altitude becomes known."""
        m, origin = self.cfg.mission, self.live.origin
        alt = origin.ground_alt_msl_m if origin is not None else None
        if self._mission_reply is None or self._mission_reply[0] != alt:
            state = self.live.state
            self._mission_reply = (alt, encode_mission(
                m.vehicle_id, m.origin(alt), m.domain, state.geometry, state.hash,
                ground_alt_known=alt is not None, thresholds=m.thresholds,
                target_pd=self.cfg.target_pd))
        return self._mission_reply[1]

    def _on_frames(self, payload: bytes) -> None:
        """A detector's frames message (on the loop)."""
        self.core.receive_frames(payload)
        self._do(self.core.actions())

    # --- MAVLink -----------------------------------------------------------------------------

    def _on_messages(self, conn: Connection | None, msgs: list) -> None:
        self.core.receive_mavlink(msgs, self._clock())
        self._do(self.core.actions())
        if not self._process_scheduled:  # once per loop pass, after every readable link
            self._process_scheduled = True
            asyncio.get_running_loop().call_soon(self._process)

    def _process(self) -> None:
        self._process_scheduled = False
        self.core.process()
        self._do(self.core.actions())

    # --- timers and actions --------------------------------------------------------------

    def _tick(self) -> None:
        now = self._clock()
        for c in self.links:
            c.check_silence(now)
        self.core.tick(now, time.time())
        self._do(self.core.actions())
        if self.notifier.watchdog_interval_s and now >= self._next_watchdog_s:
            self.notifier.watchdog()
            self._next_watchdog_s = now + self.notifier.watchdog_interval_s

    def _do(self, a: Actions) -> None:
        """Do what the core decided, in its order (core.Actions)."""
        for msg in a.send:
            for c in self.links:
                c.send(msg)
        if a.record and self.recorder is not None:
            unix_s = time.time()
            for data in a.record:
                self.recorder.write(data, unix_s)
        if a.tiles is not None:
            self._put(self.pub_tiles, a.tiles)
        if a.journal is not None:  # before the detections: an id published is kept
            self.core.journal_written(self.files.append_journal(a.journal))
        for payload in a.detections:
            self._put(self.pub_detections, payload)
        if a.status_due:
            if self.recorder is not None:
                self.recorder.flush()
            self._publish_status()
        if a.checkpoint is not None:
            self._write_checkpoint(a.checkpoint)
        if a.journal_reset:
            self.files.reset_journal()
        if a.nonces is not None:  # before the replies: a replay after a crash is refused
            self.files.write_nonces(a.nonces)
        for ticket, payload in a.replies:
            self._reply_retask(ticket, payload)
        for level, text in a.logs:
            log.log(level, "%s", text)

    def _put(self, pub: SourcedPublisher | None, payload: bytes) -> None:
        if pub is None:  # no session yet (_open_bus): nobody to publish to
            self.core.put_failed()
            return
        try:
            pub.put(payload)
        except Exception as exc:  # noqa: BLE001 - no peer or a closing session: keep going
            self.core.put_failed()
            log.debug("zenoh put failed: %s", exc)

    def _link_report(self, now: float) -> LinkReport:
        return LinkReport(
            links=tuple(c.describe(now) for c in self.links),
            states=tuple(c.state for c in self.links),
            url=", ".join(c.url for c in self.links),
            losses=sum(c.losses for c in self.links),
            kernel_drops=sum(c.kernel_drops for c in self.links),
            parse_errors=sum(c.bad for c in self.links),
            recording_error=self.recorder.error if self.recorder is not None else None)

    def _publish_status(self) -> None:
        now = self._clock()
        fields, line = self.core.status(now, self._link_report(now))
        self._put(self.pub_status, self._status_encoder.encode(fields))
        self.notifier.status(line)
        self._do(self.core.actions())  # the status adds only log lines

    def _checkpoint(self) -> None:
        """Write a checkpoint of the grid now."""
        self._write_checkpoint(self.core.checkpoint_meta(time.time()))

    def _write_checkpoint(self, meta: CheckpointMeta) -> None:
        error = None
        try:
            write_checkpoint(self.state_dir / CHECKPOINT_NAME, self.live.grid, meta,
                             self.live.checkpoint_cameras, self.core.candidates_checkpoint())
        except (OSError, PdcovError) as exc:  # atomic_write: OutputError (disk full, ...)
            error = str(exc)
        self.core.checkpoint_written(meta, error)
        self._do(self.core.actions())  # the outcome adds only log lines

    def _shutdown(self) -> None:
        try:
            self.core.stop(self._clock())  # the pending detections published now
            self._do(self.core.actions())
            self._checkpoint()
        except Exception as exc:  # noqa: BLE001 - still close everything below
            log.error("final checkpoint failed: %s", exc)
        for c in self.links:
            c.close()
        if self.recorder is not None:
            self.recorder.close()
        for query in self._retask_queries.values():  # the ground station's get times out
            query.drop()
        for e in reversed(self._zenoh_entities):
            try:
                e.undeclare()
            except Exception:  # noqa: BLE001
                pass
        if self.session is not None:
            self.session.close()
        self.notifier.close()
