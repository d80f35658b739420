"""The asyncio shell of ``pdcov serve``: the event loop's wiring and nothing else -- the run
loop and its timer, the signals, the links' readers (mavlink_io), the Zenoh session opened
in an executor, Zenoh's threads handed to the loop. ``ServiceCore`` (core.py) decides
(docs/service.md); the I/O it asks for is done without the loop by startup.py (the core
from the checkpoint), bus_endpoints.py (the Zenoh keys and replies), effects.py (the core's
actions) and mavlink_link.py (a link's reads and sends).

Clock: one monotonic clock (``time.monotonic`` unless a test hands another) stamps every
event, the links' silence and the snapshot rate limits; wall-clock time (``time.time``) is
only written into recordings and checkpoints, as a value.

Threads: everything runs on the event loop's thread. MAVLink is read with
``loop.add_reader``; Zenoh calls its callbacks on its own threads, which hand the payload
(frames) or the query to the loop with ``loop.call_soon_threadsafe`` and return at once.

Files in service.state_dir: checkpoint/ (checkpoint.py), the candidates journal
(candidate_store.py),
``epoch``, the re-tasking nonces (state_files.py), recordings/.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import time
from collections.abc import Callable
from pathlib import Path

from pdcov.bus.session import (
    BusSecurity,
    bus_security,
    describe_session,
    open_session,
    peer_warning,
    session_mode,
)
from pdcov.errors import ConfigError
from pdcov.service.bus_endpoints import BusEndpoints
from pdcov.service.checkpoint import CHECKPOINT_NAME
from pdcov.service.coverage import LiveCoverage
from pdcov.service.effects import Effects
from pdcov.service.mavlink_io import Connection
from pdcov.service.mavlink_link import MavlinkLink
from pdcov.service.settings import ServeConfig
from pdcov.service.startup import signing_key, start_core, start_recorder
from pdcov.service.state_files import StateFiles
from pdcov.service.systemd_notify import SystemdNotifier
from pdcov.telemetry.link_protocol import MAV_COMP_ID_ONBOARD_COMPUTER

log = logging.getLogger("pdcov.serve")
TICK_S = 0.05
"""The longest the loop sleeps between ticks (the core's timer may wake it sooner): links'
silence is checked this often."""
OPEN_ATTEMPT_S = 2.0
"""Longest wait of one attempt to open a client session (for a router to answer)."""
OPEN_RETRY_S = 1.0
"""Pause between two attempts to open a client session."""


class Daemon:
    """``pdcov serve`` once the config is checked: ``await run()`` until SIGTERM/SIGINT.
    ``clock``: the one monotonic clock (s) every decision is given."""

    def __init__(self, cfg: ServeConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self._clock = clock
        self.stop_event: asyncio.Event | None = None
        self.connections: list[Connection] = []
        self.notifier = SystemdNotifier()
        self._next_watchdog_s = 0.0
        self._process_scheduled = False
        state_dir = Path(cfg.service.state_dir)
        state_dir.mkdir(parents=True, exist_ok=True)
        files = StateFiles(state_dir)
        self.core = start_core(cfg, files, clock)  # a new or resumed grid: before the loop
        self.bus = BusEndpoints(cfg, self.core, clock, act=lambda: self.effects.act())
        self.effects = Effects(self.core, self.bus, files, state_dir / CHECKPOINT_NAME,
                               self.notifier, clock)

    @property
    def live(self) -> LiveCoverage:
        """The core's frames and grid."""
        return self.core.coverage

    def _ids(self) -> tuple[int, int]:
        return (self.core.protocol.system_id or self.cfg.link.system_id or 1,
                MAV_COMP_ID_ONBOARD_COMPUTER)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        self.stop_event = asyncio.Event()
        for w in self.cfg.mission.warnings:  # what loading the mission found (config.Mission)
            log.warning("%s", w)
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.stop_event.set)
        self.effects.recorder = start_recorder(self.cfg)
        key = signing_key(self.cfg)
        for url in self.cfg.link.connect:
            c = Connection(url, on_messages=self._on_messages,
                           from_autopilot=self.core.protocol.from_autopilot, ids=self._ids,
                           signing_key=key, timeout_s=self.cfg.link.timeout_s,
                           reconnect_max_s=self.cfg.link.reconnect_max_s, clock=self._clock)
            c.start()
            self.connections.append(c)
            self.effects.links.append(c.link)
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
                self.bus.declare(await loop.run_in_executor(None, open_session, self.cfg.bus),
                                 loop.call_soon_threadsafe)
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
            self.bus.declare(session, loop.call_soon_threadsafe)
            return

    def _on_messages(self, link: MavlinkLink | None, msgs: list) -> None:
        self.core.receive_mavlink(msgs, self._clock())
        self.effects.act()
        if not self._process_scheduled:  # once per loop pass, after every readable link
            self._process_scheduled = True
            asyncio.get_running_loop().call_soon(self._process)

    def _process(self) -> None:
        self._process_scheduled = False
        self.core.process()
        self.effects.act()

    def _tick(self) -> None:
        now = self._clock()
        for link in self.effects.links:
            link.check_silence(now)
        self.core.tick(now, time.time())
        self.effects.act()
        if self.notifier.watchdog_interval_s and now >= self._next_watchdog_s:
            self.notifier.watchdog()
            self._next_watchdog_s = now + self.notifier.watchdog_interval_s

    def _shutdown(self) -> None:
        try:
            self.core.stop(self._clock())  # the pending detections published now
            self.effects.act()
            self.effects.checkpoint()
        except Exception as exc:  # noqa: BLE001 - still close everything below
            log.error("final checkpoint failed: %s", exc)
        for c in self.connections:
            c.close()
        self.effects.close()
        self.bus.close()
        self.notifier.close()
