"""The daemon's security with real Zenoh sessions: status and tiles carry its session as
source, MAVLink answered only to the autopilot, a flood of snapshot queries refused while
others still get theirs."""

from __future__ import annotations

import asyncio
import os
import socket
import threading
import time

import pytest
import yaml
import zenoh

from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.service.daemon import Daemon
from pdcov.service.query_limit import QueryLimits
from pdcov.service.settings import load_serve_config
from tests.support.link_feed import Hover, pack
from tests.support.serve_harness import Subscriber, free_port, process, router, serve_args, stop

os.environ.setdefault("MAVLINK20", "1")


from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.security_config import config


def hover_datagrams(seconds: float = 4.0) -> list[bytes]:
    """A hovering autopilot's messages (system 1, component 1), one datagram each: the daemon
    takes frames from them, so its grid and tiles change."""
    return [pack(m) for m in Hover(seconds=seconds).messages()]


class Sources:
    """A session's subscriber to a vehicle's status and tiles: (key, source zid, sn) of each
    sample (zid and sn None for a sample without source info)."""

    def __init__(self, session, keys: VehicleKeys) -> None:
        self.lock = threading.Lock()
        self.seen: list[tuple[str, str | None, int | None]] = []
        self.subs = [session.declare_subscriber(k, self._on) for k in (keys.status, keys.tiles)]

    def _on(self, sample) -> None:
        info = sample.source_info
        with self.lock:
            self.seen.append((str(sample.key_expr), None, None) if info is None else
                             (str(sample.key_expr), str(info.source_id.zid), info.source_sn))

    def wait(self, key: str, n: int, timeout_s: float = 60.0) -> list:
        """The samples seen once ``n`` of them are on ``key``."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self.lock:
                seen = list(self.seen)
            if [k for k, _, _ in seen].count(key) >= n:
                return seen
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for {n} samples on {key}: {len(seen)} "
                             "samples in all")

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


@pytest.mark.parametrize("path", ["router", "peer to peer"])
def test_status_and_tiles_carry_the_daemon_session_as_source(tmp_path, path) -> None:
    zport, mport = free_port(), free_port(socket.SOCK_DGRAM)
    cfg_path = config(tmp_path, "uav1", state=tmp_path / "state", zenoh_port=zport)
    doc = yaml.safe_load(cfg_path.read_text())
    if path == "router":
        r = router(zport)
        client = BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{zport}",),
                           multicast_scouting=False)
    else:  # the daemon listens, the ground station connects to it directly
        r = None
        doc["bus"].update(connect=[], listen=[f"tcp/127.0.0.1:{zport}"])
        client = BusConfig(mode="peer", connect=(f"tcp/127.0.0.1:{zport}",),
                           multicast_scouting=False)
    cfg_path.write_text(yaml.safe_dump(doc))
    keys = VehicleKeys("uav1")
    session = open_session(client)
    sources = Sources(session, keys)
    autopilot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with process(serve_args(cfg_path, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon:
            sources.wait(keys.status, 3)  # connected: now the frames, hence tiles
            for datagram in hover_datagrams():
                autopilot.sendto(datagram, ("127.0.0.1", mport))
            seen = sources.wait(keys.tiles, 1)
            replies = list(session.get(keys.snapshot, timeout=10.0))
            assert daemon.poll() is None, (tmp_path / "serve.log").read_text()[-2000:]
            assert stop(daemon) == 0
    finally:
        autopilot.close()
        sources.close()
        session.close()
        if r is not None:
            r.close()
    assert all(zid is not None for _, zid, _ in seen), "a put without source info"
    [reply] = [x for x in replies if x.ok is not None]
    daemon_zid = str(reply.replier_id.zid)
    assert {zid for _, zid, _ in seen} == {daemon_zid}
    assert daemon_zid != str(session.zid())
    for key in (keys.status, keys.tiles):  # sn 0, 1, 2, ... per publisher
        sns = [sn for k, _, sn in seen if k == key]
        assert sns == list(range(sns[0], sns[0] + len(sns))), (key, sns)


def rogue_datagrams(n: int) -> list[bytes]:
    """What ``n`` rogue senders send, one datagram each: a HEARTBEAT of another autopilot
    (system 7), a GCS HEARTBEAT (system 255), ATTITUDE from another component of the
    vehicle's system (1, 50), and junk."""
    mav = mavlink.MAVLink(None)
    kinds = [pack(mav.heartbeat_encode(2, 3, 0, 0, 4), 7, 1),
             pack(mav.heartbeat_encode(6, 8, 0, 0, 4), 255, 190),
             pack(mav.attitude_encode(1000, 0.0, 0.0, 0.0, 0, 0, 0), 1, 50),
             b"\xfd\x09junk" + bytes(range(40))]
    return [kinds[k % len(kinds)] for k in range(n)]


