"""A tiny stand-in publisher for the watcher's tests: a real CoverageGrid updated with nadir
frames, encoded with the bus codecs as the daemon publishes it (status, tiles, snapshot).
It is not the daemon; the end-to-end tests use the real one."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pdcov.bus.grid_state import GridState, decode_snapshot, encode_snapshot, grid_hash
from pdcov.bus.sources import SourcedPublisher
from pdcov.bus.status import decode_status, encode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles, tile_grid_shape
from pdcov.config.load import load_mission
from pdcov.core.limiting import LimitingFactor
from pdcov.core.pose import CameraPose
from pdcov.ground.watcher import QuerySnapshot, Watcher
from tests.support.harness import free_port as free_port  # re-exported for the watch tests

DEMO = str(Path(__file__).resolve().parents[2] / "service/pdcov/data/demo_mission.yaml")
R_ENU_CAM_NADIR = np.diag([1.0, -1.0, -1.0])  # optical axis down, image x east


class TinyPublisher:
    """The demo mission's grid flown along a lane at ``y_m``; after each ``step`` the tiles
    that changed since the last ``tiles()`` are due."""

    def __init__(self, vehicle_id: str = "demo", y_m: float = -40.0, tile_size: int = 8,
                 mission_path: str = DEMO) -> None:
        self.mission = load_mission(mission_path)
        self.vehicle_id = vehicle_id
        self.grid = self.mission.new_mission_grid()
        self.y_m = y_m
        self.tile_size = tile_size
        self.seq = 0
        self.t_s = 0.0
        self.uptime_s = 0.0
        self._changed: set[tuple[int, int]] = set()

    def step(self, n: int = 1) -> None:
        """Add ``n`` frames 0.5 s apart, moving 1.5 m east per frame."""
        ts = self.tile_size
        for _ in range(n):
            before = self.grid.log_miss_d.copy(), self.grid.limiting.copy()
            x = -58.0 + 1.5 * (self.grid.frames % 26)
            self.grid.update(CameraPose(R_ENU_CAM_NADIR, np.array([x, self.y_m, 10.0]),
                                        self.t_s), self.t_s)
            self.t_s += 0.5
            self.uptime_s += 0.5
            rows, cols = np.nonzero((before[0] != self.grid.log_miss_d)
                                    | (before[1] != self.grid.limiting))
            self._changed.update(zip((rows // ts).tolist(), (cols // ts).tolist(),
                                     strict=True))

    def tiles(self) -> bytes | None:
        """The next tiles message (seq + 1), or None when nothing changed."""
        if not self._changed:
            return None
        self.seq += 1
        payload = encode_tiles(GridState.from_grid(self.grid), sorted(self._changed),
                               seq=self.seq, t_s=self.t_s, tile_size=self.tile_size)
        self._changed.clear()
        return payload

    def snapshot(self) -> bytes:
        return encode_snapshot(self.grid)

    def status(self) -> bytes:
        g = self.grid
        m = g.metrics(self.mission.thresholds)
        geo = g.geometry
        o = self.mission.origin()
        return encode_status({
            "vehicle_id": self.vehicle_id, "seq": int(self.uptime_s * 2),
            "uptime_s": self.uptime_s, "t_s": self.t_s,
            "thresholds": list(self.mission.thresholds),
            "proportion_at_or_above": {str(t): p for t, p in m.proportion_at_or_above.items()},
            "mean_pd": m.mean_pd, "expected_false_alarms": m.expected_false_alarms,
            "cells_free": m.cells_free, "cells_observed": m.cells_observed,
            "frames": {"used": g.frames, "skipped": {"stale": 0}},
            "link": {"state": "up"},
            "pose": {"lat_deg": o.lat_deg + 1e-5 * g.frames, "lon_deg": o.lon_deg,
                     "alt_msl_m": 15.0, "heading_deg": 90.0, "t_s": self.t_s},
            "gimbal": {}, "faults": {}, "tiles_seq": self.seq, "tiles_behind": 0,
            "grid": {"hash": grid_hash(geo, g.mask), "x0_m": geo.x0_m, "y0_m": geo.y0_m,
                     "cell_size_m": geo.cell_size_m, "n_rows": geo.n_rows,
                     "n_cols": geo.n_cols, "tile_size": self.tile_size,
                     "origin": {"lat_deg": o.lat_deg, "lon_deg": o.lon_deg,
                                "ground_alt_msl_m": o.ground_alt_msl_m}}})

    def n_tiles(self) -> int:
        r, c = tile_grid_shape(self.tile_size, *self.grid.geometry.shape)
        return r * c


PINNED_SESSION = "a1" * 16
"""The daemon's session a ``pinned`` watcher follows."""


