"""Boustrophedon (Morse) decomposition of the free space for a linear Morse function.

The paper (section II-C, Fig. 3) splits the free space F into cells whose slices
h(x, y) = const are single intervals, for h(x, y) = a x + b y. We work in the *sweep frame*,
the ENU frame rotated so that h = x' (x' along the gradient of h, y' along the slices):

1. every vertex of F gives an event x'; between consecutive events F is cut into slabs, and
   each connected piece of a slab is a trapezoid-like region with one slice interval per x';
2. a piece and the piece in the next slab are joined when each is the other's only
   neighbour across the event line (the slice's connectivity does not change there);
   where it changes (a split or a merge: a critical point of h) a new cell starts;
3. two cells are adjacent when they share a boundary of positive length;
4. the walk is the closed depth-first tour of the adjacency graph from the cell with the
   lowest h (the paper's "Hamiltonian walk": every cell at least once, back at the start).

Cells are shapely polygons in ENU metres; together they cover F and do not overlap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import LineString, MultiPolygon, Polygon, box
from shapely.geometry.base import BaseGeometry

from pdcov.errors import DomainError

_REL_TOL = 1e-9


@dataclass(frozen=True, slots=True)
class SweepFrame:
    """ENU rotated so that x' = h(x, y) = cos(angle) x + sin(angle) y.

    h_angle_rad: direction of the gradient of h in ENU, counter-clockwise from east.
    Tracks of a lawnmower run along y' (the slices), spaced along x'.
    """

    h_angle_rad: float

    def to_sweep(self, geom: BaseGeometry) -> BaseGeometry:
        a, b = math.cos(self.h_angle_rad), math.sin(self.h_angle_rad)
        return affinity.affine_transform(geom, [a, b, -b, a, 0.0, 0.0])

    def to_enu(self, geom: BaseGeometry) -> BaseGeometry:
        a, b = math.cos(self.h_angle_rad), math.sin(self.h_angle_rad)
        return affinity.affine_transform(geom, [a, -b, b, a, 0.0, 0.0])

    def points_to_enu(self, xy_sweep_m: np.ndarray) -> np.ndarray:
        """(N, 2) sweep-frame points to (N, 2) ENU metres."""
        a, b = math.cos(self.h_angle_rad), math.sin(self.h_angle_rad)
        p = np.asarray(xy_sweep_m, dtype=float).reshape(-1, 2)
        return np.column_stack([a * p[:, 0] - b * p[:, 1], b * p[:, 0] + a * p[:, 1]])


@dataclass(frozen=True, slots=True)
class Decomposition:
    """Cells of the free space, their adjacency graph and a walk visiting every cell.

    cells: polygons in ENU metres, numbered by increasing min h.
    adjacency: edges (i, j), i < j, between cells sharing a boundary of positive length.
    walk: cell indices of a closed walk through the adjacency graph that visits every cell
        (one tour per connected component of the free space, one after another).
    """

    frame: SweepFrame
    cells: tuple[Polygon, ...]
    adjacency: tuple[tuple[int, int], ...]
    walk: tuple[int, ...]

    def visit_order(self) -> list[int]:
        """Cells in the order the walk first reaches them (each exactly once)."""
        seen: dict[int, None] = {}
        for c in self.walk:
            seen.setdefault(c, None)
        return list(seen)


def polygons_of(geom: BaseGeometry, min_area_m2: float = 0.0) -> list[Polygon]:
    """The polygons with area above ``min_area_m2`` inside any shapely geometry."""
    parts = getattr(geom, "geoms", [geom])
    out: list[Polygon] = []
    for g in parts:
        if isinstance(g, Polygon):
            if g.area > min_area_m2:
                out.append(g)
        elif hasattr(g, "geoms"):
            out.extend(polygons_of(g, min_area_m2))
    return out


def _slice_interval(piece: Polygon, x: float, span: tuple[float, float]) -> tuple[float, float]:
    """(y_lo, y_hi) of the piece's slice at x' = x (a piece has one interval per slice)."""
    cut = piece.intersection(LineString([(x, span[0]), (x, span[1])]))
    if cut.is_empty:
        return (math.inf, -math.inf)
    _, y_lo, _, y_hi = cut.bounds
    return (y_lo, y_hi)


def boustrophedon_decomposition(free_enu: Polygon | MultiPolygon,
                                h_angle_rad: float) -> Decomposition:
    """Decompose the free space (ENU metres) for h = cos(angle) x + sin(angle) y."""
    if free_enu.is_empty or free_enu.area <= 0:
        raise DomainError("decomposition: the free space is empty")
    frame = SweepFrame(float(h_angle_rad))
    free = frame.to_sweep(free_enu)
    x_min, y_min, x_max, y_max = free.bounds
    scale = max(x_max - x_min, y_max - y_min)
    tol = _REL_TOL * scale
    span = (y_min - 1.0, y_max + 1.0)

    xs = np.unique(shapely.get_coordinates(free)[:, 0])
    events = [xs[0]]
    for x in xs[1:]:
        if x - events[-1] > tol:
            events.append(float(x))
    events[-1] = max(events[-1], x_max)

    # Pieces of every slab between consecutive events, with the slab each belongs to.
    pieces: list[Polygon] = []
    slab_of: list[int] = []
    min_area = (_REL_TOL * scale) ** 2
    for k, (xa, xb) in enumerate(zip(events[:-1], events[1:], strict=True)):
        for p in polygons_of(free.intersection(box(xa, span[0], xb, span[1])), min_area):
            pieces.append(p)
            slab_of.append(k)

    # Adjacency of pieces across each event line: overlapping slice intervals there.
    right: dict[int, list[int]] = {i: [] for i in range(len(pieces))}
    left: dict[int, list[int]] = {i: [] for i in range(len(pieces))}
    by_slab: dict[int, list[int]] = {}
    for i, k in enumerate(slab_of):
        by_slab.setdefault(k, []).append(i)
    for k, members in by_slab.items():
        xb = events[k + 1]
        for i in members:
            lo_a, hi_a = _slice_interval(pieces[i], xb, span)
            for j in by_slab.get(k + 1, []):
                lo_b, hi_b = _slice_interval(pieces[j], xb, span)
                if min(hi_a, hi_b) - max(lo_a, lo_b) > tol:
                    right[i].append(j)
                    left[j].append(i)

    # Join pieces whose connectivity does not change across the event (union-find).
    parent = list(range(len(pieces)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(pieces)):
        if len(right[i]) == 1 and len(left[right[i][0]]) == 1:
            parent[find(right[i][0])] = find(i)

    groups: dict[int, list[int]] = {}
    for i in range(len(pieces)):
        groups.setdefault(find(i), []).append(i)
    merged = [(shapely.union_all([pieces[i] for i in members]), members)
              for members in groups.values()]
    merged.sort(key=lambda gm: (gm[0].bounds[0], gm[0].bounds[1]))
    cell_of_piece = {}
    for c, (_, members) in enumerate(merged):
        for i in members:
            cell_of_piece[i] = c
    edges = sorted({(min(cell_of_piece[i], cell_of_piece[j]),
                     max(cell_of_piece[i], cell_of_piece[j]))
                    for i in right for j in right[i]
                    if cell_of_piece[i] != cell_of_piece[j]})
    cells = tuple(frame.to_enu(_as_polygon(g)) for g, _ in merged)
    return Decomposition(frame, cells, tuple(edges), tuple(_walk(len(cells), edges)))


def _as_polygon(geom: BaseGeometry) -> Polygon:
    """A merged cell as one polygon (slivers from floating-point seams are dropped)."""
    parts = polygons_of(geom)
    return max(parts, key=lambda p: p.area) if len(parts) > 1 else parts[0]


def _walk(n_cells: int, edges: list[tuple[int, int]]) -> list[int]:
    """Closed depth-first tours of the graph, one per component, lowest index first."""
    nbrs: dict[int, list[int]] = {i: [] for i in range(n_cells)}
    for a, b in edges:
        nbrs[a].append(b)
        nbrs[b].append(a)
    seen: set[int] = set()
    walk: list[int] = []
    for start in range(n_cells):
        if start in seen:
            continue
        seen.add(start)
        walk.append(start)
        stack = [(start, iter(sorted(nbrs[start])))]
        while stack:
            node, it = stack[-1]
            nxt = next((n for n in it if n not in seen), None)
            if nxt is None:
                stack.pop()
                if stack:
                    walk.append(stack[-1][0])
            else:
                seen.add(nxt)
                walk.append(nxt)
                stack.append((nxt, iter(sorted(nbrs[nxt]))))
    return walk
