"""The coverage kernel on terrain: closed-form pixel sizes on a tilted plane, the exact shadow
of a wall, faces turned away, the limiting factor per cell, and the horizon test against a
brute-force line-of-sight march."""

import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.limiting import LimitingFactor
from pdcov.core.occlusion import hidden_by_terrain
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.core.terrain import TerrainSurface

DEG = math.pi / 180
F_PX = 500.0
PINHOLE = CameraModel(640, 480, np.array([[F_PX, 0, 319.5], [0, F_PX, 239.5], [0, 0, 1]]))
WIDE = CameraModel.from_fov(1920, 1080, 100)
DETECTOR = DetectorModel.from_dict({"version": 4, "bin_edges_px": [1, 20, 40, 80, 2000],
                                    "p_detect": [0.1, 0.4, 0.6, 0.3],
                                    "p_false_alarm": [0.05, 0.1, 0.2, 0.3],
                                    "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],
                                    "input_size_px": None})
DOMAIN = Domain.from_enu([[-40, -40], [40, -40], [40, 40], [-40, 40]])
GEOMETRY = DOMAIN.grid_geometry(1.0)
X_CORNER, Y_CORNER = np.meshgrid(GEOMETRY.x0_m + np.arange(GEOMETRY.n_cols + 1),
                                 GEOMETRY.y0_m + np.arange(GEOMETRY.n_rows + 1))


def grid_on(z_corner_m=None, camera=PINHOLE, **kw):
    terrain = None if z_corner_m is None else TerrainSurface(GEOMETRY, z_corner_m)
    return CoverageGrid(GEOMETRY, DOMAIN.free_mask(GEOMETRY), camera, DETECTOR,
                        terrain=terrain, **kw)


def pose(xyz, cam_pitch_deg=-90.0, yaw_deg=0.0):
    return fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, yaw_deg * DEG), xyz,
                            FixedMount(pitch_rad=cam_pitch_deg * DEG))


def cell(x_m, y_m):
    row, col = GEOMETRY.cell_of(x_m, y_m)
    return int(row), int(col)


def size_at(grid, p, x_m, y_m):
    observed, size = grid.observe(p, (0, GEOMETRY.n_rows, 0, GEOMETRY.n_cols))
    full = np.full(GEOMETRY.shape, np.nan)
    full[observed] = size
    return full[cell(x_m, y_m)]


def test_level_terrain_is_the_flat_grid_raised():
    """Ground at z = 5 m seen from 5 m higher is the flat ground seen from the original
    height: the same cells, looks and probabilities."""
    flat = grid_on()
    level = grid_on(np.full(X_CORNER.shape, 5.0))
    for k in range(12):
        xyz = (k * 1.7 - 10.0, 3.0, 12.0)
        flat.update(pose(xyz, -60.0, 90.0 + 9 * k))
        level.update(pose((xyz[0], xyz[1], xyz[2] + 5.0), -60.0, 90.0 + 9 * k))
    assert flat.n_obs.sum() > 1000
    np.testing.assert_array_equal(level.n_obs, flat.n_obs)
    np.testing.assert_allclose(level.pd, flat.pd, atol=1e-12)
    np.testing.assert_array_equal(level.limiting, flat.limiting)


def test_zero_terrain_takes_the_flat_path_bit_for_bit():
    flat, zero = grid_on(), grid_on(np.zeros(X_CORNER.shape))
    for k in range(5):
        p = pose((k - 2.0, 1.0, 15.0), -70.0, 30.0 * k)
        flat.update(p)
        zero.update(p)
    np.testing.assert_array_equal(zero.log_miss_d, flat.log_miss_d)
    np.testing.assert_array_equal(zero.log_miss_fa, flat.log_miss_fa)


