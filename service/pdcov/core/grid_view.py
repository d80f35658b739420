"""Which cells of the grid a camera frame sees, and how large (paper, III-C).

A cell is observed in a frame when the ray through its centre reaches the picture: in front
of the camera, inside the calibrated field of view, inside the image, within the maximum
slant range. Its apparent size is the square root of the area, in pixels, of its image
inside the picture.

On terrain (``relief``: a ``TerrainSurface``) each cell's corners and centre lie on the
surface, its image is that of its 3-D patch, and it is observed only when it faces the
camera and the terrain does not rise above the line of sight to its centre
(``core/occlusion.py``). Without it the ground is the plane z = 0 of the paper.

With something standing on the ground (``covered``: a ``TerrainSurface`` whose ``cover`` is
set, core/ground_cover.py) each observed cell also has a transmittance, the mean over rays
from points spread over it of what the trees let through (0 behind or under a roof); a cell
none of whose rays gets through is not observed: HIDDEN, or BUILDING under a roof.

Every function takes the frame's camera (``GridCamera``) explicitly: a grid evaluates frames
of several cameras (``CoverageGrid.update_with``) with one ``GridView``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.cell_area import clipped_quad_area, quad_area
from pdcov.core.domain import GridGeometry
from pdcov.core.footprint import BorderRaysEnu
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid_camera import GridCamera
from pdcov.core.ground_cover import CoverKind, cell_transmittance
from pdcov.core.limiting import LimitingFactor
from pdcov.core.occlusion import hidden_by_terrain, sight_clear
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import BLOCK, TerrainSurface
from pdcov.core.tiles import TiledLayer

_SUBDIVISIONS = 8  # sub-cells per side for cells only partly inside the picture
_TOO_FAR_BAND_ROWS = 32
"""Rows per band in which ``GridView.mark_too_far`` bounds the cells it judges."""


def window_union(a: tuple[int, int, int, int] | None, b: tuple[int, int, int, int] | None
                 ) -> tuple[int, int, int, int] | None:
    """The smallest window (r0, r1, c0, c1) holding windows ``a`` and ``b`` (None: none)."""
    if a is None or b is None:
        return a or b
    return min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])


@dataclass(frozen=True, slots=True, eq=False)
class GridView:
    """The view geometry of a grid's cells: ``geometry`` (ENU), ``free`` (the free cells:
    only those are in view), ``relief`` (the ground under the cells; None: the plane
    z = 0, the flat-earth path) and ``covered`` (the terrain when something stands on it,
    else None). Windows are (r0, r1, c0, c1) of grid rows and columns."""

    geometry: GridGeometry
    free: FreeCells
    relief: TerrainSurface | None
    covered: TerrainSurface | None = None

    @classmethod
    def over(cls, geometry: GridGeometry, free: FreeCells, terrain: TerrainSurface | None
             ) -> GridView:
        """The view over ``terrain`` (None: the plane z = 0): the flat-earth path where its
        ground is level at 0, its cover where something stands on it."""
        return cls(geometry, free, None if terrain is None or terrain.is_level_zero else terrain,
                   None if terrain is None or terrain.cover is None else terrain)

    def observe_area(self, frame: GridCamera, pose: CameraPose,
                     window: tuple[int, int, int, int]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The observed mask of ``window``, the image area (px^2) inside the picture of
        every cell of it (meaningful only where observed; float32 or float64), the
        LimitingFactor of the cells not observed (uint8; NEVER_IN_VIEW, TOO_FAR, HIDDEN,
        BUILDING) and, with ``covered``, the transmittance of every cell (float32, 1 where
        not observed; None without one)."""
        H, in_view, in_range, z_c = self._centres(frame, pose, window)
        if not in_view.any():
            return (in_view, np.zeros(in_view.shape), np.zeros(in_view.shape, np.uint8),
                    None)
        r0, r1, c0, c1 = window
        n_rows, n_cols = in_view.shape
        g, cam, relief = self.geometry, frame.camera, self.relief
        cs = g.cell_size_m
        r = pose.r_cam_enu
        up_cam = pose.R_enu_cam[2]
        z_v = None if relief is None else relief.z_corner_m[r0:r1 + 1, c0:c1 + 1]
        observed = in_view & in_range
        reach = np.where(in_view, np.uint8(LimitingFactor.TOO_FAR),
                         np.uint8(LimitingFactor.NEVER_IN_VIEW))
        if relief is not None and observed.any():
            assert z_v is not None and z_c is not None
            # Cells whose line of sight is steeper than any terrain on the way face the camera
            # and are not hidden: only the others are tested, and when none is left (gentle
            # terrain seen from above), nothing is.
            clear = sight_clear(relief, r, window, z_c)
            if not (clear | ~observed).all():
                rows, cols = np.nonzero(observed)
                front = clear[rows, cols]
                test = ~front
                front[test] = self._faces_camera(r, z_v, rows[test], cols[test], r0, c0)
                x = g.x0_m + cs * (cols[front] + c0 + 0.5)
                y = g.y0_m + cs * (rows[front] + r0 + 0.5)
                blocked = ~front
                blocked[front] = hidden_by_terrain(relief, r, x, y,
                                                   z_c[rows[front], cols[front]])
                observed[rows[blocked], cols[blocked]] = False
                reach[rows[blocked], cols[blocked]] = LimitingFactor.HIDDEN
        transmit = None
        if self.covered is not None and observed.any():
            transmit = self._transmittance(pose, window, observed, reach)
        if not observed.any():
            return observed, np.zeros(observed.shape), reach, transmit
        with np.errstate(invalid="ignore", over="ignore"):
            # Corners, projected all at once: a cell wholly in the picture takes the area of
            # its corners' quadrilateral.
            if z_v is None:
                px_v = cam.project_lattice(H, n_cols + 1, n_rows + 1)
            else:
                jv = np.arange(n_cols + 1, dtype=np.float64)
                iv = np.arange(n_rows + 1, dtype=np.float64)[:, None]
                px_v = cam.project_xyz(*(H[k, 0] * jv + (H[k, 1] * iv + H[k, 2])
                                         + up_cam[k] * z_v for k in range(3)))
            v_in = cam.in_picture(px_v)
            corners = np.array([[0, 0, 1], [n_cols, 0, 1], [0, n_rows, 1],
                                [n_cols, n_rows, 1]], dtype=np.float64)
            hull = corners @ H.T
            if relief is not None:  # the window's box between its lowest and highest corner
                z_lo, z_hi = relief.window_z_range_m(r0, r1, c0, c1)  # (or a little wider)
                hull = np.concatenate([hull + up_cam * z_lo, hull + up_cam * z_hi])
            v_ok = None  # all projectable
            if not cam.all_projectable(hull):
                jj, ii = np.meshgrid(np.arange(n_cols + 1), np.arange(n_rows + 1))
                p_v = jj[..., None] * H[:, 0] + ii[..., None] * H[:, 1] + H[:, 2]
                if z_v is not None:
                    p_v = p_v + z_v[..., None] * up_cam
                v_ok = cam.projectable(p_v)
                v_in &= v_ok
            whole = v_in[:-1, :-1] & v_in[:-1, 1:] & v_in[1:, 1:] & v_in[1:, :-1]
            area = quad_area(px_v[:-1, :-1], px_v[:-1, 1:], px_v[1:, 1:], px_v[1:, :-1])
        # Cells straddling the picture's edge: clip their image to the picture.
        rows, cols = np.nonzero(observed & ~whole)
        if len(rows):
            # Flat indices of the corners (row, col), (row, col + 1), (row + 1, col + 1),
            # (row + 1, col) in the corner lattice.
            at = (rows * (n_cols + 1) + cols)[:, None] + np.array([0, 1, n_cols + 2, n_cols + 1])
            q = px_v.reshape(-1, 2)[at].astype(np.float64)
            ok = np.ones(len(rows), dtype=bool) if v_ok is None else v_ok.ravel()[at].all(axis=1)
            edge_area = np.empty(len(rows))
            edge_area[ok] = clipped_quad_area(q[ok], cam.width_px, cam.height_px)
            # Cells with a corner where projection folds back: integrate over sub-cells.
            if not ok.all():
                edge_area[~ok] = self._partial_area(cam, pose, rows[~ok] + r0, cols[~ok] + c0)
            area[rows, cols] = edge_area
        return observed, area, reach, transmit

    def limiting(self, frame: GridCamera, window: tuple[int, int, int, int],
                 observed: np.ndarray, size_index: np.ndarray, reach: np.ndarray
                 ) -> np.ndarray:
        """The LimitingFactor (uint8) a frame gives the cells of ``window``: by size bin
        (``size_index``) where ``observed``, CANOPY for those seen at a covered size under
        trees; ``reach`` (``observe_area``'s) elsewhere."""
        seen = np.where(observed, frame.seen_code.take(size_index * observed), reach)
        if self.covered is not None and self.covered.cover is not None:
            r0, r1, c0, c1 = window
            under = self.covered.cover.kind[r0:r1, c0:c1] == CoverKind.FOLIAGE
            seen[under & (seen == LimitingFactor.SEEN)] = LimitingFactor.CANOPY
        return seen

    def _transmittance(self, pose: CameraPose, window: tuple[int, int, int, int],
                       observed: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """The transmittance (float32, the window's shape; 1 where not observed) of the
        ``observed`` cells of ``window`` through the cover; cells it blocks wholly are
        taken out of ``observed`` and marked in ``reach`` (BUILDING under a roof, else
        HIDDEN)."""
        terrain = self.covered
        assert terrain is not None and terrain.cover is not None
        tops = terrain.cover_tops
        assert tops is not None
        r0, _, c0, _ = window
        rows, cols = np.nonzero(observed)
        t = cell_transmittance(terrain.cover, tops, terrain.max_slope,
                               None if self.relief is None else self.relief.height_m,
                               pose.r_cam_enu, rows + r0, cols + c0)
        out = np.ones(observed.shape, dtype=np.float32)
        out[rows, cols] = t
        blocked = t == 0
        if blocked.any():
            br, bc = rows[blocked], cols[blocked]
            observed[br, bc] = False
            reach[br, bc] = np.where(terrain.cover.roof[br + r0, bc + c0],
                                     np.uint8(LimitingFactor.BUILDING),
                                     np.uint8(LimitingFactor.HIDDEN))
        return out

    def mark_too_far(self, frame: GridCamera, pose: CameraPose,
                     window: tuple[int, int, int, int] | None, limiting: TiledLayer
                     ) -> tuple[int, int, int, int] | None:
        """Mark TOO_FAR the cells in view beyond the maximum range, out to twice it, outside
        ``window`` (the window's own cells are judged by ``observe_area``); the terrain's
        line of sight is not tested there. For frames whose picture reaches past the range.
        ``limiting``: the grid's LimitingFactor per cell (uint8 tiles), raised. Returns
        the window (r0, r1, c0, c1) of the cells it marked, None for none."""
        wide, _ = self.window(frame, pose, 2.0 * frame.max_range_m)
        if wide is None or wide == window:
            return None
        changed: tuple[int, int, int, int] | None = None
        r0, r1, c0, c1 = wide
        # Only free cells below TOO_FAR can change: each band of rows is judged over the
        # columns that hold such cells.
        unmarked = self.free.window(wide) & (limiting.read(wide) < LimitingFactor.TOO_FAR)
        for b0 in range(0, r1 - r0, _TOO_FAR_BAND_ROWS):
            band = unmarked[b0:b0 + _TOO_FAR_BAND_ROWS]
            cols = np.flatnonzero(band.any(axis=0))
            if not len(cols):
                continue
            sub = (r0 + b0, r0 + b0 + len(band), c0 + int(cols[0]), c0 + int(cols[-1]) + 1)
            _, in_view, in_range = self.centres(frame, pose, sub)
            marked = in_view & ~in_range & band[:, cols[0]:cols[-1] + 1]
            mr, mc = np.flatnonzero(marked.any(axis=1)), np.flatnonzero(marked.any(axis=0))
            if not len(mr):
                continue
            limiting.write(sub, np.maximum(limiting.read(sub), marked.view(np.uint8)
                                           * np.uint8(LimitingFactor.TOO_FAR)))
            changed = window_union(changed, (sub[0] + int(mr[0]), sub[0] + int(mr[-1]) + 1,
                                       sub[2] + int(mc[0]), sub[2] + int(mc[-1]) + 1))
        return changed

    def centres(self, frame: GridCamera, pose: CameraPose, window: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """H, the map of window lattice indices [j, i, 1] to the optical frame on the plane
        z = 0, and per cell of ``window``: whether it is in view (free, its centre in the
        picture and in the calibrated field of view) and within the maximum slant range."""
        return self._centres(frame, pose, window)[:3]

    def _centres(self, frame: GridCamera, pose: CameraPose, window: tuple[int, int, int, int]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """``centres``, and the heights (m) of the window's cell centres on the terrain
        (None: flat)."""
        r0, r1, c0, c1 = window
        n_rows, n_cols = r1 - r0, c1 - c0
        g = self.geometry
        cs = g.cell_size_m
        cam = frame.camera
        r = pose.r_cam_enu
        relief = self.relief
        # The window's cell corners form a lattice; the corner (col c0 + j, row r0 + i) at
        # height z is, in the optical frame, R_cam_enu @ ([x, y, z] - r) = H @ [j, i, 1]
        # + z up_cam, with up_cam = R_cam_enu @ [0, 0, 1].
        H = pose.R_enu_cam.T @ np.array([[cs, 0.0, g.x0_m + cs * c0 - r[0]],
                                         [0.0, cs, g.y0_m + cs * r0 - r[1]],
                                         [0.0, 0.0, -r[2]]])
        H_centre = H.copy()
        H_centre[:, 2] += 0.5 * (H[:, 0] + H[:, 1])
        j = np.arange(n_cols, dtype=np.float64)
        i = np.arange(n_rows, dtype=np.float64)[:, None]
        dx2 = (g.x0_m + cs * (np.arange(c0, c1) + 0.5) - r[0]) ** 2
        dy2 = (g.y0_m + cs * (np.arange(r0, r1) + 0.5) - r[1]) ** 2
        xyz_c = [H_centre[k, 0] * j + (H_centre[k, 1] * i + H_centre[k, 2]) for k in range(3)]
        z_c = None
        if relief is None:
            in_range = dy2[:, None] + (dx2 + r[2] ** 2) <= frame.max_range_m**2
        else:
            z_c = relief.centre_z_m(r0, r1, c0, c1)
            in_range = dy2[:, None] + (dx2 + (z_c - r[2]) ** 2) <= frame.max_range_m**2
            up_cam = pose.R_enu_cam[2]
            for k in range(3):
                xyz_c[k] += up_cam[k] * z_c
        # Behind the camera the maps hold meaningless values; the tests below reject those.
        with np.errstate(invalid="ignore", over="ignore"):
            px_c = (cam.project_lattice(H_centre, n_cols, n_rows) if relief is None
                    else cam.project_xyz(*xyz_c))
            in_view = self.free.window(window) & cam.in_picture(px_c)
            if in_view.any():
                in_view &= cam.in_fov_xyz(*xyz_c)
        return H, in_view, in_range, z_c

    def _faces_camera(self, r_cam_enu: np.ndarray, z_corner_m: np.ndarray, rows: np.ndarray,
                      cols: np.ndarray, r0: int, c0: int) -> np.ndarray:
        """True for the cells (rows, cols) of the window at (r0, c0) whose corner heights
        are ``z_corner_m`` whose surface faces the camera: the camera is on the upper side of
        the plane through the centre with the normal of the diagonals' cross product."""
        cs = self.geometry.cell_size_m
        z00, z01 = z_corner_m[rows, cols], z_corner_m[rows, cols + 1]
        z10, z11 = z_corner_m[rows + 1, cols], z_corner_m[rows + 1, cols + 1]
        # (cs, cs, z11 - z00) x (-cs, cs, z10 - z01) / cs = (n_x, n_y, 2 cs)
        n_x = (z10 - z01) - (z11 - z00)
        n_y = -(z11 - z00) - (z10 - z01)
        g = self.geometry
        x = g.x0_m + cs * (cols + c0 + 0.5)
        y = g.y0_m + cs * (rows + r0 + 0.5)
        z = 0.25 * ((z00 + z11) + (z01 + z10))
        return (n_x * (r_cam_enu[0] - x) + n_y * (r_cam_enu[1] - y)
                + 2 * cs * (r_cam_enu[2] - z)) > 0

    def _partial_area(self, camera: CameraModel, pose: CameraPose, rows: np.ndarray,
                      cols: np.ndarray) -> np.ndarray:
        """Image area (px^2) inside the picture of cells only partly inside it: each cell is
        split into sub-cells, and a sub-cell counts with its whole image area when its corners
        project trustworthily and the centre of its image is inside the picture."""
        m = _SUBDIVISIONS
        g = self.geometry
        cs = g.cell_size_m
        f = np.linspace(0.0, 1.0, m + 1)
        x = g.x0_m + cs * (cols[:, None, None] + f[None, None, :])       # (k, 1, m+1)
        y = g.y0_m + cs * (rows[:, None, None] + f[None, :, None])       # (k, m+1, 1)
        x, y = np.broadcast_arrays(x, y)
        z = np.zeros_like(x) if self.relief is None else self.relief.height_m(x, y)
        p_enu = np.stack([x, y, z], axis=-1).reshape(-1, 3)
        p_cam = (p_enu - pose.r_cam_enu) @ pose.R_enu_cam
        ok = camera.projectable(p_cam)
        px: np.ndarray = np.zeros((len(p_cam), 2))
        px[ok] = camera.project(p_cam[ok])
        px = px.reshape(len(rows), m + 1, m + 1, 2)
        ok = ok.reshape(len(rows), m + 1, m + 1)
        quads = np.stack([px[:, :-1, :-1], px[:, :-1, 1:], px[:, 1:, 1:], px[:, 1:, :-1]],
                         axis=3)                                           # (k, m, m, 4, 2)
        sub_ok = ok[:, :-1, :-1] & ok[:, :-1, 1:] & ok[:, 1:, 1:] & ok[:, 1:, :-1]
        centre = quads.mean(axis=3).reshape(-1, 2)
        sub_ok &= camera.in_picture(centre).reshape(sub_ok.shape)
        return np.where(sub_ok, quad_area(*np.moveaxis(quads, 3, 0)), 0.0).sum(axis=(1, 2))

    def window(self, frame: GridCamera, pose: CameraPose, range_m: float | None = None
               ) -> tuple[tuple[int, int, int, int] | None, bool]:
        """(r0, r1, c0, c1): the grid cells that may be observed within ``range_m`` slant
        range (default the maximum range), from the footprint's extent padded by one cell
        and by the chord error of the sampled border; and whether the picture reaches beyond
        that range.

        On terrain the footprint lies between the ground planes through the lowest and the
        highest terrain: the picture's cone between them projects inside the footprints on
        those two planes. Their extent on the whole surface's range gives a first window,
        the range under that window a second, tighter one."""
        relief = self.relief
        range_m = frame.max_range_m if range_m is None else range_m
        rays = BorderRaysEnu.of(frame.camera, pose)
        if relief is None:
            return self._window_between(rays, range_m, (0.0, 0.0))
        z_range = relief.z_range_m
        window, clipped = self._window_between(rays, range_m, z_range)
        if window is None:
            return None, clipped
        window = self._blocks_in_view(frame.fov_box, pose, range_m, window)
        if window is None:
            return None, clipped
        local = relief.window_z_range_m(*window)
        if local == z_range:
            return window, clipped
        return self._window_between(rays, range_m, local, window)[0], clipped

    def _blocks_in_view(self, fov_box: tuple[float, float, float, float], pose: CameraPose,
                        range_m: float, window: tuple[int, int, int, int]
                        ) -> tuple[int, int, int, int] | None:
        """The part of ``window`` covered by the terrain blocks (core/terrain.py) that may be
        in view: a block is out when its box (its cells, from its lowest to its highest
        height) lies wholly outside one side of the pyramid bounding the calibrated field of
        view, or farther than ``range_m``."""
        relief = self.relief
        assert relief is not None
        g = self.geometry
        (b_r0, b_r1, b_c0, b_c1), z_lo, z_hi = relief.block_bounds(*window)
        step = BLOCK * g.cell_size_m
        x = g.x0_m + step * np.arange(b_c0, b_c1 + 1) - pose.r_cam_enu[0]
        y = g.y0_m + step * np.arange(b_r0, b_r1 + 1) - pose.r_cam_enu[1]
        x_lo, x_hi = x[None, :-1], x[None, 1:]
        y_lo, y_hi = y[:-1, None], y[1:, None]
        z_lo = z_lo - pose.r_cam_enu[2]
        z_hi = z_hi - pose.r_cam_enu[2]
        R_cam_enu = pose.R_enu_cam.T
        x_min, x_max, y_min, y_max = fov_box
        # For each side plane n . p >= 0 of the pyramid (and z > 0), a box is wholly outside
        # when the largest n . p over its corners is negative: per axis, the larger of the
        # two extremes weighted by n's component.
        n_enu = np.empty((5, 3, 1, 1))
        for k, (k_x, k_y) in enumerate(((0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0),
                                        (0.0, -1.0))):
            bound = (x_min if k_x > 0 else x_max) if k_x else (
                (y_min if k_y > 0 else y_max) if k_y else 0.0)
            # n = k_x e_x + k_y e_y - (k bound - [no side]) e_z, in the optical frame.
            n_cam = np.array([k_x, k_y, 1.0 if not (k_x or k_y) else -(k_x + k_y) * bound])
            n_enu[k, :, 0, 0] = R_cam_enu.T @ n_cam
        # All five planes at once: (plane, block row, block column).
        n_x, n_y, n_z = n_enu[:, 0], n_enu[:, 1], n_enu[:, 2]
        top = (np.maximum(n_x * x_lo, n_x * x_hi) + np.maximum(n_y * y_lo, n_y * y_hi)
               + np.maximum(n_z * z_lo, n_z * z_hi))
        out = (top < 0).any(axis=0)
        # Nearest point of each box to the camera.
        near2 = (np.clip(0.0, x_lo, x_hi) ** 2 + np.clip(0.0, y_lo, y_hi) ** 2
                 + np.clip(0.0, z_lo, z_hi) ** 2)
        out |= near2 > range_m**2
        rows, cols = np.nonzero(~out)
        if len(rows) == 0:
            return None
        r0, r1, c0, c1 = window
        return (max(r0, (b_r0 + int(rows.min())) * BLOCK),
                min(r1, (b_r0 + int(rows.max()) + 1) * BLOCK),
                max(c0, (b_c0 + int(cols.min())) * BLOCK),
                min(c1, (b_c0 + int(cols.max()) + 1) * BLOCK))

    def _window_between(self, rays: BorderRaysEnu, range_m: float,
                        z_range_m: tuple[float, float],
                        within: tuple[int, int, int, int] | None = None
                        ) -> tuple[tuple[int, int, int, int] | None, bool]:
        """The window of the footprints of ``rays`` on the ground planes through the lowest
        and the highest height of ``z_range_m``, inside ``within``, and whether the picture
        reaches beyond ``range_m``; all within range when the camera is not above the
        highest."""
        z_lo, z_hi = z_range_m
        lo, clipped = rays.extent_enu(range_m, z_lo)
        extents = [lo]
        if z_hi > z_lo:
            hi, clipped_hi = rays.extent_enu(range_m, z_hi)
            clipped = clipped or clipped_hi
            cx, cy = (float(v) for v in rays.pose.r_cam_enu[:2])
            extents.append(hi if hi is not None else
                           (cx - range_m, cx + range_m, cy - range_m, cy + range_m))
        found = [e for e in extents if e is not None]
        if not found:
            return None, clipped
        g = self.geometry
        pad = 1.5 * g.cell_size_m + 0.01 * range_m
        box = np.array(found)  # (x_min, x_max, y_min, y_max) per plane
        row_lo, col_lo = g.cell_of(box[:, 0].min() - pad, box[:, 2].min() - pad)
        row_hi, col_hi = g.cell_of(box[:, 1].max() + pad, box[:, 3].max() + pad)
        w_r0, w_r1, w_c0, w_c1 = within or (0, g.n_rows, 0, g.n_cols)
        r0, r1 = max(int(row_lo), w_r0), min(int(row_hi) + 1, w_r1)
        c0, c1 = max(int(col_lo), w_c0), min(int(col_hi) + 1, w_c1)
        if r0 >= r1 or c0 >= c1:
            return None, clipped
        return (r0, r1, c0, c1), clipped
