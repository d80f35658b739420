"""The router and disk scenarios: the Zenoh router gone mid-flight, and the state directory
full mid-flight (a small tmpfs, root only)."""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from tests.support.checkpoint_files import read_checkpoint
from tests.support.harness import child, router

from .rig import (
    VEHICLE,
    WatcherThread,
    cells_differing,
    fly,
    make_rig,
    serve,
    settled,
    side_for,
    sigterm,
)


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
    final = read_checkpoint(rig.state / "checkpoint")
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
            res.final_frames = int(read_checkpoint(state / "checkpoint")["frames"])
    finally:
        w.close()
        r.close()
        subprocess.run(["umount", "-l", str(state)], check=False)
    return res
