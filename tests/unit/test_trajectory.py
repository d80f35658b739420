"""Kinematic flight of a plan: speeds, corners, hovers, attitude and camera poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.mount import GimbalMount
from pdcov.core.pose import FixedMount
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint
from pdcov.planning.trajectory import (
    G_MPS2,
    Flight,
    Kinematics,
    camera_poses,
    fly,
    slew_time_s,
    slewed,
)

KIN = Kinematics(max_accel_mps2=2.0, max_yaw_rate_rad_s=math.radians(90), tilt=True,
                 corner_cut_m=20.0)


def test_straight_leg_trapezoid_time_and_rate():
    # 100 m at 5 m/s with 2 m/s^2: 2.5 s to accelerate over 6.25 m, same to stop.
    plan = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 100, 10, 5)))
    f = fly(plan, 5.0, KIN)
    expected = 2 * 2.5 + (100 - 2 * 6.25) / 5
    assert f.duration_s == pytest.approx(expected, rel=2e-3)
    assert f.path_length_m == pytest.approx(100.0)
    assert np.allclose(np.diff(f.t_s), 0.2)
    assert f.speed_mps.max() == pytest.approx(5.0)
    assert np.allclose(f.r_body_enu[:, 0], 0.0) and np.allclose(f.r_body_enu[:, 2], 10.0)
    assert np.all(np.diff(f.r_body_enu[:, 1]) >= -1e-9)
    # Heading north: body x along NED north; pitched nose-down while accelerating.
    mid = len(f.t_s) // 2
    assert np.allclose(f.R_ned_body[mid], np.eye(3), atol=1e-6)
    assert f.R_ned_body[2][2, 0] > 0.1  # body x has a down component: nose down


def test_corner_is_rounded_and_slowed_but_reversal_stops():
    right_angle = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 50, 10, 5), Waypoint(50, 50, 10, 5)))
    f = fly(right_angle, 20.0, KIN)
    # The corner radius v^2/a = 12.5 m fits: full speed, the corner point is cut.
    d_corner = np.linalg.norm(f.r_body_enu[:, :2] - [0, 50], axis=1).min()
    assert d_corner == pytest.approx(12.5 * (math.sqrt(2) - 1), rel=0.02)
    assert f.path_length_m < 100.0
    # Lateral acceleration on the arc tilts the body towards the turn (right: east).
    i = np.argmin(np.linalg.norm(f.r_body_enu[:, :2] - [0, 50], axis=1))
    body_down_ned = f.R_ned_body[i][:, 2]
    tilt = math.degrees(math.acos(body_down_ned[2]))
    assert tilt == pytest.approx(math.degrees(math.atan2(2.0, G_MPS2)), abs=1.0)
    # With the turn starting at most 2 m before the corner: radius 2 m, sqrt(2 a) m/s.
    tight = fly(right_angle, 20.0, Kinematics(max_accel_mps2=2.0, corner_cut_m=2.0))
    d_tight = np.linalg.norm(tight.r_body_enu[:, :2] - [0, 50], axis=1)
    assert d_tight.min() == pytest.approx(2.0 * (math.sqrt(2) - 1), rel=0.02)
    assert tight.speed_mps[np.argmin(d_tight)] == pytest.approx(2.0, rel=0.01)
    reversal = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 50, 10, 5), Waypoint(0, 0, 10, 5)))
    g = fly(reversal, 20.0, KIN)
    assert np.linalg.norm(g.r_body_enu[:, :2] - [0, 50], axis=1).min() < 0.05
    # Two stop-to-stop legs plus the 180 deg yaw at the rate limit (which overlaps the last
    # and first few centimetres of creeping, hence the tolerance).
    turn_time = math.pi / KIN.max_yaw_rate_rad_s
    assert g.duration_s == pytest.approx(2 * (2 * 2.5 + (50 - 12.5) / 5) + turn_time, rel=0.02)
    assert g.duration_s > 2 * (2 * 2.5 + (50 - 12.5) / 5) + 0.8 * turn_time


def test_hover_holds_position_for_its_time():
    plan = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 20, 10, 5, hover_s=4.0),
                 Waypoint(0, 40, 10, 5)))
    f = fly(plan, 10.0, KIN)
    at = np.linalg.norm(f.r_body_enu[:, :2] - [0, 20], axis=1) < 1e-6
    assert (at.sum() - 1) * 0.1 == pytest.approx(4.0, abs=0.15)
    assert np.all(f.speed_mps[at] < 1e-9)
    # Level while it hovers (the body's z axis straight down), not tilted by the braking.
    assert np.allclose(f.R_ned_body[at][:, :, 2], [0, 0, 1], atol=1e-9)


def test_fixed_mount_follows_body_gimbal_holds_nadir():
    plan = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 50, 10, 5), Waypoint(50, 50, 10, 5)))
    f = fly(plan, 5.0, KIN)
    fixed = camera_poses(f, FixedMount())
    gimbal = camera_poses(f, GimbalMount())
    for pf, pg, R in zip(fixed, gimbal, f.R_ned_body, strict=True):
        down_body = np.array([R[1, 2], R[0, 2], -R[2, 2]])  # body z in ENU
        assert np.allclose(pf.optical_axis_enu, down_body, atol=1e-9)
        assert np.allclose(pg.optical_axis_enu, [0, 0, -1], atol=1e-9)
    # Level flight north: image up points along the heading (north), image right east.
    mid = len(gimbal) // 4
    assert np.allclose(gimbal[mid].R_enu_cam[:, 0], [1, 0, 0], atol=1e-6)
    assert np.allclose(-gimbal[mid].R_enu_cam[:, 1], [0, 1, 0], atol=1e-6)
    # Some fixed-mount frames are tilted during the turn and acceleration.
    assert max(math.degrees(math.acos(-p.optical_axis_enu[2])) for p in fixed) > 5.0
    assert [p.t_s for p in fixed] == list(f.t_s)


def test_gimbal_pitch_forward():
    plan = Plan((Waypoint(0, 0, 10, 5), Waypoint(0, 50, 10, 5)))
    f = fly(plan, 5.0, Kinematics(tilt=False))
    p = camera_poses(f, GimbalMount(), gimbal_pitch_rad=math.radians(-45))[3]
    assert np.allclose(p.optical_axis_enu, [0, math.sqrt(0.5), -math.sqrt(0.5)], atol=1e-9)


def _at_rest(n: int, dt_s: float, heading_deg: float = 0.0) -> Flight:
    h = math.radians(heading_deg)
    R = np.array([[[math.cos(h), -math.sin(h), 0.0], [math.sin(h), math.cos(h), 0.0],
                   [0.0, 0.0, 1.0]]] * n)
    return Flight(dt_s * np.arange(n), np.tile([0.0, 0.0, 10.0], (n, 1)), R, np.zeros(n),
                  dt_s * (n - 1), 0.0)


def test_gimbal_slews_at_its_rate_the_short_way_round():
    """From an earth yaw of 180 deg to -45 deg (= 315) at 90 deg/s, samples 0.1 s apart:
    9 deg per sample clockwise through 270 (135 deg, 1.5 s), the pitch from -45 to -60 deg
    reached after 0.2 s on the way; written as 225 deg or -135 deg, a half turn from 45 deg
    goes the same way."""
    south = GimbalPointing(math.radians(-45), math.pi, True)
    north_west = GimbalPointing(math.radians(-60), math.radians(-45), True)
    aims = slewed([south] + [north_west] * 20, _at_rest(21, 0.1), math.radians(90))
    yaw_deg = [math.degrees(a.yaw_rad) % 360 for a in aims]
    np.testing.assert_allclose(yaw_deg[:17], [180 + 9 * k for k in range(15)] + [315, 315],
                               atol=1e-9)
    assert [round(math.degrees(a.pitch_rad), 6) for a in aims[:4]] == [-45, -54, -60, -60]
    assert all(a is north_west for a in aims[16:])  # reached (to a rounding) at 1.5 s
    assert slew_time_s(south, north_west, math.radians(90)) == pytest.approx(1.5)
    for written in (225.0, -135.0):
        to = GimbalPointing(-math.pi / 4, math.radians(written), True)
        a = slewed([GimbalPointing(-math.pi / 4, math.radians(45), True), to],
                   _at_rest(2, 0.1), math.radians(90))
        assert math.degrees(a[1].yaw_rad) == pytest.approx(36.0)  # 45 - 9: anticlockwise


def test_a_following_yaw_turns_with_the_vehicle_and_a_lock_converts_at_the_heading():
    """A yaw following the vehicle (body frame) needs no slew while the vehicle turns; a
    change to a locked earth yaw starts from the gimbal's earth yaw at that heading."""
    follow = GimbalPointing(-math.pi / 4, 0.0, False)
    assert slewed([follow] * 5, _at_rest(5, 0.1, 90.0), 1.0) == [follow] * 5
    lock = GimbalPointing(-math.pi / 4, math.radians(100), True)
    a = slewed([follow, lock], _at_rest(2, 0.1, 90.0), math.radians(50))
    assert math.degrees(a[1].yaw_rad) == pytest.approx(95.0) and a[1].earth_yaw
