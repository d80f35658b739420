"""Motion blur (core/blur.py) and the grid's lookup by size and blur: hand-checkable cases,
OpenCV's projection Jacobian as an independent oracle, and 'no blur' equal to today's grid."""

import math

import cv2
import numpy as np
import pytest

from pdcov.core.blur import (
    BlurEffect,
    blur_lattice_px,
    blur_px,
    blur_xyz_px,
    describe_blur,
)
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import CameraPose, FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx, R_from_rotvec
from pdcov.errors import DetectorModelError

DEG = math.pi / 180
F = 500.0
PINHOLE = CameraModel(640, 480, np.array([[F, 0, 319.5], [0, F, 239.5], [0, 0, 1]]))
DISTORTED = CameraModel(640, 480, np.array([[F, 0, 310.0], [0, 505.0, 245.0], [0, 0, 1]]),
                        "plumb_bob", np.array([-0.2, 0.05, 0.001, -0.002, 0.01]))
SIZE_ONLY = {"bin_edges_px": [1, 20, 40, 80, 2000], "p_detect": [0.1, 0.4, 0.6, 0.3],
             "p_false_alarm": [0.05, 0.1, 0.2, 0.3], "input_size_px": None,
             "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],}
BLUR = {"edges_px": [0, 1, 3, 10],
        "p_detect": [[0.12, 0.45, 0.65, 0.35], [0.08, 0.3, 0.5, 0.3], [0.02, 0.1, 0.2, 0.1]],
        "p_false_alarm": [[0.05, 0.1, 0.2, 0.3], [0.06, 0.12, 0.2, 0.3],
                          [0.1, 0.2, 0.3, 0.4]]}
MODEL_1D = DetectorModel.from_dict({"version": 4, **SIZE_ONLY})
MODEL_2D = DetectorModel.from_dict({"version": 4, **SIZE_ONLY, "blur": BLUR})


def nadir(xyz=(0.0, 0.0, 10.0), yaw_deg=0.0, v=None, omega=None, t_s=0.0):
    p = fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, yaw_deg * DEG), xyz, FixedMount(), t_s)
    return CameraPose(p.R_enu_cam, p.r_cam_enu, t_s, v, omega)


def ground_points_of_pixels(cam, pose, px):
    """ENU points on z = 0 seen at pixels ``px`` (k, 2)."""
    rays = pose.R_enu_cam @ cam.pixel_rays(px).T
    s = -pose.r_cam_enu[2] / rays[2]
    return (pose.r_cam_enu[:, None] + s * rays).T


def test_nadir_translation_blurs_every_point_by_f_v_t_over_h():
    h, v, T = 40.0, 12.0, 0.004
    p = nadir((3.0, -2.0, h), yaw_deg=30, v=np.array([v * 0.6, v * 0.8, 0.0]),
              omega=np.zeros(3))
    pts = ground_points_of_pixels(PINHOLE, p, np.array([[319.5, 239.5], [10.0, 20.0],
                                                         [600.0, 470.0]]))
    np.testing.assert_allclose(blur_px(PINHOLE, p, pts, T), F * v * T / h, rtol=1e-9)


def test_pure_yaw_rate_leaves_the_centre_sharp_and_blurs_radius_r_by_omega_t_r():
    omega, T = 0.5, 0.01  # rad/s about the vertical (ENU up), s
    p = nadir((0.0, 0.0, 30.0), v=np.zeros(3), omega=np.array([0.0, 0.0, omega]))
    c = np.array([319.5, 239.5])
    r = np.array([0.0, 50.0, 200.0])
    px = c + np.stack([r * math.cos(0.3), r * math.sin(0.3)], axis=1)
    b = blur_px(PINHOLE, p, ground_points_of_pixels(PINHOLE, p, px), T)
    assert b[0] == pytest.approx(0.0, abs=1e-9)
    # Exactly the chord 2 r sin(omega T / 2); to first order omega T r.
    np.testing.assert_allclose(b, 2 * r * math.sin(omega * T / 2), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b, omega * T * r, rtol=1e-5)


@pytest.mark.parametrize("cam", [PINHOLE, DISTORTED], ids=["pinhole", "plumb_bob"])
def test_blur_is_the_projection_jacobian_times_the_motion(cam):
    """OpenCV's projectPoints Jacobian (independent of our projection) times the camera's
    motion over a short exposure gives the same image motion as projecting at both ends."""
    rng = np.random.default_rng(3)
    base = fixed_mount_pose(R_from_euler_zyx(0.1, -0.35, 0.7), (5.0, 7.0, 60.0),
                            FixedMount(pitch_rad=-70 * DEG))
    v = np.array([9.0, -4.0, 1.5])
    omega = np.array([0.3, -0.2, 0.6])
    p = CameraPose(base.R_enu_cam, base.r_cam_enu, 0.0, v, omega)
    px = rng.uniform([60, 60], [580, 420], (20, 2))
    pts = ground_points_of_pixels(cam, p, px)
    T = 1e-3
    p_cam = (pts - p.r_cam_enu) @ p.R_enu_cam
    K = cam.K.copy()
    _, J = cv2.projectPoints(p_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                             cam.dist_coeffs)
    J = J.reshape(-1, 2, J.shape[-1])
    R_cam_enu = p.R_enu_cam.T
    # d p_cam = exp([-R_cam_enu omega dt]x) p_cam - R_cam_enu v dt: a rotation vector and a
    # translation in OpenCV's extrinsics about the identity.
    d_rvec = -R_cam_enu @ omega * T
    d_tvec = -R_cam_enu @ v * T
    d_px = J[:, :, 0:3] @ d_rvec + J[:, :, 3:6] @ d_tvec
    np.testing.assert_allclose(blur_px(cam, p, pts, T), np.hypot(*d_px.T), rtol=1e-4)


