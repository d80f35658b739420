"""The simulator's people under trees are found as the coverage grid predicts (issue 38,
"Done when"): per frame, each person's chance is the grid's P_D of their cell for that
frame alone (P_D(size) x the cell's transmittance); the people the simulated detector finds
over many frames agree with the sum of those chances within three binomial sigmas, under
the trees and in the open, and the trees cut the finds."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import CoverKind, GroundCover
from pdcov.core.pose import CameraPose
from pdcov.core.terrain import TerrainSurface
from pdcov_sitl.detector import FALSE_ALARM_ID, DetectorOptions, SimulatedDetector
from pdcov_sitl.targets import on_ground

CAMERA = CameraModel.from_fov(640, 480, 67.4)
DETECTOR = DetectorModel((1.0, 8.0, 16.0, 32.0, 1000.0), (0.3, 0.6, 0.85, 0.9),
                         (0.0,) * 4, (0.0,) * 4, input_size_px=640)
SIDE_M = 160
DOMAIN = Domain.from_enu([[0, 0], [SIDE_M, 0], [SIDE_M, SIDE_M], [0, SIDE_M]])
R_NADIR = np.diag([1.0, -1.0, -1.0])  # optical x east, y south, z down


def terrain() -> TerrainSurface:
    """Flat ground; trees 14 to 22 m tall (a smooth stand with per-cell roughness) over
    x in [40, 120) m, y in [40, 120) m, a 9 m house east of them."""
    g = DOMAIN.grid_geometry(1.0)
    rng = np.random.default_rng(38)
    y, x = np.mgrid[0:g.n_rows, 0:g.n_cols] + 0.5
    h = np.zeros(g.shape)
    kind = np.zeros(g.shape, np.uint8)
    trees = (x >= 40) & (x < 120) & (y >= 40) & (y < 120)
    stand = 18 + 3 * np.sin(x / 9) * np.cos(y / 11) + rng.uniform(-1, 1, g.shape)
    h[trees], kind[trees] = stand[trees], CoverKind.FOLIAGE
    house = (x >= 130) & (x < 142) & (y >= 70) & (y < 82)
    h[house], kind[house] = 9.0, CoverKind.SOLID
    return TerrainSurface(g, np.zeros((g.n_rows + 1, g.n_cols + 1)), "test",
                          cover=GroundCover(g, h, kind))


def poses() -> list[CameraPose]:
    """Over the forest and its edges, straight down and 35 deg off nadir, 40 and 60 m up."""
    out = []
    for x, y, z in ((80, 80, 60), (60, 70, 40), (100, 95, 40), (120, 60, 60), (45, 110, 50)):
        out.append(CameraPose(R_NADIR, np.array([x, y, z], float), 0.0))
        for azimuth_deg in (0.0, 120.0, 240.0):  # tilted about east, then turned
            tilt = Rotation.from_euler("xz", [35.0, azimuth_deg], degrees=True).as_matrix()
            out.append(CameraPose(tilt @ R_NADIR, np.array([x, y, z], float), 0.0))
    return out


def test_people_under_trees_are_found_as_predicted():
    ground = terrain()
    g = ground.geometry
    rng = np.random.default_rng(7)
    xy = rng.uniform(2, SIDE_M - 2, (3000, 2))
    people = on_ground(xy[:, 0], xy[:, 1], ground)
    row, col = (np.asarray(v) for v in g.cell_of(xy[:, 0], xy[:, 1]))
    assert ground.cover is not None
    under = ground.cover.kind[row, col] == CoverKind.FOLIAGE
    empty = CoverageGrid(g, DOMAIN.free_mask(g), CAMERA, DETECTOR, terrain=ground)
    sim = SimulatedDetector(empty, people, DetectorOptions(box_noise_px=0.0), seed=11)
    predicted = {True: [], False: []}
    found = {True: 0, False: 0}
    t_s = 0.0
    for pose in poses():
        for _ in range(6):  # every frame draws afresh: six draws per pose
            t_s += 1.0
            grid = CoverageGrid(g, DOMAIN.free_mask(g), CAMERA, DETECTOR, terrain=ground)
            grid.update(pose)
            p = grid.pd[row, col]
            ids = np.array([d.person_id for d in sim.frame(pose, t_s)
                            if d.person_id != FALSE_ALARM_ID], dtype=np.intp)
            for where in (True, False):
                predicted[where].append(p[under == where])
                found[where] += int(np.count_nonzero(under[ids] == where))
    rate = {}
    for where in (True, False):
        p = np.concatenate(predicted[where])
        mean, sigma = float(p.sum()), math.sqrt(float((p * (1 - p)).sum()))
        print(f"{'under trees' if where else 'in the open'}: found {found[where]}, predicted "
              f"{mean:.1f} +- {sigma:.1f} (3 sigma {3 * sigma:.1f})")
        assert abs(found[where] - mean) <= 3 * sigma
        rate[where] = found[where] / max(np.count_nonzero(p), 1)
    assert rate[True] < 0.6 * rate[False]  # the trees hide people
