"""``pdcov demo``, live: the whole system on one machine, on loopback.

A Zenoh router in this process (mode router, tcp/127.0.0.1:<free port>, no multicast
scouting); per vehicle the simulator (``pdcov-sitl fly``, a JSBSim quadcopter speaking
MAVLink over TCP) and the daemon (``pdcov serve``) as processes; one watcher
(``pdcov watch --record``) showing the coverage live in this terminal (and the browser with
``web``). When every simulator has landed and the daemons' grids have stopped changing,
the watcher is stopped (it writes the report) and then the daemons (they checkpoint).
Every child is stopped on the way out, whatever the way out is (end, error, Ctrl-C).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import yaml

from pdcov.atomic import write_text_atomic
from pdcov.bus.errors import BusPayloadError
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.status import decode_status, merge_status
from pdcov.errors import PdcovError

SETTLE_S = 2.0  # the daemons' frame counts unchanged this long: the flight is evaluated


@dataclass(frozen=True, slots=True)
class DemoVehicle:
    """One simulated vehicle: its id, MAVLink system id and the plan it flies."""

    vehicle_id: str
    system_id: int
    plan: Path


@dataclass(frozen=True, slots=True)
class LiveDemo:
    """out: the demo folder, new or empty (``pdcov demo`` gives a fresh one that replaces
    the previous folder whole when the demo finishes). mission_doc: the mission config
    mapping (the bundled demo mission) each vehicle's config is made from. speed: simulator
    speed-up. web: (host, port) for the browser map, or None. timeout_s: the longest the
    flights may take."""

    out: Path
    mission_doc: Mapping[str, Any]
    vehicles: tuple[DemoVehicle, ...]
    speed: float = 8.0
    web: tuple[str, int] | None = None
    timeout_s: float = 900.0
    plain: bool = False


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Children:
    """Child processes, each in its own session (Ctrl-C reaches only the demo, which stops
    them in order): SIGTERM, then SIGKILL after a grace period."""

    def __init__(self) -> None:
        self.procs: list[tuple[str, subprocess.Popen[bytes]]] = []
        self._logs: list[IO[bytes]] = []
        self._log_paths: dict[subprocess.Popen[bytes], Path] = {}

    def start(self, name: str, args: Sequence[str], log: Path | None) -> subprocess.Popen[bytes]:
        out: Any = None
        if log is not None:
            f = log.open("wb")
            self._logs.append(f)
            out = f
        p = subprocess.Popen(list(args), stdout=out, stderr=subprocess.STDOUT if out else None,
                             stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs.append((name, p))
        if log is not None:
            self._log_paths[p] = log
        return p

    def log_end(self, p: subprocess.Popen[bytes], lines: int = 15) -> str:
        """For an error message: the last ``lines`` lines of ``p``'s log, or "" (no log).
        The message must carry them: a failed demo's folder, logs included, is removed and
        the previous one put back."""
        path = self._log_paths.get(p)
        if path is None:
            return ""
        try:
            with path.open("rb") as f:
                f.seek(max(0, path.stat().st_size - 8192))
                tail = f.read().decode("utf-8", "replace").splitlines()[-lines:]
        except OSError:
            return ""
        return "; its log ends:\n" + "\n".join(f"    {line}" for line in tail) if tail else ""

    def log_ends(self, lines: int = 5) -> str:
        """``log_end`` of every child that has a log, each under its name."""
        return "".join(f"\n  the {name}{self.log_end(p, lines)}" for name, p in self.procs
                       if p in self._log_paths)

    @staticmethod
    def terminate(p: subprocess.Popen[bytes], grace_s: float) -> int:
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGTERM)
            try:
                p.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=10)
        return int(p.returncode)

    def stop_all(self) -> None:
        """Stop every child; a second Ctrl-C meanwhile kills the rest at once, so that no
        child outlives the demo (and writes into a folder being put back)."""
        try:
            for _, p in reversed(self.procs):
                self.terminate(p, 10.0)
        except KeyboardInterrupt:
            for _, p in self.procs:
                if p.poll() is None:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(p.pid, signal.SIGKILL)
                    p.wait(timeout=10)
            raise
        finally:
            for f in self._logs:
                f.close()


class FleetStatus:
    """The daemons' last status, heard on the router's own session (for knowing when the
    flights are evaluated; the watcher process is what the user sees)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.status: dict[str, dict[str, Any]] = {}
        self.changed_s: dict[str, float] = {}

    def on_sample(self, sample: Any) -> None:
        try:
            doc = decode_status(sample.payload.to_bytes(), str(sample.key_expr))
        except BusPayloadError:
            return
        vid = doc["vehicle_id"]
        with self.lock:
            old = self.status.get(vid)
            key = (doc["frames"].get("used"), doc["tiles_seq"])
            if old is None or (old["frames"].get("used"), old["tiles_seq"]) != key:
                self.changed_s[vid] = time.monotonic()
            self.status[vid] = merge_status(old, doc)

    def settled(self, ids: Sequence[str], quiet_s: float) -> bool:
        now = time.monotonic()
        with self.lock:
            return all(v in self.changed_s and now - self.changed_s[v] >= quiet_s
                       for v in ids)

    def final(self) -> dict[str, dict[str, Any]]:
        with self.lock:
            return dict(self.status)


