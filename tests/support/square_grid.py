"""A square coverage grid and nadir poses over it, for the tests of the grid's update."""

import math

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import Domain
from pdcov.core.grid import CoverageGrid
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx

DEG = math.pi / 180
PINHOLE = CameraModel(640, 480, np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]))
DETECTOR = DetectorModel.from_dict({"version": 4, "bin_edges_px": [1, 20, 40, 80, 2000],
                                    "p_detect": [0.1, 0.4, 0.6, 0.3],
                                    "p_false_alarm": [0.05, 0.1, 0.2, 0.3],
                                    "fa_rate_per_mpx": [20.0, 40.0, 80.0, 120.0],
                                    "input_size_px": None})


def square_grid(half_m=40.0, cell_m=1.0, camera=PINHOLE, **kw):
    dom = Domain.from_enu([[-half_m, -half_m], [half_m, -half_m], [half_m, half_m],
                           [-half_m, half_m]])
    g = dom.grid_geometry(cell_m)
    return CoverageGrid(g, dom.free_mask(g), camera, DETECTOR, **kw)


def pose(roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, xyz=(0.0, 0.0, 10.0), cam_pitch_deg=-90.0,
         t_s=float("nan")):
    return fixed_mount_pose(R_from_euler_zyx(roll_deg * DEG, pitch_deg * DEG, yaw_deg * DEG),
                            xyz, FixedMount(pitch_rad=cam_pitch_deg * DEG), t_s)
