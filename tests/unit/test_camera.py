"""Camera model: OpenCV round trips, the calibrated field of view, calibration errors."""

import numpy as np
import pytest
import yaml

from pdcov.core.camera import CameraModel
from pdcov.errors import CalibrationError

K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]


def cameras():
    yield CameraModel(640, 480, np.array(K), "plumb_bob", np.array([-0.1, 0.05, 1e-3, -1e-3, 0]))
    yield CameraModel(640, 480, np.array(K), "plumb_bob",
                      np.array([-0.1, 0.05, 0, 0, 0.01, 0.02, 0.001, 0.0]))
    yield CameraModel.from_fov(1280, 720, 150, "fisheye", (0.02, -0.01, 0.003, -0.001))


@pytest.mark.parametrize("cam", list(cameras()), ids=["plumb_bob", "rational", "fisheye"])
def test_pixel_ray_project_round_trip(cam):
    rng = np.random.default_rng(1)
    px = rng.uniform([0, 0], [cam.width_px - 1, cam.height_px - 1], size=(500, 2))
    rays = cam.pixel_rays(px)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    np.testing.assert_allclose(cam.project(rays * 7.0), px, atol=1e-6)
    _, ok = cam.visible(rays * 3.0)
    assert ok.all()


@pytest.mark.parametrize("cam", [*cameras(), CameraModel(
    640, 480, np.array([[500.0, 3.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]]),
    "plumb_bob", np.array([-0.1, 0.05, 1e-3, -1e-3, 0.002])), CameraModel.from_fov(640, 480, 70)],
    ids=["plumb_bob", "rational", "fisheye", "skewed", "pinhole"])
def test_project_xyz_is_opencvs_projection(cam):
    """The numpy projection the terrain kernel uses equals OpenCV's projectPoints."""
    rng = np.random.default_rng(2)
    px = rng.uniform([0, 0], [cam.width_px - 1, cam.height_px - 1], size=(400, 2))
    p = cam.pixel_rays(px) * rng.uniform(1.0, 80.0, (400, 1))
    np.testing.assert_allclose(cam.project_xyz(p[:, 0], p[:, 1], p[:, 2]), cam.project(p),
                               atol=1e-9)


def test_pinhole_centre_and_known_point():
    cam = CameraModel(640, 480, np.array(K), "plumb_bob", np.zeros(5))
    np.testing.assert_allclose(cam.project(np.array([[0.1, -0.2, 1.0]])), [[370.0, 140.0]])
    px, ok = cam.visible(np.array([[0, 0, 1.0], [0, 0, -1.0], [10, 0, 1.0]]))
    assert ok.tolist() == [True, False, False]


def test_fold_back_guard_rejects_points_beyond_the_field_of_view():
    # Strong barrel distortion: the polynomial folds far-off-axis points back into the image
    # (its fold, at normalised radius 0.86, lies just beyond the picture's corner at 0.80).
    cam = CameraModel(640, 480, np.array(K), "plumb_bob", np.array([-0.2, 0, 0, 0, 0]))
    far = np.array([[2.0, 0.0, 1.0]])  # 63 deg off axis, outside the ~39 deg half-width
    folded = cam.project(far)
    assert cam.in_picture(folded).all(), "premise: OpenCV folds this point into the image"
    _, ok = cam.visible(far)
    assert not ok.any()


@pytest.mark.parametrize(("model", "coeffs", "words"), [
    ("plumb_bob", [-3.0, 0, 0, 0, 0], "stops growing at 111 px from the principal point "
     "(normalised radius 0.222), short of the corner at 401 px (0.801)"),
    ("plumb_bob", [-0.3, 0, 0, 0, 0], "at 351 px from the principal point (normalised "
     "radius 0.703)"),
    ("fisheye", [-0.5, 0, 0, 0], "(normalised radius 0.544)"),
])
def test_a_lens_that_folds_over_inside_the_picture_is_refused_naming_the_radius(
        model, coeffs, words):
    with pytest.raises(CalibrationError, match="m.yaml: camera: distortion_coeffs: the lens "
                                               "folds over inside the picture") as exc:
        CameraModel(640, 480, np.array(K), model, np.array(coeffs), source="m.yaml: camera")
    assert words in str(exc.value)


def test_from_camera_info(tmp_path):
    info = {"image_width": 640, "image_height": 480,
            "camera_matrix": {"rows": 3, "cols": 3, "data": sum(K, [])},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.1, 0.01, 0, 0, 0]}}
    path = tmp_path / "cam.yaml"
    path.write_text(yaml.safe_dump(info))
    cam = CameraModel.from_camera_info(path)
    assert cam.width_px == 640 and cam.K[0, 0] == 500 and cam.dist_coeffs[0] == -0.1
    info["distortion_model"] = "equidistant"
    info["distortion_coefficients"]["data"] = [0.01, 0, 0, 0]
    path.write_text(yaml.safe_dump(info))
    assert CameraModel.from_camera_info(path).is_fisheye


@pytest.mark.parametrize("change, field", [
    ({"K": [[-500, 0, 320], [0, 500, 240], [0, 0, 1]]}, "focal"),
    ({"K": [[500, 0, 900], [0, 500, 240], [0, 0, 1]]}, "principal point"),
    ({"distortion_coeffs": [0.1, 0.2, 0.3]}, "distortion_coeffs"),
    ({"distortion_coeffs": [float("nan"), 0, 0, 0, 0]}, "distortion_coeffs"),
    ({"width_px": 0}, "width_px"),
    ({"distortion_model": "kannala"}, "distortion_model"),
    ({"K": [[500, 0, 320], [0, 500, 240]]}, "K"),
])
def test_bad_calibration_names_the_field(change, field):
    doc = {"width_px": 640, "height_px": 480, "K": K, "distortion_model": "plumb_bob",
           "distortion_coeffs": [0, 0, 0, 0, 0]} | change
    with pytest.raises(CalibrationError, match=field):
        CameraModel.from_config(doc, source="mission.yaml")


def test_skew_is_honoured():
    Ks = np.array([[500.0, 5.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    cam = CameraModel(640, 480, Ks, "plumb_bob", np.zeros(5))
    np.testing.assert_allclose(cam.project(np.array([[0.1, 0.1, 1.0]])), [[370.5, 290.0]])
