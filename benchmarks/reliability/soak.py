"""The soak scenario: a long flight with random link and autopilot faults; memory over
simulated time, and the daemon's final grid against `pdcov evaluate` and the watcher."""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.support.checkpoint_files import read_checkpoint
from tests.support.harness import child, router

from ..daemon import memory_bytes
from .rig import (
    WatcherThread,
    cells_differing,
    fly,
    make_rig,
    offline,
    serve,
    settled,
    side_for,
    sigterm,
)


def random_faults(flight_s: float, seed: int) -> str:
    """Link faults all along and, every ~5 simulated minutes, an outage (2-15 s: longer than
    half the daemon's 20 s history too), a GPS glitch or a NaN window. Not included:
    ``reboot`` (pdcov evaluate re-bases a log's clock on its last boot, the live daemon on its
    first, so frames fall on other times; covered by tests/slow/test_fuzz_link.py and
    tests/simulators/test_serve_fly.py) and ``gimbal_fail`` (the simulated gimbal stays silent
    after it: the rest of the flight would be unusable)."""
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
    final = read_checkpoint(rig.state / "checkpoint")
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
    from pdcov.config.load import load_mission
    from pdcov.flight.frame_decision import Framing
    from pdcov.flight.log_frames import poses_from_log
    from pdcov.telemetry.frame_policy import FrameSource
    from pdcov_sitl.faults import FaultSpec

    m = load_mission(config)
    poses = poses_from_log(tlog, Framing(m.first_camera.mount, m.first_camera.frame_rate_hz,
                                         frame_source=FrameSource(m.frame_source),
                                         max_gap_s=m.max_gap_s),
                           origin_lat_deg=m.origin_lat_deg, origin_lon_deg=m.origin_lon_deg,
                           ground_alt_msl_m=m.ground_alt_msl_m)
    spec = FaultSpec.parse(faults)
    windows = [(w.start_s - 1.5, w.start_s + w.duration_s + m.max_gap_s + 0.5)
               for w in (*spec.outages, *(n.window for n in spec.nans),
                         *(g.window for g in spec.gps_glitches))]
    inside = [any(a <= t <= b for a, b in windows) for t in poses.skipped_t_s]
    return sum(inside), [float(t) for t, i in zip(poses.skipped_t_s, inside, strict=True)
                         if not i]
