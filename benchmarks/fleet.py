"""``python -m benchmarks.fleet``: a fleet through one Zenoh router (issue 15, "Fleet load").

N simulated vehicles (``pdcov-sitl fly``, each its own MAVLink system id and vehicle id,
a lawnmower over its own 30 m square), their N daemons (``pdcov serve``, peer sessions to
the router, the bus defaults: status every 1 s, tiles every 0.2 s) and 2 watchers
(``pdcov watch --record``, client sessions) through one Zenoh router in this process
(router mode, tcp on loopback, multicast scouting off). When every simulator has landed
and the daemons' grids have settled, the watchers are stopped (each writes the grid it
rebuilt per vehicle) and then the daemons (each writes its checkpoint): every watcher must
hold every vehicle's grid exactly, cell for cell (log-miss sums and counts).

Figures, per vehicle: the daemon's CPU (user + system seconds over the flight's wall time,
/proc/PID/stat), the simulator's, and the Zenoh payload bytes per second of status and
tiles as the router forwards them (a subscriber on the router's session; Zenoh's own
framing not counted); the watchers' CPU. ``--speed`` runs the simulators faster than real
time: bytes and CPU per second of wall time then carry ``speed`` seconds of flight.

The security checks that share its docs block are security.py's; shared helpers are in
harness.py and report.py.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from shapely.geometry import box

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.keys import parse_key
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.status import decode_status
from pdcov.core.geodesy import Origin
from pdcov.ground.demo import Children, FleetStatus, free_port
from pdcov.planning.patterns import lawnmower
from pdcov.planning.plan_files import write_plan
from tests.support.checkpoint_files import read_checkpoint
from tests.support.harness import small_mission
from tests.support.marked_block import write_marked_block

from .daemon import cpu_s, memory_bytes
from .security import SECURITY_TESTS, security_checks, security_table

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "reliability.md"
DOC_START, DOC_END = "<!-- fleet-security:start -->", "<!-- fleet-security:end -->"

MISSION = small_mission(coverage={"min_revisit_s": 1.0})
ORIGIN = MISSION["origin"]
GRID_ARRAYS = ("log_miss_d", "log_miss_fa", "n_obs", "limiting")
SETTLE_S = 3.0


@dataclass(frozen=True)
class VehicleFigures:
    vehicle_id: str
    frames: int
    daemon_cpu_s: float
    sim_cpu_s: float
    daemon_rss_peak_mb: float
    status_bytes: int
    status_messages: int
    tiles_bytes: int
    tiles_messages: int
    status_uptime_s: float  # the daemon's clock from its first status heard to its last

    @property
    def status_per_uptime_s(self) -> float:
        """Statuses per second of the daemon's own clock (its ``uptime_s``): what its
        schedule sent, whatever the machine's load."""
        return (self.status_messages - 1) / self.status_uptime_s \
            if self.status_uptime_s > 0 else 0.0

    @property
    def status_bytes_per_uptime_s(self) -> float:
        """Status payload bytes per second of the daemon's clock (mean size x rate): the
        1 kB/s budget (issue 13)."""
        return self.status_bytes / self.status_messages * self.status_per_uptime_s \
            if self.status_messages else 0.0


@dataclass(frozen=True)
class FleetRun:
    vehicles: tuple[VehicleFigures, ...]
    watchers: int
    speed: float
    flight_wall_s: float
    window_s: float  # daemons' start to the grids settled: what CPU and bytes are over
    total_wall_s: float
    watcher_cpu_s: tuple[float, ...]
    mismatches: tuple[str, ...]  # "watcher w, vehicle v: what differs"; empty: all exact


