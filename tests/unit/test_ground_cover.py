"""What stands on the ground (core/ground_cover.py): transmittances a person can check by
hand, and what the coverage grid makes of them (P_D x transmittance, CANOPY, BUILDING)."""

import math

import numpy as np
import pytest

from pdcov.core.domain import GridGeometry
from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import (
    RAYS_PER_SIDE,
    CoverKind,
    GroundCover,
    cell_transmittance,
    transmittance,
)
from pdcov.core.limiting import LimitingFactor
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.core.terrain import TerrainSurface
from tests.support.square_grid import pose as camera_pose
from tests.support.square_grid import square_grid

K = 0.08  # 1/m
GEOMETRY = GridGeometry(0.0, 0.0, 1.0, 200, 200)
FOREST = (slice(50, 150), slice(50, 150))  # rows, cols: 20 m of trees
HOUSE = (slice(20, 30), slice(20, 30))     # a 10 m house


def scene(ramp: float = 0.0) -> TerrainSurface:
    """The 200 m square: the forest and the house on flat ground (or a ramp z = ramp x)."""
    h = np.zeros(GEOMETRY.shape)
    kind = np.zeros(GEOMETRY.shape, np.uint8)
    h[FOREST], kind[FOREST] = 20.0, CoverKind.FOLIAGE
    h[HOUSE], kind[HOUSE] = 10.0, CoverKind.SOLID
    x = np.arange(GEOMETRY.n_cols + 1, dtype=float)
    z = np.broadcast_to(ramp * x, (GEOMETRY.n_rows + 1, GEOMETRY.n_cols + 1))
    return TerrainSurface(GEOMETRY, z, "test", cover=GroundCover(GEOMETRY, h, kind, K))


def t_of(terrain: TerrainSurface, r_cam, xy) -> np.ndarray:
    xy = np.asarray(xy, dtype=float)
    assert terrain.cover is not None and terrain.cover_tops is not None
    return transmittance(terrain.cover, terrain.cover_tops, terrain.max_slope,
                         np.asarray(r_cam, float), xy[:, 0], xy[:, 1],
                         terrain.height_m(xy[:, 0], xy[:, 1]))


def test_straight_down_through_the_trees_is_exp_minus_k_h():
    t = t_of(scene(), [100.5, 100.5, 100.0], [[100.5, 100.5], [100.2, 100.7]])
    assert t == pytest.approx(math.exp(-K * 20.0), rel=1e-3)


def test_oblique_rays_through_the_forest_edge_by_hand():
    # Camera 100 m west of the point and 100 m up: 45 deg. From x = 160 (east of the trees,
    # which end at x = 150) the ray enters them at 10 m up and leaves at 20 m: 10 m
    # horizontally, 10 sqrt(2) m of foliage.
    t = t_of(scene(), [60.0, 100.0, 100.0], [[160.0, 100.0]])
    assert t[0] == pytest.approx(math.exp(-K * 10 * math.sqrt(2)), rel=1e-6)
    # From inside the forest at x = 140: the camera 80 m away, tan e = 1.25: 16 m
    # horizontally to the tree tops, 16 sqrt(1 + 1.25^2) m of foliage.
    t = t_of(scene(), [60.0, 100.0, 100.0], [[140.0, 100.0]])
    assert t[0] == pytest.approx(math.exp(-K * 16 * math.hypot(1, 1.25)), rel=1e-6)
    # A diagonal ray: from (160, 100) to the camera at (60, 70, 100): tan e = 100 / 104.4;
    # it enters the trees at x = 150 (10.44 m along) and leaves at 20 m up (20.88 m).
    rho = math.hypot(100, 30)
    t = t_of(scene(), [60.0, 70.0, 100.0], [[160.0, 100.0]])
    inside = (20 * rho / 100 - 10 * rho / 100) * math.hypot(1, 100 / rho)
    assert t[0] == pytest.approx(math.exp(-K * inside), rel=1e-6)