@pytest.mark.parametrize("slope", [0.3, -0.4])
def test_tilted_plane_cell_size_is_the_trapezoid_by_hand(slope):
    """Nadir pinhole camera at height h over the plane z = s x. The cell [x0 - c/2, x0 +
    c/2] x [-c/2, c/2] has its vertical edges at depth h - s x, each imaged as a segment
    f c / (h - s x) long at u = f x / (h - s x): its image is a trapezoid of area
    (u+ - u-) (L+ + L-) / 2."""
    h, c, x0 = 10.0, 1.0, 2.5
    grid = grid_on(slope * X_CORNER)
    x_lo, x_hi = x0 - c / 2, x0 + c / 2
    u_lo, u_hi = F_PX * x_lo / (h - slope * x_lo), F_PX * x_hi / (h - slope * x_hi)
    l_lo, l_hi = F_PX * c / (h - slope * x_lo), F_PX * c / (h - slope * x_hi)
    expected = math.sqrt(abs(u_hi - u_lo) * (l_lo + l_hi) / 2)
    p = pose((0.0, 0.5, h))
    assert size_at(grid, p, x0, 0.5) == pytest.approx(expected, rel=1e-9)
    # The flat-earth kernel would give f c / h = 50 px: the test tells them apart.
    assert abs(expected - F_PX * c / h) > 1.0


def test_wall_casts_its_shadow_exactly():
    """A wall 6 m high on x in [10, 12] (sloping to the ground over one cell each side), the
    camera 12 m high at x = 0 looking east: the top's far edge (x = 12, 6 m) hides the ground
    out to x = 12 * 12 / (12 - 6) = 24 m, and the wall's far side faces away."""
    z = np.where((X_CORNER >= 10) & (X_CORNER <= 12), 6.0, 0.0)
    grid = grid_on(z, camera=WIDE, max_range_m=200.0)
    grid.update(pose((0.0, 0.0, 12.0), -25.0, 90.0))
    row = cell(0.0, 0.5)[0]
    x_centre = GEOMETRY.x0_m + np.arange(GEOMETRY.n_cols) + 0.5
    code = dict(zip(x_centre, grid.limiting[row], strict=True))
    assert all(code[x] == LimitingFactor.SEEN for x in (9.5, 10.5, 11.5))  # the near side, top
    assert all(code[x] == LimitingFactor.HIDDEN for x in np.arange(12.5, 24.0))
    assert all(code[x] == LimitingFactor.SEEN for x in np.arange(24.5, 40.0))
    hidden = grid.limiting == LimitingFactor.HIDDEN
    assert not grid.n_obs[hidden].any() and not (grid.pd[hidden] > 0).any()


def test_slope_turned_away_from_the_camera_is_hidden():
    """Ground rising 2 m per metre towards the camera, beyond x = 5: seen from x = 0 at
    3 m, the slope is the back of a hill: every cell on it is hidden, those before it seen."""
    z = np.clip(40.0 - 2.0 * X_CORNER, 0.0, 30.0)
    z[X_CORNER < 5] = 0.0
    grid = grid_on(z, camera=WIDE, max_range_m=200.0)
    grid.update(pose((0.0, 0.0, 40.0), -30.0, 90.0))
    row = cell(0.0, 0.5)[0]
    col = cell(16.5, 0.5)[1]  # on the slope (z from 8 to 6)
    assert grid.limiting[row, col] == LimitingFactor.HIDDEN


def test_limiting_factors_on_flat_ground_and_their_merge():
    far = grid_on(max_range_m=12.0)
    far.update(pose((0.0, 0.0, 10.0), -45.0, 90.0))  # looking east, range 12 m
    near_ok = far.limiting[cell(5.5, 0.5)]  # in view from x = 3.5 m, in range to 6.6 m
    assert near_ok == LimitingFactor.SEEN
    assert far.limiting[cell(20.5, 0.5)] == LimitingFactor.TOO_FAR
    assert far.limiting[cell(-30.5, 0.5)] == LimitingFactor.NEVER_IN_VIEW
    small = grid_on()
    small.update(pose((0.0, 0.0, 600.0)))  # 1 m cells 0.83 px: below the first edge, 1 px
    assert small.limiting[cell(0.5, 0.5)] == LimitingFactor.TOO_SMALL
    far.merge(small)
    assert far.limiting[cell(20.5, 0.5)] == LimitingFactor.TOO_SMALL  # the better of the two
    counts = far.metrics([0.5]).limiting_cells
    assert sum(counts.values()) == int(DOMAIN.free_mask(GEOMETRY).sum())
    assert counts["too_far"] == int((far.limiting == LimitingFactor.TOO_FAR).sum())


