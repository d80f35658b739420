"""What one frame's update of the coverage grid saw of its cells (for the candidates)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
    by the table index; ``transmittance`` (float32, the window's shape; None: 1 everywhere)
    the share of the cell's P_D what stands on the ground let through (core/ground_cover.py).
    The arrays are the update's own (no copy): read, never write."""

    t_s: float
    window: tuple[int, int, int, int]
    in_view: np.ndarray
    counted: np.ndarray
    size_index: np.ndarray
    bin_index: np.ndarray
    area_px2: np.ndarray
    tables: tuple[np.ndarray, np.ndarray]
    transmittance: np.ndarray | None = None

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

    def log_miss_d(self, rows: np.ndarray, cols: np.ndarray, index: np.ndarray
                   ) -> np.ndarray:
        """log(1 - P_D) (float64, <= 0) of the looks at grid cells (rows, cols) at table
        ``index`` (``look_at``), P_D scaled by the cells' transmittance."""
        log_miss = self.tables[0].take(index).astype(np.float64)
        if self.transmittance is None:
            return log_miss
        lr, lc, inside = self._local(rows, cols)
        t = np.where(inside, self.transmittance[lr, lc], 1.0).astype(np.float64)
        return np.log1p(np.expm1(log_miss) * t)
