"""The crash scenario: `kill -9` of the daemon, half the kills aimed at a checkpoint write;
every restart must resume a valid checkpoint."""

from __future__ import annotations

import math
import os
import random
import shutil
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.support.harness import child, router

from .rig import WatcherThread, fly, make_rig, serve, side_for, sigterm


@dataclass
class CrashResult:
    kills: int
    during_write: int
    resumed: int
    set_aside: int
    stale_frames: list[int] = field(default_factory=list)  # frames missing vs the bound
    ages_s: list[float] = field(default_factory=list)  # kill - checkpoint, 0: held every frame
    restarts_s: list[float] = field(default_factory=list)  # kill to first resumed status
    period_s: float = 0.0
    failures: list[str] = field(default_factory=list)
    aimed: int = 0                                          # kills aimed at a write
    tmp_sizes: list[int] = field(default_factory=list)     # an interrupted write's files, bytes


def _files(folder: Path) -> list[Path]:
    """The files under ``folder`` now (a daemon may be removing and writing them: what
    vanishes while walked is left out)."""
    return [Path(root) / name for root, _, names in os.walk(folder) for name in names]


def _mtime_ns(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except FileNotFoundError:
        return -1


def writing(state: Path) -> list[Path]:
    """The temporary files of a checkpoint being written in ``state``: a chunk of a slot's
    grid store (zarr's ``.partial``), its metadata or ``current`` (atomic_write's ``.tmp``)."""
    from pdcov.service.checkpoint import CHECKPOINT_NAME

    return [p for p in _files(state / CHECKPOINT_NAME) if p.name.endswith((".partial", ".tmp"))]


def interrupted_write(state: Path) -> list[Path]:
    """The files a checkpoint being written when the daemon died left in ``state``: its
    temporary files, and what it wrote in the slot ``current`` does not name after
    ``current`` was last renamed (the checkpoint never completed)."""
    from pdcov.service.checkpoint import CHECKPOINT_NAME, CURRENT, SLOTS

    folder = state / CHECKPOINT_NAME
    current = folder / CURRENT
    if not current.exists():
        return writing(state)
    other = SLOTS[0] if current.read_text().strip() != SLOTS[0] else SLOTS[1]
    since = current.stat().st_mtime_ns
    newer = [p for p in _files(folder / other) if _mtime_ns(p) > since]
    return sorted(set(writing(state)) | set(newer))


def kill_during_write(pid: int, state: Path, timeout_s: float) -> bool:
    """``kill -9`` process group ``pid`` the moment a checkpoint's temporary file appears in
    ``state`` (polled in a tight loop); True when it did, False (no kill) after timeout_s."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if writing(state):
            os.killpg(pid, signal.SIGKILL)
            return True
    return False


def crash(folder: Path, kills: int, period_s: float = 0.25, seed: int = 2,
          speed: float = 2.0) -> CrashResult:
    """``kill -9`` the daemon ``kills`` times mid-flight (checkpoints every ``period_s``),
    restarting it each time: even kills aimed at a checkpoint write, odd ones at a random
    moment."""
    from pdcov.config.load import load_mission
    from pdcov.service.checkpoint import CHECKPOINT_NAME, read_meta, resume
    from pdcov.service.settings import mission_hash

    rng = random.Random(seed)
    est_wall_s = kills * 8.0
    rig = make_rig(folder, side_for(est_wall_s * speed + 120), checkpoint_period_s=period_s)
    mission = load_mission(rig.config)
    mhash = mission_hash(mission, mission.new_mission_grid())
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
                left = [p for p in interrupted_write(rig.state) if p.exists()]
                if left:
                    res.during_write += 1
                    res.tmp_sizes.extend(p.stat().st_size for p in left if p.exists())
                copy = folder / "copy"
                shutil.rmtree(copy, ignore_errors=True)
                shutil.copytree(rig.state, copy, ignore=shutil.ignore_patterns("recordings"))
                meta = read_meta(copy / CHECKPOINT_NAME)
                grid = resume(copy, mhash, mission.new_mission_grid()).grid
                if grid is None:
                    res.failures.append(f"kill {k + 1}: the checkpoint does not resume")
                    continue
                # The checkpoint's age at the kill, when the daemon had reported frames it
                # lacks; 0 when it held them all (no new frame: nothing to write).
                reported = max((s["frames"]["grid"] for t, s in w.statuses if t <= t_kill),
                               default=0)
                res.ages_s.append(t_kill - meta["written_unix_s"]
                                  if grid.frames < reported else 0.0)
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
