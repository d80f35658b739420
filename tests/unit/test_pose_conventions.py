"""Frame conventions, each pinned with a case a person can check by hand."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pdcov.core.pose import (
    GIMBAL_FLAG_YAW_IN_EARTH_FRAME,
    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME,
    GIMBAL_FLAG_YAW_LOCK,
    CameraPose,
    FixedMount,
    GimbalFrame,
    R_ned_gimbal_from_quat,
    camera_pose,
    fixed_mount_pose,
    gimbal_frame_from_flags,
)
from pdcov.core.rotations import (
    R_from_euler_zyx,
    angle_between_R,
    euler_zyx_from_R,
    quat_wxyz_from_R,
)

EAST, NORTH, UP = np.eye(3)
DEG = np.pi / 180


def nadir_pose(yaw_deg: float, r=(0.0, 0.0, 10.0)) -> CameraPose:
    return fixed_mount_pose(R_from_euler_zyx(0, 0, yaw_deg * DEG), r, FixedMount())


def image_axes(pose: CameraPose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(image right, image up, optical axis) in ENU."""
    R = pose.R_enu_cam
    return R[:, 0], -R[:, 1], R[:, 2]


def test_level_nadir_heading_north():
    right, up, axis = image_axes(nadir_pose(0))
    np.testing.assert_allclose(axis, -UP, atol=1e-12)
    np.testing.assert_allclose(up, NORTH, atol=1e-12)
    np.testing.assert_allclose(right, EAST, atol=1e-12)


def test_level_nadir_heading_east():
    right, up, axis = image_axes(nadir_pose(90))
    np.testing.assert_allclose(axis, -UP, atol=1e-12)
    np.testing.assert_allclose(up, EAST, atol=1e-12)
    np.testing.assert_allclose(right, -NORTH, atol=1e-12)


def test_forward_camera_heading_north_looks_north():
    pose = fixed_mount_pose(R_from_euler_zyx(0, 0, 0), (0, 0, 10), FixedMount(pitch_rad=0.0))
    right, up, axis = image_axes(pose)
    np.testing.assert_allclose(axis, NORTH, atol=1e-12)
    np.testing.assert_allclose(up, UP, atol=1e-12)
    np.testing.assert_allclose(right, EAST, atol=1e-12)


def test_camera_pitched_down_45_looks_ahead_and_down():
    pose = fixed_mount_pose(R_from_euler_zyx(0, 0, 0), (0, 0, 10),
                            FixedMount(pitch_rad=-45 * DEG))
    np.testing.assert_allclose(image_axes(pose)[2], (NORTH - UP) / np.sqrt(2), atol=1e-12)


def test_vehicle_nose_down_tilts_fixed_nadir_camera_backwards():
    # Nose down by 20 deg: a body-fixed nadir camera now looks 20 deg behind the vehicle.
    pose = fixed_mount_pose(R_from_euler_zyx(0, -20 * DEG, 0), (0, 0, 10), FixedMount())
    axis = image_axes(pose)[2]
    np.testing.assert_allclose(axis, [0, -np.sin(20 * DEG), -np.cos(20 * DEG)], atol=1e-12)


def test_vehicle_roll_right_tilts_nadir_camera_left():
    # Right wing down (roll +): the body's down axis swings to the left (west when heading N).
    pose = fixed_mount_pose(R_from_euler_zyx(10 * DEG, 0, 0), (0, 0, 10), FixedMount())
    axis = image_axes(pose)[2]
    assert axis[0] < -0.17 and abs(axis[1]) < 1e-12


def test_lever_arm_forward_of_vehicle_heading_east():
    mount = FixedMount(lever_arm_frd_m=(0.5, 0.0, 0.2))
    pose = fixed_mount_pose(R_from_euler_zyx(0, 0, 90 * DEG), (10, 20, 30), mount)
    np.testing.assert_allclose(pose.r_cam_enu, [10.5, 20, 29.8], atol=1e-12)


def test_gimbal_flag_frames():
    assert gimbal_frame_from_flags(GIMBAL_FLAG_YAW_IN_EARTH_FRAME) is GimbalFrame.EARTH
    assert gimbal_frame_from_flags(GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME) is GimbalFrame.VEHICLE
    assert gimbal_frame_from_flags(GIMBAL_FLAG_YAW_LOCK) is GimbalFrame.EARTH
    assert gimbal_frame_from_flags(0) is GimbalFrame.VEHICLE
    # ArduPilot's servo mount flags from the real log (roll+pitch lock, yaw in vehicle frame).
    assert gimbal_frame_from_flags(44) is GimbalFrame.VEHICLE


