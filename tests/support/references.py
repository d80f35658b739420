"""The two straightforward ways to compute the grid that ``CoverageGrid.update`` computes.

R1, per-pixel ray casting (the paper's Fig. 5): every pixel's ray meets the ground; a cell is
observed when at least one ray lands in it, and its apparent area is the number of rays that
do. R2, per-cell projection of the whole domain every frame, no incremental window: every
cell centre is tested (in range, in the calibrated field of view, projected with OpenCV's
``projectPoints`` into the picture) and every observed cell's corners are projected; a cell
wholly in the picture takes its corners' quadrilateral area, one straddling the picture's
edge the area of that quadrilateral clipped to the picture (shapely). Both accumulate the
same log-miss sums as pdcov, in float64. R3, R1 over a DEM, is in ``terrain_reference``.
"""

from __future__ import annotations

import numpy as np
import shapely

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.pose import CameraPose


class ReferenceGrid:
    """Log-miss sums (float64) and look counts over ``geometry``'s free cells (``mask``)."""

    def __init__(self, geometry: GridGeometry, mask: np.ndarray, camera: CameraModel,
                 detector: DetectorModel, max_range_m: float) -> None:
        self.geometry = geometry
        self.mask = mask
        self.camera = camera
        self.detector = detector
        self.max_range_m = max_range_m
        self.size_scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
        self.log_miss_d = np.zeros(geometry.shape)
        self.n_obs = np.zeros(geometry.shape, dtype=np.int32)
        self.not_comparable = 0   # R2: observed cells with a corner beyond trustworthy projection

    @property
    def pd(self) -> np.ndarray:
        return -np.expm1(self.log_miss_d)

    def add(self, observed: np.ndarray, area_px2: np.ndarray) -> None:
        """Add one frame: ``observed`` (n_rows, n_cols) and the image area (px^2) of each
        observed cell, in row-major order."""
        pd, _ = self.detector.lookup(np.sqrt(area_px2) * self.size_scale)
        with np.errstate(divide="ignore"):
            self.log_miss_d[observed] += np.log1p(-pd)
        self.n_obs[observed] += 1


def pixel_rays(camera: CameraModel, step_px: int = 1) -> np.ndarray:
    """Unit rays (N, 3) float32 (optical frame), through every pixel centre (``step_px`` 1)
    or through the centre of every whole block of ``step_px`` x ``step_px`` pixels, each
    then standing for ``step_px**2`` pixels; row-major."""
    half = (step_px - 1) / 2
    ys, xs = np.mgrid[0:camera.height_px // step_px, 0:camera.width_px // step_px]
    px = np.column_stack([xs.ravel(), ys.ravel()]) * float(step_px) + half
    return camera.pixel_rays(px).astype(np.float32)


def r1_update(ref: ReferenceGrid, rays_cam: np.ndarray, pose: CameraPose) -> None:
    """R1: cast every pixel's ray (``pixel_rays``) to the ground and count rays per cell."""
    g = ref.geometry
    d = rays_cam @ pose.R_enu_cam.T.astype(np.float32)
    d = d[d[:, 2] < 0].astype(np.float64)
    r = pose.r_cam_enu
    t = -r[2] / d[:, 2]
    near = t <= ref.max_range_m
    col = np.floor((r[0] + t[near] * d[near, 0] - g.x0_m) / g.cell_size_m).astype(np.int64)
    row = np.floor((r[1] + t[near] * d[near, 1] - g.y0_m) / g.cell_size_m).astype(np.int64)
    inside = (row >= 0) & (row < g.n_rows) & (col >= 0) & (col < g.n_cols)
    counts = np.bincount(row[inside] * g.n_cols + col[inside], minlength=g.n_rows * g.n_cols)
    counts = counts.reshape(g.shape)
    observed = ref.mask & (counts > 0)
    ref.add(observed, counts[observed].astype(np.float64))


def r2_update(ref: ReferenceGrid, pose: CameraPose) -> None:
    """R2: project every cell of the domain (centres, then the observed cells' corners)."""
    g = ref.geometry
    cam = ref.camera
    xs, ys = g.centres_enu()
    X, Y = np.meshgrid(xs, ys)
    p_enu = np.stack([X, Y, np.zeros_like(X)], axis=-1).reshape(-1, 3)
    p_cam = (p_enu - pose.r_cam_enu) @ pose.R_enu_cam
    observed = (ref.mask.ravel() & (np.einsum("ij,ij->i", p_cam, p_cam) <= ref.max_range_m**2)
                & cam.in_fov(p_cam))
    idx = np.flatnonzero(observed)
    observed[idx] = cam.in_picture(cam.project(p_cam[idx]))
    observed = observed.reshape(g.shape)
    rows, cols = np.nonzero(observed)
    # Corners (row, col), (row, col + 1), (row + 1, col + 1), (row + 1, col) of each cell.
    cs = g.cell_size_m
    cx = g.x0_m + cs * (cols[:, None] + np.array([0, 1, 1, 0]))
    cy = g.y0_m + cs * (rows[:, None] + np.array([0, 0, 1, 1]))
    c_enu = np.stack([cx, cy, np.zeros_like(cx)], axis=-1).reshape(-1, 3)
    c_cam = (c_enu - pose.r_cam_enu) @ pose.R_enu_cam
    ok = cam.projectable(c_cam).reshape(-1, 4).all(axis=1)
    quads = np.full((len(rows) * 4, 2), np.nan)
    rep = np.repeat(ok, 4)
    quads[rep] = cam.project(c_cam[rep])
    quads = quads.reshape(-1, 4, 2)
    picture = shapely.box(-0.5, -0.5, cam.width_px - 0.5, cam.height_px - 0.5)
    area = np.full(len(rows), np.nan)
    if ok.any():
        polys = shapely.polygons(np.concatenate([quads[ok], quads[ok][:, :1]], axis=1))
        area[ok] = shapely.area(shapely.intersection(shapely.make_valid(polys), picture))
    ref.not_comparable += int((~ok).sum())
    keep = ok
    sel = np.zeros(g.shape, dtype=bool)
    sel[rows[keep], cols[keep]] = True
    ref.add(sel, area[keep])
