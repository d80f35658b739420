"""End-to-end helpers for ``pdcov serve`` tests: the config writer and a subscriber that
rebuilds the grid from tiles and snapshots exactly as docs/protocol.md says. Ports, the
in-process Zenoh router, processes that are always killed and the daemon's command line
come from benchmarks.harness (shared with the benchmarks) and are re-exported here."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import yaml

from benchmarks.harness import ROOT, free_port, router, serve_args, stop
from benchmarks.harness import child as process
from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.session import BusConfig, open_session
from pdcov.bus.status import decode_status, merge_status
from pdcov.bus.tiles import apply_tiles, decode_tiles
from pdcov.cli import main as pdcov_main

__all__ = ["REAL", "ROOT", "Subscriber", "free_port", "process", "router", "serve_args",
           "serve_config", "small_plan", "stop"]

REAL = ROOT.parent / "shared" / "real-logs"


def serve_config(base: dict, path: Path, *, zenoh_port: int, state_dir: Path,
                 **service) -> Path:
    doc = dict(base)
    doc["bus"] = {"mode": "peer", "connect": [f"tcp/127.0.0.1:{zenoh_port}"],
                  "listen": ["tcp/127.0.0.1:0"], "multicast_scouting": False,
                  "status_period_s": 0.2, "tiles_period_s": 0.1,
                  "tiles_max_bytes_per_s": 1 << 20}
    doc["service"] = {"state_dir": str(state_dir), "checkpoint_period_s": 1.0, **service}
    path.write_text(yaml.safe_dump(doc))
    return path


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
