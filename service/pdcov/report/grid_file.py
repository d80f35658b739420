"""The run's grid file: the one place a run folder's grid snapshot is written.

A grid of at most ``tiles.MAX_DENSE_CELLS`` cells is written whole as grid.npz (the
snapshot ``CoverageGrid.load_npz`` reads, core/grid_snapshot.py); a larger one as grid.zarr,
the grid store of the tiles its frames touched (core/grid_store.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_store import write_store
from pdcov.core.tiles import MAX_DENSE_CELLS

GRID_NPZ = "grid.npz"
GRID_STORE = "grid.zarr"


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
        if not with_limiting:  # the store has no way to say its limiting is unknown
            return GridFile(None, f"{GRID_STORE}: grid over {MAX_DENSE_CELLS:,} cells "
                                  f"({n_cells:,}) without its limiting factors: not written")
        write_store(out_dir / GRID_STORE, grid)
        return GridFile(GRID_STORE)
    grid.save_npz(out_dir / GRID_NPZ, with_limiting=with_limiting)
    return GridFile(GRID_NPZ)
