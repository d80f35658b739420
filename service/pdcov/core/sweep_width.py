"""Search theory's lateral range curve and effective sweep width (Koopman), from the grid.

The lateral range curve p(x) is the probability of detecting a person at lateral offset x
(m, east of the track, across it) from one straight, level pass; the effective sweep width
is W = integral p(x) dx (m): the width of a sensor that detects everything inside it and
nothing outside with the same detections per metre flown. Both come from a synthetic pass
through a fresh ``CoverageGrid`` (the same kernel, looks rule and revisit rule as every
other grid) over the flat ground z = 0, heading north, frames at the camera's rate; p(x) is
the cumulative P_D of the cells at offset x, averaged over rows that saw the whole pass
(at least ten frame steps of them, so that where the frames fall against the rows averages
out). Those rows are the grid: its cost is the band's cells times the frames that cross
the footprint's length, not the footprint's area.

For a flight of track length L (m) over an area A (m^2) the coverage factor is C = W L / A
and the probability of detection it implies is, for random search (Koopman's exponential
detection law), POD = 1 - exp(-C), and for perfectly spaced parallel sweeps with a definite
range law, POD = min(C, 1): the upper bound. pdcov's per-cell P_D is what the flight
actually gave each cell; its mean over the free cells is the search's real POD for a
uniform prior, and sits between the two for a well-flown pattern (docs/outputs.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.footprint import footprint_polygon
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_camera import default_max_range_m
from pdcov.core.looks import LooksConfig
from pdcov.core.pose import CameraPose, FixedMount, fixed_mount_pose
from pdcov.core.terrain import TerrainSurface

_AVERAGED_ROWS = 5  # p(x) is averaged over at least this many rows and _AVERAGED_STEPS
_AVERAGED_STEPS = 10  # frame steps: the frames' phase against the rows averages out
_MARGIN_CELLS = 2  # cells kept beyond the footprint on every side
MAX_PASS_FRAMES = 20_000
"""The most frames a synthetic pass may take: its cost is frames x the band's cells."""
SEARCH_SPEED_MIN_MPS = 0.5
"""Ground speeds below this (m/s: hovering, drifting, climbing) are not sweeping: the sweep
width is taken at the median of the faster frames' speeds."""


@dataclass(frozen=True, slots=True)
class LateralRange:
    """A lateral range curve: p (cumulative P_D of one pass) at cell-centre offsets_m (m,
    east of the track, + right of a northbound vehicle); sweep_width_m = sum(p) x cell size
    (m); frames: the pass's frames."""

    offsets_m: np.ndarray
    p: np.ndarray
    sweep_width_m: float
    frames: int


def lateral_range(camera: CameraModel, detector: DetectorModel, mount: FixedMount, *,
                  altitude_m: float, speed_mps: float, frame_rate_hz: float,
                  cell_size_m: float, min_revisit_s: float | None = None,
                  looks: LooksConfig | None = None, exposure_s: float | None = None,
                  max_range_m: float | None = None) -> LateralRange:
    """The lateral range curve of ``camera`` and ``detector`` on ``mount`` (level flight
    heading north) at ``altitude_m`` above flat ground, ``speed_mps`` and ``frame_rate_hz``,
    on cells of ``cell_size_m``; the other arguments as ``CoverageGrid``'s. The track lies
    on a column's centre; the pass is the footprint's length plus margins long, so that the
    averaged rows (the grid) see every frame that can see them. ValueError for a non-positive
    altitude, speed, frame rate or cell size, or a pass that would take more than
    MAX_PASS_FRAMES frames (a footprint long against the step between frames)."""
    for name, v in (("altitude_m", altitude_m), ("speed_mps", speed_mps),
                    ("frame_rate_hz", frame_rate_hz), ("cell_size_m", cell_size_m)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v}")
    c = cell_size_m
    step_m = speed_mps / frame_rate_hz
    reach_m = max_range_m or default_max_range_m(camera, detector, c)
    foot = footprint_polygon(camera, _pose(mount, 0.0, altitude_m, 0.0, speed_mps), reach_m)
    if foot.is_empty:
        return LateralRange(np.zeros(1), np.zeros(1), 0.0, 0)
    fx0, fy0, fx1, fy1 = foot.bounds  # about the camera's nadir point at (0, 0)
    half_cols = math.ceil(max(abs(fx0), abs(fx1)) / c) + _MARGIN_CELLS
    # The grid is the averaged band alone, rows [0, n_rows c): cells elsewhere would be
    # computed and thrown away, the whole footprint's length at every frame.
    n_rows = max(_AVERAGED_ROWS, math.ceil(_AVERAGED_STEPS * step_m / c))
    band_m = n_rows * c
    margin_m = _MARGIN_CELLS * c + step_m
    y_first, y_last = -fy1 - margin_m, band_m - fy0 + margin_m  # camera positions
    n_frames = math.ceil((y_last - y_first) / step_m) + 1
    if n_frames > MAX_PASS_FRAMES:
        raise ValueError(f"a pass would take {n_frames:,} frames (over {MAX_PASS_FRAMES:,}): "
                         f"a footprint {fy1 - fy0:.0f} m long at {step_m:.3g} m a frame")
    geometry = GridGeometry(-(half_cols + 0.5) * c, 0.0, c, n_rows, 2 * half_cols + 1)
    grid = CoverageGrid(geometry, np.ones(geometry.shape, bool), camera, detector,
                        max_range_m=max_range_m, min_revisit_s=min_revisit_s,
                        exposure_s=exposure_s, looks=looks)
    for k in range(n_frames):
        grid.update(_pose(mount, y_first + k * step_m, altitude_m, k / frame_rate_hz,
                          speed_mps))
    p = grid.pd.mean(axis=0)
    offsets = (np.arange(geometry.n_cols) - half_cols) * c
    return LateralRange(offsets, p, float(p.sum() * c), n_frames)


