"""The canopy scene: hills, a town block and a forest on a 200 x 200 m grid of 1 m cells, a
640 x 480 camera, a detector model with a smooth P_D(size), and a nadir and an oblique pose.

Everything is analytic in ENU metres (row 0 south, x east), so a test can say by hand where
things are:

* the ground (``ground_z_m``): a gentle tilt (4 cm/m eastwards), a long sinusoidal swell of
  3 m, a 22 m Gaussian hill north-west (HILL_ENU_M) and a steep 14 m knoll (KNOLL_ENU_M,
  north of the street between forest and town) whose back slope the oblique camera cannot
  see;
* the town (SOLID, ``BUILDINGS_ENU_M``): blocks A and B (12 m) with a 10 m street between
  them, and C (15 m) round a 16 x 36 m courtyard, across an 8 m street from A and B;
* the forest (FOLIAGE, ``forest_mask``): 18 m trees with irregular heights (16-21 m), a
  ragged west edge and a round clearing (CLEARING_ENU_M).

Heights of what stands on the ground are above each cell centre's ground (GroundCover's
convention); extinction k = EXTINCTION_PER_M, so straight down through 18 m of trees the
transmittance is exp(-0.08 x 18) = 0.24.
"""

from __future__ import annotations

import math

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.ground_cover import CoverKind, GroundCover
from pdcov.core.pose import CameraPose, FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.core.terrain import TerrainSurface

SIDE_M = 200.0
CELL_M = 1.0
GEOMETRY = GridGeometry(0.0, 0.0, CELL_M, int(SIDE_M / CELL_M), int(SIDE_M / CELL_M))

HILL_M, HILL_ENU_M, HILL_SIGMA_M = 22.0, (70.0, 178.0), 28.0
KNOLL_M, KNOLL_ENU_M, KNOLL_SIGMA_M = 14.0, (104.0, 128.0), 7.0

# (x_min, x_max, y_min, y_max, height_m) of each solid box; C's courtyard is cut out of it.
BUILDINGS_ENU_M = (
    (112.0, 140.0, 48.0, 70.0, 12.0),    # A
    (112.0, 140.0, 80.0, 112.0, 12.0),   # B, across a 10 m street from A
    (148.0, 184.0, 48.0, 112.0, 15.0),   # C, across an 8 m street from A and B
)
COURTYARD_ENU_M = (158.0, 174.0, 62.0, 98.0)
FOREST_ENU_M = (18.0, 96.0, 55.0, 135.0)  # x_min, x_max, y_min, y_max
FOREST_TOP_M = 18.0
CLEARING_ENU_M, CLEARING_RADIUS_M = (60.0, 100.0), 7.0
EXTINCTION_PER_M = 0.08

# Camera: 640 x 480, 70 deg across, mild barrel distortion (tests.support.scenarios').
CAMERA_SPEC = (640, 480, 70.0, "plumb_bob", (-0.05, 0.01, 0.0005, -0.0005, 0.0))
NADIR_XY_M, NADIR_HEIGHT_M = (100.0, 90.0), 90.0
OBLIQUE_XY_M, OBLIQUE_HEIGHT_M, OBLIQUE_OFF_NADIR_DEG = (100.0, 5.0), 60.0, 45.0


