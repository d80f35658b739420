"""GIS exports: the grid's bands as Cloud-Optimised GeoTIFFs (tiled, compressed, written
block by block: pd.tif, looks.tif, limiting.tif), the P_D overlay as an RGBA COG in Web
Mercator (pd_rgba_3857.tif) and the threshold outline as GeoJSON (rasterio); cell outlines
in ENU and their WGS84 coordinates for the other exports (report/exports.py).

The grid lives in the local ENU plane about the mission origin, which a transverse Mercator
projection centred on that origin at the plane's scale (``local_crs_wkt``; no false
easting or northing) matches to well under a millimetre over a few km. The grid's
GeoTIFFs are warped from it into the mission's UTM zone (an EPSG CRS, which GIS tools
take), the P_D overlay into Web Mercator; the GeoJSON is WGS84 longitude/latitude as RFC
7946 requires.
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from pdcov.atomic import atomic_path, write_text_atomic
from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, deg_rounded, enu_to_geodetic
from pdcov.core.limiting import LimitingFactor
from pdcov.core.tiles import Window

_WGS84_A_M, _WGS84_E2 = 6378137.0, 6.69437999014e-3


def local_crs_wkt(origin: Origin) -> str:
    """PROJ string of the transverse Mercator plane centred on ``origin`` that matches its ENU
    plane: the ENU plane lies at the origin's height h (``ground_alt_msl_m``, the height
    its geodetic conversions use), where a metre spans R / (R + h) of a metre on the
    ellipsoid (R the Gaussian radius there), so the scale factor is (R + h) / R; with 1,
    an origin 2,500 m up would drift 0.78 m per axis at 2 km."""
    lat = math.radians(origin.lat_deg)
    w = 1.0 - _WGS84_E2 * math.sin(lat) ** 2
    r_m = _WGS84_A_M * math.sqrt(1.0 - _WGS84_E2) / w  # sqrt(M N)
    k = (r_m + origin.ground_alt_msl_m) / r_m
    return (f"+proj=tmerc +lat_0={origin.lat_deg:.9f} +lon_0={origin.lon_deg:.9f} "
            f"+k={k:.12f} +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs")


def utm_epsg(origin: Origin) -> int:
    """EPSG code of WGS 84 / UTM zone of ``origin``: 326zz north of the equator, 327zz
    south, the zone by longitude with the grid's exceptions: 32 over south-west Norway
    (56-64 N, 3-12 E) and 31, 33, 35, 37 over Svalbard (72-84 N, 0-42 E). Beyond 84 N or
    80 S (polar stereographic's, UTM's edge) still the zone by longitude: the transverse
    Mercator holds there too."""
    lat, lon = origin.lat_deg, (origin.lon_deg + 180.0) % 360.0 - 180.0
    zone = min(int((lon + 180.0) // 6.0) + 1, 60)
    if 56.0 <= lat < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    elif 72.0 <= lat <= 84.0 and 0.0 <= lon < 42.0:
        zone = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return (32600 if lat >= 0.0 else 32700) + zone


def _plane_tags(geometry: GridGeometry, origin: Origin) -> dict[str, str]:
    """GeoTIFF metadata naming the grid's place: the ENU origin (WGS84 degrees, ground m
    MSL), the plane's convention and PROJ string, the grid's south-west corner (ENU m)
    and cell size (m)."""
    return {"ENU_ORIGIN_LAT_DEG": repr(origin.lat_deg),
            "ENU_ORIGIN_LON_DEG": repr(origin.lon_deg),
            "ENU_ORIGIN_ALT_MSL_M": repr(origin.ground_alt_msl_m),
            "ENU_PLANE": _ENU_PLANE, "ENU_PLANE_PROJ": local_crs_wkt(origin),
            "GRID_SW_ENU_M": f"{geometry.x0_m!r} {geometry.y0_m!r}",
            "GRID_CELL_SIZE_M": repr(geometry.cell_size_m)}


_ENU_PLANE = ("pdcov's grid lies on the east-north-up plane tangent to the WGS84 ellipsoid "
              "normal at ENU_ORIGIN, at its ground height (x east, y north, metres; the "
              "plane is ENU_PLANE_PROJ); cells of GRID_CELL_SIZE_M from GRID_SW_ENU_M, "
              "rows growing north; grid.npz holds them exactly")
_WARP_TOLERANCE_PX = 1e-5  # GDAL's approximate transform error when warping (pixels)


def _transform(geometry: GridGeometry) -> Any:
    from rasterio.transform import from_origin

    x0, _, _, y1 = geometry.extent_enu
    return from_origin(x0, y1, geometry.cell_size_m, geometry.cell_size_m)


GEOTIFF_BLOCK = 256
"""GeoTIFF tile side (pixels): the file is tiled, deflate-compressed and written a block
at a time."""
_GDAL_CACHE_MB = 64  # GDAL's block cache while writing (its default is 5 % of the RAM)

BandReader = Callable[[Window], np.ndarray]
"""A band's cells of a window (r0, r1, c0, c1 of the raster's grid; rows growing north)."""

BAND_INFO = {
    "pd": ("cumulative probability of detection P_D of the cell", "probability 0-1"),
    "pfa": ("cumulative probability of at least one false alarm in the cell",
            "probability 0-1"),
    "n_obs": ("looks: frames that observed the cell", "count"),
    "limiting": ("limiting factor: what limited the cell's P_D (LIMITING_CODES)", "code"),
    "posterior_poa": ("probability of area after the search", "probability"),
}
"""What a band named so holds, and its units: written as the band's LONG_NAME and UNITS
metadata and its GDAL unit type (the band's description is its name)."""
LIMITING_NODATA = 255
"""limiting.tif's value outside the free cells."""
LOOKS_NODATA = -1
"""looks.tif's value outside the free cells."""


def limiting_codes() -> str:
    """The limiting factor codes as a metadata value: "0=never_in_view, 1=too_far, ..."."""
    return ", ".join(f"{f.value}={f.name.lower()}" for f in LimitingFactor)


def array_band(values: np.ndarray) -> BandReader:
    """A band read from an array of the whole raster."""
    return lambda w: values[w[0]:w[1], w[2]:w[3]]


@contextmanager
def _cog(path: str | Path) -> Iterator[Path]:
    """A path to write a tiled GeoTIFF to, laid out as a Cloud-Optimised GeoTIFF at
    ``path`` by GDAL's COG driver (deflate, GEOTIFF_BLOCK tiles, nearest overviews) when
    the block ends. Atomic: temp files then rename."""
    import rasterio
    from rasterio.shutil import copy as gdal_copy

    with rasterio.Env(GDAL_CACHEMAX=_GDAL_CACHE_MB), atomic_path(path) as cog, \
            tempfile.TemporaryDirectory(prefix=".gtiff.", dir=Path(path).parent) as work:
        tiled = Path(work) / "blocks.tif"
        yield tiled
        gdal_copy(tiled, cog, driver="COG", compress="DEFLATE", blocksize=GEOTIFF_BLOCK,
                  overview_resampling="nearest")


def write_geotiff(path: str | Path, bands: Mapping[str, BandReader], geometry: GridGeometry,
                  origin: Origin, mask: BandReader, *, dtype: str = "float32",
                  nodata: float = math.nan, tags: Mapping[str, str] | None = None,
                  exact_grid: bool = False) -> None:
    """Cloud-Optimised GeoTIFF of ``dtype`` with one band per entry of ``bands`` over the
    cells of ``geometry`` (rows grow north, as in the grid; written north-up), ``nodata``
    outside the free cells (``mask``): tiled (GEOTIFF_BLOCK), deflate-compressed, with
    overviews, so a viewer reads a county's at any zoom a few tiles at a time. Each band's
    description is its name, with BAND_INFO's LONG_NAME and UNITS; the file's metadata:
    ``tags`` and where the grid lies (``_plane_tags``). In the mission's UTM zone
    (``warp_to_utm``), or with ``exact_grid`` the grid's own cells in the local plane
    (``local_crs_wkt``, as ``read_geotiff_band`` reads). Written block by block (only one
    block of each band in memory at once), then laid out as a COG by GDAL's COG driver.
    Atomic."""
    import rasterio
    from rasterio.windows import Window as RasterWindow

    b = GEOTIFF_BLOCK
    with _cog(path) as tiled:
        local = tiled if exact_grid else tiled.with_name("local.tif")
        with rasterio.open(local, "w", driver="GTiff", width=geometry.n_cols,
                           height=geometry.n_rows, count=len(bands), dtype=dtype,
                           crs=local_crs_wkt(origin), transform=_transform(geometry),
                           nodata=nodata, compress="deflate", tiled=True, blockxsize=b,
                           blockysize=b) as dst:
            for top in range(0, geometry.n_rows, b):  # file rows from the north edge
                r1 = geometry.n_rows - top
                r0 = max(0, r1 - b)
                for c0 in range(0, geometry.n_cols, b):
                    c1 = min(c0 + b, geometry.n_cols)
                    w = (r0, r1, c0, c1)
                    free = mask(w)
                    block = np.stack([np.where(free, read(w), nodata).astype(dtype)
                                      for read in bands.values()])
                    dst.write(block[:, ::-1], window=RasterWindow(c0, top, c1 - c0, r1 - r0))
        if not exact_grid:
            warp_to_utm(local, tiled, origin, geometry.cell_size_m)
        with rasterio.open(tiled, "r+") as dst:
            dst.update_tags(**(tags or {}), **_plane_tags(geometry, origin))
            for i, name in enumerate(bands, start=1):
                dst.set_band_description(i, name)
                if name in BAND_INFO:
                    long_name, units = BAND_INFO[name]
                    dst.update_tags(i, LONG_NAME=long_name, UNITS=units)
                    dst.set_band_unit(i, units)


def warp_to_utm(local: Path, out: Path, origin: Origin, cell_size_m: float) -> None:
    """``local`` (a GeoTIFF on the local plane) warped into a tiled GeoTIFF ``out`` in the
    mission's UTM zone (``utm_epsg``), a block at a time: pixels of ``cell_size_m`` UTM
    metres on the zone's lattice of that size (so runs of one mission line up) over the
    cells' bounds, each the value of the cell under its centre (nearest neighbour, to within
    _WARP_TOLERANCE_PX: no value that no cell had, integer codes exact), nodata beyond
    the cells. The grid is turned by the meridian convergence against the zone's (up to a
    few degrees) and scaled by under 0.1 %, so a few cells in a thousand show twice or not
    at all: grid.npz holds them all."""
    import rasterio
    from rasterio.crs import CRS
    from rasterio.enums import Resampling
    from rasterio.transform import from_origin
    from rasterio.vrt import WarpedVRT
    from rasterio.warp import transform_bounds

    crs, c = CRS.from_epsg(utm_epsg(origin)), cell_size_m
    with rasterio.open(local) as src:
        left, bottom, right, top = transform_bounds(src.crs, crs, *src.bounds)
        i0, i1 = math.floor(left / c), math.ceil(right / c)
        j0, j1 = math.floor(bottom / c), math.ceil(top / c)
        transform, width, height = from_origin(i0 * c, j1 * c, c, c), i1 - i0, j1 - j0
        profile = {**src.profile, "crs": crs, "transform": transform, "width": width,
                   "height": height}
        with WarpedVRT(src, crs=crs, transform=transform, width=width, height=height,
                       resampling=Resampling.nearest, tolerance=_WARP_TOLERANCE_PX) as vrt, \
                rasterio.open(out, "w", **profile) as dst:
            for _, window in dst.block_windows(1):
                dst.write(vrt.read(window=window), window=window)


def write_rgba_3857(path: str | Path, rgba: np.ndarray, geometry: GridGeometry,
                    origin: Origin, tags: Mapping[str, str] | None = None) -> None:
    """An RGBA image (uint8 rows x cols x 4, north up; one pixel a cell of ``geometry``,
    e.g. report/colours.pd_rgba's) as a Cloud-Optimised GeoTIFF in Web Mercator
    (EPSG:3857), for tools that take images: warped from the local plane by nearest
    neighbour (colours kept exactly) at about the same number of pixels, alpha 0 beyond
    the image. The whole image is held in memory: bound it as the overlay is
    (colours.pd_rgba's ``max_side``). Atomic."""
    import rasterio
    from rasterio.enums import ColorInterp, Resampling
    from rasterio.warp import calculate_default_transform, reproject

    src_crs, n_rows, n_cols = local_crs_wkt(origin), rgba.shape[0], rgba.shape[1]
    x0, x1, y0, y1 = geometry.extent_enu
    dst_transform, width, height = calculate_default_transform(
        src_crs, "EPSG:3857", n_cols, n_rows, left=x0, bottom=y0, right=x1, top=y1)
    out = np.zeros((4, height, width), np.uint8)  # transparent beyond the image
    reproject(np.moveaxis(rgba, -1, 0), out, src_transform=_transform(geometry),
              src_crs=src_crs, dst_transform=dst_transform, dst_crs="EPSG:3857",
              resampling=Resampling.nearest)
    b = GEOTIFF_BLOCK
    with _cog(path) as tiled, rasterio.open(
            tiled, "w", driver="GTiff", width=width, height=height, count=4, dtype="uint8",
            crs="EPSG:3857", transform=dst_transform, photometric="RGB", alpha="YES",
            compress="deflate", tiled=True, blockxsize=b, blockysize=b) as dst:
        dst.colorinterp = (ColorInterp.red, ColorInterp.green, ColorInterp.blue,
                           ColorInterp.alpha)
        dst.update_tags(**(tags or {}))
        dst.write(out)


def read_geotiff_band(path: str | Path, geometry: GridGeometry) -> np.ndarray:
    """Band 1 of a GeoTIFF aligned with ``geometry`` (same size and transform), as a grid
    array with rows growing north. Raises ValueError when it is not aligned."""
    import rasterio

    with rasterio.open(path) as src:
        if (src.width, src.height) != (geometry.n_cols, geometry.n_rows):
            raise ValueError(f"raster is {src.width} x {src.height} cells, the grid is "
                             f"{geometry.n_cols} x {geometry.n_rows}")
        if not np.allclose(tuple(src.transform)[:6], tuple(_transform(geometry))[:6],
                           atol=1e-6):
            raise ValueError(f"raster transform {tuple(src.transform)[:6]} does not match the "
                             f"grid's {tuple(_transform(geometry))[:6]}")
        return np.flipud(src.read(1).astype(float))


def threshold_outline(pd: np.ndarray, mask: np.ndarray, geometry: GridGeometry,
                      threshold: float) -> list[list[list[list[float]]]]:
    """Polygons (ENU metres, rings of [x, y]) of the free cells with P_D >= ``threshold``:
    a list of polygons, each a list of rings (exterior first, then holes)."""
    return cells_outline(mask & (pd >= threshold), geometry)


def cells_outline(cells: np.ndarray, geometry: GridGeometry) -> list[list[list[list[float]]]]:
    """Polygons (ENU metres, rings of [x, y], exterior first, then holes) of the cells set
    in the boolean grid array ``cells`` (rows growing north); cells touching by a side
    share a polygon."""
    from rasterio.features import shapes

    hit = np.flipud(cells).astype(np.uint8)
    polys = []
    for geom, value in shapes(hit, mask=hit > 0, transform=_transform(geometry)):
        if value == 1:
            polys.append([[list(map(float, p)) for p in ring] for ring in geom["coordinates"]])
    return polys


def polygons_lon_lat(polygons_enu: list[list[list[list[float]]]], origin: Origin
                     ) -> list[list[list[list[float]]]]:
    """ENU polygons (lists of rings of [x, y] m, on the origin's ground) as WGS84
    [lon, lat] degrees, the order GeoJSON (RFC 7946) and KML use, rounded to
    ``geodesy.DEG_DECIMALS``, wound as RFC 7946 section 3.1.6 wants: the exterior
    counter-clockwise, the holes clockwise (seen from above, east right, north up)."""
    out = []
    for poly in polygons_enu:
        rings = []
        for ring in poly:
            enu = np.array(ring, dtype=float).reshape(-1, 2)
            lla = enu_to_geodetic(np.c_[enu, np.zeros(len(enu))], origin)
            rings.append([[deg_rounded(lon), deg_rounded(lat)] for lat, lon, _ in lla])
        wound = orient(shapely.Polygon(rings[0], rings[1:]), sign=1.0)
        out.append([[list(xy) for xy in wound.exterior.coords],
                    *([list(xy) for xy in r.coords] for r in wound.interiors)])
    return out


def write_outline_geojson(path: str | Path, polygons_enu: list[list[list[list[float]]]],
                          origin: Origin, threshold: float) -> None:
    """GeoJSON FeatureCollection (WGS84 lon/lat) of the threshold outline, atomically."""
    coords = polygons_lon_lat(polygons_enu, origin)
    doc = {"type": "FeatureCollection", "features": [{
        "type": "Feature",
        "properties": {"pd_threshold": threshold, "cells": "P_D >= threshold"},
        "geometry": {"type": "MultiPolygon", "coordinates": coords}}]}
    write_text_atomic(path, json.dumps(doc))
