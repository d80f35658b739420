"""One MAVLink link kept open on the event loop: its socket opened (and reopened, forever,
with backoff) by URL in the default executor, then watched with ``loop.add_reader``; what
is read and sent is mavlink_link.MavlinkLink's, the socket mavlink_socket's.

Why add_reader and not a reader thread: every message then reaches the decisions on the
event loop's own thread, in order, with no locks and no hand-over. Only opening a link
blocks (a TCP connect, a serial device that is not there yet): that runs off the loop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from pdcov.service.mavlink_link import MavlinkLink
from pdcov.service.mavlink_socket import open_connection
from pdcov.telemetry.link_protocol import LinkState

log = logging.getLogger(__name__)
BACKOFF_START_S = 0.5


class Connection:
    """A link URL kept open: ``link`` (a MavlinkLink, given the same callbacks) once
    ``start()`` is called on the loop, until ``close()``."""

    def __init__(self, url: str, *, on_messages: Callable[[MavlinkLink, list], None],
                 from_autopilot: Callable[[Any], bool],
                 ids: Callable[[], tuple[int, int]], signing_key: bytes | None,
                 timeout_s: float, reconnect_max_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.link = MavlinkLink(url, on_messages=on_messages, from_autopilot=from_autopilot,
                                ids=ids, timeout_s=timeout_s, on_lost=self._lost, clock=clock)
        self._ids = ids
        self._signing_key = signing_key
        self.reconnect_max_s = reconnect_max_s
        self._task: asyncio.Task | None = None
        self._closing = False

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._open_forever())

    async def _open_forever(self) -> None:
        loop = asyncio.get_running_loop()
        delay = BACKOFF_START_S
        url = self.link.url
        while not self._closing:
            sysid, compid = self._ids()
            try:
                conn = await loop.run_in_executor(None, open_connection, url, sysid,
                                                  compid, self._signing_key)
            except Exception as exc:  # noqa: BLE001 - any failure to open: retry later
                self.link.state = LinkState.CONNECTING
                log.warning("link %s: cannot open (%s); retrying in %.1f s", url, exc, delay)
                await asyncio.sleep(delay)
                delay = min(2 * delay, self.reconnect_max_s)
                continue
            if self._closing:
                conn.close()
                return
            loop.add_reader(self.link.attach(conn), self.link.readable)
            log.info("link %s: open", url)
            return

    @staticmethod
    def _unwatch(fd: int) -> None:
        with contextlib.suppress(RuntimeError, ValueError):  # no loop running: nothing to stop
            asyncio.get_running_loop().remove_reader(fd)

    def _lost(self, why: str) -> None:
        log.warning("link %s: lost (%s); reopening", self.link.url, why)
        self.link.lost(self._unwatch)
        if not self._closing:
            self.start()

    def close(self) -> None:
        self._closing = True
        if self._task is not None:
            self._task.cancel()
        self.link.close(self._unwatch)
