"""The oracle the UTM GeoTIFFs (report/gis.py) are read back against: which grid cell lies
under each pixel centre, and where ENU points land in the raster, by pdcov's own geodesy
(core/geodesy.py, pymap3d) and PROJ between WGS84 and the raster's CRS."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu

EDGE_CELLS = 0.01
"""How near a cell edge (cells) a pixel centre may lie before it could be either cell's."""


@dataclass(frozen=True, slots=True)
class PixelCells:
    """Per raster pixel (flattened, row-major): its row and column, the grid cell under its
    centre (row growing north, column east), whether that centre lies over the grid and
    whether it lies over the grid more than EDGE_CELLS from a cell edge."""

    row: np.ndarray
    col: np.ndarray
    cell_row: np.ndarray
    cell_col: np.ndarray
    inside: np.ndarray
    clear: np.ndarray


def pixel_cells(src: Any, geometry: GridGeometry, origin: Origin) -> PixelCells:
    """The grid cells under the pixel centres of ``src`` (an open rasterio dataset)."""
    import rasterio
    from rasterio.warp import transform

    rows, cols = (a.ravel() for a in np.mgrid[0:src.height, 0:src.width])
    xs, ys = rasterio.transform.xy(src.transform, rows, cols)
    lon, lat = transform(src.crs, "EPSG:4326", xs, ys)
    enu = geodetic_to_enu(np.asarray(lat), np.asarray(lon), origin.ground_alt_msl_m, origin)
    fc = (enu[:, 0] - geometry.x0_m) / geometry.cell_size_m
    fr = (enu[:, 1] - geometry.y0_m) / geometry.cell_size_m
    inside = (fc >= 0) & (fc < geometry.n_cols) & (fr >= 0) & (fr < geometry.n_rows)
    clear = inside & (np.abs(fc - np.round(fc)) > EDGE_CELLS) & (
        np.abs(fr - np.round(fr)) > EDGE_CELLS)
    k, r = (np.clip(np.floor(f), 0, n - 1).astype(int)
            for f, n in ((fc, geometry.n_cols), (fr, geometry.n_rows)))
    return PixelCells(rows, cols, r, k, inside, clear)


def enu_to_raster_xy(xy_enu_m: np.ndarray, origin: Origin, crs: Any
                     ) -> tuple[np.ndarray, np.ndarray]:
    """ENU points (N, 2) m on the origin's ground in ``crs``'s coordinates (x, y)."""
    from rasterio.warp import transform

    xy = np.asarray(xy_enu_m, dtype=float).reshape(-1, 2)
    lla = enu_to_geodetic(np.c_[xy, np.zeros(len(xy))], origin)
    x, y = transform("EPSG:4326", crs, lla[:, 1], lla[:, 0])
    return np.asarray(x), np.asarray(y)