def test_a_house_blocks_the_rays_that_pass_below_its_roof_and_none_above():
    # Camera west of the house (x 20..30) at 30 m: the ray from x = 32 passes it at 1.9 to
    # 11.3 m up (below the 10 m roof: blocked), the one from x = 60 at 15 to 20 m (above).
    t = t_of(scene(), [0.0, 25.0, 30.0], [[32.0, 25.0], [60.0, 25.0]])
    assert t.tolist() == [0.0, 1.0]
    # Under the roof nothing is seen, from straight above or from the side.
    for cam in ([25.0, 25.0, 100.0], [-50.0, 60.0, 40.0]):
        assert t_of(scene(), cam, [[25.5, 25.5], [21.0, 29.0]]).tolist() == [0.0, 0.0]


def test_open_ground_far_from_anything_is_not_attenuated():
    t = t_of(scene(), [180.0, 20.0, 60.0], [[180.0, 20.0], [170.0, 40.0]])
    assert t.tolist() == [1.0, 1.0]


def test_on_a_slope_the_trees_stand_on_their_own_ground():
    # z = 0.1 x: a cell's trees reach 20 m above its centre; straight down from above a
    # centre, 20 m of foliage wherever the forest is.
    terrain = scene(ramp=0.1)
    for x in (60.5, 140.5):
        z = float(terrain.height_m(np.array(x), np.array(100.5)))
        t = t_of(terrain, [x, 100.5, z + 100.0], [[x, 100.5]])
        assert t[0] == pytest.approx(math.exp(-K * 20.0), rel=1e-3)


def test_a_cell_is_the_mean_of_its_rays_at_edges_and_its_first_ray_inside():
    terrain = scene()
    cover, tops = terrain.cover, terrain.cover_tops
    assert cover is not None and tops is not None
    cam = np.array([60.0, 70.0, 100.0])
    rows, cols = np.array([100, 100]), np.array([149, 120])  # at the edge; deep inside
    got = cell_transmittance(cover, tops, 0.0, None, cam, rows, cols)
    n = RAYS_PER_SIDE
    f = (np.arange(n) + 0.5) / n
    xy = np.array([[149 + a, 100 + b] for b in f for a in f])
    assert got[0] == pytest.approx(t_of(terrain, cam, xy).mean(), rel=1e-12)
    assert got[1] == pytest.approx(t_of(terrain, cam, [[120 + f[0], 100 + f[0]]])[0],
                                   rel=1e-12)


def test_cover_is_validated_and_open_cells_have_no_height():
    g = GridGeometry(0.0, 0.0, 1.0, 2, 2)
    with pytest.raises(ValueError, match="shape"):
        GroundCover(g, np.zeros((3, 2)), np.zeros((2, 2), np.uint8))
    with pytest.raises(ValueError, match=">= 0"):
        GroundCover(g, -np.ones((2, 2)), np.zeros((2, 2), np.uint8))
    with pytest.raises(ValueError, match="CoverKind"):
        GroundCover(g, np.ones((2, 2)), np.full((2, 2), 9, np.uint8))
    c = GroundCover(g, np.array([[5.0, 0.0], [3.0, 2.0]]),
                    np.array([[0, 1], [2, 1]], np.uint8))
    assert c.height_m.tolist() == [[0.0, 0.0], [3.0, 2.0]]
    assert c.kind.tolist() == [[0, 0], [2, 1]]


def covered_grid(**kw) -> tuple[CoverageGrid, np.ndarray]:
    """The test square (80 m, 1 m cells) with trees (14 m) over x > 0 and a 6 m house at
    x in [-30, -20), y in [-25, -15): the grid over it, and the kind per cell."""
    flat = square_grid()
    g = flat.geometry
    h = np.zeros(g.shape)
    kind = np.zeros(g.shape, np.uint8)
    h[:, 40:], kind[:, 40:] = 14.0, CoverKind.FOLIAGE
    h[15:25, 10:20], kind[15:25, 10:20] = 6.0, CoverKind.SOLID
    terrain = TerrainSurface(g, np.zeros((g.n_rows + 1, g.n_cols + 1)), "test",
                             cover=GroundCover(g, h, kind, K))
    return square_grid(terrain=terrain, **kw), kind


