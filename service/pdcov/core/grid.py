"""The coverage grid: cumulative P_D and P_FA per cell over camera frames (paper, III-C).

Accumulators are log-miss sums ``L = sum(log(1 - P(s)))`` so that ``P = 1 - exp(L)``; an update
is an addition, grids merge by adding, and frame order does not matter. This equals the
paper's recursion ``P(k) = P(k-1) + (1 - P(k-1)) P(s)``.

Which cells a frame observes, and their image areas, is ``core/grid_view.py`` (on terrain
too); a cell's apparent size is the square root of its image area, scaled to detector-input
pixels. Without terrain, or on a surface at height 0 everywhere, the ground is the plane
z = 0 of the paper and the grid is exactly the flat-earth one.

With ``exposure_s`` and a detector model with blur bins, a cell's P_D and P_FA in a frame
are looked up by its size and by its motion blur (core/blur.py), the flat index
``blur_row * (N + 2) + size_index`` into ``DetectorModel.padded_tables_by_blur``; without
them, or for a pose without a known velocity and angular rate, by size only.

A frame may be taken with another camera than the grid's own (``update_with``): a zoomed
lens (core/zoom.py) or another camera of the mission with its own detector model; the
frame's ``GridCamera`` (core/grid_camera.py) is handed down explicitly. Its looks add into
the same cells' sums, as do another grid's (``merge``: another flight, vehicle or
camera): looks are combined as independent, two cameras giving p1 and p2 on a cell give
1 - (1 - p1)(1 - p2), or by the looks rule below (grids of different detectors combine at
its quadrature nodes, ``log_miss_nodes``; the grids of a mission's cameras:
core/combine_cameras.py).

Beside the probabilities each cell keeps its ``LimitingFactor`` (core/limiting.py): the best
that any frame did for it, from never in view to seen at a size the detector model covers.
Snapshots are written and read by core/grid_snapshot.py.

How one person's looks combine is ``looks`` (``core/looks.py``): independent (the paper, the
log-miss sums above), correlated (per cell the counts of its looks in each size bin, P_D
computed from them when read) or viewpoint (per cell and viewpoint bin the best look). With
the last two ``log_miss_d`` is derived from that state when read, only where frames changed
it since (``refresh``); P_FA, 1 - exp(-rate(s) A) a look, is the independent sum under every rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from pdcov.core.blur import BlurEffect, blur_effect, blur_lattice_px, blur_xyz_px
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.grid_camera import GridCamera
from pdcov.core.grid_snapshot import read_snapshot, save_snapshot, write_snapshot
from pdcov.core.grid_view import GridView, window_union
from pdcov.core.last_look import LastLook
from pdcov.core.limiting import limiting_counts
from pdcov.core.looks import (
    QUADRATURE,
    CorrelatedLooks,
    LooksConfig,
    ViewpointLooks,
    looks_state,
    same_looks_tables,
)
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface

# Frame times closer than this count as equal in the revisit test: decimal times read from a
# file (0.1 s steps, or epoch times near 1.7e9 s with 2.4e-7 s float64 spacing) differ from
# their true differences by rounding well below it, so the same poses give the same grid
# whatever their time origin.
_REVISIT_TOL_S = 1e-6
_MAX_CAMERAS = 256  # GridCamera values kept (each distinct zoom of a frame is one)


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
        self.geometry = geometry
        self.mask = mask
        # The kernel's terrain: None on the plane z = 0, which takes the flat-earth path.
        self._view = GridView(geometry, mask,
                              None if terrain is None or terrain.is_level_zero else terrain)
        if max_range_m is not None and not max_range_m > 0:
            raise ValueError(f"max_range_m must be positive, got {max_range_m}")
        self._max_range_given = max_range_m
        self._cameras: dict[tuple[int, int], GridCamera] = {}
        self._base = self._grid_camera(camera, detector)
        self.min_revisit_s = min_revisit_s
        if exposure_s is not None and not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"exposure_s must be a positive number of seconds, "
                             f"got {exposure_s}")
        self.exposure_s = exposure_s
        self.blur_effect = blur_effect(exposure_s, detector)
        self.frames_blurred = 0  # frames whose P_D took their blur into account
        self._log_miss_d = np.zeros(geometry.shape, dtype=np.float32)
        self.looks = LooksConfig() if looks is None else looks
        self._looks = looks_state(self.looks, geometry.shape, detector)
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
    def camera(self) -> CameraModel:
        """The grid's own camera (``update_with`` may evaluate a frame with another)."""
        return self._base.camera

    @property
    def detector(self) -> DetectorModel:
        """The grid's own detector model."""
        return self._base.detector

    @property
    def base_detector(self) -> DetectorModel:
        """The grid's own detector model, as ``detector`` (``update_with`` may evaluate a
        frame with another)."""
        return self._base.detector

    @property
    def size_scale(self) -> float:
        """The grid's own camera's image-to-detector-input scale."""
        return self._base.size_scale

    @property
    def max_range_m(self) -> float:
        """The grid's own camera's maximum slant range (m)."""
        return self._base.max_range_m

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

    def mark_looks_changed(self, window: tuple[int, int, int, int],
                           cells: np.ndarray | None = None) -> None:
        """The looks state of ``cells`` (bool, the window's shape; None: all) of ``window``
        changed: their ``log_miss_d`` is derived again when next read."""
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
        return self._update(frame, pose, t_s)

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

    # -- update -----------------------------------------------------------------------------

    def update(self, pose: CameraPose, t_s: float | None = None) -> int:
        """Add one camera frame; returns the number of free cells it observed, and sets
        ``touched`` to the window of cells it may have changed (its window, and the cells
        it marked TOO_FAR beyond it).

        t_s (s, autopilot clock) defaults to ``pose.t_s``; it is only used with
        ``min_revisit_s``, and must then not go back in time (ValueError, nothing counted).
        """
        return self._update(self._base, pose, t_s)

    def _update(self, frame: GridCamera, pose: CameraPose, t_s: float | None) -> int:
        """``update`` of a frame taken with camera and detector model ``frame``."""
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
        view = self._view
        window, clipped = view.window(frame, pose)
        far = view.mark_too_far(frame, pose, window, self.limiting) if clipped else None
        self.touched = window_union(window, far)
        if window is None:
            return 0
        r0, r1, c0, c1 = window
        observed, area_px2, reach = view.observe_area(frame, pose, window)
        # Bin by area against squared edges: sqrt(area) * scale >= edge <=> area >= edge'^2.
        edges = frame.area_edges_px2[area_px2.dtype == np.float32]
        with np.errstate(invalid="ignore"):
            idx = np.searchsorted(edges, area_px2, side="right")
        limiting = self.limiting[r0:r1, c0:c1]
        np.maximum(limiting, np.where(observed, frame.seen_code.take(idx * observed), reach),
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
            idx += self._blur_rows(frame, pose, window, observed) * (frame.detector.n_bins + 2)
        tab_d, tab_fa = frame.log_miss_tables
        self.last_look = LastLook(t, window, in_view, observed, size_idx, idx, area_px2,
                                  frame.log_miss_tables)
        if self._looks is None:
            self._log_miss_d[r0:r1, c0:c1] += tab_d.take(idx)
        else:
            self._add_looks(pose, window, idx)
        self.log_miss_fa[r0:r1, c0:c1] += np.multiply(  # log(1 - P_FA) = -rate A (in view)
            tab_fa.take(idx), area_px2, out=np.zeros(idx.shape, np.float32), where=observed)
        self.n_obs[r0:r1, c0:c1] += observed
        return int(np.count_nonzero(observed))

    def _blur_rows(self, frame: GridCamera, pose: CameraPose,
                   window: tuple[int, int, int, int], observed: np.ndarray) -> np.ndarray:
        """The detector model's blur row (``DetectorModel.blur_row``) of the observed cells
        of ``window``, from the blur at their centres (on the terrain when there is one),
        scaled to detector-input pixels as sizes are; 0 elsewhere."""
        r0, r1, c0, c1 = window
        g = self.geometry
        cs = g.cell_size_m
        assert self.exposure_s is not None  # blur_effect is APPLIED
        relief = self._view.relief
        if relief is None:  # the centres' lattice on the plane z = 0
            blur = blur_lattice_px(frame.camera, pose, g.x0_m + cs * (c0 + 0.5),
                                   g.y0_m + cs * (r0 + 0.5), cs, c1 - c0, r1 - r0,
                                   self.exposure_s)
            return frame.detector.blur_row(frame.size_scale * blur) * observed
        rows, cols = np.nonzero(observed)
        z = relief.centre_z_m(r0, r1, c0, c1)[rows, cols]
        blur = blur_xyz_px(frame.camera, pose, g.x0_m + cs * (cols + c0 + 0.5),
                           g.y0_m + cs * (rows + r0 + 0.5), z, self.exposure_s)
        out = np.zeros(observed.shape, dtype=np.intp)
        out[rows, cols] = frame.detector.blur_row(frame.size_scale * blur)
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
            relief = self._view.relief
            z = 0.0 if relief is None else relief.centre_z_m(r0, r1, c0, c1)
            counted = looks.add(window, idx, x, y, z, pose.r_cam_enu)
        else:
            return
        self.mark_looks_changed(window, counted)

    def observe(self, pose: CameraPose, window: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, np.ndarray]:
        """Cells of ``window`` (r0, r1, c0, c1) observed by ``pose``, and their apparent size.

        Returns a bool mask (r1 - r0, c1 - c0) and, for the True cells in row-major order, the
        square root of the area in image pixels of each cell's image inside the picture.
        """
        observed, area_px2, _ = self._view.observe_area(self._base, pose, window)
        return observed, np.sqrt(area_px2[observed].astype(np.float64))

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
        if self._looks is not None and not same_looks_tables(self.detector, other.detector):
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
            self.mark_looks_changed((0, self.geometry.n_rows, 0, self.geometry.n_cols))
        self.log_miss_fa += other.log_miss_fa
        self.n_obs += other.n_obs
        np.maximum(self.limiting, other.limiting, out=self.limiting)
        self.frames += other.frames
        self.frames_blurred += other.frames_blurred
        if self.last_obs_s is not None and other.last_obs_s is not None:
            np.maximum(self.last_obs_s, other.last_obs_s, out=self.last_obs_s)
            self.latest_frame_t_s = max(self.latest_frame_t_s, other.latest_frame_t_s)

    def save_npz(self, path: str | Path, *, with_limiting: bool = True) -> None:
        """Write a snapshot atomically (temp file, fsync, rename; core/grid_snapshot.py):
        pd, pfa, n_obs, mask, the log-miss sums, limiting (LimitingFactor per cell; not with
        ``with_limiting`` False, for a grid whose limiting factors are unknown), x0_m, y0_m
        (south-west corner of cell [0, 0]), cell_size_m, frames, the looks state, and with
        ``min_revisit_s`` each cell's last counted look, last_obs_s."""
        save_snapshot(self, path, with_limiting=with_limiting)

    def write_npz(self, fh: IO[bytes], *, with_limiting: bool = True) -> None:
        """Write the snapshot ``save_npz`` writes to an open binary file (the daemon sends
        these bytes over Zenoh: np.load reads them)."""
        write_snapshot(self, fh, with_limiting=with_limiting)

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
        snapshot = read_snapshot(path, data)
        grid = cls(snapshot.geometry, snapshot.mask, camera, detector, max_range_m=max_range_m,
                   min_revisit_s=min_revisit_s, terrain=terrain, exposure_s=exposure_s,
                   looks=looks)
        snapshot.restore(grid)
        return grid