def test_too_far_marks_every_cell_in_view_beyond_the_range_whatever_was_marked_before():
    """A wide camera looking out past its 12 m range, three frames: after each, the cells
    outside the frame's own window are the earlier codes raised to TOO_FAR exactly where a
    free cell's centre, in the window out to twice the range, is in the picture and further
    than the range (the rule judged per cell here, by projecting each centre)."""
    grid = grid_on(camera=WIDE, max_range_m=12.0)
    xs, ys = GEOMETRY.centres_enu()
    X, Y = np.meshgrid(xs, ys)
    for xyz, pitch, yaw in [((0.0, 0.0, 8.0), -30.0, 90.0), ((5.0, -3.0, 8.0), -30.0, 60.0),
                            ((-6.0, 4.0, 8.0), -25.0, 200.0)]:
        p = pose(xyz, pitch, yaw)
        expected = grid.limiting.copy()
        (r0, r1, c0, c1), _ = grid._view.window(grid._base, p, 24.0)
        p_cam = (np.stack([X, Y, np.zeros_like(X)], axis=-1) - p.r_cam_enu) @ p.R_enu_cam
        sl = (slice(r0, r1), slice(c0, c1))
        pc = p_cam[sl].reshape(-1, 3)
        ahead = pc[:, 2] > 0
        seen = np.zeros(len(pc), dtype=bool)
        seen[ahead] = (WIDE.in_picture(WIDE.project(pc[ahead]))
                       & WIDE.in_fov_xyz(*pc[ahead].T))
        far = np.linalg.norm(pc, axis=1) > 12.0
        mark = (seen & far).reshape(r1 - r0, c1 - c0) & grid.mask[sl]
        expected[sl] = np.maximum(expected[sl], mark * np.uint8(LimitingFactor.TOO_FAR))
        grid.update(p)
        outside = np.ones(grid.mask.shape, dtype=bool)
        w0, w1, v0, v1 = grid.touched
        outside[w0:w1, v0:v1] = False
        assert (expected == LimitingFactor.TOO_FAR).sum() > 100
        np.testing.assert_array_equal(grid.limiting[outside], expected[outside])


def test_snapshot_keeps_the_limiting_factor(tmp_path):
    grid = grid_on(np.where(X_CORNER > 10, 4.0, 0.0), camera=WIDE)
    grid.update(pose((0.0, 0.0, 12.0), -30.0, 90.0))
    grid.save_npz(tmp_path / "g.npz")
    back = CoverageGrid.load_npz(tmp_path / "g.npz", WIDE, DETECTOR)
    np.testing.assert_array_equal(back.limiting, grid.limiting)
    # A snapshot written before limiting factors: what its sums and counts tell.
    with np.load(tmp_path / "g.npz") as data:
        old = {k: data[k] for k in data.files if k != "limiting"}
    np.savez(tmp_path / "old.npz", **old)
    back = CoverageGrid.load_npz(tmp_path / "old.npz", WIDE, DETECTOR)
    seen = grid.limiting == LimitingFactor.SEEN
    assert (back.limiting[seen] == LimitingFactor.SEEN).all()
    assert (back.limiting[grid.n_obs == 0] == LimitingFactor.NEVER_IN_VIEW).all()


def _hills(seed):
    rng = np.random.default_rng(seed)
    z = np.zeros(X_CORNER.shape)
    for _ in range(6):
        cx, cy = rng.uniform(-35, 35, 2)
        z += rng.uniform(4, 14) * np.exp(-((X_CORNER - cx) ** 2 + (Y_CORNER - cy) ** 2)
                                          / (2 * rng.uniform(3, 9) ** 2))
    return TerrainSurface(GEOMETRY, z)


