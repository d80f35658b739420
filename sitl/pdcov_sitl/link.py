"""The simulator's side of a MAVLink link: non-blocking byte I/O on UDP, TCP or a serial
pseudo-terminal, chosen by a URL. Bytes only; framing and MAVLink live elsewhere.

URLs (which side listens matters; ``tcp:`` here is the opposite of pymavlink's ``tcp:``)::

    udpout:HOST:PORT   send to HOST:PORT (a ground station listening there, pymavlink
                       udpin:); replies go back to our socket (default udpout:127.0.0.1:14550)
    udpin:HOST:PORT    listen on HOST:PORT; send to the address last heard from (nothing is
                       sent until a ground station has sent a packet, e.g. its HEARTBEAT)
    tcp:HOST:PORT      TCP server, as ArduPilot SITL's port 5760: the simulator listens and
    tcpin:HOST:PORT    any number of clients connect (pymavlink tcp:, MAVSDK tcpout://,
                       QGroundControl TCP link); a client that disconnects may reconnect
    tcpout:HOST:PORT   TCP client: the simulator connects to a listening ground station
                       (pymavlink tcpin:), retrying each second while it is not there
    pty:[LINK]         a pseudo-terminal pair; the client opens the slave as a serial port
                       (its path is ``Link.describe()``; with LINK, a symlink to it there)

Port 0 picks a free port (``Link.local_address`` tells which).
"""

from __future__ import annotations

import errno
import os
import socket
import time
import tty
from dataclasses import dataclass

DEFAULT_URL = "udpout:127.0.0.1:14550"
READ_CHUNK = 65536
TCP_BACKLOG_MAX_BYTES = 1 << 20
"""A TCP client that stops reading loses its oldest unsent bytes beyond this (a simulator
must never block on a ground station)."""
RECONNECT_S = 1.0


class LinkError(ValueError):
    """A link URL that cannot be used; the message names the URL and what to write."""


@dataclass(frozen=True, slots=True)
class LinkUrl:
    """A parsed link URL: scheme and, for network links, host and port."""

    scheme: str
    host: str = ""
    port: int = 0
    path: str = ""

    @classmethod
    def parse(cls, url: str) -> LinkUrl:
        scheme, colon, rest = url.partition(":")
        if scheme == "pty":
            return cls("pty", path=rest)
        if scheme not in ("udpout", "udpin", "tcp", "tcpin", "tcpout") or not colon:
            raise LinkError(f"link {url!r}: expected udpout:HOST:PORT, udpin:HOST:PORT, "
                            f"tcp:HOST:PORT (server), tcpin:HOST:PORT (server), "
                            f"tcpout:HOST:PORT (client) or pty:[PATH]")
        host, colon, port = rest.rpartition(":")
        if not colon or not host or not port.isdigit() or int(port) > 65535:
            raise LinkError(f"link {url!r}: expected {scheme}:HOST:PORT with PORT 0..65535")
        return cls("tcpin" if scheme == "tcp" else scheme, host, int(port))


class Link:
    """Non-blocking bytes in and out. ``write`` never blocks (bytes a peer cannot take
    are dropped, as on a radio); ``read`` returns what has arrived, b"" if nothing."""

    def write(self, data: bytes) -> None:
        raise NotImplementedError

    def read(self) -> bytes:
        raise NotImplementedError

    def pending_bytes(self) -> int:
        """Bytes accepted by ``write`` but not yet handed to the operating system."""
        return 0

    def ready(self) -> bool:
        """Whether written bytes can reach a peer (udpin: one has spoken; TCP: connected)."""
        return True

    def describe(self) -> str:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Link:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_link(url: str) -> Link:
    """Open the link a URL names (module docstring); raises LinkError or OSError."""
    u = LinkUrl.parse(url)
    if u.scheme == "pty":
        return PtyLink(u.path)
    if u.scheme in ("udpout", "udpin"):
        return UdpLink(u)
    if u.scheme == "tcpin":
        return TcpServerLink(u)
    return TcpClientLink(u)


