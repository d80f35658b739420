"""Two coverage grids of the same cells added: another flight, vehicle or sortie."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pdcov.core.grid_layer import Layer
from pdcov.core.looks import same_looks_tables

if TYPE_CHECKING:
    from pdcov.core.grid import CoverageGrid


def merge_grids(into: CoverageGrid, other: CoverageGrid) -> None:
    """Add ``other`` into ``into``, a grid of the same geometry (another flight or vehicle),
    tile by tile (the tiles ``other`` touched).

    With correlated or viewpoint looks both grids must have the same looks rule and
    detector model (their states add up only then); grids of different detectors
    combine at the quadrature nodes instead (``log_miss_nodes``)."""
    if other.geometry != into.geometry or not other.free.same_as(into.free):
        raise ValueError("cannot merge grids of different geometry or free-space mask")
    if other.looks != into.looks:
        raise ValueError(f"cannot merge a grid of coverage.looks {other.looks.rule} "
                         f"into one of {into.looks.rule} (or of other viewpoint bins)")
    looks = into.looks_model
    if looks is not None and not same_looks_tables(into.detector, other.detector):
        raise ValueError(
            f"cannot merge {into.looks.rule} looks of different detector models (their "
            "bins' P_D or correlation differ): combine them per person at the "
            "quadrature nodes, looks.pd_of_node_log_miss(a.log_miss_nodes() + "
            "b.log_miss_nodes())")
    for layer, add in ((Layer.LOG_MISS_FA, np.add), (Layer.N_OBS, np.add),
                       (Layer.LIMITING, np.maximum), (Layer.LAST_OBS_S, np.maximum),
                       (Layer.LOOKS, None), (Layer.LOG_MISS_D, np.add)):
        if not (into.keeps(layer) and other.keeps(layer)):
            continue
        if layer is Layer.LOG_MISS_D and looks is not None:
            continue  # derived from the looks state
        mine = into.layer(layer)
        for key, tile in other.layer(layer).tiles.items():
            cells = mine.tile(key)
            if layer is Layer.LOOKS:
                assert looks is not None
                cells[...] = looks.combined([cells, tile])
                into.mark_looks_changed(into.layout.window_of(key))
            else:
                assert add is not None
                add(cells, tile, out=cells)
    into.frames += other.frames
    into.frames_blurred += other.frames_blurred
    if into.keeps(Layer.LAST_OBS_S) and other.keeps(Layer.LAST_OBS_S):
        into.latest_frame_t_s = max(into.latest_frame_t_s, other.latest_frame_t_s)
