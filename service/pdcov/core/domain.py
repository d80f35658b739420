"""Search domain (polygon minus obstacles, ENU metres) and its grid of square cells.

Cells are aligned to the domain's bounding box: cell (row i, col j) spans
x in [x0 + j c, x0 + (j + 1) c), y in [y0 + i c, y0 + (i + 1) c); rows grow north, columns
east. A cell is free when its centre lies in the free space.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon, shape
from shapely.validation import explain_validity

from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.errors import DomainError, where
from pdcov.yaml_file import read_text

# The most cells a grid may have: about 65 x 65 km of 1 m cells. The grid holds in memory
# only the tiles frames touch (core/tiles.py), so the bound is on what a mistyped cell size
# asks for, not on the memory of a domain.
MAX_GRID_CELLS = 2**32


def _count(n: int) -> str:
    """A count as a person reads it: 160,000,000,000, or 1e+276 where the digits would
    fill the line."""
    return f"{n:,}" if n < 10**15 else f"{n:.3e}" if n < 10**300 else f"10^{len(str(n)) - 1}"


@dataclass(frozen=True, slots=True)
class GridGeometry:
    """A regular grid: south-west corner (x0_m, y0_m) of cell [0, 0] in ENU, cell size, shape."""

    x0_m: float
    y0_m: float
    cell_size_m: float
    n_rows: int
    n_cols: int

    def __post_init__(self) -> None:
        if not (self.cell_size_m > 0 and math.isfinite(self.cell_size_m)):
            raise DomainError(f"cell_size_m: expected a positive number, got {self.cell_size_m}")
        if self.n_rows < 1 or self.n_cols < 1:
            raise DomainError(f"grid must have at least one cell, got {self.n_rows} x "
                              f"{self.n_cols}")
        n_cells = self.n_rows * self.n_cols
        if n_cells > MAX_GRID_CELLS:
            # Refused here, before anything is built: a mistyped cell size (mm for m).
            # In floats, factor by factor: a cell size of 1e-274 m gives counts no float
            # quotient of the product holds (OverflowError).
            side_m = (self.cell_size_m * math.sqrt(self.n_rows / MAX_GRID_CELLS)
                      * math.sqrt(self.n_cols))
            raise DomainError(
                f"cell_size_m = {self.cell_size_m:g} m gives {_count(self.n_rows)} x "
                f"{_count(self.n_cols)} = {_count(n_cells)} cells; at most "
                f"{MAX_GRID_CELLS:,} cells are allowed: use cells of at least "
                f"{side_m:.3g} m")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.n_rows, self.n_cols)

    def centres_enu(self) -> tuple[np.ndarray, np.ndarray]:
        """x and y (each (n_cols,) and (n_rows,)) of the cell centres in ENU metres."""
        c = self.cell_size_m
        return (self.x0_m + c * (np.arange(self.n_cols) + 0.5),
                self.y0_m + c * (np.arange(self.n_rows) + 0.5))

    def cell_of(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) integer indices of ENU points; may lie outside the grid."""
        c = self.cell_size_m
        return (np.floor((np.asarray(y_m) - self.y0_m) / c).astype(np.int64),
                np.floor((np.asarray(x_m) - self.x0_m) / c).astype(np.int64))

    @property
    def extent_enu(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the grid in ENU metres."""
        c = self.cell_size_m
        return (self.x0_m, self.x0_m + c * self.n_cols, self.y0_m, self.y0_m + c * self.n_rows)


@dataclass(frozen=True, slots=True)
class Domain:
    """The search area: outer boundary minus obstacles, in ENU metres."""

    boundary: Polygon
    obstacles: tuple[Polygon, ...] = ()

    def __post_init__(self) -> None:
        for name, poly in [("polygon", self.boundary)] + [
                (f"obstacles[{i}]", o) for i, o in enumerate(self.obstacles)]:
            if poly.is_empty or poly.area <= 0:
                raise DomainError(f"domain.{name}: polygon has no area")
            if not poly.is_valid:
                raise DomainError(f"domain.{name}: invalid polygon ({explain_validity(poly)})")

    @property
    def free_space(self) -> Polygon | MultiPolygon:
        """Boundary minus the union of the obstacles (shapely geometry, ENU metres)."""
        if not self.obstacles:
            return self.boundary
        return self.boundary.difference(shapely.union_all(self.obstacles))

    def grid_geometry(self, cell_size_m: float) -> GridGeometry:
        """Cells of ``cell_size_m`` aligned to the boundary's bounding box."""
        if not (cell_size_m > 0 and math.isfinite(cell_size_m)):
            raise DomainError(f"domain.cell_size_m: expected a positive number of metres, "
                              f"got {cell_size_m}")
        x_min, y_min, x_max, y_max = self.boundary.bounds
        cols, rows = (x_max - x_min) / cell_size_m, (y_max - y_min) / cell_size_m
        if not (math.isfinite(cols) and math.isfinite(rows)):  # a cell of 5e-324 m
            raise DomainError(f"domain.cell_size_m = {cell_size_m:g} m: too small for a "
                              f"{x_max - x_min:g} x {y_max - y_min:g} m domain (at most "
                              f"{MAX_GRID_CELLS:,} cells)")
        n_cols = max(1, math.ceil(cols - 1e-9))
        n_rows = max(1, math.ceil(rows - 1e-9))
        return GridGeometry(x_min, y_min, cell_size_m, n_rows, n_cols)

    def free_mask(self, geometry: GridGeometry) -> np.ndarray:
        """Boolean (n_rows, n_cols): True where the cell centre lies in the free space."""
        xs, ys = geometry.centres_enu()
        X, Y = np.meshgrid(xs, ys)
        free = self.free_space
        shapely.prepare(free)
        return shapely.contains_xy(free, X, Y)

    def without_cells(self, geometry: GridGeometry, mask: np.ndarray) -> Domain:
        """This domain with the squares of ``geometry``'s cells where ``mask`` is True as
        obstacles too (``cell_polygons``): those cells are not free; no other cell changes
        (its centre lies half a cell from them)."""
        extra = cell_polygons(geometry, mask)
        return Domain(self.boundary, self.obstacles + extra) if extra else self

    def has_free_cell(self, geometry: GridGeometry, cells_per_chunk: int = 2**16) -> bool:
        """True if some cell centre lies in the free space; scans the rows in chunks of
        about ``cells_per_chunk`` cells and stops at the first free cell, so it costs little
        on any usable domain (a chunk of 256 rows of a county's 30,000 columns would take
        120 MB of centres)."""
        xs, ys = geometry.centres_enu()
        free = self.free_space
        if free.is_empty:
            return False
        shapely.prepare(free)
        rows_per_chunk = max(1, cells_per_chunk // geometry.n_cols)
        for r0 in range(0, geometry.n_rows, rows_per_chunk):
            X, Y = np.meshgrid(xs, ys[r0:r0 + rows_per_chunk])
            if shapely.contains_xy(free, X, Y).any():
                return True
        return False

    @classmethod
    def from_enu(cls, polygon_enu_m: Any, obstacles_enu_m: Any = (),
                 source: str | None = None) -> Domain:
        return cls(_polygon(polygon_enu_m, "domain.polygon_enu_m", source),
                   tuple(_polygon(o, f"domain.obstacles_enu_m[{i}]", source)
                         for i, o in enumerate(obstacles_enu_m or ())))

    @classmethod
    def from_geodetic(cls, polygon_deg: Any, obstacles_deg: Any, origin: Origin,
                      source: str | None = None) -> Domain:
        """From [[lat_deg, lon_deg], ...] rings, projected to ENU about ``origin``."""
        def to_enu(ring: Any, key: str) -> list[list[float]]:
            pts = _points(ring, key, source)
            enu = geodetic_to_enu(pts[:, 0], pts[:, 1], origin.ground_alt_msl_m, origin)
            return enu[:, :2].tolist()
        return cls.from_enu(to_enu(polygon_deg, "domain.polygon_geodetic_deg"),
                            [to_enu(o, f"domain.obstacles_geodetic_deg[{i}]")
                             for i, o in enumerate(obstacles_deg or ())], source)

    @classmethod
    def from_geojson(cls, path: str | Path, origin: Origin) -> Domain:
        """From a GeoJSON file (WGS84 lon/lat): the largest polygon is the boundary; its holes
        and every other polygon inside it are obstacles."""
        path = Path(path)
        text = read_text(path, "GeoJSON", DomainError)
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DomainError(f"{path}: not valid JSON ({exc})") from None
        geoms: list[Any] = []  # shapely geometries (shapely ships no type hints)
        features = doc.get("features") if isinstance(doc, dict) else None
        items = features if features is not None else [doc]
        for k, item in enumerate(items):
            g = item.get("geometry", item) if isinstance(item, dict) else None
            try:
                geom = shape(g)
            except Exception as exc:  # noqa: BLE001 - shapely raises several types
                raise DomainError(f"{path}: feature {k}: not a GeoJSON geometry ({exc})") \
                    from None
            geoms.extend(getattr(geom, "geoms", [geom]))
        polys = [g for g in geoms if isinstance(g, Polygon)]
        if not polys:
            raise DomainError(f"{path}: no Polygon or MultiPolygon found")
        polys.sort(key=lambda p: p.area, reverse=True)

        def ring_enu(coords: Any) -> list[list[float]]:
            ll = np.asarray(coords, dtype=float)[:, :2]
            return geodetic_to_enu(ll[:, 1], ll[:, 0], origin.ground_alt_msl_m,
                                   origin)[:, :2].tolist()
        outer = polys[0]
        obstacles = [ring_enu(h.coords) for h in outer.interiors]
        obstacles += [ring_enu(p.exterior.coords) for p in polys[1:]]
        return cls.from_enu(ring_enu(outer.exterior.coords), obstacles, str(path))


def cell_polygons(geometry: GridGeometry, mask: np.ndarray) -> tuple[Polygon, ...]:
    """The squares of the cells where ``mask`` (bool, the grid's shape) is True, merged
    into polygons without holes (ENU m): cells sharing edges make one polygon, cut along
    row lines where it encloses other cells (an obstacle is its outer ring: ``from_enu``
    and the mission payload keep no holes). Together they cover exactly those squares."""
    g = geometry
    m = np.asarray(mask, dtype=bool)
    if m.shape != g.shape:
        raise ValueError(f"mask shape {m.shape} != grid shape {g.shape}")
    if not m.any():
        return ()
    cs = g.cell_size_m
    # Each row's runs of cells, one box each: [start, end) columns.
    step = np.diff(np.pad(m, ((0, 0), (1, 1))).astype(np.int8), axis=1)
    rows, c_start = np.nonzero(step == 1)
    _, c_end = np.nonzero(step == -1)
    boxes = shapely.box(g.x0_m + cs * c_start, g.y0_m + cs * rows, g.x0_m + cs * c_end,
                        g.y0_m + cs * (rows + 1))
    out: list[Polygon] = []
    for poly in _polygons_in(shapely.union_all(boxes)):
        for piece in _without_holes(poly):
            # Simplified by 0 m: only the vertices amid straight edges go.
            ring = Polygon(shapely.simplify(piece, 0.0).exterior.coords)
            if ring.is_valid and not piece.interiors:
                out.append(ring)
            else:  # an outline touching itself: its rows' runs, each a rectangle
                out.extend(_row_runs(piece, g))
    return tuple(out)


def _polygons_in(geom: Any) -> list[Polygon]:
    """The polygons of area of a shapely geometry (lines and points of a cut dropped)."""
    if isinstance(geom, Polygon):
        return [geom] if geom.area > 0 else []
    return [p for part in getattr(geom, "geoms", ()) for p in _polygons_in(part)]


def _without_holes(poly: Polygon) -> list[Polygon]:
    """``poly`` cut into pieces without holes along the horizontal lines through its holes'
    lowest and highest points: each hole then reaches a cut and opens into the outline."""
    if not poly.interiors:
        return [poly]
    x0, y0, x1, y1 = poly.bounds
    cuts = sorted({y for h in poly.interiors for y in (h.bounds[1], h.bounds[3])
                   if y0 < y < y1})
    edges = [y0, *cuts, y1]
    return [p for a, b in zip(edges[:-1], edges[1:], strict=True)
            for p in _polygons_in(poly.intersection(shapely.box(x0, a, x1, b)))]


def _row_runs(poly: Polygon, g: GridGeometry) -> list[Polygon]:
    """``poly`` (cells of ``g``) cut along every row line: rectangles, one per run."""
    x0, y0, x1, y1 = poly.bounds
    cs = g.cell_size_m
    r0, r1 = round((y0 - g.y0_m) / cs), round((y1 - g.y0_m) / cs)
    return [Polygon(p.exterior.coords) for r in range(r0, r1)
            for p in _polygons_in(poly.intersection(
                shapely.box(x0, g.y0_m + cs * r, x1, g.y0_m + cs * (r + 1))))]


def _points(ring: Any, key: str, source: str | None) -> np.ndarray:
    try:
        pts = np.asarray(ring, dtype=float)
    except (TypeError, ValueError):
        pts = np.empty((0,))
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.all(np.isfinite(pts)):
        raise DomainError(f"{where(source, key)}: expected a list of at least 3 [x, y] pairs "
                          f"of finite numbers, got {ring!r}"[:300])
    return pts


def _polygon(ring: Any, key: str, source: str | None) -> Polygon:
    poly = Polygon(_points(ring, key, source))
    if not poly.is_valid:
        raise DomainError(f"{where(source, key)}: invalid polygon ({explain_validity(poly)})")
    return poly