@pytest.mark.parametrize("cam", [PINHOLE, DISTORTED, CameraModel.from_fov(
    640, 480, 150, "fisheye", (0.01, -0.005, 0.001, 0.0))], ids=["pinhole", "plumb_bob",
                                                              "fisheye"])
def test_the_lattice_form_is_the_pointwise_one(cam):
    """The grid's flat-ground path (OpenCV's maps over the window's lattice) gives the
    blur of projecting each point in float64, to the maps' float32 precision."""
    base = fixed_mount_pose(R_from_euler_zyx(0.05, -0.2, 1.0), (3.0, -4.0, 35.0),
                            FixedMount(pitch_rad=-75 * DEG))
    p = CameraPose(base.R_enu_cam, base.r_cam_enu, 0.0, np.array([8.0, 3.0, -0.5]),
                   np.array([0.2, -0.1, 0.4]))
    lattice = blur_lattice_px(cam, p, -20.0, -30.0, 0.7, 60, 80, 0.01)
    y, x = np.mgrid[0:80, 0:60]
    xyz = blur_xyz_px(cam, p, -20.0 + 0.7 * x.astype(float), -30.0 + 0.7 * y.astype(float),
                      np.zeros(x.shape), 0.01)
    seen = cam.visible((np.stack([-20.0 + 0.7 * x, -30.0 + 0.7 * y, np.zeros(x.shape)], -1)
                        .reshape(-1, 3) - p.r_cam_enu) @ p.R_enu_cam)[1].reshape(x.shape)
    assert seen.sum() > 1000 and np.nanmax(xyz[seen]) > 1.5
    np.testing.assert_allclose(lattice[seen], xyz[seen], atol=2e-3)


def test_blur_needs_a_pose_with_motion():
    with pytest.raises(ValueError, match="v_cam_enu_m_s"):
        blur_px(PINHOLE, nadir(), np.zeros((1, 3)), 0.01)


