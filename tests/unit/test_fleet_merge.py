"""The fleet's merge kept tile by tile (ground/fleet_merge.py) equals the whole-grid merge
(fleet_report.merge_fleet) bit for bit after random tiles, joins, leaves, snapshots, a
second grid and limiting factors becoming unknown; the figures of the report (the fleet's
and each vehicle's, kept per tile) equal their whole-grid computation (exact counts, sums
within 1e-12); the web map's blocks equal the whole grid's."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.bus.grid_state import GridState
from pdcov.bus.tiles import Tile, TileUpdate, tile_bounds, tile_grid_shape
from pdcov.core.domain import GridGeometry
from pdcov.ground.fleet_merge import block_max_pd
from pdcov.ground.fleet_report import merge_fleet
from pdcov.ground.watcher import Watcher

GEOMETRY = GridGeometry(0.0, 0.0, 1.0, 90, 75)
TILE = 16
THRESHOLDS = (0.5, 0.8)


def masks(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two free masks: two grids of one geometry."""
    a = np.ones(GEOMETRY.shape, bool)
    a[30:40, 10:50] = False
    b = a.copy()
    b[rng.integers(0, 90, 20), rng.integers(0, 75, 20)] = False
    return a, b


class Daemon:
    """A vehicle's grid as its daemon holds it (whole arrays), and the tiles it publishes."""

    def __init__(self, vid: str, mask: np.ndarray, rng: np.random.Generator) -> None:
        self.vid, self.rng, self.mask = vid, rng, mask
        shape = GEOMETRY.shape
        self.log_miss_d = np.zeros(shape, np.float32)
        self.log_miss_fa = np.zeros(shape, np.float32)
        self.n_obs = np.zeros(shape, np.int32)
        self.limiting: np.ndarray | None = np.zeros(shape, np.uint8)
        self.frames = 0
        self.hash = GridState.empty(GEOMETRY, mask).hash
        self.seq = 0

    def fly(self, version: int = 2) -> TileUpdate:
        """A few tiles looked at again: their changed values as a tiles message."""
        n_tr, n_tc = tile_grid_shape(TILE, *GEOMETRY.shape)
        picked = {(int(self.rng.integers(n_tr)), int(self.rng.integers(n_tc)))
                  for _ in range(int(self.rng.integers(1, 4)))}
        tiles = []
        for tr, tc in sorted(picked):
            r0, r1, c0, c1 = tile_bounds(tr, tc, TILE, *GEOMETRY.shape)
            cells = np.s_[r0:r1, c0:c1]
            shape = (r1 - r0, c1 - c0)
            self.log_miss_d[cells] -= self.rng.random(shape).astype(np.float32) * 0.7
            self.log_miss_fa[cells] -= self.rng.random(shape).astype(np.float32) * 0.01
            self.n_obs[cells] += 1
            if self.limiting is not None:
                self.limiting[cells] = self.rng.integers(0, 4, shape, dtype=np.uint8)
            tiles.append(Tile(tr, tc, self.log_miss_d[cells].copy(),
                              self.log_miss_fa[cells].copy(),
                              self.n_obs[cells].astype(np.int64), np.zeros(shape, np.uint16),
                              None if version < 2 or self.limiting is None
                              else self.limiting[cells].copy()))
        if version < 2:
            self.limiting = None
        self.frames += 1
        self.seq += 1
        return TileUpdate(version, self.seq, self.hash, float(self.seq), self.frames, TILE,
                          *GEOMETRY.shape, tuple(tiles))

    def snapshot(self) -> GridState:
        if self.limiting is None:
            self.limiting = np.zeros(GEOMETRY.shape, np.uint8)
        return GridState.from_arrays(GEOMETRY, self.mask, self.log_miss_d, self.log_miss_fa,
                                     self.n_obs, self.frames, self.limiting)


