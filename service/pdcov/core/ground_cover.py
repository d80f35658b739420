"""What stands on the ground under a coverage grid: tree cover and solid objects (ENU).

Each cell holds a vertical prism over its square, from the ground up to the top of what
stands on it: ``height_m`` above the cell centre's height on the terrain (0: open ground).
Its ``CoverKind`` says what a line of sight does in it: FOLIAGE lets it through, attenuated
by Beer-Lambert, SOLID (roofs, walls) stops it.

A person standing at a ground point is seen through a transmittance: the line of sight from
the ground point to the camera loses exp(-k L), L (m) its length inside foliage prisms below
their tops, k the extinction coefficient (1/m); one that passes below a solid prism's top
is no look (transmittance 0); a ground point under a roof is never seen. ``transmittance``
follows the rays through the cells their ground tracks cross, all at once, a few grid
lines at a time (a ray's crossings of the column lines and of the row lines are two
arithmetic sequences: merged, they give its segments, one per cell, and each segment's
length below its cell's top is exact). A cell's transmittance is the mean over
``RAYS_PER_SIDE``^2 rays from points spread evenly over it, or its first ray's alone where
that ray passes no cell beside one of another kind (``cell_transmittance``).

Rays are followed only while they may still be below some top: to the camera, and no
farther than where they rise above the highest top, or (rising faster than the steepest
terrain) above the highest object; a ray above the highest top within 3, 12 or 48 cells of
where it is jumps 2, 11 or 47 cells ahead; a point farther from every raised cell than its
ray may be followed (a distance transform, computed once) is not followed at all.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pdcov.core.domain import GridGeometry

__all__ = ["DEFAULT_EXTINCTION_PER_M", "DEFAULT_MIN_OBJECT_HEIGHT_M", "EDGE", "NEAR_CELLS",
           "RAYS_PER_SIDE", "CoverKind", "CoverTops", "GroundCover", "cell_transmittance",
           "through_cover", "transmittance"]

DEFAULT_EXTINCTION_PER_M = 0.08
"""k (1/m) when the config does not set it: Beer-Lambert with a leaf area index of 4.5, a
spherical leaf angle distribution (G = 0.5) and a clumping index of 0.7 (Chen & Black 1992;
Nilson 1971) spread over a 20 m stand, so that a person under such trees is seen straight
down through exp(-0.08 x 20) = 0.20 of the open ground's P_D."""

DEFAULT_MIN_OBJECT_HEIGHT_M = 2.0
"""Surfaces lower than this above the ground (m) count as open ground: DSM noise, low
vegetation, cars."""

RAYS_PER_SIDE = 2
"""Rays per cell side: a cell's transmittance is the mean over 2 x 2 ground points (3 x 3
brought R4's agreement from 98.8 to 99.0 % of cells at 1.6 times the cost)."""

_MIN_LOG_T = -12.0  # a ray attenuated below exp(-12) is not stepped further
EDGE = 4
"""``GroundCover.code``'s flag of a cell beside one of another kind (above every kind)."""


class CoverKind(enum.IntEnum):
    """What stands on a cell: nothing, tree cover (attenuates), or something solid."""

    OPEN = 0
    FOLIAGE = 1
    SOLID = 2


