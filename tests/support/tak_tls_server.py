"""A TAK server's TLS input as the --cot tests need it, on 127.0.0.1: mutual TLS (a client
certificate is required and verified against the clients' CA), the CoT XML events of each
client read from the stream and parsed, the handshakes it refused counted with OpenSSL's
reason. It runs its own event loop in a thread, so that a watcher process and an
in-process feed can both be tested against it."""

from __future__ import annotations

import asyncio
import ssl
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

from tests.support.tls_certs import Leaf


def server_context(cert: Leaf, client_ca: Path) -> ssl.SSLContext:
    """TLS as a TAK server's 8089: its certificate, clients' certificates required."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(cert.cert, cert.key)
    ctx.load_verify_locations(client_ca)
    ctx.verify_mode = ssl.CERT_REQUIRED
    return ctx


class TakTlsServer:
    """Listens on 127.0.0.1:``port`` (0: a free one, then ``port``) until ``close``.
    ``events``: the parsed events, in order; ``refused``: one reason per refused client;
    ``clients``: the client certificates' common names of the accepted connections."""

    def __init__(self, cert: Leaf, client_ca: Path, port: int = 0) -> None:
        self.ctx = server_context(cert, client_ca)
        self.events: list[ET.Element] = []
        self.refused: list[str] = []
        self.clients: list[str] = []
        self._lock = threading.Lock()
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._serve, "127.0.0.1", port), self._loop).result(10)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
                     ) -> None:
        try:
            await writer.start_tls(self.ctx)  # the handshake, client certificate checked
        except (ssl.SSLError, OSError) as exc:
            with self._lock:
                self.refused.append(getattr(exc, "reason", None) or type(exc).__name__)
            writer.close()
            return
        peer = writer.get_extra_info("peercert") or {}
        with self._lock:
            self.clients.append(dict(x[0] for x in peer.get("subject", ()))
                                .get("commonName", "?"))
        buf = b""
        try:
            while chunk := await reader.read(65536):
                buf += chunk
                while b"</event>" in buf:  # a stream of events, as a TAK server reads it
                    event, buf = buf.split(b"</event>", 1)
                    parsed = ET.fromstring(event[event.index(b"<event"):] + b"</event>")
                    with self._lock:
                        self.events.append(parsed)
        except (ssl.SSLError, OSError):
            pass
        finally:
            writer.close()

    def wait_for(self, done: Callable[[TakTlsServer], bool], timeout_s: float) -> None:
        """Poll until ``done(self)``, or fail after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                if done(self):
                    return
            time.sleep(0.05)
        raise AssertionError(f"TakTlsServer: not done in {timeout_s} s: "
                             f"{len(self.events)} events, refused {self.refused}")

    def close(self) -> None:
        async def stop() -> None:
            self._server.close()
            await self._server.wait_closed()

        try:
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(10)
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10)
            self._loop.close()
