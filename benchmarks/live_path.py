"""``python -m benchmarks.live_path``: what a camera frame costs on ``pdcov serve``'s live
path, side by side with the offline evaluation of the same recording (the reference method,
measured in the same run).

Recordings, made first and not timed:

* gimbal: ``pdcov-sitl fly --speed 0`` over the small simulated mission
  (tests.support.harness.small_mission: 640x480 at 5 frames/s, gimbal read by its flags) on a
  square of ``--side-m``, lawnmower 10 m up, 10 m apart, 5 m/s; its tlog is the recording;
* fixed: the same flight with a fixed nadir camera (``--gimbal fixed``);
* S1: the survey scenario (tests.support.scenarios: 1920x1080 fixed 20 deg off nadir, 30
  frames/s, 1 km square at 1 m), its first ``--s1-s`` seconds written as a tlog by
  benchmarks.offline.write_tlog (ATTITUDE and GLOBAL_POSITION_INT at 10 Hz).

Each recording is then run, in this process, twice:

* live: every message's bytes, one message at a time as a link delivers them, through
  pymavlink's parser (robust parsing, as mavlink_socket) and the daemon's decisions
  (``ServiceCore``) as the shell drives them (``receive_mavlink``, ``process``), and every
  50 ms of the autopilot's clock its ``tick`` (LinkProtocol.poll, LiveCoverage.poll with
  its tiles, ``status`` when one is due); no socket, Zenoh or file. Zenoh puts and status
  encoding are not counted.
* offline: what ``pdcov evaluate`` computes (poses_from_log, then the grid updates), outputs
  not written.

Figures: CPU milliseconds per frame added to the grid (time.process_time: the machine is
shared) and messages per CPU second, and whether the two grids are equal cell for cell
(the product's promise; the run fails when they are not). ``--smoke``: tiny flights
(CI; timings meaningless).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from shapely.geometry import box

from pdcov.config.mission import Mission
from pdcov.core.geodesy import Origin
from pdcov.core.grid import CoverageGrid
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.planning.patterns import lawnmower
from pdcov.planning.plan_files import write_plan
from pdcov.report.outputs import evaluate_poses
from pdcov.service.core import ServiceCore
from pdcov.service.daemon import TICK_S
from pdcov.service.link_setup import LinkReport
from pdcov.service.mavlink_socket import mavlink
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.frame_policy import FrameSource
from pdcov.telemetry.tlog import TlogScanner
from tests.support.harness import SMALL_MISSION, child, small_mission
from tests.support.scenarios import scenarios

from .offline import write_tlog
from .report import Row, machine, markdown

CLOCK_MESSAGES = ("ATTITUDE", "GLOBAL_POSITION_INT")
FIXED_NADIR = {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}
ALT_M, SPACING_M, SPEED_MPS = 10.0, 10.0, 5.0


@dataclass(frozen=True)
class Recording:
    """A telemetry log and the daemon config (mission + service sections) it is read with."""

    name: str
    config: Path
    tlog: Path


@dataclass(frozen=True)
class PathRun:
    """One pass over a recording: CPU seconds, messages read, frames added, the grid; live
    also the CPU seconds of the periodic work (ticks: tiles, status) within cpu_s, the
    seconds of flight (autopilot clock) it spanned, and the longest single call the daemon's
    loop would make (a message's receive and process, or a tick: wall seconds), the longest
    the loop would be held."""

    cpu_s: float
    messages: int
    frames: int
    grid: CoverageGrid
    periodic_cpu_s: float = 0.0
    flight_s: float = 0.0
    longest_call_s: float = 0.0

    @property
    def ms_per_frame(self) -> float:
        """CPU ms per frame of the work that scales with frames and messages."""
        return 1e3 * (self.cpu_s - self.periodic_cpu_s) / max(self.frames, 1)

    @property
    def messages_per_s(self) -> float:
        return self.messages / self.cpu_s

    @property
    def periodic_ms_per_s(self) -> float:
        """CPU ms of the periodic work per second of flight."""
        return 1e3 * self.periodic_cpu_s / max(self.flight_s, 1e-9)


def write_config(folder: Path, doc: dict[str, Any]) -> Path:
    doc = {**doc, "link": {"connect": ["udpin:127.0.0.1:9"]},
           "service": {"state_dir": str(folder / "state"), "record": False}}
    path = folder / "mission.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def simulated(folder: Path, name: str, side_m: float, mount: dict[str, Any] | None
              ) -> Recording:
    """``pdcov-sitl fly --speed 0`` of a lawnmower over the small mission on a square of
    ``side_m``; ``mount`` None keeps its gimbal (read by the flags), else replaces it."""
    folder.mkdir(parents=True)
    s = side_m
    doc = small_mission(vehicle_id=f"bench_{name}",
                        domain={"polygon_enu_m": [[0, 0], [s, 0], [s, s], [0, s]],
                                "cell_size_m": 1.0},
                        mount=mount or {**SMALL_MISSION["mount"], "attitude_frame": "flags"})
    config = write_config(folder, doc)
    o = doc["origin"]
    plan = write_plan(folder / "plan.plan",
                      lawnmower(box(0.0, 0.0, s, s), SPACING_M, 0.0, ALT_M, SPEED_MPS),
                      Origin(o["lat_deg"], o["lon_deg"], o["ground_alt_msl_m"]))
    gimbal = "fixed" if mount else "device-earth"
    out, log = folder / "sim", folder / "sim.log"
    with child([sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(config),
                "--plan", str(plan), "--out", str(out), "--speed", "0",
                "--connect", "udpout:127.0.0.1:9", "--gimbal", gimbal], log) as p:
        rc = p.wait(timeout=600)
    if rc != 0:
        raise RuntimeError(f"pdcov-sitl fly failed ({rc}): {log.read_text()[-2000:]}")
    return Recording(name, config, out / "flight.tlog")


def survey(folder: Path, seconds: float, smoke: bool) -> Recording:
    """The first ``seconds`` of the S1 survey as a tlog (benchmarks.offline.write_tlog)."""
    folder.mkdir(parents=True)
    sc = dataclasses.replace(scenarios(smoke)["S1"], duration_s=seconds)
    config = write_config(folder, sc.mission_doc())
    return Recording("S1", config, write_tlog(folder / "flight.tlog", sc))


def timed(run: Callable[[], tuple[int, int, CoverageGrid]]) -> PathRun:
    gc.collect()
    cpu0 = time.process_time()
    messages, frames, grid = run()
    return PathRun(time.process_time() - cpu0, messages, frames, grid)


@dataclass
class _Ticks:
    """What the live pass measures of Daemon._tick's publishing decisions."""

    cpu_s: float = 0.0
    first_s: float | None = None
    last_s: float = 0.0
    longest_s: float = 0.0  # the longest call (wall s)


def live_pass(rec: Recording) -> PathRun:
    """The recording's messages through the daemon's decisions (``ServiceCore``, as the
    shell drives it), one at a time (the core and its grid are built before the clock
    starts, as at the daemon's start)."""
    cfg = load_serve_config(rec.config)
    frames = [m.get_msgbuf() for m in TlogScanner(rec.tlog.read_bytes()).messages()]
    ticks = _Ticks()
    core = ServiceCore(cfg, cfg.mission.new_mission_grid(), 0.0, mission_hash="bench")
    live = core.coverage
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True

    def run() -> tuple[int, int, CoverageGrid]:
        now_s = next_tick_s = 0.0
        for frame in frames:
            msgs = parser.parse_buffer(frame) or []  # Daemon._on_messages
            for msg in msgs:
                if msg.get_type() in CLOCK_MESSAGES:  # the daemon's clock, played by the
                    now_s = max(now_s, msg.time_boot_ms / 1000.0)  # autopilot's
                    if ticks.first_s is None:
                        ticks.first_s = next_tick_s = now_s
            wall0 = time.perf_counter()
            core.receive_mavlink(msgs, now_s)
            core.process()  # Daemon._process
            ticks.longest_s = max(ticks.longest_s, time.perf_counter() - wall0)
            while ticks.first_s is not None and now_s >= next_tick_s:  # Daemon._tick
                next_tick_s += TICK_S
                frames_before = live.grid.frames
                cpu0, wall0 = time.process_time(), time.perf_counter()
                core.tick(now_s, 0.0)
                if core.actions().status_due:
                    core.status(now_s, LinkReport())
                    core.actions()
                ticks.longest_s = max(ticks.longest_s, time.perf_counter() - wall0)
                # A tick that decided frames (a parameter read timed out: the frames that
                # waited for it) counts as frame work, not as periodic work.
                if live.grid.frames == frames_before:
                    ticks.cpu_s += time.process_time() - cpu0
        ticks.last_s = now_s
        return len(frames), live.grid.frames, live.grid

    run_ = timed(run)
    return dataclasses.replace(run_, periodic_cpu_s=ticks.cpu_s,
                               flight_s=ticks.last_s - (ticks.first_s or 0.0),
                               longest_call_s=ticks.longest_s)


def offline_pass(rec: Recording) -> PathRun:
    """What ``pdcov evaluate --log`` computes for the recording (no outputs written)."""
    m: Mission = load_serve_config(rec.config).mission
    messages = sum(1 for _ in TlogScanner(rec.tlog.read_bytes()).messages())
    grid = m.new_mission_grid()

    def run() -> tuple[int, int, CoverageGrid]:
        lp = poses_from_log(rec.tlog, Framing(m.first_camera.mount, m.first_camera.frame_rate_hz,
                                              frame_source=FrameSource(m.frame_source),
                                              max_gap_s=m.max_gap_s,
                                              min_height_m=m.min_height_m),
                            origin_lat_deg=m.origin_lat_deg,
                            origin_lon_deg=m.origin_lon_deg,
                            ground_alt_msl_m=m.ground_alt_msl_m, system_id=m.system_id)
        poses = [p for p, low in zip(lp.poses, lp.low, strict=True) if not low]
        evaluate_poses(grid, poses, progress=False, total=len(poses))
        return messages, len(poses), grid

    return timed(run)


def equal_grids(a: CoverageGrid, b: CoverageGrid) -> bool:
    return (a.frames == b.frames and np.array_equal(a.n_obs, b.n_obs)
            and np.array_equal(a.log_miss_d, b.log_miss_d)
            and np.array_equal(a.log_miss_fa, b.log_miss_fa))


def rows_for(rec: Recording) -> tuple[list[Row], bool]:
    live, offline = live_pass(rec), offline_pass(rec)
    same = equal_grids(live.grid, offline.grid)
    describe = {"gimbal": "simulated, gimbal (device, earth frame), 5 frames/s",
                "fixed": "simulated, fixed nadir camera, 5 frames/s",
                "S1": "S1 survey tlog, 1920x1080 fixed, 30 frames/s"}[rec.name]
    rows = [Row(rec.name, "recording", f"{describe}: {live.messages:,} messages, "
                f"{live.frames:,} frames"),
            Row(rec.name, "live (daemon decisions): CPU ms/frame",
                f"{live.ms_per_frame:.2f} ({live.messages_per_s:,.0f} messages/s)"),
            Row(rec.name, "live: tiles and status, CPU ms per s of flight",
                f"{live.periodic_ms_per_s:.1f} (grid of {live.grid.mask.size:,} cells)"),
            Row(rec.name, "offline (pdcov evaluate): CPU ms/frame",
                f"{offline.ms_per_frame:.2f} ({offline.messages_per_s:,.0f} messages/s)"),
            Row(rec.name, "live grid = offline grid", "cell for cell" if same else
                f"DIFFERENT (live {live.frames} frames, offline {offline.frames})",
                "equal", same)]
    return rows, same


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.live_path", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true",
                        help="tiny flights (CI; timings meaningless)")
    parser.add_argument("--side-m", type=float, default=60.0,
                        help="side of the simulated flights' square (default 60)")
    parser.add_argument("--s1-s", type=float, default=30.0,
                        help="seconds of the S1 survey replayed (default 30)")
    parser.add_argument("--only", nargs="+", choices=["gimbal", "fixed", "S1"],
                        default=["gimbal", "fixed", "S1"])
    args = parser.parse_args(argv)
    side_m, s1_s = (20.0, 2.0) if args.smoke else (args.side_m, args.s1_s)
    rows: list[Row] = []
    ok = True
    with tempfile.TemporaryDirectory(prefix="pdcov-bench-live-") as tmp:
        d = Path(tmp)
        makers = {"gimbal": lambda: simulated(d / "gimbal", "gimbal", side_m, None),
                  "fixed": lambda: simulated(d / "fixed", "fixed", side_m, FIXED_NADIR),
                  "S1": lambda: survey(d / "s1", s1_s, args.smoke)}
        for name in args.only:
            print(f"{name}: recording", file=sys.stderr)
            rec = makers[name]()
            print(f"{name}: live and offline passes", file=sys.stderr)
            found, same = rows_for(rec)
            rows += found
            ok &= same
    command = "python -m benchmarks.live_path" + (" --smoke" if args.smoke else "")
    print(markdown(rows, machine(), command))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