@dataclass(frozen=True, slots=True, eq=False)
class GroundCover:
    """What stands on ``geometry``'s cells: ``height_m`` (float32 (n_rows, n_cols), m above
    the cell centre's ground height, >= 0) and ``kind`` (uint8 CoverKind); a cell of height
    0 is OPEN whatever its kind says, and an OPEN cell has height 0. ``extinction_per_m``:
    Beer-Lambert's k (1/m) for foliage. source: where it came from, for messages. ``code``
    (uint8, derived): the kind, plus EDGE where the cell is beside one of another kind."""

    geometry: GridGeometry
    height_m: np.ndarray
    kind: np.ndarray
    extinction_per_m: float = DEFAULT_EXTINCTION_PER_M
    source: str = ""
    _clear_m: np.ndarray = field(init=False, repr=False)
    code: np.ndarray = field(init=False, repr=False)
    _height_max_m: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        g = self.geometry
        h = np.array(self.height_m, dtype=np.float32)
        kind = np.array(self.kind, dtype=np.uint8)
        for name, a in (("height_m", h), ("kind", kind)):
            if a.shape != g.shape:
                raise ValueError(f"{name} has shape {a.shape}, the grid's {g.shape}")
        if not (np.isfinite(h).all() and (h >= 0).all()):
            raise ValueError("height_m: heights must be finite and >= 0")
        if (kind > max(CoverKind)).any():
            raise ValueError(f"kind: codes must be CoverKind values, got {int(kind.max())}")
        if not (math.isfinite(self.extinction_per_m) and self.extinction_per_m >= 0):
            raise ValueError(f"extinction_per_m must be >= 0, got {self.extinction_per_m}")
        open_ = (h == 0) | (kind == CoverKind.OPEN)
        h[open_] = 0
        kind[open_] = CoverKind.OPEN
        h.setflags(write=False)
        kind.setflags(write=False)
        object.__setattr__(self, "_height_max_m", float(h.max()))
        object.__setattr__(self, "height_m", h)
        object.__setattr__(self, "kind", kind)
        # Per cell, how far (m) every point of it is from the square of any raised cell: the
        # centres' distance less a diagonal (half of each cell's).
        if open_.all():
            clear = np.full(g.shape, np.inf, dtype=np.float32)
        else:
            from scipy.ndimage import distance_transform_edt

            d = distance_transform_edt(open_) * g.cell_size_m - math.sqrt(2) * g.cell_size_m
            clear = np.maximum(d, 0.0).astype(np.float32)
        clear.setflags(write=False)
        object.__setattr__(self, "_clear_m", clear)
        # The cells beside one of another kind (8-neighbours).
        from scipy.ndimage import maximum_filter, minimum_filter

        edge = maximum_filter(kind, size=3) != minimum_filter(kind, size=3)
        code = kind | (edge.astype(np.uint8) * np.uint8(EDGE))
        code.setflags(write=False)
        object.__setattr__(self, "code", code)

    @property
    def height_max_m(self) -> float:
        """The highest object (m above its ground; 0 without any)."""
        return self._height_max_m

    @property
    def nbytes(self) -> int:
        """Bytes its arrays hold."""
        return sum(a.nbytes for a in (self.height_m, self.kind, self.code, self._clear_m))

    @property
    def roof(self) -> np.ndarray:
        """Cells under something solid (bool (n_rows, n_cols)): a person there is never
        seen."""
        return self.kind == CoverKind.SOLID

    def clear_m(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """How far (m) every point of each cell (rows, cols) lies from the nearest raised
        cell (0 when it or a neighbour is raised; inf without any)."""
        return self._clear_m[rows, cols]

    def tops(self, centre_z_m: np.ndarray) -> CoverTops:
        """The cells' tops over ground whose cell centres are at ``centre_z_m`` (ENU z, m,
        (n_rows, n_cols))."""
        top = np.where(self.height_m > 0, centre_z_m + self.height_m, -np.inf)
        return CoverTops.of(top)


NEAR_CELLS = (3, 12, 48)
"""``CoverTops.near_top_z_m`` holds the highest top within each of these many cells
(Chebyshev) of every cell."""


@dataclass(frozen=True, slots=True, eq=False)
class CoverTops:
    """The tops of the cells (ENU z, m; -inf where open), the highest top within each of
    NEAR_CELLS cells of every cell (float32, rounded up), and the highest of all (-inf:
    none)."""

    top_z_m: np.ndarray
    near_top_z_m: tuple[np.ndarray, ...]
    top_max_z_m: float

    @property
    def nbytes(self) -> int:
        """Bytes its arrays hold."""
        return self.top_z_m.nbytes + sum(a.nbytes for a in self.near_top_z_m)

    @classmethod
    def of(cls, top_z_m: np.ndarray) -> CoverTops:
        from scipy.ndimage import maximum_filter

        top = np.array(top_z_m, dtype=np.float64)
        top.setflags(write=False)
        near = []
        for n in NEAR_CELLS:
            z = maximum_filter(top, size=2 * n + 1, mode="nearest").astype(np.float32)
            z = np.nextafter(z, np.float32(np.inf))  # never below the float64 tops
            z.setflags(write=False)
            near.append(z)
        return cls(top, tuple(near), float(top.max()))


def transmittance(cover: GroundCover, tops: CoverTops, slope_max: float,
                  r_cam_enu: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray
                  ) -> np.ndarray:
    """Per ground point (x_m, y_m, z_m) (ENU, m; on the terrain), the transmittance of its
    line of sight to the camera at ``r_cam_enu`` through ``cover`` (module docstring): 0
    when it passes below a solid top, else exp(-k L). tops: the cells' tops
    (``GroundCover.tops``); slope_max: the terrain's steepest slope (m/m), to bound the
    steps."""
    return np.exp(_trace(cover, tops, slope_max, r_cam_enu, x_m, y_m, z_m)[0])


def _trace(cover: GroundCover, tops: CoverTops, slope_max: float, r_cam_enu: np.ndarray,
           x_m: np.ndarray, y_m: np.ndarray, z_m: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """``transmittance``'s log (-inf: blocked), and whether each ray passed a cell beside
    one of another kind (``GroundCover.code``'s EDGE) while it may have been below a top."""
    x_m, y_m = np.asarray(x_m, dtype=np.float64), np.asarray(y_m, dtype=np.float64)
    z_m = np.asarray(z_m, dtype=np.float64)
    log_t = np.zeros(x_m.shape)
    met_edge = np.zeros(x_m.shape, dtype=bool)
    if log_t.size == 0 or cover.height_max_m == 0:
        return log_t, met_edge
    g = cover.geometry
    cs = g.cell_size_m
    cx, cy, cz = (float(v) for v in r_cam_enu)
    dx, dy = cx - x_m, cy - y_m
    # A point straight below the camera: its ray is vertical, followed as one rising
    # steeply to the east that leaves its cell no sooner (its length the same in the limit).
    tiny = 1e-9 * cs
    rho = np.hypot(dx, dy)
    dx = np.where(rho < tiny, tiny, dx)
    rho = np.maximum(rho, tiny)
    tan_e = (cz - z_m) / rho
    with np.errstate(divide="ignore", invalid="ignore"):
        # Rays rise at tan_e, the ground at most at slope_max: past height_max / (tan_e -
        # slope_max) a ray is above every object; past the highest top, above every top.
        end = np.minimum(rho, np.where(tan_e > 0, (tops.top_max_z_m - z_m) / tan_e, np.inf))
        end = np.where(tan_e > slope_max,
                       np.minimum(end, cover.height_max_m / (tan_e - slope_max)), end)
    row, col = (np.asarray(v, dtype=np.intp) for v in g.cell_of(x_m, y_m))
    inside = (row >= 0) & (row < g.n_rows) & (col >= 0) & (col < g.n_cols)
    # A point farther from every raised cell than it may be followed meets nothing.
    k = np.flatnonzero(inside)
    k = k[cover.clear_m(row[k], col[k]) < end[k]]
    if len(k):
        u, v = (x_m[k] - g.x0_m) / cs, (y_m[k] - g.y0_m) / cs
        du, dv = dx[k] / rho[k], dy[k] / rho[k]
        with np.errstate(divide="ignore"):
            # Followed no farther than where it leaves the grid (a little short of it).
            out_m = np.minimum(np.where(du > 0, (g.n_cols - u) / du, np.where(
                du < 0, u / -du, np.inf)), np.where(dv > 0, (g.n_rows - v) / dv, np.where(
                    dv < 0, v / -dv, np.inf))) * cs * (1 - 1e-12) - 1e-9 * cs
        rays = _Rays(u, v, z_m[k], du, dv, tan_e[k], np.minimum(end[k], out_m))
        log_t[k], met_edge[k] = _march(cover, tops, rays)
    return log_t, met_edge


@dataclass(frozen=True, slots=True)
class _Rays:
    """Rays from ground points towards a camera: the points (u, v) (cell units) and z
    (ENU, m), the unit horizontal direction (du, dv), the rise per horizontal metre tan_e,
    and how far (m, horizontally) to follow each at most."""

    u: np.ndarray
    v: np.ndarray
    z: np.ndarray
    du: np.ndarray
    dv: np.ndarray
    tan_e: np.ndarray
    end: np.ndarray


_CHUNK_LINES = (4, 8)
"""Grid lines of each direction a step of the march crosses at most: its first step (most
rays leave the trees within a few cells), then every other."""


def _march(cover: GroundCover, tops: CoverTops, rays: _Rays
           ) -> tuple[np.ndarray, np.ndarray]:
    """``_trace`` of ``rays``, all followed at once, a few cells at a time: a ray's
    crossings of the column and of the row lines are arithmetic sequences, so the segments
    between them (one per cell) are found without a loop per cell. A rising ray above the
    highest top within n cells of its cell (``CoverTops.near_top_z_m``) jumps n - 1 cells
    ahead."""
    g = cover.geometry
    cs = g.cell_size_m
    n = len(rays.z)
    log_t = np.zeros(n)
    met_edge = np.zeros(n, dtype=bool)
    s = np.zeros(n)  # how far each ray has been followed (m)
    live = np.arange(n)
    lines = _CHUNK_LINES[0]
    while len(live):
        s_l = s[live]
        u = rays.u[live] + s_l * rays.du[live] / cs
        v = rays.v[live] + s_l * rays.dv[live] / cs
        col, row = np.floor(u), np.floor(v)
        at = row.astype(np.intp) * g.n_cols + col.astype(np.intp)
        z = rays.z[live] + rays.tan_e[live] * s_l
        jump = np.zeros(len(live))
        rising = rays.tan_e[live] > 0  # a ray not rising may come down to any top
        for n_cells, near in zip(NEAR_CELLS, tops.near_top_z_m, strict=True):
            jump[rising & (z > near.ravel().take(at))] = (n_cells - 1) * cs
        ahead = s_l + jump
        march = np.flatnonzero(jump == 0)
        if len(march):
            k = live[march]
            add, blocked, edge, reached = _chunk(
                cover, tops, at[march], u[march] - col[march], v[march] - row[march],
                z[march], rays.du[k], rays.dv[k], rays.tan_e[k], rays.end[k] - s_l[march],
                lines)
            log_t[k] = np.where(blocked, -np.inf, log_t[k] + add)
            met_edge[k] |= edge
            ahead[march] += reached
        s[live] = ahead
        live = live[(ahead < rays.end[live]) & (log_t[live] > _MIN_LOG_T)]
        lines = _CHUNK_LINES[1]
    return log_t, met_edge


def _chunk(cover: GroundCover, tops: CoverTops, at: np.ndarray, fu: np.ndarray,
           fv: np.ndarray, z: np.ndarray, du: np.ndarray, dv: np.ndarray, tan_e: np.ndarray,
           limit_m: np.ndarray, lines: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One step of ``_march`` for rays now in the cells of flat index ``at``, at (fu, fv)
    in them (cell units, [0, 1)) and height z (ENU, m), inside the grid up to ``limit_m``
    (m): over at most ``lines`` lines of each direction and ``limit_m``, the log
    transmittance added, whether a solid blocked the ray, whether it passed a cell of
    ``GroundCover.code``'s EDGE, and how far it went (m). The segments in float32, relative to
    the cells the rays are in."""
    g = cover.geometry
    cs = g.cell_size_m
    m = np.arange(lines, dtype=np.float32)
    bounds = np.zeros((len(at), 2 * lines + 1), dtype=np.float32)
    reached = limit_m.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for col0, p, d in ((1, fu, du), (1 + lines, fv, dv)):
            first = np.where(d > 0, (1 - p) / d, np.where(d < 0, p / -d, np.inf)) * cs
            spacing = np.where(d != 0, cs / np.abs(d), 0.0)  # with first = inf: all inf
            last = first + (lines - 1) * spacing
            bounds[:, col0:col0 + lines] = (first[:, None] + m * spacing[:, None])
            # Beyond its last line of this direction the step cannot tell the cells.
            np.minimum(reached, last, out=reached)
        # Per horizontal metre of height above z: 1 / tan_e (a ray not rising: flat).
        per_m = np.where(tan_e > 0, 1.0 / tan_e, 1e12).astype(np.float32)[:, None]
    bounds.sort(axis=1)
    np.minimum(bounds, reached.astype(np.float32)[:, None], out=bounds)
    s0, s1 = bounds[:, :-1], bounds[:, 1:]
    mid = s0 + s1  # twice the midpoint: its cell, the segment's
    k_u, k_v = (0.5 * du / cs).astype(np.float32), (0.5 * dv / cs).astype(np.float32)
    step = (np.floor(fv.astype(np.float32)[:, None] + mid * k_v[:, None]).astype(np.intp)
            * g.n_cols + np.floor(fu.astype(np.float32)[:, None] + mid * k_u[:, None]
                                  ).astype(np.intp))
    cell = at[:, None] + step
    inside = np.minimum(s1, (tops.top_z_m.ravel().take(cell) - z[:, None]) * per_m) - s0
    code = cover.code.ravel().take(cell)
    solid = (code & np.uint8(3)) == CoverKind.SOLID
    np.clip(inside, 0.0, None, out=inside)
    blocked = np.any(solid & (inside > 0), axis=1)
    edge = np.any(code >= EDGE, axis=1)
    inside[solid] = 0.0
    length = inside.sum(axis=1) * np.sqrt(1.0 + tan_e**2)
    return -cover.extinction_per_m * length, blocked, edge, reached


def through_cover(log_miss: np.ndarray, transmittance: np.ndarray | None,
                  observed: np.ndarray) -> np.ndarray:
    """log(1 - P_D T): the log-miss ``log_miss`` = log(1 - P_D) of looks (float32) with
    their P_D scaled by the cells' ``transmittance`` (None: 1) where ``observed``; in
    place."""
    if transmittance is not None:
        dim = observed & (transmittance < 1)
        log_miss[dim] = np.log1p(np.expm1(log_miss[dim]) * transmittance[dim])
    return log_miss


def cell_transmittance(cover: GroundCover, tops: CoverTops, slope_max: float,
                       height_at: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                       r_cam_enu: np.ndarray, rows: np.ndarray, cols: np.ndarray
                       ) -> np.ndarray:
    """Per cell (rows, cols) the mean transmittance (``transmittance``) of the lines of
    sight from ``RAYS_PER_SIDE``^2 points spread evenly over it to the camera at
    ``r_cam_enu``; height_at(x, y): the ground's ENU z (m) at points (None: 0). The first
    point's ray goes first: a cell where it passes no cell beside one of another kind takes
    it alone (the others, within a cell of it, meet the same kinds of cover)."""
    g = cover.geometry
    cs = g.cell_size_m
    n = RAYS_PER_SIDE
    f = (np.arange(n) + 0.5) / n
    x = g.x0_m + cs * (cols[:, None, None] + f[None, None, :])
    y = g.y0_m + cs * (rows[:, None, None] + f[None, :, None])
    x, y = (a.reshape(len(rows), n * n) for a in np.broadcast_arrays(x, y))

    def ground(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return np.zeros_like(x_m) if height_at is None else height_at(x_m, y_m)

    x0, y0 = x[:, 0], y[:, 0]
    log_t, met_edge = _trace(cover, tops, slope_max, r_cam_enu, x0, y0, ground(x0, y0))
    out = np.exp(log_t)
    k = np.flatnonzero(met_edge)
    if len(k):
        xk, yk = x[k, 1:].ravel(), y[k, 1:].ravel()
        rest = transmittance(cover, tops, slope_max, r_cam_enu, xk, yk, ground(xk, yk))
        out[k] = (out[k] + rest.reshape(len(k), n * n - 1).sum(axis=1)) / (n * n)
    return out
