"""A daemon's checkpoint folder read as the tests compare grids: the current slot's grid
store opened with zarr (an independent reader of the Zarr v3 store) as the arrays a grid.npz
holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import zarr

from pdcov.core.domain import GridGeometry
from pdcov.core.free_cells import FreeCells


def read_checkpoint(folder: Path, camera: str | None = None) -> dict[str, Any]:
    """The grid of the checkpoint ``folder`` (or camera ``camera``'s own): log_miss_d,
    log_miss_fa, n_obs, limiting, mask, pd and pfa (and last_obs_s when kept) as whole
    arrays, ``frames``, and its metadata ``meta`` (meta.json's object)."""
    slot = folder / (folder / "current").read_text().strip()
    root = zarr.open_group(str(slot / ("grid.zarr" if camera is None
                                       else f"cameras/{camera}.zarr")), mode="r")
    out: dict[str, Any] = {name: np.asarray(root[name][...])
                           for name in ("log_miss_d", "log_miss_fa", "n_obs", "limiting",
                                        "last_obs_s") if name in root}
    attrs = root.attrs.asdict()
    g = GridGeometry(attrs["x0_m"], attrs["y0_m"], attrs["cell_size_m"], attrs["n_rows"],
                     attrs["n_cols"])
    out["mask"] = (np.asarray(root["mask"][...]) if "mask" in root else FreeCells(
        g, free_space=shapely.from_wkb(attrs["free_space_wkb"])).dense())
    out["pd"] = 0.0 - np.expm1(out["log_miss_d"].astype(np.float64))
    out["pfa"] = 0.0 - np.expm1(out["log_miss_fa"].astype(np.float64))
    out["frames"] = attrs["frames"]
    out["meta"] = json.loads((slot / "meta.json").read_text())
    return out
