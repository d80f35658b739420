"""R3: the per-pixel DEM ray caster, the terrain truth that pdcov's terrain kernel is judged by.

It shares nothing with pdcov's coverage kernel or its DEM reader: only the camera's pixel
rays (OpenCV's undistortion, as R1), its projection (OpenCV's ``projectPoints``, to decide
which cell centres lie in the picture) and the detector model's tables.

* The ground is a heightfield: heights on a regular ENU lattice, bilinear between, read
  from the DEM file with rasterio (any CRS; bilinear in the raster) and placed in ENU with
  pymap3d, Earth's curvature included.
* Each frame casts every ``step_px``-th pixel's ray into it. The march steps by the
  largest distance that provably cannot cross the surface (the gap above the ground over
  the rate at which the gap can close, from the surface's slope bound) but never less than
  a quarter of the lattice spacing, and refines the first sign change by bisection. A ray's
  first hit is where its pixel sees the ground; a cell is observed when at least one ray's
  first hit within the slant range lands in it, and its image area is the number of such
  rays times ``step_px**2`` pixels (R1's rule on the terrain).
* Occlusion truth, per frame: every free cell whose centre (on the surface) is in the
  picture and within the slant range is cast to; its line of sight is blocked when the ray
  from the camera meets the ground more than ``LOS_TOLERANCE_M`` before the centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
import rasterio
import rasterio.warp
from rasterio.crs import CRS
from scipy.ndimage import map_coordinates

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.pose import CameraPose
from tests.support.references import ReferenceGrid

MIN_STEP_OF_SPACING = 0.25   # the march's smallest step, in lattice spacings
BISECTIONS = 8               # a quarter spacing of 1 m refined to 1 mm
LOS_TOLERANCE_M = 0.05       # a line of sight may graze the ground this far before the centre
CHUNK_RAYS = 1 << 16


@dataclass(frozen=True)
class Heightfield:
    """Ground heights (m, ENU z) on a lattice: ``z_m[i, j]`` at x = x0_m + j spacing_m,
    y = y0_m + i spacing_m (row 0 south); bilinear between, NaN outside.

    slope_bound: an upper bound of the surface's gradient norm (dimensionless).
    """

    x0_m: float
    y0_m: float
    spacing_m: float
    z_m: np.ndarray
    slope_bound: float

    @classmethod
    def from_array(cls, x0_m: float, y0_m: float, spacing_m: float,
                   z_m: np.ndarray) -> Heightfield:
        z = np.asarray(z_m, dtype=np.float64)
        if not np.isfinite(z).all():
            raise ValueError("heightfield: heights must be finite (the DEM has holes there)")
        # Inside a lattice cell the bilinear gradient's x part lies between the slopes of
        # its south and north edges, its y part between those of its west and east edges.
        gx = np.abs(np.diff(z, axis=1)).max(initial=0.0) / spacing_m
        gy = np.abs(np.diff(z, axis=0)).max(initial=0.0) / spacing_m
        return cls(x0_m, y0_m, spacing_m, z, float(np.hypot(gx, gy)))

    @classmethod
    def from_dem(cls, path: Path, origin_lat_deg: float, origin_lon_deg: float,
                 ground_alt_msl_m: float, extent_enu_m: tuple[float, float, float, float],
                 spacing_m: float) -> Heightfield:
        """Sample the DEM (heights MSL) on a lattice over ``extent_enu_m`` (x_min, y_min,
        x_max, y_max) about the origin whose ground is at ``ground_alt_msl_m``."""
        x_min, y_min, x_max, y_max = extent_enu_m
        xs = np.arange(x_min, x_max + 0.5 * spacing_m, spacing_m)
        ys = np.arange(y_min, y_max + 0.5 * spacing_m, spacing_m)
        X, Y = np.meshgrid(xs, ys)
        with rasterio.open(path) as src:
            alt = src.read(1, masked=True).astype(np.float64).filled(np.nan)
            crs, to_pixel = src.crs, ~src.transform
        # Find z with the point (x, y, z)'s height equal to the DEM's there: the geodetic
        # height of an ENU point moves with z at a rate of 1 (to 1e-4 over a few km).
        z = np.zeros_like(X)
        for _ in range(3):
            lat, lon, h = pymap3d.enu2geodetic(X, Y, z, origin_lat_deg, origin_lon_deg,
                                               ground_alt_msl_m)
            east, north = rasterio.warp.transform(CRS.from_epsg(4326), crs, lon.ravel(),
                                                  lat.ravel())
            col, row = to_pixel @ (np.asarray(east), np.asarray(north))
            dem = map_coordinates(alt, [row - 0.5, col - 0.5], order=1, mode="constant",
                                  cval=np.nan)  # pixel centres at (row + 0.5, col + 0.5)
            z = z + dem.reshape(X.shape) - h
        if not np.isfinite(z).all():
            raise ValueError(f"{path}: the DEM does not cover ENU {extent_enu_m} "
                             f"(or has nodata there)")
        return cls.from_array(float(xs[0]), float(ys[0]), spacing_m, z)

    @property
    def z_range_m(self) -> tuple[float, float]:
        return float(self.z_m.min()), float(self.z_m.max())

    def height_m(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Bilinear heights (m) at ENU points; NaN outside the lattice."""
        n_rows, n_cols = self.z_m.shape
        u = (np.asarray(x_m, dtype=np.float64) - self.x0_m) / self.spacing_m
        v = (np.asarray(y_m, dtype=np.float64) - self.y0_m) / self.spacing_m
        with np.errstate(invalid="ignore"):
            inside = (u >= 0) & (u <= n_cols - 1) & (v >= 0) & (v <= n_rows - 1)
        j = np.minimum(np.floor(np.where(inside, u, 0.0)), n_cols - 2)
        i = np.minimum(np.floor(np.where(inside, v, 0.0)), n_rows - 2)
        fu, fv = u - j, v - i
        k = i.astype(np.intp) * n_cols + j.astype(np.intp)
        # The four corners, each gathered from the lattice shifted by its offset.
        z = self.z_m.ravel()
        sw, se, nw, ne = z[k], z[1:][k], z[n_cols:][k], z[n_cols + 1:][k]
        south = sw + fu * (se - sw)
        north = nw + fu * (ne - nw)
        return np.where(inside, south + fv * (north - south), np.nan)

    def first_hit_t(self, r_enu: np.ndarray, d_enu: np.ndarray, t_max_m: np.ndarray | float
                    ) -> np.ndarray:
        """Distance (m) along each unit ray ``r_enu + t d_enu`` (d_enu (N, 3)) to its first
        crossing of the surface, if at most ``t_max_m``; inf for rays that miss it by then
        or leave the lattice first."""
        d = np.asarray(d_enu, dtype=np.float64)
        t_max = np.broadcast_to(np.asarray(t_max_m, dtype=np.float64), (len(d),))
        out = np.full(len(d), np.inf)
        for k in range(0, len(d), CHUNK_RAYS):
            out[k:k + CHUNK_RAYS] = self._march(r_enu, d[k:k + CHUNK_RAYS],
                                                t_max[k:k + CHUNK_RAYS])
        return out

    def _gap_m(self, r: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Height (m) of the ray points above the ground (NaN off the lattice)."""
        return self._gap_xyz_m(r, d[:, 0], d[:, 1], d[:, 2], t)

    def _gap_xyz_m(self, r: np.ndarray, dx: np.ndarray, dy: np.ndarray, dz: np.ndarray,
                   t: np.ndarray) -> np.ndarray:
        """``_gap_m`` with the directions' components as separate (contiguous) arrays."""
        return r[2] + t * dz - self.height_m(r[0] + t * dx, r[1] + t * dy)

    def _march(self, r: np.ndarray, d: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        z_lo, z_hi = self.z_range_m
        down = d[:, 2] < 0
        with np.errstate(divide="ignore"):
            # Start where the ray comes down to the highest ground; stop at t_max, or a metre
            # below the lowest ground (it has crossed by then).
            t0 = np.where(down, np.maximum(0.0, (r[2] - z_hi) / -d[:, 2]),
                          0.0 if r[2] <= z_hi else np.inf)
            t_end = np.minimum(t_max, np.where(down, (r[2] - z_lo + 1.0) / -d[:, 2], np.inf))
        # Along the ray the gap above the ground closes at most this fast (m per m).
        closing = np.maximum(-d[:, 2] + self.slope_bound * np.hypot(d[:, 0], d[:, 1]), 1e-9)
        min_step = MIN_STEP_OF_SPACING * self.spacing_m
        idx = np.flatnonzero(t0 <= t_end)
        # The marching rays' own copies, kept as short as the rays still marching.
        t, dx, dy, dz = t0[idx], d[idx, 0], d[idx, 1], d[idx, 2]
        closing, t_end = closing[idx], t_end[idx]
        t_prev = t
        gap = self._gap_xyz_m(r, dx, dy, dz, t)
        found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        while len(idx):
            crossed = gap <= 0  # (a ray starting below the ground crosses at t0)
            if crossed.any():
                found.append((idx[crossed], t_prev[crossed], t[crossed]))
            going = ~crossed & np.isfinite(gap) & (t < t_end)
            idx, t, gap = idx[going], t[going], gap[going]
            dx, dy, dz, closing, t_end = (a[going] for a in (dx, dy, dz, closing, t_end))
            t_prev = t
            t = np.minimum(t + np.maximum(gap / closing, min_step), t_end)
            gap = self._gap_xyz_m(r, dx, dy, dz, t)
        out = np.full(len(d), np.inf)
        if found:
            idx, lo, hi = (np.concatenate(a) for a in zip(*found, strict=True))
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                below = self._gap_m(r, d[idx], mid) <= 0
                hi = np.where(below, mid, hi)
                lo = np.where(below, lo, mid)
            out[idx] = hi
        return out


class TerrainReferenceGrid(ReferenceGrid):
    """R1's sums over the terrain, and the occlusion truth per cell: ``n_clear`` / ``n_blocked``
    count the frames that had the cell's centre in the picture and within range with its line
    of sight clear / blocked by the ground. centres_enu_m: (n_rows, n_cols, 3) the cells'
    centres on the heightfield (ENU m)."""

    def __init__(self, geometry: GridGeometry, mask: np.ndarray, camera: CameraModel,
                 detector: DetectorModel, max_range_m: float, heightfield: Heightfield,
                 step_px: int) -> None:
        super().__init__(geometry, mask, camera, detector, max_range_m)
        self.heightfield = heightfield
        self.step_px = step_px
        self.n_clear = np.zeros(geometry.shape, dtype=np.int32)
        self.n_blocked = np.zeros(geometry.shape, dtype=np.int32)
        xs, ys = geometry.centres_enu()
        X, Y = np.meshgrid(xs, ys)
        self.centres_enu_m = np.stack([X, Y, heightfield.height_m(X, Y)], axis=-1)
        if not np.isfinite(self.centres_enu_m[mask]).all():
            raise ValueError("the heightfield does not cover the grid's free cells")

    @property
    def hidden(self) -> np.ndarray:
        """Free cells whose centre was in some frame's picture and range, always blocked."""
        return self.mask & (self.n_blocked > 0) & (self.n_clear == 0)


def r3_update(ref: TerrainReferenceGrid, rays_cam: np.ndarray, pose: CameraPose) -> None:
    """R3: cast ``rays_cam`` (``pixel_rays(camera, ref.step_px)``) into the terrain, count
    first hits per cell; then the lines of sight to the cell centres in the picture."""
    g, hf, cam = ref.geometry, ref.heightfield, ref.camera
    r = np.asarray(pose.r_cam_enu, dtype=np.float64)
    d = rays_cam.astype(np.float64) @ pose.R_enu_cam.T
    t = hf.first_hit_t(r, d, ref.max_range_m)
    hit = np.isfinite(t)
    p = r + t[hit, None] * d[hit]
    col = np.floor((p[:, 0] - g.x0_m) / g.cell_size_m).astype(np.int64)
    row = np.floor((p[:, 1] - g.y0_m) / g.cell_size_m).astype(np.int64)
    inside = (row >= 0) & (row < g.n_rows) & (col >= 0) & (col < g.n_cols)
    counts = np.bincount(row[inside] * g.n_cols + col[inside],
                         minlength=g.n_rows * g.n_cols).reshape(g.shape)
    observed = ref.mask & (counts > 0)
    ref.add(observed, counts[observed] * float(ref.step_px**2))

    # Lines of sight to the free cells' centres within range and in the picture.
    v = ref.centres_enu_m - r
    dist = np.sqrt(np.einsum("...i,...i->...", v, v))
    near = ref.mask & (dist <= ref.max_range_m)
    rows, cols = np.nonzero(near)
    u = v[rows, cols] / dist[rows, cols, None]
    u_cam = u @ pose.R_enu_cam
    front = u_cam[:, 2] > 0
    rows, cols, u, u_cam = rows[front], cols[front], u[front], u_cam[front]
    px = cam.project(u_cam)
    x, y = px[:, 0], px[:, 1]
    in_pic = (x >= -0.5) & (x < cam.width_px - 0.5) & (y >= -0.5) & (y < cam.height_px - 0.5)
    # Beyond the calibrated field of view a distortion polynomial can fold directions back
    # into the picture: keep only pixels whose own ray is the direction projected.
    back = np.zeros((len(px), 3))
    back[in_pic] = cam.pixel_rays(px[in_pic])
    in_pic &= np.einsum("ij,ij->i", back, u_cam) > 1.0 - 1e-8
    rows, cols, u = rows[in_pic], cols[in_pic], u[in_pic]
    blocked = np.isfinite(hf.first_hit_t(r, u, dist[rows, cols] - LOS_TOLERANCE_M))
    ref.n_blocked[rows[blocked], cols[blocked]] += 1
    ref.n_clear[rows[~blocked], cols[~blocked]] += 1
