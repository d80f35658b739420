"""``pdcov watch --cot URL``: the Cursor-on-Target feed's asyncio shell. What to send is
decided by ground/cot.py (``CotSchedule``); this sends it through pytak, which owns the
transports TAK clients and servers speak: UDP unicast and multicast (ATAK's default mesh
group udp://239.2.3.1:6969), TCP streaming to a TAK server (tcp://HOST:8087) and the same
over mutual TLS (tls://HOST:8089, with the identity ground/cot_tls.py checked).

pytak earns its place: its clients are what the TAK community runs (multicast TTL and
interface, TAK server streaming, TLS with client certificates), and hand-written sockets
would be one more thing to get wrong. We only send: a UDP URL is opened write-only
(``udp+wo``), so that nothing binds the feed's port on this machine; what a stream's server
sends (a TAK server relays every client's events) is read and dropped, so that it cannot
fill the buffer and stall the stream, and its end is noticed at once.

A destination that cannot be reached (no route, a server down or gone, a TLS server that
refuses the client certificate) never stops the watcher: the failure is logged once per
episode, the events of that moment are dropped (the next ones carry the current state: CoT
is a state feed, not a log) and the connection is tried again after ``retry_s``. The
episode ends when a connection has carried events for ``settle_s``: a TLS 1.3 server
refuses a client certificate only after the handshake, a round trip later.
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
from pdcov.ground.cot_tls import CotTls
from pdcov.ground.feed import VehicleFeed

log = logging.getLogger("pdcov.watch")

SCHEMES = ("udp", "tcp", "tls")


def parse_cot_url(text: str) -> str:
    """``--cot URL``: udp://HOST:PORT, tcp://HOST:PORT or tls://HOST:PORT; ConfigError
    naming the option otherwise."""
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
                          "streaming port, e.g. tcp://tak.local:8087) or tls://HOST:PORT "
                          "(its TLS port, e.g. tls://tak.local:8089, with --cot-cert and "
                          "--cot-ca)")
    return text


class CotFeed:
    """Sends the schedule's events to ``url`` every ``period_s`` until ``stop`` is set.
    ``feeds`` returns the watcher's vehicle feeds (called on the event loop). ``tls``: the
    identity for a tls:// URL (required there, closed when ``run`` ends)."""

    def __init__(self, url: str, schedule: CotSchedule,
                 feeds: Callable[[], list[VehicleFeed]], *, tls: CotTls | None = None,
                 period_s: float = 0.25, retry_s: float = 5.0, settle_s: float = 2.0
                 ) -> None:
        self.url = parse_cot_url(url)
        if self.url.startswith("tls://") != (tls is not None):
            raise ValueError(f"CotFeed {self.url}: a TLS identity goes with tls:// only")
        self.tls = tls
        self.schedule = schedule
        self.feeds = feeds
        self.period_s = period_s
        self.retry_s = retry_s
        self.settle_s = settle_s
        self.failures = 0
        self.last_error: str | None = None
        self._writer: Any = None
        self._tx: Any = None
        self._drain: asyncio.Task[None] | None = None
        self._connected_s = 0.0

    @property
    def warning(self) -> str | None:
        """The line the views show while the destination fails, else None."""
        if self.last_error is None:
            return None
        return f"--cot {self.url}: not sending ({self.last_error}); retrying"

    def _config(self) -> Any:
        scheme, _, rest = self.url.partition("://")
        config = ConfigParser(interpolation=None)  # no % expansion in URLs and paths
        config["pdcov"] = {"COT_URL": f"{scheme}+wo://{rest}" if scheme == "udp" else self.url,
                           "TAK_PROTO": "0",  # XML events, which every TAK client reads
                           **(self.tls.pytak_settings() if self.tls else {})}
        return config["pdcov"]

    async def _connect(self, now_s: float) -> None:
        import pytak

        config = self._config()
        reader, self._writer = await pytak.protocol_factory(config)
        self._tx = pytak.TXWorker(asyncio.Queue(), config, self._writer)
        self._connected_s = now_s
        if isinstance(reader, asyncio.StreamReader):
            self._drain = asyncio.create_task(_drain(reader))
            # Its exception is read by _lost, or by nobody once closed: not "never retrieved".
            self._drain.add_done_callback(lambda t: t.cancelled() or t.exception())

    def _failed(self, what: str, exc: BaseException, now_s: float | None = None) -> None:
        """Count, log the first of an episode, close; ``now_s`` when connected (whether the
        connection was new explains some TLS failures)."""
        self.failures += 1
        text = str(exc) if self.tls is None else self.tls.explain(
            exc, now_s is not None and now_s - self._connected_s < self.settle_s)
        if self.last_error is None:
            log.warning("--cot %s: %s failed (%s); retrying every %g s", self.url, what,
                        text, self.retry_s)
        self.last_error = f"{what}: {text}"
        self._close()

    def _lost(self) -> BaseException | None:
        """Why the stream's server ended the connection, None while it is open."""
        if self._drain is None or not self._drain.done():
            return None
        return self._drain.exception() or ConnectionResetError("closed by the server")

    def _close(self) -> None:
        writer, self._writer, self._tx = self._writer, None, None
        if self._drain is not None:
            self._drain.cancel()
            self._drain = None
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
                lost = self._lost()
                if lost is not None:
                    self._failed("sending", lost, now)
                    next_try = now + self.retry_s
                if self._tx is None and now >= next_try:
                    try:
                        await self._connect(now)
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
            if self.tls is not None:
                self.tls.close()

    async def _send(self, now_s: float) -> None:
        events = self.schedule.due(self.feeds(), now_s, time.time())
        try:
            for event in events:
                await self._tx.send_data(event)
        except Exception as exc:  # noqa: BLE001 - OSError, and pytak's TransportClosed
            self._failed("sending", exc, now_s)
            return
        if self.last_error is not None and events \
                and now_s - self._connected_s >= self.settle_s:
            log.warning("--cot %s: sending again (%d failures)", self.url, self.failures)
            self.last_error = None


async def _drain(reader: asyncio.StreamReader) -> None:
    """Read what the server sends and drop it, until it ends the stream (or fails: the
    task's exception, e.g. a TLS alert refusing the client certificate)."""
    while await reader.read(65536):
        pass
