"""The clear-sight shortcut over terrain (core/occlusion.py ``sight_clear``): a cell whose line
of sight descends more steeply than any terrain on the way is never hidden and always faces
the camera, so skipping both tests for it changes nothing."""

import math

import numpy as np
import pytest

from pdcov.core import grid_view
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.free_cells import FreeCells
from pdcov.core.grid_camera import GridCamera
from pdcov.core.grid_view import GridView
from pdcov.core.occlusion import hidden_by_terrain, sight_clear
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.core.terrain import TerrainSurface

DOMAIN = Domain.from_enu([[-40, -40], [40, -40], [40, 40], [-40, 40]])
GEOMETRY = DOMAIN.grid_geometry(1.0)
X_CORNER, Y_CORNER = np.meshgrid(GEOMETRY.x0_m + np.arange(GEOMETRY.n_cols + 1),
                                 GEOMETRY.y0_m + np.arange(GEOMETRY.n_rows + 1))
WHOLE = (0, GEOMETRY.n_rows, 0, GEOMETRY.n_cols)
X_CENTRE = GEOMETRY.x0_m + np.arange(GEOMETRY.n_cols) + 0.5
WIDE = CameraModel.from_fov(1920, 1080, 100)
DETECTOR = DetectorModel.from_dict({"version": 4, "bin_edges_px": [2, 30, 3000],
                                    "p_detect": [0.3, 0.8], "p_false_alarm": [0.1, 0.2],
                                    "fa_rate_per_mpx": [10.0, 30.0], "input_size_px": None})
# A ridge 6 m high on x in [10, 12], rising and falling over one cell each side.
RIDGE = TerrainSurface(GEOMETRY, np.where((X_CORNER >= 10) & (X_CORNER <= 12), 6.0, 0.0))


def rough(seed):
    """Rolling ground (random waves) and a ridge: slopes from gentle to about 4 m/m."""
    rng = np.random.default_rng(seed)
    z = np.zeros(X_CORNER.shape)
    for amplitude, wavelength in zip(rng.uniform(1, 4, 4), rng.uniform(12, 40, 4),
                                     strict=True):
        heading = rng.uniform(0, 2 * math.pi)
        along = X_CORNER * math.cos(heading) + Y_CORNER * math.sin(heading)
        z += amplitude * np.sin(2 * math.pi * along / wavelength + rng.uniform(0, 6))
    z += 3.0 * np.exp(-(X_CORNER + Y_CORNER - rng.uniform(-20, 20)) ** 2 / 8.0)
    return TerrainSurface(GEOMETRY, z)


def faces_camera(terrain, r_cam):
    """Per cell (the whole grid), the facing test of GridView, written out: the camera on the
    upper side of the plane through the centre with the diagonals' normal."""
    z = terrain.z_corner_m
    cs = GEOMETRY.cell_size_m
    z00, z01, z10, z11 = z[:-1, :-1], z[:-1, 1:], z[1:, :-1], z[1:, 1:]
    n_x = (z10 - z01) - (z11 - z00)
    n_y = -(z11 - z00) - (z10 - z01)
    x = X_CENTRE[None, :]
    y = (GEOMETRY.y0_m + np.arange(GEOMETRY.n_rows) + 0.5)[:, None]
    zc = 0.25 * ((z00 + z11) + (z01 + z10))
    return n_x * (r_cam[0] - x) + n_y * (r_cam[1] - y) + 2 * cs * (r_cam[2] - zc) > 0


def test_the_ridge_by_hand():
    """The camera 12 m up at x = 0, the ridge's sides 6 m per metre: a cell is clear only
    within 12 / 6 = 2 m (ground distance) of the nadir point; the ridge, the ground it hides
    (x from 12 to 24 m) and the ground just visible over it (beyond 24 m) are all left to
    the exact tests, which find the shadow."""
    r_cam = np.array([0.0, 0.5, 12.0])
    z_c = RIDGE.centre_z_m(*WHOLE)
    clear = sight_clear(RIDGE, r_cam, WHOLE, z_c)
    row = int(GEOMETRY.cell_of(0.0, 0.5)[0])
    rho = np.hypot(X_CENTRE, 0.0)
    np.testing.assert_array_equal(clear[row], rho < 2.0 / (1 + 1e-6) - 1e-6)
    assert not clear[:, (X_CENTRE > 2) | (X_CENTRE < -2)].any()
    hidden = hidden_by_terrain(RIDGE, r_cam, X_CENTRE, np.full(X_CENTRE.shape, 0.5),
                               z_c[row])
    np.testing.assert_array_equal(X_CENTRE[hidden], np.arange(12.5, 24.0))


