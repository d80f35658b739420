"""Coverage patterns as plans: lawnmower (linear Morse function), spiral (radial Morse
function), and the IAMSAR expanding-square and sector searches.

Every pattern is a polyline in ENU metres clipped to the free space; where it leaves the free
space, or where one cell's tracks end and the next cell's begin, the vehicle transits along
the shortest path inside the free space (planning/routing.py).

Headings are bearings: radians clockwise from north, so a heading of psi points along
ENU (sin psi, cos psi).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import shapely
import shapely.ops
from shapely.geometry import LineString, MultiPolygon, Point, Polygon

from pdcov.errors import ConfigError
from pdcov.planning.decomposition import Decomposition, boustrophedon_decomposition, polygons_of
from pdcov.planning.plan import Plan
from pdcov.planning.routing import (
    COVER_TOL_M,
    FreeSpaceRouter,
    PathBuilder,
    clip_and_join,
    clip_polyline,
)


def unit_of_heading(heading_rad: float) -> np.ndarray:
    """ENU unit vector (east, north) of a bearing (radians clockwise from north)."""
    return np.array([math.sin(heading_rad), math.cos(heading_rad)])


def swath_width_m(footprint_enu: Polygon, track_heading_rad: float) -> float:
    """Width of the ground strip a footprint sweeps when moved along ``track_heading_rad``:
    its extent across the track, metres. Empty footprint: 0."""
    if footprint_enu.is_empty:
        return 0.0
    across = unit_of_heading(track_heading_rad + math.pi / 2)
    pts = shapely.get_coordinates(footprint_enu)
    d = pts @ across
    return float(d.max() - d.min())


def track_spacing_m(swath_m: float, side_overlap: float) -> float:
    """Distance between neighbouring tracks for a swath width and a side overlap in [0, 1)."""
    if not 0.0 <= side_overlap < 1.0:
        raise ConfigError(f"side overlap: expected a fraction in [0, 1), got {side_overlap}")
    if not swath_m > 0:
        raise ConfigError(f"swath width: the camera sees no ground strip ({swath_m} m); "
                          f"check the mount pitch and altitude")
    return swath_m * (1.0 - side_overlap)


def _check_spacing(spacing_m: float) -> None:
    if not (spacing_m > 0 and math.isfinite(spacing_m)):
        raise ConfigError(f"track spacing: expected a positive number of metres, "
                          f"got {spacing_m}")


# -- lawnmower -----------------------------------------------------------------------------

def cell_tracks(decomposition: Decomposition, spacing_m: float) -> list[list[np.ndarray]]:
    """Per cell, its back-and-forth tracks as (2, 2) ENU segments, in sweep order.

    Tracks run along the slices of h; within a cell they are exactly ``spacing_m`` apart and
    centred, so no point of the cell is further than spacing/2 from a track across the
    sweep direction. A cell narrower than the spacing gets one track at its middle."""
    _check_spacing(spacing_m)
    frame = decomposition.frame
    out = []
    for cell in decomposition.cells:
        c = frame.to_sweep(cell)
        x0, y0, x1, y1 = c.bounds
        n = max(1, math.ceil((x1 - x0) / spacing_m - 1e-9))
        first = 0.5 * (x0 + x1) - 0.5 * (n - 1) * spacing_m
        tracks = []
        for k in range(n):
            x = first + k * spacing_m
            chord = c.intersection(LineString([(x, y0 - 1.0), (x, y1 + 1.0)]))
            if chord.is_empty or chord.length <= 0:
                continue
            _, lo, _, hi = chord.bounds
            tracks.append(frame.points_to_enu(np.array([[x, lo], [x, hi]])))
        out.append(tracks)
    return out


def _track_with_corners(cell_enu: Polygon, track_enu: np.ndarray,
                        spacing_m: float) -> list[np.ndarray]:
    """A track as pieces: the band of the cell within spacing/2 of it may reach further
    along the track than the track's own chord (a slanted edge, a corner); the track then
    starts and ends at those furthest points, reached along the boundary."""
    along = track_enu[1] - track_enu[0]
    length = float(np.linalg.norm(along))
    if length == 0:
        return [track_enu]
    along /= length
    reach = 2 * math.hypot(*np.ptp(shapely.get_coordinates(cell_enu), axis=0))
    strip = LineString([track_enu[0] - reach * along, track_enu[1] + reach * along]).buffer(
        spacing_m / 2, cap_style="flat")
    band = shapely.get_coordinates(cell_enu.intersection(strip))
    if len(band) == 0:
        return [track_enu]
    s = (band - track_enu[0]) @ along
    pieces = [track_enu]
    if s.min() < -1e-6:
        pieces.insert(0, band[np.argmin(s)][None])
    if s.max() > length + 1e-6:
        pieces.append(band[np.argmax(s)][None])
    return pieces


def lawnmower(free_enu: Polygon | MultiPolygon, spacing_m: float, heading_rad: float,
              alt_agl_m: float, speed_mps: float,
              route_in_enu: Polygon | MultiPolygon | None = None) -> Plan:
    """Boustrophedon plan: tracks along ``heading_rad`` spaced ``spacing_m`` apart, cell by
    cell in the order of the decomposition's walk (paper Fig. 3 and 4a). Turns between the
    tracks of a cell follow the free-space boundary, and a track is stretched to the furthest
    corner of the cell within half a spacing of it, so that slanted edges are flown too.
    ``route_in_enu``: where transits may go when ``free_enu`` is only the part to survey
    (default: ``free_enu``)."""
    decomposition = boustrophedon_decomposition(free_enu, -heading_rad)
    tracks = cell_tracks(decomposition, spacing_m)
    builder = PathBuilder(FreeSpaceRouter(free_enu if route_in_enu is None else route_in_enu))
    for c in decomposition.visit_order():
        cell = [_track_with_corners(decomposition.cells[c], t, spacing_m) for t in tracks[c]]
        if not cell:
            continue
        here = builder.last
        if here is not None:
            # Start from whichever end of the cell, and of its first track, is nearer.
            ends = np.array([[t[0][0], t[-1][-1]] for t in (cell[0], cell[-1])])
            d = np.linalg.norm(ends - here, axis=2)  # [first/last track, start/end]
            if d[1].min() < d[0].min():
                cell = cell[::-1]
                d = d[::-1]
            flip = bool(d[0, 1] < d[0, 0])
        else:
            flip = False
        for k, pieces in enumerate(cell):
            if (k % 2 == 1) != flip:
                pieces = [p[::-1] for p in pieces[::-1]]
            # Turns and stretches follow the boundary where both ends lie on it.
            for j, piece in enumerate(pieces):
                builder.add(piece, along_boundary=k > 0 or j > 0)
    return Plan.from_xy(builder.points(), alt_agl_m, speed_mps,
                        f"lawnmower spacing {spacing_m:g} m heading "
                        f"{math.degrees(heading_rad):g} deg")


# -- spiral and IAMSAR patterns ------------------------------------------------------------

def auto_centre_enu_m(free_enu: Polygon | MultiPolygon) -> np.ndarray:
    """Centre of the smallest circle enclosing the free space (ENU metres): the spiral
    centre that reaches every point with the fewest turns."""
    c = shapely.minimum_bounding_circle(free_enu).centroid
    return np.array([c.x, c.y])


def default_datum_enu_m(free_enu: Polygon | MultiPolygon) -> np.ndarray:
    """A datum inside the free space (ENU metres): the centre of the smallest enclosing
    circle when it lies in the free space, else the point of the largest part of the free
    space farthest from its boundary (pole of inaccessibility), where a pattern has room.
    An L-shaped domain's circle centre lies in its notch, outside the L."""
    c = auto_centre_enu_m(free_enu)
    if shapely.covers(free_enu, Point(c)):
        return c
    largest = max(polygons_of(free_enu), key=lambda p: p.area)
    minx, miny, maxx, maxy = largest.bounds
    q = shapely.ops.polylabel(largest, tolerance=1e-3 * max(maxx - minx, maxy - miny))
    return np.array([q.x, q.y])


