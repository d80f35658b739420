"""The calibrated field of view as a cone of directions: ``AngularLimit``, the angle from
the optical axis below a limit that varies with the azimuth, and the picture's border pixels
it is sampled on.

``CameraModel`` (core/camera.py) builds two of these from its undistorted border rays: the
field of view, and the cone where its projection is trustworthy (before distortion folds
back). Directions are in the OpenCV optical frame; angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["AngularLimit", "border_pixels", "radial_fold_radius"]

_FOLD_SAMPLES = 20_000
_MAX_PINHOLE_ANGLE_RAD = np.radians(89.5)  # as far as CameraModel's fold-back cone looks
_SECTORS = 1024  # pseudo-azimuth sectors of the fast angular-limit test
_ANGLE_MARGIN_RAD = 1e-9


@dataclass(frozen=True, slots=True)
class AngularLimit:
    """A cone of directions about the optical axis: angle from the axis (rad) below a limit
    that varies with the azimuth, linearly between samples.

    ``contains`` is exactly ``theta < interp(azimuth, azimuth_rad, theta_rad)``; to avoid two
    arctangents and an interpolation per point, it first compares tan^2(theta) with bounds of
    the limit over sectors of a trigonometry-free pseudo-azimuth, and evaluates the exact
    test only for the points that fall between the bounds.
    """

    azimuth_rad: np.ndarray   # (M,) increasing, wrapped one sample past -pi and pi
    theta_rad: np.ndarray     # (M,) limit at each azimuth, in (0, pi/2)
    tan2_lo: np.ndarray       # (S,) per sector: below this tan^2(theta) the point is inside
    tan2_hi: np.ndarray       # (S,) per sector: above this tan^2(theta) the point is outside
    tan2_inscribed: float     # tan^2 of the smallest limit (a convex circular cone), minus margin

    @classmethod
    def from_samples(cls, azimuth_rad: np.ndarray, theta_rad: np.ndarray) -> AngularLimit:
        """From the wrapped samples; bounds of the limit over each sector, widened by the
        neighbouring sectors and a margin so that rounding never decides."""
        edges = np.linspace(0.0, 4.0, _SECTORS + 1)
        phi_edges = np.arctan2(*_direction_of_pseudo_azimuth(edges)[::-1])
        phi_edges[0] = -np.pi  # key 0 and key 4 are the same direction, at -pi and +pi
        phi_all = np.concatenate([phi_edges, azimuth_rad[(azimuth_rad > -np.pi)
                                                          & (azimuth_rad < np.pi)]])
        order = np.argsort(phi_all, kind="stable")
        phi_all = phi_all[order]
        limit = np.interp(phi_all, azimuth_rad, theta_rad)
        start = np.searchsorted(phi_all, phi_edges[:-1], side="left")
        stop = np.searchsorted(phi_all, phi_edges[1:], side="right")
        sector_min = [np.min(limit[a:b]) for a, b in zip(start, stop, strict=True)]
        sector_max = [np.max(limit[a:b]) for a, b in zip(start, stop, strict=True)]
        lo = np.min([np.roll(sector_min, k) for k in (-1, 0, 1)], axis=0) - _ANGLE_MARGIN_RAD
        hi = np.max([np.roll(sector_max, k) for k in (-1, 0, 1)], axis=0) + _ANGLE_MARGIN_RAD
        return cls(azimuth_rad, theta_rad, np.tan(np.maximum(lo, 0.0)) ** 2,
                   np.tan(np.minimum(hi, np.pi / 2 - _ANGLE_MARGIN_RAD)) ** 2,
                   float(np.tan(max(theta_rad.min() - _ANGLE_MARGIN_RAD, 0.0)) ** 2))

    def contains(self, p_cam: np.ndarray) -> np.ndarray:
        """True where points (..., 3) in the optical frame lie strictly inside the cone."""
        p = np.asarray(p_cam, dtype=float)
        return self.contains_xyz(p[..., 0], p[..., 1], p[..., 2])

    def contains_xyz(self, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``contains`` for the coordinates given as three arrays of one shape (float64)."""
        r2 = x * x
        r2 += y * y
        z2 = z * z
        with np.errstate(invalid="ignore", divide="ignore"):
            key = _pseudo_azimuth(x, y)
            key *= _SECTORS / 4.0
            sector = np.fmax(key, 0.0).astype(np.intp)  # NaN (x = y = 0) -> 0
        np.minimum(sector, _SECTORS - 1, out=sector)
        inside = r2 < self.tan2_lo.take(sector) * z2
        inside &= z > 0
        outside = r2 > self.tan2_hi.take(sector) * z2
        outside |= z < 0
        unsure = ~(inside | outside)
        if unsure.any():
            xu, yu, zu = x[unsure], y[unsure], z[unsure]
            theta = np.arctan2(np.hypot(xu, yu), zu)
            azimuth = np.arctan2(yu, xu)
            inside[unsure] = theta < np.interp(azimuth, self.azimuth_rad, self.theta_rad)
        return inside

    def inscribed_contains(self, p_cam: np.ndarray) -> np.ndarray:
        """True where points (..., 3) lie inside the circular cone of the smallest limit."""
        p = np.asarray(p_cam, dtype=float)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        return (z > 0) & (x * x + y * y < self.tan2_inscribed * z * z)


