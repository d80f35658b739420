"""One MAVLink connection of the daemon: opened (and reopened, forever, with backoff) by
URL, read from the event loop with ``loop.add_reader`` on its file descriptor.

Why add_reader and not a reader thread: every message then reaches the decisions on the
event loop's own thread, in order, with no locks and no hand-over; reading is
non-blocking (pymavlink opens UDP and TCP sockets non-blocking and serial ports with
timeout 0), so one readable event drains what has arrived: a stream in one ``recv``, UDP
datagram by datagram up to MAX_DATAGRAMS_PER_EVENT (each message batch costs the daemon one
pass of its decisions, so a datagram per event would cost one pass per datagram). Only
opening a link blocks (a TCP connect, a serial device that is not there yet): that runs in the
default executor, off the loop.

URLs as pymavlink and MAVProxy write them: ``udpin:0.0.0.0:14550``, ``udpout:HOST:PORT``,
``tcp:HOST:PORT``, ``/dev/ttyAMA0,921600``, and ``serial:/dev/ttyAMA0:921600``.

A UDP server link (``udpin:``, ``udp:``) answers only the autopilot: pymavlink would keep
every sender's address and write every message to all of them (23,000 one-datagram senders
took the daemon from 7 % to 29 % of a core), so the daemon reads the socket itself and
writes to ``ReplyPeers``, the few addresses that delivered the autopilot's own messages.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported: speak MAVLink 2

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.telemetry.link_protocol import LinkState

log = logging.getLogger(__name__)
READ_BYTES = 65536
BACKOFF_START_S = 0.5
UDP_RCVBUF_BYTES = 4 << 20
MAX_DATAGRAMS_PER_EVENT = 64
"""UDP datagrams read per readable event at most: what has arrived, bounded so that a flood
cannot hold the loop (the rest is read on its next pass)."""
MAX_REPLY_PEERS = 4
"""Addresses a UDP server link writes to at most (an autopilot behind two radios, or a
router and a direct link, needs two or three)."""
Address = tuple[str, int]


class ReplyPeers:
    """The addresses a UDP server link writes to: the senders of the autopilot's own
    messages (its system and component, as LinkProtocol follows them), at most ``limit``,
    the least recently heard dropped first. Other senders (other systems, junk, a flood from
    many ports) get nothing back and cost no send. Without MAVLink signing a sender can
    forge the autopilot's ids and be answered too; it can never grow the set past
    ``limit``."""

    def __init__(self, limit: int = MAX_REPLY_PEERS) -> None:
        self.limit = limit
        self._heard: OrderedDict[Address, None] = OrderedDict()

    def heard(self, address: Address) -> None:
        """``address`` just delivered a message of the autopilot."""
        self._heard[address] = None
        self._heard.move_to_end(address)
        while len(self._heard) > self.limit:
            self._heard.popitem(last=False)

    @property
    def addresses(self) -> tuple[Address, ...]:
        return tuple(self._heard)


class _PeerWriter:
    """What a UDP server link's MAVLink encoder writes to (in place of the pymavlink
    connection, which would write to every sender): each message to the reply peers."""

    def __init__(self, sock: socket.socket, peers: ReplyPeers) -> None:
        self._sock = sock
        self._peers = peers

    def write(self, buf: bytes) -> None:
        for address in self._peers.addresses:
            with contextlib.suppress(OSError):  # as pymavlink: a lost datagram, not an error
                self._sock.sendto(buf, address)


def pymavlink_url(url: str) -> tuple[str, int | None]:
    """(device or URL for mavutil, baud or None): ``serial:/dev/x:921600`` and
    ``/dev/x,921600`` name a serial device and its baud rate."""
    if url.startswith("serial:"):
        dev, _, baud = url[len("serial:"):].rpartition(":")
        if dev and baud.isdigit():
            return dev, int(baud)
        return url[len("serial:"):], None
    if "," in url and url.split(":", 1)[0] not in ("udpin", "udpout", "tcp", "tcpin", "udp"):
        dev, _, baud = url.rpartition(",")
        if baud.isdigit():
            return dev, int(baud)
    return url, None


def open_connection(url: str, system_id: int, component_id: int,
                    signing_key: bytes | None) -> Any:
    """A pymavlink connection speaking MAVLink 2 (ardupilotmega dialect, which reads
    MAVLink 1 too), as (system_id, component_id); blocking (run it in an executor)."""
    device, baud = pymavlink_url(url)
    kwargs = {"baud": baud} if baud else {}
    conn = mavutil.mavlink_connection(device, source_system=system_id,
                                      source_component=component_id, autoreconnect=False,
                                      **kwargs)
    if device.startswith("udp"):
        # A burst (a log replayed fast, a link catching up) must not overflow the socket
        # while the loop is busy with a frame: ask for a large receive buffer.
        with contextlib.suppress(OSError):
            conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF_BYTES)
    conn.mav = mavlink.MAVLink(conn, srcSystem=system_id, srcComponent=component_id)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False
    if signing_key is not None:
        conn.setup_signing(signing_key, sign_outgoing=True)
    return conn


def udp_drops(fd: int) -> int | None:
    """Datagrams the kernel dropped at UDP socket ``fd`` because its receive buffer was full
    (the daemon did not read in time): the ``drops`` column of /proc/net/udp or udp6 for the
    socket's inode; None where that cannot be read (not Linux)."""
    inode = str(os.fstat(fd).st_ino)
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as fh:
                for line in fh:
                    fields = line.split()
                    if len(fields) >= 13 and fields[9] == inode:
                        return int(fields[12])
        except (OSError, ValueError):
            continue
    return None


