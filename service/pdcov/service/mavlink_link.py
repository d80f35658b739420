"""One MAVLink link of the daemon once its socket is open, without the event loop: what a
readable socket holds read and parsed, messages sent, the link's state and counters, and
its report in the status. The shell (mavlink_io.Connection) opens the socket, watches it
with ``loop.add_reader`` and reopens it when the link is lost.

Reading is non-blocking (pymavlink opens UDP and TCP sockets non-blocking and serial ports
with timeout 0), so one readable event drains what has arrived: a stream in one ``recv``,
UDP datagram by datagram up to MAX_DATAGRAMS_PER_EVENT (each message batch costs the daemon
one pass of its decisions, so a datagram per event would cost one pass per datagram). A UDP
server link reads its socket itself, with each datagram's sender (mavlink_socket).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from pdcov.service.mavlink_socket import Address, PeerWriter, ReplyPeers, udp_drops
from pdcov.telemetry.link_protocol import LinkState

__all__ = ["MAX_DATAGRAMS_PER_EVENT", "MavlinkLink"]

READ_BYTES = 65536
MAX_DATAGRAMS_PER_EVENT = 64
"""UDP datagrams read per readable event at most: what has arrived, bounded so that a flood
cannot hold the loop (the rest is read on its next pass)."""


class MavlinkLink:
    """A link URL's socket, counters and state: ``on_messages(link, msgs)`` gets each batch
    of parsed messages; ``send`` writes to it when open; ``on_lost(why)`` is told when a
    read, a write or a stream's silence loses it. ``from_autopilot(msg)``: whether a message
    (once ``on_messages`` has seen it) is the autopilot's own, which makes its sender a
    reply peer of a UDP server link."""

    def __init__(self, url: str, *, on_messages: Callable[[MavlinkLink, list], None],
                 from_autopilot: Callable[[Any], bool],
                 ids: Callable[[], tuple[int, int]], timeout_s: float,
                 on_lost: Callable[[str], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.url = url
        self._on_messages = on_messages
        self._from_autopilot = from_autopilot
        self._on_lost = on_lost
        self.reply_peers = ReplyPeers()
        self._ids = ids
        self.timeout_s = timeout_s
        self.conn: Any = None
        self._clock = clock  # the daemon's one monotonic clock (s)
        self.state = LinkState.CONNECTING
        self.last_rx_s: float | None = None
        self.opens = 0
        self.losses = 0
        self.bad = 0  # chunks pymavlink's parser raised on (the status's link_parse_errors)
        self._fd: int | None = None
        self._stream = url.startswith(("tcp:", "serial:", "/dev/")) or "," in url
        self._udp = url.startswith("udp")
        self._udp_server = url.startswith(("udpin:", "udp:"))  # pymavlink: input=True
        self._drops_closed = 0  # kernel drops at the sockets closed before this one
        self._drops_now = 0

    def attach(self, conn: Any) -> int:
        """``conn`` (mavlink_socket.open_connection's) is open: the file descriptor to
        watch for reading."""
        self.conn, self.opens = conn, self.opens + 1
        if self._udp_server:
            conn.mav.file = PeerWriter(conn.port, self.reply_peers)
        self._fd = conn.port.fileno()
        self.state = LinkState.CONNECTED
        self.last_rx_s = self._clock()
        return self._fd

    def readable(self) -> None:
        """The socket is readable: what has arrived, parsed, to ``on_messages``."""
        senders: list[Address] = []  # of each chunk (UDP server links only)
        try:
            if self._udp_server:
                chunks, senders = self._server_datagrams()
            elif hasattr(self.conn.port, "recvfrom") and self.url.startswith("udp"):
                chunks = self._datagrams()
            elif hasattr(self.conn.port, "recv"):
                data = self.conn.port.recv(READ_BYTES)
                if not data:
                    raise ConnectionError("closed by the peer")
                chunks = [data]
            else:
                chunks = [self.conn.port.read(READ_BYTES)]
        except Exception as exc:  # noqa: BLE001 - socket, peer-closed and serial errors alike
            self._on_lost(f"read failed: {exc}")
            return
        if not any(chunks):
            return
        self.last_rx_s = self._clock()
        if self.state != LinkState.CONNECTED:
            self.state = LinkState.CONNECTED
        batches: list[list] = []
        for data in chunks:
            try:
                batches.append(self.conn.mav.parse_buffer(bytes(data)) or [])
            except Exception:  # noqa: BLE001 - robust_parsing should not raise; count it
                self.bad += 1
                batches.append([])
        msgs = [m for batch in batches for m in batch]
        if msgs:
            self._on_messages(self, msgs)
        if self._udp_server:
            for address, batch in zip(senders, batches, strict=True):
                if any(self._from_autopilot(m) for m in batch):
                    self.reply_peers.heard(address)

    def _server_datagrams(self) -> tuple[list[bytes], list[Address]]:
        """A UDP server link's datagrams waiting (up to MAX_DATAGRAMS_PER_EVENT) and their
        senders, read from the socket here: pymavlink's ``recv`` would make every sender a
        client it writes to."""
        chunks: list[bytes] = []
        senders: list[Address] = []
        for _ in range(MAX_DATAGRAMS_PER_EVENT):
            try:
                data, address = self.conn.port.recvfrom(READ_BYTES)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                break  # nothing waiting (ECONNREFUSED: an ICMP error of an earlier send)
            chunks.append(data)
            senders.append(address)
        return chunks, senders

    def _datagrams(self) -> list[bytes]:
        """A UDP client link's datagrams waiting, up to MAX_DATAGRAMS_PER_EVENT, each read by
        pymavlink's ``mavudp.recv`` (broadcast: it records the last sender, which replies go
        to), which gives b"" once nothing is waiting (EAGAIN)."""
        out = []
        for _ in range(MAX_DATAGRAMS_PER_EVENT):
            data = self.conn.recv()
            if not data:
                break
            out.append(data)
        return out

    def check_silence(self, now_s: float) -> None:
        """Called periodically: a stream link silent for timeout_s is lost (reopened); a
        UDP link just reports 'waiting'."""
        if self.conn is None or self.last_rx_s is None:
            return
        if now_s - self.last_rx_s > self.timeout_s:
            if self._stream:
                self._on_lost(f"nothing received for {self.timeout_s:g} s")
            else:
                self.state = LinkState.WAITING

    def send(self, msg: Any) -> None:
        if self.conn is None:
            return
        sysid, compid = self._ids()
        self.conn.mav.srcSystem, self.conn.mav.srcComponent = sysid, compid
        try:
            self.conn.mav.send(msg)
        except OSError as exc:
            if self._stream:
                self._on_lost(f"write failed: {exc}")

    def lost(self, unwatch: Callable[[int], None]) -> None:
        """The link is lost (after ``on_lost``): counted, its socket closed (below); LOST."""
        self.losses += 1
        self._close_socket(unwatch)
        self.state = LinkState.LOST

    def close(self, unwatch: Callable[[int], None]) -> None:
        """The link is closed for good: its socket closed (below); CLOSED."""
        self._close_socket(unwatch)
        self.state = LinkState.CLOSED

    def _close_socket(self, unwatch: Callable[[int], None]) -> None:
        """Close the socket once ``unwatch(fd)`` has stopped the loop watching it."""
        self._drops_closed, self._drops_now = self.kernel_drops, 0
        if self._fd is not None:
            unwatch(self._fd)
            self._fd = None
        if self.conn is not None:
            try:
                self.conn.close()
            except Exception:  # noqa: BLE001
                pass
            self.conn = None

    def describe(self, now_s: float) -> dict[str, Any]:
        out = {"url": self.url, "state": str(self.state), "opens": self.opens,
               "losses": self.losses,
               "last_message_age_s": None if self.last_rx_s is None
               else round(now_s - self.last_rx_s, 3)}
        if self._udp_server:
            out["reply_to"] = [f"{host}:{port}" for host, port in self.reply_peers.addresses]
        return out

    @property
    def kernel_drops(self) -> int:
        """Datagrams the kernel dropped at this link's UDP sockets (0 for other links)."""
        if self._fd is not None and self._udp:
            self._drops_now = udp_drops(self._fd) or 0
        return self._drops_closed + self._drops_now