def _nearest_free_point(free_enu: Polygon | MultiPolygon, p_enu_m: np.ndarray) -> np.ndarray:
    # A little inside the boundary, so that the point is in the free space, not on its edge.
    minx, miny, maxx, maxy = free_enu.bounds
    inner = free_enu.buffer(-1e-3 * max(maxx - minx, maxy - miny))
    target = inner if not inner.is_empty else free_enu
    q = shapely.ops.nearest_points(target, Point(p_enu_m))[0]
    return np.array([q.x, q.y])


def datum_in_free_space(free_enu: Polygon | MultiPolygon,
                        datum_enu_m: np.ndarray | None) -> np.ndarray:
    """The IAMSAR datum (ENU metres): the given one, refused when outside the free space
    (the pattern would start elsewhere), or ``default_datum_enu_m``."""
    if datum_enu_m is None:
        return default_datum_enu_m(free_enu)
    d = np.asarray(datum_enu_m, dtype=float)
    if not shapely.covers(free_enu.buffer(COVER_TOL_M), Point(d)):
        q = _nearest_free_point(free_enu, d)
        raise ConfigError(f"datum ({d[0]:g}, {d[1]:g}) m (ENU) lies outside the free space "
                          f"(the domain minus its obstacles); the nearest free point is "
                          f"({q[0]:.1f}, {q[1]:.1f}) m")
    return d


