"""Calibrated camera: intrinsics, distortion (OpenCV), and the calibrated field of view.

Pixel convention (OpenCV): pixel (x, y) has its centre at integer coordinates; the picture
spans x in [-0.5, width - 0.5), y in [-0.5, height - 0.5). Normalised coordinates are
(X/Z, Y/Z) of a point in the OpenCV optical frame.

Projection and undistortion are OpenCV's (projectPoints, fisheye.projectPoints,
undistortPointsIter, fisheye.undistortPoints). The distortion polynomial of a strongly
distorted lens folds points far outside the field of view back into the image; a point is
therefore only ever reported visible when its direction lies inside the *calibrated field of
view*: the cone of directions of the image border, undistorted (see ``in_fov``).

The cone itself is ``camera_fov.AngularLimit``; reading a calibration from the mission config
or a ROS camera_info file is ``camera_config``'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pdcov.core.camera_config import (
    CameraConfig,
    camera_config_from_camera_info,
    camera_config_from_mapping,
)
from pdcov.core.camera_fov import AngularLimit, border_pixels, radial_fold_radius
from pdcov.errors import CalibrationError, where

DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "fisheye")
_COEFF_COUNTS = {"plumb_bob": (0, 4, 5, 8), "rational_polynomial": (8,), "fisheye": (4,)}
_MODEL_ALIASES = {"equidistant": "fisheye", "pinhole": "plumb_bob"}
_BORDER_SAMPLES_PER_SIDE = 256
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
_PROJECT_CHUNK = 32768
_EYE3 = np.eye(3)


@dataclass(frozen=True, slots=True)
class CameraModel:
    """A calibrated pinhole camera with OpenCV distortion.

    K: 3x3 intrinsic matrix [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] in pixels.
    dist_coeffs: plumb_bob (k1 k2 p1 p2 [k3 [k4 k5 k6]]) or fisheye (k1 k2 k3 k4).
    """

    width_px: int
    height_px: int
    K: np.ndarray
    distortion_model: str = "plumb_bob"
    dist_coeffs: np.ndarray = field(default_factory=lambda: np.zeros(5))
    source: str | None = None
    # Calibrated field of view: border angle from the optical axis per azimuth.
    _fov: AngularLimit = field(init=False, repr=False, compare=False)
    # Where projection is trustworthy: angle from the axis before the radial mapping stops
    # growing (distortion fold-back), per azimuth on the same samples as the field of view.
    _proj: AngularLimit = field(init=False, repr=False, compare=False)
    _border_rays_cam: np.ndarray = field(init=False, repr=False, compare=False)
    _K_no_skew: np.ndarray = field(init=False, repr=False, compare=False)
    _skew: float = field(init=False, repr=False, compare=False)
    _distorted: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        src = self.source
        given: Any = self.distortion_model  # from a file: may be any YAML value
        model = _MODEL_ALIASES.get(given, given) if isinstance(given, str) else ""
        if model not in DISTORTION_MODELS:
            raise CalibrationError(
                f"{where(src, 'distortion_model')}: expected one of "
                f"{', '.join(DISTORTION_MODELS)} (or equidistant), got {self.distortion_model!r}")
        for key in ("width_px", "height_px"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise CalibrationError(f"{where(src, key)}: expected a positive integer, "
                                       f"got {v!r}")
        K = np.array(self.K, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise CalibrationError(f"{where(src, 'K')}: expected a finite 3x3 matrix, "
                                   f"got {self.K!r}")
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        if fx <= 0 or fy <= 0:
            raise CalibrationError(f"{where(src, 'K')}: focal lengths fx, fy must be "
                                   f"positive, got fx={fx}, fy={fy}")
        if not (0 <= cx <= self.width_px and 0 <= cy <= self.height_px):
            raise CalibrationError(
                f"{where(src, 'K')}: principal point ({cx}, {cy}) lies outside the "
                f"{self.width_px} x {self.height_px} image")
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise CalibrationError(f"{where(src, 'K')}: last row must be [0, 0, 1] and "
                                   f"K[1][0] must be 0, got {K.tolist()}")
        d = np.array(self.dist_coeffs, dtype=float).reshape(-1)
        if d.size not in _COEFF_COUNTS[model]:
            raise CalibrationError(
                f"{where(src, 'distortion_coeffs')}: {model} takes "
                f"{' or '.join(str(n) for n in _COEFF_COUNTS[model])} coefficients, "
                f"got {d.size}")
        if not np.all(np.isfinite(d)):
            raise CalibrationError(f"{where(src, 'distortion_coeffs')}: NaN or infinite "
                                   f"coefficient in {d.tolist()}")
        if model != "fisheye" and d.size == 0:
            d = np.zeros(5)
        K.setflags(write=False)
        d.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist_coeffs", d)
        object.__setattr__(self, "distortion_model", model)
        # OpenCV's point functions ignore K[0][1]; the skew is applied around them instead.
        K_no_skew = K.copy()
        K_no_skew[0, 1] = 0.0
        object.__setattr__(self, "_K_no_skew", K_no_skew)
        object.__setattr__(self, "_skew", float(K[0, 1]))
        object.__setattr__(self, "_distorted", model == "fisheye" or bool(np.any(d)))
        if self._distorted:
            self._check_no_fold()
        self._init_fov()

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def from_config(cls, doc: Any, source: str | None = None, key: str = "camera"
                    ) -> CameraModel:
        """From a mission-config mapping: width_px, height_px, K, distortion_model,
        distortion_coeffs (``camera_config.CAMERA_CONFIG``)."""
        return cls.from_section(camera_config_from_mapping(doc, source, key), where(source, key))

    @classmethod
    def from_camera_info(cls, path: str | Path) -> CameraModel:
        """From a ROS ``camera_info`` YAML (image_width, image_height, camera_matrix,
        distortion_model, distortion_coefficients) as camera_calibration writes it."""
        return cls.from_section(camera_config_from_camera_info(path), str(path))

    @classmethod
    def from_section(cls, c: CameraConfig, source: str | None = None) -> CameraModel:
        """From a camera section as read (``camera_config``); ``source`` names it in errors."""
        return cls(c.width_px, c.height_px, c.K, c.distortion_model,
                   np.asarray(c.distortion_coeffs, dtype=float), source=source)

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float,
                 distortion_model: str = "plumb_bob",
                 dist_coeffs: tuple[float, ...] = ()) -> CameraModel:
        """A centred camera with square pixels and the given horizontal field of view
        (pinhole: f = (w/2) / tan(hfov/2); fisheye: equidistant f = (w/2) / (hfov/2))."""
        half = math.radians(hfov_deg) / 2
        f = (width_px / 2) / (half if distortion_model == "fisheye" else math.tan(half))
        K = np.array([[f, 0, width_px / 2 - 0.5], [0, f, height_px / 2 - 0.5], [0, 0, 1]])
        coeffs = dist_coeffs or ((0.0,) * 4 if distortion_model == "fisheye" else (0.0,) * 5)
        return cls(width_px, height_px, K, distortion_model, np.array(coeffs, float))

    # -- geometry ---------------------------------------------------------------------------

    @property
    def is_fisheye(self) -> bool:
        return self.distortion_model == "fisheye"

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of points (N, 3) in the optical frame, through OpenCV.

        Only meaningful where ``projectable`` is True; elsewhere the values may be folded back
        or infinite. Use ``visible`` for the combined test (in front, in the calibrated field
        of view, in the picture).
        """
        p = np.ascontiguousarray(np.asarray(p_cam, dtype=np.float64).reshape(-1, 1, 3))
        if len(p) == 0:
            return np.empty((0, 2))
        zero = np.zeros(3)
        with np.errstate(all="ignore"):
            if self.is_fisheye:
                px, _ = cv2.fisheye.projectPoints(p, zero, zero, self._K_no_skew,
                                                  self.dist_coeffs)
            else:
                px, _ = cv2.projectPoints(p, zero, zero, self._K_no_skew, self.dist_coeffs)
        px = px.reshape(-1, 2)
        if self._skew:
            px[:, 0] += self._skew * (px[:, 1] - self.K[1, 2]) / self.K[1, 1]
        return px

    def project_lattice(self, H_cam_lattice: np.ndarray, n_cols: int, n_rows: int
                        ) -> np.ndarray:
        """Pixel coordinates (n_rows, n_cols, 2) of the lattice points
        ``p_cam = H_cam_lattice @ [j, i, 1]`` (column j, row i) in the optical frame.

        The batch form of ``project`` for a regular grid of points on a plane, as the ground
        is: OpenCV's ``initUndistortRectifyMap`` evaluates the same distortion model over the
        whole lattice in one call (``H_cam_lattice`` plays the inverse rectification), far
        faster than ``projectPoints``, which always computes its Jacobians. Its output is
        float32 (pixel coordinates rounded to ~1e-4 px); without distortion the pinhole
        projection is evaluated exactly in float64 instead. Like ``project``, only meaningful
        where ``projectable``.
        """
        H = np.asarray(H_cam_lattice, dtype=np.float64)
        px: np.ndarray
        if not self._distorted:
            j = np.arange(n_cols, dtype=np.float64)
            i = np.arange(n_rows, dtype=np.float64)[:, None]
            px = np.empty((n_rows, n_cols, 2))
            with np.errstate(divide="ignore", invalid="ignore"):
                inv_z = 1.0 / (H[2, 0] * j + H[2, 1] * i + H[2, 2])
                px[..., 0] = self._K_no_skew[0, 0] * (H[0, 0] * j + H[0, 1] * i + H[0, 2]) \
                    * inv_z + self.K[0, 2]
                px[..., 1] = self._K_no_skew[1, 1] * (H[1, 0] * j + H[1, 1] * i + H[1, 2]) \
                    * inv_z + self.K[1, 2]
        elif self.is_fisheye:  # its map takes no two-channel output
            px = np.dstack(cv2.fisheye.initUndistortRectifyMap(
                self._K_no_skew, self.dist_coeffs, _inverse_3x3(H), _EYE3,
                (n_cols, n_rows), cv2.CV_32FC1))
        else:
            px, _ = cv2.initUndistortRectifyMap(self._K_no_skew, self.dist_coeffs,
                                                _inverse_3x3(H), _EYE3, (n_cols, n_rows),
                                                cv2.CV_32FC2)
        if self._skew:
            px[..., 0] += self._skew * (px[..., 1] - self.K[1, 2]) / self.K[1, 1]
        return px

    def project_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) of optical-frame points given as three float64 arrays.

        The distortion models of ``project`` evaluated in numpy (float64), for points that
        lie on no plane (the terrain's cell corners): OpenCV's plumb_bob / rational
        polynomial (k1 k2 p1 p2 k3 k4 k5 k6) and fisheye (equidistant) formulas, with the
        skew applied as ``project`` applies it. Only meaningful where ``projectable``.
        """
        K = self.K
        d = self.dist_coeffs
        px = np.empty((*np.shape(x), 2))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv_z = 1.0 / z
            a = x * inv_z
            b = y * inv_z
            r2 = a * a
            r2 += b * b
            if self._distorted and not self.is_fisheye:
                # The plumb_bob / rational terms below, in the same order, in place: the
                # terrain's lattices are the kernel's largest arrays.
                self._distort_in_place(a, b, r2, px)
            elif self.is_fisheye:
                r = np.sqrt(r2)
                theta = np.arctan(r)
                t2 = theta * theta
                theta_d = theta * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
                scale = np.where(r > 1e-12, theta_d / r, 1.0)
                xd, yd = a * scale, b * scale
            else:
                xd, yd = a, b
            if not self._distorted or self.is_fisheye:
                px[..., 0] = K[0, 0] * xd + K[0, 2]
                px[..., 1] = K[1, 1] * yd + K[1, 2]
        if self._skew:
            px[..., 0] += self._skew * (px[..., 1] - K[1, 2]) / K[1, 1]
        return px

    def _distort_in_place(self, a: np.ndarray, b: np.ndarray, r2: np.ndarray, px: np.ndarray
                          ) -> None:
        """Pixels ``px`` (..., 2) of normalised coordinates a, b (r2 = a^2 + b^2) through the
        plumb_bob / rational polynomial: x_d = a radial + 2 p1 a b + p2 (r2 + 2 a^2), y_d =
        b radial + p1 (r2 + 2 b^2) + 2 p2 a b, radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) /
        (1 + k4 r2 + k5 r2^2 + k6 r2^3); ``a`` and ``b`` are overwritten."""
        k = np.zeros(8)
        k[:self.dist_coeffs.size] = self.dist_coeffs
        radial = r2 * k[4]
        radial += k[1]
        radial *= r2
        radial += k[0]
        radial *= r2
        radial += 1
        if k[5:].any():
            radial /= 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
        ab2 = 2 * a
        ab2 *= b
        tx = 2 * a                    # p2 (r2 + 2 a^2)
        tx *= a
        tx += r2
        tx *= k[3]
        ty = 2 * b                    # p1 (r2 + 2 b^2)
        ty *= b
        ty += r2
        ty *= k[2]
        a *= radial
        a += ab2 * k[2]
        a += tx
        b *= radial
        b += ty
        ab2 *= k[3]
        b += ab2
        np.multiply(a, self.K[0, 0], out=px[..., 0])
        px[..., 0] += self.K[0, 2]
        np.multiply(b, self.K[1, 1], out=px[..., 1])
        px[..., 1] += self.K[1, 2]

    def pixel_rays(self, px: np.ndarray) -> np.ndarray:
        """Unit direction vectors (N, 3) in the optical frame of pixels (N, 2)."""
        uv = self.undistort_normalized(px)
        rays = np.concatenate([uv, np.ones((len(uv), 1))], axis=1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def undistort_normalized(self, px: np.ndarray) -> np.ndarray:
        """Normalised rectified coordinates (u, v) (N, 2) of pixels (N, 2), through OpenCV."""
        p = np.array(px, dtype=np.float64).reshape(-1, 1, 2)
        if len(p) == 0:
            return np.empty((0, 2))
        if self._skew:
            p[:, 0, 0] -= self._skew * (p[:, 0, 1] - self.K[1, 2]) / self.K[1, 1]
        if self.is_fisheye:
            uv = cv2.fisheye.undistortPoints(p, self._K_no_skew, self.dist_coeffs,
                                             criteria=_UNDISTORT_CRITERIA)
        else:
            uv = _undistort_points_iter(p, self._K_no_skew, self.dist_coeffs)
        return uv.reshape(-1, 2)

    def in_fov(self, p_cam: np.ndarray) -> np.ndarray:
        """True where the direction of points (..., 3) lies inside the calibrated field of view
        (the cone of the undistorted image border), whatever the distortion polynomial does
        beyond it."""
        return self._fov.contains(p_cam)

    def in_fov_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``in_fov`` for the optical-frame coordinates given as three float64 arrays."""
        return self._fov.contains_xyz(x, y, z)

    def projectable(self, p_cam: np.ndarray) -> np.ndarray:
        """True where ``project`` is trustworthy for points (..., 3): in front of the camera
        and inside the cone where the distortion's radial mapping still grows with the angle
        from the axis. Wider than the field of view, so that the corners of cells at the
        picture's edge project correctly (they land outside the picture)."""
        return self._proj.contains(p_cam)

    def all_projectable(self, corners_cam: np.ndarray) -> bool:
        """True when every point of the convex hull of ``corners_cam`` (k, 3) is
        ``projectable`` (the corners lie inside the narrowest cone of trustworthy
        projection, which is convex)."""
        return bool(self._proj.inscribed_contains(corners_cam).all())

    def in_picture(self, px: np.ndarray) -> np.ndarray:
        """True where pixel coordinates (..., 2) lie inside the picture."""
        x, y = px[..., 0], px[..., 1]
        return (x >= -0.5) & (x < self.width_px - 0.5) & (y >= -0.5) & (y < self.height_px - 0.5)

    def visible(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) of points (N, 3) and a mask: in front, in the calibrated field of
        view, and inside the picture."""
        p = np.asarray(p_cam, dtype=float).reshape(-1, 3)
        ok = (p[:, 2] > 0) & self.in_fov(p)
        px = np.full((len(p), 2), np.nan)
        if ok.any():
            px[ok] = self.project(p[ok])
            ok &= self.in_picture(np.nan_to_num(px, nan=-1e9))
        return px, ok

    @property
    def border_rays_cam(self) -> np.ndarray:
        """Unit rays (M, 3) through the picture's border, in order around it (optical frame)."""
        return self._border_rays_cam

    @property
    def focal_px(self) -> float:
        """Larger focal length in pixels (the finest angular resolution near the axis)."""
        return float(max(self.K[0, 0], self.K[1, 1]))

    def _check_no_fold(self) -> None:
        """Refuse a lens whose radial mapping folds back inside the picture (camera_fov.
        radial_fold_radius): its pixels beyond the fold cannot be mapped back to rays, and
        the field of view would silently shrink to the fold."""
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        w, h = self.width_px - 0.5, self.height_px - 0.5
        corner = max(math.hypot((u - cx) / fx, (v - cy) / fy)
                     for u in (-0.5, w) for v in (-0.5, h))
        fold = radial_fold_radius(self.distortion_model, self.dist_coeffs, corner)
        if fold is not None:
            f = math.sqrt(fx * fy)
            raise CalibrationError(
                f"{where(self.source, 'distortion_coeffs')}: the lens folds over inside the "
                f"picture: its radial mapping stops growing at {fold * f:.0f} px from the "
                f"principal point (normalised radius {fold:.3f}), short of the corner at "
                f"{corner * f:.0f} px ({corner:.3f}); check the coefficients "
                f"{self.dist_coeffs.tolist()}")

    def _init_fov(self) -> None:
        border = border_pixels(self.width_px, self.height_px, _BORDER_SAMPLES_PER_SIDE)
        rays = self.pixel_rays(border)
        if not np.all(np.isfinite(rays)) or np.any(rays[:, 2] <= 0):
            raise CalibrationError(
                f"{self.source or 'camera'}: the image border does not undistort to "
                f"directions in front of the camera; check the distortion coefficients "
                f"{self.dist_coeffs.tolist()} (fisheye fields of view must stay below 180 deg)")
        theta = np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2])
        azimuth = np.arctan2(rays[:, 1], rays[:, 0])
        order = np.argsort(azimuth)
        azimuth, theta = azimuth[order], theta[order]
        # Wrap one sample each way so that interpolation covers [-pi, pi] without ``period``.
        azimuth = np.concatenate([[azimuth[-1] - 2 * np.pi], azimuth, [azimuth[0] + 2 * np.pi]])
        theta = np.concatenate([[theta[-1]], theta, [theta[0]]])
        proj_theta = self._fold_back_theta(azimuth)
        object.__setattr__(self, "_border_rays_cam", rays)
        object.__setattr__(self, "_proj", AngularLimit.from_samples(azimuth, proj_theta))
        # The field of view never extends past the trustworthy cone.
        object.__setattr__(self, "_fov", AngularLimit.from_samples(
            azimuth, np.minimum(theta, proj_theta)))

    def _fold_back_theta(self, azimuth_rad: np.ndarray) -> np.ndarray:
        """Per azimuth, the angle from the axis (rad) where the projected radius stops growing,
        searched up to 89.5 deg; one sample step is kept as margin."""
        theta = np.radians(np.linspace(0.0, 89.5, 600))[1:]
        if not self._distorted:
            # The pinhole radius f tan(theta) (skewed or not) grows all the way: the search
            # would find no fold-back. Skipping it saves ~0.3 s of start-up per camera.
            return np.full(len(azimuth_rad), theta[-2])
        ca, sa = np.cos(azimuth_rad), np.sin(azimuth_rad)
        st, ct = np.sin(theta), np.cos(theta)
        dirs = np.stack([st[None, :] * ca[:, None], st[None, :] * sa[:, None],
                         np.broadcast_to(ct, (len(ca), len(theta)))], axis=-1)
        # In chunks: projectPoints also returns its Jacobians, 30 floats per point.
        dirs = dirs.reshape(-1, 3)
        px = np.concatenate([self.project(dirs[k:k + _PROJECT_CHUNK])
                             for k in range(0, len(dirs), _PROJECT_CHUNK)])
        px = px.reshape(len(ca), len(theta), 2)
        radius = np.hypot(px[..., 0] - self.K[0, 2], px[..., 1] - self.K[1, 2])
        growing = np.diff(radius, axis=1) > 0
        growing &= np.isfinite(radius[:, 1:])
        first_bad = np.where(growing.all(axis=1), len(theta) - 1, np.argmin(growing, axis=1))
        return theta[np.maximum(first_bad - 1, 0)]

    def to_config(self) -> dict[str, Any]:
        return {"width_px": int(self.width_px), "height_px": int(self.height_px),
                "K": self.K.tolist(), "distortion_model": self.distortion_model,
                "distortion_coeffs": self.dist_coeffs.tolist()}


def _inverse_3x3(M: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by its adjugate (np.linalg.inv costs ~20 us per call)."""
    (a, b, c), (d, e, f), (g, h, i) = M.tolist()
    co = [e * i - f * h, f * g - d * i, d * h - e * g]
    det = a * co[0] + b * co[1] + c * co[2]
    return np.array([[co[0], c * h - b * i, b * f - c * e],
                     [co[1], a * i - c * g, c * d - a * f],
                     [co[2], b * g - a * h, a * e - b * d]]) / det


def _undistort_points_iter(p: np.ndarray, K: np.ndarray, d: np.ndarray) -> np.ndarray:
    # OpenCV 4 has undistortPointsIter; OpenCV 5 folded its criteria into undistortPoints.
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(p, K, d, None, None, _UNDISTORT_CRITERIA)
    return cv2.undistortPoints(p, K, d, None, None, None, _UNDISTORT_CRITERIA)


