"""The terrain surface under a coverage grid: ground heights at the cells' corners (ENU).

ENU z is metres above the plane z = 0 through ``origin.ground_alt_msl_m`` (the same z as the
camera poses'). The surface between four corners is the bilinear patch through them; a
cell's centre is at the mean of its corners' heights. Reading a DEM into these heights is
``core/dem.py`` (rasterio); this module is the pure numeric part the kernel uses.

Heights of blocks of ``BLOCK`` x ``BLOCK`` cells are kept as minima and maxima, and their
steepest slope, so the range of heights and slopes under any window is found without reading
the window.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.ground_cover import CoverTops, GroundCover

__all__ = ["BLOCK", "TerrainSurface"]

BLOCK = 16  # cells per side of the blocks whose height range is kept


@dataclass(frozen=True, slots=True)
class TerrainSurface:
    """Ground heights z (m, ENU) at the corners of ``geometry``'s cells.

    z_corner_m: float64 (n_rows + 1, n_cols + 1); [i, j] is the corner at
    x = x0_m + j cell_size_m, y = y0_m + i cell_size_m (row 0 south, as the grid's rows).
    source: where the heights came from (a DEM path), for messages.
    cover: what stands on the ground (core/ground_cover.py; None: nothing, open ground).
    """

    geometry: GridGeometry
    z_corner_m: np.ndarray
    source: str = ""
    cover: GroundCover | None = None
    _cover_tops: CoverTops | None = field(init=False, repr=False, compare=False)
    _block_min: np.ndarray = field(init=False, repr=False, compare=False)
    _block_max: np.ndarray = field(init=False, repr=False, compare=False)
    _block_slope: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        z = np.array(self.z_corner_m, dtype=np.float64)
        g = self.geometry
        if z.shape != (g.n_rows + 1, g.n_cols + 1):
            raise ValueError(f"z_corner_m has shape {z.shape}, the grid's corners "
                             f"{(g.n_rows + 1, g.n_cols + 1)}")
        if not np.isfinite(z).all():
            raise ValueError("z_corner_m: heights must be finite")
        z.setflags(write=False)
        object.__setattr__(self, "z_corner_m", z)
        # Block b spans cells [b*BLOCK, (b+1)*BLOCK), i.e. corners [b*BLOCK, (b+1)*BLOCK].
        nb_r = -(-g.n_rows // BLOCK)
        nb_c = -(-g.n_cols // BLOCK)
        pad = np.pad(z, ((0, nb_r * BLOCK + 1 - z.shape[0]), (0, nb_c * BLOCK + 1 - z.shape[1])),
                     mode="edge")
        lo = np.minimum(pad[:-1, :-1], pad[1:, 1:])
        hi = np.maximum(pad[:-1, :-1], pad[1:, 1:])
        lo = np.minimum(lo, np.minimum(pad[1:, :-1], pad[:-1, 1:]))
        hi = np.maximum(hi, np.maximum(pad[1:, :-1], pad[:-1, 1:]))
        object.__setattr__(self, "_block_min",
                           lo.reshape(nb_r, BLOCK, nb_c, BLOCK).min(axis=(1, 3)))
        object.__setattr__(self, "_block_max",
                           hi.reshape(nb_r, BLOCK, nb_c, BLOCK).max(axis=(1, 3)))
        # A bilinear cell's slope along any direction (c, s) is at most |g_x c| + |g_y s|
        # <= hypot(g_x, g_y), with g_x, g_y its steepest edges along x and y.
        cs = g.cell_size_m
        g_x = np.abs(np.diff(pad, axis=1)) / cs
        g_y = np.abs(np.diff(pad, axis=0)) / cs
        slope = np.hypot(np.maximum(g_x[:-1], g_x[1:]), np.maximum(g_y[:, :-1], g_y[:, 1:]))
        object.__setattr__(self, "_block_slope",
                           slope.reshape(nb_r, BLOCK, nb_c, BLOCK).max(axis=(1, 3)))
        tops = None
        if self.cover is not None:
            if self.cover.geometry != g:
                raise ValueError("cover is for another grid geometry")
            tops = self.cover.tops(self.centre_z_m(0, g.n_rows, 0, g.n_cols))
        object.__setattr__(self, "_cover_tops", tops)

    @classmethod
    def flat(cls, geometry: GridGeometry, z_m: float = 0.0) -> TerrainSurface:
        """A level surface at height ``z_m``."""
        return cls(geometry, np.full((geometry.n_rows + 1, geometry.n_cols + 1), float(z_m)),
                   "flat")

    @property
    def is_level_zero(self) -> bool:
        """True when every ground height is 0: the flat ground the paper assumes (what
        stands on it, ``cover``, aside)."""
        return not self.z_corner_m.any()

    @property
    def nbytes(self) -> int:
        """Bytes its arrays hold, its cover's included."""
        held = self.z_corner_m.nbytes + self._block_min.nbytes * 3
        if self.cover is not None and self._cover_tops is not None:
            held += self.cover.nbytes + self._cover_tops.nbytes
        return held

    @property
    def cover_tops(self) -> CoverTops | None:
        """The tops of what stands on the cells (``GroundCover.tops``), None without a
        cover."""
        return self._cover_tops

    @property
    def max_slope(self) -> float:
        """The steepest slope (m/m, any direction) of the whole surface."""
        return float(self._block_slope.max())

    @property
    def z_range_m(self) -> tuple[float, float]:
        """The lowest and highest heights (m) of the whole surface."""
        return float(self._block_min.min()), float(self._block_max.max())

    def window_z_range_m(self, r0: int, r1: int, c0: int, c1: int) -> tuple[float, float]:
        """Lowest and highest heights (m) of cells [r0, r1) x [c0, c1), or a little wider
        (whole blocks)."""
        b_r0, b_c0 = r0 // BLOCK, c0 // BLOCK
        b_r1, b_c1 = -(-r1 // BLOCK), -(-c1 // BLOCK)
        return (float(self._block_min[b_r0:b_r1, b_c0:b_c1].min()),
                float(self._block_max[b_r0:b_r1, b_c0:b_c1].max()))

    def block_bounds(self, r0: int, r1: int, c0: int, c1: int
                     ) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray]:
        """The blocks covering cells [r0, r1) x [c0, c1): their index range (b_r0, b_r1,
        b_c0, b_c1) and lowest and highest heights (m), (b_r1 - b_r0, b_c1 - b_c0) each."""
        b = (r0 // BLOCK, -(-r1 // BLOCK), c0 // BLOCK, -(-c1 // BLOCK))
        return (b, self._block_min[b[0]:b[1], b[2]:b[3]],
                self._block_max[b[0]:b[1], b[2]:b[3]])

    def window_max_slope(self, r0: int, r1: int, c0: int, c1: int) -> float:
        """The steepest slope (m/m, any direction) of the surface over cells [r0, r1) x
        [c0, c1), or a little wider (whole blocks)."""
        return float(self._block_slope[r0 // BLOCK:-(-r1 // BLOCK),
                                       c0 // BLOCK:-(-c1 // BLOCK)].max())

    def centre_z_m(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Heights (m) of the centres of cells [r0, r1) x [c0, c1): the mean of their corners."""
        z = self.z_corner_m[r0:r1 + 1, c0:c1 + 1]
        return 0.25 * ((z[:-1, :-1] + z[1:, 1:]) + (z[:-1, 1:] + z[1:, :-1]))

    def surface_z_m(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray:
        """Height (m, ENU z) of the top of what stands on the ground at ENU points (the
        cover's top of their cell), or of the ground (``height_m``) where nothing does."""
        z = self.height_m(x_m, y_m)
        tops = self._cover_tops
        if tops is None:
            return z
        g = self.geometry
        row, col = g.cell_of(np.asarray(x_m, dtype=np.float64), np.asarray(y_m, np.float64))
        row = np.clip(row, 0, g.n_rows - 1)
        col = np.clip(col, 0, g.n_cols - 1)
        return np.maximum(z, tops.top_z_m[row, col])

    def height_m(self, x_m: np.ndarray | float, y_m: np.ndarray | float) -> np.ndarray:
        """Bilinear height (m) at ENU points; points outside the grid take the height of the
        nearest point on its edge."""
        g = self.geometry
        u = np.clip((np.asarray(x_m, dtype=np.float64) - g.x0_m) / g.cell_size_m, 0, g.n_cols)
        v = np.clip((np.asarray(y_m, dtype=np.float64) - g.y0_m) / g.cell_size_m, 0, g.n_rows)
        j = np.minimum(np.floor(u).astype(np.intp), g.n_cols - 1)
        i = np.minimum(np.floor(v).astype(np.intp), g.n_rows - 1)
        fu, fv = u - j, v - i
        z = self.z_corner_m
        return ((z[i, j] * (1 - fu) + z[i, j + 1] * fu) * (1 - fv)
                + (z[i + 1, j] * (1 - fu) + z[i + 1, j + 1] * fu) * fv)
