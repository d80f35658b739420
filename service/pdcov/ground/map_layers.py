"""The web map's layers in the page's frame (WGS84 latitude/longitude on a web Mercator map,
EPSG:3857, as Leaflet draws), computed from the grid's local ENU frame through the one
geodesy of pdcov (core/geodesy.py). Pure: numpy in, values out.

The heat map. A shown grid is a raster of square ENU cells; Leaflet stretches an image
linearly between two lat/lon corners in web Mercator. Laid on its lat/lon bounds as it is, an
ENU raster would be off by the curvature of the plane's east-west lines (about
x**2 * tan(lat) / (2 R)), by the change of Mercator's scale across it and by Leaflet's
sphere being not quite conformal on the ellipsoid's latitudes: a square centred on the
origin at 47 deg N, 200 m a side, would be off by 3 mm, 1 km a side by 8 cm, 10 km a side
by 8.5 m (``overlay_error_m`` measures it; tests/unit/test_map_layers.py holds these figures).
Rather than bound the mission's size, ``mercator_raster`` resamples the grid onto a web
Mercator raster of the same cell size: each output pixel shows the cell its centre falls in
(nearest cell). At mission scale that is the identity (the pixels are the cells); over tens
of kilometres it is the warp, placed to within half a shown cell anywhere.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu

R_MERCATOR_M = 6378137.0  # EPSG:3857's sphere, as Leaflet's L.CRS.EPSG3857
PD_LEVELS = 253
"""P_D is sent quantised to 0..PD_LEVELS; the two codes above it mark cells out of the map."""
NOT_FREE = 254  # a grid cell outside free space (outside the domain, an obstacle)
OFF_GRID = 255  # a Mercator pixel outside the grid
MAX_OUTLINE_SEGMENTS = 20_000
"""Beyond this the outline is not sent (a noisy coverage would cost megabytes a second)."""


def mercator_xy_m(lat_deg: np.ndarray, lon_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Web Mercator (EPSG:3857) easting, northing in metres of WGS84 lat/lon in degrees."""
    lat = np.radians(np.asarray(lat_deg, dtype=float))
    return (R_MERCATOR_M * np.radians(np.asarray(lon_deg, dtype=float)),
            R_MERCATOR_M * np.log(np.tan(math.pi / 4 + lat / 2)))