class Traffic:
    """Payload bytes and messages per (vehicle id, kind), heard on the router's session,
    and each vehicle's first and last status ``uptime_s`` (the daemon's clock)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.bytes: dict[tuple[str, str], int] = defaultdict(int)
        self.count: dict[tuple[str, str], int] = defaultdict(int)
        self.uptime_s: dict[str, tuple[float, float]] = {}

    def __call__(self, sample) -> None:
        try:
            vid, kind = parse_key(str(sample.key_expr))
        except Exception:  # noqa: BLE001 - not a pdcov key: not ours to count
            return
        payload = sample.payload.to_bytes()
        uptime_s = None
        if kind == "status":
            try:
                uptime_s = float(decode_status(payload)["uptime_s"])
            except BusPayloadError:
                pass  # counted in bytes, not on the clock
        with self.lock:
            self.bytes[(vid, kind)] += len(payload)
            self.count[(vid, kind)] += 1
            if uptime_s is not None:
                first, _ = self.uptime_s.get(vid, (uptime_s, uptime_s))
                self.uptime_s[vid] = (first, uptime_s)

    def uptime_span_s(self, vid: str) -> float:
        first, last = self.uptime_s.get(vid, (0.0, 0.0))
        return last - first


def vehicle_id(i: int) -> str:
    return f"uav{i + 1:02d}"


def write_inputs(folder: Path, n: int, router_ep: str) -> tuple[Path, list[Path]]:
    """The plan (a lawnmower over the square at 10 m, 5 m/s) and each vehicle's config."""
    plan = write_plan(folder / "plan.plan",
                      lawnmower(box(0.0, 0.0, 30.0, 30.0), 10.0, 0.0, 10.0, 5.0),
                      Origin(ORIGIN["lat_deg"], ORIGIN["lon_deg"], 0.0))
    configs = []
    for i in range(n):
        vid = vehicle_id(i)
        doc = dict(MISSION, vehicle_id=vid, log={"system_id": i + 1})
        doc["link"] = {"system_id": i + 1}
        doc["bus"] = {"mode": "peer", "connect": [router_ep], "listen": [],
                      "multicast_scouting": False}
        doc["service"] = {"state_dir": str(folder / "state" / vid), "checkpoint_period_s": 5.0}
        path = folder / "configs" / f"{vid}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        configs.append(path)
    return plan, configs


def compare(watcher_dir: Path, state_dir: Path, vid: str) -> str | None:
    """None when the watcher's rebuilt grid equals the daemon's checkpoint, else why not."""
    got = watcher_dir / vid / "grid.npz"
    if not got.is_file():
        return f"{got} missing"
    b = read_checkpoint(state_dir / vid / "checkpoint")
    with np.load(got) as a:
        for key in GRID_ARRAYS:
            if key not in a.files:
                return f"{key} missing from {got}"
            if a[key].shape != b[key].shape or not np.array_equal(a[key], b[key]):
                return f"{key} differs ({int(np.sum(a[key] != b[key]))} cells)" \
                    if a[key].shape == b[key].shape else f"{key} shape {a[key].shape}"
    return None


def run(folder: Path, n: int, speed: float, watchers: int = 2,
        timeout_s: float = 600.0) -> FleetRun:
    """Fly the fleet in ``folder``; raises RuntimeError naming the log of a failed child."""
    py = sys.executable
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    plan, configs = write_inputs(folder, n, router_ep)
    (folder / "logs").mkdir(exist_ok=True)
    t0 = time.monotonic()
    router = open_session(BusConfig(mode="router", listen=(router_ep,),
                                    multicast_scouting=False))
    children = Children()
    traffic, fleet = Traffic(), FleetStatus()
    subs = []
    try:
        subs = [router.declare_subscriber("pdcov/*/status", traffic),
                router.declare_subscriber("pdcov/*/tiles", traffic),
                router.declare_subscriber("pdcov/*/status", fleet.on_sample)]
        watch_procs = [children.start(
            f"watcher {w}", [py, "-m", "pdcov.cli", "watch", "--mode", "client",
                             "--zenoh-connect", router_ep, "--no-multicast-scouting",
                             "--plain", "--record", str(folder / f"watcher{w}")],
            folder / "logs" / f"watcher{w}.log") for w in range(watchers)]
        sims, daemons = [], []
        for i, cfg in enumerate(configs):
            vid, link = vehicle_id(i), f"tcp:127.0.0.1:{free_port()}"
            sims.append(children.start(
                f"simulator {vid}",
                [py, "-m", "pdcov_sitl.cli", "fly", "--config", str(cfg), "--plan", str(plan),
                 "--out", str(folder / "sim" / vid), "--connect", link, "--speed",
                 f"{speed:g}", "--system-id", str(i + 1), "--seed", str(i)],
                folder / "logs" / f"sim-{vid}.log"))
            daemons.append(children.start(
                f"daemon {vid}", [py, "-m", "pdcov.cli", "serve", "--config", str(cfg),
                                  "--connect", link], folder / "logs" / f"serve-{vid}.log"))
        t_fly = time.monotonic()
        deadline = t_fly + timeout_s
        sim_cpu = [0.0] * n
        while any(p.poll() is None for p in sims):
            for i, p in enumerate(sims):
                if p.poll() is None:
                    sim_cpu[i] = max(sim_cpu[i], _cpu(p.pid))
            _check(children, sims, folder)
            if time.monotonic() > deadline:
                raise RuntimeError(f"the flights took longer than {timeout_s:g} s")
            time.sleep(0.2)
        flight_wall_s = time.monotonic() - t_fly
        for i, p in enumerate(sims):
            if p.returncode != 0:
                raise RuntimeError(f"simulator {vehicle_id(i)} exit {p.returncode}; see "
                                   f"{folder / 'logs'}")
        ids = [vehicle_id(i) for i in range(n)]
        end = time.monotonic() + 120.0
        while not fleet.settled(ids, SETTLE_S):
            _check(children, sims, folder)
            if time.monotonic() > end:
                raise RuntimeError(f"the daemons' grids did not settle; see {folder / 'logs'}")
            time.sleep(0.2)
        daemon_cpu = [_cpu(p.pid) for p in daemons]
        rss = [memory_bytes(p.pid).get("VmHWM", 0) / 2**20 for p in daemons]
        window_s = time.monotonic() - t_fly  # daemons started: flights, then settling
        with traffic.lock:
            sent = {k: (traffic.bytes[k], traffic.count[k]) for k in list(traffic.bytes)}
            uptime_s = {vid: traffic.uptime_span_s(vid) for vid in ids}
        time.sleep(2.0)  # the watchers apply the last tiles (and re-sync a trailing gap)
        watcher_cpu = tuple(_cpu(p.pid) for p in watch_procs)
        for w, p in enumerate(watch_procs):
            if children.terminate(p, 60.0) != 0:
                raise RuntimeError(f"watcher {w} exit {p.returncode}; see {folder / 'logs'}")
        for i, p in enumerate(daemons):
            if children.terminate(p, 30.0) != 0:
                raise RuntimeError(f"daemon {vehicle_id(i)} exit {p.returncode}")
        final = fleet.final()
    finally:
        children.stop_all()
        for s in subs:
            s.undeclare()
        router.close()
    mismatches = tuple(
        f"watcher {w}, {vid}: {why}" for w in range(watchers) for vid in ids
        if (why := compare(folder / f"watcher{w}", folder / "state", vid)) is not None)
    vehicles = tuple(VehicleFigures(
        vid, int(final.get(vid, {}).get("frames", {}).get("used", 0)), daemon_cpu[i],
        sim_cpu[i], rss[i], *sent.get((vid, "status"), (0, 0)),
        *sent.get((vid, "tiles"), (0, 0)), uptime_s[vid]) for i, vid in enumerate(ids))
    return FleetRun(vehicles, watchers, speed, flight_wall_s, window_s,
                    time.monotonic() - t0, watcher_cpu, mismatches)


