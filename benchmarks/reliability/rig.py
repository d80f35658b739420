"""The rig of the reliability scenarios: a small mission, a lawnmower plan, ports, the
simulator's and the daemon's command lines, the watcher in a thread, and grid comparisons."""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import math
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from shapely.geometry import box

from pdcov.bus.grid_state import GridState
from pdcov.bus.session import BusConfig
from pdcov.bus.status import decode_status, merge_status
from pdcov.core.geodesy import Origin
from pdcov.ground.live import WatchShell
from pdcov.ground.watcher import Watcher
from pdcov.planning.patterns import lawnmower
from pdcov.planning.plan_files import write_plan
from tests.support.harness import free_port, serve_args, small_mission

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "reliability.md"
VEHICLE = "rel1"
LAT_DEG, LON_DEG, GROUND_M = 47.397742, 8.545594, 488.0
ALT_M, SPACING_M, SPEED_MPS = 10.0, 10.0, 5.0


def side_for(flight_s: float) -> float:
    """The side (m) of a square whose lawnmower at SPACING_M and SPEED_MPS lasts about
    ``flight_s`` simulated seconds."""
    return max(30.0, round(math.sqrt(flight_s * SPACING_M * SPEED_MPS * 0.93)))


@dataclass
class Rig:
    """Files and ports of one scenario."""

    folder: Path
    config: Path
    plan: Path
    zenoh_port: int
    mav_port: int

    @property
    def state(self) -> Path:
        return self.folder / "state"


def make_rig(folder: Path, side_m: float, *, checkpoint_period_s: float = 2.0,
             state_dir: Path | None = None) -> Rig:
    folder.mkdir(parents=True, exist_ok=True)
    zport, mport = free_port(), free_port()
    doc = small_mission(
        vehicle_id=VEHICLE,
        domain={"polygon_enu_m": [[0, 0], [side_m, 0], [side_m, side_m], [0, side_m]],
                "cell_size_m": 1.0},
        coverage={"min_revisit_s": 1.0},
        link={"connect": [f"udpin:127.0.0.1:{mport}"]},
        bus={"mode": "peer", "connect": [f"tcp/127.0.0.1:{zport}"],
             "listen": ["tcp/127.0.0.1:0"], "multicast_scouting": False,
             "status_period_s": 0.5, "tiles_period_s": 0.2,
             "tiles_max_bytes_per_s": 1 << 21},
        service={"state_dir": str(state_dir or folder / "state"),
                 "checkpoint_period_s": checkpoint_period_s})
    config = folder / "mission.yaml"
    config.write_text(yaml.safe_dump(doc, sort_keys=False))
    plan = lawnmower(box(0.0, 0.0, side_m, side_m), SPACING_M, 0.0, ALT_M, SPEED_MPS)
    path = write_plan(folder / "plan.plan", plan, Origin(LAT_DEG, LON_DEG, GROUND_M))
    return Rig(folder, config, path, zport, mport)


def serve(rig: Rig) -> list[str]:
    return serve_args(rig.config)


def fly(rig: Rig, speed: float, faults: str | None = None, seed: int = 0) -> list[str]:
    args = [sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(rig.config),
            "--plan", str(rig.plan), "--out", str(rig.folder / "sim"), "--connect",
            f"udpout:127.0.0.1:{rig.mav_port}", "--speed", f"{speed:g}", "--seed", str(seed)]
    return args + (["--faults", faults] if faults else [])


def sigterm(p: subprocess.Popen, timeout_s: float = 30.0) -> int:
    p.send_signal(signal.SIGTERM)
    return p.wait(timeout=timeout_s)