def pinned(watcher: Watcher | None = None) -> tuple[Watcher, TinyPublisher]:
    """A watcher following vehicle uav1, pinned to PINNED_SESSION by its snapshot reply."""
    w = watcher or Watcher()
    pub = TinyPublisher("uav1")
    pub.step(4)
    actions = w.on_status("uav1", decode_status(pub.status()), 0.0, PINNED_SESSION)
    assert actions == [QuerySnapshot("uav1")]
    w.on_snapshot_replies("uav1", [(PINNED_SESSION, decode_snapshot(pub.snapshot()))], 0.1)
    return w, pub


def forged_tiles(pub: TinyPublisher, seq: int, frames: int | None = None) -> bytes:
    """Every tile of ``pub``'s grid at P_D ~ 1: ground nobody searched shown as searched."""
    g = pub.grid
    state = GridState.from_arrays(
        g.geometry, g.mask, np.full(g.geometry.shape, -20.0, np.float32),
        np.zeros(g.geometry.shape, np.float32), np.ones(g.geometry.shape, np.int32),
        g.frames + 1 if frames is None else frames,
        np.full(g.geometry.shape, LimitingFactor.SEEN, np.uint8))
    rows, cols = tile_grid_shape(pub.tile_size, *g.geometry.shape)
    return encode_tiles(state, [(r, c) for r in range(rows) for c in range(cols)], seq=seq,
                        t_s=pub.t_s, tile_size=pub.tile_size)


def zenoh_conf(mode: str, connect: str | None = None, listen: str | None = None):
    """A loopback-only Zenoh config (no multicast scouting)."""
    import json

    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
    return conf


class ZenohTinyDaemon:
    """TinyPublisher on Zenoh as docs/protocol.md says: liveliness token, status, tiles,
    snapshot and footprint queryables; ``publish_step`` adds frames and publishes (tiles
    whose seq is in ``drop`` are not sent)."""

    def __init__(self, pub: TinyPublisher, router: str, drop=()) -> None:
        import threading

        import zenoh

        from pdcov.bus.footprint import encode_footprint
        from pdcov.bus.keys import VehicleKeys

        self.pub = pub
        self.drop = set(drop)
        self.lock = threading.Lock()
        self.keys = VehicleKeys(pub.vehicle_id)
        self.session = zenoh.open(zenoh_conf("client", connect=router))
        self.token = self.session.liveliness().declare_token(self.keys.alive)

        def snapshot(query):
            with self.lock:
                payload = self.pub.snapshot()
            query.reply(self.keys.snapshot, payload)

        def footprint(query):
            o = self.pub.mission.origin()
            ring = np.array([[o.lon_deg, o.lat_deg], [o.lon_deg + 1e-4, o.lat_deg],
                             [o.lon_deg, o.lat_deg + 1e-4]])
            query.reply(self.keys.footprint, encode_footprint(self.pub.vehicle_id, 0.0, ring))

        self.queryables = [self.session.declare_queryable(self.keys.snapshot, snapshot),
                           self.session.declare_queryable(self.keys.footprint, footprint)]
        # As the daemon publishes: each put names this session (the watcher pins to it).
        self.pub_tiles = SourcedPublisher(self.session.declare_publisher(self.keys.tiles))
        self.pub_status = SourcedPublisher(self.session.declare_publisher(self.keys.status))

    def publish_step(self, frames: int = 1, status: bool = True) -> None:
        with self.lock:
            self.pub.step(frames)
            payload = self.pub.tiles()
            seq = self.pub.seq
            st = self.pub.status()
        if payload is not None and seq not in self.drop:
            self.pub_tiles.put(payload)
        if status:
            self.pub_status.put(st)

    def close(self) -> None:
        for q in [*self.queryables, self.pub_tiles, self.pub_status]:
            q.undeclare()
        self.token.undeclare()
        self.session.close()


