"""A coverage grid's summary: shares of free cells at P_D thresholds, mean P_D, expected
false alarms and cells per limiting factor, read tile by tile (the free cells of no tile
were never in view)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.tiles import TileKey

if TYPE_CHECKING:
    from pdcov.core.free_cells import FreeCells
    from pdcov.core.grid import CoverageGrid


@dataclass(frozen=True, slots=True)
class Metrics:
    """Summary of a grid. Proportions are of free cells; false alarms sum P_FA over observed
    free cells; limiting_cells counts free cells by LimitingFactor name (lower case)."""

    frames: int
    cells_free: int
    cells_observed: int
    proportion_at_or_above: dict[float, float]
    mean_pd: float
    expected_false_alarms: float
    limiting_cells: dict[str, int] = field(default_factory=dict)


def grid_metrics(grid: CoverageGrid, thresholds: tuple[float, ...] | list[float]) -> Metrics:
    """``grid``'s summary, tile by tile: free cells of no tile were never in view
    (P_D 0, no look)."""
    n_free = grid.free.n_free
    at_or_above = dict.fromkeys(thresholds, 0)
    sum_pd, observed, false_alarms, untouched = 0.0, 0, 0.0, n_free
    for key in grid.tile_keys():
        w = grid.layout.window_of(key)
        free = grid.free.tile(key)
        pd = grid.read(Layer.PD, w)[free]
        untouched -= len(pd)
        seen = grid.read(Layer.N_OBS, w) > 0
        for t in thresholds:
            at_or_above[t] += int(np.count_nonzero(pd >= t))
        sum_pd += float(pd.sum())
        observed_here = free & seen
        observed += int(np.count_nonzero(observed_here))
        false_alarms += float(grid.read(Layer.PFA, w)[observed_here].sum())
    for t in thresholds:  # P_D 0 in the free cells of no tile
        at_or_above[t] += untouched if 0.0 >= t else 0
    return Metrics(
        frames=grid.frames,
        cells_free=n_free,
        cells_observed=observed,
        proportion_at_or_above={float(t): at_or_above[t] / n_free if n_free else 0.0
                                for t in thresholds},
        mean_pd=sum_pd / n_free if n_free else 0.0,
        expected_false_alarms=false_alarms,
        limiting_cells=limiting_counts(grid.layer(Layer.LIMITING).tiles, grid.free),
    )


def limiting_counts(tiles: Mapping[TileKey, np.ndarray], free: FreeCells) -> dict[str, int]:
    """Free cells per LimitingFactor, by lower-case name, in code order, of a grid's
    limiting ``tiles`` (those written) and its ``free`` cells (free cells of no tile:
    NEVER_IN_VIEW)."""
    counts = np.zeros(len(LimitingFactor), dtype=np.int64)
    for key, tile in tiles.items():
        counts += np.bincount(tile[free.tile(key)], minlength=len(LimitingFactor))
    counts[LimitingFactor.NEVER_IN_VIEW] += free.n_free - int(counts.sum())
    return {f.name.lower(): int(counts[f]) for f in LimitingFactor}
