"""``pdcov watch --cot URL``: the Cursor-on-Target feed's asyncio shell. What to send is
decided by ground/cot.py (``CotSchedule``); this sends it through pytak, which owns the
transports TAK clients and servers speak: UDP unicast and multicast (ATAK's default mesh
group udp://239.2.3.1:6969) and TCP streaming to a TAK server (tcp://HOST:8087).

pytak earns its place: its clients are what the TAK community runs (multicast TTL and
interface, TAK server streaming, and TLS should a later version need it), and hand-written
sockets would be one more thing to get wrong. We only send: a UDP URL is opened write-only
(``udp+wo``), so that nothing binds the feed's port on this machine.

A destination that cannot be reached (no route, a TCP server down or gone) never stops the
watcher: the failure is logged once per episode, the events of that moment are dropped (the
next ones carry the current state: CoT is a state feed, not a log) and the connection is
tried again after ``retry_s``.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from configparser import ConfigParser
from typing import Any
from urllib.parse import urlsplit

from pdcov.errors import ConfigError
from pdcov.ground.cot import CotSchedule
from pdcov.ground.feed import VehicleFeed

log = logging.getLogger("pdcov.watch")

SCHEMES = ("udp", "tcp")


def parse_cot_url(text: str) -> str:
    """``--cot URL``: udp://HOST:PORT or tcp://HOST:PORT; ConfigError naming the option
    otherwise."""
    try:
        u = urlsplit(text)
        port = u.port
    except ValueError:
        port = None
        u = None
    if u is None or u.scheme not in SCHEMES or not u.hostname or port is None \
            or u.path not in ("", "/"):
        raise ConfigError(f"--cot {text!r}: expected udp://HOST:PORT (e.g. the TAK mesh "
                          "group udp://239.2.3.1:6969) or tcp://HOST:PORT (a TAK server's "
                          "streaming port, e.g. tcp://tak.local:8087)")
    return text


class CotFeed:
    """Sends the schedule's events to ``url`` every ``period_s`` until ``stop`` is set.
    ``feeds`` returns the watcher's vehicle feeds (called on the event loop)."""

    def __init__(self, url: str, schedule: CotSchedule,
                 feeds: Callable[[], list[VehicleFeed]], *, period_s: float = 0.25,
                 retry_s: float = 5.0) -> None:
        self.url = parse_cot_url(url)
        self.schedule = schedule
        self.feeds = feeds
        self.period_s = period_s
        self.retry_s = retry_s
        self.failures = 0
        self.last_error: str | None = None
        self._writer: Any = None
        self._tx: Any = None

    @property
    def warning(self) -> str | None:
        """The line the views show while the destination fails, else None."""
        if self.last_error is None:
            return None
        return f"--cot {self.url}: not sending ({self.last_error}); retrying"

    def _config(self) -> Any:
        scheme, _, rest = self.url.partition("://")
        config = ConfigParser()
        config["pdcov"] = {"COT_URL": f"{scheme}+wo://{rest}" if scheme == "udp" else self.url,
                           "TAK_PROTO": "0"}  # XML events, which every TAK client reads
        return config["pdcov"]

    async def _connect(self) -> None:
        import pytak

        config = self._config()
        _, self._writer = await pytak.protocol_factory(config)
        self._tx = pytak.TXWorker(asyncio.Queue(), config, self._writer)

    def _failed(self, what: str, exc: BaseException) -> None:
        self.failures += 1
        if self.last_error is None:
            log.warning("--cot %s: %s failed (%s); retrying every %g s", self.url, what,
                        exc, self.retry_s)
        self.last_error = f"{what}: {exc}"
        self._close()

    def _close(self) -> None:
        writer, self._writer, self._tx = self._writer, None, None
        if writer is not None and hasattr(writer, "close"):
            try:
                writer.close()
            except OSError:
                pass

    async def run(self, stop: asyncio.Event) -> None:
        next_try = 0.0
        try:
            while not stop.is_set():
                now = time.monotonic()
                if self._tx is None and now >= next_try:
                    try:
                        await self._connect()
                    except (OSError, SyntaxError, ValueError) as exc:
                        self._failed("connecting", exc)
                        next_try = now + self.retry_s
                if self._tx is not None:
                    await self._send(now)
                try:
                    await asyncio.wait_for(stop.wait(), self.period_s)
                except asyncio.TimeoutError:
                    pass
        finally:
            self._close()

    async def _send(self, now_s: float) -> None:
        events = self.schedule.due(self.feeds(), now_s, time.time())
        try:
            for event in events:
                await self._tx.send_data(event)
        except Exception as exc:  # noqa: BLE001 - OSError, and pytak's TransportClosed
            self._failed("sending", exc)
            return
        if self.last_error is not None and events:
            log.warning("--cot %s: sending again (%d failures)", self.url, self.failures)
            self.last_error = None