# A status every this many seconds of the simulated flight. Its pose is the only position
# the ground station gets (the track of its heat map, map and exports), and the daemon
# publishes it by the wall clock: at 0.5 s of wall time, 8x real time gave a point every
# 4 s of flight, the spiral drawn in a dozen straight segments.
STATUS_PERIOD_FLIGHT_S = 0.5
MIN_STATUS_PERIOD_S = 0.1
"""But no more than 10 statuses a second of wall time per daemon (at 8x: a point every 0.8 s
of flight, 4 m at 5 m/s), so that two daemons, the simulators and the watcher keep to two
cores."""


def vehicle_config(doc: Mapping[str, Any], vehicle: DemoVehicle, router: str,
                   state_dir: Path, speed: float = 1.0) -> dict[str, Any]:
    """The mission config of one demo vehicle: the demo mission, its id, a peer session to
    the router (loopback, no multicast scouting) with a status every
    STATUS_PERIOD_FLIGHT_S of a flight simulated ``speed`` times faster than real time (at
    least MIN_STATUS_PERIOD_S of wall time), its state folder."""
    out = dict(doc)
    out["vehicle_id"] = vehicle.vehicle_id
    out["log"] = {**dict(doc.get("log") or {}), "system_id": vehicle.system_id}
    out["bus"] = {"mode": "peer", "connect": [router], "listen": ["tcp/127.0.0.1:0"],
                  "multicast_scouting": False,
                  "status_period_s": max(STATUS_PERIOD_FLIGHT_S / speed, MIN_STATUS_PERIOD_S),
                  "tiles_period_s": 0.2}
    out["service"] = {"state_dir": str(state_dir), "checkpoint_period_s": 5.0}
    return out


