"""A MAVLink link's socket, without the event loop: a pymavlink connection opened by URL
(blocking: the shell runs ``open_connection`` in an executor), a UDP server link's reply
peers and the peer writer its encoder writes to, and the datagrams the kernel dropped.

URLs as pymavlink and MAVProxy write them (telemetry/link_url.py, checked with the config):
``udpin:0.0.0.0:14550``, ``udpout:HOST:PORT``, ``tcp:HOST:PORT``, ``/dev/ttyAMA0,921600``,
and ``serial:/dev/ttyAMA0:921600``.

A UDP server link (``udpin:``, ``udp:``) answers only the autopilot: pymavlink would keep
every sender's address and write every message to all of them (23,000 one-datagram senders
took the daemon from 7 % to 29 % of a core), so the daemon reads the socket itself and
writes to ``ReplyPeers``, the few addresses that delivered the autopilot's own messages.
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections import OrderedDict
from typing import Any

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink is imported: speak MAVLink 2

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.telemetry.link_url import pymavlink_device

__all__ = ["Address", "PeerWriter", "ReplyPeers", "mavlink", "open_connection", "udp_drops"]

UDP_RCVBUF_BYTES = 4 << 20
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


class PeerWriter:
    """What a UDP server link's MAVLink encoder writes to (in place of the pymavlink
    connection, which would write to every sender): each message to the reply peers."""

    def __init__(self, sock: socket.socket, peers: ReplyPeers) -> None:
        self._sock = sock
        self._peers = peers

    def write(self, buf: bytes) -> None:
        for address in self._peers.addresses:
            with contextlib.suppress(OSError):  # as pymavlink: a lost datagram, not an error
                self._sock.sendto(buf, address)


def open_connection(url: str, system_id: int, component_id: int,
                    signing_key: bytes | None) -> Any:
    """A pymavlink connection speaking MAVLink 2 (ardupilotmega dialect, which reads
    MAVLink 1 too), as (system_id, component_id); blocking (run it in an executor). One
    attempt (retries=0): the shell retries with its own backoff and log line, where
    pymavlink's retries print "Connection refused sleeping" to stdout."""
    device, baud = pymavlink_device(url)
    kwargs = {"baud": baud} if baud else {}
    conn = mavutil.mavlink_connection(device, source_system=system_id,
                                      source_component=component_id, autoreconnect=False,
                                      retries=0, **kwargs)
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
