"""What `pdcov serve` does to the aircraft and the machine, over real sockets with the real
simulator (docs/reliability.md "Security"):

* with a MAVLink 2 signing key it ignores unsigned and wrongly signed messages and signs
  what it sends;
* every message it sends during a flight (read by a TCP tap between it and the simulator)
  is of a type on the allow-list: nothing that commands the aircraft to move;
* it listens on no port but those configured (its sockets in /proc during the flight);
* it writes only under its state directory (its open files during the flight; an empty
  HOME, working directory and TMPDIR stay empty).
"""

from __future__ import annotations

import os
import select
import socket
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from tests.support.serve_harness import (
    Subscriber,
    free_port,
    process,
    router,
    serve_args,
    serve_config,
    small_plan,
    stop,
)

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.support.harness import small_mission

KEY = bytes(range(32))
WRONG_KEY = bytes(range(1, 33))
SIM = small_mission(vehicle_id="sec1")
# What a coverage daemon may send to an autopilot: identification, stream and parameter
# requests, and its coverage for the ground station. Nothing that arms, changes mode,
# moves the aircraft or its gimbal, or writes parameters and missions.
ALLOWED = {"HEARTBEAT", "PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "NAMED_VALUE_FLOAT",
           "STATUSTEXT", "COMMAND_LONG"}
ALLOWED_COMMANDS = {mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_REQUEST_MESSAGE}


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return small_plan(tmp_path_factory.mktemp("plan"), SIM)


class Tap(threading.Thread):
    """A TCP proxy on loopback: the daemon connects to ``port``, the tap to the simulator's
    TCP server at ``upstream_port`` (retrying until it listens), bytes flow both ways, and
    every message the daemon sends is parsed (pymavlink, checking signatures with ``key``)
    and kept in ``sent``."""

    def __init__(self, upstream_port: int, key: bytes | None) -> None:
        super().__init__(daemon=True)
        self.server = socket.socket()
        self.server.bind(("127.0.0.1", 0))
        self.server.listen(2)
        self.port = self.server.getsockname()[1]
        self.upstream_port = upstream_port
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        if key is not None:
            self.parser.signing.secret_key = key
        self.sent: list = []
        self.stopping = threading.Event()
        self.lock = threading.Lock()

    def run(self) -> None:
        down = up = None
        try:
            while not self.stopping.is_set():
                socks = [s for s in (self.server, down, up) if s is not None]
                readable, _, _ = select.select(socks, [], [], 0.1)
                if self.server in readable:
                    if down is not None:
                        down.close()
                    down, _ = self.server.accept()
                if down is not None and up is None:
                    try:
                        up = socket.create_connection(("127.0.0.1", self.upstream_port), 1.0)
                    except OSError:
                        up = None
                if down is not None and down in readable:
                    data = _recv(down)
                    if not data:
                        down.close()
                        down = None
                        continue
                    msgs = self.parser.parse_buffer(data) or []
                    with self.lock:
                        self.sent += msgs
                    if up is not None:
                        try:
                            up.sendall(data)
                        except OSError:
                            up.close()
                            up = None
                if up is not None and up in readable:
                    data = _recv(up)
                    if not data:
                        up.close()
                        up = None
                    elif down is not None:
                        try:
                            down.sendall(data)
                        except OSError:
                            down.close()
                            down = None
        finally:
            for s in (down, up, self.server):
                if s is not None:
                    s.close()

    def stop(self) -> None:
        self.stopping.set()
        self.join(timeout=5)

    def messages(self) -> list:
        with self.lock:
            return list(self.sent)


def _recv(sock: socket.socket) -> bytes:
    """What arrived; b"" when the peer closed or reset the connection."""
    try:
        return sock.recv(65536)
    except OSError:
        return b""