def test_the_grid_scales_each_look_by_the_transmittance():
    grid, kind = covered_grid()
    flat = square_grid()
    p = camera_pose(xyz=(0.0, 0.0, 60.0))
    grid.update(p)
    flat.update(p)
    terrain = grid.terrain
    assert terrain is not None and terrain.cover is not None and terrain.cover_tops is not None
    seen = flat.n_obs > 0
    rows, cols = np.nonzero(seen & (kind == CoverKind.FOLIAGE))
    t = cell_transmittance(terrain.cover, terrain.cover_tops, 0.0, None, p.r_cam_enu, rows,
                           cols)
    assert 0.2 < t.min() and t.max() < 0.45  # about exp(-0.08 x 14) = 0.33
    assert grid.pd[rows, cols] == pytest.approx(flat.pd[rows, cols] * t, rel=1e-5)
    assert (grid.limiting[rows, cols] == LimitingFactor.CANOPY).all()
    # Open cells away from the trees and the house: as without them.
    open_far = seen & (kind == CoverKind.OPEN)
    open_far[:, 30:] = False
    open_far[10:30, 5:25] = False
    assert np.array_equal(grid.pd[open_far], flat.pd[open_far])
    # Under the roof: in view, never seen.
    roof = kind == CoverKind.SOLID
    assert (flat.n_obs[roof] > 0).all()
    assert not grid.pd[roof].any() and not grid.n_obs[roof].any()
    assert (grid.limiting[roof] == LimitingFactor.BUILDING).all()
    # The candidates' look of the same cells: P_D x transmittance too.
    look = grid.last_look
    assert look is not None
    _, _, index, _ = look.look_at(rows, cols)
    assert look.log_miss_d(rows, cols, index) == pytest.approx(
        np.log1p(-grid.pd[rows, cols]), rel=1e-5)


def test_nothing_standing_on_the_ground_leaves_the_grid_as_it_was():
    g = square_grid().geometry
    bare = TerrainSurface(g, np.zeros((g.n_rows + 1, g.n_cols + 1)), "test",
                          cover=GroundCover(g, np.zeros(g.shape), np.zeros(g.shape, np.uint8)))
    grid, flat = square_grid(terrain=bare), square_grid()
    for p in (camera_pose(xyz=(0.0, 0.0, 40.0)), camera_pose(pitch_deg=30.0,
                                                              xyz=(5.0, 0.0, 30.0))):
        grid.update(p)
        flat.update(p)
    for layer in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        assert np.array_equal(getattr(grid, layer), getattr(flat, layer)), layer


def test_viewpoint_looks_are_refused_with_cover():
    with pytest.raises(ValueError, match="only with independent looks"):
        covered_grid(looks=LooksConfig(LooksRule.VIEWPOINT))


def test_an_oblique_view_under_the_canopys_edge_sees_more_than_straight_down():
    # 2 m inside the forest's east edge (x = 150): straight down through 20 m of trees;
    # from 40 m east of the edge at 20 m up, the ray leaves the trees through their side
    # after 2 m, 1 m up: about 2.2 m of foliage. The planners score candidate views with
    # this rule (they update grids over mission.terrain), so such views win where they help.
    terrain = scene()
    point = [[148.0, 100.5]]
    down = t_of(terrain, [148.0, 100.5, 60.0], point)[0]
    side = t_of(terrain, [190.0, 100.5, 20.0], point)[0]
    tan_e = 20.0 / 42.0
    assert down == pytest.approx(math.exp(-K * 20.0), rel=1e-6)
    assert side == pytest.approx(math.exp(-K * 2.0 * math.hypot(1, tan_e)), rel=1e-6)
    assert side > 3 * down


def test_a_ray_down_to_a_camera_below_the_point_is_followed_through_the_trees():
    # A camera 8 m below the person's ground and 20 m west: the line of sight descends,
    # below the forest's 20 m tops all the way to its edge (x = 50), never above them.
    terrain = scene()
    t = t_of(terrain, [40.0, 100.5, -8.0], [[60.0, 100.5]])
    # Horizontal path through the trees: from x = 60 to 50, 10 m, 3-D 10 x sqrt(1 + 0.4^2).
    assert t[0] == pytest.approx(math.exp(-K * 10.0 * math.hypot(1, 8.0 / 20.0)), rel=1e-6)
