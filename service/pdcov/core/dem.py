"""Digital elevation models: ground heights (m MSL) at geodetic points, from a raster file.

``Dem.open`` reads a GeoTIFF, Cloud-Optimized GeoTIFF or SRTM ``.hgt`` in any CRS through
rasterio (extra ``gis``): band 1, once, into float64 with nodata as NaN, and only the window
around the area asked for, so that a country-sized COG is not loaded whole. Heights on the
WGS84 ellipsoid become MSL with the site's geoid height N (H_msl = h_ellipsoid - N).
``height_msl_m`` interpolates bilinearly between pixel centres; ``terrain_surface`` turns the
heights at a grid's cell corners into ENU z (core/terrain.py), through the same
``geodetic_to_enu`` as the camera poses, so the earth's curvature drop is the same on both.

Every refusal is one line naming the file and what to do (InputFileError).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import InputFileError
from pdcov.extras import GIS

__all__ = ["MAX_HEIGHT_MSL_M", "MAX_WINDOW_PIXELS", "MIN_HEIGHT_MSL_M", "Dem", "VerticalDatum",
           "check_window_size", "height_mismatch", "lonlat_bounds", "lonlat_to_pixel",
           "missing_heights_message", "open_raster", "raster_window", "terrain_surface"]

MIN_HEIGHT_MSL_M = -500.0  # below the Dead Sea shore (-430 m): not a ground height
MAX_HEIGHT_MSL_M = 9000.0  # above Everest (8849 m)
MAX_WINDOW_PIXELS = 2**28
"""The most pixels a surface or land-cover raster's window over the domain may hold (268 M:
2 GiB of float64 heights); a larger one is refused (``check_window_size``)."""
_FEET = frozenset({"ft", "foot", "feet", "us survey foot", "us_survey_foot", "ftus", "us-ft",
                   "foot_us", "international foot"})
_M_PER_DEG_LAT = 111_320.0  # enough to turn a margin in metres into degrees
_WGS84 = "EPSG:4326"


class VerticalDatum(str, Enum):
    """What a DEM's heights are measured from: mean sea level or the WGS84 ellipsoid."""

    MSL = "msl"
    ELLIPSOID = "ellipsoid"