# -- real Zenoh on loopback: a router in the test process, watchers as processes ---------


@pytest.fixture
def router():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    import zenoh

    session = zenoh.open(zenoh_conf("router", listen=endpoint))
    try:
        yield endpoint
    finally:
        session.close()


@pytest.fixture
def processes():
    procs: list[subprocess.Popen] = []
    try:
        yield procs
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)


@pytest.fixture
def daemons():
    made: list[ZenohTinyDaemon] = []
    try:
        yield made
    finally:
        for d in made:
            d.close()


def start_watcher(processes, router, *extra) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-m", "pdcov.cli", "watch", "--mode", "client",
                          "--zenoh-connect", router, "--no-multicast-scouting", "--plain",
                          *map(str, extra)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    processes.append(p)
    line = read_line(p, 60.0)  # "following ..." once subscribed
    assert line.startswith("pdcov watch: following"), line
    return p


def read_line(p: subprocess.Popen, timeout_s: float) -> str:
    """The next line of ``p``'s output, or fail after ``timeout_s``."""
    import selectors

    with selectors.DefaultSelector() as sel:
        sel.register(p.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            raise AssertionError(f"no output from {p.args} in {timeout_s} s")
    return p.stdout.readline()


def stop_watcher(p: subprocess.Popen) -> str:
    """Stop a watcher with SIGTERM; everything it printed after the lines read_line took.
    (Read through p.stdout, not communicate(timeout=...), which reads the pipe's file
    descriptor and so loses what read_line's readline left in the text buffer.)"""
    p.send_signal(signal.SIGTERM)
    p.wait(timeout=60)
    out = p.stdout.read()
    assert p.returncode == 0, out
    return out




def load(path) -> dict[str, np.ndarray]:
    """The arrays of an .npz file."""
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


class ThreadedWebMap:
    """A WebMap on 127.0.0.1 (free port) serving ``state()`` (version 7 throughout) with
    ``desk`` for re-tasking, run by an event loop in a thread; stopped, and its basemap
    closed, in ``close``."""

    def __init__(self, state, access, basemap=None, desk=None) -> None:
        import asyncio
        import threading

        from pdcov.ground.web import WebMap

        self.state = state
        self.basemap = basemap
        self.loop = asyncio.new_event_loop()
        self.web = WebMap("127.0.0.1", 0, state, lambda: 7, access, basemap, period_s=0.05,
                          desk=desk)
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self.web.start(), self.loop).result(timeout=10)

    def close(self) -> None:
        import asyncio

        try:
            asyncio.run_coroutine_threadsafe(self.web.stop(), self.loop).result(timeout=10)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(timeout=10)
            self.loop.close()
            if self.basemap is not None:
                self.basemap.close()


class Link:
    """Carries the publisher's messages to a watcher; drop= seqs of tiles to lose."""

    def __init__(self, pub: TinyPublisher, watcher: Watcher, drop=()) -> None:
        self.pub, self.w, self.drop = pub, watcher, set(drop)
        self.now_s = 0.0
        self.queries = 0

    def do(self, actions) -> None:
        for a in actions:
            assert isinstance(a, QuerySnapshot) and a.vehicle_id == self.pub.vehicle_id
            self.queries += 1
            self.do(self.w.on_snapshot(a.vehicle_id, decode_snapshot(self.pub.snapshot()),
                                       self.now_s))

    def fly(self, frames: int, status_every: int = 4) -> None:
        for k in range(frames):
            self.pub.step()
            self.now_s += 0.25
            payload = self.pub.tiles()
            if payload is not None and self.pub.seq not in self.drop:
                self.do(self.w.on_tiles(self.pub.vehicle_id, decode_tiles(payload),
                                        self.now_s))
            if k % status_every == 0:
                self.status()
            self.do(self.w.poll(self.now_s))

    def status(self) -> None:
        self.do(self.w.on_status(self.pub.vehicle_id, decode_status(self.pub.status()),
                                 self.now_s))

    def idle(self, seconds: float) -> None:
        """Nothing new flies; status keeps coming once a second."""
        end = self.now_s + seconds
        while self.now_s < end:
            self.now_s += 1.0
            self.status()
            self.do(self.w.poll(self.now_s))
