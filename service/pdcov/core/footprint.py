"""Sensor footprint on the flat ground z = 0 (paper, section III-A), or on any level plane,
and the per-pixel ray count of the paper's Fig. 5.

A pixel's ray is ``R_enu_cam @ d_cam * t + r_cam_enu``; it sees the ground where z = 0 at
t > 0. Rays that never reach the ground, or reach it beyond ``max_range_m`` from the camera,
are clipped to the circle of ground points at that slant range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import Polygon

from pdcov.core.camera import CameraModel
from pdcov.core.domain import GridGeometry
from pdcov.core.pose import CameraPose

_HORIZON_EPS = 1e-9


def ground_range_m(pose: CameraPose, max_range_m: float, ground_z_m: float = 0.0) -> float:
    """Horizontal radius about the nadir point of the ground disk (on the plane z =
    ground_z_m) within ``max_range_m`` slant range of the camera; 0 when the camera is at or
    below that plane."""
    h = float(pose.r_cam_enu[2]) - ground_z_m
    if h <= 0 or max_range_m <= h:
        return 0.0
    return math.sqrt(max_range_m**2 - h**2)


def footprint_ring_enu(camera: CameraModel, pose: CameraPose, max_range_m: float
                       ) -> np.ndarray:
    """Ground points (M, 2) ENU of the rays through the picture border, in order around it.

    Points beyond the ground disk of ``max_range_m`` slant range (and rays above the horizon)
    are moved onto the disk's circle along their azimuth. Empty (0, 2) when no border ray nor
    the optical axis reaches the ground, or when the camera is at or below the ground or
    higher than ``max_range_m`` above it.
    """
    return footprint_rings_enu(camera, pose, max_range_m, (0.0,)).rings[0]


@dataclass(frozen=True, slots=True)
class FootprintRings:
    """``footprint_ring_enu`` on several ground planes; clipped: whether any border point
    was moved onto its plane's range circle (the picture reaches beyond the range)."""

    rings: list[np.ndarray]
    clipped: bool


def footprint_rings_enu(camera: CameraModel, pose: CameraPose, max_range_m: float,
                        ground_z_m: tuple[float, ...]) -> FootprintRings:
    """``footprint_ring_enu`` on each of the ground planes z = ground_z_m (m, ENU)."""
    return BorderRaysEnu.of(camera, pose).rings(max_range_m, ground_z_m)


@dataclass(frozen=True, slots=True)
class BorderRaysEnu:
    """One frame's rays through the picture's border: directions ``d_enu`` (M, 3, ENU) from
    the camera at ``pose``; ``looks_down``: some reach the ground. Per frame, the extents of
    the footprints on several level planes (``extent_enu``) share them."""

    pose: CameraPose
    d_enu: np.ndarray
    looks_down: bool
    _all_down: bool = field(repr=False)
    # Horizontal offsets per metre of descent along the rays (x, y: lowest and highest; the
    # largest horizontal length), meaningful when all look down.
    _per_m_descent: tuple[float, float, float, float, float] = field(repr=False)

    @classmethod
    def of(cls, camera: CameraModel, pose: CameraPose) -> BorderRaysEnu:
        d = camera.border_rays_cam @ pose.R_enu_cam.T
        looks_down = not (pose.R_enu_cam[2, 2] >= 0 and d[:, 2].min() >= -_HORIZON_EPS)
        all_down = bool(d[:, 2].max() < -_HORIZON_EPS)
        per_m = (0.0,) * 5
        if all_down:
            u, v = d[:, 0] / -d[:, 2], d[:, 1] / -d[:, 2]
            per_m = (float(u.min()), float(u.max()), float(v.min()), float(v.max()),
                     float((np.hypot(d[:, 0], d[:, 1]) / -d[:, 2]).max()))
        return cls(pose, d, looks_down, all_down, per_m)

    def rings(self, max_range_m: float, ground_z_m: tuple[float, ...]) -> FootprintRings:
        """``footprint_ring_enu`` on each of the ground planes z = ground_z_m (m, ENU)."""
        d, pose = self.d_enu, self.pose
        rings = []
        clipped = False
        for z in ground_z_m:
            rho_max = ground_range_m(pose, max_range_m, z)
            if rho_max <= 0 or not self.looks_down:
                rings.append(np.empty((0, 2)))
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                # Ray parameter to the ground, at most to the disk's circle:
                # min(h / -d_z, rho / |d_xy|).
                t = np.where(d[:, 2] < -_HORIZON_EPS, (pose.r_cam_enu[2] - z) / -d[:, 2],
                             np.inf)
                t_circle = rho_max / np.hypot(d[:, 0], d[:, 1])
            clipped = clipped or bool((t_circle < t).any())
            np.minimum(t, t_circle, out=t)
            t[t == np.inf] = 0.0  # straight up: no horizontal direction to follow
            rings.append(pose.r_cam_enu[:2] + d[:, :2] * t[:, None])
        return FootprintRings(rings, clipped)

    def extent_enu(self, max_range_m: float, ground_z_m: float
                   ) -> tuple[tuple[float, float, float, float] | None, bool]:
        """(x_min, x_max, y_min, y_max) (m, ENU) of ``footprint_ring_enu`` on the plane z =
        ground_z_m (None: the ring is empty), and whether it is clipped to the range circle.
        When every ray looks down and none reaches the circle, each ring point is the nadir
        point plus the height above the plane times the ray's offset per metre of descent,
        so the extent is that of the offsets: no ring is built."""
        rho_max = ground_range_m(self.pose, max_range_m, ground_z_m)
        if rho_max <= 0 or not self.looks_down:
            return None, False
        h = float(self.pose.r_cam_enu[2]) - ground_z_m
        u_lo, u_hi, v_lo, v_hi, w_max = self._per_m_descent
        if self._all_down and rho_max > h * w_max * (1.0 + 1e-9):
            cx, cy = (float(v) for v in self.pose.r_cam_enu[:2])
            return (cx + h * u_lo, cx + h * u_hi, cy + h * v_lo, cy + h * v_hi), False
        found = self.rings(max_range_m, (ground_z_m,))
        ring = found.rings[0]
        return ((float(ring[:, 0].min()), float(ring[:, 0].max()), float(ring[:, 1].min()),
                 float(ring[:, 1].max())), found.clipped)


