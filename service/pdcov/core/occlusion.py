"""Terrain occlusion: does the terrain between the camera and a ground point rise above the
line of sight? A radial horizon test, vectorised over a frame's cells.

Seen from above the camera's nadir point N, the line of sight to a target point P runs
along the ground radial from N through P, descending linearly from the camera's height to
P's. The terrain at ground distance rho on that radial hides P when its elevation tangent
``(z - z_cam) / rho`` exceeds P's own. So per frame the targets' azimuths are split into
bins (half a cell wide at the farthest target), and along each bin's radial the terrain is
sampled where the radial crosses the grid's lines x = const and y = const: there the
bilinear surface is the straight line between two corners, so ridges and walls along grid
lines are met exactly. The running maximum of the elevation tangent along each radial
(crossings of x lines and of y lines each form an arithmetic sequence in rho, so a target's
place in them is computed, not searched) is the horizon; a target is hidden when its
tangent is below the horizon of the crossings nearer than it by more than half a cell (its
own surface). A target between two bins takes the higher of their two horizons, so a ridge
passing within one bin of the line of sight hides it: the test errs towards hiding, never
towards counting unseen ground as seen.

The radials are only sampled where the terrain could rise above some line of sight (from
the highest terrain between the camera and the targets), so the cost follows the footprint,
not the distance from the nadir point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdcov.core.terrain import TerrainSurface

__all__ = ["hidden_by_terrain", "sight_clear"]

_MAX_AZIMUTH_BINS = 4096
_TAN_TOL = 1e-9  # elevation tangents closer than this count as equal (not hidden)
# ``sight_clear``'s margin over the steepest slope, relative and in metres: far above the
# rounding of the facing test's sums (~1e-13 m), far below any terrain's detail.
_CLEAR_REL = 1e-6
_CLEAR_ABS_M = 1e-6
_COS_80 = math.cos(math.radians(80.0))


def hidden_by_terrain(terrain: TerrainSurface, r_cam_enu: np.ndarray, x_m: np.ndarray,
                      y_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """True where the terrain hides the points (x_m, y_m, z_m) (ENU, on the terrain) from a
    camera at ``r_cam_enu``; points within half a cell of the camera's nadir never are."""
    g = terrain.geometry
    cs = g.cell_size_m
    skip = 0.5 * cs  # the target's own surface
    hidden = np.zeros(np.shape(x_m), dtype=bool)
    if hidden.size == 0:
        return hidden
    cx, cy, cz = (float(v) for v in r_cam_enu)
    box = _cells_between(terrain, cx, cy, x_m, y_m)
    if box is None:
        return hidden
    rho = np.hypot(x_m - cx, y_m - cy)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_t = (z_m - cz) / rho
    # Walking from a target towards the camera its line of sight rises by -tan_t per metre
    # and the terrain by at most its steepest slope: where the line of sight is steeper,
    # the terrain never reaches it. Only the others are tested.
    test = (tan_t >= -terrain.window_max_slope(*box)) & (rho > skip)
    if not test.any():
        return hidden
    if not test.all():
        x_m, y_m, rho, tan_t = x_m[test], y_m[test], rho[test], tan_t[test]
        box = _cells_between(terrain, cx, cy, x_m, y_m)
        assert box is not None
    z_max = terrain.window_z_range_m(*box)[1]
    rho_end = float(rho.max()) - skip
    lowest = float(tan_t.min())
    # Terrain at rho can only rise above a tangent t >= lowest where (z_max - cz) / rho
    # > lowest: before rho_start every line of sight is above all terrain.
    rho_start = 1e-3 * cs
    if cz > z_max and lowest < 0:
        rho_start = max(rho_start, (cz - z_max) / -lowest)
    if rho_start >= rho_end:
        return hidden
    bins = _AzimuthBins.of(x_m - cx, y_m - cy, rho, 0.5 * cs / rho_end)
    # Radials 0..n-1 meet the lines x = const, n..2n-1 the lines y = const.
    first, inv_spacing, h_run = _line_crossings(terrain, cx, cy, cz, bins.azimuth_rad,
                                                rho_start, rho_end)
    n = len(bins.azimuth_rad)
    n_cols = h_run.shape[1]
    ia = bins.index
    ib = np.minimum(ia + 1, n - 1)
    rows = np.stack([ia, ib, ia + n, ib + n])
    with np.errstate(invalid="ignore"):
        m = np.floor((rho - skip - first.take(rows)) * inv_spacing.take(rows))
    # Column 0 of h_run is -inf: no crossing before the target.
    at = rows * n_cols + np.clip(np.nan_to_num(m, nan=-1.0) + 1, 0, n_cols - 1
                                 ).astype(np.intp)
    hidden[test] = tan_t < h_run.take(at).max(axis=0) - _TAN_TOL
    return hidden


