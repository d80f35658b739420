"""A real TAK server for the --cot system tests: taky (PyPI ``taky``, the `test` extra), run
as its own process on 127.0.0.1 as a SAR team deploys it (its CoT router; TLS with client
certificates its CA signed, like a TAK server's 8089, or plain TCP, its 8087), and a
second TAK client that connects to it as ATAK does: it announces itself and reads the
events the server relays from the other clients."""

from __future__ import annotations

import socket
import ssl
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from tests.support.harness import free_port
from tests.support.tls_certs import Leaf

# What ATAK sends first on a stream: its position report (SA) with the contact, group and
# device details a TAK server takes as the client's identity.
_SELF_ANNOUNCE = (
    '<event version="2.0" uid="{uid}" type="a-f-G-U-C" how="h-e" time="{t}" start="{t}" '
    'stale="{stale}"><point lat="46.5" lon="7.25" hae="9999999.0" ce="9999999.0" '
    'le="9999999.0"/><detail><takv os="34" device="test" version="4.10" platform="ATAK"/>'
    '<contact callsign="{uid}" endpoint="*:-1:stcp"/><__group name="Cyan" role="Team Member"/>'
    "</detail></event>")


def _cot_time(unix_s: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S.000Z", time.gmtime(unix_s))


class TakyServer:
    """taky's CoT server listening on 127.0.0.1:``port`` (a free one), its configuration,
    management socket and log in ``folder``. With ``cert``: TLS, a client certificate
    signed by ``client_ca`` required; without: plain TCP. ``close`` stops it and returns
    its log."""

    def __init__(self, folder: Path, cert: Leaf | None = None, client_ca: Path | None = None
                 ) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        ssl_section = "[ssl]\nenabled = false\n"
        if cert is not None:
            ssl_section = (f"[ssl]\nenabled = true\nclient_cert_required = true\n"
                           f"ca = {client_ca}\ncert = {cert.cert}\nkey = {cert.key}\n"
                           f"cert_db = {folder / 'cert-db.txt'}\n")
        self.conf = folder / "taky.conf"
        self.conf.write_text(
            f"[taky]\nhostname = localhost\nnode_id = pdcov-test\nbind_ip = 127.0.0.1\n"
            f"root_dir = {folder}\n\n[cot_server]\nport = {self.port}\n\n"
            f"[dp_server]\nupload_path = {folder / 'dp-user'}\n\n{ssl_section}")
        self.log = folder / "taky.log"
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen([sys.executable, "-m", "taky.cot", "-l", "debug",
                                          "-c", str(self.conf)],
                                         stdout=log, stderr=subprocess.STDOUT)
        end = time.monotonic() + 30.0
        while time.monotonic() < end and self.proc.poll() is None:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1.0).close()
                return
            except OSError:
                time.sleep(0.1)
        log_text = self.close()
        raise AssertionError(f"taky did not listen on 127.0.0.1:{self.port}: {log_text}")

    def log_text(self) -> str:
        return self.log.read_text(errors="replace")

    def wait_log(self, text: str, count: int, timeout_s: float) -> None:
        """Until taky has logged ``text`` ``count`` times, or fail after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and self.log_text().count(text) < count:
            time.sleep(0.1)
        assert self.log_text().count(text) >= count, self.log_text()[-4000:]

    def close(self) -> str:
        if self.proc.poll() is None:
            self.proc.terminate()  # SIGTERM: taky disconnects its clients and stops
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        return self.log_text()


def client_context(leaf: Leaf, server_ca: Path) -> ssl.SSLContext:
    """TLS as ATAK's to a TAK server's 8089: its own certificate, the server's verified."""
    ctx = ssl.create_default_context(cafile=str(server_ca))
    ctx.load_cert_chain(leaf.cert, leaf.key)
    return ctx


class TakClient:
    """A TAK client connected to 127.0.0.1:``port`` (TLS with ``ctx``, else plain TCP) that
    announces itself as ``uid`` and parses, in a thread, every event the server sends:
    ``events`` in order; ``error``: why the stream ended, if it did."""

    def __init__(self, port: int, uid: str, ctx: ssl.SSLContext | None = None) -> None:
        sock = socket.create_connection(("127.0.0.1", port), timeout=10.0)
        self.sock = sock if ctx is None else ctx.wrap_socket(sock, server_hostname="localhost")
        self.events: list[ET.Element] = []
        self.error: str | None = None
        self._lock = threading.Lock()
        self._closing = False
        self._thread = threading.Thread(target=self._read, daemon=True)
        now = time.time()
        try:
            self.sock.sendall(_SELF_ANNOUNCE.format(uid=uid, t=_cot_time(now),
                                                    stale=_cot_time(now + 600)).encode())
        except (ssl.SSLError, OSError) as exc:  # refused: TLS 1.3 says so after the handshake
            self.error = getattr(exc, "reason", None) or repr(exc)
            return
        self.sock.settimeout(0.5)
        self._thread.start()

    def _read(self) -> None:
        buf = b""
        while not self._closing:
            try:
                chunk = self.sock.recv(65536)
            except TimeoutError:
                continue
            except (ssl.SSLError, OSError) as exc:
                self.error = getattr(exc, "reason", None) or repr(exc)
                return
            if not chunk:
                self.error = "closed by the server"
                return
            buf += chunk
            while b"</event>" in buf:  # taky writes events back to back, no separator
                event, buf = buf.split(b"</event>", 1)
                parsed = ET.fromstring(event[event.index(b"<event"):] + b"</event>")
                with self._lock:
                    self.events.append(parsed)

    def snapshot(self) -> list[ET.Element]:
        with self._lock:
            return list(self.events)

    def wait_closed(self, timeout_s: float) -> str | None:
        """Why the server ended the stream, or None if it is still open after ``timeout_s``."""
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        return self.error

    def close(self) -> None:
        self._closing = True
        if self._thread.is_alive():
            self._thread.join(5)
        self.sock.close()
