"""The per-cell quantities a coverage grid keeps (``CoverageGrid.read``)."""

from __future__ import annotations

import enum
from typing import Protocol

import numpy as np

from pdcov.core.domain import GridGeometry

Window = tuple[int, int, int, int]  # r0, r1, c0, c1: rows r0:r1, columns c0:c1


class Layer(enum.Enum):
    """A per-cell quantity of the grid (``CoverageGrid.read``): the stored log-miss sums
    (float32, <= 0), observation counts (int32), LimitingFactor codes (uint8), the revisit
    clock (s, float64; only with ``min_revisit_s``), the looks state ((rows, cols, K):
    ``looks_model``'s), the free cells (bool), and P_D and P_FA (float64, derived)."""

    LOG_MISS_D = "log_miss_d"
    LOG_MISS_FA = "log_miss_fa"
    N_OBS = "n_obs"
    LIMITING = "limiting"
    LAST_OBS_S = "last_obs_s"
    LOOKS = "looks"
    MASK = "mask"
    PD = "pd"
    PFA = "pfa"


class CellSource(Protocol):
    """What reads a grid's cells by window: the coverage grid (``CoverageGrid``, tile by
    tile) or a ground station's copy of it (``bus.grid_state.GridState``)."""

    @property
    def geometry(self) -> GridGeometry: ...

    @property
    def frames(self) -> int: ...

    @property
    def n_free(self) -> int:
        """Free cells in the whole grid."""
        ...

    def read(self, layer: Layer, window: Window | None = None) -> np.ndarray:
        """The cells of ``window`` (r0, r1, c0, c1; None: all) of ``layer``: a new array."""
        ...

    def written_windows(self) -> list[Window]:
        """Windows outside which every layer holds its fill (no look, never in view, P_D
        0): a coverage grid's written tiles; a ground station's whole grid."""
        ...