@dataclass(frozen=True, slots=True, eq=False)
class Dem:
    """Heights (m MSL) of the window of a DEM raster that was read.

    heights_msl_m: float64 (rows, cols), NaN on nodata, row 0 at the raster's top as in the
    file; transform: the window's affine pixel -> CRS map (rasterio's: pixel (row, col) spans
    col..col+1, row..row+1, its centre at col + 0.5, row + 0.5); crs_wkt: the raster's CRS.
    inside_px: (col_min, col_max, row_min, row_max), the part of the window (pixel
    coordinates) that has heights: the raster's extent there, or half a pixel within the
    window where it was cut out of a larger raster. bounds_lonlat_deg: (west, south, east,
    north) of the whole raster, for messages.
    """

    path: Path
    heights_msl_m: np.ndarray
    transform: Any  # affine.Affine
    crs_wkt: str
    inside_px: tuple[float, float, float, float]
    bounds_lonlat_deg: tuple[float, float, float, float]

    @classmethod
    def open(cls, path: str | Path, *, vertical_datum: VerticalDatum | str = VerticalDatum.MSL,
             geoid_height_m: float | None = None,
             area_lonlat_deg: tuple[float, float, float, float] | None = None,
             margin_m: float = 200.0, max_pixels: int | None = None) -> Dem:
        """Read a DEM raster. area_lonlat_deg: (west, south, east, north) to read, widened by
        margin_m and the pixels bilinear interpolation needs (None: the whole raster).
        vertical_datum 'ellipsoid' needs geoid_height_m, N (m): H_msl = h_ellipsoid - N.
        max_pixels: the most pixels the window may hold (None: no bound).
        Raises InputFileError naming the file: not a raster, no CRS, heights in feet, a
        window beyond max_pixels, or heights outside MIN_HEIGHT_MSL_M..MAX_HEIGHT_MSL_M."""
        GIS.require("a DEM (terrain.dem) needs")
        from rasterio.errors import RasterioError
        from rasterio.windows import Window

        path = Path(path)
        datum = VerticalDatum(vertical_datum)
        if (datum == VerticalDatum.ELLIPSOID) != (geoid_height_m is not None):
            raise InputFileError(f"{path}: geoid_height_m is needed with the ellipsoid datum "
                                 "and only with it")
        with open_raster(path) as src:
            units = (src.units[0] or "").strip().lower()
            if units in _FEET:
                raise InputFileError(
                    f"{path}: heights are in feet (band units {src.units[0]!r}); pdcov needs "
                    "metres: convert, e.g. gdal_calc.py -A IN.tif --calc='A*0.3048' "
                    "--outfile=OUT_m.tif (US survey feet: A*1200/3937), and use that file")
            full = Window(0, 0, src.width, src.height)
            window = full if area_lonlat_deg is None else raster_window(src, area_lonlat_deg,
                                                                        margin_m)
            if max_pixels is not None:
                check_window_size(path, window, area_lonlat_deg, max_pixels)
            if window.width and window.height:
                try:
                    raw = src.read(1, window=window, masked=True, out_dtype="float64")
                except RasterioError as exc:
                    raise InputFileError(f"{path}: cannot read its heights: {exc}") from None
                h = raw.filled(np.nan) * src.scales[0] + src.offsets[0]
            else:  # the area is off the raster: nothing to read
                h = np.zeros((0, 0))
            transform = src.window_transform(window)
            bounds = lonlat_bounds(src)
            crs_wkt = src.crs.to_wkt()
            # Where the window was cut out of the raster, heights end half a pixel inside it
            # (the last centre with a neighbour read); at the raster's own edges, at the edge.
            c0, r0 = int(window.col_off), int(window.row_off)
            c1, r1 = c0 + int(window.width), r0 + int(window.height)
            inside = (0.0 if c0 == 0 else 0.5, c1 - c0 - (0.0 if c1 == src.width else 0.5),
                      0.0 if r0 == 0 else 0.5, r1 - r0 - (0.0 if r1 == src.height else 0.5))
        if geoid_height_m is not None:  # given exactly with the ellipsoid datum
            h -= float(geoid_height_m)
        finite = h[np.isfinite(h)]
        if finite.size and not (MIN_HEIGHT_MSL_M <= finite.min()
                                and finite.max() <= MAX_HEIGHT_MSL_M):
            raise InputFileError(
                f"{path}: heights {finite.min():g} to {finite.max():g} m MSL, outside "
                f"{MIN_HEIGHT_MSL_M:g}..{MAX_HEIGHT_MSL_M:g} m: a nodata value the file does "
                f"not declare (set it: gdal_edit.py -a_nodata VALUE {path.name}), or heights "
                "not in metres")
        h.setflags(write=False)
        return cls(path, h, transform, crs_wkt, inside, bounds)

    def height_msl_m(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
                     ) -> np.ndarray:
        """Heights (m MSL) at geodetic points (WGS84 degrees), bilinear between pixel
        centres (the outermost half pixel of the raster takes its edge's values); NaN
        outside the DEM, outside the window read, or next to a nodata pixel."""
        col, row = self._pixel(lat_deg, lon_deg)
        h = self.heights_msl_m
        out = np.full(col.shape, np.nan)
        ok = self._inside(col, row)
        if not ok.any():
            return out
        n_rows, n_cols = h.shape
        u = np.clip(col[ok] - 0.5, 0.0, n_cols - 1)
        v = np.clip(row[ok] - 0.5, 0.0, n_rows - 1)
        j = np.minimum(np.floor(u).astype(np.intp), max(n_cols - 2, 0))
        i = np.minimum(np.floor(v).astype(np.intp), max(n_rows - 2, 0))
        fu, fv = u - j, v - i
        j1, i1 = np.minimum(j + 1, n_cols - 1), np.minimum(i + 1, n_rows - 1)
        out[ok] = ((h[i, j] * (1 - fu) + h[i, j1] * fu) * (1 - fv)
                   + (h[i1, j] * (1 - fu) + h[i1, j1] * fu) * fv)
        return out

    def nearest_msl_m(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
                      ) -> np.ndarray:
        """Heights (m MSL) of the pixels the geodetic points (WGS84 degrees) fall in, not
        interpolated (a roof's edge stays an edge); NaN outside the DEM, outside the window
        read, or on nodata."""
        col, row = self._pixel(lat_deg, lon_deg)
        h = self.heights_msl_m
        out = np.full(col.shape, np.nan)
        ok = self._inside(col, row)
        if ok.any():
            n_rows, n_cols = h.shape
            out[ok] = h[np.clip(np.floor(row[ok]).astype(np.intp), 0, n_rows - 1),
                        np.clip(np.floor(col[ok]).astype(np.intp), 0, n_cols - 1)]
        return out

    def covers(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float) -> np.ndarray:
        """Whether the points lie within the DEM's window read (nodata or not)."""
        return self._inside(*self._pixel(lat_deg, lon_deg))

    def _pixel(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
               ) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (col, row) of the window at geodetic points."""
        return lonlat_to_pixel(self.transform, self.crs_wkt, lat_deg, lon_deg)

    def _inside(self, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        c0, c1, r0, r1 = self.inside_px
        return (col >= c0) & (col <= c1) & (row >= r0) & (row <= r1)


def open_raster(path: Path) -> Any:
    """The rasterio dataset of ``path`` (to be closed: ``with open_raster(p) as src``);
    InputFileError naming the file when rasterio cannot read it or it has no CRS."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        src = rasterio.open(path)
    except RasterioError as exc:
        raise InputFileError(f"{path}: not a raster rasterio can read (GeoTIFF, Cloud-"
                             f"Optimized GeoTIFF, SRTM .hgt): {exc}") from None
    if src.crs is None:
        src.close()
        raise InputFileError(f"{path}: the raster has no CRS, so its pixels cannot be "
                             "placed; set it, e.g. gdal_edit.py -a_srs EPSG:32632 "
                             f"{path.name}")
    return src


