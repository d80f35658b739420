"""The coverage grids of one mission's cameras combined: one person seen by all of them."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.looks import same_looks_tables


def combine_cameras(into: CoverageGrid, grids: Sequence[CoverageGrid],
                    window: tuple[int, int, int, int] | None = None) -> None:
    """Set the cells of ``window`` (r0, r1, c0, c1; None: the whole grid) of ``into`` (a
    grid of independent looks, over the same cells) to the looks of ``grids`` together: the
    grids of one mission's cameras, one person seen by all of them. The one rule both
    drivers use (``pdcov evaluate`` once, the daemon per frame on its window).

    Each detector model has its own latent: the cameras of the same model (the same P_D
    and correlation per bin) are one sensor, their looks state merged (correlated: counts
    added; viewpoint: the best look per bin), so two cameras give the grid of one camera
    with all their frames; cameras of different models are independent of each other, their
    log-misses add, P_D = 1 - prod over models of P_miss. With independent looks every
    camera's log-miss adds. P_FA and the observation counts add; the limiting factor is the
    best (a frame's window: its ``touched``, which holds its far cells); the frame counts
    are the sums (``min_revisit_s`` applies per camera, in its own grid). One camera's grid that is
    ``into`` itself (config.Mission.camera_grids) is already the combination: left as is,
    its looks state with it."""
    if len(grids) == 1 and grids[0] is into:
        return
    if into.looks_model is not None:
        raise ValueError("combine_cameras writes derived log-misses: into must be a grid of "
                         "independent looks")
    g = into.geometry
    w = window or (0, g.n_rows, 0, g.n_cols)
    for grid in grids:  # the masks compared once, when the whole grid is combined
        if grid.geometry != g or (window is None and not grid.free.same_as(into.free)):
            raise ValueError("cannot combine grids of different geometry or free-space mask")
    into.layer(Layer.LOG_MISS_D).write(w, _combined_log_miss(grids, w))
    for layer, dtype in ((Layer.LOG_MISS_FA, np.float32), (Layer.N_OBS, np.int32)):
        into.layer(layer).write(w, np.asarray(np.sum([grid.read(layer, w) for grid in grids],
                                                     axis=0, dtype=dtype)))
    # A frame whose picture reaches past its range marks cells TOO_FAR outside its window
    # (``GridView.mark_too_far``): ``CoverageGrid.touched`` holds them, so the best of the
    # window's tiles is the best of the grid's (only tiles some camera holds are written).
    limiting = into.layer(Layer.LIMITING)
    layers = [grid.layer(Layer.LIMITING) for grid in grids]
    for p in into.layout.parts(w):
        found = [t[p.in_tile] for lay in layers if (t := lay.get(p.key)) is not None]
        if found:
            cells = limiting.tile(p.key)[p.in_tile]
            np.maximum.reduce([cells, *found], out=cells)
    if into.keeps(Layer.LAST_OBS_S):
        clocks = [grid.read(Layer.LAST_OBS_S, w) for grid in grids
                  if grid.keeps(Layer.LAST_OBS_S)]
        if clocks:
            into.layer(Layer.LAST_OBS_S).write(w, np.maximum.reduce(
                [into.read(Layer.LAST_OBS_S, w), *clocks]))
            into.latest_frame_t_s = max(into.latest_frame_t_s, *(
                grid.latest_frame_t_s for grid in grids if grid.keeps(Layer.LAST_OBS_S)))
    into.frames = sum(grid.frames for grid in grids)
    into.frames_blurred = sum(grid.frames_blurred for grid in grids)


def combined_pd(grids: Sequence[CoverageGrid]) -> np.ndarray:
    """P_D per cell (float64) of one person seen in all of ``grids`` (the same cells),
    by ``combine_cameras``'s rule, none of them changed: the grids of one looks rule and
    detector model as one sensor (two flights of a mission: their counts add, as ``merge``
    adds them), the others independent."""
    g = grids[0].geometry
    if any(grid.geometry != g or not grid.free.same_as(grids[0].free) for grid in grids):
        raise ValueError("cannot combine grids of different geometry or free-space mask")
    L = _combined_log_miss(grids, (0, g.n_rows, 0, g.n_cols))
    return 0.0 - np.expm1(L.astype(np.float64))


def _combined_log_miss(grids: Sequence[CoverageGrid], window: tuple[int, int, int, int]
                       ) -> np.ndarray:
    """log(1 - P_D) (float32) over ``window`` of ``grids`` together (``combine_cameras``)."""
    r0, r1, c0, c1 = window
    log_miss_d = np.zeros((r1 - r0, c1 - c0), dtype=np.float32)
    for group in _detector_groups(grids):
        first = group[0].looks_model
        if len(group) == 1 or first is None:
            for grid in group:
                log_miss_d += grid.read(Layer.LOG_MISS_D, window)
            continue
        state = first.combined([grid.read(Layer.LOOKS, window) for grid in group])
        flat = state.reshape(-1, state.shape[-1])
        log_miss_d += first.log_miss_of(flat).reshape(r1 - r0, c1 - c0).astype(np.float32)
    return log_miss_d


def _detector_groups(grids: Sequence[CoverageGrid]) -> list[list[CoverageGrid]]:
    """The grids by detector model (``same_looks_tables``), in order of first appearance;
    with independent looks each grid alone (their log-misses add either way)."""
    groups: list[list[CoverageGrid]] = []
    for grid in grids:
        same = next((grp for grp in groups if grid.looks_model is not None
                     and grp[0].looks == grid.looks
                     and same_looks_tables(grp[0].detector, grid.detector)), None)
        if same is None:
            groups.append([grid])
        else:
            same.append(grid)
    return groups