def _reach_m(free_enu: Polygon | MultiPolygon, centre: np.ndarray) -> float:
    return float(np.linalg.norm(shapely.get_coordinates(free_enu) - centre, axis=1).max())


def spiral(free_enu: Polygon | MultiPolygon, spacing_m: float, alt_agl_m: float,
           speed_mps: float, centre_enu_m: np.ndarray | None = None) -> Plan:
    """Archimedean spiral outward from the centre, turns ``spacing_m`` apart: the
    continuous form of the evenly spaced level sets of h = |(x, y) - centre| (paper Fig. 4b),
    counter-clockwise, clipped to the free space."""
    _check_spacing(spacing_m)
    c = auto_centre_enu_m(free_enu) if centre_enu_m is None else np.asarray(centre_enu_m, float)
    r_end = _reach_m(free_enu, c) + 1.5 * spacing_m
    theta_end = 2 * math.pi * r_end / spacing_m
    # Sample every ~0.5 m of arc (or 5 deg), then simplify each clipped piece to 5 cm.
    r = np.arange(0.0, r_end, 0.5)
    theta = 2 * math.pi * r / spacing_m
    theta = np.unique(np.concatenate([theta, np.arange(0.0, theta_end, math.radians(5))]))
    rr = spacing_m * theta / (2 * math.pi)
    xy = c + np.column_stack([rr * np.cos(theta), rr * np.sin(theta)])
    return Plan.from_xy(clip_and_join(xy, free_enu, simplify_m=0.05), alt_agl_m, speed_mps,
                        f"spiral spacing {spacing_m:g} m centre ({c[0]:.1f}, {c[1]:.1f}) m")


def _until_it_leaves(xy_enu_m: np.ndarray, free_enu: Polygon | MultiPolygon) -> np.ndarray:
    """The polyline from its first point (in the free space) up to where it first leaves
    the free space: the leg that leaves is flown to the boundary and the pattern ends there,
    so that it keeps its shape (clipping and joining the pieces along the boundary flew one
    edge again and again with left turns)."""
    free = free_enu.buffer(COVER_TOL_M)
    shapely.prepare(free)
    pts = np.asarray(xy_enu_m, dtype=float)
    out = [pts[0]]
    for p, q in zip(pts[:-1], pts[1:], strict=True):
        if shapely.covers(free, LineString([p, q])):
            out.append(q)
            continue
        pieces = clip_polyline(np.array([p, q]), free_enu)
        if pieces and np.linalg.norm(pieces[0][0] - p) < 1e-6:
            out.append(pieces[0][-1])
        break
    return np.array(out)


def _share_of(free_enu: Polygon | MultiPolygon, region: Polygon | MultiPolygon) -> float:
    """Share of the free space's area inside ``region``, in [0, 1]."""
    return float(region.intersection(free_enu).area / free_enu.area) if free_enu.area else 0.0


