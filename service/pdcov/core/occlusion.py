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

__all__ = ["hidden_by_terrain"]

_MAX_AZIMUTH_BINS = 4096
_TAN_TOL = 1e-9  # elevation tangents closer than this count as equal (not hidden)
_COS_80 = math.cos(math.radians(80.0))


def hidden_by_terrain(terrain: TerrainSurface, r_cam_enu: np.ndarray, x_m: np.ndarray,
                      y_m: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """True where the terrain hides the points (x_m, y_m, z_m) (ENU, on the terrain) from a
    camera at ``r_cam_enu``; points within half a cell of the camera's nadir never are."""
    g = terrain.geometry
    cs = g.cell_size_m
    skip = 0.5 * cs  # the target's own surface
    if np.size(x_m) == 0:
        return np.zeros(np.shape(x_m), dtype=bool)
    cx, cy, cz = (float(v) for v in r_cam_enu)
    dx = x_m - cx
    dy = y_m - cy
    rho = np.hypot(dx, dy)
    # The highest terrain between the nadir point and the targets bounds every sample; one
    # cell of margin, as a bin's radial passes within a cell of its targets'.
    lo = g.cell_of(np.array(min(cx, float(x_m.min()))), np.array(min(cy, float(y_m.min()))))
    hi = g.cell_of(np.array(max(cx, float(x_m.max()))), np.array(max(cy, float(y_m.max()))))
    r0, c0 = max(int(lo[0]) - 1, 0), max(int(lo[1]) - 1, 0)
    r1, c1 = min(int(hi[0]) + 2, g.n_rows), min(int(hi[1]) + 2, g.n_cols)
    if r0 >= r1 or c0 >= c1:
        return np.zeros(np.shape(x_m), dtype=bool)
    z_max = terrain.window_z_range_m(r0, r1, c0, c1)[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        tan_t = (z_m - cz) / rho
    rho_end = float(rho.max()) - skip
    lowest = float(tan_t.min())
    # Terrain at rho can only rise above a tangent t >= lowest where (z_max - cz) / rho
    # > lowest: before rho_start every line of sight is above all terrain.
    rho_start = 1e-3 * cs
    if cz > z_max and lowest < 0:
        rho_start = max(rho_start, (cz - z_max) / -lowest)
    if rho_start >= rho_end:
        return np.zeros(np.shape(x_m), dtype=bool)
    bins = _AzimuthBins.of(dx, dy, rho, 0.5 * cs / rho_end)
    n_steps = int(math.ceil((rho_end - rho_start) / cs)) + 1
    # Radials 0..n-1 meet the lines x = const, n..2n-1 the lines y = const.
    first, inv_spacing, h_run = _line_crossings(terrain, cx, cy, cz, bins.azimuth_rad,
                                                rho_start, rho_end, n_steps)
    n = len(bins.azimuth_rad)
    ia = bins.index
    ib = np.minimum(ia + 1, n - 1)
    rows = np.stack([ia, ib, ia + n, ib + n])
    with np.errstate(invalid="ignore"):
        m = np.floor((rho - skip - first.take(rows)) * inv_spacing.take(rows))
    # Column 0 of h_run is -inf: no crossing before the target.
    at = rows * (n_steps + 1) + np.clip(np.nan_to_num(m, nan=-1.0) + 1, 0, n_steps
                                        ).astype(np.intp)
    horizon = h_run.take(at).max(axis=0)
    return tan_t < horizon - _TAN_TOL


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
                    azimuth_rad: np.ndarray, rho_start: float, rho_end: float, n_steps: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the radials of ``azimuth_rad`` from (cx, cy) cross the grid lines x = const
    (rows 0..n-1) and y = const (rows n..2n-1) from rho_start on: each row's first
    crossing's rho (m), the inverse of its spacing (1/m), and the running maximum of the
    terrain's elevation tangent over its crossings after a column of -inf
    (2n, n_steps + 1)."""
    g = terrain.geometry
    cs = g.cell_size_m
    cos, sin = np.cos(azimuth_rad), np.sin(azimuth_rad)
    direction = np.concatenate([cos, sin])  # along the axis the lines cross
    across = np.concatenate([sin, cos])
    c_cam = np.repeat([cx, cy], len(cos))
    c0 = np.repeat([g.x0_m, g.y0_m], len(cos))
    ahead = np.abs(direction) > 1e-12
    sign = np.where(direction >= 0, 1.0, -1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # The first grid line at or beyond the radial's point at rho_start.
        at_start = (c_cam + rho_start * direction - c0) / cs
        k_first = np.where(ahead, np.where(sign > 0, np.ceil(at_start), np.floor(at_start)),
                           0.0)
        # A radial along the lines crosses none: past rho_end, where nothing is sampled.
        first = np.where(ahead, (c0 + k_first * cs - c_cam) / direction, 2 * rho_end + 1)
        inv_spacing = np.where(ahead, np.abs(direction) / cs, 1.0 / cs)
    m = np.arange(n_steps)
    rho = first[:, None] + m / inv_spacing[:, None]
    line = c0[:, None] + (k_first[:, None] + sign[:, None] * m) * cs
    other = np.concatenate([np.full(len(cos), cy), np.full(len(cos), cx)])[:, None] \
        + across[:, None] * rho
    half = len(cos)
    x = np.concatenate([line[:half], other[half:]])
    y = np.concatenate([other[:half], line[half:]])
    tan = np.full((2 * half, n_steps + 1), -np.inf)
    with np.errstate(invalid="ignore"):
        tan[:, 1:] = np.where(rho <= rho_end, (_height_or_low(terrain, x, y) - cz) / rho,
                              -np.inf)
    return first, inv_spacing, np.maximum.accumulate(tan, axis=1)


def _height_or_low(terrain: TerrainSurface, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Bilinear terrain height (m) at ENU points; -inf outside the grid (no terrain known
    there to hide anything)."""
    g = terrain.geometry
    u = (x_m - g.x0_m) / g.cell_size_m
    v = (y_m - g.y0_m) / g.cell_size_m
    inside = (u >= 0) & (u <= g.n_cols) & (v >= 0) & (v <= g.n_rows)
    u = np.clip(u, 0, g.n_cols)
    v = np.clip(v, 0, g.n_rows)
    j = np.minimum(u.astype(np.intp), g.n_cols - 1)
    i = np.minimum(v.astype(np.intp), g.n_rows - 1)
    fu = u - j
    fv = v - i
    z = terrain.z_corner_m.ravel()
    w = g.n_cols + 1
    at = i * w + j
    z00, z01 = z.take(at), z.take(at + 1)
    z10, z11 = z.take(at + w), z.take(at + w + 1)
    h = (z00 + (z01 - z00) * fu) + ((z10 + (z11 - z10) * fu) - (z00 + (z01 - z00) * fu)) * fv
    return np.where(inside, h, -np.inf)