def sight_clear(terrain: TerrainSurface, r_cam_enu: np.ndarray,
                window: tuple[int, int, int, int], z_centre_m: np.ndarray) -> np.ndarray:
    """True for the cells of ``window`` (r0, r1, c0, c1), their centres at heights
    ``z_centre_m`` (m, ENU; the window's shape), whose line of sight from the camera at
    ``r_cam_enu`` descends more steeply than the steepest terrain S (m/m) between the window
    and the camera's nadir point: no terrain rises above it (``hidden_by_terrain`` prunes
    such targets, with a box no larger), and the cell faces the camera (a cell's plane
    through its diagonals has a gradient of at most S, so its normal (n_xy, 2 cs) meets the
    camera's offset (d_xy, dz) at n . d >= 2 cs (dz - S |d_xy|) > 0). A margin of 1e-6
    (relative) and 1e-6 m keeps rounding out: the cells it leaves out are tested exactly."""
    g = terrain.geometry
    cs = g.cell_size_m
    r0, r1, c0, c1 = window
    cx, cy, cz = (float(v) for v in r_cam_enu)
    row, col = (int(v) for v in g.cell_of(np.array(cx), np.array(cy)))
    box = (max(min(r0, row) - 1, 0), min(max(r1, row + 1) + 1, g.n_rows),
           max(min(c0, col) - 1, 0), min(max(c1, col + 1) + 1, g.n_cols))
    slope = terrain.window_max_slope(*box) * (1.0 + _CLEAR_REL)
    # First for the whole window at once: its highest terrain from its farthest corner.
    rho_far = math.hypot(max(cx - (g.x0_m + cs * c0), g.x0_m + cs * c1 - cx),
                         max(cy - (g.y0_m + cs * r0), g.y0_m + cs * r1 - cy))
    if cz - terrain.window_z_range_m(*window)[1] > slope * rho_far + _CLEAR_ABS_M:
        return np.ones(z_centre_m.shape, dtype=bool)
    dx = g.x0_m + cs * (np.arange(c0, c1) + 0.5) - cx
    dy = g.y0_m + cs * (np.arange(r0, r1) + 0.5) - cy
    rho = np.sqrt((dy * dy)[:, None] + dx * dx)
    return cz - z_centre_m > slope * rho + _CLEAR_ABS_M


def _cells_between(terrain: TerrainSurface, cx: float, cy: float, x_m: np.ndarray,
                   y_m: np.ndarray) -> tuple[int, int, int, int] | None:
    """(r0, r1, c0, c1): the cells under the camera's nadir point (cx, cy) and the targets,
    with one cell of margin (a bin's radial passes within a cell of its targets'); None
    when that lies off the grid."""
    g = terrain.geometry
    lo = g.cell_of(np.array(min(cx, float(x_m.min()))), np.array(min(cy, float(y_m.min()))))
    hi = g.cell_of(np.array(max(cx, float(x_m.max()))), np.array(max(cy, float(y_m.max()))))
    r0, c0 = max(int(lo[0]) - 1, 0), max(int(lo[1]) - 1, 0)
    r1, c1 = min(int(hi[0]) + 2, g.n_rows), min(int(hi[1]) + 2, g.n_cols)
    return None if r0 >= r1 or c0 >= c1 else (r0, r1, c0, c1)