def assert_same_state(a: GridState, b: GridState) -> None:
    for name in ("mask", "log_miss_d", "log_miss_fa", "n_obs"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name  # bit for bit
    assert a.frames == b.frames
    assert (a.limiting is None) == (b.limiting is None)
    if a.limiting is not None:
        assert a.limiting.tobytes() == b.limiting.tobytes()


def assert_figures(w: Watcher, now_s: float) -> None:
    """The report's figures against the whole grid's, fleet and vehicles."""
    report = w.report(now_s)
    merged, ids = merge_fleet(w.feeds.values(), w.grid_hash)
    assert report.merged == ids
    kept, kept_ids = w.fleet_state()
    assert kept_ids == ids
    if merged is None:
        assert kept is None and report.mean_pd is None
        return
    assert kept is not None
    assert_same_state(kept, merged)
    pairs = [(report.proportion_at_or_above, report.mean_pd, report.cells_free, merged)]
    pairs += [(v.proportion_at_or_above, v.mean_pd, None, w.feeds[v.vehicle_id].state)
              for v in report.vehicles if v.grid_ready]
    for props, mean_pd, cells_free, state in pairs:
        pd = state.pd[state.mask]
        if cells_free is not None:
            assert cells_free == pd.size
        for t, share in props.items():
            assert share == (pd >= t).sum() / pd.size
        assert mean_pd == pytest.approx(float(pd.mean()), rel=1e-12, abs=0)
    blocks = w.fleet_blocks()
    assert blocks is not None
    assert np.array_equal(blocks.values(), block_max_pd(merged.pd, merged.mask,
                                                         blocks.stride))


@pytest.mark.parametrize("seed", range(4))
def test_the_merge_kept_by_tile_is_the_whole_grid_merge(seed):
    rng = np.random.default_rng(seed)
    grid_a, grid_b = masks(rng)
    w = Watcher(thresholds=THRESHOLDS)
    daemons: dict[str, Daemon] = {}
    now = 0.0
    for step in range(160):
        now += 0.1
        roll = rng.random()
        if roll < 0.06 or not daemons:  # a vehicle joins (one in five on the other grid)
            vid = f"uav{len(daemons) + 1}"
            daemons[vid] = d = Daemon(vid, grid_b if rng.random() < 0.2 else grid_a, rng)
            for _ in range(int(rng.integers(0, 4))):
                d.fly()
            w.on_snapshot(vid, d.snapshot(), now)
        elif roll < 0.10:  # a snapshot taken again, after tiles lost or not
            d = daemons[str(rng.choice(sorted(daemons)))]
            if rng.random() < 0.5:
                d.fly()  # lost
            w.on_snapshot(d.vid, d.snapshot(), now)
        elif roll < 0.13:  # a vehicle leaves: a gap in its tiles, its snapshot asked for
            d = daemons[str(rng.choice(sorted(daemons)))]
            w.on_tiles(d.vid, d.fly(), now)
            d.fly()  # lost
            w.on_tiles(d.vid, d.fly(), now)
        elif roll < 0.15:  # an older daemon: limiting factors unknown
            d = daemons[str(rng.choice(sorted(daemons)))]
            w.on_tiles(d.vid, d.fly(version=1), now)
        else:
            for d in daemons.values():
                if rng.random() < 0.6:
                    w.on_tiles(d.vid, d.fly(), now)
        if step % 3 == 0 or roll < 0.15:
            assert_figures(w, now)
    assert_figures(w, now)
    assert w.fleet.merged_whole < w.fleet.windows_merged  # mostly tile by tile


def test_a_report_with_nothing_new_merges_nothing():
    rng = np.random.default_rng(7)
    w = Watcher(thresholds=THRESHOLDS)
    daemons = [Daemon(f"uav{k}", masks(rng)[0], rng) for k in range(3)]
    for d in daemons:
        w.on_snapshot(d.vid, d.snapshot(), 0.0)
    w.report(0.1)
    whole, windows = w.fleet.merged_whole, w.fleet.windows_merged
    w.report(0.2)
    assert (w.fleet.merged_whole, w.fleet.windows_merged) == (whole, windows)
    update = daemons[1].fly()
    w.on_tiles("uav2", update, 0.3)
    assert_figures(w, 0.4)
    assert w.fleet.merged_whole == whole
    assert w.fleet.windows_merged == windows + len(update.tiles)


def test_a_vehicle_joining_leaving_or_resent_merges_only_the_tiles_it_wrote():
    rng = np.random.default_rng(3)
    mask = masks(rng)[0]
    w = Watcher(thresholds=THRESHOLDS)
    daemons = [Daemon(f"uav{k}", mask, rng) for k in range(1, 4)]
    for d in daemons[:2]:
        w.on_snapshot(d.vid, d.snapshot(), 0.0)
        w.on_tiles(d.vid, d.fly(), 0.0)
    assert_figures(w, 0.1)
    whole = w.fleet.merged_whole
    late = daemons[2]
    written = {(t.tile_row, t.tile_col) for t in late.fly().tiles}
    w.on_snapshot(late.vid, late.snapshot(), 0.2)  # joins
    merged = w.fleet.windows_merged
    assert_figures(w, 0.3)
    layout = w.feeds[late.vid].state.free.layout  # merged by the tiles the grids store
    stored = {k for tr, tc in written
              for k in layout.keys(tile_bounds(tr, tc, TILE, *GEOMETRY.shape))}
    assert w.fleet.windows_merged - merged == len(stored)
    w.on_snapshot("uav1", daemons[0].snapshot(), 0.4)  # the same grid sent again: no change
    merged = w.fleet.windows_merged
    assert_figures(w, 0.5)
    assert w.fleet.windows_merged == merged
    w.on_tiles(late.vid, late.fly(), 0.6)
    late.fly()  # lost
    w.on_tiles(late.vid, late.fly(), 0.6)  # a gap: it leaves until its snapshot comes
    assert w.feeds[late.vid].awaiting_since_s is not None
    assert_figures(w, 0.7)
    w.on_snapshot(late.vid, late.snapshot(), 0.8)  # and comes back
    assert_figures(w, 0.9)
    daemons[1].fly()  # lost, then the snapshot taken again holds it
    w.on_snapshot("uav2", daemons[1].snapshot(), 1.0)
    assert_figures(w, 1.1)
    assert w.fleet.merged_whole == whole
