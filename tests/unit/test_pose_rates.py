"""The camera's velocity and angular rate from PoseTracker (the derivative of the
interpolated pose, one rule for the daemon and evaluate): rigid-body hand checks."""

from __future__ import annotations

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.mount import GimbalMount
from pdcov.core.pose import GIMBAL_FLAG_YAW_IN_EARTH_FRAME, R_ENU_NED, FixedMount
from pdcov.core.rotations import R_from_euler_zyx_many, quat_wxyz_from_euler_zyx
from pdcov.telemetry.pose_tracker import PoseTracker
from tests.support.mavlink_fixtures import KnownFlight, samples_from_flight

ORIGIN = Origin(-35.363261, 149.165230, 584.0)
YAW_RATE = 0.4  # rad/s, clockwise from north
V_ENU = np.array([3.0, -1.0, 0.5])  # m/s
PITCH_RATE = -0.2  # rad/s, the gimbal tilting down


def flight(gimbal: bool) -> KnownFlight:
    t = 1.0 + np.arange(100) / 20.0
    yaw = 0.3 + YAW_RATE * (t - t[0])
    R = R_from_euler_zyx_many(np.zeros_like(t), np.zeros_like(t), yaw)
    r = np.array([2.0, 3.0, 20.0]) + (t - t[0])[:, None] * V_ENU
    q_g = flags = None
    if gimbal:  # earth frame, yaw 0 (north), pitch from -60 deg down at PITCH_RATE
        q_g = quat_wxyz_from_euler_zyx(np.zeros_like(t), np.radians(-60) + PITCH_RATE
                                       * (t - t[0]), np.zeros_like(t))
        flags = [GIMBAL_FLAG_YAW_IN_EARTH_FRAME] * len(t)
    return KnownFlight(ORIGIN, t, R, r, q_g, flags)


def tracker(f: KnownFlight, mount: object) -> PoseTracker:
    tr = PoseTracker(ORIGIN, mount)  # type: ignore[arg-type]
    for s in samples_from_flight(f, home=False):
        {"AttitudeSample": tr.add_attitude, "PositionSample": tr.add_position,
         "GimbalSample": tr.add_gimbal}[type(s).__name__](s)
    return tr


def test_fixed_mount_with_a_lever_arm_turning_and_flying():
    """omega = -yaw rate about ENU up; the camera 1 m ahead of the reference point moves
    with v + omega x (its offset in ENU), in the frame and at the samples too."""
    mount = FixedMount(lever_arm_frd_m=(1.0, 0.0, 0.0))
    f = flight(gimbal=False)
    t = np.array([1.5, 2.0, 2.512, 3.3])  # 2.0: on a sample
    b = tracker(f, mount).frames_at(t)
    assert b.valid.all()
    omega = np.array([0.0, 0.0, -YAW_RATE])
    np.testing.assert_allclose(b.omega_enu_rad_s, np.tile(omega, (4, 1)), atol=1e-6)
    lever_enu = np.einsum("ij,njk,k->ni", R_ENU_NED, b.R_ned_body, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(b.v_cam_enu_m_s, V_ENU + np.cross(omega, lever_enu),
                               atol=2e-3)  # positions in degE7-like float, ~mm


def test_earth_frame_gimbal_pitching_ignores_the_vehicle_yaw():
    """An earth-frame gimbal looking north and pitching: the camera turns about east only,
    whatever the vehicle's yaw rate."""
    f = flight(gimbal=True)
    b = tracker(f, GimbalMount(attitude_frame="flags")).frames_at(np.array([2.0, 3.125]))
    assert b.valid.all()
    # Pitch about the gimbal's right axis (NED east = ENU x): nose-down is negative pitch,
    # a rotation of PITCH_RATE about east.
    np.testing.assert_allclose(b.omega_enu_rad_s, [[PITCH_RATE, 0.0, 0.0]] * 2, atol=1e-6)
    np.testing.assert_allclose(b.v_cam_enu_m_s, [V_ENU] * 2, atol=2e-3)


def test_a_frame_at_a_streams_first_sample_has_unknown_motion():
    f = flight(gimbal=False)
    tr = tracker(f, FixedMount())
    b = tr.frames_at(np.array([f.t_s[0], f.t_s[1]]))
    assert b.valid.all()
    assert np.isnan(b.v_cam_enu_m_s[0]).all() and np.isnan(b.omega_enu_rad_s[0]).all()
    assert np.isfinite(b.v_cam_enu_m_s[1]).all()
    assert tr.pose_at(f.t_s[0]).pose.v_cam_enu_m_s is None  # type: ignore[union-attr]
    pose = tr.pose_at(f.t_s[1]).pose
    assert pose is not None and pose.has_motion
    assert pose.v_cam_enu_m_s == pytest.approx(V_ENU, abs=2e-3)
