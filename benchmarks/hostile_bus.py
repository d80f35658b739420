"""``python -m benchmarks.hostile_bus``: the red team's findings on the default bus (issue
23), measured again in one run against the watcher's decisions and the bus decoders, in
memory: what a forged tiles message does to the map, what a hostile status, a 25 M-cell
snapshot, 2,000 invented vehicle ids and the 83-byte replayed tiles message cost now; and
the input bounds of issue 34 (a far-future frames flood, invented classes, a 1M-bin detector
model, zoom jitter, a folding lens, a DEM far off the home, 1e6 frames/s, a 65-character
vehicle id, a slow MBTiles) against the daemon's decisions (ServiceCore, fed MAVLink bytes
as tests/support/link_feed.py does) and the loaders, with the process's RSS before, during and
after the flood.
Prints a markdown table (docs/reliability.md "Hostile participant"); exit 1 when a bound
does not hold. The same cases run over real Zenoh in tests/system/test_watch_hostile.py and
tests/unit/test_bus_hostile.py.
"""

from __future__ import annotations

import io
import json
import sys
import time
import tracemalloc
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.grid_state import GridState, decode_snapshot, grid_hash
from pdcov.bus.status import decode_status
from pdcov.bus.tiles import decode_tiles, encode_tiles, tile_grid_shape
from pdcov.core.domain import GridGeometry
from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.ground.watcher import Watcher
from pdcov.ground.web import map_state

# The watcher tests' stand-in publisher (a real CoverageGrid through the bus codecs), so
# that these figures are of the same cases as tests/unit/test_watcher_pinning.py.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from benchmarks.hostile_inputs import input_bound_cases
from benchmarks.hostile_retask import retask_cases
from tests.support.watch_fixtures import TinyPublisher

DAEMON, ROGUE = "a1" * 16, "e7" * 16


@dataclass(frozen=True)
class Finding:
    name: str
    before: str  # the red team's figure (issue 23)
    now: str
    holds: bool


def peak_bytes(fn: Callable[[], object]) -> tuple[int, object]:
    """Peak traced allocation of ``fn()`` (numpy reports to tracemalloc) and its result."""
    tracemalloc.start()
    try:
        result: object = fn()
    except BusPayloadError as exc:
        result = exc
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak, result


def forged_tiles_case() -> Finding:
    pub = TinyPublisher("uav1")
    w = Watcher(thresholds=(0.5, 0.7, 0.8))
    w.on_snapshot("uav1", decode_snapshot(pub.snapshot()), 0.0, DAEMON)
    for k in range(20):
        pub.step()
        w.on_tiles("uav1", decode_tiles(pub.tiles()), 0.1 * k, DAEMON)
    g = pub.grid
    state = GridState.from_arrays(
        g.geometry, g.mask, np.full(g.geometry.shape, -20.0, np.float32),
        np.zeros(g.geometry.shape, np.float32), np.ones(g.geometry.shape, np.int32),
        g.frames + 1, np.full(g.geometry.shape, LimitingFactor.SEEN, np.uint8))
    rows, cols = tile_grid_shape(pub.tile_size, *g.geometry.shape)
    forged = encode_tiles(state, [(r, c) for r in range(rows) for c in range(cols)],
                          seq=pub.seq + 1, t_s=pub.t_s, tile_size=pub.tile_size)
    for _ in w.on_tiles("uav1", decode_tiles(forged), 3.0, ROGUE):  # a claim check:
        w.on_snapshot("uav1", decode_snapshot(pub.snapshot()), 3.0, DAEMON)  # answered
    shown = w.report(3.0).vehicles[0].proportion_at_or_above[0.8]
    truth = g.metrics([0.8]).proportion_at_or_above[0.8]
    warned = any("also claims" in line for line in w.report(3.0).warnings)
    return Finding("forged tiles from another session (204 B, next seq, every cell P_D 1)",
                   "map 0 % -> 100 % at P_D >= 0.8, no warning",
                   f"map {100 * shown:.1f} % = daemon's {100 * truth:.1f} %, "
                   f"{'warned' if warned else 'NOT warned'}",
                   shown == truth and warned)


def big_grid_watcher(n: int) -> tuple[Watcher, dict]:
    geo = GridGeometry(0.0, 0.0, 1.0, n, n)
    mask = np.ones((n, n), bool)
    state = GridState.empty(geo, mask)
    state.write(Layer.LOG_MISS_D, (0, n, 0, n),
                np.linspace(0, -3, n * n, dtype=np.float32).reshape(n, n))
    w = Watcher(thresholds=(0.5, 0.7, 0.8))
    w.on_snapshot("uav1", state, 0.0, DAEMON)
    pub = TinyPublisher("uav1")
    doc = json.loads(pub.status())
    doc["grid"].update(hash=grid_hash(geo, mask), n_rows=n, n_cols=n, x0_m=0.0, y0_m=0.0,
                       cell_size_m=1.0)
    return w, doc