def raster_window(src: Any, area: tuple[float, float, float, float], margin_m: float) -> Any:
    """The pixels of ``src`` under a lon/lat box (west, south, east, north; degrees) widened
    by margin_m, plus two pixels on each side for interpolation, cut to the raster (a
    rasterio Window, possibly empty)."""
    from rasterio.warp import transform_bounds
    from rasterio.windows import Window

    west, south, east, north = area
    dlat = margin_m / _M_PER_DEG_LAT
    dlon = dlat / max(math.cos(math.radians(max(abs(south), abs(north)))), 1e-6)
    box = transform_bounds(_WGS84, src.crs, west - dlon, max(south - dlat, -90.0),
                           east + dlon, min(north + dlat, 90.0), densify_pts=21)
    cols, rows = _apply(~src.transform, np.array([box[0], box[2], box[0], box[2]]),
                        np.array([box[1], box[1], box[3], box[3]]))
    c0 = min(max(math.floor(cols.min()) - 2, 0), src.width)
    c1 = min(max(math.ceil(cols.max()) + 2, c0), src.width)
    r0 = min(max(math.floor(rows.min()) - 2, 0), src.height)
    r1 = min(max(math.ceil(rows.max()) + 2, r0), src.height)
    return Window(c0, r0, c1 - c0, r1 - r0)


def check_window_size(path: Path, window: Any,
                      area: tuple[float, float, float, float] | None, max_pixels: int) -> None:
    """InputFileError naming the file when ``window`` holds more than ``max_pixels`` pixels,
    with the gdal_translate command that cuts the raster to ``area`` (lon/lat degrees)."""
    n = int(window.width) * int(window.height)
    if n <= max_pixels:
        return
    cut = ("" if area is None else
           f" -projwin {area[0]:.6f} {area[3]:.6f} {area[2]:.6f} {area[1]:.6f} -projwin_srs "
           "EPSG:4326")
    raise InputFileError(f"{path}: the window over the domain is {int(window.width):,} x "
                         f"{int(window.height):,} pixels, more than {max_pixels:,}: cut the "
                         f"raster to the domain first (gdal_translate{cut} {path.name} "
                         "cut.tif) or use a coarser one")


