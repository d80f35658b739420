"""The coverage grid: cumulative P_D and P_FA per cell over camera frames (paper, III-C).

Accumulators are log-miss sums ``L = sum(log(1 - P(s)))`` so that ``P = 1 - exp(L)``; an update
is an addition, grids merge by adding, and frame order does not matter. This equals the
paper's recursion ``P(k) = P(k-1) + (1 - P(k-1)) P(s)``.

A cell is observed in a frame when the ray through its centre reaches the picture: in front
of the camera, inside the calibrated field of view, inside the image, within the maximum
slant range. Its apparent size is the square root of the area, in pixels, of its image
inside the picture, scaled to detector-input pixels.

On terrain (``terrain``: a ``TerrainSurface``) each cell's corners and centre lie on the
surface, its image is that of its 3-D patch, and it is observed only when it faces the
camera and the terrain does not rise above the line of sight to its centre
(``core/occlusion.py``). Without terrain, or on a surface at height 0 everywhere, the ground
is the plane z = 0 of the paper and the grid is exactly the flat-earth one.

With ``exposure_s`` and a detector model with blur bins, a cell's P_D and P_FA in a frame
are looked up by its size and by its motion blur (core/blur.py), the flat index
``blur_row * (N + 2) + size_index`` into ``DetectorModel.padded_tables_by_blur``; without
them, or for a pose without a known velocity and angular rate, by size only.

A frame may be taken with another camera than the grid's own (``update_with``): a zoomed
lens (core/zoom.py) or another camera of the mission with its own detector model. Its looks
add into the same cells' sums, as do another grid's (``merge``: another flight, vehicle or
camera): looks are combined as independent, two cameras giving p1 and p2 on a cell give
1 - (1 - p1)(1 - p2), or by the looks rule below (grids of different detectors combine at
its quadrature nodes, ``log_miss_nodes``).

Beside the probabilities each cell keeps its ``LimitingFactor``: the best that any frame did
for it, from never in view to seen at a size the detector model covers.

How one person's looks combine is ``looks`` (``core/looks.py``): independent (the paper, the
log-miss sums above), correlated (per cell the counts of its looks in each size bin, P_D
computed from them when read) or viewpoint (per cell and viewpoint bin the best look). With
the last two ``log_miss_d`` is derived from that state when read, only where frames changed
it since (``refresh``); P_FA, 1 - exp(-rate(s) A) a look, is the independent sum under every rule.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.core.blur import BlurEffect, blur_effect, blur_lattice_px, blur_xyz_px
from pdcov.core.camera import CameraModel
from pdcov.core.cell_area import clipped_quad_area, quad_area
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.footprint import footprint_rings_enu
from pdcov.core.looks import (
    QUADRATURE,
    CorrelatedLooks,
    LooksConfig,
    LooksRule,
    ViewpointLooks,
)
from pdcov.core.occlusion import hidden_by_terrain
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import BLOCK, TerrainSurface
from pdcov.errors import InputFileError
from pdcov.npz_file import read_npz

SNAPSHOT_VERSION = 3  # 3: the looks state; 2: the revisit clock in float64; 1: float32
READABLE_SNAPSHOT_VERSIONS = (1, 2, 3)
# Frame times closer than this count as equal in the revisit test: decimal times read from a
# file (0.1 s steps, or epoch times near 1.7e9 s with 2.4e-7 s float64 spacing) differ from
# their true differences by rounding well below it, so the same poses give the same grid
# whatever their time origin.
_REVISIT_TOL_S = 1e-6
# A version-1 revisit clock (float32) is used only where it resolves 1 ms: times below 2^13 s.
_FLOAT32_CLOCK_LIMIT_S = 2.0**13
_SUBDIVISIONS = 8  # sub-cells per side for cells only partly inside the picture
_MAX_CAMERAS = 256  # GridCamera values kept (each distinct zoom of a frame is one)


def default_max_range_m(camera: CameraModel, detector: DetectorModel,
                        cell_size_m: float) -> float:
    """Slant range (m) where a cell of ``cell_size_m`` on the optical axis looks half as large
    as the smallest size the detector model covers (beyond it P_D is 0 anyway)."""
    scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
    return 2.0 * camera.focal_px * cell_size_m * scale / max(detector.bin_edges_px[0], 1e-3)


_TOO_FAR_BAND_ROWS = 32
"""Rows per band in which ``_mark_too_far`` bounds the cells it judges."""


class LimitingFactor(enum.IntEnum):
    """What limited a cell's P_D: the best that any frame did for it (the largest code over
    its frames, so grids merge by the maximum). A cell in the picture is 'in view'."""

    NEVER_IN_VIEW = 0  # no frame had its centre in the picture
    TOO_FAR = 1  # in view only beyond the maximum slant range
    HIDDEN = 2  # in view within range, but terrain hid it (or it faced away from the camera)
    TOO_SMALL = 3  # seen, but always smaller than the detector model's smallest size bin
    TOO_LARGE = 4  # seen, but only larger than its largest bin
    SEEN = 5  # seen at a size the detector model covers


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


@dataclass(frozen=True, slots=True)
class LastLook:
    """What ``CoverageGrid.update`` saw of one frame's cells, for the candidates
    (detection/candidates.py): ``window`` (r0, r1, c0, c1), and per cell of it (arrays of
    the window's shape): ``in_view`` (observed: in the picture, within range, not hidden),
    ``counted`` (observed and past the revisit clock: a look, counted in ``n_obs``),
    ``size_index`` (the detector's padded size bin index, meaningful where in view),
    ``bin_index`` (the padded table index ``blur_row * (N + 2) + size_index`` the look was
    counted with; 0 where not counted) and ``area_px2`` (the cell's image area inside the
    picture, image px^2, meaningful where in view); ``tables``: the per-look tables the
    frame used, (log(1 - P_D), log(1 - P_FA) per image px^2 = -rate size_scale^2), indexed
    by the table index. The arrays are the update's own (no copy): read, never write."""

    t_s: float
    window: tuple[int, int, int, int]
    in_view: np.ndarray
    counted: np.ndarray
    size_index: np.ndarray
    bin_index: np.ndarray
    area_px2: np.ndarray
    tables: tuple[np.ndarray, np.ndarray]

    def _local(self, rows: np.ndarray, cols: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Window-local indices of grid cells (rows, cols) and whether each is inside."""
        r0, r1, c0, c1 = self.window
        rows, cols = np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp)
        inside = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
        return np.where(inside, rows - r0, 0), np.where(inside, cols - c0, 0), inside

    def look_at(self, rows: np.ndarray, cols: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per grid cell (rows, cols): (counted, in_view, table index, log(1 - P_FA)) of
        this frame's look: the table index the look was counted with, or for a cell in view
        but not counted (the revisit clock) its size bin by size only (blur unknown); 0
        (P_D = P_FA = 0) for a cell not in view or outside the window. log(1 - P_FA) =
        -rate A_px, the look's expected false boxes over the cell's image, negated."""
        lr, lc, inside = self._local(rows, cols)
        counted = inside & self.counted[lr, lc]
        in_view = inside & self.in_view[lr, lc]
        index = np.where(counted, self.bin_index[lr, lc],
                         np.where(in_view, self.size_index[lr, lc], 0))
        log_fa = np.where(in_view, self.tables[1].take(index).astype(np.float64)
                          * self.area_px2[lr, lc], 0.0)
        return counted, in_view, index, log_fa

    def log_miss_d(self, index: np.ndarray) -> np.ndarray:
        """log(1 - P_D) (float64, <= 0) of a look at table ``index`` (``look_at``)."""
        return self.tables[0].take(index).astype(np.float64)


@dataclass(frozen=True, slots=True)
class Metrics:
    """Summary of a grid. Proportions are of free cells; false alarms sum P_FA over observed
    free cells; limiting_cells counts free cells by LimitingFactor name (lower case)."""

    frames: int
    cells_free: int
    cells_observed: int
    proportion_at_or_above: dict[float, float]
    mean_pd: float
    expected_false_alarms: float
    limiting_cells: dict[str, int] = field(default_factory=dict)


class CoverageGrid:
    """Cumulative detection and false-alarm probabilities over a grid of cells.

    geometry: the cells (ENU). mask: bool (n_rows, n_cols), True for free cells (only those
    are updated). max_range_m: slant range beyond which cells are not observed; None chooses
    ``default_max_range_m``. terrain: the ground under the cells (ENU, core/terrain.py;
    None: the plane z = 0).
    min_revisit_s: count at most one
    observation per cell per this many seconds (None: every frame counts, as in the paper).
    exposure_s: the camera's exposure time (s); with it, a detector model with blur bins
    and a pose with a known velocity and angular rate, each cell's P_D and P_FA are looked up
    by its size and its motion blur (core/blur.py) at its centre. Otherwise by size only.

    With ``min_revisit_s`` which look counts depends on the order of the frames, so frames
    must come in time order (``update`` refuses one earlier than the latest); times are kept
    in float64 seconds (any clock: boot time or Unix epoch give the same grid), and two times
    within 1 microsecond count as equal.

    looks: how one person's looks combine (``core/looks.py``; None: independent, the paper).
    ``min_revisit_s`` decides which looks count under every rule.
    """

    def __init__(self, geometry: GridGeometry, mask: np.ndarray, camera: CameraModel,
                 detector: DetectorModel, *, max_range_m: float | None = None,
                 min_revisit_s: float | None = None,
                 terrain: TerrainSurface | None = None,
                 exposure_s: float | None = None,
                 looks: LooksConfig | None = None) -> None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != geometry.shape:
            raise ValueError(f"mask shape {mask.shape} != grid shape {geometry.shape}")
        if terrain is not None and terrain.geometry != geometry:
            raise ValueError("terrain is for another grid geometry")
        self.terrain = terrain
        # The kernel's terrain: None on the plane z = 0, which takes the flat-earth path.
        self._relief = None if terrain is None or terrain.is_level_zero else terrain
        self.geometry = geometry
        self.mask = mask
        if max_range_m is not None and not max_range_m > 0:
            raise ValueError(f"max_range_m must be positive, got {max_range_m}")
        self._max_range_given = max_range_m
        self._cameras: dict[tuple[int, int], GridCamera] = {}
        self._base = self._grid_camera(camera, detector)
        self._use(self._base)
        self.min_revisit_s = min_revisit_s
        if exposure_s is not None and not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"exposure_s must be a positive number of seconds, "
                             f"got {exposure_s}")
        self.exposure_s = exposure_s
        self.blur_effect = blur_effect(exposure_s, detector)
        self.frames_blurred = 0  # frames whose P_D took their blur into account
        self._log_miss_d = np.zeros(geometry.shape, dtype=np.float32)
        self.looks = LooksConfig() if looks is None else looks
        self._looks = _looks_state(self.looks, geometry.shape, detector)
        # Cells whose looks changed since log_miss_d was last derived, and their bounding
        # window (None: none); only with a looks state.
        self._dirty = np.zeros(geometry.shape, dtype=bool) if self._looks else None
        self._dirty_box: tuple[int, int, int, int] | None = None
        self.log_miss_fa = np.zeros(geometry.shape, dtype=np.float32)
        self.n_obs = np.zeros(geometry.shape, dtype=np.int32)
        self.limiting = np.zeros(geometry.shape, dtype=np.uint8)  # LimitingFactor per cell
        self.last_obs_s = (np.full(geometry.shape, -np.inf, dtype=np.float64)
                           if min_revisit_s else None)
        self.latest_frame_t_s = -math.inf  # latest frame time seen (s), with min_revisit_s
        self.frames = 0
        # The cells (r0, r1, c0, c1) the latest update may have changed, None for none: a
        # subscriber (the daemon's tiles and status) re-reads only those.
        self.touched: tuple[int, int, int, int] | None = None
        # The latest update's look of the cells of its window (None: no cell in view).
        self.last_look: LastLook | None = None

    # -- results ----------------------------------------------------------------------------

    @property
    def log_miss_d(self) -> np.ndarray:
        """log(1 - P_D) per cell (float32, <= 0): the running sum with independent looks,
        else derived from the looks state (``refresh`` first). The same array every time:
        a holder of it sees it change in place."""
        if self._dirty_box is not None:
            self.refresh()
        return self._log_miss_d

    @property
    def base_detector(self) -> DetectorModel:
        """The grid's own detector model (``update_with`` may evaluate a frame with
        another)."""
        return self._base.detector

    @property
    def looks_state(self) -> CorrelatedLooks | ViewpointLooks | None:
        """The per-cell looks state (``core/looks.py``; None with independent looks)."""
        return self._looks

    def refresh(self) -> None:
        """Derive ``log_miss_d`` of the cells whose looks changed since the last read."""
        box, looks, dirty = self._dirty_box, self._looks, self._dirty
        if box is None or looks is None or dirty is None:
            return
        r0, r1, c0, c1 = box
        rows, cols = np.nonzero(dirty[r0:r1, c0:c1])
        rows += r0
        cols += c0
        self._log_miss_d[rows, cols] = looks.log_miss_at(rows, cols)
        dirty[r0:r1, c0:c1] = False
        self._dirty_box = None

    def log_miss_nodes(self, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Per cell of ``window`` (r0, r1, c0, c1; None: the whole grid), log P_miss given the
        person's latent quantile at each ``looks.QUADRATURE`` node: (rows, cols, J) float64.
        For grids of different cameras or detectors seeing the same person: sum theirs and
        take ``looks.pd_of_node_log_miss``. Independent and viewpoint grids do not depend
        on the latent: their log-miss at every node."""
        r0, r1, c0, c1 = window or (0, self.geometry.n_rows, 0, self.geometry.n_cols)
        if isinstance(self._looks, CorrelatedLooks):
            return self._looks.log_miss_nodes((r0, r1, c0, c1))
        flat = self.log_miss_d[r0:r1, c0:c1].astype(np.float64)
        return np.repeat(flat[..., None], len(QUADRATURE.q), axis=2)

    def _mark_dirty(self, window: tuple[int, int, int, int],
                    cells: np.ndarray | None = None) -> None:
        """The looks of ``cells`` (bool, the window's shape; None: all) of ``window``
        changed."""
        r0, r1, c0, c1 = window
        if self._dirty is None:
            raise TypeError("only a grid with a looks state has cells to refresh")
        dirty = self._dirty[r0:r1, c0:c1]
        if cells is None:
            dirty[:] = True
        else:
            dirty |= cells
        box = self._dirty_box
        self._dirty_box = window if box is None else (
            min(box[0], r0), max(box[1], r1), min(box[2], c0), max(box[3], c1))

    @property
    def pd(self) -> np.ndarray:
        """Cumulative probability of detection per cell (float64, 0 where not free)."""
        return 0.0 - np.expm1(self.log_miss_d.astype(np.float64))  # 0.0 - : no -0.0

    @property
    def pfa(self) -> np.ndarray:
        """Cumulative probability of false alarm per cell (float64)."""
        return 0.0 - np.expm1(self.log_miss_fa.astype(np.float64))

    def metrics(self, thresholds: tuple[float, ...] | list[float]) -> Metrics:
        pd = self.pd[self.mask]
        observed = self.mask & (self.n_obs > 0)
        n_free = int(self.mask.sum())
        return Metrics(
            frames=self.frames,
            cells_free=n_free,
            cells_observed=int(observed.sum()),
            proportion_at_or_above={float(t): float((pd >= t).mean()) if n_free else 0.0
                                    for t in thresholds},
            mean_pd=float(pd.mean()) if n_free else 0.0,
            expected_false_alarms=float(self.pfa[observed].sum()),
            limiting_cells=self.limiting_counts(),
        )

    def limiting_counts(self) -> dict[str, int]:
        """Free cells per LimitingFactor, by lower-case name, in code order."""
        return limiting_counts(self.limiting, self.mask)

    # -- the camera of a frame --------------------------------------------------------------

    def update_with(self, pose: CameraPose, camera: CameraModel | None = None,
                    detector: DetectorModel | None = None, t_s: float | None = None) -> int:
        """``update`` for a frame taken with another camera (a zoomed lens: core/zoom.py)
        and/or another detector model (another camera of the mission) than the grid's own;
        None keeps the grid's. Its looks add into the same cells' log-miss sums: the looks of
        all cameras are combined as independent (module docstring). The per-camera values
        are computed once per (camera, detector) object pair (``GridCamera``); with
        ``max_range_m`` not given, each camera has its own default range."""
        base = self._base
        if (detector is not None and detector.blur is None
                and self.blur_effect is BlurEffect.APPLIED):
            raise ValueError(f"{detector.source or 'the frame detector model'} has no blur "
                             f"bins, the grid's ({base.detector.source or 'its own'}) has: "
                             "a frame's P_D would mix two blur rules; give the camera a "
                             "grid of its own (Mission.new_grid(camera))")
        frame = self._grid_camera(camera or base.camera, detector or base.detector)
        if frame is base:
            return self.update(pose, t_s)
        self._use(frame)
        try:
            return self.update(pose, t_s)
        finally:
            self._use(base)

    def _grid_camera(self, camera: CameraModel, detector: DetectorModel) -> GridCamera:
        key = (id(camera), id(detector))  # the objects are kept in the value: ids stay theirs
        found = self._cameras.get(key)
        if found is None:
            if len(self._cameras) >= _MAX_CAMERAS:  # a long zoom: keep the grid's own
                self._cameras = {k: v for k, v in self._cameras.items() if v is self._base}
            found = GridCamera.build(camera, detector, self.geometry.cell_size_m,
                                     self._max_range_given)
            self._cameras[key] = found
        return found

    def _use(self, c: GridCamera) -> None:
        """Make ``c`` the camera ``update`` evaluates frames with."""
        self.camera, self.detector = c.camera, c.detector
        self.size_scale, self.max_range_m = c.size_scale, c.max_range_m
        self._fov_box, self._area_edges_px2 = c.fov_box, c.area_edges_px2
        self._seen_code, self._log_miss_tables = c.seen_code, c.log_miss_tables

    # -- update -----------------------------------------------------------------------------

    def update(self, pose: CameraPose, t_s: float | None = None) -> int:
        """Add one camera frame; returns the number of free cells it observed, and sets
        ``touched`` to the window of cells it may have changed (its window, and the cells
        it marked TOO_FAR beyond it).

        t_s (s, autopilot clock) defaults to ``pose.t_s``; it is only used with
        ``min_revisit_s``, and must then not go back in time (ValueError, nothing counted).
        """
        t = float(pose.t_s if t_s is None else t_s)
        self.touched = None
        self.last_look = None
        if self.last_obs_s is not None:
            if not math.isfinite(t):
                raise ValueError(f"min_revisit_s needs frame times: pose.t_s or t_s, got {t}")
            if t < self.latest_frame_t_s - _REVISIT_TOL_S:
                raise ValueError(f"min_revisit_s needs frames in time order: t_s = {t!r} s "
                                 f"after a frame at {self.latest_frame_t_s!r} s")
            self.latest_frame_t_s = max(self.latest_frame_t_s, t)
        self.frames += 1
        blurred = self.blur_effect is BlurEffect.APPLIED and pose.has_motion
        self.frames_blurred += blurred
        window, clipped = self._window(pose)
        far = self._mark_too_far(pose, window) if clipped else None
        self.touched = _union(window, far)
        if window is None:
            return 0
        r0, r1, c0, c1 = window
        observed, area_px2, reach = self._observe_area(pose, window)
        # Bin by area against squared edges: sqrt(area) * scale >= edge <=> area >= edge'^2.
        edges = self._area_edges_px2[area_px2.dtype == np.float32]
        with np.errstate(invalid="ignore"):
            idx = np.searchsorted(edges, area_px2, side="right")
        limiting = self.limiting[r0:r1, c0:c1]
        np.maximum(limiting, np.where(observed, self._seen_code.take(idx * observed), reach),
                   out=limiting)
        in_view, size_idx = observed, idx
        if self.last_obs_s is not None:
            if self.min_revisit_s is None:  # only if min_revisit_s was cleared after __init__
                raise TypeError("min_revisit_s is None but last_obs_s is kept")
            last = self.last_obs_s[r0:r1, c0:c1]
            observed = observed & ((t - last) >= self.min_revisit_s - _REVISIT_TOL_S)
            last[observed] = t
        # Unobserved cells take index 0, whose log-miss is 0: the additions below are dense
        # over the window (cheaper than masked scatters) and leave those cells unchanged.
        idx = idx * observed
        if blurred:
            idx += self._blur_rows(pose, window, observed) * (self.detector.n_bins + 2)
        tab_d, tab_fa = self._log_miss_tables
        self.last_look = LastLook(t, window, in_view, observed, size_idx, idx, area_px2,
                                  self._log_miss_tables)
        if self._looks is None:
            self._log_miss_d[r0:r1, c0:c1] += tab_d.take(idx)
        else:
            self._add_looks(pose, window, idx)
        self.log_miss_fa[r0:r1, c0:c1] += np.multiply(  # log(1 - P_FA) = -rate A (in view)
            tab_fa.take(idx), area_px2, out=np.zeros(idx.shape, np.float32), where=observed)
        self.n_obs[r0:r1, c0:c1] += observed
        return int(np.count_nonzero(observed))

    def _blur_rows(self, pose: CameraPose, window: tuple[int, int, int, int],
                   observed: np.ndarray) -> np.ndarray:
        """The detector model's blur row (``DetectorModel.blur_row``) of the observed cells
        of ``window``, from the blur at their centres (on the terrain when there is one),
        scaled to detector-input pixels as sizes are; 0 elsewhere."""
        r0, r1, c0, c1 = window
        g = self.geometry
        cs = g.cell_size_m
        assert self.exposure_s is not None  # blur_effect is APPLIED
        if self._relief is None:  # the centres' lattice on the plane z = 0
            blur = blur_lattice_px(self.camera, pose, g.x0_m + cs * (c0 + 0.5),
                                   g.y0_m + cs * (r0 + 0.5), cs, c1 - c0, r1 - r0,
                                   self.exposure_s)
            return self.detector.blur_row(self.size_scale * blur) * observed
        rows, cols = np.nonzero(observed)
        z = self._relief.centre_z_m(r0, r1, c0, c1)[rows, cols]
        blur = blur_xyz_px(self.camera, pose, g.x0_m + cs * (cols + c0 + 0.5),
                           g.y0_m + cs * (rows + r0 + 0.5), z, self.exposure_s)
        out = np.zeros(observed.shape, dtype=np.intp)
        out[rows, cols] = self.detector.blur_row(self.size_scale * blur)
        return out

    def _add_looks(self, pose: CameraPose, window: tuple[int, int, int, int],
                   idx: np.ndarray) -> None:
        """Count the looks of a frame (padded bin index ``idx`` per cell of ``window``, 0
        where not counted) in the looks state."""
        looks = self._looks
        if isinstance(looks, CorrelatedLooks):
            counted = looks.add(window, idx)
        elif isinstance(looks, ViewpointLooks):
            r0, r1, c0, c1 = window
            g = self.geometry
            x = g.x0_m + g.cell_size_m * (np.arange(c0, c1) + 0.5)
            y = g.y0_m + g.cell_size_m * (np.arange(r0, r1) + 0.5)
            z = 0.0 if self._relief is None else self._relief.centre_z_m(r0, r1, c0, c1)
            counted = looks.add(window, idx, x, y, z, pose.r_cam_enu)
        else:
            return
        self._mark_dirty(window, counted)

    def observe(self, pose: CameraPose, window: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, np.ndarray]:
        """Cells of ``window`` (r0, r1, c0, c1) observed by ``pose``, and their apparent size.

        Returns a bool mask (r1 - r0, c1 - c0) and, for the True cells in row-major order, the
        square root of the area in image pixels of each cell's image inside the picture.
        """
        observed, area_px2, _ = self._observe_area(pose, window)
        return observed, np.sqrt(area_px2[observed].astype(np.float64))

    def _observe_area(self, pose: CameraPose, window: tuple[int, int, int, int]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The observed mask of ``window``, the image area (px^2) inside the picture of
        every cell of it (meaningful only where observed; float32 or float64), and the
        LimitingFactor of the cells not observed (uint8; NEVER_IN_VIEW, TOO_FAR, HIDDEN)."""
        H, in_view, in_range = self._centres(pose, window)
        if not in_view.any():
            return in_view, np.zeros(in_view.shape), np.zeros(in_view.shape, np.uint8)
        r0, r1, c0, c1 = window
        n_rows, n_cols = in_view.shape
        g, cam, relief = self.geometry, self.camera, self._relief
        cs = g.cell_size_m
        r = pose.r_cam_enu
        up_cam = pose.R_enu_cam[2]
        z_v = None if relief is None else relief.z_corner_m[r0:r1 + 1, c0:c1 + 1]
        observed = in_view & in_range
        reach = np.where(in_view, np.uint8(LimitingFactor.TOO_FAR),
                         np.uint8(LimitingFactor.NEVER_IN_VIEW))
        if relief is not None and observed.any():
            assert z_v is not None
            z_c = relief.centre_z_m(r0, r1, c0, c1)
            rows, cols = np.nonzero(observed)
            blocked = ~self._faces_camera(r, z_v, rows, cols, r0, c0)
            front = ~blocked
            x = g.x0_m + cs * (cols[front] + c0 + 0.5)
            y = g.y0_m + cs * (rows[front] + r0 + 0.5)
            blocked[front] = hidden_by_terrain(relief, r, x, y, z_c[rows[front], cols[front]])
            observed[rows[blocked], cols[blocked]] = False
            reach[rows[blocked], cols[blocked]] = LimitingFactor.HIDDEN
        if not observed.any():
            return observed, np.zeros(observed.shape), reach
        with np.errstate(invalid="ignore", over="ignore"):
            # Corners, projected all at once: a cell wholly in the picture takes the area of
            # its corners' quadrilateral.
            if z_v is None:
                px_v = cam.project_lattice(H, n_cols + 1, n_rows + 1)
            else:
                jv = np.arange(n_cols + 1, dtype=np.float64)
                iv = np.arange(n_rows + 1, dtype=np.float64)[:, None]
                px_v = cam.project_xyz(*(H[k, 0] * jv + (H[k, 1] * iv + H[k, 2])
                                         + up_cam[k] * z_v for k in range(3)))
            v_in = cam.in_picture(px_v)
            corners = np.array([[0, 0, 1], [n_cols, 0, 1], [0, n_rows, 1],
                                [n_cols, n_rows, 1]], dtype=np.float64)
            hull = corners @ H.T
            if z_v is not None:  # the window's box between its lowest and highest corner
                hull = np.concatenate([hull + up_cam * float(z_v.min()),
                                       hull + up_cam * float(z_v.max())])
            v_ok = None  # all projectable
            if not cam.all_projectable(hull):
                jj, ii = np.meshgrid(np.arange(n_cols + 1), np.arange(n_rows + 1))
                p_v = jj[..., None] * H[:, 0] + ii[..., None] * H[:, 1] + H[:, 2]
                if z_v is not None:
                    p_v = p_v + z_v[..., None] * up_cam
                v_ok = cam.projectable(p_v)
                v_in &= v_ok
            whole = v_in[:-1, :-1] & v_in[:-1, 1:] & v_in[1:, 1:] & v_in[1:, :-1]
            area = quad_area(px_v[:-1, :-1], px_v[:-1, 1:], px_v[1:, 1:], px_v[1:, :-1])
        # Cells straddling the picture's edge: clip their image to the picture.
        rows, cols = np.nonzero(observed & ~whole)
        if len(rows):
            # Flat indices of the corners (row, col), (row, col + 1), (row + 1, col + 1),
            # (row + 1, col) in the corner lattice.
            at = (rows * (n_cols + 1) + cols)[:, None] + np.array([0, 1, n_cols + 2, n_cols + 1])
            q = px_v.reshape(-1, 2)[at].astype(np.float64)
            ok = np.ones(len(rows), dtype=bool) if v_ok is None else v_ok.ravel()[at].all(axis=1)
            edge_area = np.empty(len(rows))
            edge_area[ok] = clipped_quad_area(q[ok], cam.width_px, cam.height_px)
            # Cells with a corner where projection folds back: integrate over sub-cells.
            if not ok.all():
                edge_area[~ok] = self._partial_area(pose, rows[~ok] + r0, cols[~ok] + c0)
            area[rows, cols] = edge_area
        return observed, area, reach

    def _mark_too_far(self, pose: CameraPose, window: tuple[int, int, int, int] | None
                      ) -> tuple[int, int, int, int] | None:
        """Mark TOO_FAR the cells in view beyond the maximum range, out to twice it, outside
        ``window`` (the window's own cells are judged by ``_observe_area``); the terrain's
        line of sight is not tested there. For frames whose picture reaches past the range.
        Returns the window (r0, r1, c0, c1) of the cells it marked, None for none."""
        wide, _ = self._window(pose, 2.0 * self.max_range_m)
        if wide is None or wide == window:
            return None
        changed: tuple[int, int, int, int] | None = None
        r0, r1, c0, c1 = wide
        # Only free cells below TOO_FAR can change: each band of rows is judged over the
        # columns that hold such cells.
        unmarked = self.mask[r0:r1, c0:c1] & (self.limiting[r0:r1, c0:c1]
                                              < LimitingFactor.TOO_FAR)
        for b0 in range(0, r1 - r0, _TOO_FAR_BAND_ROWS):
            band = unmarked[b0:b0 + _TOO_FAR_BAND_ROWS]
            cols = np.flatnonzero(band.any(axis=0))
            if not len(cols):
                continue
            sub = (r0 + b0, r0 + b0 + len(band), c0 + int(cols[0]), c0 + int(cols[-1]) + 1)
            _, in_view, in_range = self._centres(pose, sub)
            marked = in_view & ~in_range & band[:, cols[0]:cols[-1] + 1]
            mr, mc = np.flatnonzero(marked.any(axis=1)), np.flatnonzero(marked.any(axis=0))
            if not len(mr):
                continue
            limiting = self.limiting[sub[0]:sub[1], sub[2]:sub[3]]
            np.maximum(limiting, marked.view(np.uint8) * np.uint8(LimitingFactor.TOO_FAR),
                       out=limiting)
            changed = _union(changed, (sub[0] + int(mr[0]), sub[0] + int(mr[-1]) + 1,
                                       sub[2] + int(mc[0]), sub[2] + int(mc[-1]) + 1))
        return changed

    def _centres(self, pose: CameraPose, window: tuple[int, int, int, int]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """H, the map of window lattice indices [j, i, 1] to the optical frame on the plane
        z = 0, and per cell of ``window``: whether it is in view (free, its centre in the
        picture and in the calibrated field of view) and within the maximum slant range."""
        r0, r1, c0, c1 = window
        n_rows, n_cols = r1 - r0, c1 - c0
        g = self.geometry
        cs = g.cell_size_m
        cam = self.camera
        r = pose.r_cam_enu
        relief = self._relief
        # The window's cell corners form a lattice; the corner (col c0 + j, row r0 + i) at
        # height z is, in the optical frame, R_cam_enu @ ([x, y, z] - r) = H @ [j, i, 1]
        # + z up_cam, with up_cam = R_cam_enu @ [0, 0, 1].
        H = pose.R_enu_cam.T @ np.array([[cs, 0.0, g.x0_m + cs * c0 - r[0]],
                                         [0.0, cs, g.y0_m + cs * r0 - r[1]],
                                         [0.0, 0.0, -r[2]]])
        H_centre = H.copy()
        H_centre[:, 2] += 0.5 * (H[:, 0] + H[:, 1])
        j = np.arange(n_cols, dtype=np.float64)
        i = np.arange(n_rows, dtype=np.float64)[:, None]
        dx2 = (g.x0_m + cs * (np.arange(c0, c1) + 0.5) - r[0]) ** 2
        dy2 = (g.y0_m + cs * (np.arange(r0, r1) + 0.5) - r[1]) ** 2
        xyz_c = [H_centre[k, 0] * j + (H_centre[k, 1] * i + H_centre[k, 2]) for k in range(3)]
        if relief is None:
            in_range = dy2[:, None] + (dx2 + r[2] ** 2) <= self.max_range_m**2
        else:
            z_c = relief.centre_z_m(r0, r1, c0, c1)
            in_range = dy2[:, None] + (dx2 + (z_c - r[2]) ** 2) <= self.max_range_m**2
            up_cam = pose.R_enu_cam[2]
            xyz_c = [xyz_c[k] + up_cam[k] * z_c for k in range(3)]
        # Behind the camera the maps hold meaningless values; the tests below reject those.
        with np.errstate(invalid="ignore", over="ignore"):
            px_c = (cam.project_lattice(H_centre, n_cols, n_rows) if relief is None
                    else cam.project_xyz(*xyz_c))
            in_view = self.mask[r0:r1, c0:c1] & cam.in_picture(px_c)
            if in_view.any():
                in_view &= cam.in_fov_xyz(*xyz_c)
        return H, in_view, in_range

    def _faces_camera(self, r_cam_enu: np.ndarray, z_corner_m: np.ndarray, rows: np.ndarray,
                      cols: np.ndarray, r0: int, c0: int) -> np.ndarray:
        """True for the cells (rows, cols) of the window at (r0, c0) whose corner heights
        are ``z_corner_m`` whose surface faces the camera: the camera is on the upper side of
        the plane through the centre with the normal of the diagonals' cross product."""
        cs = self.geometry.cell_size_m
        z00, z01 = z_corner_m[rows, cols], z_corner_m[rows, cols + 1]
        z10, z11 = z_corner_m[rows + 1, cols], z_corner_m[rows + 1, cols + 1]
        # (cs, cs, z11 - z00) x (-cs, cs, z10 - z01) / cs = (n_x, n_y, 2 cs)
        n_x = (z10 - z01) - (z11 - z00)
        n_y = -(z11 - z00) - (z10 - z01)
        g = self.geometry
        x = g.x0_m + cs * (cols + c0 + 0.5)
        y = g.y0_m + cs * (rows + r0 + 0.5)
        z = 0.25 * ((z00 + z11) + (z01 + z10))
        return (n_x * (r_cam_enu[0] - x) + n_y * (r_cam_enu[1] - y)
                + 2 * cs * (r_cam_enu[2] - z)) > 0

    def _partial_area(self, pose: CameraPose, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Image area (px^2) inside the picture of cells only partly inside it: each cell is
        split into sub-cells, and a sub-cell counts with its whole image area when its corners
        project trustworthily and the centre of its image is inside the picture."""
        m = _SUBDIVISIONS
        g = self.geometry
        cs = g.cell_size_m
        f = np.linspace(0.0, 1.0, m + 1)
        x = g.x0_m + cs * (cols[:, None, None] + f[None, None, :])       # (k, 1, m+1)
        y = g.y0_m + cs * (rows[:, None, None] + f[None, :, None])       # (k, m+1, 1)
        x, y = np.broadcast_arrays(x, y)
        z = np.zeros_like(x) if self._relief is None else self._relief.height_m(x, y)
        p_enu = np.stack([x, y, z], axis=-1).reshape(-1, 3)
        p_cam = (p_enu - pose.r_cam_enu) @ pose.R_enu_cam
        ok = self.camera.projectable(p_cam)
        px: np.ndarray = np.zeros((len(p_cam), 2))
        px[ok] = self.camera.project(p_cam[ok])
        px = px.reshape(len(rows), m + 1, m + 1, 2)
        ok = ok.reshape(len(rows), m + 1, m + 1)
        quads = np.stack([px[:, :-1, :-1], px[:, :-1, 1:], px[:, 1:, 1:], px[:, 1:, :-1]],
                         axis=3)                                           # (k, m, m, 4, 2)
        sub_ok = ok[:, :-1, :-1] & ok[:, :-1, 1:] & ok[:, 1:, 1:] & ok[:, 1:, :-1]
        centre = quads.mean(axis=3).reshape(-1, 2)
        sub_ok &= self.camera.in_picture(centre).reshape(sub_ok.shape)
        return np.where(sub_ok, quad_area(*np.moveaxis(quads, 3, 0)), 0.0).sum(axis=(1, 2))

    def _window(self, pose: CameraPose, range_m: float | None = None
                ) -> tuple[tuple[int, int, int, int] | None, bool]:
        """(r0, r1, c0, c1): the grid cells that may be observed within ``range_m`` slant
        range (default the maximum range), from the footprint's extent padded by one cell
        and by the chord error of the sampled border; and whether the picture reaches beyond
        that range.

        On terrain the footprint lies between the ground planes through the lowest and the
        highest terrain: the picture's cone between them projects inside the footprints on
        those two planes. Their extent on the whole surface's range gives a first window,
        the range under that window a second, tighter one."""
        relief = self._relief
        range_m = self.max_range_m if range_m is None else range_m
        if relief is None:
            return self._window_between(pose, range_m, (0.0, 0.0))
        z_range = relief.z_range_m
        window, clipped = self._window_between(pose, range_m, z_range)
        if window is None:
            return None, clipped
        window = self._blocks_in_view(pose, range_m, window)
        if window is None:
            return None, clipped
        local = relief.window_z_range_m(*window)
        if local == z_range:
            return window, clipped
        return self._window_between(pose, range_m, local, window)[0], clipped

    def _blocks_in_view(self, pose: CameraPose, range_m: float,
                        window: tuple[int, int, int, int]) -> tuple[int, int, int, int] | None:
        """The part of ``window`` covered by the terrain blocks (core/terrain.py) that may be
        in view: a block is out when its box (its cells, from its lowest to its highest
        height) lies wholly outside one side of the pyramid bounding the calibrated field of
        view, or farther than ``range_m``."""
        relief = self._relief
        assert relief is not None
        g = self.geometry
        (b_r0, b_r1, b_c0, b_c1), z_lo, z_hi = relief.block_bounds(*window)
        step = BLOCK * g.cell_size_m
        x = g.x0_m + step * np.arange(b_c0, b_c1 + 1) - pose.r_cam_enu[0]
        y = g.y0_m + step * np.arange(b_r0, b_r1 + 1) - pose.r_cam_enu[1]
        x_lo, x_hi = x[None, :-1], x[None, 1:]
        y_lo, y_hi = y[:-1, None], y[1:, None]
        z_lo = z_lo - pose.r_cam_enu[2]
        z_hi = z_hi - pose.r_cam_enu[2]
        R_cam_enu = pose.R_enu_cam.T
        x_min, x_max, y_min, y_max = self._fov_box
        # For each side plane n . p >= 0 of the pyramid (and z > 0), a box is wholly outside
        # when the largest n . p over its corners is negative: per axis, the larger of the
        # two extremes weighted by n's component.
        out = np.zeros(z_lo.shape, dtype=bool)
        for k_x, k_y in ((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
            bound = (x_min if k_x > 0 else x_max) if k_x else (
                (y_min if k_y > 0 else y_max) if k_y else 0.0)
            # n = k_x e_x + k_y e_y - (k bound - [no side]) e_z, in the optical frame.
            n_cam = np.array([k_x, k_y, 1.0 if not (k_x or k_y) else -(k_x + k_y) * bound])
            n_enu = R_cam_enu.T @ n_cam
            top = (np.maximum(n_enu[0] * x_lo, n_enu[0] * x_hi)
                   + np.maximum(n_enu[1] * y_lo, n_enu[1] * y_hi)
                   + np.maximum(n_enu[2] * z_lo, n_enu[2] * z_hi))
            out |= top < 0
        # Nearest point of each box to the camera.
        near2 = (np.clip(0.0, x_lo, x_hi) ** 2 + np.clip(0.0, y_lo, y_hi) ** 2
                 + np.clip(0.0, z_lo, z_hi) ** 2)
        out |= near2 > range_m**2
        rows, cols = np.nonzero(~out)
        if len(rows) == 0:
            return None
        r0, r1, c0, c1 = window
        return (max(r0, (b_r0 + int(rows.min())) * BLOCK),
                min(r1, (b_r0 + int(rows.max()) + 1) * BLOCK),
                max(c0, (b_c0 + int(cols.min())) * BLOCK),
                min(c1, (b_c0 + int(cols.max()) + 1) * BLOCK))

    def _window_between(self, pose: CameraPose, range_m: float,
                        z_range_m: tuple[float, float],
                        within: tuple[int, int, int, int] | None = None
                        ) -> tuple[tuple[int, int, int, int] | None, bool]:
        """The window of the footprints on the ground planes through the lowest and the
        highest height of ``z_range_m``, inside ``within``, and whether the picture reaches
        beyond ``range_m``; all within range when the camera is not above the highest."""
        z_lo, z_hi = z_range_m
        found = footprint_rings_enu(self.camera, pose, range_m,
                                    (z_lo,) if z_lo == z_hi else (z_lo, z_hi))
        rings = list(found.rings)
        if z_hi > z_lo and len(rings[1]) == 0:
            rings.append(pose.r_cam_enu[:2] + range_m * np.array([[-1.0, -1.0], [1.0, 1.0]]))
        ring = np.concatenate(rings)
        if len(ring) == 0:
            return None, found.clipped
        g = self.geometry
        pad = 1.5 * g.cell_size_m + 0.01 * range_m
        row_lo, col_lo = g.cell_of(ring[:, 0].min() - pad, ring[:, 1].min() - pad)
        row_hi, col_hi = g.cell_of(ring[:, 0].max() + pad, ring[:, 1].max() + pad)
        w_r0, w_r1, w_c0, w_c1 = within or (0, g.n_rows, 0, g.n_cols)
        r0, r1 = max(int(row_lo), w_r0), min(int(row_hi) + 1, w_r1)
        c0, c1 = max(int(col_lo), w_c0), min(int(col_hi) + 1, w_c1)
        if r0 >= r1 or c0 >= c1:
            return None, found.clipped
        return (r0, r1, c0, c1), found.clipped

    # -- combine and persist ----------------------------------------------------------------

    def merge(self, other: CoverageGrid) -> None:
        """Add another grid of the same geometry (another flight or vehicle) into this one.

        With correlated or viewpoint looks both grids must have the same looks rule and
        detector model (their states add up only then); grids of different detectors
        combine at the quadrature nodes instead (``log_miss_nodes``)."""
        if other.geometry != self.geometry or not np.array_equal(other.mask, self.mask):
            raise ValueError("cannot merge grids of different geometry or free-space mask")
        if other.looks != self.looks:
            raise ValueError(f"cannot merge a grid of coverage.looks {other.looks.rule} "
                             f"into one of {self.looks.rule} (or of other viewpoint bins)")
        if self._looks is not None and not _same_looks_tables(self.detector, other.detector):
            raise ValueError(
                f"cannot merge {self.looks.rule} looks of different detector models (their "
                "bins' P_D or correlation differ): combine them per person at the "
                "quadrature nodes, looks.pd_of_node_log_miss(a.log_miss_nodes() + "
                "b.log_miss_nodes())")
        if isinstance(self._looks, CorrelatedLooks) and isinstance(other._looks,
                                                                   CorrelatedLooks):
            self._looks.merge(other._looks)
        elif isinstance(self._looks, ViewpointLooks) and isinstance(other._looks,
                                                                    ViewpointLooks):
            self._looks.merge(other._looks)
        else:
            self._log_miss_d += other._log_miss_d
        if self._looks is not None:
            self._mark_dirty((0, self.geometry.n_rows, 0, self.geometry.n_cols))
        self.log_miss_fa += other.log_miss_fa
        self.n_obs += other.n_obs
        np.maximum(self.limiting, other.limiting, out=self.limiting)
        self.frames += other.frames
        self.frames_blurred += other.frames_blurred
        if self.last_obs_s is not None and other.last_obs_s is not None:
            np.maximum(self.last_obs_s, other.last_obs_s, out=self.last_obs_s)
            self.latest_frame_t_s = max(self.latest_frame_t_s, other.latest_frame_t_s)

    def save_npz(self, path: str | Path, *, with_limiting: bool = True) -> None:
        """Write a snapshot atomically (temp file, fsync, rename): pd, pfa, n_obs, mask, the
        log-miss sums, limiting (LimitingFactor per cell; not with ``with_limiting`` False,
        for a grid whose limiting factors are unknown), x0_m, y0_m (south-west corner of
        cell [0, 0]), cell_size_m, frames, and with ``min_revisit_s`` each cell's last
        counted look, last_obs_s."""
        with atomic_write(path, "wb") as fh:
            self.write_npz(fh, with_limiting=with_limiting)

    def write_npz(self, fh: IO[bytes], *, with_limiting: bool = True) -> None:
        """Write the snapshot ``save_npz`` writes to an open binary file (the daemon sends
        these bytes over Zenoh: np.load reads them)."""
        g = self.geometry
        optional: dict[str, np.ndarray] = (
            {} if self.last_obs_s is None else {"last_obs_s": self.last_obs_s})
        if with_limiting:
            optional["limiting"] = self.limiting
        looks = self._looks
        if isinstance(looks, CorrelatedLooks):
            optional["looks_counts"] = looks.counts
        elif isinstance(looks, ViewpointLooks):
            optional["looks_best"] = looks.best
        np.savez_compressed(
            fh, version=SNAPSHOT_VERSION, pd=self.pd, pfa=self.pfa, n_obs=self.n_obs,
            mask=self.mask, log_miss_d=self.log_miss_d, log_miss_fa=self.log_miss_fa,
            x0_m=g.x0_m, y0_m=g.y0_m, cell_size_m=g.cell_size_m,
            frames=self.frames, looks=str(self.looks.rule),
            **optional)  # type: ignore[arg-type]  # mypy matches **optional to allow_pickle

    @classmethod
    def load_npz(cls, path: str | Path, camera: CameraModel, detector: DetectorModel,
                 *, max_range_m: float | None = None, min_revisit_s: float | None = None,
                 terrain: TerrainSurface | None = None,
                 exposure_s: float | None = None,
                 looks: LooksConfig | None = None, data: bytes | None = None
                 ) -> CoverageGrid:
        """Restore a snapshot written by ``save_npz`` (version 3, 2 or 1), from ``path``, or
        from its bytes ``data`` (``path`` then names it in messages). A version-1 revisit
        clock (float32) is refused where it cannot resolve a millisecond (times of 2^13 s and
        more, e.g. Unix epoch times) when ``min_revisit_s`` would use it. A snapshot of
        another looks rule than ``looks`` is refused (versions 1 and 2 are independent)."""
        path = Path(path)
        arrays = read_npz(path if data is None else data, lambda why: InputFileError(
            f"{path}: cannot read grid snapshot ({why})"))
        return cls._from_arrays(path, arrays, camera, detector, max_range_m=max_range_m,
                                min_revisit_s=min_revisit_s, terrain=terrain,
                                exposure_s=exposure_s, looks=looks)

    @classmethod
    def _from_arrays(cls, path: Path, data: dict[str, np.ndarray], camera: CameraModel,
                     detector: DetectorModel, *, max_range_m: float | None,
                     min_revisit_s: float | None, terrain: TerrainSurface | None,
                     exposure_s: float | None, looks: LooksConfig | None) -> CoverageGrid:
        missing = {"mask", "log_miss_d", "log_miss_fa", "n_obs", "x0_m", "y0_m",
                   "cell_size_m"} - set(data)
        if missing:
            raise InputFileError(f"{path}: not a pdcov grid snapshot (missing "
                                 f"{', '.join(sorted(missing))})")
        version = int(data.get("version", 1))
        if version not in READABLE_SNAPSHOT_VERSIONS:
            raise InputFileError(f"{path}: grid snapshot version {version}, expected "
                                 f"{' or '.join(map(str, READABLE_SNAPSHOT_VERSIONS))}")
        _check_snapshot_values(path, data)
        mask = data["mask"].astype(bool)
        geometry = GridGeometry(float(data["x0_m"]), float(data["y0_m"]),
                                float(data["cell_size_m"]), *mask.shape)
        grid = cls(geometry, mask, camera, detector, max_range_m=max_range_m,
                   min_revisit_s=min_revisit_s, terrain=terrain, exposure_s=exposure_s,
                   looks=looks)
        grid._log_miss_d[:] = data["log_miss_d"]
        _load_looks(path, data, grid)
        grid.log_miss_fa[:] = data["log_miss_fa"]
        grid.n_obs[:] = data["n_obs"]
        if "limiting" in data:
            grid.limiting[:] = data["limiting"]
        else:  # written before limiting factors: what the sums and counts still tell
            grid.limiting[:] = np.where(grid.log_miss_d < 0, LimitingFactor.SEEN,
                                        np.where(grid.n_obs > 0, LimitingFactor.TOO_SMALL,
                                                 LimitingFactor.NEVER_IN_VIEW))
        grid.frames = int(data.get("frames", 0))
        if grid.last_obs_s is not None and "last_obs_s" in data:
            last = data["last_obs_s"]
            if last.shape != mask.shape:
                raise InputFileError(f"{path}: last_obs_s has shape {last.shape}, the mask "
                                     f"{mask.shape}")
            finite = last[np.isfinite(last)]
            latest = float(finite.max()) if finite.size else -math.inf
            if version == 1 and finite.size and np.abs(finite).max() >= _FLOAT32_CLOCK_LIMIT_S:
                raise InputFileError(
                    f"{path}: grid snapshot version 1 keeps the revisit clock in float32, "
                    f"which resolves only {np.spacing(np.float32(latest)):g} s at t = "
                    f"{latest:.0f} s; re-create the grid with this pdcov, or load it "
                    "without coverage.min_revisit_s")
            grid.last_obs_s[:] = last
            grid.latest_frame_t_s = float(data.get("latest_frame_t_s", latest))
        return grid


def limiting_counts(limiting: np.ndarray, mask: np.ndarray) -> dict[str, int]:
    """Cells of ``mask`` per LimitingFactor code of ``limiting``, by lower-case name, in
    code order."""
    counts = np.bincount(limiting[mask], minlength=len(LimitingFactor))
    return {f.name.lower(): int(counts[f]) for f in LimitingFactor}


def _union(a: tuple[int, int, int, int] | None, b: tuple[int, int, int, int] | None
           ) -> tuple[int, int, int, int] | None:
    """The smallest window (r0, r1, c0, c1) holding windows ``a`` and ``b`` (None: none)."""
    if a is None or b is None:
        return a or b
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


def combine_cameras(into: CoverageGrid, grids: Sequence[CoverageGrid],
                    window: tuple[int, int, int, int] | None = None) -> None:
    """Set the cells of ``window`` (r0, r1, c0, c1; None: the whole grid) of ``into`` (a
    grid of independent looks, over the same cells) to the looks of ``grids`` together: the
    grids of one mission's cameras, one person seen by all of them. The one rule both
    drivers use (``pdcov evaluate`` once, the daemon per frame on its window).

    Each detector model has its own latent: the cameras of the same model (the same P_D
    and correlation per bin) are one sensor, their looks state merged (correlated: counts
    added; viewpoint: the best look per bin), so two cameras give the grid of one camera
    with all their frames; cameras of different models are independent of each other, their
    log-misses add, P_D = 1 - prod over models of P_miss. With independent looks every
    camera's log-miss adds. P_FA and the observation counts add; the limiting factor is the
    best (over the whole grid, whatever the window); the frame counts are the sums
    (``min_revisit_s`` applies per camera, in its own grid)."""
    if into.looks_state is not None:
        raise ValueError("combine_cameras writes derived log-misses: into must be a grid of "
                         "independent looks")
    g = into.geometry
    r0, r1, c0, c1 = window or (0, g.n_rows, 0, g.n_cols)
    cells = np.s_[r0:r1, c0:c1]
    for grid in grids:  # the masks compared once, when the whole grid is combined
        if grid.geometry != g or (window is None and not np.array_equal(grid.mask,
                                                                         into.mask)):
            raise ValueError("cannot combine grids of different geometry or free-space mask")
    into._log_miss_d[cells] = _combined_log_miss(grids, (r0, r1, c0, c1))
    into.log_miss_fa[cells] = 0.0
    into.n_obs[cells] = 0
    # The whole grid's: a frame whose picture reaches past its range marks cells TOO_FAR
    # outside its window (``_mark_too_far``).
    np.maximum.reduce([grid.limiting for grid in grids], out=into.limiting)
    for grid in grids:
        into.log_miss_fa[cells] += grid.log_miss_fa[cells]
        into.n_obs[cells] += grid.n_obs[cells]
        if into.last_obs_s is not None and grid.last_obs_s is not None:
            np.maximum(into.last_obs_s[cells], grid.last_obs_s[cells],
                       out=into.last_obs_s[cells])
            into.latest_frame_t_s = max(into.latest_frame_t_s, grid.latest_frame_t_s)
    into.frames = sum(grid.frames for grid in grids)
    into.frames_blurred = sum(grid.frames_blurred for grid in grids)


def combined_pd(grids: Sequence[CoverageGrid]) -> np.ndarray:
    """P_D per cell (float64) of one person seen in all of ``grids`` (the same cells),
    by ``combine_cameras``'s rule, none of them changed: the grids of one looks rule and
    detector model as one sensor (two flights of a mission: their counts add, as ``merge``
    adds them), the others independent."""
    g = grids[0].geometry
    if any(grid.geometry != g or not np.array_equal(grid.mask, grids[0].mask)
           for grid in grids):
        raise ValueError("cannot combine grids of different geometry or free-space mask")
    L = _combined_log_miss(grids, (0, g.n_rows, 0, g.n_cols))
    return 0.0 - np.expm1(L.astype(np.float64))


def _combined_log_miss(grids: Sequence[CoverageGrid], window: tuple[int, int, int, int]
                       ) -> np.ndarray:
    """log(1 - P_D) (float32) over ``window`` of ``grids`` together (``combine_cameras``)."""
    r0, r1, c0, c1 = window
    cells = np.s_[r0:r1, c0:c1]
    log_miss_d = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
    for group in _detector_groups(grids):
        looks = [grid.looks_state for grid in group]
        first = looks[0]
        if len(group) == 1 or first is None:
            for grid in group:
                log_miss_d += grid.log_miss_d[cells]
            continue
        if isinstance(first, CorrelatedLooks):
            state = sum(s.counts[cells] for s in looks if isinstance(s, CorrelatedLooks))
        else:
            state = np.maximum.reduce([s.best[cells] for s in looks
                                       if isinstance(s, ViewpointLooks)])
        flat = np.asarray(state).reshape(-1, np.shape(state)[-1])
        log_miss_d += first.log_miss_of(flat).reshape(r1 - r0, c1 - c0).astype(np.float32)
    return log_miss_d


def _detector_groups(grids: Sequence[CoverageGrid]) -> list[list[CoverageGrid]]:
    """The grids by detector model (``_same_looks_tables``), in order of first appearance;
    with independent looks each grid alone (their log-misses add either way)."""
    groups: list[list[CoverageGrid]] = []
    for grid in grids:
        same = next((grp for grp in groups if grid.looks_state is not None
                     and grp[0].looks == grid.looks
                     and _same_looks_tables(grp[0].base_detector, grid.base_detector)), None)
        if same is None:
            groups.append([grid])
        else:
            same.append(grid)
    return groups


def _check_snapshot_values(path: Path, data: dict[str, np.ndarray]) -> None:
    """Refuse (InputFileError) a snapshot whose arrays could not have been written by
    ``save_npz``: shapes other than the mask's, non-numeric arrays, NaN or positive log-miss
    sums, counts outside 0..2^31-1, a non-finite geometry, a negative frame count, a NaN
    revisit clock. So a damaged file is never half loaded into a grid."""
    def bad(why: str) -> InputFileError:
        return InputFileError(f"{path}: not a usable grid snapshot: {why}")

    mask = data["mask"]
    if mask.ndim != 2 or mask.dtype.kind not in "bui":
        raise bad(f"mask: expected a 2-D boolean array, got {mask.dtype} {mask.shape}")
    for key, kinds in (("log_miss_d", "f"), ("log_miss_fa", "f"), ("n_obs", "iu"),
                       ("last_obs_s", "f"), ("limiting", "iu")):
        a = data.get(key)
        if a is None:
            continue
        if a.shape != mask.shape:
            raise InputFileError(f"{path}: {key} has shape {a.shape}, the mask {mask.shape}")
        if a.dtype.kind not in kinds:
            raise bad(f"{key}: expected numbers, got {a.dtype}")
        if np.isnan(a).any():
            raise bad(f"{key}: NaN values")
    for key in ("log_miss_d", "log_miss_fa"):
        if (data[key] > 0).any():
            raise bad(f"{key}: positive values (log-miss sums are <= 0)")
    limiting = data.get("limiting")
    if limiting is not None and limiting.size and (
            int(limiting.min()) < 0 or int(limiting.max()) > max(LimitingFactor)):
        raise bad(f"limiting: codes outside 0..{int(max(LimitingFactor))}")
    n_obs = data["n_obs"]
    if n_obs.size and (int(n_obs.min()) < 0 or int(n_obs.max()) > 2**31 - 1):
        raise bad("n_obs: counts outside 0..2^31-1")
    for key in ("x0_m", "y0_m", "cell_size_m", "frames", "version"):
        a = data.get(key)
        if a is not None and (a.size != 1 or a.dtype.kind not in "fiu"
                              or not math.isfinite(float(a))):
            raise bad(f"{key}: expected one finite number")
    if int(data.get("frames", 0)) < 0:
        raise bad("frames: negative")


def _looks_state(config: LooksConfig, shape: tuple[int, int], detector: DetectorModel
                 ) -> CorrelatedLooks | ViewpointLooks | None:
    """The per-cell looks state a rule keeps (None: independent, the log-miss sums)."""
    if config.rule is LooksRule.CORRELATED:
        return CorrelatedLooks(shape, detector)
    if config.rule is LooksRule.VIEWPOINT:
        return ViewpointLooks(shape, detector, config.viewpoint)
    return None


def _same_looks_tables(a: DetectorModel, b: DetectorModel) -> bool:
    """Whether two detector models give a look in each bin the same meaning for the looks
    state: the same P_D and correlation per bin."""
    rho = [None if m.looks is None else m.looks.correlation for m in (a, b)]
    return a.p_detect == b.p_detect and rho[0] == rho[1]


def _load_looks(path: Path, data: dict[str, np.ndarray], grid: CoverageGrid) -> None:
    """Restore a snapshot's looks state into ``grid``, refusing a snapshot of another rule
    (InputFileError)."""
    written = str(data["looks"]) if "looks" in data else str(LooksRule.INDEPENDENT)
    rule = grid.looks.rule
    if written != str(rule):
        raise InputFileError(f"{path}: the grid snapshot was made with coverage.looks: "
                             f"{written}, the mission says {rule}; load it with the same "
                             "looks rule")
    looks = grid._looks
    key, target = (("looks_counts", looks.counts) if isinstance(looks, CorrelatedLooks)
                   else ("looks_best", looks.best) if isinstance(looks, ViewpointLooks)
                   else (None, None))
    if key is None or target is None:
        return
    a = data.get(key)
    if a is None or a.shape != target.shape or a.dtype != target.dtype:
        raise InputFileError(
            f"{path}: {key}: expected {target.dtype} {target.shape} (the {rule} looks of "
            f"this mission's grid and detector model), got "
            f"{'nothing' if a is None else f'{a.dtype} {a.shape}'}")
    if isinstance(looks, ViewpointLooks) and a.size and int(a.max()) >= len(
            looks.log1m_by_rank):
        raise InputFileError(f"{path}: looks_best: ranks above the detector model's "
                             f"{len(looks.log1m_by_rank) - 1}")
    target[:] = a
    grid._mark_dirty((0, grid.geometry.n_rows, 0, grid.geometry.n_cols))
