"""The run's grid file: the one place a run folder's grid snapshot is written.

A grid of at most ``tiles.MAX_DENSE_CELLS`` cells is written whole as grid.npz (the
snapshot ``CoverageGrid.load_npz`` reads, core/grid_snapshot.py); a larger one is not
written yet (its chunked store, grid.zarr, is to come), and the run's summary says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pdcov.core.grid import CoverageGrid
from pdcov.core.tiles import MAX_DENSE_CELLS

GRID_NPZ = "grid.npz"


@dataclass(frozen=True, slots=True)
class GridFile:
    """What ``write_grid_file`` did: the file it wrote (None: none) or why not."""

    name: str | None
    not_written: str | None = None


def write_grid_file(out_dir: Path, grid: CoverageGrid, *, with_limiting: bool) -> GridFile:
    """Write ``grid``'s snapshot into ``out_dir`` atomically (without limiting factors
    when ``with_limiting`` is False), when its size allows (module docstring)."""
    g = grid.geometry
    n_cells = g.n_rows * g.n_cols
    if n_cells > MAX_DENSE_CELLS:
        return GridFile(None, f"{GRID_NPZ}: grid over {MAX_DENSE_CELLS:,} cells "
                              f"({n_cells:,}): grid.npz not written (a grid this large "
                              "has no snapshot file yet); pd.tif holds the cells of the "
                              "extent its frames touched")
    grid.save_npz(out_dir / GRID_NPZ, with_limiting=with_limiting)
    return GridFile(GRID_NPZ)
