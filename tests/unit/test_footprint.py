"""Footprint polygon: clipping at the horizon and at the maximum range."""

import math

import numpy as np
import pytest

from pdcov.core.camera import CameraModel
from pdcov.core.footprint import (
    BorderRaysEnu,
    footprint_polygon,
    footprint_rings_enu,
    ground_range_m,
)
from pdcov.core.pose import FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx

CAM = CameraModel.from_fov(640, 480, 90)  # +-45 deg across, +-36.9 deg up-down


def looking_north(cam_pitch_deg: float, h: float = 10.0):
    return fixed_mount_pose(R_from_euler_zyx(0, 0, 0), (0, 0, h),
                            FixedMount(pitch_rad=math.radians(cam_pitch_deg)))


def test_rays_above_the_horizon_are_clipped_at_the_range_circle():
    pose = looking_north(-20)  # the top of the image is 17 deg above the horizon
    fp = footprint_polygon(CAM, pose, max_range_m=100.0)
    rho = ground_range_m(pose, 100.0)
    assert rho == pytest.approx(math.sqrt(100**2 - 10**2))
    pts = np.asarray(fp.exterior.coords)
    assert np.hypot(pts[:, 0], pts[:, 1]).max() <= rho + 1e-6
    assert pts[:, 1].max() == pytest.approx(rho, rel=1e-3)  # reaches the circle due north
    # The near edge: the bottom of the image, 20 + 36.87 deg below the horizon.
    assert pts[:, 1].min() == pytest.approx(10 / math.tan(math.radians(56.87)), rel=1e-3)


def test_range_shorter_than_the_near_edge_sees_nothing_and_camera_up_sees_nothing():
    assert footprint_polygon(CAM, looking_north(-90), max_range_m=9.0).is_empty
    assert footprint_polygon(CAM, looking_north(60), max_range_m=1000.0).is_empty


def test_range_clips_a_nadir_footprint_to_a_disk():
    fp = footprint_polygon(CAM, looking_north(-90), max_range_m=math.hypot(10, 5))
    # Rectangle 20 m x 15 m about the nadir point, cut by a 5 m disk: the disk itself.
    assert fp.area == pytest.approx(math.pi * 25, rel=2e-3)


@pytest.mark.parametrize(("pitch_deg", "yaw_deg", "range_m", "z_m"), [
    (-90, 0, 100.0, 0.0),     # nadir, within range: the closed form
    (-60, 30, 100.0, 4.0),    # tilted, a raised plane: the closed form
    (-60, 30, 14.0, 0.0),     # the far edge beyond the range: clipped, the ring
    (-20, 200, 100.0, -5.0),  # above the horizon: the ring
    (-90, 0, 5.0, 0.0),       # the range shorter than the height: nothing
    (-90, 0, 100.0, 12.0),    # the plane above the camera: nothing
])
def test_border_rays_extent_is_the_rings(pitch_deg, yaw_deg, range_m, z_m):
    """BorderRaysEnu.extent_enu: the extent of footprint_rings_enu's ring and its clipping,
    without the ring when no ray reaches the range circle."""
    pose = fixed_mount_pose(R_from_euler_zyx(0, 0, math.radians(yaw_deg)), (3.0, -2.0, 10.0),
                            FixedMount(pitch_rad=math.radians(pitch_deg)))
    found = footprint_rings_enu(CAM, pose, range_m, (z_m,))
    extent, clipped = BorderRaysEnu.of(CAM, pose).extent_enu(range_m, z_m)
    assert clipped == found.clipped
    ring = found.rings[0]
    if len(ring) == 0:
        assert extent is None
        return
    assert extent is not None
    np.testing.assert_allclose(extent, (ring[:, 0].min(), ring[:, 0].max(),
                                        ring[:, 1].min(), ring[:, 1].max()), rtol=0,
                               atol=1e-9)