def hostile_status_case() -> Finding:
    w, doc = big_grid_watcher(1000)
    doc["thresholds"] = [round(0.5 + k * 1e-5, 5) for k in range(5500)]
    payload = json.dumps(doc).encode()
    t0 = time.perf_counter()
    try:
        w.on_status("uav1", decode_status(payload), 1.0, DAEMON)
        refused = False
    except BusPayloadError:
        refused = True
    t1 = time.perf_counter()
    map_state(w, w.report(1.0), None, 1, None)
    t2 = time.perf_counter()
    return Finding(f"status with 5,500 thresholds ({len(payload) // 1000} kB) beside a 1 M-cell "
                   "grid", "/state.json 4 ms -> 55 s",
                   f"{'refused' if refused else 'TAKEN'} in {1e3 * (t1 - t0):.1f} ms; "
                   f"map state {1e3 * (t2 - t1):.0f} ms", refused and t2 - t1 < 5.0)


def huge_snapshot_case() -> Finding:
    side = 5000
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, arr in (("mask", np.ones((side, side), bool)),
                          ("log_miss_d", np.zeros((side, side), np.float32)),
                          ("log_miss_fa", np.zeros((side, side), np.float32)),
                          ("n_obs", np.zeros((side, side), np.int32)),
                          ("x0_m", np.array(0.0)), ("y0_m", np.array(0.0)),
                          ("cell_size_m", np.array(1.0))):
            b = io.BytesIO()
            np.save(b, arr)
            z.writestr(name + ".npy", b.getvalue())
    payload = buf.getvalue()
    peak, result = peak_bytes(lambda: decode_snapshot(payload))
    refused = isinstance(result, BusPayloadError)
    return Finding(f"snapshot of 25 M cells ({len(payload) / 1e6:.1f} MB)",
                   "watcher 114 MB -> 1.1 GB",
                   f"{'refused' if refused else 'TAKEN'}, peak {peak / 1e6:.1f} MB while "
                   "decoding", refused and peak < 50e6)


def fake_vehicles_case() -> Finding:
    pub = TinyPublisher("x")
    status = json.loads(pub.status())
    w = Watcher()

    def flood() -> None:
        for k in range(2000):
            vid = f"fake{k:04d}"
            w.on_alive(vid, True, 0.0)
            doc = dict(status, vehicle_id=vid)
            w.on_status(vid, decode_status(json.dumps(doc).encode()), 0.0, ROGUE)
            w.on_snapshot(vid, decode_snapshot(pub.snapshot()), 0.0, ROGUE)

    peak, _ = peak_bytes(flood)
    return Finding("2,000 invented vehicle ids (liveliness, status, snapshot)",
                   "206 MB", f"{len(w.feeds)} followed, "
                   f"{sum(w.refused.values())} refused, peak {peak / 1e6:.1f} MB",
                   len(w.feeds) <= 64)


def replayed_tiles_case() -> Finding:
    pub = TinyPublisher("uav1")
    g = pub.grid.geometry
    other = GridState.empty(GridGeometry(g.x0_m, g.y0_m, g.cell_size_m, 30, 30),
                            np.ones((30, 30), bool))
    other.frames = 2**32 - 1
    bad = encode_tiles(other, [(0, 0)], seq=1, t_s=0.0, tile_size=8,
                       grid_hash=grid_hash(g, pub.grid.mask))
    w = Watcher()
    queries = 0
    now = 0.0

    def do(actions) -> None:
        nonlocal queries
        for _ in actions:
            queries += 1
            do(w.on_snapshot("uav1", decode_snapshot(pub.snapshot()), now, DAEMON))

    do(w.on_tiles("uav1", decode_tiles(bad), now, DAEMON))
    while now < 60.0:
        now += 0.25
        pub.step()
        payload = pub.tiles()
        if payload is not None:
            do(w.on_tiles("uav1", decode_tiles(payload), now, DAEMON))
        do(w.on_status("uav1", decode_status(pub.status()), now, DAEMON))
        do(w.poll(now))
    ready = w.report(now).vehicles[0].grid_ready
    return Finding("83-byte tiles (the vehicle's hash, a 30 x 30 geometry, frames 2^32 - 1) "
                   "before the snapshot", "never ready, snapshot every 5 s for good",
                   f"{'ready' if ready else 'NOT ready'}, {queries} snapshot in 60 s",
                   ready and queries == 1)


def main() -> int:
    findings = [forged_tiles_case(), hostile_status_case(), huge_snapshot_case(),
                fake_vehicles_case(), replayed_tiles_case(),
                *(Finding(*c) for c in input_bound_cases()),
                *(Finding(*c) for c in retask_cases())]
    print("| finding | red team (before) | now | holds |")
    print("|---|---|---|---|")
    for f in findings:
        print(f"| {f.name} | {f.before} | {f.now} | {'yes' if f.holds else 'NO'} |")
    return 0 if all(f.holds for f in findings) else 1


if __name__ == "__main__":
    sys.exit(main())
