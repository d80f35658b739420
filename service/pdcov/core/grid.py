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

A frame may be taken with another camera than the grid's own (``update_with``: a zoomed
lens, core/zoom.py, or another camera with its own detector model; its ``GridCamera``).
Its looks add into the same cells' sums, as do another grid's (``merge``): as independent,
p1 and p2 on a cell give 1 - (1 - p1)(1 - p2), or by the looks rule below (different
detectors combine at its quadrature nodes; a mission's cameras: core/combine_cameras.py).

The per-cell arrays are kept in tiles (core/tiles.py) allocated when a frame first touches
them: a grid over a county holds only what was seen. ``read`` gives any window of a layer,
``layer`` its tiles; ``pd``, ``n_obs``, ... the whole grid, read-only.

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
from pathlib import Path
from typing import IO

import numpy as np

from pdcov.core.blur import BlurEffect, blur_effect
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid_camera import GridCamera
from pdcov.core.grid_layer import Layer
from pdcov.core.grid_merge import merge_grids
from pdcov.core.grid_metrics import Metrics, grid_metrics, limiting_counts
from pdcov.core.grid_snapshot import read_snapshot, save_snapshot, write_snapshot
from pdcov.core.grid_view import GridView, window_union
from pdcov.core.ground_cover import through_cover
from pdcov.core.last_look import LastLook
from pdcov.core.limiting import LimitingFactor
from pdcov.core.looks import (
    QUADRATURE,
    CorrelatedLooks,
    LooksConfig,
    LooksModel,
    ViewpointLooks,
    looks_model,
)
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface
from pdcov.core.tiles import TileClock, TiledLayer, TileKey, TilePart, Window

# Frame times closer than this count as equal in the revisit test: decimal times read from a
# file (0.1 s steps, or epoch times near 1.7e9 s with 2.4e-7 s float64 spacing) differ from
# their true differences by rounding well below it, so the same poses give the same grid
# whatever their time origin.
_REVISIT_TOL_S = 1e-6
_MAX_CAMERAS = 256  # GridCamera values kept (each distinct zoom of a frame is one)


class _WholeLayer:
    """A grid's layer as one read-only array (``TiledLayer.dense``)."""

    def __init__(self, layer: Layer) -> None:
        self.layer = layer

    def __get__(self, grid: CoverageGrid, owner: type) -> np.ndarray:
        return grid.layer(self.layer).dense()


class CoverageGrid:
    """Cumulative detection and false-alarm probabilities over a grid of cells.

    geometry: the cells (ENU). free: the free cells (only those are updated): a bool
    (n_rows, n_cols) mask, or ``FreeCells`` (tile by tile from the domain's free space).
    max_range_m: slant range beyond which cells are not observed; None chooses
    ``default_max_range_m``. terrain: the ground under the cells and what stands on it
    (ENU, core/terrain.py; None: the plane z = 0).
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

    def __init__(self, geometry: GridGeometry, free: np.ndarray | FreeCells,
                 camera: CameraModel, detector: DetectorModel, *,
                 max_range_m: float | None = None,
                 min_revisit_s: float | None = None,
                 terrain: TerrainSurface | None = None,
                 exposure_s: float | None = None,
                 looks: LooksConfig | None = None) -> None:
        if not isinstance(free, FreeCells):
            free = FreeCells(geometry, mask=free)
        elif free.geometry != geometry:
            raise ValueError("the free cells are of another grid geometry")
        layout = free.layout
        if terrain is not None and terrain.geometry != geometry:
            raise ValueError("terrain is for another grid geometry")
        self.terrain = terrain
        self.geometry = geometry
        self.layout = layout
        self.free = free
        self._view = GridView.over(geometry, free, terrain)
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
        self.looks = LooksConfig() if looks is None else looks
        self._looks = looks_model(self.looks, detector)
        if self._looks is not None and self._view.covered is not None:
            raise ValueError("terrain.cover scales P_D per look: only with independent looks")
        clock = self.clock = TileClock()
        self._layers: dict[Layer, TiledLayer] = {
            Layer.LOG_MISS_D: TiledLayer(layout, np.float32, 0.0, clock=clock),
            Layer.LOG_MISS_FA: TiledLayer(layout, np.float32, 0.0, clock=clock),
            Layer.N_OBS: TiledLayer(layout, np.int32, 0, clock=clock),
            Layer.LIMITING: TiledLayer(layout, np.uint8, LimitingFactor.NEVER_IN_VIEW,
                                       clock=clock)}
        if min_revisit_s:
            self._layers[Layer.LAST_OBS_S] = TiledLayer(layout, np.float64, -np.inf,
                                                        clock=clock)
        if self._looks is not None:
            self._layers[Layer.LOOKS] = TiledLayer(layout, self._looks.dtype, 0,
                                                   self._looks.depth, clock)
        # Cells whose looks changed since log_miss_d was last derived, per tile.
        self._dirty: dict[TileKey, np.ndarray] = {}
        self.latest_frame_t_s = -math.inf  # latest frame time seen (s), with min_revisit_s
        self.frames = 0
        # The cells (r0, r1, c0, c1) the latest update may have changed, None for none: a
        # subscriber (the daemon's tiles and status) re-reads only those.
        self.touched: Window | None = None
        # The latest update's look of the cells of its window (None: no cell in view).
        self.last_look: LastLook | None = None

    # -- results ----------------------------------------------------------------------------

    def layer(self, layer: Layer) -> TiledLayer:
        """A stored layer's tiles, to read tile by tile (``read`` for windows); log_miss_d
        up to date (``refresh``). KeyError for a layer the grid does not keep (the revisit
        clock without ``min_revisit_s``, looks with independent looks)."""
        if layer is Layer.LOG_MISS_D:
            self.refresh()
        return self._layers[layer]

    def keeps(self, layer: Layer) -> bool:
        """Whether the grid keeps ``layer`` (every layer but the revisit clock and the
        looks state, which come with ``min_revisit_s`` and correlated or viewpoint looks)."""
        return layer in self._layers or layer in (Layer.MASK, Layer.PD, Layer.PFA)

    def read(self, layer: Layer, window: Window | None = None) -> np.ndarray:
        """The cells of ``window`` (r0, r1, c0, c1; None: the whole grid) of ``layer``: a
        new array."""
        w = window or (0, self.geometry.n_rows, 0, self.geometry.n_cols)
        if layer is Layer.MASK:
            return np.array(self.free.window(w))
        if layer in (Layer.PD, Layer.PFA):
            log_miss = self.read(Layer.LOG_MISS_D if layer is Layer.PD else Layer.LOG_MISS_FA,
                                 w)
            out: np.ndarray = 0.0 - np.expm1(log_miss.astype(np.float64))  # 0.0 -: no -0.0
            return out
        return self.layer(layer).read(w)

    def tile_keys(self, since: int = 0) -> list[TileKey]:
        """The tiles written (any layer) after ``clock.now`` was ``since`` (0: every tile
        a frame touched), row by row."""
        keys: set[TileKey] = set()
        for lay in self._layers.values():
            keys.update(lay.changed_since(since))
        return sorted(keys)

    def written_windows(self) -> list[Window]:
        """Each written tile's cells, row by row (``CellSource``)."""
        return [self.layout.window_of(key) for key in self.tile_keys()]

    @property
    def n_free(self) -> int:
        """Free cells in the whole grid."""
        return self.free.n_free

    @property
    def nbytes(self) -> int:
        """Bytes held by the grid's tiles."""
        return sum(lay.nbytes for lay in self._layers.values())

    # The whole grid's layers as read-only arrays (up to ``tiles.MAX_DENSE_CELLS`` cells):
    # log(1 - P_D) (float32, <= 0: the running sum with independent looks, else derived from
    # the looks state), log(1 - P_FA) (float32, <= 0), counted looks (int32), LimitingFactor
    # (uint8).
    log_miss_d = _WholeLayer(Layer.LOG_MISS_D)
    log_miss_fa = _WholeLayer(Layer.LOG_MISS_FA)
    n_obs = _WholeLayer(Layer.N_OBS)
    limiting = _WholeLayer(Layer.LIMITING)

    @property
    def last_obs_s(self) -> np.ndarray | None:
        """Each cell's last counted look (s, float64, -inf: none; the whole grid,
        read-only), None without ``min_revisit_s``."""
        return self.layer(Layer.LAST_OBS_S).dense() if self.keeps(Layer.LAST_OBS_S) else None

    @property
    def mask(self) -> np.ndarray:
        """The free cells (bool; the whole grid, read-only)."""
        return self.free.dense()

    @property
    def camera(self) -> CameraModel:
        """The grid's own camera (``update_with`` may evaluate a frame with another)."""
        return self._base.camera

    @property
    def detector(self) -> DetectorModel:
        """The grid's own detector model (``update_with`` may evaluate a frame with
        another)."""
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
    def looks_model(self) -> LooksModel | None:
        """The model of the per-cell looks state (``core/looks.py``; its cells: the LOOKS
        layer); None with independent looks."""
        return self._looks

    def refresh(self) -> None:
        """Derive ``log_miss_d`` of the cells whose looks changed since the last read."""
        looks = self._looks
        if not self._dirty or looks is None:
            return
        state, log_miss_d = self._layers[Layer.LOOKS], self._layers[Layer.LOG_MISS_D]
        for key, dirty in self._dirty.items():
            rows, cols = np.nonzero(dirty)
            log_miss_d.tile(key)[rows, cols] = looks.log_miss_of(state.tiles[key][rows, cols])
        self._dirty = {}

    def log_miss_nodes(self, window: Window | None = None) -> np.ndarray:
        """Per cell of ``window`` (r0, r1, c0, c1; None: the whole grid), log P_miss given the
        person's latent quantile at each ``looks.QUADRATURE`` node: (rows, cols, J) float64.
        For grids of different cameras or detectors seeing the same person: sum theirs and
        take ``looks.pd_of_node_log_miss``. Independent and viewpoint grids do not depend
        on the latent: their log-miss at every node."""
        w = window or (0, self.geometry.n_rows, 0, self.geometry.n_cols)
        if isinstance(self._looks, CorrelatedLooks):
            return self._looks.log_miss_nodes(self.read(Layer.LOOKS, w))
        flat = self.read(Layer.LOG_MISS_D, w).astype(np.float64)
        return np.repeat(flat[..., None], len(QUADRATURE.q), axis=2)

    def mark_looks_changed(self, window: Window, cells: np.ndarray | None = None) -> None:
        """The looks state of ``cells`` (bool, the window's shape; None: all) of ``window``
        changed: their ``log_miss_d`` is derived again when next read."""
        if self._looks is None:
            raise TypeError("only a grid with a looks state has cells to refresh")
        for p in self.layout.parts(window):
            dirty = self._dirty.get(p.key)
            if dirty is None:
                dirty = self._dirty[p.key] = np.zeros(self.layout.shape_of(p.key), bool)
            if cells is None:
                dirty[p.in_tile] = True
            else:
                dirty[p.in_tile] |= cells[p.in_window]

    @property
    def pd(self) -> np.ndarray:
        """Cumulative probability of detection per cell (float64, 0 where not free)."""
        return 0.0 - np.expm1(self.log_miss_d.astype(np.float64))  # 0.0 - : no -0.0

    @property
    def pfa(self) -> np.ndarray:
        """Cumulative probability of false alarm per cell (float64)."""
        return 0.0 - np.expm1(self.log_miss_fa.astype(np.float64))

    def metrics(self, thresholds: tuple[float, ...] | list[float]) -> Metrics:
        """The grid's summary (core/grid_metrics.py)."""
        return grid_metrics(self, thresholds)

    def limiting_counts(self) -> dict[str, int]:
        """Free cells per LimitingFactor, by lower-case name, in code order."""
        return limiting_counts(self.layer(Layer.LIMITING).tiles, self.free)

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
        """``update`` of a frame taken with camera and detector model ``frame``: the
        window's values computed at once, added tile by tile."""
        t = float(pose.t_s if t_s is None else t_s)
        self.touched = None
        self.last_look = None
        revisit = self._layers.get(Layer.LAST_OBS_S)
        if revisit is not None:
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
        layers = self._layers
        window, clipped = view.window(frame, pose)
        far = (view.mark_too_far(frame, pose, window, layers[Layer.LIMITING]) if clipped
               else None)
        self.touched = window_union(window, far)
        if window is None:
            return 0
        observed, area_px2, reach, transmit = view.observe_area(frame, pose, window)
        # Bin by area against squared edges: sqrt(area) * scale >= edge <=> area >= edge'^2.
        edges = frame.area_edges_px2[area_px2.dtype == np.float32]
        with np.errstate(invalid="ignore"):
            idx = np.searchsorted(edges, area_px2, side="right")
        seen = view.limiting(frame, window, observed, idx, reach)
        parts = list(self.layout.parts(window))
        in_view, size_idx = observed, idx
        if revisit is not None:
            if self.min_revisit_s is None:  # only if min_revisit_s was cleared after __init__
                raise TypeError("min_revisit_s is None but last_obs_s is kept")
            counted = np.zeros_like(observed)
            for p in parts:
                last = revisit.tile(p.key)[p.in_tile]
                ok = observed[p.in_window] & ((t - last) >= self.min_revisit_s - _REVISIT_TOL_S)
                last[ok] = t
                counted[p.in_window] = ok
            observed = counted
        # Unobserved cells take index 0, whose log-miss is 0: the additions below are dense
        # over the window (cheaper than masked scatters) and leave those cells unchanged.
        idx = idx * observed
        if blurred:
            assert self.exposure_s is not None  # blur_effect is APPLIED
            idx += frame.blur_rows(pose, self.geometry, self._view.relief, window, observed,
                                   self.exposure_s) * (frame.detector.n_bins + 2)
        tab_d, tab_fa = tables = frame.log_miss_tables
        self.last_look = LastLook(t, window, in_view, observed, size_idx, idx, area_px2, tables,
                                  transmit)
        add_d = None if self._looks else through_cover(tab_d.take(idx), transmit, observed)
        add_fa = np.multiply(  # log(1 - P_FA) = -rate A (in view)
            tab_fa.take(idx), area_px2, out=np.zeros(idx.shape, np.float32), where=observed)
        for p in parts:
            key, tile, win = p.key, p.in_tile, p.in_window
            limiting = layers[Layer.LIMITING].tile(key)[tile]
            np.maximum(limiting, seen[win], out=limiting)
            if add_d is not None:
                layers[Layer.LOG_MISS_D].tile(key)[tile] += add_d[win]
            layers[Layer.LOG_MISS_FA].tile(key)[tile] += add_fa[win]
            layers[Layer.N_OBS].tile(key)[tile] += observed[win]
        if add_d is None:
            self._add_looks(pose, window, idx, parts)
        return int(np.count_nonzero(observed))

    def _add_looks(self, pose: CameraPose, window: Window, idx: np.ndarray,
                   parts: list[TilePart]) -> None:
        """Count the looks of a frame (padded bin index ``idx`` per cell of ``window``, 0
        where not counted) in the looks state, tile by tile."""
        looks, state = self._looks, self._layers[Layer.LOOKS]
        r0, r1, c0, c1 = window
        if isinstance(looks, ViewpointLooks):
            g = self.geometry
            x = g.x0_m + g.cell_size_m * (np.arange(c0, c1) + 0.5)
            y = g.y0_m + g.cell_size_m * (np.arange(r0, r1) + 0.5)
            relief = self._view.relief
            z = (np.zeros((r1 - r0, c1 - c0)) if relief is None
                 else relief.centre_z_m(r0, r1, c0, c1))
        counted = np.zeros(idx.shape, dtype=bool)
        for p in parts:
            cells = state.tile(p.key)[p.in_tile]
            win = p.in_window
            if isinstance(looks, CorrelatedLooks):
                counted[win] = looks.add(cells, idx[win])
            elif isinstance(looks, ViewpointLooks):
                counted[win] = looks.add(cells, idx[win], x[win[1]], y[win[0]], z[win],
                                         pose.r_cam_enu)
        self.mark_looks_changed(window, counted)

    def observe(self, pose: CameraPose, window: Window) -> tuple[np.ndarray, np.ndarray]:
        """Cells of ``window`` (r0, r1, c0, c1) observed by ``pose``, and their apparent size.

        Returns a bool mask (r1 - r0, c1 - c0) and, for the True cells in row-major order, the
        square root of the area in image pixels of each cell's image inside the picture."""
        observed, area_px2, _, _ = self._view.observe_area(self._base, pose, window)
        return observed, np.sqrt(area_px2[observed].astype(np.float64))

    # -- combine and persist ----------------------------------------------------------------

    def merge(self, other: CoverageGrid) -> None:
        """Add another grid of the same geometry (another flight or vehicle) into this one
        (core/grid_merge.py)."""
        merge_grids(self, other)

    def save_npz(self, path: str | Path, *, with_limiting: bool = True) -> None:
        """Write a snapshot atomically (temp file, fsync, rename; core/grid_snapshot.py)."""
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
        """Restore a snapshot written by ``save_npz`` (any readable version,
        core/grid_snapshot.py), from ``path``, or from its bytes ``data`` (``path`` then
        names it in messages). A version-1 revisit clock (float32) is refused where it
        cannot resolve a millisecond (times of 2^13 s and more, e.g. Unix epoch times) when
        ``min_revisit_s`` would use it. A snapshot of another looks rule than ``looks`` is
        refused (versions 1 and 2 are independent)."""
        snapshot = read_snapshot(path, data)
        grid = cls(snapshot.geometry, snapshot.mask, camera, detector, max_range_m=max_range_m,
                   min_revisit_s=min_revisit_s, terrain=terrain, exposure_s=exposure_s,
                   looks=looks)
        snapshot.restore(grid)
        return grid