def _cpu(pid: int) -> float:
    try:
        return cpu_s(pid)
    except (OSError, IndexError):
        return 0.0


def _check(children: Children, sims: list, folder: Path) -> None:
    for name, p in children.procs:
        if p not in sims and p.poll() is not None:
            raise RuntimeError(f"the {name} stopped (exit {p.returncode}); see "
                               f"{folder / 'logs'}")


def markdown(r: FleetRun, command: str) -> str:
    """The figures as the table docs/reliability.md shows."""
    n = len(r.vehicles)
    wall = r.window_s
    lines = [f"`{command}`: {n} vehicles, {r.watchers} watchers, one router; simulators at "
             f"--speed {r.speed:g}; flights {r.flight_wall_s:.0f} s of wall time, CPU and "
             f"bytes over {wall:.0f} s (daemons' start to grids settled), whole run "
             f"{r.total_wall_s:.0f} s; {os.cpu_count()} CPUs.", "",
             "| vehicle | frames | daemon CPU s (share of a core) | simulator CPU s | daemon "
             "RSS peak MB | status B/s of the daemon's clock (B/msg, msgs) | tiles B/s "
             "(msgs) |",
             "|---|---|---|---|---|---|---|"]
    for v in r.vehicles:
        lines.append(f"| {v.vehicle_id} | {v.frames} | {v.daemon_cpu_s:.1f} "
                     f"({v.daemon_cpu_s / wall:.1%}) | {v.sim_cpu_s:.1f} | "
                     f"{v.daemon_rss_peak_mb:.0f} | {v.status_bytes_per_uptime_s:,.0f} "
                     f"({v.status_bytes / max(v.status_messages, 1):,.0f}, "
                     f"{v.status_messages}) | {v.tiles_bytes / wall:,.0f} "
                     f"({v.tiles_messages}) |")
    mean = {k: float(np.mean([getattr(v, k) for v in r.vehicles]))
            for k in ("daemon_cpu_s", "sim_cpu_s", "status_bytes_per_uptime_s", "tiles_bytes")}
    lines.append(f"| mean | | {mean['daemon_cpu_s']:.1f} ({mean['daemon_cpu_s'] / wall:.1%}) "
                 f"| {mean['sim_cpu_s']:.1f} | | {mean['status_bytes_per_uptime_s']:,.0f} | "
                 f"{mean['tiles_bytes'] / wall:,.0f} |")
    lines += ["", f"Watchers' CPU: {', '.join(f'{c:.1f} s' for c in r.watcher_cpu_s)}. "
              f"Grids: {n * r.watchers - len(r.mismatches)} of {n * r.watchers} "
              "(watcher, vehicle) pairs equal the daemon's checkpoint cell for cell"
              + (": " + "; ".join(r.mismatches) if r.mismatches else ".")]
    return "\n".join(lines)


