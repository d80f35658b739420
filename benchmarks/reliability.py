"""``python -m benchmarks.reliability``: the daemon's faults end to end, with real processes
(issue 15, part A). Each scenario runs ``pdcov-sitl fly`` (JSBSim, MAVLink over UDP),
``pdcov serve`` and a Zenoh router in this process, and the ground watcher's own shell
(``ground.live.WatchShell`` with ``ground.watcher.Watcher``) in a thread of this process:

* **soak**: a long flight at high speed with random link and autopilot faults; the daemon's
  resident memory sampled over simulated time; the final grid (checkpoint written at
  SIGTERM) equals ``pdcov evaluate`` of the daemon's own recording cell for cell, the
  watcher's grid equals it too, and the frames used are compared with ``pdcov evaluate`` of
  the simulator's own tlog (what was sent before the link faults);
* **crash**: ``kill -9`` with a checkpoint every ``period`` s, every other kill aimed at a
  checkpoint write (the moment its temporary file appears; the file is left behind, empty or
  part-written) and the others at random moments; every restart resumes a valid checkpoint
  holding every frame some status had reported ``period`` + 0.5 s before the kill;
* **router**: the Zenoh router gone for ``outage`` s mid-flight, then back on the same port;
  the watcher (never restarted) ends with the daemon's exact final grid;
* **disk**: the state directory on a small tmpfs, filled up mid-flight: the daemon keeps
  computing and publishing, says so in its status (``checkpoint.error``,
  ``recording_error``, ``faults.checkpoint_errors``), and checkpoints again when space is
  freed. Needs root (mount); skipped with the reason otherwise.

``--write-docs`` runs the documented sizes (a 2-hour soak, 50 kills, a 60 s router outage)
plus the fuzz properties with many examples, and writes docs/reliability.md; ``--quick``
runs the CI sizes (tests/test_reliability.py uses the functions directly).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
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
from pdcov.planning.plan import write_plan

from .daemon import memory_bytes
from .harness import child, free_port, router, serve_args, small_mission
from .report import write_marked_block

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "reliability.md"
VEHICLE = "rel1"
LAT_DEG, LON_DEG, GROUND_M = 47.397742, 8.545594, 488.0
ALT_M, SPACING_M, SPEED_MPS = 10.0, 10.0, 5.0


# --- the rig ----------------------------------------------------------------------------------

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
            return None if s is None else GridState(s.geometry, s.mask.copy(),
                                                    s.log_miss_d.copy(),
                                                    s.log_miss_fa.copy(), s.n_obs.copy(),
                                                    s.frames)
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


def load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def cells_differing(a, b) -> int:
    """Cells where log_miss_d, log_miss_fa or n_obs differ (any of a/b a dict or GridState)."""
    def get(x, k):
        return x[k] if isinstance(x, dict) else getattr(x, k)
    diff = np.zeros(np.shape(get(a, "n_obs")), bool)
    for k in ("log_miss_d", "log_miss_fa", "n_obs"):
        diff |= np.asarray(get(a, k)) != np.asarray(get(b, k))
    return int(diff.sum())


# --- soak ---------------------------------------------------------------------------------------

def random_faults(flight_s: float, seed: int) -> str:
    """Link faults all along and, every ~5 simulated minutes, an outage (2-15 s: longer than
    half the daemon's 20 s history too), a GPS glitch or a NaN window. Not included:
    ``reboot`` (pdcov evaluate re-bases a log's clock on its last boot, the live daemon on its
    first, so frames fall on other times; covered by tests/test_fuzz_link.py and
    tests/test_serve_fly.py) and ``gimbal_fail`` (the simulated gimbal stays silent after it:
    the rest of the flight would be unusable)."""
    rng = random.Random(seed)
    items = ["drop=0.01", "corrupt=0.0005", "reorder=0.01", "duplicate=0.01"]
    t = rng.uniform(40, 120)
    while t < flight_s - 30:
        kind = rng.choice(("outage", "outage", "gps_glitch", "nan"))
        if kind == "outage":
            items.append(f"outage={t:.0f}+{rng.uniform(2, 15):.1f}")
        elif kind == "gps_glitch":
            items.append(f"gps_glitch={t:.0f}+{rng.uniform(1, 5):.1f}:{rng.uniform(5, 40):.0f}")
        else:
            msg = rng.choice(("ATTITUDE.roll", "ATTITUDE.yaw",
                              "GIMBAL_DEVICE_ATTITUDE_STATUS.angular_velocity_x"))
            items.append(f"nan={msg}@{t:.0f}+{rng.uniform(0.2, 2):.1f}")
        t += rng.uniform(150, 450)
    return ",".join(items)


@dataclass
class SoakResult:
    flight_s: float
    wall_s: float
    faults: str
    rss: list[tuple[float, float]]          # (simulated s, MiB)
    status: dict
    frames_live: int
    frames_recording: int
    frames_sim_tlog: int
    cells: int
    differ_recording: int
    differ_watcher: int
    messages_recorded_bytes: int
    exit_code: int
    traceback: bool
    udp_drops: int | None = None   # datagrams the kernel dropped at the daemon's socket
    skipped_in_faults: int = 0     # frames of the recording skipped inside injected outages
    lost: list[float] = field(default_factory=list)  # skipped elsewhere: frame times (s)

    @property
    def rss_growth_mib(self) -> float:
        """RSS at the end minus RSS after the first quarter of the flight (warm-up)."""
        after = [m for t, m in self.rss if t >= 0.25 * self.flight_s] or [m for _, m in self.rss]
        return after[-1] - after[0] if after else math.nan


def udp_drops(pid: int, port: int) -> int | None:
    """Datagrams the kernel dropped at process ``pid``'s UDP socket bound to ``port`` (its
    receive buffer was full: the reader did not keep up); None when no such socket."""
    for line in Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[1].rsplit(":", 1)[1], 16) == port:
            return int(fields[-1])
    return None


def soak(folder: Path, flight_s: float, speed: float, seed: int = 1,
         rss_every_s: float = 2.0, timeout_s: float | None = None) -> SoakResult:
    """Fly about ``flight_s`` simulated seconds at ``speed`` with random faults."""
    rig = make_rig(folder, side_for(flight_s), checkpoint_period_s=5.0)
    faults = random_faults(flight_s, seed)
    timeout_s = timeout_s or 120 + 3 * flight_s / max(speed, 5)
    r = router(rig.zenoh_port)
    w = WatcherThread(rig.zenoh_port)
    rss: list[tuple[float, float]] = []
    start = time.monotonic()
    log = folder / "serve.log"
    try:
        with child(serve(rig), log) as daemon:
            w.wait(lambda s: True, 60, "a first status", daemon, log)
            with child(fly(rig, speed, faults, seed), folder / "fly.log") as sim:
                end = time.monotonic() + timeout_s
                while sim.poll() is None:
                    if time.monotonic() > end:
                        raise TimeoutError(f"the flight took more than {timeout_s:.0f} s")
                    if daemon.poll() is not None:
                        raise RuntimeError(f"pdcov serve exited: "
                                           f"{log.read_text(errors='replace')[-3000:]}")
                    st = w.status()
                    if st is not None and st.get("t_s") is not None:
                        rss.append((float(st["t_s"]), memory_bytes(daemon.pid)["VmRSS"] / 2**20))
                    time.sleep(rss_every_s)
                if sim.returncode != 0:
                    raise RuntimeError((folder / "fly.log").read_text()[-2000:])
            end = time.monotonic() + 120
            while not settled(w):
                if time.monotonic() > end:
                    raise TimeoutError("the daemon and the watcher did not settle")
                time.sleep(0.5)
            time.sleep(1.0)
            st = w.status()
            rss.append((float(st["t_s"]), memory_bytes(daemon.pid)["VmRSS"] / 2**20))
            drops = udp_drops(daemon.pid, rig.mav_port)
            watcher_grid = w.grid()
            code = sigterm(daemon)
    finally:
        w.close()
        r.close()
    wall = time.monotonic() - start
    final = load(rig.state / "checkpoint.npz")
    recs = sorted((rig.state / "recordings").glob("*.tlog"))
    ref = offline(rig.config, recs[-1], folder / "offline-recording")
    sim_ref = offline(rig.config, folder / "sim" / "flight.tlog", folder / "offline-sim")
    in_faults, lost = skipped_frames(rig.config, recs[-1], faults)
    return SoakResult(
        skipped_in_faults=in_faults, lost=lost, udp_drops=drops,
        flight_s=float(st["t_s"]), wall_s=wall, faults=faults, rss=rss, status=st,
        frames_live=int(final["frames"]), frames_recording=int(ref["frames"]),
        frames_sim_tlog=int(sim_ref["frames"]), cells=int(final["mask"].sum()),
        differ_recording=cells_differing(final, ref),
        differ_watcher=cells_differing(final, watcher_grid),
        messages_recorded_bytes=sum(p.stat().st_size for p in recs), exit_code=code,
        traceback="Traceback" in log.read_text(errors="replace"))


def skipped_frames(config: Path, tlog: Path, faults: str) -> tuple[int, list[float]]:
    """Frames ``pdcov evaluate`` skips in ``tlog`` (telemetry gaps): how many lie in an
    injected outage, NaN window or GPS glitch (whose frames the estimator status skips),
    widened by the 1 s gap rule, and the times of the others
    (frames lost to something else: the daemon not keeping up, a dropped burst)."""
    from pdcov.config import load_mission
    from pdcov.telemetry.pose_tracker import poses_from_log
    from pdcov_sitl.faults import FaultSpec

    m = load_mission(config)
    poses = poses_from_log(tlog, origin_lat_deg=m.origin_lat_deg,
                           origin_lon_deg=m.origin_lon_deg, ground_alt_msl_m=m.ground_alt_msl_m,
                           mount=m.mount, frame_rate_hz=m.frame_rate_hz,
                           frame_source=m.frame_source, max_gap_s=m.max_gap_s)
    spec = FaultSpec.parse(faults)
    windows = [(w.start_s - 1.5, w.start_s + w.duration_s + m.max_gap_s + 0.5)
               for w in (*spec.outages, *(n.window for n in spec.nans),
                         *(g.window for g in spec.gps_glitches))]
    inside = [any(a <= t <= b for a, b in windows) for t in poses.skipped_t_s]
    return sum(inside), [float(t) for t, i in zip(poses.skipped_t_s, inside, strict=True)
                         if not i]


# --- crash consistency ----------------------------------------------------------------------

@dataclass
class CrashResult:
    kills: int
    during_write: int
    resumed: int
    set_aside: int
    stale_frames: list[int] = field(default_factory=list)  # frames missing vs the bound
    ages_s: list[float] = field(default_factory=list)      # kill time - checkpoint written
    restarts_s: list[float] = field(default_factory=list)  # kill to first resumed status
    period_s: float = 0.0
    failures: list[str] = field(default_factory=list)
    aimed: int = 0                                          # kills aimed at a write
    tmp_sizes: list[int] = field(default_factory=list)     # left temporary files, bytes


def kill_during_write(pid: int, state: Path, timeout_s: float) -> bool:
    """``kill -9`` process group ``pid`` the moment a checkpoint's temporary file appears in
    ``state`` (polled in a tight loop); True when it did, False (no kill) after timeout_s."""
    from pdcov.service.checkpoint import CHECKPOINT_NAME

    prefix = f".{CHECKPOINT_NAME}."
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        with os.scandir(state) as it:
            if any(e.name.startswith(prefix) and e.name.endswith(".tmp") for e in it):
                os.killpg(pid, signal.SIGKILL)
                return True
    return False


def crash(folder: Path, kills: int, period_s: float = 0.25, seed: int = 2,
          speed: float = 2.0) -> CrashResult:
    """``kill -9`` the daemon ``kills`` times mid-flight (checkpoints every ``period_s``),
    restarting it each time: even kills aimed at a checkpoint write, odd ones at a random
    moment."""
    from pdcov.config import load_mission
    from pdcov.service.checkpoint import CHECKPOINT_NAME, read_meta, resume
    from pdcov.service.settings import mission_hash

    rng = random.Random(seed)
    est_wall_s = kills * 8.0
    rig = make_rig(folder, side_for(est_wall_s * speed + 120), checkpoint_period_s=period_s)
    mission = load_mission(rig.config)
    mhash = mission_hash(mission, mission.new_grid())
    res = CrashResult(kills, 0, 0, 0, period_s=period_s)
    t_kill = math.nan
    r = router(rig.zenoh_port)
    w = WatcherThread(rig.zenoh_port)
    log = folder / "serve.log"
    try:
        with child(fly(rig, speed, None, seed), folder / "fly.log") as sim:
            for k in range(kills + 1):
                with child(serve(rig), log, "ab") as daemon:
                    n0 = len(w.statuses)
                    w.wait(lambda s, n0=n0: len(w.statuses) > n0 and s.get("full"), 90,
                           "the new daemon's first status", daemon, log)
                    st = w.status()
                    if k > 0:
                        res.restarts_s.append(time.time() - t_kill)
                        if st["checkpoint"]["resumed"]:
                            res.resumed += 1
                        else:
                            res.failures.append(f"restart {k}: not resumed: {st['checkpoint']}")
                        if st["checkpoint"]["set_aside"]:
                            res.set_aside += 1
                            res.failures.append(f"restart {k}: set aside {st['checkpoint']}")
                    if k == kills:
                        sigterm(daemon)
                        break
                    if sim.poll() is not None:
                        res.failures.append(f"the flight ended after {k} kills")
                        break
                    # New frames flowing (the link is up, the gimbal reading resolved), then
                    # a random moment.
                    w.wait(lambda s, f=st["frames"]["grid"]: s["frames"]["grid"] > f + 5, 60,
                           "new frames", daemon, log)
                    time.sleep(rng.uniform(0.0, 1.5))
                    aimed = k % 2 == 0 and kill_during_write(daemon.pid, rig.state,
                                                             10 * period_s + 2.0)
                    t_kill = time.time()
                    if aimed:
                        res.aimed += 1
                    else:
                        os.killpg(daemon.pid, signal.SIGKILL)
                    daemon.wait(timeout=10)
                # The state directory as the next start finds it (checked on a copy).
                left = list(rig.state.glob(f".{CHECKPOINT_NAME}.*.tmp"))
                if left:
                    res.during_write += 1
                    res.tmp_sizes.extend(p.stat().st_size for p in left)
                copy = folder / "copy"
                shutil.rmtree(copy, ignore_errors=True)
                shutil.copytree(rig.state, copy, ignore=shutil.ignore_patterns("recordings"))
                meta = read_meta(copy / CHECKPOINT_NAME)
                grid = resume(copy, mhash, mission.new_grid()).grid
                if grid is None:
                    res.failures.append(f"kill {k + 1}: the checkpoint does not resume")
                    continue
                res.ages_s.append(t_kill - meta["written_unix_s"])
                # Every frame a status reported period + 0.5 s before the kill is in it.
                bound = max((s["frames"]["grid"] for t, s in w.statuses
                             if t <= t_kill - period_s - 0.5), default=0)
                if grid.frames < bound:
                    res.stale_frames.append(bound - grid.frames)
                    res.failures.append(f"kill {k + 1}: checkpoint has {grid.frames} frames, "
                                        f"a status {period_s + 0.5:g} s earlier had {bound}")
    finally:
        w.close()
        r.close()
    return res


# --- router outage -------------------------------------------------------------------------------

@dataclass
class RouterResult:
    outage_s: float
    frames_before: int
    frames_after_outage: int
    frames_final: int
    differ: int
    snapshots: int
    gaps: int
    exit_code: int


def router_outage(folder: Path, outage_s: float, speed: float = 4.0) -> RouterResult:
    """Close the router mid-flight for ``outage_s`` (wall) seconds, open it again on the same
    port; the watcher keeps running throughout."""
    flight_s = (outage_s + 25) * speed
    rig = make_rig(folder, side_for(flight_s))
    r = router(rig.zenoh_port)
    w = WatcherThread(rig.zenoh_port)
    log = folder / "serve.log"
    try:
        with child(serve(rig), log) as daemon, \
             child(fly(rig, speed), folder / "fly.log") as sim:
            st = w.wait(lambda s: s["frames"]["grid"] > 30, 120, "30 frames", daemon, log)
            before = st["frames"]["grid"]
            r.close()
            time.sleep(outage_s)
            r = router(rig.zenoh_port)
            n0 = len(w.statuses)
            st = w.wait(lambda s: len(w.statuses) > n0, 60, "a status after the outage",
                        daemon, log)
            after = st["frames"]["grid"]
            sim.wait(timeout=60 + 3 * flight_s / speed)
            end = time.monotonic() + 120
            while not settled(w):
                if time.monotonic() > end:
                    raise TimeoutError("the watcher did not catch up after the outage")
                time.sleep(0.5)
            time.sleep(1.0)
            grid = w.grid()
            feed = w.watcher.feeds[VEHICLE]
            code = sigterm(daemon)
    finally:
        w.close()
        r.close()
    final = load(rig.state / "checkpoint.npz")
    return RouterResult(outage_s, before, after, int(final["frames"]),
                        cells_differing(final, grid), feed.snapshots, feed.gaps, code)


# --- disk full -----------------------------------------------------------------------------------

@dataclass
class DiskResult:
    skipped: str | None
    tmpfs_bytes: int = 0
    frames_when_full: int = 0
    frames_while_full: int = 0
    statuses_while_full: int = 0
    checkpoint_errors: int = 0
    error_in_status: str | None = None
    recording_error_in_status: str | None = None
    checkpoint_again_s: float = math.nan
    recording_again: bool = False
    final_frames: int = 0
    exit_code: int = -1


def can_mount_tmpfs(path: Path) -> str | None:
    """None when a tmpfs can be mounted at ``path`` here, else the reason."""
    if os.geteuid() != 0:
        return "not root: cannot mount a tmpfs (and no loop device without root)"
    path.mkdir(parents=True, exist_ok=True)
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(path)],
                         capture_output=True, text=True)
    if res.returncode != 0:
        return f"mount -t tmpfs failed: {res.stderr.strip() or res.returncode}"
    subprocess.run(["umount", str(path)], check=False)
    return None


def fill(folder: Path) -> Path:
    """Fill the file system of ``folder`` with one file until ENOSPC; returns the file."""
    filler = folder / "filler.bin"
    with filler.open("wb", buffering=0) as f:
        for size in (65536, 1024, 64):
            with contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * size)
    return filler


def disk_full(folder: Path, full_s: float = 8.0, speed: float = 4.0,
              size_bytes: int = 8 << 20) -> DiskResult:
    """The state directory on a ``size_bytes`` tmpfs, filled for ``full_s`` s mid-flight."""
    state = folder / "state"
    why = can_mount_tmpfs(state)
    if why is not None:
        return DiskResult(skipped=why)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_bytes}", "tmpfs", str(state)],
                   check=True)
    res = DiskResult(skipped=None, tmpfs_bytes=size_bytes)
    rig = make_rig(folder, side_for((full_s + 60) * speed), checkpoint_period_s=1.0,
                   state_dir=state)
    r = router(rig.zenoh_port)
    w = WatcherThread(rig.zenoh_port)
    log = folder / "serve.log"
    try:
        with child(serve(rig), log) as daemon, \
             child(fly(rig, speed), folder / "fly.log"):
            st = w.wait(lambda s: s["frames"]["grid"] > 20 and s["checkpoint"].get(
                "written_unix_s"), 120, "20 frames and a checkpoint", daemon, log)
            res.frames_when_full = st["frames"]["grid"]
            filler = fill(state)
            t_full = time.time()
            st = w.wait(lambda s: s["checkpoint"].get("error") is not None, 30,
                        "checkpoint.error in the status", daemon, log)
            res.error_in_status = st["checkpoint"]["error"]
            while time.time() < t_full + full_s:
                time.sleep(0.2)
            statuses = [s for t, s in w.statuses if t_full <= t]
            st = w.status()
            res.statuses_while_full = len(statuses)
            res.frames_while_full = st["frames"]["grid"] - res.frames_when_full
            res.checkpoint_errors = st["faults"].get("checkpoint_errors", 0)
            res.recording_error_in_status = st["checkpoint"].get("recording_error")
            filler.unlink()
            t_free = time.time()
            st = w.wait(lambda s: s["checkpoint"].get("error") is None
                        and (s["checkpoint"].get("written_unix_s") or 0) > t_free, 30,
                        "a checkpoint written after space returned", daemon, log)
            res.checkpoint_again_s = st["checkpoint"]["written_unix_s"] - t_free
            w.wait(lambda s: s["checkpoint"].get("recording_error") is None, 30,
                   "recording again", daemon, log)
            res.recording_again = True
            res.exit_code = sigterm(daemon)
            res.final_frames = int(load(state / "checkpoint.npz")["frames"])
    finally:
        w.close()
        r.close()
        subprocess.run(["umount", "-l", str(state)], check=False)
    return res


# --- fuzzing figures ------------------------------------------------------------------------

def fuzz(examples: int) -> dict[str, object]:
    """Run the fuzz properties (tests/test_fuzz_*.py) with ``examples`` examples each."""
    env = dict(os.environ, PDCOV_FUZZ_EXAMPLES=str(examples))
    start = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                          "tests/test_fuzz_link.py", "tests/test_fuzz_inputs.py"],
                         cwd=ROOT, env=env, capture_output=True, text=True)
    last = (res.stdout.strip().splitlines() or [""])[-1]
    return {"examples": examples, "exit": res.returncode, "summary": last,
            "wall_s": time.monotonic() - start}


# --- report ---------------------------------------------------------------------------------

def report(soak_r: SoakResult, crash_r: CrashResult, router_r: RouterResult,
           disk_r: DiskResult, fuzz_r: dict, command: str) -> str:
    rss = soak_r.rss
    picks = [rss[round(i * (len(rss) - 1) / 8)] for i in range(9)] if rss else []
    ages = np.array(crash_r.ages_s) if crash_r.ages_s else np.array([math.nan])
    restarts = np.array(crash_r.restarts_s) if crash_r.restarts_s else np.array([math.nan])
    zero_tmp = sum(1 for n in crash_r.tmp_sizes if n == 0)
    part_tmp = len(crash_r.tmp_sizes) - zero_tmp
    tmp_span = (f"{min(crash_r.tmp_sizes):,}-{max(crash_r.tmp_sizes):,} bytes"
                if crash_r.tmp_sizes else "none")
    st = soak_r.status
    lines = [
        "## Bad input and faults",
        "",
        f"Regenerated by `{command}`; CI runs the same functions at small "
        "sizes in `tests/test_reliability.py` and the fuzz properties with 25 examples each "
        "(`tests/test_fuzz_link.py`, `tests/test_fuzz_inputs.py`). Machine: 2 shared cores, "
        "loaded by other work while this ran.",
        "",
        "## Bad input (fuzzing)",
        "",
        f"`PDCOV_FUZZ_EXAMPLES={fuzz_r['examples']}`: every hypothesis property of the two fuzz "
        f"files ran {fuzz_r['examples']} examples: **{fuzz_r['summary']}** "
        f"({fuzz_r['wall_s']:.0f} s).",
        "",
        "| input | tried | property |",
        "|---|---|---|",
        "| MAVLink bytes: random, inserted between and inside frames, flipped bits, any chunking "
        "| random bytes, junk + frames | no exception, grid finite and <= 0, a rejection counted |",
        "| MAVLink fields: NaN, +-inf, 1e38, angles beyond 2 pi, zero/NaN/tiny/huge/non-unit "
        "quaternions, lat/lon out of range, any time_boot_ms | hostile values | refused and "
        "counted (`link.rejected`, `faults.nan_samples`, `faults.invalid_samples`) |",
        "| MAVLink streams: duplicates, reordering, other systems' ids, time going back (incl. "
        "reboots), a time jump of 49 days | random mixes | no exception; `link.other_systems` "
        "counts; frames after a reboot or a 15 s outage used |",
        "| mission YAML, camera_info, detector YAML, pose CSV, .plan, WPL | damaged bytes, random "
        "bytes, hostile values in the documents | only `PdcovError` (exit 2, one line) |",
        "| checkpoints | damaged bytes; NaN/positive/inf/negative/mis-shaped arrays; bad "
        "metadata | set aside whole, never loaded in part |",
        "| Zenoh status, tiles, snapshot | damaged and random bytes, hostile grid fields, "
        "another grid's tiles | refused (`BusPayloadError`) and counted; the watcher's grid "
        "unchanged |",
        "",
        "## Soak",
        "",
        f"A lawnmower of {soak_r.flight_s / 3600:.2f} simulated hours "
        f"({soak_r.flight_s:.0f} s, {soak_r.cells} cells) flown by `pdcov-sitl` in "
        f"{soak_r.wall_s / 60:.1f} min of wall time, with these faults: `{soak_r.faults}`.",
        "",
        "| figure | value |",
        "|---|---|",
        f"| frames in the daemon's grid | {soak_r.frames_live} |",
        f"| frames of `pdcov evaluate` of the daemon's recording | {soak_r.frames_recording} |",
        f"| cells differing from that offline grid (of {soak_r.cells}) | "
        f"{soak_r.differ_recording} |",
        f"| cells differing between the watcher's grid and the daemon's | "
        f"{soak_r.differ_watcher} |",
        f"| frames of `pdcov evaluate` of the simulator's tlog (before link faults) | "
        f"{soak_r.frames_sim_tlog} |",
        f"| frames skipped live, by reason | {json.dumps(st['frames']['skipped'])} |",
        f"| of the recording's skipped frames: inside injected outages and NaN windows / "
        f"elsewhere (lost) | "
        f"{soak_r.skipped_in_faults} / {len(soak_r.lost)} |",
        f"| datagrams the kernel dropped at the daemon's UDP socket (not read in time) | "
        f"{soak_r.udp_drops} |",
        f"| faults counted | {json.dumps(st['faults'])} |",
        f"| rejected messages by type | {json.dumps(st['link'].get('rejected', {}))} |",
        f"| RSS growth after the first quarter | {soak_r.rss_growth_mib:+.1f} MiB |",
        f"| exit status at SIGTERM; traceback in the log | {soak_r.exit_code}; "
        f"{'yes' if soak_r.traceback else 'none'} |",
        "",
        "The daemon's resident memory (VmRSS) over simulated time:",
        "",
        "| simulated s | " + " | ".join(f"{t:.0f}" for t, _ in picks) + " |",
        "|---|" + "---|" * len(picks),
        "| RSS MiB | " + " | ".join(f"{m:.1f}" for _, m in picks) + " |",
        "",
        "Frames missing against the simulator's tlog are those the link faults took "
        "(dropped, corrupted, outages): the daemon's recording holds what arrived, and the "
        "live grid equals the offline evaluation of it: no frame that arrived usable was lost.",
        "",
        "## Crash consistency (kill -9)",
        "",
        f"{crash_r.kills} `kill -9` mid-flight, checkpoints every {crash_r.period_s:g} s: "
        f"{crash_r.aimed} aimed at a checkpoint write (killed the moment its temporary file "
        f"appeared), the others at random moments. {crash_r.during_write} kills landed during "
        f"a write: their temporary file was left, {zero_tmp} of them empty, {part_tmp} "
        f"part-written or written but not yet renamed (sizes {tmp_span}); the next start "
        f"removes it and resumes the previous checkpoint.",
        "",
        "| figure | value |",
        "|---|---|",
        f"| restarts that resumed the checkpoint | {crash_r.resumed} of {crash_r.kills} |",
        f"| checkpoints set aside (unreadable) | {crash_r.set_aside} |",
        f"| checkpoints missing frames a status reported {crash_r.period_s + 0.5:g} s before "
        f"the kill | {len(crash_r.stale_frames)} |",
        f"| checkpoint age at the kill (its write time to the kill), median / max; the "
        f"period is {crash_r.period_s:g} s | {np.nanmedian(ages):.2f} / "
        f"{np.nanmax(ages):.2f} s |",
        f"| kill to the restarted daemon's first status, median / max | "
        f"{np.nanmedian(restarts):.1f} / {np.nanmax(restarts):.1f} s |",
        f"| failures | {len(crash_r.failures)} {'; '.join(crash_r.failures[:3])} |",
        "",
        "## Zenoh router gone",
        "",
        f"The router closed {router_r.outage_s:g} s mid-flight and opened again on the same port; "
        f"the daemon (peer) and the watcher (client) were not restarted. The daemon had "
        f"{router_r.frames_before} frames when the router went and {router_r.frames_after_outage} "
        f"in its first status after; it ended with {router_r.frames_final}. The watcher's grid "
        f"differs from the daemon's final checkpoint in **{router_r.differ} cells** (it asked for "
        f"{router_r.snapshots} snapshots, saw {router_r.gaps} gaps).",
        "",
        "## Disk full",
        "",
    ]
    if disk_r.skipped:
        lines.append(f"Skipped: {disk_r.skipped}.")
    else:
        lines += [
            f"The state directory on a {disk_r.tmpfs_bytes >> 20} MiB tmpfs, filled to ENOSPC "
            "mid-flight, then freed:",
            "",
            "| figure | value |",
            "|---|---|",
            f"| frames added while full | {disk_r.frames_while_full} |",
            f"| statuses published while full | {disk_r.statuses_while_full} |",
            f"| `faults.checkpoint_errors` | {disk_r.checkpoint_errors} |",
            f"| `checkpoint.error` in the status | `{disk_r.error_in_status}` |",
            f"| `checkpoint.recording_error` in the status | "
            f"`{disk_r.recording_error_in_status}` |",
            f"| checkpoint written again after space returned | "
            f"{disk_r.checkpoint_again_s:.1f} s |",
            f"| recording again | {'yes' if disk_r.recording_again else 'no'} |",
            f"| exit status at SIGTERM; frames in the final checkpoint | {disk_r.exit_code}; "
            f"{disk_r.final_frames} |",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.reliability",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--write-docs", action="store_true", help=f"write {DOC.relative_to(ROOT)}")
    p.add_argument("--quick", action="store_true", help="CI sizes (figures mean little)")
    p.add_argument("--soak-s", type=float, help="simulated flight seconds (default 7200)")
    p.add_argument("--speed", type=float, default=8.0, help="simulator speed (default 8)")
    p.add_argument("--kills", type=int, help="kill -9 count (default 50)")
    p.add_argument("--outage-s", type=float, help="router outage, wall s (default 60)")
    p.add_argument("--examples", type=int, help="fuzz examples per property (default 500)")
    p.add_argument("--keep", type=Path, help="run in this folder and keep it")
    args = p.parse_args(argv)
    q = args.quick
    soak_s = args.soak_s or (600 if q else 7200)
    kills = args.kills or (5 if q else 50)
    outage = args.outage_s or (10 if q else 60)
    examples = args.examples or (25 if q else 500)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="pdcov-reliability-"))
    try:
        print(f"fuzz: {examples} examples per property", flush=True)
        fz = fuzz(examples)
        print(f"  {fz}", flush=True)
        print(f"soak: {soak_s:g} simulated s at --speed {args.speed:g}", flush=True)
        sk = soak(folder / "soak", soak_s, args.speed)
        print(f"  frames {sk.frames_live}, differ {sk.differ_recording}/{sk.differ_watcher}, "
              f"RSS growth {sk.rss_growth_mib:+.1f} MiB, {sk.wall_s:.0f} s", flush=True)
        print(f"crash: {kills} kills", flush=True)
        cr = crash(folder / "crash", kills)
        print(f"  resumed {cr.resumed}/{cr.kills}, during write {cr.during_write}, "
              f"failures {cr.failures}", flush=True)
        print(f"router: {outage:g} s outage", flush=True)
        ro = router_outage(folder / "router", outage)
        print(f"  {ro}", flush=True)
        print("disk full", flush=True)
        dk = disk_full(folder / "disk")
        print(f"  {dk}", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    text = report(sk, cr, ro, dk, fz, " ".join(["python -m benchmarks.reliability",
                                                *(sys.argv[1:] if argv is None else argv)]))
    if args.write_docs:
        # Only this block: the fleet and security block is benchmarks.fleet's.
        write_marked_block(DOC, text.rstrip("\n"), "<!-- faults:start -->", "<!-- faults:end -->")
        print(f"wrote {DOC}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