def _pseudo_azimuth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A trigonometry-free key in [0, 4] increasing with arctan2(y, x) over [-pi, pi]."""
    p = y / (np.abs(x) + np.abs(y))
    return np.where(x >= 0, p + 2.0, np.where(y < 0, -p, 4.0 - p))


def _direction_of_pseudo_azimuth(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of a direction with the given ``_pseudo_azimuth`` key (inverse of it)."""
    p = np.where(key < 1, -key, np.where(key <= 3, key - 2.0, 4.0 - key))
    x = np.where(key < 1, -(1 + p), np.where(key <= 3, 1 - np.abs(p), -(1 - p)))
    return x, p


def border_pixels(width_px: int, height_px: int, per_side: int) -> np.ndarray:
    """Points (4 * per_side, 2) along the picture's outer edge, clockwise from top-left."""
    x0, y0, x1, y1 = -0.5, -0.5, width_px - 0.5, height_px - 0.5
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    top = np.stack([x0 + t * (x1 - x0), np.full_like(t, y0)], axis=1)
    right = np.stack([np.full_like(t, x1), y0 + t * (y1 - y0)], axis=1)
    bottom = np.stack([x1 - t * (x1 - x0), np.full_like(t, y1)], axis=1)
    left = np.stack([np.full_like(t, x0), y1 - t * (y1 - y0)], axis=1)
    return np.concatenate([top, right, bottom, left])


def radial_fold_radius(model: str, dist_coeffs: np.ndarray, corner_radius: float
                       ) -> float | None:
    """The distorted normalised radius at which the lens's radial mapping stops growing
    (it folds back), when that lies inside ``corner_radius`` (the picture's farthest corner,
    distorted normalised radius); None when the mapping grows out to the corner.

    Radial part only (the tangential terms of a real calibration are small): plumb_bob and
    rational_polynomial r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 +
    k6 r^6), for r = tan(theta) up to 89.5 deg; fisheye r_d = theta (1 + k1 theta^2 + ...
    + k4 theta^8) up to 90 deg (OpenCV's models). Inside the fold two directions land on
    the same pixel: the picture cannot be mapped back to rays."""
    d = np.asarray(dist_coeffs, dtype=float)
    if model == "fisheye":
        a = np.linspace(0.0, np.pi / 2, _FOLD_SAMPLES)
        a2 = a * a
        r_d = a * (1 + a2 * (d[0] + a2 * (d[1] + a2 * (d[2] + a2 * d[3]))))
    else:
        k = np.zeros(8)
        k[:d.size] = d
        r = np.tan(np.linspace(0.0, _MAX_PINHOLE_ANGLE_RAD, _FOLD_SAMPLES))
        r2 = r * r
        num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
        den = 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
        with np.errstate(divide="ignore", invalid="ignore"):
            r_d = r * num / den
    growing = np.isfinite(r_d[1:]) & (np.diff(r_d) > 0)
    if growing.all():
        return None
    fold = float(r_d[int(np.argmin(growing))])
    return fold if fold < corner_radius else None