def docs_block(fleet_md: str, sec: dict[str, str], command: str) -> str:
    """docs/reliability.md's fleet and security sections."""
    return f"""## Fleet load

Regenerated with the security checks below by `{command}`; CI flies 4 vehicles at
`--speed 2` with the same code (`tests/simulators/test_fleet.py`, about a minute). N simulators
(`pdcov-sitl fly`, JSBSim, each its own system id and vehicle id, a lawnmower over its own
30 m square at 5 frames/s), their N daemons (`pdcov serve`, peer sessions, bus defaults:
status 1 s, tiles 0.2 s) and 2 watchers (`pdcov watch --record`, client sessions) through
one Zenoh router in the benchmark's process (router mode, TCP on loopback, multicast
scouting off). When the flights have landed and the grids settled the watchers stop (each
writes the grid it rebuilt per vehicle), then the daemons (each writes its checkpoint), and
every watcher's grid of every vehicle is compared with that daemon's checkpoint cell for
cell. Daemon CPU is user + system time from its start (its Python start-up and
imports included) over the window; bytes are Zenoh payloads as the router forwards them
to each watcher (Zenoh's framing not counted). Status bytes per second are over the
daemon's own clock (its statuses' `uptime_s`, first to last heard: the mean size times
the rate its schedule kept), so they do not shrink or grow with the machine's load; tiles
over the window. Machine: 2 cores shared with other work.

{fleet_md}

## Security

Every check is a test on loopback with real processes and sessions: `{' '.join(SECURITY_TESTS)}`
— **{sec['tests']}** ({sec['tests_wall_s']} s here).

{security_table(sec)}

Found and fixed on the way: a Zenoh session with `bus.listen` empty listened on Zenoh's
default, a random plain-TCP port on every interface (peer mode) — a daemon reachable
directly, past the router's access control (in the ACL test a forged put from uav2 reached
uav1 that way). A session now listens only where configured. And the status was
1.4-1.6 kB per message at 1 Hz: the rarely changing detail now goes out in full statuses
only (docs/protocol.md "full and brief statuses").

Deploying it: make a CA, a certificate for the router whose names include the address the
vehicles dial, one per vehicle with the vehicle id as its common name and one for the ground
station (`ground`); put them in `/etc/pdcov/tls/` and use the three example files
(`systemd/zenoh/router.json5` for the ground router — a rule and a subject per vehicle;
`aircraft.json5` as the daemon's `bus.config_file` with `bus.connect: [tls/ROUTER:7447]`
and `listen: []`; `ground.json5` for `pdcov watch --zenoh-config`). Access control by
identity needs mutual TLS (or Zenoh's user/password authentication); with TLS alone the
link is encrypted and the router authenticated, but every client is anonymous."""


def write_docs(block: str) -> None:
    """Put ``block`` between the fleet-security markers of docs/reliability.md."""
    write_marked_block(DOC, block, DOC_START, DOC_END)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.fleet", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", type=int, default=10, help="fleet size (10)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="simulator speed-up (1: real time)")
    parser.add_argument("--watchers", type=int, default=2, help="watchers (2)")
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it")
    parser.add_argument("--json", type=Path, metavar="PATH",
                        help="also write the figures, the mismatches and the table to PATH "
                             "as JSON")
    parser.add_argument("--write-docs", action="store_true",
                        help=f"also run the security checks and write both into "
                             f"{DOC.relative_to(ROOT)} (between its fleet-security markers)")
    args = parser.parse_args(argv)
    command = (f"python -m benchmarks.fleet --vehicles {args.vehicles} --speed {args.speed:g}"
               + (f" --watchers {args.watchers}" if args.watchers != 2 else ""))
    docs_command = command + " --write-docs"
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        result = run(args.keep, args.vehicles, args.speed, args.watchers)
    else:
        with tempfile.TemporaryDirectory(prefix="pdcov-fleet-") as tmp:
            result = run(Path(tmp), args.vehicles, args.speed, args.watchers)
    table = markdown(result, docs_command if args.write_docs else command)
    print(table)
    if args.write_docs:
        sec = security_checks()
        print(f"security: {sec}")
        write_docs(docs_block(table, sec, docs_command))
        print(f"wrote {DOC}")
    if args.json:
        args.json.write_text(json.dumps({"vehicles": [v.__dict__ for v in result.vehicles],
                                         "flight_wall_s": result.flight_wall_s,
                                         "window_s": result.window_s,
                                         "watcher_cpu_s": result.watcher_cpu_s,
                                         "mismatches": result.mismatches,
                                         "table": table}, indent=1))
    return 1 if result.mismatches else 0


if __name__ == "__main__":
    sys.exit(main())