def expanding_square(free_enu: Polygon | MultiPolygon, spacing_m: float, alt_agl_m: float,
                     speed_mps: float, datum_enu_m: np.ndarray | None = None,
                     heading_rad: float = 0.0) -> Plan:
    """IAMSAR expanding square (SS): from the datum (inside the free space; default
    ``default_datum_enu_m``), legs of 1, 1, 2, 2, 3, 3, ... spacings, turning right 90 deg
    after each, first leg along ``heading_rad``, until the square contains the free space or
    a leg would leave it (that leg is flown to the boundary, and the pattern ends). The
    description gives the share of the free space within half a spacing of the legs."""
    _check_spacing(spacing_m)
    d = datum_in_free_space(free_enu, datum_enu_m)
    reach = _reach_m(free_enu, d)
    pts = [d]
    k = 0
    while (k // 2) * spacing_m <= 2 * reach + spacing_m:
        leg = (k // 2 + 1) * spacing_m
        pts.append(pts[-1] + leg * unit_of_heading(heading_rad + k * math.pi / 2))
        k += 1
    xy = _until_it_leaves(np.array(pts), free_enu)
    share = _share_of(free_enu, LineString(xy).buffer(spacing_m / 2, join_style="mitre"))
    return Plan.from_xy(xy, alt_agl_m, speed_mps,
                        f"expanding square spacing {spacing_m:g} m datum "
                        f"({d[0]:.1f}, {d[1]:.1f}) m; covers {share:.0%} of the free space")


SECTOR_SECOND_ROTATION_RAD = math.radians(30.0)  # IAMSAR: second pattern turned 30 deg


def sector_search(free_enu: Polygon | MultiPolygon, alt_agl_m: float, speed_mps: float,
                  datum_enu_m: np.ndarray | None = None, heading_rad: float = 0.0,
                  radius_m: float | None = None, second: bool = False) -> Plan:
    """IAMSAR sector search (VS): three equilateral triangles through the datum, right turns
    of 120 deg, first leg along ``heading_rad``, datum as for ``expanding_square``: points
    at bearings h + (0, 60, 240, 300, 120, 180) deg. With ``second``, the IAMSAR second
    pattern follows from the datum, turned 30 deg right so its legs fall between the first's.

    Radius: by default the largest (up to the free space's reach from the datum) that keeps
    every triangle inside the free space; a given radius whose pattern leaves the free space
    is flown up to the boundary, where the pattern ends (as ``expanding_square``). The
    description gives the share of the free space inside the hexagon(s) the triangles span.
    """
    d = datum_in_free_space(free_enu, datum_enu_m)
    headings = (heading_rad, heading_rad + SECTOR_SECOND_ROTATION_RAD) if second \
        else (heading_rad,)

    def pattern(radius: float) -> np.ndarray:
        pts = [d]
        for h in headings:
            for deg in (0, 60, None, 240, 300, None, 120, 180, None):
                pts.append(d if deg is None
                           else d + radius * unit_of_heading(h + math.radians(deg)))
        return np.array(pts)

    if radius_m is None:
        radius = _largest_inside(pattern, free_enu, _reach_m(free_enu, d))
        if radius < 0.5:
            raise ConfigError(f"sector search: no triangle fits in the free space around the "
                              f"datum ({d[0]:.1f}, {d[1]:.1f}) m (on its boundary?); move "
                              f"the datum inside or give --radius-m")
    else:
        radius = radius_m
    if not (radius > 0 and math.isfinite(radius)):
        raise ConfigError(f"sector search radius: expected a positive number of metres, "
                          f"got {radius}")
    xy = _until_it_leaves(pattern(radius), free_enu)
    if len(xy) < 2:
        raise ConfigError(f"sector search: its first leg from the datum ({d[0]:.1f}, "
                          f"{d[1]:.1f}) m leaves the free space at once; change the datum "
                          f"or --heading-deg")
    share = _share_of(free_enu, shapely.convex_hull(shapely.multipoints(xy)))
    what = "sector search with the second pattern turned 30 deg" if second else "sector search"
    return Plan.from_xy(xy, alt_agl_m, speed_mps,
                        f"{what} radius {radius:g} m datum ({d[0]:.1f}, {d[1]:.1f}) m; "
                        f"covers {share:.0%} of the free space")


def _largest_inside(pattern: Callable[[float], np.ndarray],
                    free_enu: Polygon | MultiPolygon, max_m: float) -> float:
    """The largest size r in (0, max_m] with ``pattern(r)`` (a polyline) in the free space,
    by bisection to 1 cm (the pattern scales about a point of the free space)."""
    free = free_enu.buffer(COVER_TOL_M)
    shapely.prepare(free)

    def inside(r: float) -> bool:
        return bool(shapely.covers(free, LineString(pattern(r))))

    if inside(max_m):
        return max_m
    lo, hi = 0.0, max_m
    while hi - lo > 0.01:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if inside(mid) else (lo, mid)
    return lo