def mercator_to_lat_lon_deg(x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of mercator_xy_m."""
    lat = 2 * np.arctan(np.exp(np.asarray(y_m, dtype=float) / R_MERCATOR_M)) - math.pi / 2
    return np.degrees(lat), np.degrees(np.asarray(x_m, dtype=float) / R_MERCATOR_M)


def rings_lat_lon(rings_xy_m: list[list[list[float]]], origin: Origin,
                  ) -> list[list[list[float]]]:
    """ENU rings of [x, y] metres (on the origin's ground plane) as rings of [lat, lon]
    degrees, rounded to 1e-8 deg (1 mm)."""
    out = []
    for ring in rings_xy_m:
        xy = np.asarray(ring, dtype=float).reshape(-1, 2)
        lla = enu_to_geodetic(np.c_[xy, np.zeros(len(xy))], origin)
        out.append([[round(float(a), 8), round(float(b), 8)] for a, b in lla[:, :2]])
    return out


@lru_cache(maxsize=8)
def _resampling(x0_m: float, y0_m: float, cell_m: float, n_rows: int, n_cols: int,
                origin: Origin) -> tuple[tuple[tuple[float, float], tuple[float, float]],
                                         int, int, np.ndarray]:
    """Bounds [[south, west], [north, east]] (deg), height, width and, per Mercator pixel
    (rows from the north), the index of the grid cell (rows from the south) its centre falls
    in, -1 outside the grid. Cached: the grid's geometry and origin seldom change."""
    t = np.linspace(0.0, 1.0, 33)
    x1, y1 = x0_m + n_cols * cell_m, y0_m + n_rows * cell_m
    xs, ys = x0_m + (x1 - x0_m) * t, y0_m + (y1 - y0_m) * t
    edge = np.r_[np.c_[xs, np.full_like(t, y0_m)], np.c_[xs, np.full_like(t, y1)],
                 np.c_[np.full_like(t, x0_m), ys], np.c_[np.full_like(t, x1), ys]]
    lla = enu_to_geodetic(np.c_[edge, np.zeros(len(edge))], origin)
    mx, my = mercator_xy_m(lla[:, 0], lla[:, 1])
    west, east, south, north = mx.min(), mx.max(), my.min(), my.max()
    # Mercator metres per ground metre at the grid's centre, east and north apart: Leaflet's
    # sphere on the ellipsoid's latitudes is not quite conformal (0.3 % apart at 47 deg).
    c = enu_to_geodetic(np.array([[(x0_m + x1) / 2 + d, (y0_m + y1) / 2 + e, 0.0]
                                  for d, e in ((0, 0), (1, 0), (0, 1))]), origin)
    cmx, cmy = mercator_xy_m(c[:, 0], c[:, 1])
    w = max(1, round((east - west) / (cell_m * float(cmx[1] - cmx[0]))))
    h = max(1, round((north - south) / (cell_m * float(cmy[2] - cmy[0]))))
    cx = west + (np.arange(w) + 0.5) * (east - west) / w
    cy = north - (np.arange(h) + 0.5) * (north - south) / h
    lat, lon = mercator_to_lat_lon_deg(*np.meshgrid(cx, cy))
    enu = geodetic_to_enu(lat, lon, origin.ground_alt_msl_m, origin)
    col = np.floor((enu[..., 0] - x0_m) / cell_m)
    row = np.floor((enu[..., 1] - y0_m) / cell_m)
    inside = (col >= 0) & (col < n_cols) & (row >= 0) & (row < n_rows)
    index = np.where(inside, row * n_cols + col, -1).astype(np.int64)
    (s, w_deg), (n, e) = (tuple(map(float, mercator_to_lat_lon_deg(x, y)))
                          for x, y in ((west, south), (east, north)))
    index.setflags(write=False)
    return ((s, w_deg), (n, e)), h, w, index


def mercator_raster(q: np.ndarray, x0_m: float, y0_m: float, cell_m: float, origin: Origin,
                    ) -> tuple[list[list[float]], np.ndarray]:
    """The shown grid ``q`` (uint8 codes, rows from the south, cells of ``cell_m`` from the
    ENU corner x0_m, y0_m) resampled onto web Mercator: its bounds [[south, west], [north,
    east]] in degrees and the raster (uint8, rows from the north), OFF_GRID outside the
    grid."""
    bounds, h, w, index = _resampling(float(x0_m), float(y0_m), float(cell_m), q.shape[0],
                                      q.shape[1], origin)
    flat = np.append(q.ravel(), np.uint8(OFF_GRID))
    return [list(bounds[0]), list(bounds[1])], flat[index].reshape(h, w)


def overlay_error_m(x0_m: float, y0_m: float, width_m: float, height_m: float,
                    origin: Origin, n: int = 21) -> float:
    """How far (ground metres) the ENU rectangle's points would lie from where an image laid
    linearly on its lat/lon bounds in web Mercator puts them: the error of not warping."""
    gx, gy = np.meshgrid(x0_m + width_m * np.linspace(0, 1, n),
                         y0_m + height_m * np.linspace(0, 1, n))
    lla = enu_to_geodetic(np.stack([gx, gy, np.zeros_like(gx)], axis=-1), origin)
    mx, my = mercator_xy_m(lla[..., 0], lla[..., 1])
    # The linear image: Mercator position proportional to the ENU position in the rectangle.
    fx, fy = (gx - x0_m) / width_m, (gy - y0_m) / height_m
    lin_x = mx[0, 0] + fx * (mx[-1, -1] - mx[0, 0])
    lin_y = my[0, 0] + fy * (my[-1, -1] - my[0, 0])
    scale = np.cos(np.radians(lla[..., 0]))  # Mercator metres -> ground metres
    return float(np.max(np.hypot(lin_x - mx, lin_y - my) * scale))


def outline_segments_xy(hit: np.ndarray, x0_m: float, y0_m: float, cell_m: float,
                        ) -> np.ndarray:
    """The boundary of the cells where ``hit`` (rows from the south) is true, as straight
    segments (N, 2, 2) of ENU [x, y] metres; collinear cell edges are joined."""
    p = np.pad(np.asarray(hit, dtype=bool), 1)
    # Horizontal edges at y0 + r*cell (r = 0..n_rows), runs along the columns.
    horizontal = p[:-1, 1:-1] != p[1:, 1:-1]
    # Vertical edges at x0 + c*cell (c = 0..n_cols), runs along the rows.
    vertical = (p[1:-1, :-1] != p[1:-1, 1:]).T
    segments = []
    for edges, along_x in ((horizontal, True), (vertical, False)):
        d = np.diff(np.pad(edges, ((0, 0), (1, 1))).astype(np.int8), axis=1)
        line, start = np.nonzero(d == 1)
        _, stop = np.nonzero(d == -1)
        a, b, k = start * cell_m, stop * cell_m, line * cell_m
        if along_x:
            seg = np.stack([np.c_[x0_m + a, y0_m + k], np.c_[x0_m + b, y0_m + k]], axis=1)
        else:
            seg = np.stack([np.c_[x0_m + k, y0_m + a], np.c_[x0_m + k, y0_m + b]], axis=1)
        segments.append(seg)
    return np.concatenate(segments).reshape(-1, 2, 2)


def segments_lat_lon(segments_xy_m: np.ndarray, origin: Origin) -> list[list[list[float]]]:
    """Segments (N, 2, 2) of ENU [x, y] as [[lat, lon], [lat, lon]] degrees (1e-8 deg)."""
    xy = np.asarray(segments_xy_m, dtype=float).reshape(-1, 2)
    lla = np.round(enu_to_geodetic(np.c_[xy, np.zeros(len(xy))], origin)[:, :2], 8)
    return lla.reshape(-1, 2, 2).tolist()