def listening_sockets(pid: int) -> list[tuple[str, str]]:
    """(protocol, local address in /proc hex) of the process's listening TCP sockets and
    unconnected (receiving) UDP sockets."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    out = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        for line in Path(f"/proc/{pid}/net/{proto}").read_text().splitlines()[1:]:
            f = line.split()
            local, remote, state, inode = f[1], f[2], f[3], f[9]
            if inode not in inodes:
                continue
            if (proto.startswith("tcp") and state == "0A") or (
                    proto.startswith("udp") and remote.endswith(":0000")):
                out.append((proto, local))
    return out


def files_open_for_writing(pid: int) -> set[str]:
    """Regular files the process holds open with write access."""
    out = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
            flags = int(Path(f"/proc/{pid}/fdinfo/{fd}").read_text().split("flags:")[1]
                        .split()[0], 8)
        except (OSError, IndexError, ValueError):
            continue
        if target.startswith("/") and flags & (os.O_WRONLY | os.O_RDWR) \
                and not target.startswith("/dev/"):
            out.add(target)
    return out


def fly_args(cfg: Path, plan: Path, out: Path, connect: str, *more: str) -> list[str]:
    return [sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(cfg), "--plan",
            str(plan), "--out", str(out), "--connect", connect, "--speed", "0", *more]


def test_a_signed_flight_sends_only_allowed_messages_listens_nowhere_writes_only_state(
        tmp_path, plan):
    zport, sim_port = free_port(), free_port()
    state = tmp_path / "state"
    cfg = serve_config(SIM, tmp_path / "m.yaml", zenoh_port=zport, state_dir=state)
    doc = yaml.safe_load(cfg.read_text())
    doc["bus"]["listen"] = []  # nothing configured to listen: Zenoh must not either
    doc["link"] = {"signing_key": KEY.hex()}
    cfg.write_text(yaml.safe_dump(doc))
    home, cwd, tmpdir = (tmp_path / n for n in ("home", "cwd", "tmp"))
    for d in (home, cwd, tmpdir):
        d.mkdir()
    tap = Tap(sim_port, KEY)
    tap.start()
    r = router(zport)
    sub = Subscriber(zport, SIM["vehicle_id"])
    env = {"HOME": str(home), "TMPDIR": str(tmpdir), "XDG_CACHE_HOME": str(home / ".cache"),
           "XDG_CONFIG_HOME": str(home / ".config"), "XDG_DATA_HOME": str(home / ".local")}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # process() passes the environment on
    start_cwd = os.getcwd()
    try:
        os.chdir(cwd)
        with process(fly_args(cfg, plan, tmp_path / "fly", f"tcp:127.0.0.1:{sim_port}",
                              "--signing-key", KEY.hex()), tmp_path / "fly.log") as fly, \
             process(serve_args(cfg, "--connect", f"tcp:127.0.0.1:{tap.port}"),
                     tmp_path / "serve.log") as daemon:
            sockets, writing = set(), set()
            end = time.monotonic() + 120
            while fly.poll() is None and time.monotonic() < end:
                sockets.update(listening_sockets(daemon.pid))
                writing |= files_open_for_writing(daemon.pid)
                sub.sync()
                time.sleep(0.2)
            assert fly.wait(timeout=5) == 0, (tmp_path / "fly.log").read_text()[-2000:]
            # The last frame may wait for telemetry the landed simulator no longer sends.
            st = sub.wait(lambda s: s["frames"]["used"] > 50 and s["frames"]["pending"] <= 1,
                          30, "the flight's frames")
            assert daemon.poll() is None, (tmp_path / "serve.log").read_text()[-3000:]
            assert stop(daemon) == 0
    finally:
        os.chdir(start_cwd)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        sub.close()
        r.close()
        tap.stop()
    log = (tmp_path / "serve.log").read_text()
    # Signed both ways: the simulator (which ignores unsigned messages) acknowledged the
    # daemon's requests, and the daemon took the simulator's telemetry.
    assert st["link"]["intervals"].get("acked"), st["link"]
    assert st["link"]["system_id"] == 1 and st["faults"].get("bad_messages", 0) == 0, log
    sent = tap.messages()
    assert len(sent) > 20
    kinds = {m.get_type() for m in sent}
    assert kinds <= ALLOWED, kinds - ALLOWED
    assert "BAD_DATA" not in kinds and all(m.get_signed() for m in sent)
    assert {m.command for m in sent if m.get_type() == "COMMAND_LONG"} <= ALLOWED_COMMANDS
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in sent} == {(1, 191)}
    assert {m.type for m in sent if m.get_type() == "HEARTBEAT"} == {
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER}
    assert sockets == set(), sockets
    writing.discard(str(tmp_path / "serve.log"))  # its stdout/stderr, opened by the test
    assert writing and all(Path(p).is_relative_to(state) for p in writing), writing
    for d in (home, cwd, tmpdir):
        assert list(d.rglob("*")) == [], d
    assert (state / "checkpoint" / "current").is_file()


@pytest.mark.parametrize("sim_key", [None, WRONG_KEY], ids=["unsigned", "wrong key"])
def test_with_a_key_unsigned_and_wrongly_signed_telemetry_is_ignored(tmp_path, plan, sim_key):
    zport, mport = free_port(), free_port()
    cfg = serve_config(SIM, tmp_path / "m.yaml", zenoh_port=zport, state_dir=tmp_path / "st")
    doc = yaml.safe_load(cfg.read_text())
    doc["link"] = {"signing_key": KEY.hex()}
    cfg.write_text(yaml.safe_dump(doc))
    more = ["--signing-key", sim_key.hex()] if sim_key else []
    r = router(zport)
    sub = Subscriber(zport, SIM["vehicle_id"])
    try:
        with process(serve_args(cfg, "--connect", f"udpin:127.0.0.1:{mport}"),
                     tmp_path / "serve.log") as daemon:
            sub.wait(lambda s: True, 30, "the daemon's first status")
            with process(fly_args(cfg, plan, tmp_path / "fly", f"udpout:127.0.0.1:{mport}",
                                  *more), tmp_path / "fly.log") as fly:
                st = sub.wait(lambda s: s["link"]["bad_messages"] > 300 or fly.poll()
                              is not None, 90, "rejected telemetry")
            st = sub.status
            assert daemon.poll() is None
            assert stop(daemon) == 0
    finally:
        sub.close()
        r.close()
    link = st["link"]
    assert link["bad_messages"] > 300, link
    assert link["messages"] == 0 and link["system_id"] is None, link
    assert st["frames"]["used"] == 0 and st["pose"] is None
