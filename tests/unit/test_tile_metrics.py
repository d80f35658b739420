"""The daemon's periodic work follows the cells frames touch: status metrics kept per tile
(bus.tile_metrics) equal their whole-grid computation, and the tiles the daemon sends
equal those a whole-grid comparison would send, after random updates and a resume."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.bus.grid_state import GridState
from pdcov.bus.tile_metrics import TileMetrics
from pdcov.bus.tiles import decode_tiles, encode_tiles, tile_grid_shape, tile_wire_bytes
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.service.coverage import LiveCoverage
from pdcov.service.tile_sender import TileSender
from tests.support.service_feed import feed, serve_cfg

CAMERA = CameraModel(640, 480, np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))
DETECTOR = DetectorModel.from_dict({"version": 4, "bin_edges_px": [1, 20, 40, 80, 2000],
                                    "p_detect": [0.1, 0.4, 0.6, 0.3],
                                    "p_false_alarm": [0.05, 0.1, 0.2, 0.3],
                                    "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],
                                    "input_size_px": None})
THRESHOLDS = (0.3, 0.5, 0.9)


def grid(**kw) -> CoverageGrid:
    # An L-shaped domain: tiles with obstacle cells, partly free tiles, a ragged last row.
    dom = Domain.from_enu([[-45, -37], [45, -37], [45, 0], [0, 0], [0, 41], [-45, 41]])
    g = dom.grid_geometry(1.0)
    return CoverageGrid(g, dom.free_mask(g), CAMERA, DETECTOR, **kw)


def random_pose(rng, t_s):
    R = R_from_euler_zyx(*np.radians(rng.uniform([-15, -15, 0], [15, 15, 360])))
    xyz = (*rng.uniform(-50, 50, 2), rng.uniform(4, 25))
    return fixed_mount_pose(R, xyz, FixedMount(pitch_rad=math.radians(-90 + rng.uniform(0, 40))),
                            t_s)


def whole(g: CoverageGrid, tile_size: int) -> TileMetrics:
    return TileMetrics(GridState.from_grid(g), tile_size, THRESHOLDS)


@pytest.mark.parametrize("min_revisit_s", [None, 0.45])
def test_incremental_metrics_equal_the_whole_grid_after_random_updates_and_a_resume(
        tmp_path, min_revisit_s):
    rng = np.random.default_rng(7)
    g = grid(min_revisit_s=min_revisit_s)
    live = TileMetrics(g, 16, THRESHOLDS)  # reads the grid's tiles by window
    checked = 0
    for k in range(120):
        g.update(random_pose(rng, 0.1 * k))
        if g.touched is not None:
            live.mark(g.touched)
        if rng.random() < 0.2:  # summaries at random moments, several updates apart
            s = live.summary()
            assert s == whole(g, 16).summary()  # bit for bit
            ref = g.metrics(THRESHOLDS)  # the whole-grid metrics CoverageGrid gives
            assert (s.cells_free, s.cells_observed) == (ref.cells_free, ref.cells_observed)
            assert {t: s.proportion_at_or_above(t) for t in THRESHOLDS} == \
                ref.proportion_at_or_above
            assert s.mean_pd == pytest.approx(ref.mean_pd, rel=1e-12)
            assert s.expected_false_alarms == pytest.approx(ref.expected_false_alarms,
                                                            rel=1e-12)
            checked += 1
    assert checked >= 10 and live.summary().cells_observed > 1000
    # A checkpoint resume: every tile stale once, then incremental again on both grids.
    g.save_npz(tmp_path / "grid.npz")
    back = CoverageGrid.load_npz(tmp_path / "grid.npz", CAMERA, DETECTOR,
                                 min_revisit_s=min_revisit_s)
    resumed = TileMetrics(back, 16, THRESHOLDS)
    assert resumed.summary() == live.summary()
    for k in range(120, 150):
        p = random_pose(rng, 0.1 * k)
        for gg, m in ((g, live), (back, resumed)):
            gg.update(p)
            if gg.touched is not None:
                m.mark(gg.touched)
    assert resumed.summary() == live.summary() == whole(back, 16).summary()


def test_tiles_never_written_count_at_thresholds_up_to_zero_only():
    # Only the tiles frames touched are read: the free cells of the others (P_D 0) count at
    # a threshold of 0 (every free cell) and at no positive one.
    rng = np.random.default_rng(11)
    g = grid()
    for k in range(5):
        g.update(random_pose(rng, 0.1 * k))
    thresholds = (-0.5, 0.0, 1e-9, *THRESHOLDS)
    s = TileMetrics(g, 8, thresholds).summary()
    pd, free = g.pd, g.mask
    assert s.at_or_above == {t: int(np.count_nonzero(free & (pd >= t))) for t in thresholds}
    assert s.at_or_above[0.0] == s.cells_free == int(free.sum()) > s.at_or_above[1e-9] > 0
    assert s.cells_observed == int(np.count_nonzero(free & (g.n_obs > 0))) > 0


class WholeGridTiles(TileSender):
    """The daemon's tiles as they were chosen before touched windows: every tile period,
    the whole grid's observation counts compared with those last sent."""

    def __init__(self, grid, *args):
        super().__init__(grid, *args)
        self.sent_n_obs = np.zeros(grid.geometry.shape, np.int32)

    def send(self, now_s, t_s):
        rate = self._rate
        self._allowance = min(rate, self._allowance + rate * (now_s - self._last_tiles_s))
        self._last_tiles_s = now_s
        ts = self.tile_size
        n_tr, n_tc = tile_grid_shape(ts, *self.grid.geometry.shape)
        gm = self.grid.geometry
        pad = ((0, n_tr * ts - gm.n_rows), (0, n_tc * ts - gm.n_cols))
        changed = np.pad(self.grid.n_obs != self.sent_n_obs, pad).reshape(
            n_tr, ts, n_tc, ts).any(axis=(1, 3))
        for tr, tc in zip(*np.nonzero(changed), strict=True):
            self._dirty_since.setdefault((int(tr), int(tc)), now_s)
        if not self._dirty_since or self._allowance <= 0:
            return None
        order = sorted(self._dirty_since, key=self._dirty_since.__getitem__)
        per_tile = tile_wire_bytes(ts) * self._ratio
        ids = order[:max(1, min(len(order), int(self._allowance // max(per_tile, 1.0)), 0xFFFF))]
        payload = encode_tiles(GridState.from_grid(self.grid), ids, seq=self.seq, t_s=t_s,
                               tile_size=ts)
        self.seq += 1
        self._allowance -= len(payload)
        self._ratio = max(0.01, len(payload) / (len(ids) * tile_wire_bytes(ts)))
        for tr, tc in ids:
            del self._dirty_since[(tr, tc)]
            win = np.s_[tr * ts:(tr + 1) * ts, tc * ts:(tc + 1) * ts]
            self.sent_n_obs[win] = self.grid.n_obs[win]
        return payload


def whole_grid_tiles(cfg, grid, now_s):
    """A LiveCoverage whose tiles are chosen by WholeGridTiles."""
    live = LiveCoverage(cfg, grid, now_s)
    live.tile_sender = WholeGridTiles(grid, live.grid_hash, cfg.bus.tile_size,
                                      cfg.bus.tiles_max_bytes_per_s, now_s)
    return live


@pytest.mark.parametrize("resumed", [False, True])
def test_tiles_and_status_equal_the_whole_grid_comparison(resumed):
    cfg = serve_cfg()
    grids = [cfg.mission.new_mission_grid(), cfg.mission.new_mission_grid()]
    if resumed:  # a checkpointed grid: its observed tiles are sent first
        for gg in grids:
            feed_grid = LiveCoverage(cfg, gg, 0.0)
            feed(feed_grid, 0.0, 4.0)
            feed_grid.process()
    live, ref = LiveCoverage(cfg, grids[0], 0.0), whole_grid_tiles(cfg, grids[1], 0.0)
    now, sent = 0.0, 0
    for second in range(12):
        t0 = 10.0 + second
        for lc in (live, ref):
            feed(lc, t0, t0 + 0.95)
            lc.process()
        for _ in range(7):  # polls at 0.15 s: tile periods fall between feeds
            a, b = live.poll(now), ref.poll(now)
            assert a.tiles == b.tiles and a.status == b.status
            assert a.named_value == b.named_value and a.statustext == b.statustext
            sent += a.tiles is not None
            now += 0.15
        fa = live.status_fields(uptime_s=now, seq=0, link={}, checkpoint={})
        m = ref.grid.metrics(cfg.mission.thresholds)
        assert fa["proportion_at_or_above"] == {str(float(t)): v for t, v in
                                                m.proportion_at_or_above.items()}
        assert (fa["cells_free"], fa["cells_observed"]) == (m.cells_free, m.cells_observed)
        assert fa["mean_pd"] == pytest.approx(m.mean_pd, rel=1e-12)
        assert fa["expected_false_alarms"] == pytest.approx(m.expected_false_alarms,
                                                            rel=1e-12)
        assert fa["grid"]["hash"] == GridState.from_grid(ref.grid).hash
    assert sent >= 5 and live.counters.used > 50
    assert np.array_equal(ref.tile_sender.sent_n_obs, live.grid.n_obs)  # all sent
    assert live.tile_sender.behind == 0


def test_tiles_encode_the_same_bytes_without_the_whole_grid():
    # encode_tiles computes P_D per tile now, and takes the grid hash from its caller: the
    # same bytes as P_D of the whole grid and the state's own hash.
    rng = np.random.default_rng(3)
    g = grid()
    for k in range(40):
        g.update(random_pose(rng, 0.1 * k))
    state = GridState.from_grid(g)
    state.write(Layer.LOG_MISS_D, (5, 6, 7, 8), -np.inf)  # P_D = 1
    n_tr, n_tc = tile_grid_shape(16, *g.geometry.shape)
    ids = [(r, c) for r in range(n_tr) for c in range(n_tc)]
    payload = encode_tiles(state, ids, seq=3, t_s=1.5, tile_size=16, grid_hash=state.hash)
    assert payload == encode_tiles(state, ids, seq=3, t_s=1.5, tile_size=16)
    pd_whole = np.rint(state.pd * 65535.0).astype("<u2")
    for tile in decode_tiles(payload).tiles:
        r0, c0 = tile.tile_row * 16, tile.tile_col * 16
        np.testing.assert_array_equal(tile.pd_q, pd_whole[r0:r0 + 16, c0:c0 + 16])