class WatcherThread:
    """``pdcov watch``'s shell and decisions in a thread (its own event loop and Zenoh client
    session), following VEHICLE; keeps every status (brief ones merged over the last full
    one) with its receive time (wall s)."""

    def __init__(self, zenoh_port: int) -> None:
        self.watcher = Watcher(VEHICLE)
        self.statuses: list[tuple[float, dict]] = []
        self.bad: list[str] = []
        bus = BusConfig(mode="client", connect=(f"tcp/127.0.0.1:{zenoh_port}",),
                        multicast_scouting=False)
        self.shell = WatchShell(self.watcher, bus, record=self._record)
        self.loop = asyncio.new_event_loop()
        self._stop: asyncio.Event | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)

        async def main() -> None:
            self._stop = asyncio.Event()
            await self.shell.run(self._stop)
        self.loop.run_until_complete(main())

    def _record(self, vehicle_id: str, kind: str, payload: bytes) -> None:
        if kind == "status":
            try:
                doc = merge_status(self.status(), decode_status(payload))
            except Exception as exc:  # noqa: BLE001 - counted: the daemon sent it
                self.bad.append(str(exc))
                return
            self.statuses.append((time.time(), doc))

    def _on_loop(self, fn):
        async def call():
            return fn()
        return asyncio.run_coroutine_threadsafe(call(), self.loop).result(10)

    def grid(self) -> GridState | None:
        """A copy of the watcher's grid of VEHICLE (None while it has none)."""
        def copy() -> GridState | None:
            feed = self.watcher.feeds.get(VEHICLE)
            s = feed.state if feed is not None and feed.awaiting_since_s is None else None
            return None if s is None else s.copy()
        return self._on_loop(copy)

    def status(self) -> dict | None:
        return self.statuses[-1][1] if self.statuses else None

    def wait(self, predicate, timeout_s: float, what: str,
             daemon: subprocess.Popen | None = None, log: Path | None = None) -> dict:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if daemon is not None and daemon.poll() is not None:
                tail = log.read_text(errors="replace")[-3000:] if log else ""
                raise RuntimeError(f"pdcov serve exited with {daemon.returncode}:\n{tail}")
            st = self.status()
            if st is not None and predicate(st):
                return st
            time.sleep(0.1)
        raise TimeoutError(f"no status with {what} within {timeout_s:g} s; last: "
                           f"{json.dumps(self.status())[:1500]}")

    def close(self) -> None:
        if self._stop is not None:
            self.loop.call_soon_threadsafe(self._stop.set)
        self.thread.join(timeout=20)


def settled(w: WatcherThread) -> bool:
    """After the landing: the daemon has decided every frame it can and the watcher holds its
    grid as of the status. The last frame may stay pending for good: no telemetry after it
    will come to interpolate from (it is in no grid, so the comparison is unaffected)."""
    st = w.status()
    if st is None or st["frames"]["pending"] > 1:
        return False
    g = w.grid()
    return g is not None and g.frames == st["frames"]["grid"]


def offline(config: Path, tlog: Path, out: Path) -> dict[str, np.ndarray]:
    """``pdcov evaluate --log`` of ``tlog``: its grid.npz arrays."""
    from pdcov.cli import main as pdcov_main

    with contextlib.redirect_stdout(io.StringIO()):
        code = pdcov_main(["evaluate", "--config", str(config), "--log", str(tlog), "--out",
                           str(out), "--no-progress"])
    if code != 0:
        raise RuntimeError(f"pdcov evaluate --log {tlog} exited {code}")
    with np.load(out / "grid.npz") as z:
        return {k: z[k] for k in z.files}


def cells_differing(a, b) -> int:
    """Cells where log_miss_d, log_miss_fa, n_obs or limiting differ (any of a/b a dict or
    GridState; a limiting factor missing or unknown differs everywhere)."""
    def get(x, k):
        return x.get(k) if isinstance(x, dict) else getattr(x, k)
    diff = np.zeros(np.shape(get(a, "n_obs")), bool)
    for k in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        va, vb = get(a, k), get(b, k)
        diff |= True if va is None or vb is None else np.asarray(va) != np.asarray(vb)
    return int(diff.sum())
