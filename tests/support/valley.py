"""A synthetic alpine valley (issue 21): analytic heights, written as a GeoTIFF in UTM.

The valley runs north along x = side/2 of a square domain [0, side]^2 (ENU metres, the
mission origin at its south-west corner): its floor rises 6 % northwards, its walls rise
quadratically east and west, a 38 m Gaussian hill stands in its southern half and a 26 m
ridge crosses it, slightly oblique, in its northern half. Positions and widths scale with the
side; heights do not. The benchmark (S5) and the tests build their DEMs here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymap3d
import rasterio
import rasterio.warp
from rasterio.crs import CRS
from rasterio.transform import from_origin

# Near Meiringen, Switzerland; UTM zone 32 N, where grid north is 0.6 deg from true north,
# so a DEM reader that ignores the CRS's rotation is caught.
ALPINE_ORIGIN_LAT_DEG, ALPINE_ORIGIN_LON_DEG = 46.72, 8.18
ALPINE_FLOOR_ALT_MSL_M = 595.0
UTM_32N = CRS.from_epsg(32632)


@dataclass(frozen=True, slots=True)
class Valley:
    """The valley's ground heights above the floor at the origin (m).

    side_m: the domain's side (m). floor_slope: the floor's rise per metre north. wall_m:
    the walls' height above the floor at the domain's east and west edges. hill_m, ridge_m:
    the heights of the hill and the ridge above the floor and walls under them.
    """

    side_m: float
    floor_slope: float = 0.06
    wall_m: float = 20.0
    hill_m: float = 38.0
    ridge_m: float = 26.0

    def height_m(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Heights (m) above the floor at the origin of ENU points (x east, y north, m)."""
        s = self.side_m
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        floor = self.floor_slope * y
        walls = self.wall_m * ((x - 0.5 * s) / (0.5 * s)) ** 2
        hill = self.hill_m * np.exp(-((x - 0.38 * s) ** 2 + (y - 0.33 * s) ** 2)
                                    / (2 * (0.11 * s) ** 2))
        # Distance across the ridge line y = 0.68 s + 0.1 (x - s/2); its ends fade out
        # smoothly 0.12 s beyond x = 0.18 s and x = 0.82 s.
        across = (y - 0.68 * s - 0.1 * (x - 0.5 * s)) / math.hypot(1.0, 0.1)
        ends = 0.5 * (np.tanh((x - 0.18 * s) / (0.06 * s)) - np.tanh((x - 0.82 * s) / (0.06 * s)))
        ridge = self.ridge_m * np.exp(-across**2 / (2 * (0.045 * s) ** 2)) * ends
        return floor + walls + hill + ridge


@dataclass(frozen=True, slots=True)
class ValleyDem:
    """Where the valley's DEM lies: the origin (the floor there is ``floor_alt_msl_m``), the
    raster's spacing (m, in UTM 32 N) and the margin (m) it extends beyond the domain."""

    valley: Valley
    spacing_m: float = 1.0
    margin_m: float = 200.0
    origin_lat_deg: float = ALPINE_ORIGIN_LAT_DEG
    origin_lon_deg: float = ALPINE_ORIGIN_LON_DEG
    floor_alt_msl_m: float = ALPINE_FLOOR_ALT_MSL_M

    def write_geotiff(self, path: Path) -> Path:
        """Write heights MSL (float32) at the pixel centres of a north-up UTM 32 N raster
        covering the domain and the margin."""
        s, m = self.valley.side_m, self.margin_m
        return write_enu_geotiff(path, self.valley.height_m, self.origin_lat_deg,
                                 self.origin_lon_deg, self.floor_alt_msl_m,
                                 (-m, -m, s + m, s + m), self.spacing_m)


def write_enu_geotiff(path: Path, height_m: Callable[[np.ndarray, np.ndarray], np.ndarray],
                      origin_lat_deg: float, origin_lon_deg: float, ground_alt_msl_m: float,
                      box_enu_m: tuple[float, float, float, float], spacing_m: float) -> Path:
    """Write analytic heights as a DEM: ``height_m(x, y)`` (m above ``ground_alt_msl_m``
    at ENU x, y about the origin) at the pixel centres of a north-up UTM 32 N float32
    raster of ``spacing_m`` pixels (aligned to whole multiples of it) covering the ENU box
    (x0, y0, x1, y1) (m); heights MSL."""
    x0, y0, x1, y1 = box_enu_m
    h = spacing_m
    ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    lat, lon, _ = pymap3d.enu2geodetic(ring[:, 0], ring[:, 1], 0.0, origin_lat_deg,
                                       origin_lon_deg, ground_alt_msl_m)
    east, north = rasterio.warp.transform(CRS.from_epsg(4326), UTM_32N, lon, lat)
    west_m, south_m = math.floor(min(east) / h) * h, math.floor(min(north) / h) * h
    n_cols = math.ceil((max(east) - west_m) / h)
    n_rows = math.ceil((max(north) - south_m) / h)
    north_m = south_m + n_rows * h
    e = west_m + h * (np.arange(n_cols) + 0.5)
    n = north_m - h * (np.arange(n_rows) + 0.5)
    E, N = np.meshgrid(e, n)
    lon_px, lat_px = rasterio.warp.transform(UTM_32N, CRS.from_epsg(4326), E.ravel(),
                                             N.ravel())
    x, y, _ = pymap3d.geodetic2enu(np.array(lat_px), np.array(lon_px), ground_alt_msl_m,
                                   origin_lat_deg, origin_lon_deg, ground_alt_msl_m)
    alt_msl_m = ground_alt_msl_m + height_m(x, y)
    with rasterio.open(path, "w", driver="GTiff", width=n_cols, height=n_rows, count=1,
                       dtype="float32", crs=UTM_32N,
                       transform=from_origin(west_m, north_m, h, h), nodata=-9999.0,
                       tiled=True, blockxsize=256, blockysize=256,
                       compress="deflate") as dst:
        dst.write(alt_msl_m.reshape(n_rows, n_cols).astype(np.float32), 1)
    return path
