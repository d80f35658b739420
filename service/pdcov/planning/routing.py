"""Routing inside the free space: shortest paths between its points, polylines clipped to it,
and pieces joined through it; what the patterns (planning/patterns.py) and the gap re-fly
(planning/refly.py) fly between their tracks.

A path takes the straight line where it lies in the free space, otherwise the shortest path
through the free space's vertices (a visibility graph, Dijkstra); between two points of one
boundary ring it may follow that ring. Only parts of the free space that are not connected to
each other are joined by a straight line across what separates them. ENU metres throughout.
"""

from __future__ import annotations

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from shapely.geometry import LinearRing, LineString, MultiPolygon, Point, Polygon
from shapely.ops import substring

from pdcov.errors import ConfigError
from pdcov.planning.decomposition import polygons_of

__all__ = ["COVER_TOL_M", "FreeSpaceRouter", "PathBuilder", "clip_and_join", "clip_polyline"]

COVER_TOL_M = 1e-5
"""Tolerance (m) of "inside the free space": the free space is buffered by it for the tests."""


class FreeSpaceRouter:
    """Shortest paths between points of the free space (ENU metres), staying inside it.

    The straight line is used when it lies in the free space; otherwise the path runs through
    the free space's vertices (visibility graph, Dijkstra), built on first need."""

    def __init__(self, free_enu: Polygon | MultiPolygon):
        self._free = free_enu.buffer(COVER_TOL_M)
        shapely.prepare(self._free)
        self._nodes = np.unique(shapely.get_coordinates(free_enu), axis=0)
        self._rings = [LinearRing(r) for p in polygons_of(free_enu)
                       for r in (p.exterior, *p.interiors)]
        self._graph: csr_matrix | None = None

    def _visible(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether each segment a[i] -> b[i] lies in the free space."""
        segs = shapely.linestrings(np.stack([a, b], axis=1))
        return shapely.covers(self._free, segs)

    def _node_graph(self) -> csr_matrix:
        if self._graph is None:
            n = len(self._nodes)
            i, j = np.triu_indices(n, k=1)
            ok = self._visible(self._nodes[i], self._nodes[j])
            i, j = i[ok], j[ok]
            w = np.linalg.norm(self._nodes[i] - self._nodes[j], axis=1)
            self._graph = csr_matrix((np.concatenate([w, w]), (np.concatenate([i, j]),
                                      np.concatenate([j, i]))), shape=(n, n))
        return self._graph

    def boundary_path(self, a_enu_m: np.ndarray, b_enu_m: np.ndarray) -> np.ndarray | None:
        """(K, 2) points from a to b along the shorter way round the free-space boundary ring
        both lie on; None when they do not lie on one ring."""
        a, b = Point(a_enu_m), Point(b_enu_m)
        for ring in self._rings:
            if ring.distance(a) > COVER_TOL_M or ring.distance(b) > COVER_TOL_M:
                continue
            length = ring.length
            da, db = ring.project(a), ring.project(b)
            forward = (db - da) % length
            start, end, backward = (da, db, False) if forward <= length / 2 else (db, da, True)
            if end >= start:
                arc = shapely.get_coordinates(substring(ring, start, end))
            else:
                arc = np.vstack([shapely.get_coordinates(substring(ring, start, length)),
                                 shapely.get_coordinates(substring(ring, 0.0, end))])
            arc = arc[::-1] if backward else arc
            return np.vstack([[a.x, a.y], arc[1:-1], [b.x, b.y]])
        return None

    def path(self, a_enu_m: np.ndarray, b_enu_m: np.ndarray) -> np.ndarray:
        """(K, 2) points from a to b inclusive; a straight line when none exists in free
        space (a and b in parts of the free space that do not touch)."""
        a, b = np.asarray(a_enu_m, float), np.asarray(b_enu_m, float)
        if self._visible(a[None], b[None])[0]:
            return np.array([a, b])
        g = self._node_graph()
        n = len(self._nodes)
        ends = np.array([a, b])
        # Augmented graph: nodes, then a (n) and b (n + 1), joined to the nodes they see.
        rows, cols, wts = [], [], []
        for k, p in enumerate(ends):
            vis = self._visible(np.repeat(p[None], n, axis=0), self._nodes)
            idx = np.flatnonzero(vis)
            d = np.linalg.norm(self._nodes[idx] - p, axis=1)
            rows += [idx, np.full(len(idx), n + k)]
            cols += [np.full(len(idx), n + k), idx]
            wts += [d, d]
        coo = g.tocoo()
        full = csr_matrix((np.concatenate([coo.data, *wts]),
                           (np.concatenate([coo.row, *rows]), np.concatenate([coo.col, *cols]))),
                          shape=(n + 2, n + 2))
        dist, pred = dijkstra(full, indices=n, return_predecessors=True)
        if not np.isfinite(dist[n + 1]):
            return np.array([a, b])
        order = [n + 1]
        while order[-1] != n:
            order.append(int(pred[order[-1]]))
        pts = np.vstack([self._nodes, ends])
        return pts[order[::-1]]


class PathBuilder:
    """Accumulates a polyline, joining each new piece through the free space."""

    def __init__(self, router: FreeSpaceRouter):
        self._router = router
        self._pts: list[np.ndarray] = []

    @property
    def last(self) -> np.ndarray | None:
        return self._pts[-1] if self._pts else None

    def add(self, piece_enu_m: np.ndarray, along_boundary: bool = False) -> None:
        """Append a piece; with ``along_boundary``, a link between two points of one boundary
        ring follows that ring (so that the strip along the boundary is flown too)."""
        piece = np.asarray(piece_enu_m, dtype=float).reshape(-1, 2)
        if self._pts:
            link = (self._router.boundary_path(self._pts[-1], piece[0]) if along_boundary
                    else None)
            if link is None:
                link = self._router.path(self._pts[-1], piece[0])
            self._pts.extend(link[1:-1])
        self._pts.extend(piece)

    def points(self) -> np.ndarray:
        return np.array(self._pts).reshape(-1, 2)


def clip_polyline(xy_enu_m: np.ndarray, free_enu: Polygon | MultiPolygon) -> list[np.ndarray]:
    """The parts of a polyline inside the free space, in order along it (each (K, 2))."""
    free = free_enu
    shapely.prepare(free)
    pts = np.asarray(xy_enu_m, dtype=float).reshape(-1, 2)
    pieces: list[list[np.ndarray]] = []
    for p, q in zip(pts[:-1], pts[1:], strict=True):
        seg = LineString([p, q])
        if shapely.covers(free, seg):
            parts = [(0.0, p, q)]
        elif not shapely.intersects(free, seg):
            parts = []
        else:
            parts = []
            inside = seg.intersection(free)
            for g in getattr(inside, "geoms", [inside]):
                if isinstance(g, LineString) and g.length > COVER_TOL_M:
                    c = np.asarray(g.coords)
                    if np.dot(c[-1] - c[0], q - p) < 0:
                        c = c[::-1]
                    parts.append((float(np.dot(c[0] - p, q - p)), c[0], c[-1]))
            parts.sort(key=lambda t: t[0])
        for _, a, b in parts:
            if pieces and np.linalg.norm(pieces[-1][-1] - a) < 1e-6:
                pieces[-1].append(b)
            else:
                pieces.append([a, b])
    return [np.array(p) for p in pieces]


def clip_and_join(xy_enu_m: np.ndarray, free_enu: Polygon | MultiPolygon,
                  simplify_m: float = 0.0) -> np.ndarray:
    """A polyline's parts inside the free space, joined through it (``PathBuilder``, along
    the boundary where two parts end on one ring); each part simplified to ``simplify_m``."""
    builder = PathBuilder(FreeSpaceRouter(free_enu))
    for piece in clip_polyline(xy_enu_m, free_enu):
        if simplify_m > 0 and len(piece) > 2:
            piece = np.asarray(LineString(piece).simplify(simplify_m).coords)
        builder.add(piece, along_boundary=True)
    pts = builder.points()
    if len(pts) == 0:
        raise ConfigError("pattern: no part of it lies in the free space; check the centre "
                          "or datum and the radius")
    return pts