def test_gentle_slope_seen_from_above_is_clear_everywhere():
    """A plane rising 0.1 m per metre, the camera 30 m above the highest ground: every line
    of sight within the 80 m grid descends at least 30 / 57 > 0.1 m per metre."""
    terrain = TerrainSurface(GEOMETRY, 0.1 * (X_CORNER + 40.0))
    r_cam = np.array([0.0, 0.0, 38.0])
    assert sight_clear(terrain, r_cam, WHOLE, terrain.centre_z_m(*WHOLE)).all()
    # A window away from the nadir point judges the terrain between them too.
    window = (50, 70, 60, 75)
    assert sight_clear(terrain, r_cam, window, terrain.centre_z_m(*window)).all()


@pytest.mark.parametrize("seed", range(6))
def test_a_clear_cell_faces_the_camera_and_is_never_hidden(seed):
    terrain = rough(seed)
    rng = np.random.default_rng(seed + 100)
    checked = 0
    for _ in range(20):
        x, y = rng.uniform(-35, 35, 2)
        r_cam = np.array([x, y, float(terrain.height_m(x, y)) + rng.uniform(-2, 80)])
        # A window of 1-30 cells a side within 30 m of the nadir point.
        r0, c0 = (int(np.clip(v + 40 + rng.integers(-30, 15), 0, 60)) for v in (y, x))
        window = (r0, min(r0 + int(rng.integers(1, 31)), GEOMETRY.n_rows),
                  c0, min(c0 + int(rng.integers(1, 31)), GEOMETRY.n_cols))
        z_c = terrain.centre_z_m(*window)
        clear = sight_clear(terrain, r_cam, window, z_c)
        rows, cols = np.nonzero(clear)
        if not len(rows):
            continue
        checked += len(rows)
        faces = faces_camera(terrain, r_cam)[window[0]:window[1], window[2]:window[3]]
        assert faces[rows, cols].all()
        # Tested among all the window's cells, as the kernel tests them.
        x_c, y_c = np.meshgrid(GEOMETRY.x0_m + np.arange(window[2], window[3]) + 0.5,
                               GEOMETRY.y0_m + np.arange(window[0], window[1]) + 0.5)
        assert not hidden_by_terrain(terrain, r_cam, x_c, y_c, z_c)[clear].any()
    assert checked > 200


def _pose(xyz, pitch_deg, yaw_deg):
    return fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, math.radians(yaw_deg)), xyz,
                            FixedMount(pitch_rad=math.radians(pitch_deg)))


@pytest.mark.parametrize("terrain", [RIDGE, rough(7), rough(8),
                                     TerrainSurface(GEOMETRY, 0.2 * X_CORNER + 3.0)],
                         ids=["ridge", "rough-7", "rough-8", "gentle"])
def test_observe_area_with_the_shortcut_equals_testing_every_cell(terrain, monkeypatch):
    """Bit for bit: the observed cells, their areas and their limiting factors, with clear
    cells skipped, and with every cell tested (no cell clear)."""
    view = GridView(GEOMETRY, FreeCells(GEOMETRY, mask=DOMAIN.free_mask(GEOMETRY)), terrain)
    frame = GridCamera.build(WIDE, DETECTOR, GEOMETRY.cell_size_m, 80.0)
    poses = [_pose((0.0, 0.5, 12.0), -25.0, 90.0), _pose((-20.0, 5.0, 40.0), -90.0, 0.0),
             _pose((10.0, -10.0, 30.0), -50.0, 200.0), _pose((5.0, 5.0, 70.0), -70.0, 45.0)]
    got = []
    for p in poses:
        window, _ = view.window(frame, p)
        got.append((window, view.observe_area(frame, p, window)))
    monkeypatch.setattr(grid_view, "sight_clear",
                        lambda t, r, w, z: np.zeros(z.shape, dtype=bool))
    for p, (window, (observed, area, reach, _)) in zip(poses, got, strict=True):
        o2, a2, r2, _ = view.observe_area(frame, p, window)
        assert observed.sum() > 50
        np.testing.assert_array_equal(observed, o2)
        np.testing.assert_array_equal(area[observed], a2[o2])
        np.testing.assert_array_equal(reach, r2)