def udp_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def drain(s: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(s.recv(65536))
        except BlockingIOError:
            return out


async def autopilot_among_rogues(d: Daemon, mport: int, n_rogues: int
                                 ) -> tuple[list, list[bytes], tuple, int]:
    """Run the daemon; rogues from ``n_rogues`` distinct ports before and after an autopilot
    (hovering, then a HEARTBEAT a second) appears. (What the autopilot got, what the rogues
    got, the link's reply peers, the number of pymavlink's own UDP clients)."""
    loop = asyncio.get_running_loop()
    task = loop.create_task(d.run())
    rogues: list[socket.socket] = []
    autopilot = udp_socket()
    target = ("127.0.0.1", mport)
    try:
        links = d.effects.links
        for _ in range(400):
            if links and links[0].state == "connected" and d.stop_event is not None:
                break
            await asyncio.sleep(0.025)
        assert links[0].state == "connected"

        async def rogue_wave(n: int) -> None:
            for k, datagram in enumerate(rogue_datagrams(n)):
                s = udp_socket()
                rogues.append(s)
                s.sendto(datagram, target)
                if k % 50 == 49:
                    await asyncio.sleep(0)  # the daemon reads meanwhile

        await rogue_wave(n_rogues // 2)
        for k, datagram in enumerate(hover_datagrams(seconds=2.0)):
            autopilot.sendto(datagram, target)
            if k % 20 == 19:
                await asyncio.sleep(0.01)
        await rogue_wave(n_rogues - n_rogues // 2)
        beat = pack(mavlink.MAVLink(None).heartbeat_encode(2, 3, 128 | 1, 4, 4))
        for _ in range(3):  # the daemon's HEARTBEAT (1 Hz) and request retries (1 s)
            autopilot.sendto(beat, target)
            await asyncio.sleep(1.0)
        link = links[0]
        parser = mavlink.MAVLink(None)
        got = [m for data in drain(autopilot) for m in parser.parse_buffer(data) or []]
        rogue_got = [data for s in rogues for data in drain(s)]
        return got, rogue_got, link.reply_peers.addresses, len(link.conn.clients)
    finally:
        assert d.stop_event is not None
        d.stop_event.set()
        await asyncio.wait_for(task, 30.0)
        autopilot.close()
        for s in rogues:
            s.close()


def test_mavlink_is_answered_only_to_the_autopilot_not_to_rogue_senders(tmp_path) -> None:
    mport = free_port(socket.SOCK_DGRAM)
    cfg_path = config(tmp_path, "uav1", state=tmp_path / "state")
    doc = yaml.safe_load(cfg_path.read_text())
    doc["bus"].update(connect=[], listen=["tcp/127.0.0.1:0"])
    # The vehicle's system id configured: the first autopilot HEARTBEAT (here system 7's)
    # is not taken for it.
    doc["link"] = {"connect": [f"udpin:127.0.0.1:{mport}"], "system_id": 1}
    cfg_path.write_text(yaml.safe_dump(doc))
    d = Daemon(load_serve_config(cfg_path))
    got, rogue_got, peers, pymavlink_clients = asyncio.run(
        asyncio.wait_for(autopilot_among_rogues(d, mport, 3000), 120.0))
    kinds = {m.get_type() for m in got}
    assert "HEARTBEAT" in kinds, kinds
    commands = {m.command for m in got if m.get_type() == "COMMAND_LONG"}
    assert mavlink.MAV_CMD_SET_MESSAGE_INTERVAL in commands, commands
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in got} == {(1, 191)}
    assert rogue_got == [], f"{len(rogue_got)} datagrams sent to rogue senders"
    # One address to write each message to, however many others sent datagrams.
    assert len(peers) == 1 and peers[0][0] == "127.0.0.1", peers
    assert pymavlink_clients == 0
    assert d.live.counters.used > 0  # the autopilot's telemetry was taken meanwhile


def snapshot_queries(session, key: str, n: int, *, declare_source: bool
                     ) -> tuple[int, list[str]]:
    """``n`` snapshot queries one after the other, as fast as they are answered, with the
    session's source info or none: (snapshots received, error replies' texts)."""
    ok, errors = 0, []
    for k in range(n):
        more = {"source_info": zenoh.SourceInfo(session.id, k)} if declare_source else {}
        for reply in session.get(key, timeout=10.0, **more):
            if reply.ok is not None:
                ok += 1
            else:
                errors.append(reply.err.payload.to_bytes().decode())
    return ok, errors


def test_a_flood_of_snapshot_queries_is_refused_and_others_still_get_theirs(tmp_path) -> None:
    zport = free_port()
    cfg_path = config(tmp_path, "uav1", state=tmp_path / "state", zenoh_port=zport)
    r = router(zport)
    sub = Subscriber(zport, "uav1")
    keys = VehicleKeys("uav1")
    flooder, anonymous, other = (open_session(BusConfig(
        mode="client", connect=(f"tcp/127.0.0.1:{zport}",), multicast_scouting=False))
        for _ in range(3))
    try:
        with process(serve_args(cfg_path, "--connect", f"udpin:127.0.0.1:{free_port()}"),
                     tmp_path / "serve.log") as daemon:
            sub.wait(lambda s: True, 60, "the daemon's first status")
            t0 = time.monotonic()
            flood_ok, flood_err = snapshot_queries(flooder, keys.snapshot, 40,
                                                   declare_source=True)
            elapsed_s = time.monotonic() - t0
            anon_ok, anon_err = snapshot_queries(anonymous, keys.snapshot, 40,
                                                 declare_source=False)
            other_ok, other_err = snapshot_queries(other, keys.snapshot, 1,
                                                   declare_source=True)
            # A status may go out between two refusals: wait for one that counts them all.
            refused = len(flood_err) + len(anon_err)
            st = sub.wait(lambda s: s["faults"].get("snapshot_queries_refused", 0) >= refused,
                          30, "the refusals counted")
            assert daemon.poll() is None, (tmp_path / "serve.log").read_text()[-2000:]
            assert stop(daemon) == 0
    finally:
        for s in (flooder, anonymous, other):
            s.close()
        sub.close()
        r.close()
    lim = QueryLimits()
    # Every query answered: a snapshot while its bucket held one, a reason after.
    assert flood_ok + len(flood_err) == 40 and anon_ok + len(anon_err) == 40
    assert lim.burst <= flood_ok <= lim.burst + lim.per_requester_hz * elapsed_s + 1
    # The anonymous bucket is shared: the test's Subscriber took one snapshot from it.
    assert 1 <= anon_ok <= lim.burst
    assert flood_err and all(e.startswith("rate limited:") for e in flood_err + anon_err)
    assert (other_ok, other_err) == (1, [])  # not starved by the flooders
    assert st["faults"]["snapshot_queries_refused"] >= len(flood_err) + len(anon_err)