def footprint_polygon(camera: CameraModel, pose: CameraPose, max_range_m: float) -> Polygon:
    """The ground footprint as a shapely polygon in ENU metres (empty when nothing is seen)."""
    ring = footprint_ring_enu(camera, pose, max_range_m)
    if len(ring) < 3:
        return Polygon()
    poly = shapely.make_valid(Polygon(ring))
    disk = shapely.Point(pose.r_cam_enu[:2]).buffer(ground_range_m(pose, max_range_m),
                                                     quad_segs=64)
    poly = poly.intersection(disk)
    if poly.geom_type != "Polygon":
        parts = [g for g in getattr(poly, "geoms", []) if g.geom_type == "Polygon"]
        poly = max(parts, key=lambda g: g.area) if parts else Polygon()
    return poly


def pixel_grid_rays(camera: CameraModel, step_px: int = 1) -> np.ndarray:
    """Unit rays (N, 3) float32 in the optical frame through every ``step_px``-th pixel
    centre, row by row."""
    xs = np.arange(0, camera.width_px, step_px, dtype=np.float64)
    ys = np.arange(0, camera.height_px, step_px, dtype=np.float64)
    out = np.empty((len(xs) * len(ys), 3), dtype=np.float32)
    rows_per_chunk = max(1, 2_000_000 // len(xs))
    for i in range(0, len(ys), rows_per_chunk):
        X, Y = np.meshgrid(xs, ys[i:i + rows_per_chunk])
        px = np.stack([X.ravel(), Y.ravel()], axis=1)
        out[i * len(xs):i * len(xs) + len(px)] = camera.pixel_rays(px)
    return out


def ray_count_map(rays_cam: np.ndarray, pose: CameraPose, geometry: GridGeometry,
                  max_range_m: float = math.inf) -> np.ndarray:
    """Fig. 5: for each cell, the number of pixel rays meeting the ground inside it.

    rays_cam: (N, 3) rays in the optical frame (``pixel_grid_rays``). Returns int64
    (n_rows, n_cols). A ray counts where it meets the ground at t > 0 within
    ``max_range_m`` of the camera.
    """
    counts = np.zeros(geometry.shape, dtype=np.int64)
    R = pose.R_enu_cam.astype(np.float32)
    r = pose.r_cam_enu
    chunk = 1_000_000
    for i in range(0, len(rays_cam), chunk):
        d = rays_cam[i:i + chunk] @ R.T
        down = d[:, 2] < -_HORIZON_EPS
        d = d[down].astype(np.float64)
        t = -r[2] / d[:, 2]
        keep = (t > 0) & (t <= max_range_m)
        x = r[0] + t[keep] * d[keep, 0]
        y = r[1] + t[keep] * d[keep, 1]
        row, col = geometry.cell_of(x, y)
        inside = (row >= 0) & (row < geometry.n_rows) & (col >= 0) & (col < geometry.n_cols)
        flat = row[inside] * geometry.n_cols + col[inside]
        counts += np.bincount(flat, minlength=counts.size).reshape(geometry.shape)
    return counts
