"""Coverage grid: hand-checkable geometry, the paper's recursion, merge, snapshots, and the
apparent cell areas cross-checked against per-pixel ray casting (the paper's Fig. 5)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from pdcov.core.camera import CameraModel
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.footprint import footprint_polygon, pixel_grid_rays, ray_count_map
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose
from tests.support.square_grid import DETECTOR, PINHOLE, pose, square_grid

FISHEYE = CameraModel.from_fov(640, 480, 150, "fisheye", (0.01, -0.005, 0.001, 0.0))


def sizes_map(grid, p):
    g = grid.geometry
    observed, size = grid.observe(p, (0, g.n_rows, 0, g.n_cols))
    out = np.full(g.shape, np.nan)
    out[observed] = size
    return out


def test_nadir_pinhole_footprint_is_the_analytic_rectangle():
    h = 10.0
    fp = footprint_polygon(PINHOLE, pose(xyz=(3.0, -2.0, h)), 1e6)
    half_w, half_h = h * 320 / 500, h * 240 / 500
    np.testing.assert_allclose(fp.bounds, (3 - half_w, -2 - half_h, 3 + half_w, -2 + half_h),
                               atol=1e-9)
    assert fp.area == pytest.approx(4 * half_w * half_h, rel=1e-9)


def test_nadir_cell_at_image_centre_has_side_f_c_over_h():
    grid = square_grid(cell_m=1.0)
    h = 10.0
    sizes = sizes_map(grid, pose(xyz=(0.5, 0.5, h)))  # camera above the centre of cell (40, 40)
    assert sizes[40, 40] == pytest.approx(500 * 1.0 / h, rel=1e-9)
    # Heading east: the image is turned but the centre cell looks just as large.
    sizes = sizes_map(grid, pose(yaw_deg=90, xyz=(0.5, 0.5, h)))
    assert sizes[40, 40] == pytest.approx(50.0, rel=1e-9)


def test_nadir_observed_cells_are_those_whose_centre_is_in_the_footprint():
    grid = square_grid()
    sizes = sizes_map(grid, pose(xyz=(0.5, 0.5, 10)))
    rows, cols = np.nonzero(np.isfinite(sizes))
    xs, ys = grid.geometry.centres_enu()
    # Footprint half-extents 6.4 m east-west, 4.8 m north-south around (0.5, 0.5).
    assert np.all(np.abs(xs[cols] - 0.5) < 6.4) and np.all(np.abs(ys[rows] - 0.5) < 4.8)
    assert len(rows) == 13 * 9  # centres at 0.5 + k: |k| <= 6 east-west, |k| <= 4 north-south


HIRES_PINHOLE = CameraModel(1920, 1440, np.array([[1500.0, 0, 959.5], [0, 1500.0, 719.5],
                                                   [0, 0, 1]]), "plumb_bob",
                            np.array([-0.05, 0.01, 0.0005, -0.0005, 0.0]))
HIRES_FISHEYE = CameraModel.from_fov(1920, 1440, 150, "fisheye", (0.01, -0.005, 0.001, 0.0))


def wholly_inside(grid, p):
    """Cells whose four corners all project inside the picture."""
    g = grid.geometry
    xs = g.x0_m + g.cell_size_m * np.arange(g.n_cols + 1)
    ys = g.y0_m + g.cell_size_m * np.arange(g.n_rows + 1)
    X, Y = np.meshgrid(xs, ys)
    p_cam = (np.stack([X, Y, 0 * X], -1).reshape(-1, 3) - p.r_cam_enu) @ p.R_enu_cam
    _, ok = grid.camera.visible(p_cam)
    ok = ok.reshape(X.shape)
    return ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]


@pytest.mark.parametrize("camera", [HIRES_PINHOLE, HIRES_FISHEYE], ids=["plumb_bob", "fisheye"])
@pytest.mark.parametrize("attitude", [(0, 0, 0), (8, -15, 30)], ids=["nadir", "tilted"])
def test_apparent_area_matches_per_pixel_ray_count(camera, attitude):
    # Cells near the axis are about 250 px a side; only cells of 50 px a side or more are
    # compared, where counting pixel centres is itself exact to about 1 %. (Fisheye: the
    # corner quadrilateral ignores the curvature of the cell's edges; from 3 m a 1 m cell
    # spans up to ~18 deg and the error stays ~1 %; it reaches 2.3 % from 2 m.)
    grid = square_grid(half_m=20, cell_m=1.0, camera=camera, max_range_m=1e6)
    p = pose(*attitude, xyz=(0.3, 0.2, 6.0 if camera is HIRES_PINHOLE else 3.0))
    area = sizes_map(grid, p) ** 2
    counts = ray_count_map(pixel_grid_rays(camera), p, grid.geometry)
    inside = wholly_inside(grid, p) & (counts >= 2500)
    assert inside.sum() >= 20
    rel = np.abs(area[inside] - counts[inside]) / counts[inside]
    assert rel.max() < 0.02, rel.max()
    # Cells partly in the picture: their clipped area, summed, matches the pixels they got.
    partial = np.isfinite(area) & ~inside
    assert area[partial].sum() == pytest.approx(counts[partial].sum(), rel=0.02)


def test_recursion_and_log_miss_forms_agree():
    grid = square_grid()
    poses = [pose(xyz=(x, 0.3 * x, 9 + 0.2 * x), yaw_deg=7 * x) for x in range(-6, 7)]
    g = grid.geometry
    p_rec = np.zeros(g.shape)
    for p in poses:
        sizes = sizes_map(grid, p)
        seen = np.isfinite(sizes)
        ps, _ = DETECTOR.lookup(np.where(seen, sizes, np.nan))
        p_rec = p_rec + (1 - p_rec) * np.where(seen, ps, 0.0)  # paper, section III-C
        grid.update(p)
    np.testing.assert_allclose(grid.pd, p_rec, atol=1e-6)
    assert p_rec.max() > 0.9  # many looks: the comparison is not trivial


def test_merge_is_commutative_and_equals_one_grid():
    poses = [pose(xyz=(x, -x, 10), yaw_deg=11 * x) for x in range(-8, 9)]
    a, b, ab, ba, one = (square_grid() for _ in range(5))
    for i, p in enumerate(poses):
        (a if i % 2 else b).update(p)
        one.update(p)
    ab.merge(a)
    ab.merge(b)
    ba.merge(b)
    ba.merge(a)
    np.testing.assert_array_equal(ab.log_miss_d, ba.log_miss_d)
    np.testing.assert_allclose(ab.pd, one.pd, atol=1e-6)
    np.testing.assert_array_equal(ab.n_obs, one.n_obs)
    assert ab.frames == one.frames == len(poses)


def test_fold_back_guard_never_marks_cells_beyond_the_field_of_view():
    cam = CameraModel(640, 480, PINHOLE.K, "plumb_bob", np.array([-0.2, 0.0, 0.0, 0.0, 0.0]))
    grid = square_grid(half_m=150, camera=cam, max_range_m=1e6)
    # Looking north, 45 deg below the horizon: the picture's top edge meets the ground ~85 m
    # away, and cells far beyond it (~63 deg off axis) fold back into the image.
    p = pose(xyz=(0, -140, 10), cam_pitch_deg=-45)
    seen = np.isfinite(sizes_map(grid, p))
    hit = ray_count_map(pixel_grid_rays(cam), p, grid.geometry) > 0
    assert seen.sum() > 500
    # Every observed cell is (next to) a cell that some pixel's ray really reaches.
    assert not (seen & ~ndimage.binary_dilation(hit, np.ones((3, 3)))).any()
    # Premise: without the guard, OpenCV would fold far cells into the picture.
    xs, ys = grid.geometry.centres_enu()
    X, Y = np.meshgrid(xs, ys)
    p_cam = (np.stack([X, Y, 0 * X], -1).reshape(-1, 3) - p.r_cam_enu) @ p.R_enu_cam
    front = p_cam[:, 2] > 0
    raw = np.zeros(len(p_cam), bool)
    raw[front] = cam.in_picture(cam.project(p_cam[front]))
    assert (raw.reshape(X.shape) & ~ndimage.binary_dilation(hit, np.ones((3, 3)))).sum() > 500


def test_camera_above_horizon_or_underground_sees_nothing():
    grid = square_grid()
    assert grid.update(pose(cam_pitch_deg=30)) == 0
    assert grid.update(pose(xyz=(0, 0, -1))) == 0
    assert grid.frames == 2 and grid.n_obs.sum() == 0


def test_max_range_limits_observation():
    near = square_grid(half_m=100, max_range_m=30.0)
    far = square_grid(half_m=100, max_range_m=1e6)
    p = pose(xyz=(0, -90, 10), cam_pitch_deg=-20)
    near.update(p)
    far.update(p)
    xs, ys = near.geometry.centres_enu()
    X, Y = np.meshgrid(xs, ys)
    dist = np.sqrt(X**2 + (Y + 90) ** 2 + 100)
    assert near.n_obs[dist > 30].sum() == 0
    assert far.n_obs[dist > 30].sum() > 0


def test_min_revisit_counts_one_look_per_interval():
    grid = square_grid(min_revisit_s=1.0)
    for k in range(10):  # 5 Hz hover for 2 s
        grid.update(pose(xyz=(0.5, 0.5, 10), t_s=0.2 * k))
    assert grid.n_obs[40, 40] == 2
    plain = square_grid()
    for k in range(10):
        plain.update(pose(xyz=(0.5, 0.5, 10), t_s=0.2 * k))
    assert plain.n_obs[40, 40] == 10


def test_min_revisit_without_frame_time_raises_before_counting_the_frame():
    grid = square_grid(min_revisit_s=1.0)
    with pytest.raises(ValueError, match="frame times"):
        grid.update(pose(xyz=(0.5, 0.5, 10)))
    assert grid.frames == 0 and grid.n_obs.sum() == 0


def test_obstacle_cells_are_never_updated():
    dom = Domain.from_enu([[-20, -20], [20, -20], [20, 20], [-20, 20]],
                          [[[-2, -2], [2, -2], [2, 2], [-2, 2]]])
    g = dom.grid_geometry(1.0)
    grid = CoverageGrid(g, dom.free_mask(g), PINHOLE, DETECTOR)
    grid.update(pose())
    assert grid.n_obs[18:22, 18:22].sum() == 0 and grid.n_obs.sum() > 50


def test_snapshot_round_trip(tmp_path):
    grid = square_grid()
    for x in range(5):
        grid.update(pose(xyz=(x, 0, 10)))
    path = tmp_path / "grid.npz"
    grid.save_npz(path)
    assert [p.name for p in tmp_path.iterdir()] == ["grid.npz"]
    again = CoverageGrid.load_npz(path, PINHOLE, DETECTOR)
    np.testing.assert_array_equal(again.log_miss_d, grid.log_miss_d)
    np.testing.assert_array_equal(again.n_obs, grid.n_obs)
    assert again.geometry == grid.geometry and again.frames == 5
    with np.load(path) as z:
        np.testing.assert_allclose(z["pd"], grid.pd)
        assert float(z["x0_m"]) == -40 and float(z["cell_size_m"]) == 1.0


def test_snapshot_of_another_version_or_inconsistent_shapes_is_refused(tmp_path):
    from pdcov.errors import InputFileError

    grid = square_grid(half_m=5)
    grid.save_npz(tmp_path / "grid.npz")
    with np.load(tmp_path / "grid.npz") as z:
        data = dict(z)
    np.savez(tmp_path / "v9.npz", **(data | {"version": 9}))
    with pytest.raises(InputFileError, match="v9.npz.*version 9, expected 1 or 2"):
        CoverageGrid.load_npz(tmp_path / "v9.npz", PINHOLE, DETECTOR)
    np.savez(tmp_path / "cut.npz", **(data | {"n_obs": data["n_obs"][:3]}))
    with pytest.raises(InputFileError, match="cut.npz: n_obs has shape"):
        CoverageGrid.load_npz(tmp_path / "cut.npz", PINHOLE, DETECTOR)


def test_snapshot_keeps_the_revisit_clock(tmp_path):
    grid = square_grid(min_revisit_s=1.0)
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=0.0))
    grid.save_npz(tmp_path / "g.npz")
    again = CoverageGrid.load_npz(tmp_path / "g.npz", PINHOLE, DETECTOR, min_revisit_s=1.0)
    again.update(pose(xyz=(0.5, 0.5, 10), t_s=0.5))  # within 1 s of the saved look
    assert again.n_obs[40, 40] == 1
    again.update(pose(xyz=(0.5, 0.5, 10), t_s=1.2))
    assert again.n_obs[40, 40] == 2


def test_metrics():
    grid = square_grid(half_m=10)
    for _ in range(3):
        grid.update(pose(xyz=(0, 0, 10)))
    m = grid.metrics([0.5, 0.8])
    pd = grid.pd
    assert m.cells_free == 400 and m.frames == 3
    assert m.cells_observed == int((grid.n_obs > 0).sum())
    assert m.proportion_at_or_above[0.5] == pytest.approx((pd >= 0.5).mean())
    assert m.mean_pd == pytest.approx(pd.mean())
    assert m.expected_false_alarms == pytest.approx(grid.pfa.sum(), rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(2, 40),
                          st.floats(-30, 30), st.floats(-30, 30), st.floats(-180, 180),
                          st.floats(-120, -20)), min_size=1, max_size=6))
def test_probabilities_stay_in_range_and_never_decrease(frames):
    grid = square_grid(half_m=30)
    before = grid.pd
    for x, y, z, roll, pitch, yaw, cam_pitch in frames:
        grid.update(pose(roll, pitch, yaw, (x, y, z), cam_pitch))
        pd, pfa = grid.pd, grid.pfa
        assert np.all((pd >= 0) & (pd <= 1) & (pfa >= 0) & (pfa <= 1))
        assert np.all(pd >= before)
        before = pd


def test_merge_rejects_other_geometry():
    with pytest.raises(ValueError):
        square_grid(half_m=10).merge(square_grid(half_m=11))


def test_grid_geometry_validation():
    from pdcov.errors import DomainError
    with pytest.raises(DomainError):
        GridGeometry(0, 0, -1, 3, 3)
    with pytest.raises(ValueError):
        CameraPose(np.eye(3) * 2, (0, 0, 1))


def test_last_look_holds_the_frame_s_per_look_evidence_at_nadir():
    # f = 500 px at 10 m: the cell under the camera is 50 px on a side (bin [40, 80), padded
    # index 3: P_D 0.6) and 2500 px^2 (80 false boxes per Mpx: -rate A = -0.2).
    grid = square_grid(min_revisit_s=1.0)
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=0.0))
    look = grid.last_look
    assert look is not None and look.t_s == 0.0
    rows, cols = np.array([40, 40, 0]), np.array([40, 39, 0])  # centre, its west, a far corner
    counted, in_view, index, log_fa = look.look_at(rows, cols)
    assert counted.tolist() == [True, True, False] and in_view.tolist() == [True, True, False]
    assert index[0] == 3 and index[2] == 0
    assert look.log_miss_d(rows, cols, index)[0] == pytest.approx(math.log(0.4), rel=1e-6)
    assert log_fa[0] == pytest.approx(-80e-6 * 2500, rel=1e-6) and log_fa[2] == 0.0
    assert grid.n_obs[40, 40] == 1 and grid.log_miss_d[40, 40] == pytest.approx(math.log(0.4))
    # 0.2 s later: in view, but not a look on the revisit clock; its size bin is kept.
    grid.update(pose(xyz=(0.5, 0.5, 10), t_s=0.2))
    counted, in_view, index, log_fa = grid.last_look.look_at(rows[:1], cols[:1])
    assert (counted[0], in_view[0], index[0]) == (False, True, 3)
    assert log_fa[0] == pytest.approx(-0.2, rel=1e-6) and grid.n_obs[40, 40] == 1
    # A frame that sees no cell leaves no look.
    grid.update(pose(xyz=(0.5, 0.5, 10), cam_pitch_deg=90.0, t_s=2.0))
    assert grid.last_look is None
