"""What the coverage grid needs of one camera and its detector model, computed once."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdcov.core.blur import blur_lattice_px, blur_xyz_px
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.limiting import LimitingFactor
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface


def default_max_range_m(camera: CameraModel, detector: DetectorModel,
                        cell_size_m: float) -> float:
    """Slant range (m) where a cell of ``cell_size_m`` on the optical axis looks half as large
    as the smallest size the detector model covers (beyond it P_D is 0 anyway)."""
    scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
    return 2.0 * camera.focal_px * cell_size_m * scale / max(detector.bin_edges_px[0], 1e-3)


@dataclass(frozen=True, slots=True)
class GridCamera:
    """What ``CoverageGrid.update`` needs of one camera and its detector model, computed once
    (``build``): the calibrated field of view's bounding pyramid (the border rays' x / z and
    y / z extremes in the optical frame), the image-to-detector-input scale, the slant range
    beyond which cells are not observed (m), the detector's bin edges as image areas (px^2;
    (float64, float32), indexed by ``area dtype is float32``, so that areas are compared with
    edges of their own dtype), the LimitingFactor of an observed cell by its size bin index
    (0: below the first edge, len(edges): above the last) and the log-miss tables (P_D; P_FA
    per image px^2: -rate size_scale^2) by the kernel's bin index (blur row * (N + 2) + size)."""

    camera: CameraModel
    detector: DetectorModel
    fov_box: tuple[float, float, float, float]
    size_scale: float
    max_range_m: float
    area_edges_px2: tuple[np.ndarray, np.ndarray]
    seen_code: np.ndarray
    log_miss_tables: tuple[np.ndarray, np.ndarray]

    @classmethod
    def build(cls, camera: CameraModel, detector: DetectorModel, cell_size_m: float,
              max_range_m: float | None = None) -> GridCamera:
        """max_range_m: None chooses ``default_max_range_m`` (so it follows a zoomed
        camera's focal length)."""
        rays = camera.border_rays_cam
        x_z, y_z = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
        fov_box = (float(x_z.min()), float(x_z.max()), float(y_z.min()), float(y_z.max()))
        size_scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
        if max_range_m is None:
            max_range_m = default_max_range_m(camera, detector, cell_size_m)
        if not max_range_m > 0:
            raise ValueError(f"max_range_m must be positive, got {max_range_m}")
        # Indexed by the kernel's bin index: blur row * (N + 2) + size index (the detector
        # model's padded_tables_by_blur); row 0, P by size only, when blur does not apply.
        pd, fa = detector.padded_tables_by_blur()[0], detector.padded_fa_rate_per_px2_by_blur()
        with np.errstate(divide="ignore"):
            tables = (np.log1p(-pd).astype(np.float32), (-fa * size_scale**2).astype(np.float32))
        # Bin by area against squared edges: sqrt(area) * scale >= edge <=> area >= edge'^2.
        area_edges = (np.asarray(detector.bin_edges_px, dtype=np.float64) / size_scale) ** 2
        seen_code = np.full(len(area_edges) + 1, LimitingFactor.SEEN, dtype=np.uint8)
        seen_code[0] = LimitingFactor.TOO_SMALL
        seen_code[-1] = LimitingFactor.TOO_LARGE
        return cls(camera, detector, fov_box, size_scale, float(max_range_m),
                   (area_edges, area_edges.astype(np.float32)), seen_code, tables)

    def blur_rows(self, pose: CameraPose, geometry: GridGeometry,
                  relief: TerrainSurface | None, window: tuple[int, int, int, int],
                  observed: np.ndarray, exposure_s: float) -> np.ndarray:
        """The detector model's blur row (``DetectorModel.blur_row``) of the ``observed``
        cells of ``window`` of ``geometry``, from the blur over ``exposure_s`` (s) at their
        centres (on ``relief``, None: the plane z = 0), scaled to detector-input pixels as
        sizes are; 0 elsewhere."""
        r0, r1, c0, c1 = window
        g = geometry
        cs = g.cell_size_m
        if relief is None:  # the centres' lattice on the plane z = 0
            blur = blur_lattice_px(self.camera, pose, g.x0_m + cs * (c0 + 0.5),
                                   g.y0_m + cs * (r0 + 0.5), cs, c1 - c0, r1 - r0, exposure_s)
            return self.detector.blur_row(self.size_scale * blur) * observed
        rows, cols = np.nonzero(observed)
        z = relief.centre_z_m(r0, r1, c0, c1)[rows, cols]
        blur = blur_xyz_px(self.camera, pose, g.x0_m + cs * (cols + c0 + 0.5),
                           g.y0_m + cs * (rows + r0 + 0.5), z, exposure_s)
        out = np.zeros(observed.shape, dtype=np.intp)
        out[rows, cols] = self.detector.blur_row(self.size_scale * blur)
        return out