def _brute_force_hidden(terrain, r_cam, x, y, z, step_m=0.02, skip_m=0.5, depth_m=0.02):
    """March every line of sight in 2 cm steps; hidden where the bilinear terrain rises more
    than 2 cm above it before the last half metre of ground distance (a line of sight that
    grazes the terrain closer than that is neither)."""
    out = np.zeros(len(x), dtype=bool)
    for k in range(len(x)):
        d = np.array([x[k], y[k], z[k]]) - r_cam
        ground = math.hypot(d[0], d[1])
        if ground <= skip_m:
            continue
        t = np.arange(step_m, ground - skip_m, step_m) / ground
        p = r_cam + t[:, None] * d
        out[k] = bool((terrain.height_m(p[:, 0], p[:, 1]) > p[:, 2] + depth_m).any())
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_horizon_agrees_with_a_brute_force_line_of_sight_march(seed):
    """Over random hills, the horizon test hides every target a 2 cm line-of-sight march
    finds hidden, and agrees with it on at least 97 % of targets (it errs towards hiding
    where the terrain passes within a bin of the line of sight)."""
    terrain = _hills(seed)
    rng = np.random.default_rng(seed + 10)
    r_cam = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), 0.0])
    r_cam[2] = float(terrain.height_m(r_cam[0], r_cam[1])) + rng.uniform(8, 20)
    x = rng.uniform(-39, 39, 600)
    y = rng.uniform(-39, 39, 600)
    z = terrain.height_m(x, y)
    ours = hidden_by_terrain(terrain, r_cam, x, y, z)
    truth = _brute_force_hidden(terrain, r_cam, x, y, z)
    assert truth.sum() > 20  # the hills hide something
    assert not (truth & ~ours).any(), "a target the march finds hidden counted as visible"
    assert (ours == truth).mean() >= 0.97


def test_cells_seen_through_the_window_equal_those_of_the_whole_grid():
    """The window (footprints on the lowest and highest terrain planes) never cuts off an
    observed cell: update over its window observes what observing the whole grid does."""
    terrain = _hills(4)
    for k, p in enumerate([pose((0.0, -10.0, 35.0), -50.0, 20.0),
                           pose((-20.0, 5.0, 25.0), -90.0, 0.0),
                           pose((10.0, 10.0, 18.0), -20.0, 200.0)]):
        grid = CoverageGrid(GEOMETRY, DOMAIN.free_mask(GEOMETRY), WIDE, DETECTOR,
                            terrain=terrain, max_range_m=60.0)
        observed, _ = grid.observe(p, (0, GEOMETRY.n_rows, 0, GEOMETRY.n_cols))
        grid.update(p)
        assert observed.sum() > 50, k
        np.testing.assert_array_equal(grid.n_obs > 0, observed)


def test_live_footprint_lies_on_the_terrain_under_the_view():
    """The footprint the daemon publishes: over ground 20 m up, a camera 30 m up sees the
    ring a camera 10 m above flat ground sees."""
    from types import SimpleNamespace

    from pdcov.core.geodesy import Origin
    from pdcov.service.status import footprint_lonlat

    origin = Origin(46.0, 7.0, 500.0)
    raised = grid_on(np.full(X_CORNER.shape, 20.0))
    ring_up = footprint_lonlat(SimpleNamespace(
        last_pose=pose((1.0, 2.0, 30.0), -60.0, 40.0), origin=origin, grid=raised))
    ring_flat = footprint_lonlat(SimpleNamespace(
        last_pose=pose((1.0, 2.0, 10.0), -60.0, 40.0), origin=origin, grid=grid_on()))
    assert ring_up is not None and ring_flat is not None
    np.testing.assert_allclose(ring_up, ring_flat, atol=1e-8)  # degrees: ~1 mm