def lonlat_to_pixel(transform: Any, crs_wkt: str, lat_deg: np.ndarray | float,
                    lon_deg: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (col, row; float, pixel (r, c) spans c..c+1, r..r+1) at geodetic
    points (WGS84 degrees) of a raster of affine ``transform`` in CRS ``crs_wkt``."""
    lat = np.asarray(lat_deg, dtype=np.float64)
    lon = np.broadcast_to(np.asarray(lon_deg, dtype=np.float64), lat.shape)
    from rasterio.crs import CRS
    from rasterio.warp import transform as warp

    crs = CRS.from_wkt(crs_wkt)
    if crs == CRS.from_string(_WGS84):
        x, y = lon, lat
    else:
        xs, ys = warp(_WGS84, crs, lon.ravel(), lat.ravel())
        x, y = np.reshape(xs, lat.shape), np.reshape(ys, lat.shape)
    return _apply(~transform, x, y)


def _apply(affine: Any, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An affine map of points, element-wise (``affine * (x, y)`` on arrays)."""
    return affine.a * x + affine.b * y + affine.c, affine.d * x + affine.e * y + affine.f


def lonlat_bounds(src: Any) -> tuple[float, float, float, float]:
    """(west, south, east, north) of a rasterio dataset's whole extent, WGS84 degrees."""
    from rasterio.warp import transform_bounds

    w, s, e, n = transform_bounds(src.crs, _WGS84, *src.bounds, densify_pts=21)
    return float(w), float(s), float(e), float(n)


def terrain_surface(dem: Dem, geometry: GridGeometry, origin: Origin,
                    mask: np.ndarray | None = None) -> TerrainSurface:
    """The ground under ``geometry``'s cell corners in ENU (z about origin.ground_alt_msl_m).

    Each corner (x, y, 0) goes to geodetic, takes the DEM's height H there (m MSL) and comes
    back as the ENU z of (lat, lon, H). mask: the free cells (None: all); every corner of a
    free cell needs a height, else InputFileError says how much of the domain the DEM misses
    and where; other corners without one take the nearest corner's height.
    """
    g = geometry
    x = g.x0_m + g.cell_size_m * np.arange(g.n_cols + 1)
    y = g.y0_m + g.cell_size_m * np.arange(g.n_rows + 1)
    xx, yy = np.meshgrid(x, y)
    geo = enu_to_geodetic(np.stack([xx, yy, np.zeros_like(xx)], axis=-1), origin)
    lat, lon = geo[..., 0], geo[..., 1]
    h = dem.height_msl_m(lat, lon)
    free = np.ones(g.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    has = np.isfinite(h)
    # A free cell needs its four corners.
    cell_ok = has[:-1, :-1] & has[1:, 1:] & has[:-1, 1:] & has[1:, :-1]
    if (free & ~cell_ok).any():
        covered = dem.covers(lat, lon)
        cell_in = covered[:-1, :-1] & covered[1:, 1:] & covered[:-1, 1:] & covered[1:, :-1]
        raise InputFileError(missing_heights_message(dem, g, origin, free, cell_ok, cell_in))
    if not has.all():
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(~has, return_distances=False, return_indices=True)
        h = h[idx[0], idx[1]]
    z = geodetic_to_enu(lat, lon, h, origin)[..., 2]
    return TerrainSurface(g, z, str(dem.path))


def height_mismatch(dem: Dem, lat_deg: float, lon_deg: float, alt_msl_m: float,
                    margin_m: float, what: str) -> str | None:
    """A warning line when an altitude (m MSL) measured or configured at a point differs from
    the DEM there by more than margin_m; None when it agrees or the DEM has no height there.
    what: the altitude's name, e.g. 'origin.ground_alt_msl_m'."""
    h = float(dem.height_msl_m(lat_deg, lon_deg))
    if not math.isfinite(h) or abs(alt_msl_m - h) <= margin_m:
        return None
    return (f"{what} {alt_msl_m:.1f} m MSL differs from the DEM's {h:.1f} m there "
            f"({dem.path.name}) by {alt_msl_m - h:+.1f} m, more than terrain.check_margin_m = "
            f"{margin_m:g} m: check the DEM's datum (terrain.vertical_datum, "
            "geoid_height_m) and the altitude")


DEFAULT_MAX_HOME_OFFSET_M = 30.0
"""terrain.max_home_offset_m when the config does not set it (m)."""


def home_offset_error(dem: Dem, lat_deg: float, lon_deg: float, alt_msl_m: float,
                      max_offset_m: float) -> str | None:
    """Why a home altitude (m MSL) at a point cannot be used with this DEM: it differs from
    the DEM's height there by more than ``max_offset_m`` (a wrong datum, DEM or altitude
    moves every cell's view by as much); None when within it or the DEM has no height
    there."""
    h = float(dem.height_msl_m(lat_deg, lon_deg))
    if not math.isfinite(h) or abs(alt_msl_m - h) <= max_offset_m:
        return None
    return (f"{alt_msl_m:.1f} m MSL is {alt_msl_m - h:+.1f} m from the DEM's {h:.1f} m there "
            f"({dem.path.name}), more than terrain.max_home_offset_m = {max_offset_m:g} m: "
            "fix the altitude or the DEM's datum (terrain.vertical_datum, geoid_height_m), "
            "or raise terrain.max_home_offset_m if the DEM is known to be off")


def _area(m2: float) -> str:
    return f"{m2 / 1e6:,.3g} km^2" if m2 >= 1e5 else f"{m2:,.0f} m^2"


def _compass(dx: float, dy: float) -> str:
    names = ("east", "north-east", "north", "north-west", "west", "south-west", "south",
             "south-east")
    return names[round(math.degrees(math.atan2(dy, dx)) / 45.0) % 8]


def elsewhere_message(dem: Dem, g: GridGeometry, origin: Origin, *, what: str = "DEM",
                      key: str = "terrain.dem", overlapping: bool = False) -> str | None:
    """One line when ``dem``'s raster does not cover ``g``'s cells at all: where it lies
    (how far, in which direction); None when its extent overlaps the grid's, unless
    ``overlapping`` (its cells are known to be missed all the same)."""
    import shapely
    from shapely.ops import nearest_points

    x1, y1 = g.x0_m + g.cell_size_m * g.n_cols, g.y0_m + g.cell_size_m * g.n_rows
    grid_box = shapely.box(g.x0_m, g.y0_m, x1, y1)
    w, s, e, n = dem.bounds_lonlat_deg
    ring = np.array([[s, w], [s, e], [n, e], [n, w]])
    r = geodetic_to_enu(ring[:, 0], ring[:, 1], origin.ground_alt_msl_m, origin)
    dem_box = shapely.Polygon(r[:, :2])
    dist_m = float(shapely.distance(grid_box, dem_box))
    if dist_m == 0 and not overlapping:
        return None
    a, b = nearest_points(grid_box, dem_box)
    where_ = (f"{dist_m / 1000:,.1f} km to the {_compass(b.x - a.x, b.y - a.y)} of it"
              if dist_m > 0 else "beside it, without reaching its cells")
    return (f"{dem.path}: the {what} does not cover the domain at all: it spans lat "
            f"{s:.4f}..{n:.4f}, lon {w:.4f}..{e:.4f} deg, {where_}; check {key} "
            "and origin.lat_deg / origin.lon_deg")


def missing_heights_message(dem: Dem, g: GridGeometry, origin: Origin, free: np.ndarray,
                            cell_ok: np.ndarray, cell_in: np.ndarray, *, what: str = "DEM",
                            key: str = "terrain.dem",
                            hole: str = "have a corner without a height") -> str:
    """What ``dem`` (a DEM, or a DSM: ``what``, the config ``key`` naming it) misses under
    the free cells, in one line. cell_ok: the cells that have their heights; cell_in: those
    within the raster's window (bool, the grid's shape each); hole: how a cell within it
    lacks its heights."""
    cell_m2 = g.cell_size_m ** 2
    n_free = int(free.sum())
    xc, yc = g.centres_enu()
    cx, cy = np.meshgrid(xc, yc)
    outside = free & ~cell_in
    x1, y1 = g.x0_m + g.cell_size_m * g.n_cols, g.y0_m + g.cell_size_m * g.n_rows
    if outside.all() or not cell_in.any():
        found = elsewhere_message(dem, g, origin, what=what, key=key, overlapping=True)
        assert found is not None
        return found
    if outside.any():
        k = int(outside.sum())
        dx, dy = cx[outside].mean() - cx[free].mean(), cy[outside].mean() - cy[free].mean()
        side = (_compass(float(dx), float(dy)) if math.hypot(dx, dy) > 0.05 * math.hypot(
            x1 - g.x0_m, y1 - g.y0_m) else "every")
        return (f"{dem.path}: the {what} covers only {100 * (n_free - k) / n_free:.1f} % of the "
                f"domain: {100 * k / n_free:.1f} % ({_area(k * cell_m2)}) is outside it, on "
                f"its {side} side (ENU x {cx[outside].min():.0f}..{cx[outside].max():.0f} m, "
                f"y {cy[outside].min():.0f}..{cy[outside].max():.0f} m); use a {what} that "
                "covers the whole domain")
    holes = free & ~cell_ok
    k = int(holes.sum())
    return (f"{dem.path}: nodata under the domain: {k} of its {n_free} free cells "
            f"({100 * k / n_free:.2g} %, {_area(k * cell_m2)}) {hole}, "
            f"at ENU x {cx[holes].min():.0f}..{cx[holes].max():.0f} m, "
            f"y {cy[holes].min():.0f}..{cy[holes].max():.0f} m; fill the holes "
            f"(gdal_fillnodata.py) or use another {what}")
