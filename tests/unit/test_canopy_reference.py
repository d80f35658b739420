"""R4, the forward ray caster through terrain and ground cover (tests/support/canopy_reference.py),
on scenes whose answers are worked out by hand: a 45 deg ray through one tree cell, straight
down through a uniform forest, a wall's shadow, a ridge's, and open flat ground, where its
cells' image areas are the projected quadrilaterals'."""

import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.domain import GridGeometry
from pdcov.core.ground_cover import CoverKind, GroundCover
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface
from tests.support.canopy_reference import CanopyReference, sub_pixel_rays
from tests.support.canopy_scene import smooth_detector

NADIR = np.diag([1.0, -1.0, -1.0])  # optical x east, y south, z down
CAMERA = CameraModel.from_fov(64, 48, 60.0)
DETECTOR = smooth_detector()
SQRT2 = math.sqrt(2.0)


def looking_at(r_cam_enu, target_enu) -> CameraPose:
    """A pose at ``r_cam_enu`` with the optical axis through ``target_enu``, image right
    level (not for straight down)."""
    z = np.subtract(target_enu, r_cam_enu, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return CameraPose(np.column_stack([x, np.cross(z, x), z]), r_cam_enu)


def scene(n=40, x0=-20.0, cover=None, z_corner=None, k=0.5) -> TerrainSurface:
    """n x n cells of 1 m from (x0, x0); ``cover``: (height_m, kind) arrays or None."""
    g = GridGeometry(x0, x0, 1.0, n, n)
    z = np.zeros((n + 1, n + 1)) if z_corner is None else z_corner
    gc = None if cover is None else GroundCover(g, cover[0], cover[1], k, "test")
    return TerrainSurface(g, z, "test", cover=gc)


def one_tree(height_m, row=25, col=25, n=40, x0=-20.0, kind=CoverKind.FOLIAGE):
    h = np.zeros((n, n))
    h[row, col] = height_m
    return h, np.where(h > 0, kind, CoverKind.OPEN)


def reference(terrain, camera=CAMERA, rays_per_side=2) -> CanopyReference:
    return CanopyReference(terrain, camera, DETECTOR, 500.0, rays_per_side)


def test_sub_pixel_rays_spread_evenly_over_each_pixel():
    rays, px = sub_pixel_rays(CAMERA, 2)
    assert rays.shape == (64 * 48 * 4, 3) and px.shape == (64 * 48 * 4, 2)
    # Pixel (0, 0) spans [-0.5, 0.5)^2: its rays go through (+-0.25, +-0.25).
    assert sorted(map(tuple, px[px.max(axis=1) < 0.5])) == [(-0.25, -0.25), (-0.25, 0.25),
                                                           (0.25, -0.25), (0.25, 0.25)]
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    np.testing.assert_allclose(CAMERA.project(rays), px, atol=1e-6)
    # Jittered: one point drawn in each quarter of each pixel.
    rays_j, px_j = sub_pixel_rays(CAMERA, 2, seed=3)
    assert (np.abs(px_j - px) <= 0.25).all() and np.abs(px_j - px).mean() > 0.1
    np.testing.assert_allclose(CAMERA.project(rays_j), px_j, atol=1e-6)


@pytest.mark.parametrize(("height_m", "x_from_m", "length_m"), [
    (2.0, 5.5, 0.5 * SQRT2),   # from the middle of the tree cell out through its east wall
    (5.0, 2.0, SQRT2),         # in through the west wall at 3 m, out through the east at 4 m
    (3.5, 2.0, 0.5 * SQRT2),   # in through the west wall at 3 m, out through the top at 5.5 m
    (2.5, 2.0, 0.0),           # over the top: at 3 m where it reaches the cell
])
def test_a_45_degree_ray_through_one_tree_cell(height_m, x_from_m, length_m):
    # The tree: cell [25, 25] (x, y in [5, 6]) on flat ground, k = 0.5 / m. The line of sight
    # rises eastwards at 45 deg from (x_from, 5.5, 0) to a camera 30 m along it.
    ref = reference(scene(cover=one_tree(height_m)))
    p = np.array([[x_from_m, 5.5, 0.0]])
    r_cam = p[0] + 30.0 * np.array([1.0, 0.0, 1.0]) / SQRT2
    t = ref.line_of_sight(p, r_cam)[0]
    # Midpoint sums over 5 cm steps: each wall or top crossed is off by at most half a step.
    assert -math.log(t) / 0.5 == pytest.approx(length_m, abs=0.05)
    if length_m == 0.0:
        assert t == 1.0


def test_straight_down_through_a_uniform_forest_t_is_exp_minus_k_h():
    # 15 m of trees over all of flat ground, k = 0.08 / m, a camera 50 m up: a ray that lands
    # at slant distance s crosses 15 s / 50 m of trees; under the camera exp(-1.2) = 0.301.
    n, h, k = 60, 15.0, 0.08
    ref = reference(scene(n=n, x0=-30.0, k=k,
                          cover=(np.full((n, n), h), np.full((n, n), CoverKind.FOLIAGE))))
    r_cam = np.array([0.2, 0.3, 50.0])
    look = ref.look(CameraPose(NADIR, r_cam))
    seen = look.observed
    assert seen.sum() > 1500
    # Each cell's mean over the rays that land in it (on z = 0, in closed form).
    d = ref.rays_cam @ NADIR.T
    s = 50.0 / -d[:, 2]
    row, col = np.floor(r_cam[1] + s * d[:, 1] + 30.0), np.floor(r_cam[0] + s * d[:, 0] + 30.0)
    flat = (row * n + col).astype(int)
    with np.errstate(invalid="ignore"):
        expected = (np.bincount(flat, np.exp(-k * h * s / 50.0), n * n)
                    / np.bincount(flat, minlength=n * n)).reshape(n, n)
    np.testing.assert_allclose(look.transmittance[seen], expected[seen], rtol=1e-9)
    assert look.transmittance[30, 30] == pytest.approx(math.exp(-k * h), rel=1e-3)
    p_det, _ = DETECTOR.lookup(np.sqrt(look.area_px2[seen]))
    np.testing.assert_allclose(look.pd[seen], p_det * look.transmittance[seen])


def test_a_wall_hides_a_person_in_its_shadow_and_under_itself():
    # A 10 m wall along x in [10, 11] on flat ground, a camera 15 m up at x = 0: the line of
    # sight to (X, y, 0) is at 15 (1 - 11 / X) m over the wall's east face, below its top
    # for X < 33. In front of the wall, and beyond its shadow, nothing is in the way.
    n = 60
    h = np.zeros((n, n))
    h[:, 30] = 10.0  # x0 = -20: column 30 is x in [10, 11]
    ref = reference(scene(n=n, cover=(h, np.where(h > 0, CoverKind.SOLID, CoverKind.OPEN))))
    r_cam = np.array([0.0, 0.5, 15.0])
    x = np.array([5.0, 9.9, 10.5, 11.5, 20.0, 32.5, 33.5, 38.0])
    p = np.column_stack([x, np.full_like(x, 0.5), np.zeros_like(x)])
    np.testing.assert_array_equal(ref.line_of_sight(p, r_cam), [1, 1, 0, 0, 0, 0, 1, 1])
    # A frame looking east: the cells of the wall and of its shadow are observed with P_D 0.
    look = ref.look(looking_at(r_cam, [16.0, 0.5, 0.0]))  # sees x from 6 m to 37 m
    row = 20  # y in [0, 1]
    seen = look.observed[row]
    cols_x = np.arange(n) - 20.0  # each cell's west edge
    shadow = (cols_x >= 10.0) & (cols_x + 1 <= 32.5)
    clear = (cols_x + 1 <= 10.0) | (cols_x >= 33.5)
    assert seen[shadow].sum() >= 20 and seen[clear].sum() >= 5
    assert (look.pd[row][shadow & seen] == 0).all()
    assert (look.transmittance[row][clear & seen] == 1.0).all()
    p_det, _ = DETECTOR.lookup(np.sqrt(look.area_px2[row][clear & seen]))
    np.testing.assert_allclose(look.pd[row][clear & seen], p_det)


def test_open_flat_ground_sees_everything_at_its_projected_area():
    # No cover (and cover all OPEN): every ray's transmittance is 1; a cell's image area,
    # rays x px^2 a ray, is the area of its corners' quadrilateral (a pinhole maps the
    # ground plane to the image by a homography: straight edges stay straight), up to the
    # rays' squares straddling its edges: at most sqrt 2 per ray spacing of its perimeter,
    # far fewer on average (one ray in a square, drawn at random in it).
    camera = CameraModel.from_fov(160, 120, 60.0)  # 11 px a metre 12 m away
    pose = looking_at(np.array([0.3, -12.0, 9.0]), [0.0, 2.0, 0.0])
    flat = scene()
    open_ = scene(cover=(np.zeros((40, 40)), np.zeros((40, 40), np.uint8)))
    looks = [reference(t, camera, rays_per_side=3).look(pose) for t in (flat, open_)]
    look = looks[0]
    np.testing.assert_array_equal(look.area_px2, looks[1].area_px2)
    seen = look.observed
    assert seen.sum() > 300
    assert (look.transmittance[seen] == 1.0).all() and not look.hidden.any()
    g = flat.geometry
    rows, cols = np.nonzero(seen)
    cx = g.x0_m + np.array([0, 1, 1, 0]) + cols[:, None]
    cy = g.y0_m + np.array([0, 0, 1, 1]) + rows[:, None]
    p_cam = (np.stack([cx, cy, np.zeros_like(cx)], axis=-1) - pose.r_cam_enu) @ pose.R_enu_cam
    q = camera.project(p_cam.reshape(-1, 3)).reshape(-1, 4, 2)
    whole = camera.in_picture(q).all(axis=1)
    x, y = q[..., 0], q[..., 1]
    quad = 0.5 * np.abs((x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y).sum(axis=1))
    perimeter = np.linalg.norm(q - np.roll(q, -1, axis=1), axis=2).sum(axis=1)
    area = look.area_px2[rows, cols]
    assert whole.sum() > 200
    err = np.abs(area - quad)[whole]
    assert (err <= SQRT2 * perimeter[whole] / 3 + 1.0).all()
    large = quad[whole] > 50.0
    assert large.sum() > 50 and np.median((err / quad[whole])[large]) < 0.01
    assert area[whole].sum() == pytest.approx(quad[whole].sum(), rel=2e-3)
    p_det, _ = DETECTOR.lookup(np.sqrt(area))
    np.testing.assert_allclose(look.pd[rows, cols], p_det)


def test_the_ground_is_met_where_the_algebra_says():
    # z = 0.5 x (a plane is its own bilinear surface): from (0, 0, 10) along (1, 0, -1) / sqrt 2
    # the ray is at 10 - s at x = s, meeting 0.5 s at s = 20 / 3.
    n = 40
    x = -20.0 + np.arange(n + 1)
    ref = reference(scene(z_corner=np.broadcast_to(0.5 * x, (n + 1, n + 1)).copy()))
    d = np.array([[1.0, 0.0, -1.0], [0.0, 0.6, -0.8]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t, on_ground = ref.ground_hit(np.array([0.0, 0.0, 10.0]), d)
    # Along y the plane stays at z = 0: 10 / 0.8.
    np.testing.assert_allclose(t, [20.0 / 3.0 * SQRT2, 12.5], atol=1e-5)
    assert on_ground.all()


def test_a_ridge_hides_the_ground_behind_it():
    # A 10 m ridge, flat-topped over x in [5, 7] (ramps from x = 4 and to x = 8), on level
    # ground; from (0, 0.5, 14) the line of sight to (X, y, 0) is at 14 (1 - 7 / X) m over
    # the ridge's east edge, below it for X < 24.5: those cells are hidden, none of their
    # ground seen.
    n = 60
    x = -20.0 + np.arange(n + 1)
    ridge = np.clip(10.0 * np.minimum(x - 4.0, 8.0 - x), 0.0, 10.0)
    ref = reference(scene(n=n, z_corner=np.broadcast_to(ridge, (n + 1, n + 1)).copy()))
    look = ref.look(looking_at(np.array([0.0, 0.5, 14.0]), [16.0, 0.5, 0.0]))
    row = 20
    west = np.arange(n) - 20.0
    behind = (west >= 8.0) & (west + 1 <= 24.0)
    assert look.in_view[row][behind].sum() >= 12
    assert look.hidden[row][behind & look.in_view[row]].all()
    assert (look.rays[row][behind] == 0).all() and not look.observed[row][behind].any()
    beyond = (west >= 25.0) & look.in_view[row]
    assert beyond.sum() >= 3 and look.observed[row][beyond].all()