def run_live_demo(demo: LiveDemo, stdout: IO[str] | None = None) -> dict[str, Any]:
    """Run the demo; returns the daemons' final status by vehicle id and the report folder.
    Raises PdcovError when a process fails (naming its log)."""
    say = stdout or sys.stdout
    out = demo.out
    for folder in ("configs", "logs", "sim", "state"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    report = out / "report"
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    previous = _interrupt_on_signals()
    router = open_session(BusConfig(mode="router", listen=(router_ep,),
                                    multicast_scouting=False))
    children = Children()
    fleet = FleetStatus()
    sub = None
    try:
        sub = router.declare_subscriber("pdcov/*/status", fleet.on_sample)
        configs = []
        for v in demo.vehicles:
            cfg = out / "configs" / f"{v.vehicle_id}.yaml"
            write_text_atomic(cfg, yaml.safe_dump(vehicle_config(
                demo.mission_doc, v, router_ep, out / "state" / v.vehicle_id, demo.speed)))
            configs.append(cfg)
        py = sys.executable
        watch = [py, "-m", "pdcov.cli", "watch", "--config", str(configs[0]), "--mode",
                 "client", "--zenoh-connect", router_ep, "--no-multicast-scouting",
                 "--record", str(report)]
        if demo.web is not None:
            watch += ["--web", f"{demo.web[0]}:{demo.web[1]}"]
        if demo.plain:
            watch.append("--plain")
        watcher = children.start("watcher", watch, None)
        sims = []
        for v, cfg in zip(demo.vehicles, configs, strict=True):
            # The simulator is the TCP server of the MAVLink link: started first, so that
            # the daemon's first connection attempt finds it listening.
            link = f"tcp:127.0.0.1:{free_port()}"
            sims.append((v, children.start(
                f"simulator {v.vehicle_id}",
                [py, "-m", "pdcov_sitl.cli", "fly", "--config", str(cfg), "--plan",
                 str(v.plan), "--out", str(out / "sim" / v.vehicle_id), "--connect", link,
                 "--speed", f"{demo.speed:g}", "--system-id", str(v.system_id)],
                out / "logs" / f"sim-{v.vehicle_id}.log")))
            children.start(f"daemon {v.vehicle_id}",
                           [py, "-m", "pdcov.cli", "serve", "--config", str(cfg),
                            "--connect", link], out / "logs" / f"serve-{v.vehicle_id}.log")
        deadline = time.monotonic() + demo.timeout_s
        while any(p.poll() is None for _, p in sims):
            _check_alive(children, skip={p for _, p in sims})
            if time.monotonic() > deadline:
                raise PdcovError(f"demo: the flights took longer than {demo.timeout_s:g} s"
                                 f"{children.log_ends()}")
            time.sleep(0.2)
        for v, p in sims:
            if p.returncode != 0:
                raise PdcovError(f"demo: the simulator of {v.vehicle_id} failed (exit "
                                 f"{p.returncode}){children.log_end(p)}")
        ids = [v.vehicle_id for v in demo.vehicles]
        end = time.monotonic() + 60.0
        while not fleet.settled(ids, SETTLE_S):
            _check_alive(children, skip={p for _, p in sims})  # the sims have landed
            if time.monotonic() > end:
                raise PdcovError("demo: the daemons' grids did not settle within 60 s"
                                 f"{children.log_ends()}")
            time.sleep(0.2)
        # The watcher applies the last tiles within a tiles period; give it one second.
        time.sleep(1.0)
        if children.terminate(watcher, 60.0) != 0:
            raise PdcovError(f"demo: the watcher exited with status {watcher.returncode}")
        for name, p in children.procs:
            if name.startswith("daemon") and children.terminate(p, 30.0) != 0:
                raise PdcovError(f"demo: {name} exited with status {p.returncode}"
                                 f"{children.log_end(p)}")
        final = fleet.final()
        summary = {"wall_s": round(time.monotonic() - t0, 1), "report": str(report),
                   "status": final}
        (out / "demo.json").write_text(json.dumps(summary, indent=2) + "\n")
        print(f"\npdcov demo: {len(ids)} vehicle(s) flew and were evaluated in "
              f"{summary['wall_s']:.0f} s.", file=say)
        print(f"report: {report / 'fleet'} (heatmap.png, thresholds.png, metrics.json, "
              f"grid.npz)\nper vehicle: {', '.join(str(report / i) for i in ids)}; "
              f"flights (tlog): {out / 'sim'}; logs: {out / 'logs'}", file=say, flush=True)
        return summary
    finally:
        try:
            children.stop_all()
        finally:  # also after a second Ctrl-C during stop_all
            if sub is not None:
                sub.undeclare()
            router.close()
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def _interrupt(signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _interrupt_on_signals() -> dict[int, Any]:
    """SIGINT (even when inherited as ignored), SIGTERM and SIGHUP raise KeyboardInterrupt,
    so that the children are stopped however the demo is stopped; returns the handlers
    to restore."""
    previous: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        previous[sig] = signal.getsignal(sig)
        signal.signal(sig, _interrupt)
    return previous


def _check_alive(children: Children, skip: set[Any] | frozenset = frozenset()) -> None:
    for name, p in children.procs:
        if p not in skip and p.poll() is not None:
            raise PdcovError(f"demo: the {name} stopped (exit {p.returncode})"
                             f"{children.log_end(p)}")

