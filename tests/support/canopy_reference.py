"""R4: the per-pixel forward ray caster through terrain and ground cover, the truth that
pdcov's canopy/building kernel is judged by (tests/integration/test_canopy_agreement.py).

It shares nothing with pdcov's coverage kernel, its cover traversal (core/ground_cover.py)
or its occlusion test (core/occlusion.py): only the camera's pixel rays and projection
(OpenCV, ``CameraModel``), the terrain's bilinear height (``TerrainSurface.height_m``), the
cover's arrays (``GroundCover.height_m``, ``kind``, ``extinction_per_m``) and the detector
model's table (``DetectorModel.lookup``).

The scene (ENU metres): the ground is the bilinear surface through the cells' corner
heights; on a raised cell stands a vertical prism over its square, from the ground up to
its top, the cell centre's ground height (the mean of its corners) plus ``height_m``.

* Each frame casts ``rays_per_side``^2 rays per pixel, one through a random point of each
  of the equal squares it is split into (``sub_pixel_rays``; each ray then stands for
  1 / rays_per_side^2 px^2), forward from the camera. A ray's first crossing of
  the ground is found by marching: steps of the largest length that provably cannot cross
  the surface (its height above the ground over the rate at which that can close, from the
  surface's slope bound), never less than ``step_of_cell`` of a cell, the crossing refined
  by bisection. The cell of that point is where the pixel sees the ground.
* Along the ray, from where it comes down to the highest top to its ground point, it is
  sampled at the midpoints of steps of ``step_of_cell`` of a cell: a sample below the top of
  a FOLIAGE prism adds the step's length to the ray's length in foliage L, one below the
  top of a SOLID prism blocks the ray. Stretches that provably meet no prism are skipped:
  farther horizontally from every raised cell than the stretch is long (a distance
  transform), or above every top within ``WINDOW_CELLS`` cells while moving less than that.
  A ray's transmittance is 0 when blocked, else exp(-k L).
* Per cell: the rays landing in it give its image area (their count times a ray's px^2)
  and its transmittance (their mean). It is observed when its centre (on the ground) is in
  front of the camera, in the calibrated field of view, projects into the picture, lies
  within the maximum slant range, is not hidden by the ground (the line of sight to it
  meets the ground before it comes within half a cell of the centre horizontally), and at
  least one ray lands in it. Its P_D is the detector's P_D at its apparent size (the
  square root of its image area, scaled to detector-input pixels) times its
  transmittance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt, maximum_filter

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.ground_cover import CoverKind
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface

STEP_OF_CELL = 1.0 / 20.0  # the march's fine step, in cells
BISECTIONS = 16            # a fine step of 5 cm refined to 1 um
WINDOW_CELLS = 8           # the half-width of the window of the tops' running maximum
CHUNK_RAYS = 1 << 14      # rays marched at once (their blocks of fine steps stay in cache)
FINE_STEPS_PER_BLOCK = 16  # fine steps taken at once where a ray is near cover


def sub_pixel_rays(camera: CameraModel, rays_per_side: int, seed: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (N, 3) in the optical frame through ``rays_per_side``^2 points per pixel
    (N = width x height x rays_per_side^2, row-major by pixel), one in each of the
    rays_per_side x rays_per_side squares a pixel is split into, and the points' pixel
    coordinates (N, 2). ``seed`` None: the squares' centres; else a point drawn uniformly
    in each square (stratified jitter): a regular lattice aliases with cell edges that run
    along it (a square cell of 4.9 px sides holds 9 x 9 or 10 x 10 points of a 0.5 px
    lattice, 20 % apart), random points count its area without that bias."""
    n = rays_per_side
    sub = (np.arange(n) + 0.5) / n - 0.5
    u = (np.arange(camera.width_px)[:, None] + sub[None, :]).ravel()
    v = (np.arange(camera.height_px)[:, None] + sub[None, :]).ravel()
    U, V = np.meshgrid(u, v)
    px = np.column_stack([U.ravel(), V.ravel()])
    if seed is not None:
        px += np.random.default_rng(seed).uniform(-0.5 / n, 0.5 / n, px.shape)
    return camera.pixel_rays(px), px