class UdpLink(Link):
    def __init__(self, u: LinkUrl):
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._peer: tuple[str, int] | None = None
        if u.scheme == "udpin":
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind((u.host, u.port))
        else:
            self._peer = (socket.gethostbyname(u.host), u.port)
            self._sock.bind(("0.0.0.0", 0))
        self._listening = u.scheme == "udpin"
        self._url = u
        self.local_address = self._sock.getsockname()

    def write(self, data: bytes) -> None:
        if self._peer is None:
            return
        try:
            self._sock.sendto(data, self._peer)
        except OSError:  # no route, buffer full, port unreachable: the datagram is lost
            pass

    def read(self) -> bytes:
        chunks = []
        while True:
            try:
                data, addr = self._sock.recvfrom(READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable reported on a later call
                continue
            if self._listening:
                self._peer = addr
            chunks.append(data)
        return b"".join(chunks)

    def ready(self) -> bool:
        if self._peer is None:
            self.read()  # learns the peer of a udpin: link (what it read is dropped)
        return self._peer is not None

    def describe(self) -> str:
        if self._listening:
            return f"UDP, listening on {self.local_address[0]}:{self.local_address[1]}"
        return f"UDP, sending to {self._url.host}:{self._url.port}"

    def close(self) -> None:
        self._sock.close()


class _TcpConnection:
    """One connected TCP socket with its unsent bytes."""

    def __init__(self, sock: socket.socket):
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = sock
        self.out = bytearray()
        self.alive = True

    def flush(self) -> None:
        while self.out and self.alive:
            try:
                n = self.sock.send(self.out)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.alive = False
                break
            del self.out[:n]
        if len(self.out) > TCP_BACKLOG_MAX_BYTES:
            del self.out[:len(self.out) - TCP_BACKLOG_MAX_BYTES]

    def read(self) -> bytes:
        chunks = []
        while self.alive:
            try:
                data = self.sock.recv(READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                data = b""
            if not data:
                self.alive = False
                break
            chunks.append(data)
        return b"".join(chunks)

    def close(self) -> None:
        self.alive = False
        self.sock.close()


class TcpServerLink(Link):
    def __init__(self, u: LinkUrl):
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind((u.host, u.port))
        self._server.listen(4)
        self._server.setblocking(False)
        self.local_address = self._server.getsockname()
        self._clients: list[_TcpConnection] = []

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self._server.accept()
            except (BlockingIOError, InterruptedError):
                break
            self._clients.append(_TcpConnection(sock))

    def _prune(self) -> None:
        for c in [c for c in self._clients if not c.alive]:
            c.close()
            self._clients.remove(c)

    def write(self, data: bytes) -> None:  # new clients are accepted by read()
        for c in self._clients:
            c.out += data
            c.flush()
        self._prune()

    def read(self) -> bytes:
        self._accept()
        data = b"".join(c.read() for c in self._clients)
        for c in self._clients:
            c.flush()
        self._prune()
        return data

    def pending_bytes(self) -> int:
        for c in self._clients:
            c.flush()
        return sum(len(c.out) for c in self._clients)

    def ready(self) -> bool:
        self._accept()
        self._prune()
        return bool(self._clients)

    def describe(self) -> str:
        return f"TCP server on {self.local_address[0]}:{self.local_address[1]}"

    def close(self) -> None:
        for c in self._clients:
            c.close()
        self._clients.clear()
        self._server.close()


class TcpClientLink(Link):
    def __init__(self, u: LinkUrl):
        self._address = (u.host, u.port)
        self._conn: _TcpConnection | None = None
        self._pending: socket.socket | None = None
        self._next_try = 0.0
        self._connect()

    def _connect(self) -> None:
        """Advance a non-blocking connect; retried each RECONNECT_S (monotonic clock)."""
        if self._conn is not None and self._conn.alive:
            return
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._pending is None:
            if time.monotonic() < self._next_try:
                return
            self._next_try = time.monotonic() + RECONNECT_S
            self._pending = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._pending.setblocking(False)
            self._pending.connect_ex(self._address)
        err = self._pending.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if err == 0:
            try:
                self._pending.getpeername()
            except OSError:  # still connecting
                return
            self._conn, self._pending = _TcpConnection(self._pending), None
        elif err not in (errno.EINPROGRESS, errno.EALREADY):
            self._pending.close()
            self._pending = None

    def write(self, data: bytes) -> None:
        self._connect()
        if self._conn is not None:
            self._conn.out += data
            self._conn.flush()

    def read(self) -> bytes:
        self._connect()
        return self._conn.read() if self._conn is not None else b""

    def pending_bytes(self) -> int:
        if self._conn is None:
            return 0
        self._conn.flush()
        return len(self._conn.out)

    def ready(self) -> bool:
        self._connect()
        return self._conn is not None and self._conn.alive

    def describe(self) -> str:
        return f"TCP client of {self._address[0]}:{self._address[1]}"

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        if self._pending is not None:
            self._pending.close()


class PtyLink(Link):
    """A pseudo-terminal in raw mode. We keep the slave open ourselves so that the master
    stays usable while no client has it open; bytes nobody reads are dropped once the
    terminal's buffer is full."""

    def __init__(self, symlink: str = ""):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.slave_path = os.ttyname(self._slave)
        self._symlink = symlink
        if symlink:
            if os.path.islink(symlink):
                os.unlink(symlink)
            os.symlink(self.slave_path, symlink)

    def write(self, data: bytes) -> None:
        try:
            os.write(self._master, data)
        except (BlockingIOError, InterruptedError):
            pass  # terminal buffer full: nobody reads, the bytes are lost as on a UART
        except OSError:
            pass

    def read(self) -> bytes:
        chunks = []
        while True:
            try:
                data = os.read(self._master, READ_CHUNK)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # EIO while the other side is closed
                break
            if not data:
                break
            chunks.append(data)
        return b"".join(chunks)

    def describe(self) -> str:
        link = f" (link {self._symlink})" if self._symlink else ""
        return f"serial pseudo-terminal {self.slave_path}{link}"

    def close(self) -> None:
        if self._symlink and os.path.islink(self._symlink):
            os.unlink(self._symlink)
        os.close(self._master)
        os.close(self._slave)