def test_gimbal_yaw_in_vehicle_frame_follows_heading_but_not_attitude():
    # Gimbal looking forward and 30 deg down relative to the heading; vehicle heading east,
    # pitched nose-down 10 deg: the camera still looks east and 30 deg below the horizon.
    q = quat_wxyz_from_R(R_from_euler_zyx(0, -30 * DEG, 0))
    R_ned_body = R_from_euler_zyx(0, -10 * DEG, 90 * DEG)
    R_ned_gimbal = R_ned_gimbal_from_quat(q, GimbalFrame.VEHICLE, R_ned_body)
    axis = camera_pose(R_ned_body, (0, 0, 10), R_ned_gimbal).optical_axis_enu
    np.testing.assert_allclose(axis, [np.cos(30 * DEG), 0, -np.sin(30 * DEG)], atol=1e-12)


def test_gimbal_yaw_in_earth_frame_ignores_heading():
    q = quat_wxyz_from_R(R_from_euler_zyx(0, -30 * DEG, 0))  # north and down 30 deg
    R_ned_body = R_from_euler_zyx(0.1, -0.2, 2.0)
    R_ned_gimbal = R_ned_gimbal_from_quat(q, GimbalFrame.EARTH, R_ned_body)
    axis = camera_pose(R_ned_body, (0, 0, 10), R_ned_gimbal).optical_axis_enu
    np.testing.assert_allclose(axis, [0, np.cos(30 * DEG), -np.sin(30 * DEG)], atol=1e-12)


def test_gimbal_body_frame_composes_with_full_attitude():
    q = quat_wxyz_from_R(R_from_euler_zyx(0, -70 * DEG, 0))
    R_ned_body = R_from_euler_zyx(0, -20 * DEG, 0)  # nose down 20 deg
    R_ned_gimbal = R_ned_gimbal_from_quat(q, GimbalFrame.BODY, R_ned_body)
    axis = camera_pose(R_ned_body, (0, 0, 10), R_ned_gimbal).optical_axis_enu
    np.testing.assert_allclose(axis, -UP, atol=1e-12)  # -70 body + -20 vehicle = nadir


def test_camera_pose_rejects_non_rotation():
    with pytest.raises(ValueError):
        CameraPose(np.diag([1.0, 1.0, -1.0]), (0, 0, 1))
    with pytest.raises(ValueError):
        CameraPose(np.eye(3), (0, np.nan, 1))


angles = st.floats(-np.pi, np.pi, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(angles, st.floats(-1.5, 1.5), angles)
def test_euler_round_trip(roll, pitch, yaw):
    R = R_from_euler_zyx(roll, pitch, yaw)
    assert angle_between_R(R_from_euler_zyx(*euler_zyx_from_R(R)), R) < 1e-9


@settings(max_examples=200, deadline=None)
@given(angles, st.floats(-1.5, 1.5), angles, angles, st.floats(-1.5, 1.5), angles)
def test_quaternion_pose_round_trip(r1, p1, y1, r2, p2, y2):
    R_ned_body = R_from_euler_zyx(r1, p1, y1)
    mount = FixedMount(r2, p2, y2, (0.1, -0.2, 0.3))
    pose = fixed_mount_pose(R_ned_body, (1, 2, 3), mount)
    again = CameraPose.from_quat(pose.q_enu_cam_wxyz, pose.r_cam_enu)
    assert angle_between_R(again.R_enu_cam, pose.R_enu_cam) < 1e-9
    # The same gimbal attitude given in the three frames gives the same camera.
    R_ned_gimbal = R_ned_body @ mount.R_body_gimbal
    q_body = quat_wxyz_from_R(mount.R_body_gimbal)
    q_earth = quat_wxyz_from_R(R_ned_gimbal)
    for q, frame in ((q_body, GimbalFrame.BODY), (q_earth, GimbalFrame.EARTH)):
        got = R_ned_gimbal_from_quat(q, frame, R_ned_body)
        assert angle_between_R(got, R_ned_gimbal) < 1e-9