def ground_z_m(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """The scene's ground height (ENU z, m) at ENU x, y (m)."""
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    hill = HILL_M * np.exp(-((x - HILL_ENU_M[0]) ** 2 + (y - HILL_ENU_M[1]) ** 2)
                           / (2 * HILL_SIGMA_M**2))
    knoll = KNOLL_M * np.exp(-((x - KNOLL_ENU_M[0]) ** 2 + (y - KNOLL_ENU_M[1]) ** 2)
                             / (2 * KNOLL_SIGMA_M**2))
    swell = 3.0 * np.sin(2 * np.pi * x / 130.0) * np.cos(2 * np.pi * y / 170.0)
    return 0.04 * x + swell + hill + knoll


def cell_centres_m(geometry: GridGeometry = GEOMETRY) -> tuple[np.ndarray, np.ndarray]:
    """ENU x and y (m) of every cell centre, (n_rows, n_cols) each."""
    xs, ys = geometry.centres_enu()
    return np.meshgrid(xs, ys)


def buildings_mask(geometry: GridGeometry = GEOMETRY) -> tuple[np.ndarray, np.ndarray]:
    """Cells whose centre lies in a building, and their heights (m; 0 elsewhere)."""
    X, Y = cell_centres_m(geometry)
    height = np.zeros(geometry.shape)
    for x0, x1, y0, y1, h in BUILDINGS_ENU_M:
        height[(X > x0) & (X < x1) & (Y > y0) & (Y < y1)] = h
    cx0, cx1, cy0, cy1 = COURTYARD_ENU_M
    height[(X > cx0) & (X < cx1) & (Y > cy0) & (Y < cy1)] = 0.0
    return height > 0, height


def forest_mask(geometry: GridGeometry = GEOMETRY) -> np.ndarray:
    """Cells whose centre lies in the forest: FOREST_ENU_M with a west edge ragged by up to
    6 m, less the round clearing."""
    X, Y = cell_centres_m(geometry)
    x0, x1, y0, y1 = FOREST_ENU_M
    west = x0 + 3.0 * (1.0 + np.sin(Y / 4.0) * np.cos(Y / 11.0))
    inside = (X > west) & (X < x1) & (Y > y0) & (Y < y1)
    clearing = np.hypot(X - CLEARING_ENU_M[0], Y - CLEARING_ENU_M[1]) < CLEARING_RADIUS_M
    return inside & ~clearing


def forest_heights_m(geometry: GridGeometry = GEOMETRY) -> np.ndarray:
    """Tree heights (m) over every cell (where there are trees): 18 m, a smooth +-2 m
    undulation and +-1 m of cell-to-cell noise (a fixed seed)."""
    X, Y = cell_centres_m(geometry)
    smooth = 2.0 * np.sin(X / 9.0 + 1.0) * np.cos(Y / 13.0)
    noise = np.random.default_rng(21).uniform(-1.0, 1.0, geometry.shape)
    return FOREST_TOP_M + smooth + noise


def ground_cover(geometry: GridGeometry = GEOMETRY) -> GroundCover:
    """The town (SOLID) and the forest (FOLIAGE) on ``geometry``."""
    solid, h_building = buildings_mask(geometry)
    forest = forest_mask(geometry) & ~solid
    height = np.where(solid, h_building, np.where(forest, forest_heights_m(geometry), 0.0))
    kind = np.full(geometry.shape, CoverKind.OPEN, dtype=np.uint8)
    kind[forest] = CoverKind.FOLIAGE
    kind[solid] = CoverKind.SOLID
    return GroundCover(geometry, height, kind, EXTINCTION_PER_M, "canopy scene")


def terrain(geometry: GridGeometry = GEOMETRY, with_cover: bool = True) -> TerrainSurface:
    """The scene's ground at the cells' corners, with its cover (``with_cover``) or bare."""
    x = geometry.x0_m + geometry.cell_size_m * np.arange(geometry.n_cols + 1)
    y = geometry.y0_m + geometry.cell_size_m * np.arange(geometry.n_rows + 1)
    X, Y = np.meshgrid(x, y)
    return TerrainSurface(geometry, ground_z_m(X, Y), "canopy scene",
                          cover=ground_cover(geometry) if with_cover else None)


def camera() -> CameraModel:
    return CameraModel.from_fov(*CAMERA_SPEC)


def smooth_detector() -> DetectorModel:
    """A detector model whose P_D rises smoothly with size: 0.92 / (1 + exp(-(s - 4) /
    1.2)) at the centres of 390 bins of 0.1 px from 1 to 40 image pixels (no input
    scaling), so that P_D changes by at most 0.02 from one bin to the next and a small
    difference in a cell's size moves its P_D by as little. A 1 m cell seen from 90 m
    (5 px) has P_D 0.64, from 150 m (3 px) 0.28."""
    edges = np.round(np.arange(1.0, 40.0 + 1e-9, 0.1), 6)
    mid = 0.5 * (edges[:-1] + edges[1:])
    pd = 0.92 / (1.0 + np.exp(-(mid - 4.0) / 1.2))
    n = len(mid)
    return DetectorModel.from_dict({
        "version": 4, "input_size_px": None, "bin_edges_px": edges.tolist(),
        "p_detect": np.round(pd, 6).tolist(), "p_false_alarm": [0.05] * n,
        "fa_rate_per_mpx": [0.01] * n}, source="canopy scene smooth detector")


def nadir_pose() -> CameraPose:
    """Level, heading north, camera straight down NADIR_HEIGHT_M above the ground at
    NADIR_XY_M: it sees the forest's east half and blocks A and B and C's west part."""
    x, y = NADIR_XY_M
    z = float(ground_z_m(x, y)) + NADIR_HEIGHT_M
    return fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, 0.0), (x, y, z), FixedMount())


def oblique_pose() -> CameraPose:
    """Level, heading north, camera OBLIQUE_OFF_NADIR_DEG forward of nadir,
    OBLIQUE_HEIGHT_M above the ground at OBLIQUE_XY_M on the south edge: it looks across
    the forest and the town (the ground north of each building in its shadow) to the knoll
    and past it."""
    x, y = OBLIQUE_XY_M
    z = float(ground_z_m(x, y)) + OBLIQUE_HEIGHT_M
    mount = FixedMount(pitch_rad=math.radians(OBLIQUE_OFF_NADIR_DEG - 90.0))
    return fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, 0.0), (x, y, z), mount)
