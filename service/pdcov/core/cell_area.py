"""Image areas of grid cells: a cell's quadrilateral image, whole or clipped to the picture.

The coverage grid (``core/grid.py``) sizes a cell by the square root of its image area in
pixels. A cell wholly inside the picture takes the shoelace area of its corners' quadrilateral
(``quad_area``); a cell straddling the picture's edge takes the area of that quadrilateral
clipped to the picture (``clipped_quad_area``), by Green's theorem over the clipped sides, or by
Sutherland-Hodgman for a cell larger than the picture. Pixel coordinates, areas in px^2.
"""

from __future__ import annotations

import numpy as np

__all__ = ["clipped_quad_area", "quad_area"]

_NEXT = [1, 2, 3, 0]  # the next corner of a quadrilateral


def clipped_quad_area(q: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """Area of quadrilaterals (K, 4, 2) inside the picture [-0.5, w - 0.5] x [-0.5, h - 0.5].

    By Green's theorem the area of the clipped quadrilateral is the integral of
    (x - x_ref) dy around its boundary. With x_ref on the picture's left (or right) edge the
    integrand vanishes along that edge and, dy being 0, along the top and bottom edges; so
    when the quadrilateral does not reach past the opposite vertical edge, only its own sides,
    each clipped to the picture, contribute. Quadrilaterals past both vertical edges use the
    same formula with x and y exchanged; those past all four edges (a cell larger than the
    picture) go through ``_polygon_clipped_area``.
    """
    x, y = q[..., 0], q[..., 1]
    w, h = width_px - 0.5, height_px - 0.5
    left, right = _corner_min(x) < -0.5, _corner_max(x) > w
    both_x = left & right
    if not both_x.any():
        return _green_clipped_area(x, y, w, h, right)
    below, above = _corner_min(y) < -0.5, _corner_max(y) > h
    area = np.empty(len(q))
    for sel, u, v, bu, bv, past in ((~both_x, x, y, w, h, right),
                                    (both_x & ~(below & above), y, x, h, w, above)):
        area[sel] = _green_clipped_area(u[sel], v[sel], bu, bv, past[sel])
    rest = both_x & below & above
    area[rest] = _polygon_clipped_area(q[rest], width_px, height_px)
    return area


def _corner_min(v: np.ndarray) -> np.ndarray:
    return np.minimum(np.minimum(v[:, 0], v[:, 1]), np.minimum(v[:, 2], v[:, 3]))


def _corner_max(v: np.ndarray) -> np.ndarray:
    return np.maximum(np.maximum(v[:, 0], v[:, 1]), np.maximum(v[:, 2], v[:, 3]))


def _green_clipped_area(x: np.ndarray, y: np.ndarray, x_hi: float, y_hi: float,
                        right: np.ndarray) -> np.ndarray:
    """Area inside [-0.5, x_hi] x [-0.5, y_hi] of quadrilaterals with corners x, y (K, 4)
    that do not reach past both x bounds; ``right`` (K,) is True for those past x_hi."""
    dx = x[:, _NEXT] - x
    dy = y[:, _NEXT] - y
    t_in = np.zeros(x.shape)
    t_out = np.ones(x.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        # Liang-Barsky: the part t in [t_in, t_out] of each side a + t d inside the picture.
        for a, d, hi in ((x, dx, x_hi), (y, dy, y_hi)):
            t1 = (-0.5 - a) / d
            t2 = (hi - a) / d
            flat = d == 0
            np.maximum(t_in, np.where(flat, -np.inf, np.minimum(t1, t2)), out=t_in)
            np.minimum(t_out, np.where(flat, np.inf, np.maximum(t1, t2)), out=t_out)
            t_in[flat & ((a < -0.5) | (a > hi))] = np.inf
        span = t_out - t_in
        x_mid = x + 0.5 * (t_in + t_out) * dx - np.where(right, x_hi, -0.5)[:, None]
        integral = np.where(span > 0, x_mid * span * dy, 0.0)
    return np.abs(integral[:, 0] + integral[:, 1] + integral[:, 2] + integral[:, 3])


def _polygon_clipped_area(q: np.ndarray, width_px: int, height_px: int) -> np.ndarray:
    """Area of polygons (K, n, 2) inside the picture [-0.5, w - 0.5) x [-0.5, h - 0.5).

    Sutherland-Hodgman against the picture's four edges, vectorised over K: each stage keeps
    the inside vertices and the edge crossings; the valid vertices are then moved to the front
    and the tail is padded with the first one, which adds nothing to the shoelace sum.
    """
    poly = q
    for axis, bound, keep_above in ((0, -0.5, True), (0, width_px - 0.5, False),
                                    (1, -0.5, True), (1, height_px - 0.5, False)):
        if poly.shape[0] == 0:
            break
        a = poly
        b = np.roll(poly, -1, axis=1)
        da = a[..., axis] - bound
        db = b[..., axis] - bound
        if not keep_above:
            da, db = -da, -db
        a_in = da >= 0
        cross = (da >= 0) != (db >= 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(cross, da / (da - db), 0.0)
        x = a + t[..., None] * (b - a)
        out = np.stack([a, x], axis=2).reshape(len(poly), -1, 2)
        valid = np.stack([a_in, cross], axis=2).reshape(len(poly), -1)
        order = np.argsort(~valid, axis=1, kind="stable")
        out = np.take_along_axis(out, order[..., None], axis=1)
        n_valid = valid.sum(axis=1)
        pad = np.arange(out.shape[1])[None, :] >= n_valid[:, None]
        out = np.where(pad[..., None], out[:, :1], out)
        poly = out[:, :max(int(n_valid.max(initial=0)), 1)]
    x, y = poly[..., 0], poly[..., 1]
    return 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))


def quad_area(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Shoelace area of quadrilaterals a-b-c-d, any orientation; corners (..., 2)."""
    return 0.5 * np.abs((a[..., 0] - c[..., 0]) * (b[..., 1] - d[..., 1])
                        - (b[..., 0] - d[..., 0]) * (a[..., 1] - c[..., 1]))
