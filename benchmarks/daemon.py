"""``python -m benchmarks.daemon``: ``pdcov serve`` fed S1 telemetry live by the simulator.

The simulator (``pdcov-sitl fly``, real time) flies S1's lawnmower (1 km square at 1 m cells,
1920x1080 camera 20 deg off nadir at 60 m, 10 m/s) and speaks MAVLink to the daemon over UDP;
the daemon counts 30 frames/s and publishes over Zenoh (peer, loopback, its defaults: status
every 1 s, tiles every 0.2 s within 64 kB/s); a subscriber in this process receives them.
Over a window of ``--window-s`` seconds that starts with the first frame counted:

* CPU share of one core: the daemon process's user+system time over wall time
  (/proc/PID/stat); the simulator's is not counted.
* frames skipped in the window, by reason (the target is none);
* publish-to-receive latency p50/p99 of status and tiles: the daemon's session stamps each
  put with its clock (Zenoh timestamping, ``bus.zenoh``), the subscriber compares with its
  own (same machine, same clock);
* Zenoh payload bytes/s of status and of tiles;
* the daemon's resident memory: peak (VmHWM) and at the end (VmRSS).

Targets (issue 13): <= 25 % of one core, no frame skipped, p99 < 100 ms, RSS < 300 MB,
status < 1 kB/s, tiles < 64 kB/s. ``--smoke`` runs the tiny S1 for a few seconds (CI; its
figures mean nothing).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml
from shapely.geometry import box

from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.status import decode_status
from pdcov.config.load import load_mission
from pdcov.core.geodesy import Origin
from pdcov.core.mission import AltitudeFrame
from pdcov.planning.patterns import lawnmower
from pdcov.planning.plan_files import write_plan
from pdcov.planning.terrain_follow import TerrainFollowing, follow_terrain
from tests.support.harness import child, free_port, serve_args
from tests.support.scenarios import ORIGIN_LAT_DEG, ORIGIN_LON_DEG, Scenario, scenarios

from .report import Row, machine, markdown

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` (its threads included)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14, 15)


def memory_bytes(pid: int) -> dict[str, int]:
    """VmHWM (peak) and VmRSS of process ``pid`` in bytes."""
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmHWM", "VmRSS"):
            out[key] = int(value.split()[0]) * 1024
    return out


def write_inputs(folder: Path, sc: Scenario, mav_port: int, zenoh_port: int) -> tuple[Path, Path]:
    """The mission config (the scenario plus the daemon's sections) and its lawnmower plan;
    over a scenario's relief (S5) the DEM is written beside them and the plan follows the
    terrain (AMSL waypoints, planning/terrain_follow.py), as the simulator then flies it."""
    dem = None if sc.relief is None else sc.relief.write_geotiff(folder / "dem.tif")
    doc = sc.mission_doc(None if dem is None else str(dem))
    doc["link"] = {"connect": [f"udpin:127.0.0.1:{mav_port}"], "attitude_hz": 30,
                   "position_hz": 10}
    doc["bus"] = {"mode": "peer", "listen": [f"tcp/127.0.0.1:{zenoh_port}"],
                  "multicast_scouting": False, "zenoh": {"timestamping/enabled": True}}
    doc["service"] = {"state_dir": str(folder / "state")}
    config = folder / "mission.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    plan = lawnmower(box(0.0, 0.0, sc.side_m, sc.side_m), sc.spacing_m, 0.0, sc.alt_m,
                     sc.speed_mps)
    origin = Origin(ORIGIN_LAT_DEG, ORIGIN_LON_DEG, 0.0)
    if dem is not None:
        mission = load_mission(config)
        assert mission.terrain is not None
        plan = follow_terrain(plan, mission.terrain, TerrainFollowing(AltitudeFrame.AMSL))
        origin = mission.origin()
    return config, write_plan(folder / "plan.plan", plan, origin)


@dataclass
class Received:
    """What the subscriber got: per key, receive wall times, payload sizes, latencies."""

    t_s: dict[str, list[float]] = field(default_factory=lambda: {"status": [], "tiles": []})
    size: dict[str, list[int]] = field(default_factory=lambda: {"status": [], "tiles": []})
    latency_s: dict[str, list[float]] = field(
        default_factory=lambda: {"status": [], "tiles": []})
    status: dict | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def callback(self, kind: str):
        def on_sample(sample) -> None:
            now = time.time()
            payload = sample.payload.to_bytes()
            ts = sample.timestamp
            with self.lock:
                self.t_s[kind].append(now)
                self.size[kind].append(len(payload))
                if ts is not None:
                    self.latency_s[kind].append(now - ts.get_time().timestamp())
                if kind == "status":
                    self.status = decode_status(payload)
        return on_sample

    def last_status(self) -> dict | None:
        with self.lock:
            return self.status

    def in_window(self, kind: str, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """(sizes, latencies) of the samples received in [t0, t1] (wall s)."""
        with self.lock:
            t = np.array(self.t_s[kind])
            size = np.array(self.size[kind])
            lat = np.array(self.latency_s[kind])
        keep = (t >= t0) & (t <= t1)
        return size[keep], (lat[keep] if len(lat) == len(t) else lat)


def wait_status(rx: Received, predicate, timeout_s: float, what: str,
                daemon: subprocess.Popen, log: Path) -> dict:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if daemon.poll() is not None:
            tail = log.read_text(errors="replace")[-2000:]
            raise RuntimeError(f"pdcov serve exited with {daemon.returncode}:\n{tail}")
        st = rx.last_status()
        if st is not None and predicate(st):
            return st
        time.sleep(0.05)
    raise TimeoutError(f"no status with {what} within {timeout_s:g} s; last: "
                       f"{rx.last_status()}")


@dataclass(frozen=True)
class DaemonRun:
    window_s: float
    cpu_share: float
    frames_used: int
    skipped: dict[str, int]
    frames_expected: float
    autopilot_s: float
    pending: int
    latency_ms: dict[str, tuple[float, float]]
    bytes_per_s: dict[str, float]
    memory: dict[str, int]


def run(folder: Path, sc: Scenario, window_s: float, start_timeout_s: float) -> DaemonRun:
    """Simulator -> ``pdcov serve`` -> subscriber; measure over ``window_s`` seconds."""
    mav_port, zenoh_port = free_port(socket.SOCK_DGRAM), free_port()
    config, plan = write_inputs(folder, sc, mav_port, zenoh_port)
    keys = VehicleKeys(sc.mission_doc()["vehicle_id"])
    session = open_session(BusConfig(mode="peer", connect=(f"tcp/127.0.0.1:{zenoh_port}",),
                                     multicast_scouting=False))
    rx = Received()
    subs = [session.declare_subscriber(keys.status, rx.callback("status")),
            session.declare_subscriber(keys.tiles, rx.callback("tiles"))]
    try:
        with child(serve_args(config), folder / "serve.log", grace_s=20) as daemon, \
             child([sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(config),
                    "--plan", str(plan), "--out", str(folder / "sim"), "--connect",
                    f"udpout:127.0.0.1:{mav_port}", "--speed", "1"], folder / "sim.log"):
            first = wait_status(rx, lambda s: s["frames"]["used"] > 0, start_timeout_s,
                                "frames counted", daemon, folder / "serve.log")
            cpu0, t0 = cpu_s(daemon.pid), time.time()
            time.sleep(window_s)
            cpu1, t1 = cpu_s(daemon.pid), time.time()
            last = rx.last_status()
            memory = memory_bytes(daemon.pid)
    finally:
        for s in subs:
            s.undeclare()
        session.close()
    wall = t1 - t0
    skipped = {k: v - first["frames"]["skipped"].get(k, 0)
               for k, v in last["frames"]["skipped"].items()}
    used = last["frames"]["used"] - first["frames"]["used"]
    span_s = (last["frames"]["last_t_s"] or 0.0) - (first["frames"]["last_t_s"] or 0.0)
    latency, rates = {}, {}
    for kind in ("status", "tiles"):
        size, lat = rx.in_window(kind, t0, t1)
        rates[kind] = float(size.sum()) / wall
        latency[kind] = ((float(np.percentile(lat, 50)) * 1e3, float(np.percentile(lat, 99))
                          * 1e3) if len(lat) else (float("nan"), float("nan")))
    return DaemonRun(wall, (cpu1 - cpu0) / wall, used, {k: v for k, v in skipped.items() if v},
                     span_s * sc.rate_hz, (last["t_s"] or 0.0) - (first["t_s"] or 0.0),
                     last["frames"]["pending"], latency, rates, memory)


def rows(r: DaemonRun, sc: Scenario) -> list[Row]:
    skipped = sum(r.skipped.values())
    reasons = ", ".join(f"{k}: {v}" for k, v in sorted(r.skipped.items())) or "none"
    p99 = max(r.latency_ms["status"][1], r.latency_ms["tiles"][1])
    rss = r.memory.get("VmHWM", 0) / 2**20
    pace = r.autopilot_s / r.window_s
    return [
        Row(f"{sc.name} live", "setup", f"{sc.describe().rsplit(', ', 1)[0]}; pdcov-sitl fly in "
            f"real time, measured over {r.window_s:.0f} s"),
        # The simulator must keep real time, or the daemon gets fewer frames per second
        # than the flight has and every figure below is too kind.
        Row(f"{sc.name} live", "simulator pace", f"{pace:.2f}x real time (autopilot clock "
            f"{r.autopilot_s:.1f} s in {r.window_s:.1f} s)", ">= 0.95x (else the machine is "
            "too loaded to judge the rest)", pace >= 0.95),
        Row(f"{sc.name} live", "daemon CPU (share of one core)", f"{r.cpu_share:.1%}", "<= 25 %",
            r.cpu_share <= 0.25),
        Row(f"{sc.name} live", "frames skipped", f"{skipped} of {r.frames_used + skipped} "
            f"({reasons}); {r.frames_expected:.0f} frame times in the window, "
            f"{r.pending} pending at its end", "0", skipped == 0),
        Row(f"{sc.name} live", "publish -> receive latency p50 / p99",
            f"status {r.latency_ms['status'][0]:.1f} / {r.latency_ms['status'][1]:.1f} ms, "
            f"tiles {r.latency_ms['tiles'][0]:.1f} / {r.latency_ms['tiles'][1]:.1f} ms",
            "p99 < 100 ms", p99 < 100.0),
        Row(f"{sc.name} live", "Zenoh status", f"{r.bytes_per_s['status']:,.0f} B/s", "< 1 kB/s",
            r.bytes_per_s["status"] < 1000),
        Row(f"{sc.name} live", "Zenoh tiles", f"{r.bytes_per_s['tiles'] / 1e3:,.1f} kB/s",
            "< 64 kB/s", r.bytes_per_s["tiles"] < 64000),
        Row(f"{sc.name} live", "daemon memory (RSS peak / end)",
            f"{rss:,.0f} / {r.memory.get('VmRSS', 0) / 2**20:,.0f} MB", "< 300 MB",
            rss < 300),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.daemon", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--window-s", type=float,
                        help="seconds measured once frames are counted (60; --smoke: 3)")
    parser.add_argument("--smoke", action="store_true", help="tiny scenario, a few seconds")
    parser.add_argument("--scenario", choices=("S1", "S5"), default="S1",
                        help="S1 on flat ground (default), or S5: the same survey over a 1 km "
                             "valley DEM, the plan following the terrain")
    parser.add_argument("--json", type=Path, metavar="PATH",
                        help="also write the figures and each row's verdict (null: no target) "
                             "to PATH as JSON")
    args = parser.parse_args(argv)
    sc = scenarios(args.smoke)[args.scenario]
    window = args.window_s if args.window_s is not None else (3.0 if args.smoke else 60.0)
    with tempfile.TemporaryDirectory(prefix="pdcov-bench-daemon-") as tmp:
        result = run(Path(tmp), sc, window, start_timeout_s=120.0)
    command = ("python -m benchmarks.daemon" + (" --smoke" if args.smoke else "")
               + ("" if args.scenario == "S1" else f" --scenario {args.scenario}"))
    table = rows(result, sc)
    print(markdown(table, machine(), command))
    print(json.dumps({"skipped": result.skipped, "memory": result.memory}), file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps({"run": asdict(result),
                                         "rows_ok": [row.ok for row in table]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