@dataclass(frozen=True)
class CanopyLook:
    """One frame of the reference, per cell (n_rows, n_cols).

    rays: rays landing on the cell's ground; area_px2: their image area (px^2);
    transmittance: their mean transmittance (NaN without rays); centre_px: the pixel of the
    cell centre (NaN where not in front and in the field of view); in_view: centre in
    front, in the calibrated field of view and in the picture; in_range: centre within the
    maximum slant range; hidden: the ground hides the centre (only tested in view and in
    range); observed: all of these and at least one ray; pd: P_D of the look (0 where not
    observed)."""

    rays: np.ndarray
    area_px2: np.ndarray
    transmittance: np.ndarray
    centre_px: np.ndarray
    in_view: np.ndarray
    in_range: np.ndarray
    hidden: np.ndarray
    observed: np.ndarray
    pd: np.ndarray


class CanopyReference:
    """The forward ray caster over ``terrain`` (and its ``cover``) for ``camera`` and
    ``detector``; cells beyond ``max_range_m`` slant range are not observed.
    rays_per_side: rays per pixel side; step_of_cell: the fine step, in cells;
    jitter_seed: the seed of the rays' points in their pixels (None: a regular lattice)."""

    def __init__(self, terrain: TerrainSurface, camera: CameraModel, detector: DetectorModel,
                 max_range_m: float, rays_per_side: int = 2,
                 step_of_cell: float = STEP_OF_CELL, jitter_seed: int | None = 0) -> None:
        g = terrain.geometry
        self.terrain = terrain
        self.geometry = g
        self.camera = camera
        self.detector = detector
        self.max_range_m = float(max_range_m)
        self.cell_m = cs = g.cell_size_m
        self.step_m = step_of_cell * cs
        self.size_scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
        z = np.asarray(terrain.z_corner_m, dtype=np.float64)
        self.centre_z_m = 0.25 * (z[:-1, :-1] + z[:-1, 1:] + z[1:, :-1] + z[1:, 1:])
        self.ground_lo_m, self.ground_hi_m = float(z.min()), float(z.max())
        # A bilinear patch's gradient lies between its edges' slopes along x and along y.
        g_x = np.abs(np.diff(z, axis=1)).max(initial=0.0) / cs
        g_y = np.abs(np.diff(z, axis=0)).max(initial=0.0) / cs
        self.slope_bound = float(math.hypot(g_x, g_y))
        cover = terrain.cover
        if cover is None:
            height, kind, self.extinction_per_m = np.zeros(g.shape), np.zeros(g.shape), 0.0
        else:
            height, kind = np.asarray(cover.height_m, float), np.asarray(cover.kind)
            self.extinction_per_m = float(cover.extinction_per_m)
        raised = (height > 0) & (kind != CoverKind.OPEN)
        self.top_z_m = np.where(raised, self.centre_z_m + height, -np.inf)
        self.solid = raised & (kind == CoverKind.SOLID)
        self.foliage = raised & (kind == CoverKind.FOLIAGE)
        self.top_max_m = float(self.top_z_m.max()) if raised.any() else -np.inf
        # Flat tables of the foliage and solid tops (ENU z, m; -inf: none) with a border of
        # one cell of -inf all round, for points off the grid (``_flat_cell``).
        self._top_foliage = np.pad(np.where(self.foliage, self.top_z_m, -np.inf), 1,
                                   constant_values=-np.inf).ravel()
        self._top_solid = np.pad(np.where(self.solid, self.top_z_m, -np.inf), 1,
                                 constant_values=-np.inf).ravel()
        # How far (m) every point of a cell is from every raised cell's square: the centres'
        # distance less a diagonal (half of each cell's); inf without any.
        if raised.any():
            d = distance_transform_edt(~raised) * cs - math.sqrt(2.0) * cs
            self.clear_m = np.maximum(d, 0.0)
        else:
            self.clear_m = np.full(g.shape, np.inf)
        self.top_near_z_m = maximum_filter(self.top_z_m, size=2 * WINDOW_CELLS + 1,
                                           mode="constant", cval=-np.inf)
        self.rays_cam, self.rays_px = sub_pixel_rays(camera, rays_per_side, jitter_seed)
        self.ray_area_px2 = 1.0 / rays_per_side**2

    # -- one frame --------------------------------------------------------------------------

    def look(self, pose: CameraPose) -> CanopyLook:
        """Cast every sub-pixel ray of a frame at ``pose`` and judge every cell."""
        g = self.geometry
        r = np.asarray(pose.r_cam_enu, dtype=np.float64)
        rays = np.zeros(g.n_rows * g.n_cols)
        t_sum = np.zeros(g.n_rows * g.n_cols)
        for k in range(0, len(self.rays_cam), CHUNK_RAYS):
            d = self.rays_cam[k:k + CHUNK_RAYS] @ pose.R_enu_cam.T
            t, on_ground = self.ground_hit(r, d)
            land = np.flatnonzero(on_ground)
            p = r + t[land, None] * d[land]
            row, col = self._cell_of(p[:, 0], p[:, 1])
            inside = (row >= 0) & (row < g.n_rows) & (col >= 0) & (col < g.n_cols)
            land, row, col = land[inside], row[inside], col[inside]
            trans = self.transmittance(r, d[land], t[land])
            flat = row * g.n_cols + col
            rays += np.bincount(flat, minlength=len(rays))
            t_sum += np.bincount(flat, weights=trans, minlength=len(rays))
        rays = rays.reshape(g.shape)
        with np.errstate(invalid="ignore", divide="ignore"):
            trans_mean = np.where(rays > 0, t_sum.reshape(g.shape) / rays, np.nan)
        area = rays * self.ray_area_px2
        centre_px, in_view, in_range, hidden = self._centres(pose)
        observed = in_view & in_range & ~hidden & (rays > 0)
        p_det, _ = self.detector.lookup(np.sqrt(area) * self.size_scale)
        pd = np.where(observed, p_det * np.nan_to_num(trans_mean), 0.0)
        return CanopyLook(rays, area, trans_mean, centre_px, in_view, in_range, hidden,
                          observed, pd)

    def _cell_of(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = self.geometry
        return (np.floor((y_m - g.y0_m) / self.cell_m).astype(np.int64),
                np.floor((x_m - g.x0_m) / self.cell_m).astype(np.int64))

    def _centres(self, pose: CameraPose
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per cell: its centre's pixel, and whether it is in view, in range and hidden."""
        g, cam = self.geometry, self.camera
        xs, ys = g.centres_enu()
        X, Y = np.meshgrid(xs, ys)
        r = np.asarray(pose.r_cam_enu, dtype=np.float64)
        v = np.stack([X, Y, self.centre_z_m], axis=-1) - r
        dist = np.sqrt(np.einsum("...i,...i->...", v, v))
        p_cam = v @ pose.R_enu_cam
        front = (p_cam[..., 2] > 0) & cam.in_fov(p_cam)
        centre_px = np.full((*g.shape, 2), np.nan)
        centre_px[front] = cam.project(p_cam[front])
        in_view = front & cam.in_picture(np.nan_to_num(centre_px, nan=-1e9))
        in_range = dist <= self.max_range_m
        hidden = np.zeros(g.shape, dtype=bool)
        rows, cols = np.nonzero(in_view & in_range)
        if len(rows):
            u = v[rows, cols] / dist[rows, cols, None]
            rho = np.hypot(v[rows, cols, 0], v[rows, cols, 1])
            # The line of sight may meet the ground within half a cell (horizontally) of the
            # centre: that is the cell's own surface.
            with np.errstate(divide="ignore"):
                t_own = dist[rows, cols] * (1.0 - 0.5 * self.cell_m / rho)
            t, _ = self.ground_hit(r, u, t_own)
            hidden[rows, cols] = np.isfinite(t) & (t_own > 0)
        return centre_px, in_view, in_range, hidden

    # -- rays -------------------------------------------------------------------------------

    def _gap_m(self, r: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Height (m) of the points r + t d above the ground."""
        return r[2] + t * d[:, 2] - self.terrain.height_m(r[0] + t * d[:, 0], r[1] + t * d[:, 1])

    def ground_hit(self, r_enu: np.ndarray, d_enu: np.ndarray,
                   t_max_m: np.ndarray | float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distance (m) along each unit ray ``r_enu + t d_enu`` (d_enu (N, 3)) to its first
        meeting with the ground over the grid, if at most ``t_max_m`` (inf: none); and
        whether it meets the surface there (False where it enters the grid's column below
        the ground, i.e. it met the ground outside the grid)."""
        d = np.asarray(d_enu, dtype=np.float64).reshape(-1, 3)
        r = np.asarray(r_enu, dtype=np.float64)
        n = len(d)
        t_max = np.broadcast_to(np.asarray(t_max_m, dtype=np.float64), (n,))
        g = self.geometry
        x_lo, x_hi, y_lo, y_hi = g.extent_enu
        with np.errstate(divide="ignore", invalid="ignore"):
            # Where the ray's ground track is over the grid (slabs in x and y).
            t_in = np.zeros(n)
            t_out = np.full(n, np.inf)
            for axis, lo, hi in ((0, x_lo, x_hi), (1, y_lo, y_hi)):
                a = (lo - r[axis]) / d[:, axis]
                b = (hi - r[axis]) / d[:, axis]
                still = d[:, axis] == 0
                inside = (r[axis] >= lo) & (r[axis] <= hi)
                t_in = np.maximum(t_in, np.where(still, 0.0 if inside else np.inf,
                                                 np.minimum(a, b)))
                t_out = np.minimum(t_out, np.where(still, np.inf if inside else -np.inf,
                                                   np.maximum(a, b)))
            down = d[:, 2] < 0
            # From where the ray comes down to the highest ground to a metre below the
            # lowest (it has crossed by then).
            t_top = np.where(down, np.maximum(0.0, (r[2] - self.ground_hi_m) / -d[:, 2]),
                             0.0 if r[2] <= self.ground_hi_m else np.inf)
            t_bottom = np.where(down, (r[2] - self.ground_lo_m + 1.0) / -d[:, 2], np.inf)
        t0 = np.maximum(t_in, t_top)
        t_end = np.minimum(np.minimum(t_out, t_bottom), t_max)
        closing = np.maximum(-d[:, 2] + self.slope_bound * np.hypot(d[:, 0], d[:, 1]), 1e-9)
        idx = np.flatnonzero(t0 <= t_end)
        t, t_prev = t0[idx], t0[idx]
        gap = self._gap_m(r, d[idx], t)
        if np.any((t == 0) & (gap <= 0)):
            raise ValueError("the camera is below the ground")
        found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        while len(idx):
            crossed = gap <= 0
            if crossed.any():
                found.append((idx[crossed], t_prev[crossed], t[crossed]))
            going = ~crossed & (t < t_end[idx])
            idx, t, gap = idx[going], t[going], gap[going]
            t_prev = t
            t = np.minimum(t + np.maximum(gap / closing[idx], self.step_m), t_end[idx])
            gap = self._gap_m(r, d[idx], t)
        out = np.full(n, np.inf)
        on_ground = np.zeros(n, dtype=bool)
        if found:
            idx, lo, hi = (np.concatenate(a) for a in zip(*found, strict=True))
            # Crossed at the first point: entered the grid's column below the ground, unless
            # that point was where the ray came down to the highest ground.
            on_ground[idx] = (hi > lo) | (t_in[idx] < t_top[idx])
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                below = self._gap_m(r, d[idx], mid) <= 0
                hi = np.where(below, mid, hi)
                lo = np.where(below, lo, mid)
            out[idx] = hi
        return out, on_ground

    def transmittance(self, r_enu: np.ndarray, d_enu: np.ndarray, t_end_m: np.ndarray
                      ) -> np.ndarray:
        """Transmittance of each unit ray ``r_enu + t d_enu`` (d_enu (N, 3)) for t in
        [0, t_end_m] through the cover: 0 when it passes below a solid prism's top, else
        exp(-k L), L (m) its length below foliage prisms' tops."""
        d = np.asarray(d_enu, dtype=np.float64).reshape(-1, 3)
        r = np.asarray(r_enu, dtype=np.float64)
        n = len(d)
        t_end_all = np.broadcast_to(np.asarray(t_end_m, dtype=np.float64), (n,))
        out = np.ones(n)
        if not np.isfinite(self.top_max_m) or n == 0:
            return out
        length, blocked = self.cover_along(r, d, t_end_all)
        out = np.exp(-self.extinction_per_m * length)
        out[blocked] = 0.0
        return out

    def cover_along(self, r: np.ndarray, d: np.ndarray, t_end_all: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Per unit ray ``r + t d``, t in [0, t_end]: its length (m) below foliage tops
        (midpoint rule on steps of ``step_m``) and whether it passes below a solid top (at
        a step's midpoint, or at its end point: a ground point under a roof)."""
        g = self.geometry
        step, w, block = self.step_m, WINDOW_CELLS * self.cell_m, FINE_STEPS_PER_BLOCK
        n = len(d)
        length = np.zeros(n)
        blocked = np.zeros(n, dtype=bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_start = np.where(d[:, 2] < 0, np.maximum(0.0, (r[2] - self.top_max_m) / -d[:, 2]),
                               0.0 if r[2] < self.top_max_m else np.inf)
        idx = np.flatnonzero(t_start < t_end_all)
        t = t_start[idx]
        dx, dy, dz = d[idx, 0], d[idx, 1], d[idx, 2]
        h = np.hypot(dx, dy)
        t_end = t_end_all[idx]
        n_rows, n_cols = g.shape
        k_half = np.arange(block) + 0.5
        while len(idx):
            row, col = self._cell_of(r[0] + t * dx, r[1] + t * dy)
            row, col = np.clip(row, 0, n_rows - 1), np.clip(col, 0, n_cols - 1)
            with np.errstate(divide="ignore", invalid="ignore"):
                # Clear of every raised square for clear / h; or above every top of the
                # window round the cell while moving less than WINDOW_CELLS cells.
                above = r[2] + t * dz - self.top_near_z_m[row, col]
                skip = np.where(above > 0,
                                np.minimum(w / h, np.where(dz < 0, above / -dz, np.inf)), 0.0)
                skip = np.maximum(skip, self.clear_m[row, col] / h)
            fine = np.flatnonzero(~(skip >= step))
            t_next = np.minimum(t + skip, t_end)
            if len(fine):
                # ``block`` fine steps at once: midpoints m of the steps [a, b] up to t_end.
                tf, te = t[fine, None], t_end[fine, None]
                a = tf + (k_half - 0.5) * step
                dt = np.clip(np.minimum(a + step, te) - a, 0.0, None)
                m = a + 0.5 * dt
                cell = self._flat_cell(r[0] + m * dx[fine, None], r[1] + m * dy[fine, None])
                z = r[2] + m * dz[fine, None]
                length[idx[fine]] += (dt * (z < self._top_foliage[cell])).sum(axis=1)
                blocked[idx[fine]] |= ((z < self._top_solid[cell]) & (dt > 0)).any(axis=1)
                t_next[fine] = np.where(te[:, 0] - tf[:, 0] <= block * step, te[:, 0],
                                        tf[:, 0] + block * step)
            t = t_next
            going = (t < t_end) & ~blocked[idx]
            idx, t, t_end, dx, dy, dz, h = (a[going] for a in (idx, t, t_end, dx, dy, dz, h))
        # The end points themselves (ground points under a roof are never seen).
        p = r + t_end_all[:, None] * d
        ends = np.isfinite(t_end_all)
        cell = self._flat_cell(p[ends, 0], p[ends, 1])
        blocked[ends] |= p[ends, 2] < self._top_solid[cell]
        return length, blocked

    def _flat_cell(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Flat index of the cells of ENU points into the ``_top_*`` tables (points off the
        grid: its border)."""
        g = self.geometry
        row = np.clip(np.floor((y_m - g.y0_m) / self.cell_m), -1, g.n_rows) + 1
        col = np.clip(np.floor((x_m - g.x0_m) / self.cell_m), -1, g.n_cols) + 1
        return (row * (g.n_cols + 2) + col).astype(np.intp)

    def line_of_sight(self, p_enu: np.ndarray, r_cam_enu: np.ndarray) -> np.ndarray:
        """Transmittance of the lines of sight from ground points ``p_enu`` (N, 3) to a
        camera at ``r_cam_enu`` through the cover (the ground itself not tested)."""
        r = np.asarray(r_cam_enu, dtype=np.float64)
        v = np.asarray(p_enu, dtype=np.float64).reshape(-1, 3) - r
        dist = np.linalg.norm(v, axis=1)
        return self.transmittance(r, v / dist[:, None], dist)
