"""End-to-end helpers for ``pdcov serve`` tests: the config writer, a subscriber that
rebuilds the grid from tiles and snapshots exactly as docs/protocol.md says, and a flight of
``pdcov-sitl fly`` into the daemon with ``pdcov evaluate`` of its logs to compare. Ports, the
in-process Zenoh router, processes that are always killed and the daemon's command line
come from tests.support.harness (shared with the benchmarks) and are re-exported here."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from pdcov.bus.detections import decode_detections
from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.status import decode_status, merge_status
from pdcov.bus.tiles import apply_tiles, decode_tiles
from pdcov.cli import main as pdcov_main
from tests.support.checkpoint_files import read_checkpoint
from tests.support.harness import ROOT, free_port, router, serve_args, stop
from tests.support.harness import child as process

__all__ = ["REAL", "ROOT", "SPEED", "Subscriber", "candidates_query", "finish", "fly_args",
           "fly_udp", "free_port", "offline", "process", "recording", "router", "same",
           "serve_args", "serve_config", "small_plan", "stop", "watched"]

REAL = ROOT.parent / "shared" / "real-logs"


def serve_config(base: dict, path: Path, *, zenoh_port: int, state_dir: Path,
                 session: dict | None = None, **service) -> Path:
    """The daemon's config: ``base`` with a fast-publishing bus section (by default a peer
    that connects to the router on ``zenoh_port`` and listens on a free loopback port;
    ``session``: mode, connect and listen instead, a key given None left out) and a
    service section writing into ``state_dir``."""
    doc = dict(base)
    bus = {"mode": "peer", "connect": [f"tcp/127.0.0.1:{zenoh_port}"],
           "listen": ["tcp/127.0.0.1:0"], **(session or {})}
    doc["bus"] = {**{k: v for k, v in bus.items() if v is not None},
                  "multicast_scouting": False, "status_period_s": 0.2, "tiles_period_s": 0.1,
                  "tiles_max_bytes_per_s": 1 << 20}
    doc["service"] = {"state_dir": str(state_dir), "checkpoint_period_s": 1.0, **service}
    path.write_text(yaml.safe_dump(doc))
    return path


def candidates_query(session, keys: VehicleKeys, timeout_s: float = 30.0) -> list[dict]:
    """The candidates the daemon answers on ``keys.candidates`` (decoded), asking again until
    one answers (a daemon starting or restarting) or ``timeout_s`` passes."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        for reply in session.get(keys.candidates, timeout=5.0):
            if reply.ok is not None:
                return decode_detections(reply.ok.payload.to_bytes())["candidates"]
        time.sleep(0.2)
    raise AssertionError(f"no answer to the query {keys.candidates}")


def small_plan(folder: Path, mission: dict) -> Path:
    """``pdcov plan`` of ``mission`` (a lawnmower at 10 m height, 10 m apart) in ``folder``;
    the .plan file's path."""
    (folder / "m.yaml").write_text(yaml.safe_dump(mission))
    assert pdcov_main(["plan", "--config", str(folder / "m.yaml"), "--altitude-m", "10",
                       "--spacing-m", "10", "--out", str(folder / "plan"), "--no-figures"]) == 0
    return folder / "plan" / "plan.plan"


