"""The canopy config scene for the tests of terrain.surface: a 100 x 100 m domain of 10 m
cells about the origin (46.5 N, 7.5 E) with a house, trees, a hedge, a shed and unclassed
trees on it (``OBJECTS``), written as real GeoTIFFs: the DEM (a tilted plane) and the DSM in
UTM 32N, the land cover (WorldCover-like codes) in WGS84 degrees with nodata; ``doc`` is the
mission config over them (``mission_doc``'s camera), ``load`` reads it.

Needs rasterio: a test module importing this calls ``pytest.importorskip("rasterio")``
first."""

from __future__ import annotations

import numpy as np
import rasterio
from rasterio.transform import from_origin
from rasterio.warp import transform as warp_transform

from pdcov.config.load import mission_from_dict
from pdcov.config.mission import Mission
from pdcov.core.geodesy import Origin, geodetic_to_enu
from tests.support.evaluate_inputs import mission_doc

LAT0, LON0, H0 = 46.5, 7.5, 1000.0
UTM32N = "EPSG:32632"
E0, N0 = (float(v[0]) for v in warp_transform("EPSG:4326", UTM32N, [LON0], [LAT0]))

# What stands on the 100 x 100 m domain of 10 m cells about the origin (cell (row i, col j)
# has its centre at x = -45 + 10 j, y = -45 + 10 i): ENU boxes (x0, x1, y0, y1), height
# above the ground (m) and the land-cover code there (0: the land cover's nodata). Their
# edges lie on cell edges, 5 m from every centre, farther than the rasters' pixels reach.
OBJECTS = [
    ((10, 30, 10, 30), 10.0, 50),    # a house: cells rows 6-7, cols 6-7
    ((-40, -10, -40, -20), 15.0, 10),  # trees: rows 1-2, cols 1-3
    ((-40, -30, 20, 30), 1.5, 30),   # a hedge, below min_object_height_m: row 7, col 1
    ((30, 40, -40, -30), 6.0, 30),   # a shed on grassland: row 1, col 8
    ((-40, -30, 0, 10), 12.0, 0),    # trees where the land cover has nodata: row 5, col 1
]
GRASS = 30


def plane(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The ground (m MSL): a tilted plane in UTM, which bilinear interpolation keeps."""
    return H0 + 0.02 * (e - E0) + 0.01 * (n - N0)


def enu_of_utm(e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lon, lat = warp_transform(UTM32N, "EPSG:4326", e.ravel(), n.ravel())
    r = geodetic_to_enu(np.asarray(lat), np.asarray(lon), H0, Origin(LAT0, LON0, H0))
    return r[:, 0].reshape(e.shape), r[:, 1].reshape(e.shape)


def in_box(x: np.ndarray, y: np.ndarray, box) -> np.ndarray:
    x0, x1, y0, y1 = box
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def write(path, values, transform, crs, nodata=None, dtype="float64"):
    with rasterio.open(path, "w", driver="GTiff", height=values.shape[0],
                       width=values.shape[1], count=1, dtype=dtype, crs=crs,
                       transform=transform, nodata=nodata) as dst:
        dst.write(values.astype(dtype), 1)
    return path


def utm_centres(half_m: float, px_m: float) -> tuple[np.ndarray, np.ndarray]:
    n = round(2 * half_m / px_m)
    c = (np.arange(n) + 0.5) * px_m
    return np.meshgrid(E0 - half_m + c, N0 + half_m - c)


def write_dem(tmp_path, offset_m=0.0, px_m=10.0, hole_at=None):
    """The DEM: the plane, px_m pixels 400 m about the origin, offset_m higher; hole_at:
    an ENU point (x, y) whose pixel is nodata."""
    e, n = utm_centres(400.0, px_m)
    h = plane(e, n) + offset_m
    if hole_at is not None:
        x, y = enu_of_utm(e, n)
        h[np.unravel_index(np.argmin(np.hypot(x - hole_at[0], y - hole_at[1])), h.shape)] = \
            -9999.0
    return write(tmp_path / "dem.tif", h, from_origin(E0 - 400, N0 + 400, px_m, px_m),
                 UTM32N, nodata=-9999.0)


def write_dsm(tmp_path, hole=None, west_m=150.0, offset_m=0.0):
    """The DSM: 2 m pixels over the ground and OBJECTS, 150 m about the origin, offset_m
    higher; ``hole``: an ENU box of nodata; west_m: how far west of the origin the raster
    reaches."""
    e, n = utm_centres(150.0, 2.0)
    keep = round((150.0 - west_m) / 2.0)
    e, n = e[:, keep:], n[:, keep:]
    x, y = enu_of_utm(e, n)
    h = plane(e, n) + offset_m
    for box, height, _ in OBJECTS:
        h = np.where(in_box(x, y, box), h + height, h)
    if hole is not None:
        h[in_box(x, y, hole)] = -9999.0
    return write(tmp_path / "dsm.tif", h, from_origin(E0 - west_m, N0 + 150, 2, 2), UTM32N,
                 nodata=-9999.0)


def write_landcover(tmp_path, dtype="uint8", values=None):
    """WorldCover-like codes in EPSG:4326 (pixels of 4e-5 deg: 4.4 x 3.1 m), nodata 0."""
    px = 4e-5
    n_lat, n_lon = 80, 100
    lat = LAT0 + 0.0016 - (np.arange(n_lat) + 0.5) * px
    lon = LON0 - 0.002 + (np.arange(n_lon) + 0.5) * px
    LON, LAT = np.meshgrid(lon, lat)
    r = geodetic_to_enu(LAT.ravel(), LON.ravel(), H0, Origin(LAT0, LON0, H0))
    x, y = r[:, 0].reshape(LAT.shape), r[:, 1].reshape(LAT.shape)
    codes = np.full(LAT.shape, GRASS)
    for box, _, code in OBJECTS:
        codes[in_box(x, y, box)] = code
    if values is not None:
        codes = values(codes)
    return write(tmp_path / "landcover.tif", codes, from_origin(LON0 - 0.002, LAT0 + 0.0016,
                                                                px, px), "EPSG:4326",
                 nodata=0, dtype=dtype)


def doc(tmp_path, *, with_dsm=True, with_landcover=True, **terrain):
    """The mission over the scene: the DEM, DSM and land cover written to tmp_path (those
    asked for), the terrain keys given."""
    d = mission_doc(terrain={"dem": str(write_dem(tmp_path)),
                             **({"surface": str(write_dsm(tmp_path))} if with_dsm else {}),
                             **({"landcover": str(write_landcover(tmp_path))}
                                if with_landcover else {}), **terrain})
    d["origin"] = {"lat_deg": LAT0, "lon_deg": LON0}
    d["domain"] = {"polygon_enu_m": [[-50, -50], [50, -50], [50, 50], [-50, 50]],
                   "cell_size_m": 10.0}
    return d


def load(tmp_path, d) -> Mission:
    return mission_from_dict(d, source="m.yaml", base_dir=tmp_path)