class Connection:
    """A link URL kept open: ``on_messages(conn, msgs)`` gets each batch of parsed
    messages; ``send`` writes to it when open. ``from_autopilot(msg)``: whether a message
    (once ``on_messages`` has seen it) is the autopilot's own, which makes its sender a
    reply peer of a UDP server link."""

    def __init__(self, url: str, *, on_messages: Callable[[Connection, list], None],
                 from_autopilot: Callable[[Any], bool],
                 ids: Callable[[], tuple[int, int]], signing_key: bytes | None,
                 timeout_s: float, reconnect_max_s: float,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.url = url
        self._on_messages = on_messages
        self._from_autopilot = from_autopilot
        self.reply_peers = ReplyPeers()
        self._ids = ids
        self._signing_key = signing_key
        self.timeout_s = timeout_s
        self.reconnect_max_s = reconnect_max_s
        self.conn: Any = None
        self._clock = clock  # the daemon's one monotonic clock (s)
        self.state = LinkState.CONNECTING
        self.last_rx_s: float | None = None
        self.opens = 0
        self.losses = 0
        self.bad = 0  # chunks pymavlink's parser raised on (the status's link_parse_errors)
        self._fd: int | None = None
        self._task: asyncio.Task | None = None
        self._closing = False
        self._stream = url.startswith(("tcp:", "serial:", "/dev/")) or "," in url
        self._udp = url.startswith("udp")
        self._udp_server = url.startswith(("udpin:", "udp:"))  # pymavlink: input=True
        self._drops_closed = 0  # kernel drops at the sockets closed before this one
        self._drops_now = 0

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._open_forever())

    async def _open_forever(self) -> None:
        loop = asyncio.get_running_loop()
        delay = BACKOFF_START_S
        while not self._closing:
            sysid, compid = self._ids()
            try:
                conn = await loop.run_in_executor(None, open_connection, self.url, sysid,
                                                  compid, self._signing_key)
            except Exception as exc:  # noqa: BLE001 - any failure to open: retry later
                self.state = LinkState.CONNECTING
                log.warning("link %s: cannot open (%s); retrying in %.1f s", self.url, exc,
                            delay)
                await asyncio.sleep(delay)
                delay = min(2 * delay, self.reconnect_max_s)
                continue
            if self._closing:
                conn.close()
                return
            self.conn, self.opens = conn, self.opens + 1
            if self._udp_server:
                conn.mav.file = _PeerWriter(conn.port, self.reply_peers)
            self._fd = conn.port.fileno()
            self.state = LinkState.CONNECTED
            self.last_rx_s = self._clock()
            loop.add_reader(self._fd, self._readable)
            log.info("link %s: open", self.url)
            return

    def _readable(self) -> None:
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
            self._lost(f"read failed: {exc}")
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

    def _lost(self, why: str) -> None:
        log.warning("link %s: lost (%s); reopening", self.url, why)
        self.losses += 1
        self._close_conn()
        self.state = LinkState.LOST
        if not self._closing:
            self.start()

    def check_silence(self, now_s: float) -> None:
        """Called periodically: a stream link silent for timeout_s is reopened; a UDP link
        just reports 'waiting'."""
        if self.conn is None or self.last_rx_s is None:
            return
        if now_s - self.last_rx_s > self.timeout_s:
            if self._stream:
                self._lost(f"nothing received for {self.timeout_s:g} s")
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
                self._lost(f"write failed: {exc}")

    def _close_conn(self) -> None:
        self._drops_closed, self._drops_now = self.kernel_drops, 0
        if self._fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._fd)
            except (RuntimeError, ValueError):
                pass
            self._fd = None
        if self.conn is not None:
            try:
                self.conn.close()
            except Exception:  # noqa: BLE001
                pass
            self.conn = None

    def close(self) -> None:
        self._closing = True
        if self._task is not None:
            self._task.cancel()
        self._close_conn()
        self.state = LinkState.CLOSED

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
