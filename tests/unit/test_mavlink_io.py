"""service.mavlink_io.Connection and its mavlink_link.MavlinkLink on a real UDP socket
(loopback): one readable event drains the datagrams waiting (bounded), and replies go to the
sender of the autopilot's messages."""

from __future__ import annotations

import asyncio
import os
import socket

os.environ["MAVLINK20"] = "1"  # before pymavlink: MAVLink 2 frames

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.service.mavlink_io import Connection
from pdcov.service.mavlink_link import MAX_DATAGRAMS_PER_EVENT
from tests.support.harness import free_port


def heartbeat_frames(n: int) -> list[bytes]:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return [mavlink.MAVLink_heartbeat_message(2, 3, 0, i, 4, 3).pack(mav) for i in range(n)]


async def open_udpin(port: int, on_messages) -> Connection:
    """A started udpin Connection on ``port``, once connected."""
    conn = Connection(f"udpin:127.0.0.1:{port}", on_messages=on_messages,
                      from_autopilot=lambda m: m.get_srcSystem() == 1, ids=lambda: (1, 191),
                      signing_key=None, timeout_s=5.0, reconnect_max_s=1.0)
    conn.start()
    for _ in range(500):
        if conn.link.state == "connected":
            break
        await asyncio.sleep(0.01)
    assert conn.link.state == "connected"
    return conn


async def receive_bursts(bursts: list[int]) -> tuple[list[int], bytes]:
    """Send each burst of heartbeats at once to a udpin Connection; the number of messages
    per on_messages call, and what a reply sent after the last burst brought back."""
    port = free_port(socket.SOCK_DGRAM)
    calls: list[int] = []
    conn = await open_udpin(port, lambda c, m: calls.append(len(m)))
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", 0))
    peer.settimeout(5.0)
    try:
        sent = 0
        for n in bursts:
            # No await between the sends: all are waiting when the loop sees the socket.
            for frame in heartbeat_frames(n):
                peer.sendto(frame, ("127.0.0.1", port))
            sent += n
            for _ in range(500):
                await asyncio.sleep(0.01)
                if sum(calls) >= sent:
                    break
        conn.link.send(mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
        reply = await asyncio.get_running_loop().run_in_executor(None, peer.recv, 4096)
        return calls, reply
    finally:
        conn.close()
        peer.close()


def test_one_event_drains_the_waiting_datagrams_and_replies_reach_the_sender() -> None:
    calls, reply = asyncio.run(asyncio.wait_for(receive_bursts([10]), 20.0))
    assert calls == [10]  # one batch, one pass of the daemon's decisions
    msgs = mavlink.MAVLink(None).parse_buffer(reply)
    assert [(m.get_type(), m.type) for m in msgs] == [("HEARTBEAT", 18)]


def test_a_flood_is_read_in_bounded_batches() -> None:
    n = 2 * MAX_DATAGRAMS_PER_EVENT + 5
    calls, _ = asyncio.run(asyncio.wait_for(receive_bursts([n]), 20.0))
    assert calls == [MAX_DATAGRAMS_PER_EVENT, MAX_DATAGRAMS_PER_EVENT, 5]


async def overflow(n: int) -> tuple[int, int]:
    """A udpin Connection whose receive buffer is made small, sent ``n`` heartbeats while the
    loop does not read; (kernel_drops, messages read afterwards)."""
    port = free_port(socket.SOCK_DGRAM)
    got: list[int] = []
    conn = await open_udpin(port, lambda c, m: got.append(len(m)))
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        conn.link.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        assert conn.link.kernel_drops == 0
        for frame in heartbeat_frames(n):  # no await: the loop cannot read meanwhile
            peer.sendto(frame, ("127.0.0.1", port))
        drops = conn.link.kernel_drops
        for _ in range(100):
            await asyncio.sleep(0.01)
        return drops, sum(got)
    finally:
        conn.close()
        peer.close()


def test_datagrams_the_kernel_dropped_are_counted() -> None:
    drops, read = asyncio.run(asyncio.wait_for(overflow(500), 20.0))
    # A 4 kB buffer holds a few datagrams: the rest were dropped, and each is accounted for.
    assert drops > 0 and read > 0
    assert drops + read == 500
