"""Where on the ground a detector's box is, and how sure that is (docs/service.md
"Detections").

The box's ground point is the pixel at the middle of its bottom edge for the classes that
stand on the ground (``Geolocation.standing_classes``: a standing person's feet), its
centre for any other class; the pixel's ray (through the distortion: ``pixel_rays``) from
the frame's camera pose meets the ground: the plane z = 0, or the mission's terrain
(``TerrainSurface``: marched along the ray in steps of half a cell, then bisected against
its bilinear surface).

Uncertainty: the errors of the pose and of the pixel (``Geolocation``'s 1-sigma values,
independent) are propagated through the intersection by central differences over +-1
sigma of each (the Jacobian of the ground point's east and north in each error): the
horizontal covariance C = J diag(sigma^2) J^T, and ``sigma_m`` = sqrt of C's largest
eigenvalue, the 1-sigma error along the worst direction. Attitude errors are small
rotations of the camera about the level axes of its heading (roll: about the forward
one, pitch: about the right one) and about the vertical (yaw); position errors move the
camera east, north (horizontal sigma each) and up (vertical sigma). Hand check: a nadir
camera at height h maps a pixel error of d px to h d / f m, and a roll or pitch error of
e rad to about h e m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box, valid_class_name
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface

__all__ = ["Geolocation", "PositionAccuracy", "box_ground_px", "ground_points_enu", "locate_boxes"]

_BISECTIONS = 60  # halvings of a march step: far below a millimetre
_MAX_MARCH_STEPS = 100_000


@dataclass(frozen=True, slots=True)
class PositionAccuracy:
    """The 1-sigma error of the vehicle's position the autopilot reports at a frame (m):
    horizontal (per axis, east and north) and vertical (GPS_RAW_INT h_acc, v_acc)."""

    horizontal_m: float
    vertical_m: float

    def __post_init__(self) -> None:
        for name in ("horizontal_m", "vertical_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"position accuracy {name} {v!r}: expected a finite "
                                 "number >= 0 (m)")


@dataclass(frozen=True, slots=True)
class Geolocation:
    """How boxes are geolocated (module docstring): the classes whose ground point is the
    bottom centre, and the 1-sigma errors of the camera's attitude (rad), of its position
    (m) and of a box's pixel (px)."""

    standing_classes: tuple[str, ...] = ("person", "pedestrian")
    roll_sigma_rad: float = math.radians(0.5)
    pitch_sigma_rad: float = math.radians(0.5)
    yaw_sigma_rad: float = math.radians(1.0)
    horizontal_sigma_m: float = 1.0
    vertical_sigma_m: float = 1.0
    pixel_sigma_px: float = 2.0

    def __post_init__(self) -> None:
        if not all(valid_class_name(c) for c in self.standing_classes):
            raise ValueError(f"standing_classes {self.standing_classes!r}: expected class "
                             "names")
        for name in ("roll_sigma_rad", "pitch_sigma_rad", "yaw_sigma_rad",
                     "horizontal_sigma_m", "vertical_sigma_m", "pixel_sigma_px"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} {v!r}: expected a finite number >= 0")

    def with_accuracy(self, accuracy: PositionAccuracy | None) -> Geolocation:
        """These errors with the position's sigmas replaced by the reported ``accuracy``
        (None: unchanged, the configured ones)."""
        if accuracy is None:
            return self
        return replace(self, horizontal_sigma_m=accuracy.horizontal_m,
                       vertical_sigma_m=accuracy.vertical_m)

    @property
    def sigmas(self) -> np.ndarray:
        """The 8 error sigmas: roll, pitch, yaw (rad), east, north, up (m), pixel x, y (px)."""
        h, p = self.horizontal_sigma_m, self.pixel_sigma_px
        return np.array([self.roll_sigma_rad, self.pitch_sigma_rad, self.yaw_sigma_rad,
                         h, h, self.vertical_sigma_m, p, p])


def box_ground_px(box: Box, standing_classes: tuple[str, ...]) -> tuple[float, float]:
    """The pixel of ``box`` that lies on the ground: its bottom centre for a standing class,
    else its centre."""
    return box.bottom_centre_px if box.class_name in standing_classes else box.centre_px


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle_rad) * K + (1.0 - math.cos(angle_rad)) * (K @ K)