class Subscriber:
    """A client session following one vehicle: the latest status, the grid rebuilt from
    tiles (after a snapshot when a gap is seen), errors from decoders."""

    def __init__(self, zenoh_port: int, vehicle_id: str) -> None:
        self.keys = VehicleKeys(vehicle_id)
        self.session = open_session(BusConfig(mode="client",
                                              connect=(f"tcp/127.0.0.1:{zenoh_port}",),
                                              multicast_scouting=False))
        self.lock = threading.Lock()
        self.status: dict | None = None
        self.statuses = 0
        self.grid: GridState | None = None
        self.last_seq: int | None = None
        self.gaps = 0
        self.errors: list[str] = []
        self.tile_bytes = 0
        self.last_seq_seen: int | None = None
        self._queue: list = []
        self._subs = [self.session.declare_subscriber(self.keys.status, self._on_status),
                      self.session.declare_subscriber(self.keys.tiles, self._on_tiles)]

    def _on_status(self, sample) -> None:
        try:
            doc = decode_status(sample.payload.to_bytes())
        except BusPayloadError as exc:
            self.errors.append(str(exc))
            return
        with self.lock:
            self.status, self.statuses = merge_status(self.status, doc), self.statuses + 1

    def _on_tiles(self, sample) -> None:
        """Zenoh thread: decode and queue; never block here (a get inside a callback
        would wait for this very thread)."""
        payload = sample.payload.to_bytes()
        try:
            update = decode_tiles(payload)
        except BusPayloadError as exc:
            self.errors.append(str(exc))
            return
        with self.lock:
            self.tile_bytes += len(payload)
            self.last_seq_seen = update.seq
            self._queue.append(update)

    def sync(self) -> None:
        """Apply queued tiles, first fetching the snapshot when there is no grid, a gap in
        seq or another grid hash (docs/protocol.md, "Joining"): tiles older than the
        snapshot (fewer frames) are dropped."""
        with self.lock:
            queue, self._queue = self._queue, []
        if self.grid is None and self.status is not None:
            self.grid = self.snapshot()  # a late joiner starts from the snapshot
        for update in queue:
            gap = self.last_seq is not None and update.seq != self.last_seq + 1
            self.last_seq = update.seq
            if self.grid is None or gap or update.grid_hash != self.grid.hash:
                self.gaps += gap
                self.grid = self.snapshot()
            if self.grid is not None and update.frames >= self.grid.frames:
                apply_tiles(self.grid, update)

    def snapshot(self) -> GridState | None:
        for reply in self.session.get(self.keys.snapshot, timeout=5.0):
            if reply.ok is not None:
                return decode_snapshot(reply.ok.payload.to_bytes())
        return None

    def footprint(self) -> bytes | None:
        for reply in self.session.get(self.keys.footprint, timeout=5.0):
            if reply.ok is not None:
                return reply.ok.payload.to_bytes()
        return None

    def wait(self, predicate, timeout_s: float, what: str) -> dict:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.sync()
            with self.lock:
                st = self.status
            if st is not None and predicate(st):
                return st
            time.sleep(0.05)
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; last "
                             f"status {self.status}")

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


SPEED = 6.0
"""Simulated seconds per wall second for the flights that need no wall-clock pacing; the
daemons keep up at this pace with all flights at once on the loaded 2-core test machine."""


def fly_args(cfg, plan, out, link: str, *more, speed: float = SPEED) -> list[str]:
    """The simulator flying ``plan`` over ``link`` (its end, docs/simulator.md), ``speed``
    times faster than real time (at --speed 0 a burst of small datagrams can overflow a busy
    receiver's socket on a loaded machine: then live and the simulator's tlog differ)."""
    return [sys.executable, "-m", "pdcov_sitl.cli", "fly", "--config", str(cfg), "--plan",
            str(plan), "--out", str(out), "--connect", link, "--speed", str(speed), *more]