def test_rotvec_matches_scipy():
    from scipy.spatial.transform import Rotation
    for w in ([0.0, 0.0, 0.0], [1e-9, 0.0, 2e-9], [0.3, -1.2, 2.0]):
        np.testing.assert_allclose(R_from_rotvec(np.array(w)),
                                   Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


# --- the detector model's blur bins ---------------------------------------------------------


def test_lookup_by_size_and_blur_and_padded_rows():
    pd, pfa = MODEL_2D.lookup(np.array([30.0, 30.0, 30.0, 30.0, 0.5]),
                              np.array([0.0, 2.0, 9.9, 10.0, 0.5]))
    assert pd.tolist() == [0.45, 0.3, 0.1, 0.0, 0.0]
    assert pfa.tolist() == [0.1, 0.12, 0.2, 0.0, 0.0]
    # Without a blur: the size-only table (row 0).
    assert MODEL_2D.lookup(np.array([30.0]))[0].tolist() == [0.4]
    assert MODEL_1D.padded_tables_by_blur()[0].tolist() == MODEL_1D.padded_tables()[0].tolist()
    assert MODEL_2D.n_table_rows == 5 and MODEL_2D.padded_tables_by_blur()[0].size == 5 * 6


def test_blur_model_round_trips_and_bad_tables_are_named():
    doc = MODEL_2D.to_dict()
    assert doc["version"] == 4
    assert DetectorModel.from_dict(doc).blur == MODEL_2D.blur
    with pytest.raises(DetectorModelError, match="blur: needs version 3"):
        DetectorModel.from_dict({"version": 2, **SIZE_ONLY, "blur": BLUR}, source="m.yaml")
    with pytest.raises(DetectorModelError, match=r"m.yaml: blur.edges_px: .*the first 0"):
        DetectorModel.from_dict({"version": 4, **SIZE_ONLY,
                                 "blur": {**BLUR, "edges_px": [1, 3, 5, 10]}}, source="m.yaml")
    with pytest.raises(DetectorModelError, match=r"blur.p_detect: expected 3 rows .* of 4"):
        DetectorModel.from_dict({"version": 4, **SIZE_ONLY,
                                 "blur": {**BLUR, "p_detect": BLUR["p_detect"][:2]}})
    with pytest.raises(DetectorModelError, match=r"blur.p_false_alarm: probabilities"):
        DetectorModel.from_dict({"version": 4, **SIZE_ONLY, "blur": {
            **BLUR, "p_false_alarm": [[1.5, 0, 0, 0]] + BLUR["p_false_alarm"][1:]}})


# --- the grid -------------------------------------------------------------------------------


def grid(detector, **kw):
    dom = Domain.from_enu([[-40, -40], [40, -40], [40, 40], [-40, 40]])
    g = dom.grid_geometry(1.0)
    return CoverageGrid(g, dom.free_mask(g), PINHOLE, detector, **kw)


def test_nadir_blur_picks_the_blur_bin_of_f_v_t_over_h():
    # 500 px * 4 m/s * 0.01 s / 10 m = 2 px: blur bin [1, 3) everywhere.
    p = nadir((0.5, 0.5, 10.0), v=np.array([4.0, 0.0, 0.0]), omega=np.zeros(3))
    gr = grid(MODEL_2D, exposure_s=0.01)
    gr.update(p)
    assert gr.blur_effect is BlurEffect.APPLIED and gr.frames_blurred == 1
    # The cell under the camera is 50 px: size bin [40, 80).
    assert gr.pd[40, 40] == pytest.approx(0.5, rel=1e-6)
    # P_FA by size only: at least one false box in its 2,500 px^2 at 80 per Mpx.
    assert gr.pfa[40, 40] == pytest.approx(1 - math.exp(-80e-6 * 2500), rel=1e-5)
    observed, size = gr.observe(p, (0, 80, 0, 80))
    expect, _ = MODEL_2D.lookup(size, np.full(size.shape, 2.0))
    np.testing.assert_allclose(gr.pd[observed], expect, rtol=1e-6)


def test_no_blur_is_exactly_the_size_only_grid():
    moving = nadir((0.5, 0.5, 10.0), yaw_deg=20, v=np.array([4.0, 1.0, 0.0]),
                   omega=np.array([0.1, 0.0, 0.3]))
    still = nadir((0.5, 0.5, 10.0), yaw_deg=20)
    ref = grid(MODEL_1D)
    ref.update(still)
    for g, p in ((grid(MODEL_2D), moving),  # no exposure_s
                 (grid(MODEL_1D, exposure_s=0.01), moving),  # no blur bins
                 (grid(MODEL_2D, exposure_s=0.01), still)):  # no motion known
        g.update(p)
        assert np.array_equal(g.log_miss_d, ref.log_miss_d)
        assert np.array_equal(g.log_miss_fa, ref.log_miss_fa)
        assert np.array_equal(g.limiting, ref.limiting)
    assert grid(MODEL_2D).blur_effect is BlurEffect.NO_EXPOSURE
    assert grid(MODEL_1D, exposure_s=0.01).blur_effect is BlurEffect.NO_BLUR_BINS


def test_faster_flight_costs_detection():
    means = []
    for v in (0.0, 2.0, 6.0, 30.0):  # blur 0, 1, 3, 15 px
        g = grid(MODEL_2D, exposure_s=0.01)
        g.update(nadir((0.5, 0.5, 10.0), v=np.array([v, 0.0, 0.0]), omega=np.zeros(3)))
        means.append(g.pd[g.n_obs > 0].mean())
    assert means[0] > means[1] > means[2] > means[3] == 0.0


def test_summary_line_says_which_rule_applied():
    assert "no effect (no camera.exposure_s" in describe_blur(BlurEffect.NO_EXPOSURE, None,
                                                              0, 5)
    line = describe_blur(BlurEffect.APPLIED, 0.002, 3, 5)
    assert "applied (exposure 0.002 s) to 3 of 5 frames" in line and "2 frames" in line


def test_on_terrain_the_blur_is_at_the_cells_height():
    """Ground raised 6 m under a camera 16 m up: the terrain path blurs by f v T / 10 m, the
    blur of a camera 10 m above flat ground (the same size, so the same P_D)."""
    from pdcov.core.terrain import TerrainSurface
    dom = Domain.from_enu([[-40, -40], [40, -40], [40, 40], [-40, 40]])
    g = dom.grid_geometry(1.0)
    raised = CoverageGrid(g, dom.free_mask(g), PINHOLE, MODEL_2D, exposure_s=0.01,
                          terrain=TerrainSurface.flat(g, 6.0))
    flat = grid(MODEL_2D, exposure_s=0.01)
    # 500 * 2.4 * 0.01 / 10 = 1.2 px: blur bin [1, 3); from 16 m (the heights ignored) it
    # would be 0.75 px, bin [0, 1).
    v = np.array([2.4, 0.0, 0.0])
    raised.update(nadir((0.5, 0.5, 16.0), v=v, omega=np.zeros(3)))
    flat.update(nadir((0.5, 0.5, 10.0), v=v, omega=np.zeros(3)))
    assert raised.pd[40, 40] == pytest.approx(0.5, rel=1e-6)
    seen = (raised.n_obs > 0) & (flat.n_obs > 0)
    assert seen.sum() > 100  # the 12.8 m x 9.6 m footprint
    np.testing.assert_allclose(raised.pd[seen], flat.pd[seen], rtol=1e-5)
