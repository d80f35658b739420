"""Correlated looks end to end, in memory: the simulator's detector (pdcov_sitl/detector.py)
draws each person's latent detectability from the model's looks section; a lawnmower flown
by pdcov's planner and kinematic model looks at every person many times. The share of
people found matches the correlated grid's prediction at their cells (a Poisson-binomial
z-score within 3) and falls well short of the independent grid's (the paper's product
over-predicts)."""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import box

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.detector_sections import LooksModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.core.pose import FixedMount
from pdcov.planning.patterns import lawnmower
from pdcov.planning.trajectory import camera_poses, fly
from pdcov_sitl.detector import DetectorOptions, SimulatedDetector
from pdcov_sitl.targets import place_targets

CAMERA = CameraModel.from_fov(640, 480, 67.4)
DOMAIN = Domain.from_enu([[0, 0], [40, 0], [40, 40], [0, 40]])
DETECTOR = DetectorModel((4.0, 16.0, 32.0, 64.0, 400.0), (0.15, 0.3, 0.4, 0.35),
                         (0.0, 0.0, 0.0, 0.0), input_size_px=640, confidence_threshold=0.5,
                         looks=LooksModel((0.5, 0.4, 0.3, 0.4)))
PEOPLE = 1500


def grid(rule: LooksRule) -> CoverageGrid:
    g = DOMAIN.grid_geometry(1.0)
    return CoverageGrid(g, DOMAIN.free_mask(g), CAMERA, DETECTOR, looks=LooksConfig(rule))


def z_score(found: np.ndarray, p: np.ndarray) -> float:
    return float((found.sum() - p.sum()) / math.sqrt((p * (1 - p)).sum()))


def test_found_share_matches_correlated_and_not_independent_prediction():
    people = place_targets(PEOPLE, DOMAIN, None, seed=5)
    det = SimulatedDetector(grid(LooksRule.INDEPENDENT), people, DetectorOptions(), 11)
    assert det.person_q is not None
    plan = lawnmower(box(0, 0, 40, 40), 6.0, 0.0, 12.0, 4.0)
    poses = camera_poses(fly(plan, 3.0), FixedMount(pitch_rad=-math.pi / 2))
    correlated, independent = grid(LooksRule.CORRELATED), grid(LooksRule.INDEPENDENT)
    found = np.zeros(PEOPLE, dtype=bool)
    for pose in poses:
        for d in det.frame(pose, pose.t_s):
            found[d.person_id] = True
        correlated.update(pose)
        independent.update(pose)
    rows, cols = DOMAIN.grid_geometry(1.0).cell_of(people.r_enu_m[:, 0], people.r_enu_m[:, 1])
    looks = correlated.n_obs[rows, cols]
    assert np.median(looks) >= 15  # many looks at everyone: where correlation tells
    p_corr = correlated.pd[rows, cols]
    p_ind = independent.pd[rows, cols]
    z_corr, z_ind = z_score(found, p_corr), z_score(found, p_ind)
    assert abs(z_corr) < 3, (found.mean(), p_corr.mean(), z_corr)
    assert z_ind < -6, (found.mean(), p_ind.mean(), z_ind)
    assert p_ind.mean() - found.mean() > 0.03
    print(f"found {found.mean():.3f}, correlated {p_corr.mean():.3f} (z {z_corr:+.2f}), "
          f"independent {p_ind.mean():.3f} (z {z_ind:+.2f}), median looks {np.median(looks)}")
