"""The coverage grid: cumulative P_D and P_FA per cell over camera frames (paper, III-C).

Accumulators are log-miss sums ``L = sum(log(1 - P(s)))`` so that ``P = 1 - exp(L)``; an update
is an addition, grids merge by adding, and frame order does not matter. This equals the
paper's recursion ``P(k) = P(k-1) + (1 - P(k-1)) P(s)``.

A cell is observed in a frame when the ray through its centre reaches the picture: in front
of the camera, inside the calibrated field of view, inside the image, within the maximum
range. Its apparent size is the square root of the area, in pixels, of its image inside the
picture, scaled to detector-input pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.core.camera import CameraModel
from pdcov.core.cell_area import clipped_quad_area, quad_area
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.footprint import footprint_ring_enu
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import InputFileError
from pdcov.npz_file import read_npz

SNAPSHOT_VERSION = 2  # 2: the revisit clock (last_obs_s) in float64; 1: float32
_READABLE_VERSIONS = (1, 2)
# Frame times closer than this count as equal in the revisit test: decimal times read from a
# file (0.1 s steps, or epoch times near 1.7e9 s with 2.4e-7 s float64 spacing) differ from
# their true differences by rounding well below it, so the same poses give the same grid
# whatever their time origin.
_REVISIT_TOL_S = 1e-6
# A version-1 revisit clock (float32) is used only where it resolves 1 ms: times below 2^13 s.
_FLOAT32_CLOCK_LIMIT_S = 2.0**13
_SUBDIVISIONS = 8  # sub-cells per side for cells only partly inside the picture


def default_max_range_m(camera: CameraModel, detector: DetectorModel,
                        cell_size_m: float) -> float:
    """Slant range (m) where a cell of ``cell_size_m`` on the optical axis looks half as large
    as the smallest size the detector model covers (beyond it P_D is 0 anyway)."""
    scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
    return 2.0 * camera.focal_px * cell_size_m * scale / max(detector.bin_edges_px[0], 1e-3)


@dataclass(frozen=True, slots=True)
class Metrics:
    """Summary of a grid. Proportions are of free cells; false alarms sum P_FA over observed
    free cells."""

    frames: int
    cells_free: int
    cells_observed: int
    proportion_at_or_above: dict[float, float]
    mean_pd: float
    expected_false_alarms: float


class CoverageGrid:
    """Cumulative detection and false-alarm probabilities over a grid of cells.

    geometry: the cells (ENU). mask: bool (n_rows, n_cols), True for free cells (only those
    are updated). max_range_m: slant range beyond which cells are not observed; None chooses
    ``default_max_range_m``. min_revisit_s: count at most one
    observation per cell per this many seconds (None: every frame counts, as in the paper).
    terrain: the ground under the cells (ENU, core/terrain.py); None: the plane z = 0.

    With ``min_revisit_s`` which look counts depends on the order of the frames, so frames
    must come in time order (``update`` refuses one earlier than the latest); times are kept
    in float64 seconds (any clock: boot time or Unix epoch give the same grid), and two times
    within 1 microsecond count as equal.
    """

    def __init__(self, geometry: GridGeometry, mask: np.ndarray, camera: CameraModel,
                 detector: DetectorModel, *, max_range_m: float | None = None,
                 min_revisit_s: float | None = None,
                 terrain: TerrainSurface | None = None) -> None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != geometry.shape:
            raise ValueError(f"mask shape {mask.shape} != grid shape {geometry.shape}")
        self.geometry = geometry
        self.mask = mask
        self.camera = camera
        self.detector = detector
        self.size_scale = detector.image_to_input_scale(camera.width_px, camera.height_px)
        if max_range_m is None:
            max_range_m = default_max_range_m(camera, detector, geometry.cell_size_m)
        if not max_range_m > 0:
            raise ValueError(f"max_range_m must be positive, got {max_range_m}")
        self.max_range_m = float(max_range_m)
        self.min_revisit_s = min_revisit_s
        self.terrain = terrain
        self.log_miss_d = np.zeros(geometry.shape, dtype=np.float32)
        self.log_miss_fa = np.zeros(geometry.shape, dtype=np.float32)
        self.n_obs = np.zeros(geometry.shape, dtype=np.int32)
        self.last_obs_s = (np.full(geometry.shape, -np.inf, dtype=np.float64)
                           if min_revisit_s else None)
        self.latest_frame_t_s = -math.inf  # latest frame time seen (s), with min_revisit_s
        self.frames = 0
        # The cells (r0, r1, c0, c1) the latest update may have changed, None for none: a
        # subscriber (the daemon's tiles and status) re-reads only those.
        self.touched: tuple[int, int, int, int] | None = None
        pd, pfa = detector.padded_tables()
        with np.errstate(divide="ignore"):
            self._log_miss_tables = (np.log1p(-pd).astype(np.float32),
                                     np.log1p(-pfa).astype(np.float32))
        # Bin edges as image areas (px^2), indexed by ``area dtype is float32``: (float64
        # edges, float32 edges), so that update compares areas with edges of their own dtype.
        area_edges = (np.asarray(detector.bin_edges_px, dtype=np.float64) / self.size_scale) ** 2
        self._area_edges_px2 = (area_edges, area_edges.astype(np.float32))

    # -- results ----------------------------------------------------------------------------

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
        )

    # -- update -----------------------------------------------------------------------------

    def update(self, pose: CameraPose, t_s: float | None = None) -> int:
        """Add one camera frame; returns the number of free cells it observed, and sets
        ``touched`` to the window of cells it may have changed.

        t_s (s, autopilot clock) defaults to ``pose.t_s``; it is only used with
        ``min_revisit_s``, and must then not go back in time (ValueError, nothing counted).
        """
        t = float(pose.t_s if t_s is None else t_s)
        self.touched = None
        if self.last_obs_s is not None:
            if not math.isfinite(t):
                raise ValueError(f"min_revisit_s needs frame times: pose.t_s or t_s, got {t}")
            if t < self.latest_frame_t_s - _REVISIT_TOL_S:
                raise ValueError(f"min_revisit_s needs frames in time order: t_s = {t!r} s "
                                 f"after a frame at {self.latest_frame_t_s!r} s")
            self.latest_frame_t_s = max(self.latest_frame_t_s, t)
        self.frames += 1
        window = self._window(pose)
        if window is None:
            return 0
        r0, r1, c0, c1 = window
        self.touched = window
        observed, area_px2 = self._observe_area(pose, window)
        if self.last_obs_s is not None:
            if self.min_revisit_s is None:  # only if min_revisit_s was cleared after __init__
                raise TypeError("min_revisit_s is None but last_obs_s is kept")
            last = self.last_obs_s[r0:r1, c0:c1]
            observed &= (t - last) >= self.min_revisit_s - _REVISIT_TOL_S
            last[observed] = t
        # Bin by area against squared edges: sqrt(area) * scale >= edge <=> area >= edge'^2.
        # Unobserved cells take index 0, whose log-miss is 0: the additions below are dense
        # over the window (cheaper than masked scatters) and leave those cells unchanged.
        edges = self._area_edges_px2[area_px2.dtype == np.float32]
        with np.errstate(invalid="ignore"):
            idx = np.searchsorted(edges, area_px2, side="right")
        idx *= observed
        tab_d, tab_fa = self._log_miss_tables
        self.log_miss_d[r0:r1, c0:c1] += tab_d.take(idx)
        self.log_miss_fa[r0:r1, c0:c1] += tab_fa.take(idx)
        self.n_obs[r0:r1, c0:c1] += observed
        return int(np.count_nonzero(observed))

    def observe(self, pose: CameraPose, window: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, np.ndarray]:
        """Cells of ``window`` (r0, r1, c0, c1) observed by ``pose``, and their apparent size.

        Returns a bool mask (r1 - r0, c1 - c0) and, for the True cells in row-major order, the
        square root of the area in image pixels of each cell's image inside the picture.
        """
        observed, area_px2 = self._observe_area(pose, window)
        return observed, np.sqrt(area_px2[observed].astype(np.float64))

    def _observe_area(self, pose: CameraPose, window: tuple[int, int, int, int]
                      ) -> tuple[np.ndarray, np.ndarray]:
        """The observed mask of ``window`` and the image area (px^2) inside the picture of
        every cell of it (meaningful only where observed; float32 or float64)."""
        r0, r1, c0, c1 = window
        n_rows, n_cols = r1 - r0, c1 - c0
        g = self.geometry
        cs = g.cell_size_m
        cam = self.camera
        r = pose.r_cam_enu
        # The window's cell corners form a lattice on the ground; the corner (col c0 + j,
        # row r0 + i) is, in the optical frame, R_cam_enu @ ([x, y, 0] - r) = H @ [j, i, 1].
        H = pose.R_enu_cam.T @ np.array([[cs, 0.0, g.x0_m + cs * c0 - r[0]],
                                         [0.0, cs, g.y0_m + cs * r0 - r[1]],
                                         [0.0, 0.0, -r[2]]])
        H_centre = H.copy()
        H_centre[:, 2] += 0.5 * (H[:, 0] + H[:, 1])
        # Cell centres: free, in range, in the picture, in the calibrated field of view.
        dx2 = (g.x0_m + cs * (np.arange(c0, c1) + 0.5) - r[0]) ** 2
        dy2 = (g.y0_m + cs * (np.arange(r0, r1) + 0.5) - r[1]) ** 2
        observed = self.mask[r0:r1, c0:c1] & (
            dy2[:, None] + (dx2 + r[2] ** 2) <= self.max_range_m**2)
        # Behind the camera the maps hold meaningless values; the tests below reject those.
        with np.errstate(invalid="ignore", over="ignore"):
            observed &= cam.in_picture(cam.project_lattice(H_centre, n_cols, n_rows))
            if not observed.any():
                return observed, np.zeros(observed.shape)
            j = np.arange(n_cols, dtype=np.float64)
            i = np.arange(n_rows, dtype=np.float64)[:, None]
            observed &= cam.in_fov_xyz(*(H_centre[k, 0] * j + (H_centre[k, 1] * i
                                                               + H_centre[k, 2])
                                         for k in range(3)))
            # Corners, projected all at once: a cell wholly in the picture takes the area of
            # its corners' quadrilateral.
            px_v = cam.project_lattice(H, n_cols + 1, n_rows + 1)
            v_in = cam.in_picture(px_v)
            corners = np.array([[0, 0, 1], [n_cols, 0, 1], [0, n_rows, 1],
                                [n_cols, n_rows, 1]])
            v_ok = None  # all projectable
            if not cam.all_projectable(corners @ H.T):
                jj, ii = np.meshgrid(np.arange(n_cols + 1), np.arange(n_rows + 1))
                v_ok = cam.projectable(jj[..., None] * H[:, 0] + ii[..., None] * H[:, 1]
                                       + H[:, 2])
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
        return observed, area

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
        p_enu = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3)
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

    def _window(self, pose: CameraPose) -> tuple[int, int, int, int] | None:
        """(r0, r1, c0, c1): the grid cells that may be observed, from the footprint's extent
        padded by one cell and by the chord error of the sampled border."""
        ring = footprint_ring_enu(self.camera, pose, self.max_range_m)
        if len(ring) == 0:
            return None
        g = self.geometry
        pad = 1.5 * g.cell_size_m + 0.01 * self.max_range_m
        row_lo, col_lo = g.cell_of(ring[:, 0].min() - pad, ring[:, 1].min() - pad)
        row_hi, col_hi = g.cell_of(ring[:, 0].max() + pad, ring[:, 1].max() + pad)
        r0, r1 = max(int(row_lo), 0), min(int(row_hi) + 1, g.n_rows)
        c0, c1 = max(int(col_lo), 0), min(int(col_hi) + 1, g.n_cols)
        if r0 >= r1 or c0 >= c1:
            return None
        return r0, r1, c0, c1

    # -- combine and persist ----------------------------------------------------------------

    def merge(self, other: CoverageGrid) -> None:
        """Add another grid of the same geometry (another flight or vehicle) into this one."""
        if other.geometry != self.geometry or not np.array_equal(other.mask, self.mask):
            raise ValueError("cannot merge grids of different geometry or free-space mask")
        self.log_miss_d += other.log_miss_d
        self.log_miss_fa += other.log_miss_fa
        self.n_obs += other.n_obs
        self.frames += other.frames
        if self.last_obs_s is not None and other.last_obs_s is not None:
            np.maximum(self.last_obs_s, other.last_obs_s, out=self.last_obs_s)
            self.latest_frame_t_s = max(self.latest_frame_t_s, other.latest_frame_t_s)

    def save_npz(self, path: str | Path) -> None:
        """Write a snapshot atomically (temp file, fsync, rename): pd, pfa, n_obs, mask, the
        log-miss sums, x0_m, y0_m (south-west corner of cell [0, 0]), cell_size_m, frames, and
        with ``min_revisit_s`` each cell's last counted look, last_obs_s."""
        with atomic_write(path, "wb") as fh:
            self.write_npz(fh)

    def write_npz(self, fh: IO[bytes]) -> None:
        """Write the snapshot ``save_npz`` writes to an open binary file (the daemon sends
        these bytes over Zenoh: np.load reads them)."""
        g = self.geometry
        revisit = {} if self.last_obs_s is None else {"last_obs_s": self.last_obs_s}
        np.savez_compressed(
            fh, version=SNAPSHOT_VERSION, pd=self.pd, pfa=self.pfa, n_obs=self.n_obs,
            mask=self.mask, log_miss_d=self.log_miss_d, log_miss_fa=self.log_miss_fa,
            x0_m=g.x0_m, y0_m=g.y0_m, cell_size_m=g.cell_size_m, frames=self.frames,
            **revisit)  # type: ignore[arg-type]  # mypy matches **revisit to allow_pickle

    @classmethod
    def load_npz(cls, path: str | Path, camera: CameraModel, detector: DetectorModel,
                 *, max_range_m: float | None = None, min_revisit_s: float | None = None,
                 terrain: TerrainSurface | None = None) -> CoverageGrid:
        """Restore a snapshot written by ``save_npz`` (version 2, or 1). A version-1 revisit
        clock (float32) is refused where it cannot resolve a millisecond (times of 2^13 s and
        more, e.g. Unix epoch times) when ``min_revisit_s`` would use it."""
        path = Path(path)
        data = read_npz(path, lambda why: InputFileError(
            f"{path}: cannot read grid snapshot ({why})"))
        missing = {"mask", "log_miss_d", "log_miss_fa", "n_obs", "x0_m", "y0_m",
                   "cell_size_m"} - set(data)
        if missing:
            raise InputFileError(f"{path}: not a pdcov grid snapshot (missing "
                                 f"{', '.join(sorted(missing))})")
        version = int(data.get("version", 1))
        if version not in _READABLE_VERSIONS:
            raise InputFileError(f"{path}: grid snapshot version {version}, expected "
                                 f"{' or '.join(map(str, _READABLE_VERSIONS))}")
        _check_snapshot_values(path, data)
        mask = data["mask"].astype(bool)
        geometry = GridGeometry(float(data["x0_m"]), float(data["y0_m"]),
                                float(data["cell_size_m"]), *mask.shape)
        grid = cls(geometry, mask, camera, detector, max_range_m=max_range_m,
                   min_revisit_s=min_revisit_s, terrain=terrain)
        grid.log_miss_d[:] = data["log_miss_d"]
        grid.log_miss_fa[:] = data["log_miss_fa"]
        grid.n_obs[:] = data["n_obs"]
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
                       ("last_obs_s", "f")):
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