def offline(cfg, tlog, out, *more: str) -> dict:
    """``pdcov evaluate`` of a tlog, in a process of its own (flights evaluate at once); its
    summary (stdout) under "summary"."""
    res = subprocess.run([sys.executable, "-m", "pdcov.cli", "evaluate", "--config", str(cfg),
                          "--log", str(tlog), "--out", str(out), "--no-progress", *more],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    with np.load(out / "grid.npz") as z:
        return {"summary": res.stdout, **{k: z[k] for k in z.files}}


def same(state, ref, what) -> None:
    for key in ("log_miss_d", "log_miss_fa", "n_obs"):
        np.testing.assert_array_equal(getattr(state, key), ref[key], err_msg=f"{what}: {key}")


def live_equals_offline(out: dict) -> None:
    """``fly_udp``'s outcome with "sim" (``offline`` of the simulator's tlog): more than 100
    frames, the same frames live and offline, and the daemon's snapshot, tiles and
    checkpoint (limiting factors included) equal to evaluate's grid cell for cell."""
    st, ref, tmp = out["st"], out["sim"], out["cfg"].parent
    assert st["frames"]["grid"] == int(ref["frames"]) > 100, \
        (tmp / "serve.log").read_text()[-3000:]
    same(out["snap"], ref, "snapshot vs pdcov evaluate of the simulator's tlog")
    same(out["grid"], ref, "tiles vs pdcov evaluate of the simulator's tlog")
    z = read_checkpoint(tmp / "st" / "checkpoint")
    same(out["snap"], z, "checkpoint")
    np.testing.assert_array_equal(z["limiting"], ref["limiting"])


def recording(tmp: Path) -> Path:
    """The daemon's one recording of the flight."""
    rec = sorted((tmp / "st" / "recordings").glob("*.tlog"))
    assert len(rec) == 1, rec
    return rec[0]


@contextlib.contextmanager
def watched(zport: int):
    """A router and a subscriber following sim1 through it; closed on exit."""
    r = router(zport)
    sub = None
    try:
        sub = Subscriber(zport, "sim1")
        yield sub
    finally:
        if sub is not None:
            sub.close()
        r.close()


def finish(sub: Subscriber, daemon, tmp: Path, before_stop=None
           ) -> tuple[dict, object, object]:
    """Wait until the daemon has read everything (its newest telemetry time and frames the
    same in 6 statuses in a row: a daemon behind a fast simulator may still have datagrams
    in its socket when it has no frame pending) and sent the last tiles; (final status,
    tiles grid, snapshot); stop the daemon (SIGTERM: final checkpoint, exit 0). Frames may
    stay pending at the very end (a stream's last sample before them, no more telemetry to
    decide them): offline places no frame there either."""
    seen: list = [None, None, 0]

    def settled(st: dict) -> bool:
        key = (st["t_s"], st["frames"]["grid"], st["frames"]["pending"])
        if key != seen[0]:
            seen[:] = [key, st["seq"], 0]
        elif st["seq"] != seen[1]:
            seen[1:] = [st["seq"], seen[2] + 1]
        return seen[2] >= 5 and st["tiles_seq"] == sub.last_seq

    sub.wait(settled, 90, "the last telemetry, frames and tiles")
    time.sleep(0.5)
    sub.sync()
    st = sub.status
    snap = sub.snapshot()
    if before_stop is not None:
        before_stop()
    assert daemon.poll() is None, (tmp / "serve.log").read_text()[-3000:]
    assert stop(daemon) == 0
    assert not sub.errors, sub.errors
    return st, sub.grid, snap


def fly_udp(tmp: Path, doc: dict, plan: Path, *fly_more: str, detector=None,
            sim_config: Path | None = None, settled=None, **service):
    """Daemon first (UDP), then the simulator. ``detector(fly, sub, zenoh_port)`` runs
    while the simulator flies and returns the frame times it published and how many it
    sent twice. ``sim_config``: the simulator's mission config (its ground) when it is not
    the daemon's. ``settled(zenoh_port)`` runs once the daemon has taken everything, before
    it stops; what it returns is ``out["settled"]``."""
    zport, mport = free_port(), free_port()
    cfg = serve_config(doc, tmp / "m.yaml", zenoh_port=zport, state_dir=tmp / "st", **service)
    out = {"cfg": cfg}
    with watched(zport) as sub, process(serve_args(cfg, "--connect",
                                                   f"udpin:127.0.0.1:{mport}"),
                                        tmp / "serve.log") as daemon:
        sub.wait(lambda s: True, 60, "the daemon's first status")
        with process(fly_args(sim_config or cfg, plan, tmp / "fly",
                              f"udpout:127.0.0.1:{mport}", *fly_more),
                     tmp / "fly.log") as fly:
            if detector is not None:
                out["times"], out["resent"] = detector(fly, sub, zport)
            assert fly.wait(timeout=240) == 0, (tmp / "fly.log").read_text()[-2000:]
        out["st"], out["grid"], out["snap"] = finish(
            sub, daemon, tmp, None if settled is None else lambda: out.update(
                settled=settled(zport)))
    return out
