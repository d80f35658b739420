"""Comparisons of pdcov's grid with the reference grids (tests.support.references: R1, R2;
tests.support.terrain_reference: R3) and the agreement each reference must reach, shared by
the tests and the benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdcov.core.grid import CoverageGrid
from tests.support.references import ReferenceGrid
from tests.support.terrain_reference import TerrainReferenceGrid

# |P_D difference| tolerance and the share of compared cells within it that each reference
# must reach. R1 counts pixel centres: a cell's count differs from its area by up to about its
# perimeter in pixels, which moves cells near a bin edge into the next bin. R2 computes what
# pdcov does with OpenCV's projectPoints in float64; pdcov's float32 pixel maps differ by
# ~1e-4 px. R3 casts through the DEM: issue 21's "done when".
R1_TOLERANCE_PD, R1_MIN_SHARE = 0.05, 0.95
R2_TOLERANCE_PD, R2_MIN_SHARE = 1e-5, 0.999
R3_TOLERANCE_PD, R3_MIN_SHARE = 0.05, 0.97


@dataclass(frozen=True)
class Agreement:
    """How a reference grid compares with pdcov's over the free cells.

    max_abs_dpd: largest |P_D difference| over all free cells. share_within: share, of the
    cells both observed equally often, whose |P_D difference| is at most ``tolerance``.
    cells_compared: those cells. p99_rel_log_miss: 99th percentile over them of the relative
    difference of the log-miss sums (which, unlike P_D, do not saturate at 1).
    looks_differ: free cells observed a different number of times (the references decide
    differently at the picture's edge: R1 counts a cell when any pixel's ray lands in it,
    pdcov when the ray through its centre reaches the picture).
    """

    max_abs_dpd: float
    share_within: float
    tolerance: float
    cells_compared: int
    p99_rel_log_miss: float
    looks_differ: int


def agreement(grid: CoverageGrid, ref: ReferenceGrid, tolerance: float) -> Agreement:
    """Compare the cumulative P_D of ``grid`` and ``ref``."""
    free = grid.mask
    dpd = np.abs(grid.pd - ref.pd)
    same = free & (grid.n_obs == ref.n_obs) & (grid.n_obs > 0)
    n_same = int(same.sum())
    mine, theirs = grid.log_miss_d[same].astype(np.float64), ref.log_miss_d[same]
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(mine == theirs, 0.0, np.abs(mine - theirs) / np.abs(theirs))
    return Agreement(
        max_abs_dpd=float(dpd[free].max(initial=0.0)),
        share_within=float((dpd[same] <= tolerance).mean()) if n_same else 1.0,
        tolerance=tolerance,
        cells_compared=n_same,
        p99_rel_log_miss=float(np.nanpercentile(rel, 99)) if n_same else 0.0,
        looks_differ=int((grid.n_obs != ref.n_obs)[free].sum()),
    )


@dataclass(frozen=True)
class TerrainAgreement:
    """How pdcov's grid compares with R3's (the terrain truth) over all free cells.

    share_within: share of the free cells whose P_D differs by at most ``tolerance``;
    share_within_observed: the same share of the free cells either grid observed
    (cells_observed of them). never_seen: free cells no ray of R3 reached in any frame;
    never_seen_counted: those of them pdcov observed. hidden: free cells whose centre was in
    some frame's picture and range but always behind terrain (R3's ``hidden``);
    hidden_counted: those of them pdcov observed.
    """

    share_within: float
    share_within_observed: float
    tolerance: float
    cells_free: int
    cells_observed: int
    never_seen: int
    never_seen_counted: int
    hidden: int
    hidden_counted: int


def terrain_agreement(grid: CoverageGrid, ref: TerrainReferenceGrid,
                      tolerance: float) -> TerrainAgreement:
    """Compare ``grid`` (flat or with terrain) with R3's ``ref`` over the same frames."""
    free = grid.mask
    seen = grid.n_obs > 0
    never = free & (ref.n_obs == 0)
    hidden = ref.hidden
    close = np.abs(grid.pd - ref.pd) <= tolerance
    observed = free & (seen | (ref.n_obs > 0))
    return TerrainAgreement(
        share_within=float(close[free].mean()),
        share_within_observed=float(close[observed].mean()) if observed.any() else 1.0,
        tolerance=tolerance,
        cells_free=int(free.sum()),
        cells_observed=int(observed.sum()),
        never_seen=int(never.sum()),
        never_seen_counted=int((never & seen).sum()),
        hidden=int(hidden.sum()),
        hidden_counted=int((hidden & seen).sum()),
    )