def _level_axes(R_enu_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera's heading as level unit axes (forward, right) in ENU: the horizontal
    direction of the optical axis, or of the image's up (-y) when the camera looks nearly
    straight down (the optical axis within about 6 degrees of the vertical)."""
    ahead = R_enu_cam[:, 2] if np.hypot(*R_enu_cam[:2, 2]) > 0.1 else -R_enu_cam[:, 1]
    f = np.array([ahead[0], ahead[1], 0.0])
    f /= np.linalg.norm(f)
    return f, np.array([f[1], -f[0], 0.0])


def ground_points_enu(r_enu_m: np.ndarray, d_enu: np.ndarray,
                      terrain: TerrainSurface | None = None) -> np.ndarray:
    """Where rays from ``r_enu_m`` (N, 3) along ``d_enu`` (N, 3) first meet the ground
    (N, 3) (ENU m): the plane z = 0 without ``terrain`` (or on level-zero terrain), else its
    surface; NaN for a ray that never meets it going down (level or up, or starting below
    it)."""
    r = np.asarray(r_enu_m, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(d_enu, dtype=np.float64).reshape(-1, 3)
    out = np.full(r.shape, np.nan)
    down = d[:, 2] < 0
    if terrain is None or terrain.is_level_zero:
        t = -r[down, 2] / d[down, 2]
        ok = t >= 0
        idx = np.flatnonzero(down)[ok]
        out[idx] = r[idx] + t[ok, None] * d[idx]
        return out
    idx = np.flatnonzero(down)
    if not len(idx):
        return out
    r, d = r[idx], d[idx]
    z_lo, z_hi = terrain.z_range_m
    # The ray lies above the whole terrain until it descends to z_hi, and below it after z_lo.
    t0 = np.maximum(0.0, (r[:, 2] - z_hi) / -d[:, 2])
    t1 = (r[:, 2] - z_lo) / -d[:, 2]
    horiz = np.hypot(d[:, 0], d[:, 1])
    step = 0.5 * terrain.geometry.cell_size_m / np.maximum(horiz, 1e-9)
    step = np.minimum(step, np.maximum(t1 - t0, 1e-9))  # at least one step per ray
    n_steps = int(min(_MAX_MARCH_STEPS, np.ceil(((t1 - t0) / step).max())))

    def above(t: np.ndarray) -> np.ndarray:  # height of the ray over the terrain (m)
        p = r + t[:, None] * d
        return p[:, 2] - terrain.height_m(p[:, 0], p[:, 1])

    lo = t0.copy()
    hit = np.zeros(len(r), dtype=bool)
    hi = np.full(len(r), np.nan)
    starts_below = above(t0) < 0
    for k in range(1, n_steps + 1):
        t = np.minimum(t0 + k * step, t1)
        open_ = ~hit & ~starts_below
        if not open_.any():
            break
        under = open_ & (above(t) <= 0)
        hi[under] = t[under]
        hit |= under
        lo[open_ & ~under] = t[open_ & ~under]
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        under = hit & (above(np.where(hit, mid, lo)) <= 0)
        hi = np.where(under, mid, hi)
        lo = np.where(hit & ~under, mid, lo)
    t = np.where(hit, hi, np.nan)
    out[idx] = r + t[:, None] * d
    return out


def locate_boxes(camera: CameraModel, pose: CameraPose, boxes: tuple[Box, ...] | list[Box],
                 geolocation: Geolocation, terrain: TerrainSurface | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The ground points (N, 3) (ENU m) of ``boxes`` seen from ``pose`` and their 1-sigma
    horizontal uncertainty (N,) (m; module docstring). NaN (point and sigma) for a box whose
    ray, or one of its +-1 sigma perturbations, misses the ground."""
    n = len(boxes)
    if n == 0:
        return np.empty((0, 3)), np.empty(0)
    s = geolocation.sigmas
    px = np.array([box_ground_px(b, geolocation.standing_classes) for b in boxes])
    # Rays of the pixel and of its x/y perturbations: (n, 5, 3) in the camera frame.
    shifts = np.array([[0, 0], [s[6], 0], [-s[6], 0], [0, s[7]], [0, -s[7]]])
    rays_cam = camera.pixel_rays((px[:, None, :] + shifts[None]).reshape(-1, 2)).reshape(n, 5, 3)
    R, r0 = pose.R_enu_cam, pose.r_cam_enu
    forward, right = _level_axes(R)
    up = np.array([0.0, 0.0, 1.0])
    # Each case: (rotation applied in ENU, camera offset, which ray): the nominal, then
    # -/+ each of the 8 errors.
    eye, zero = np.eye(3), np.zeros(3)
    cases = [(eye, zero, 0)]
    for axis, sigma in ((forward, s[0]), (right, s[1]), (up, s[2])):
        cases += [(_rotation(axis, -sigma), zero, 0), (_rotation(axis, sigma), zero, 0)]
    for axis, sigma in ((np.array([1.0, 0, 0]), s[3]), (np.array([0, 1.0, 0]), s[4]),
                        (up, s[5])):
        cases += [(eye, -sigma * axis, 0), (eye, sigma * axis, 0)]
    cases += [(eye, zero, 2), (eye, zero, 1), (eye, zero, 4), (eye, zero, 3)]
    origins = np.array([[r0 + off for _rot, off, _ray in cases]] * n)  # (n, 17, 3)
    dirs = np.stack([rays_cam[:, ray] @ (rot @ R).T for rot, _off, ray in cases], axis=1)
    ground = ground_points_enu(origins.reshape(-1, 3), dirs.reshape(-1, 3),
                               terrain).reshape(n, len(cases), 3)
    # J (n, 2, 8): d(east, north) / d(error), central differences over +-1 sigma.
    plus, minus = ground[:, 2::2, :2], ground[:, 1::2, :2]
    with np.errstate(invalid="ignore", divide="ignore"):
        J = np.where(s[None, :, None] > 0, (plus - minus) / (2 * np.where(s > 0, s, 1))[
            None, :, None], 0.0).transpose(0, 2, 1)
    C = J @ np.diag(s**2) @ J.transpose(0, 2, 1)
    sigma_m = np.sqrt(np.maximum(np.linalg.eigvalsh(np.nan_to_num(C))[:, -1], 0.0))
    points = ground[:, 0].copy()
    miss = ~np.isfinite(ground).all(axis=(1, 2))
    points[miss] = np.nan
    sigma_m[miss] = np.nan
    return points, sigma_m
