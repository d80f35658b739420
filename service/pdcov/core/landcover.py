"""Land-cover rasters: the class code (an integer, e.g. ESA WorldCover's 10 tree cover, 50
built-up) at geodetic points, and what each class stands for (``CoverKind``).

``LandCover.open`` reads band 1 of a raster rasterio reads, in any CRS, once: only the
window over the area asked for (``dem.raster_window``), in the file's own integer type.
``codes_at`` takes the code of the pixel a point falls in (nearest pixel: codes are
classes, never interpolated). A float raster is accepted only when its values are whole
numbers. Every refusal is one line naming the file (InputFileError).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from pdcov.core.dem import (
    MAX_WINDOW_PIXELS,
    check_window_size,
    lonlat_bounds,
    lonlat_to_pixel,
    open_raster,
    raster_window,
)
from pdcov.core.ground_cover import CoverKind
from pdcov.errors import InputFileError
from pdcov.extras import GIS

__all__ = ["WORLDCOVER_CLASSES", "LandCover", "cover_kinds"]

WORLDCOVER_CLASSES: Mapping[int, CoverKind] = MappingProxyType(
    {10: CoverKind.FOLIAGE, 50: CoverKind.SOLID})
"""The default classes (ESA WorldCover 2020/2021 codes): 10 tree cover is foliage, 50
built-up is solid; a raised surface of any other code is solid (``cover_kinds``)."""


@dataclass(frozen=True, slots=True, eq=False)
class LandCover:
    """Class codes of the window of a land-cover raster that was read.

    codes: int64 (rows, cols), row 0 at the raster's top as in the file, 0 where has_code is
    False; has_code: bool, False on the raster's nodata (or NaN); transform: the window's
    affine pixel -> CRS map (rasterio's); crs_wkt: the raster's CRS. bounds_lonlat_deg:
    (west, south, east, north) of the whole raster, for messages.
    """

    path: Path
    codes: np.ndarray
    has_code: np.ndarray
    transform: Any  # affine.Affine
    crs_wkt: str
    bounds_lonlat_deg: tuple[float, float, float, float]

    @classmethod
    def open(cls, path: str | Path, *, area_lonlat_deg: tuple[float, float, float, float],
             margin_m: float = 0.0, max_pixels: int = MAX_WINDOW_PIXELS) -> LandCover:
        """Read the codes under ``area_lonlat_deg`` (west, south, east, north; degrees)
        widened by margin_m (m). Raises InputFileError naming the file: not a raster, no
        CRS, a window of more than ``max_pixels`` pixels, codes that are not whole
        numbers."""
        GIS.require("a land-cover raster (terrain.landcover) needs")
        from rasterio.errors import RasterioError

        path = Path(path)
        with open_raster(path) as src:
            window = raster_window(src, area_lonlat_deg, margin_m)
            check_window_size(path, window, area_lonlat_deg, max_pixels)
            if window.width and window.height:
                try:
                    raw = src.read(1, window=window, masked=True)
                except RasterioError as exc:
                    raise InputFileError(f"{path}: cannot read its classes: {exc}") from None
            else:  # the area is off the raster: nothing to read
                raw = np.ma.masked_array(np.zeros((0, 0), dtype=np.uint8))
            transform = src.window_transform(window)
            bounds = lonlat_bounds(src)
            crs_wkt = src.crs.to_wkt()
        has = ~np.ma.getmaskarray(raw)
        values = np.ma.getdata(raw)
        if values.dtype.kind == "f":
            has &= np.isfinite(values)
            v = values[has]
            bad = v[(v != np.round(v)) | (np.abs(v) >= 2.0**53)]
            if bad.size:
                raise InputFileError(
                    f"{path}: a land-cover raster holds class codes, whole numbers; this "
                    f"{values.dtype} one holds {float(bad[0]):g}: use the classes' raster "
                    "(e.g. ESA WorldCover's uint8 codes), not a fraction or a height")
        elif values.dtype.kind not in "iub":
            raise InputFileError(f"{path}: a land-cover raster holds class codes, whole "
                                 f"numbers; its band is {values.dtype}")
        codes = np.where(has, values, 0).astype(np.int64)
        codes.setflags(write=False)
        has.setflags(write=False)
        return cls(path, codes, has, transform, crs_wkt, bounds)

    def codes_at(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The code of the pixel each geodetic point (WGS84 degrees) falls in (int64, 0
        where it has none), and whether it has one (bool): False outside the window read
        or on nodata."""
        col, row = lonlat_to_pixel(self.transform, self.crs_wkt, lat_deg, lon_deg)
        n_rows, n_cols = self.codes.shape
        with np.errstate(invalid="ignore"):
            j = np.floor(col)
            i = np.floor(row)
            inside = (j >= 0) & (j < n_cols) & (i >= 0) & (i < n_rows)
        codes = np.zeros(inside.shape, dtype=np.int64)
        has = np.zeros(inside.shape, dtype=bool)
        ii, jj = i[inside].astype(np.intp), j[inside].astype(np.intp)
        codes[inside] = self.codes[ii, jj]
        has[inside] = self.has_code[ii, jj]
        return codes, has


def cover_kinds(codes: np.ndarray, has_code: np.ndarray,
                classes: Mapping[int, CoverKind]) -> np.ndarray:
    """The CoverKind (uint8) of a raised surface of each code: its class's in ``classes``;
    SOLID for a code not listed or no code (has_code False): what stands there is not known
    to let a line of sight through."""
    kind = np.full(np.shape(codes), CoverKind.SOLID, dtype=np.uint8)
    for code, k in classes.items():
        kind[has_code & (codes == code)] = k
    return kind
