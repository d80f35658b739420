"""Motion blur: how far a ground point's image moves during one exposure, in pixels.

During the exposure ``T`` (``camera.exposure_s``) the camera moves with its velocity
``v_cam_enu_m_s`` and turns with its angular rate ``omega_enu_rad_s`` (CameraPose, ENU). A
ground point's blur is the distance between its images at the exposure's start and end,
t_s - T/2 and t_s + T/2, each projected through the camera model (distortion included):

    r(t) = r_cam_enu + v (t - t_s),   R_enu_cam(t) = exp([omega]x (t - t_s)) R_enu_cam.

Hand checks (docs/detector-model.md): a nadir camera at height h moving at v m/s with focal
length f px blurs every point by f v T / h px; a pure yaw rate omega leaves the image centre
sharp and blurs a pixel at radius r px by omega T r px (to first order).

Whether blur enters the grid (``blur_effect``): it needs the exposure time, a detector
model with blur bins and, per frame, a pose whose velocity and angular rate are known;
without any of them the grid is exactly the size-only one.
"""

from __future__ import annotations

import enum

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.pose import CameraPose
from pdcov.core.rotations import R_from_rotvec


class BlurEffect(enum.Enum):
    """Whether a grid's P_D depends on motion blur, and if not, why not."""

    APPLIED = "applied"
    NO_EXPOSURE = "no camera.exposure_s in the mission"
    NO_BLUR_BINS = "the detector model has no blur bins"


def blur_effect(exposure_s: float | None, detector: DetectorModel) -> BlurEffect:
    """APPLIED when both the exposure time and the model's blur bins are given."""
    if exposure_s is None:
        return BlurEffect.NO_EXPOSURE
    if detector.blur is None:
        return BlurEffect.NO_BLUR_BINS
    return BlurEffect.APPLIED


def describe_blur(effect: BlurEffect, exposure_s: float | None, frames_blurred: int,
                  frames: int) -> str:
    """One summary line: which blur rule applied, to how many frames."""
    if effect is not BlurEffect.APPLIED:
        return f"motion blur: no effect ({effect.value}); P_D by size only"
    line = (f"motion blur: applied (exposure {exposure_s:g} s) to {frames_blurred} of "
            f"{frames} frames")
    if frames_blurred < frames:
        line += (f"; {frames - frames_blurred} frames without a known velocity and angular "
                 "rate took P_D by size only")
    return line


def blur_px(camera: CameraModel, pose: CameraPose, points_enu: np.ndarray,
            exposure_s: float) -> np.ndarray:
    """Blur (k,) in image pixels of ground points ``points_enu`` (k, 3), ENU m, seen from
    ``pose`` during an exposure of ``exposure_s`` s centred on the frame time.

    The pose must carry its velocity and angular rate (ValueError otherwise). Points that do
    not project at either end of the exposure (behind the camera) give NaN.
    """
    p = np.asarray(points_enu, dtype=np.float64).reshape(-1, 3)
    return blur_xyz_px(camera, pose, p[:, 0], p[:, 1], p[:, 2], exposure_s)


def _exposure_ends(pose: CameraPose, exposure_s: float
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
    """(R_cam_enu, r_cam_enu) at the start and the end of the exposure: the optical frame
    there is p_cam = R_cam_enu (p - r_cam_enu)."""
    if pose.v_cam_enu_m_s is None or pose.omega_enu_rad_s is None:
        raise ValueError("blur_px needs a pose with v_cam_enu_m_s and omega_enu_rad_s")
    half = 0.5 * float(exposure_s)
    return [((R_from_rotvec(sign * half * pose.omega_enu_rad_s) @ pose.R_enu_cam).T,
             pose.r_cam_enu + sign * half * pose.v_cam_enu_m_s) for sign in (-1.0, 1.0)]


def _streak_px(px: list[np.ndarray]) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.hypot(px[1][..., 0] - px[0][..., 0], px[1][..., 1] - px[0][..., 1])


def blur_xyz_px(camera: CameraModel, pose: CameraPose, x_m: np.ndarray, y_m: np.ndarray,
                z_m: np.ndarray, exposure_s: float) -> np.ndarray:
    """``blur_px`` of points given as three float64 arrays of ENU coordinates (m)."""
    px = []
    for M, c in _exposure_ends(pose, exposure_s):
        dx, dy, dz = x_m - c[0], y_m - c[1], z_m - c[2]
        xyz = [M[k, 0] * dx + M[k, 1] * dy + M[k, 2] * dz for k in range(3)]
        with np.errstate(invalid="ignore", divide="ignore"):
            px.append(camera.project_xyz(xyz[0], xyz[1],
                                         np.where(xyz[2] > 0, xyz[2], np.nan)))
    return _streak_px(px)


def blur_lattice_px(camera: CameraModel, pose: CameraPose, x0_m: float, y0_m: float,
                    step_m: float, n_cols: int, n_rows: int, exposure_s: float) -> np.ndarray:
    """``blur_px`` (n_rows, n_cols) of the ground points (x0_m + step_m j, y0_m + step_m i,
    0) ENU m: the lattice form, through ``CameraModel.project_lattice`` (its distorted maps
    are float32, ~1e-4 px). Only meaningful where the points project at both ends."""
    px = []
    for M, c in _exposure_ends(pose, exposure_s):
        H = M @ np.array([[step_m, 0.0, x0_m - c[0]], [0.0, step_m, y0_m - c[1]],
                          [0.0, 0.0, -c[2]]])
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            px.append(camera.project_lattice(H, n_cols, n_rows))
    return _streak_px(px)