@dataclass(frozen=True, slots=True)
class _AzimuthBins:
    """Azimuth bins over targets: each bin's radial direction (rad, ENU, from east) and
    each target's bin (the bin below it; the target lies between it and the next)."""

    azimuth_rad: np.ndarray
    index: np.ndarray

    @classmethod
    def of(cls, dx: np.ndarray, dy: np.ndarray, rho: np.ndarray, max_width_rad: float
           ) -> _AzimuthBins:
        """Bins at most ``max_width_rad`` wide spanning targets at (dx, dy) (m) from the
        nadir point, at ground distances rho. Targets within 80 deg of their mean direction
        are binned by the tangent of their angle from it (no arctangent per target; the
        bins are then narrowest at the sides), others by their angle."""
        ref_x, ref_y = float(dx.sum()), float(dy.sum())
        norm = math.hypot(ref_x, ref_y)
        ref_x, ref_y = (ref_x / norm, ref_y / norm) if norm > 0 else (1.0, 0.0)
        ref = math.atan2(ref_y, ref_x)
        dot = dx * ref_x + dy * ref_y
        cross = dy * ref_x - dx * ref_y
        with np.errstate(divide="ignore", invalid="ignore"):
            tangent = cross / dot
            far = rho > 0
            tangent_ok = bool((dot[far] > _COS_80 * rho[far]).all())
            key = tangent if tangent_ok else np.arctan2(cross, dot)
        lo, hi = float(np.nanmin(key[far])), float(np.nanmax(key[far]))
        n = min(_MAX_AZIMUTH_BINS, int(math.ceil((hi - lo) / max_width_rad)) + 2)
        width = (hi - lo) / (n - 1) if hi > lo else 1.0
        edges = lo + width * np.arange(n)
        azimuth = ref + (np.arctan(edges) if tangent_ok else edges)
        index = np.clip(np.nan_to_num((key - lo) / width, nan=0.0), 0, n - 1).astype(np.intp)
        return cls(azimuth, index)


def _line_crossings(terrain: TerrainSurface, cx: float, cy: float, cz: float,
                    azimuth_rad: np.ndarray, rho_start: float, rho_end: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the radials of ``azimuth_rad`` from (cx, cy) cross the grid lines x = const
    (rows 0..n-1) and y = const (rows n..2n-1) from rho_start on: each row's first
    crossing's rho (m), the inverse of its spacing (1/m), and the running maximum of the
    terrain's elevation tangent over its crossings after a column of -inf
    (2n, 1 + the most crossings of a row). On a grid line the surface is the straight line
    between the two corners either side of the crossing; outside the grid there is no
    terrain (-inf)."""
    g = terrain.geometry
    cs = g.cell_size_m
    n = len(azimuth_rad)
    cos, sin = np.cos(azimuth_rad), np.sin(azimuth_rad)
    # Per row, in cell units: the camera's coordinate across the lines and along them, the
    # radial's components, the number of lines and of cells along them, and the strides of
    # the corner array across and along the lines.
    u_cam = np.repeat([(cx - g.x0_m) / cs, (cy - g.y0_m) / cs], n)
    v_cam = np.repeat([(cy - g.y0_m) / cs, (cx - g.x0_m) / cs], n)
    direction = np.concatenate([cos, sin])
    across = np.concatenate([sin, cos])
    n_lines, n_along = (np.repeat(v, n) for v in ((g.n_cols, g.n_rows), (g.n_rows, g.n_cols)))
    w = g.n_cols + 1
    stride_line, stride_along = (np.repeat(v, n) for v in ((1, w), (w, 1)))
    ahead = np.abs(direction) > 1e-12
    sign = np.where(direction >= 0, 1.0, -1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # The first grid line at or beyond the radial's point at rho_start.
        at_start = u_cam + rho_start / cs * direction
        k_first = np.where(ahead, np.where(sign > 0, np.ceil(at_start), np.floor(at_start)),
                           0.0)
        # A radial along the lines crosses none: past rho_end, where nothing is sampled.
        first = np.where(ahead, (k_first - u_cam) * cs / direction, 2 * rho_end + 1)
        inv_spacing = np.where(ahead, np.abs(direction) / cs, 1.0 / cs)
    # Crossings of a row: at most its span of rho over the spacing, plus one.
    n_steps = int(math.ceil((rho_end - rho_start) * float(inv_spacing.max()))) + 1
    m = np.arange(n_steps)
    rho = first[:, None] + m / inv_spacing[:, None]
    line = k_first[:, None] + sign[:, None] * m
    along = v_cam[:, None] + (across / cs)[:, None] * rho
    inside = ((line >= 0) & (line <= n_lines[:, None]) & (along >= 0)
              & (along <= n_along[:, None]) & (rho <= rho_end))
    cell = np.clip(along, 0, n_along[:, None] - 1).astype(np.intp)
    frac = along - cell
    at = (np.clip(line, 0, n_lines[:, None]).astype(np.intp) * stride_line[:, None]
          + cell * stride_along[:, None])
    z = terrain.z_corner_m.ravel()
    z0 = z.take(at)
    height = z0 + frac * (z.take(at + stride_along[:, None]) - z0)
    tan = np.full((2 * n, n_steps + 1), -np.inf)
    with np.errstate(invalid="ignore"):
        np.divide(height - cz, rho, out=tan[:, 1:], where=inside)
    return first, inv_spacing, np.maximum.accumulate(tan, axis=1)
