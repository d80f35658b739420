"""The shapes of a coverage the exports carry (report/exports.py, report/kml.py): the P_D
outlines per threshold, the gaps (free cells below the target P_D) and the re-fly areas
proposed over them, each with the POD the search achieved in it, in WGS84."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin

MAX_GAP_SHAPES = 500
"""Gap polygons exported at most (the largest; the FeatureCollection says how many there
were): a scattered grid can have thousands of one-cell gaps, which no map tool draws well."""
MAX_REFLY_AREAS = 50
"""Re-fly areas (assignments) exported at most, the largest."""
MIN_REFLY_CELLS = 4
"""A re-fly area smaller than this many cells is not worth an assignment (its gap still is
a shape)."""

Polygon = list[list[list[float]]]
"""One polygon: rings of [lon, lat] degrees, the exterior first and counter-clockwise, then
the holes, clockwise (RFC 7946; report/gis.polygons_lon_lat)."""

@dataclass(frozen=True, slots=True)
class Coverage:
    """The P_D grid to export: ``pd`` and ``mask`` (n_rows, n_cols; rows growing north),
    its geometry (ENU m about ``origin``), the thresholds outlined and the target P_D below
    which a free cell is a gap."""

    pd: np.ndarray
    mask: np.ndarray
    geometry: GridGeometry
    origin: Origin
    thresholds: tuple[float, ...]
    target_pd: float

    def pd_at(self, x_m: float, y_m: float) -> float | None:
        """P_D of the free cell holding ENU point (x_m, y_m), None outside the free cells."""
        g = self.geometry
        c = int(np.floor((x_m - g.x0_m) / g.cell_size_m))
        r = int(np.floor((y_m - g.y0_m) / g.cell_size_m))
        if not (0 <= r < g.n_rows and 0 <= c < g.n_cols) or not self.mask[r, c]:
            return None
        return float(self.pd[r, c])


@dataclass(frozen=True, slots=True)
class ReflyArea:
    """A re-fly area (a CalTopo Assignment): its ``polygon``, ``area_m2``, the gap cells in
    it and ``pod``: the mean P_D of the free cells whose centres it holds, the probability
    that this search would have found a person there (uniform prior), 0 with none."""

    polygon: Polygon
    area_m2: float
    gap_cells: int
    pod: float


@dataclass(frozen=True, slots=True)
class MapLayers:
    """The coverage's shapes in WGS84: an outline per threshold (ascending), the gaps
    (free cells below the target, largest first, at most MAX_GAP_SHAPES of ``gaps_total``)
    and the re-fly areas (the gaps grown by a cell, merged and simplified)."""

    outlines: tuple[tuple[float, tuple[Polygon, ...]], ...]
    gaps: tuple[Polygon, ...]
    gaps_total: int
    refly: tuple[ReflyArea, ...]
    target_pd: float


def map_layers(coverage: Coverage) -> MapLayers:
    """The outlines, gaps and re-fly areas of ``coverage`` (needs the gis extra)."""
    from pdcov.report.gis import cells_outline, polygons_lon_lat, threshold_outline

    g, o = coverage.geometry, coverage.origin
    outlines = tuple(
        (t, tuple(polygons_lon_lat(threshold_outline(coverage.pd, coverage.mask, g, t), o)))
        for t in sorted(coverage.thresholds))
    gap_cells = coverage.mask & (coverage.pd < coverage.target_pd)
    gap_enu = cells_outline(gap_cells, g)
    gap_shapes = sorted((shapely.Polygon(p[0], p[1:]) for p in gap_enu), key=lambda s: -s.area)
    kept = gap_shapes[:MAX_GAP_SHAPES]
    gaps = tuple(polygons_lon_lat([_rings(s) for s in kept], o))
    refly = _refly_areas(gap_shapes, gap_cells, coverage)
    refly_ll = polygons_lon_lat([_rings(a) for a, _, _, _ in refly], o)
    return MapLayers(outlines, gaps, len(gap_shapes),
                     tuple(ReflyArea(p, area, n, pod)
                           for p, (_, area, n, pod) in zip(refly_ll, refly, strict=True)),
                     coverage.target_pd)


def _rings(p: shapely.Polygon) -> list[list[list[float]]]:
    return [[list(xy) for xy in p.exterior.coords],
            *([list(xy) for xy in r.coords] for r in p.interiors)]


def _refly_areas(gaps: list[shapely.Polygon], gap_cells: np.ndarray, coverage: Coverage
                 ) -> list[tuple[shapely.Polygon, float, int, float]]:
    """The gaps as areas to fly again: grown by a cell and simplified (as planning/refly.py
    sweeps them, so that a staircase of cell edges and one-cell slivers between gaps make
    one area), the largest MAX_REFLY_AREAS of at least MIN_REFLY_CELLS gap cells each:
    (polygon ENU m, area m², gap cells, mean P_D of the free cells in it)."""
    if not gaps:
        return []
    g = coverage.geometry
    c = g.cell_size_m
    grown = shapely.union_all(gaps).buffer(c, join_style="mitre").simplify(c)
    parts = [p for p in getattr(grown, "geoms", [grown]) if isinstance(p, shapely.Polygon)]
    xs, ys = g.centres_enu()
    rows, cols = np.nonzero(gap_cells)
    x_m, y_m = xs[cols], ys[rows]  # coordinates, not points: 16 B a gap cell
    out = []
    for p in parts:
        shapely.prepare(p)
        n = int(np.count_nonzero(shapely.contains_xy(p, x_m, y_m)))
        if n >= MIN_REFLY_CELLS:
            out.append((p, float(p.area), n))
    kept = sorted(out, key=lambda a: -a[1])[:MAX_REFLY_AREAS]
    return [(p, area, n, _mean_pd_in(p, coverage)) for p, area, n in kept]


def _mean_pd_in(area: shapely.Polygon, coverage: Coverage) -> float:
    """Mean P_D of the free cells whose centres lie in ``area`` (ENU m); 0 with none. Only
    the cells of its bounding box are tested."""
    g = coverage.geometry
    x0, y0, x1, y1 = area.bounds
    c0 = max(int((x0 - g.x0_m) // g.cell_size_m), 0)
    r0 = max(int((y0 - g.y0_m) // g.cell_size_m), 0)
    c1 = min(int((x1 - g.x0_m) // g.cell_size_m) + 1, g.n_cols)
    r1 = min(int((y1 - g.y0_m) // g.cell_size_m) + 1, g.n_rows)
    xs, ys = g.centres_enu()
    cx, cy = np.meshgrid(xs[c0:c1], ys[r0:r1])
    inside = shapely.contains_xy(area, cx, cy) & coverage.mask[r0:r1, c0:c1]
    return float(coverage.pd[r0:r1, c0:c1][inside].mean()) if inside.any() else 0.0