def _pose(mount: FixedMount, y_m: float, altitude_m: float, t_s: float,
          speed_mps: float) -> CameraPose:
    """The camera on ``mount`` of a level vehicle heading north at (0, y_m, altitude_m),
    moving north at ``speed_mps`` without turning (its motion known, for blur)."""
    pose = fixed_mount_pose(np.eye(3), np.array([0.0, y_m, altitude_m]), mount, t_s)
    return dataclasses.replace(pose, v_cam_enu_m_s=np.array([0.0, speed_mps, 0.0]),
                               omega_enu_rad_s=np.zeros(3))


@dataclass(frozen=True, slots=True)
class SearchEffort:
    """Koopman's figures of a search: sweep width W (m), track length L flown (m) and area
    A searched (m^2)."""

    sweep_width_m: float
    track_length_m: float
    area_m2: float

    @property
    def coverage_factor(self) -> float:
        """C = W L / A (dimensionless; 0 for an empty area)."""
        return self.sweep_width_m * self.track_length_m / self.area_m2 if self.area_m2 > 0 \
            else 0.0

    @property
    def pod_random_search(self) -> float:
        """POD of random search, the exponential detection law: 1 - exp(-C)."""
        return -math.expm1(-self.coverage_factor)

    @property
    def pod_parallel_sweeps(self) -> float:
        """POD of perfectly spaced parallel sweeps with a definite range law: min(C, 1), the
        upper bound for any pattern of the same effort."""
        return min(self.coverage_factor, 1.0)


@dataclass(frozen=True, slots=True)
class FlightSample:
    """What a flight's frames say of its search effort: heights_agl_m (N,) of the camera
    above the ground under it (m), speeds_mps (ground speeds between consecutive frames
    with a positive time step, m/s), track_length_m (horizontal path between consecutive
    frames, m), time_on_scene_s (first to last frame, s; flights added)."""

    heights_agl_m: np.ndarray
    speeds_mps: np.ndarray
    track_length_m: float
    time_on_scene_s: float = 0.0

    @classmethod
    def of(cls, poses: Sequence[CameraPose], terrain: TerrainSurface | None = None
           ) -> FlightSample:
        """The sample of ``poses`` (in time order), heights above ``terrain`` (None: above
        the plane z = 0)."""
        r = np.array([p.r_cam_enu for p in poses], dtype=float).reshape(-1, 3)
        t = np.array([p.t_s for p in poses], dtype=float)
        ground = (np.zeros(len(r)) if terrain is None
                  else np.asarray(terrain.height_m(r[:, 0], r[:, 1]), float))
        step = np.hypot(np.diff(r[:, 0]), np.diff(r[:, 1]))
        dt = np.diff(t)
        moving = np.isfinite(dt) & (dt > 0)
        span_s = float(t[-1] - t[0]) if len(t) > 1 and np.isfinite(t[[0, -1]]).all() else 0.0
        return cls(r[:, 2] - ground, step[moving] / dt[moving], float(step.sum()), span_s)

    @classmethod
    def joined(cls, samples: Sequence[FlightSample]) -> FlightSample:
        """Several flights' samples as one: heights and speeds together, lengths added."""
        return cls(np.concatenate([s.heights_agl_m for s in samples] or [np.zeros(0)]),
                   np.concatenate([s.speeds_mps for s in samples] or [np.zeros(0)]),
                   float(sum(s.track_length_m for s in samples)),
                   float(sum(s.time_on_scene_s for s in samples)))

    @property
    def sweeping(self) -> np.ndarray:
        """Which speeds_mps are a search's (at least SEARCH_SPEED_MIN_MPS)."""
        return self.speeds_mps >= SEARCH_SPEED_MIN_MPS

    @property
    def search_speed_mps(self) -> float:
        """The median of the sweeping speeds (m/s; NaN with none)."""
        fast = self.speeds_mps[self.sweeping]
        return float(np.median(fast)) if len(fast) else math.nan

    def unusable(self) -> str | None:
        """Why no sweep width can be computed from the sample (None: it can)."""
        if len(self.heights_agl_m) < 2:
            return f"{len(self.heights_agl_m)} frame(s): a sweep width needs at least 2"
        if not (self.sweeping.any() and self.track_length_m > 0):
            return (f"the camera never moved at {SEARCH_SPEED_MIN_MPS} m/s or more between "
                    "frames (or their times are unknown)")
        if not float(np.median(self.heights_agl_m)) > 0:
            return "the camera's median height above the ground is not positive"
        return None
