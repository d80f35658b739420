"""A plan flown kinematically: timed vehicle states and camera poses at the frame rate.

The model of a multicopter in an auto mission (a planning prediction, not a simulator):

* straight legs at each waypoint's speed, starting and ending at rest;
* at a corner without hover the path is rounded by a circular arc tangent to both legs
  that starts at most ``corner_cut_m`` before the waypoint (the autopilot's waypoint radius,
  ArduPilot WPNAV_RADIUS / PX4 NAV_ACC_RAD) and within half of each leg, and whose radius
  is at most v^2 / a (what the leg speed needs); the speed on the arc is sqrt(a * radius),
  so a sharp corner slows the vehicle and a reversal (a U-turn at a point) stops it;
* a waypoint with a hover time is reached exactly, at rest and level, and held, turning
  towards the next leg meanwhile;
* a gimbal holds the pointing its waypoint carries (``Plan.pointings``) from leaving the
  previous waypoint, as the mission's gimbal items command it (the slew is not modelled),
  and the camera its zoom likewise (``Plan.zooms_hfov_deg``, optimise.flight_cameras);
* speed changes at most ``max_accel_mps2`` along the path, heading (the direction of travel,
  as with ArduPilot's WP_YAW_BEHAVIOR default) at most ``max_yaw_rate_rad_s``;
* with ``tilt``, the body tilts so that its thrust axis carries the acceleration (no drag).

Positions are ENU metres (z: the waypoints' ``z_enu_m``, straight between them, so a
terrain-following plan is flown along its profile), times seconds from the start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.core.mount import GimbalMount
from pdcov.core.pose import (
    CameraPose,
    FixedMount,
    camera_motion,
    camera_pose,
    fixed_mount_pose,
    heading_rad,
    known_motion,
)
from pdcov.core.rotations import R_from_euler_zyx, Rz
from pdcov.planning.plan import GimbalPointing, Plan

G_MPS2 = 9.80665
RATE_STEP_S = 1e-3  # the step of the difference that gives each pose's velocity and rate
_STEP_M = 0.1
_ARC_STEP_RAD = math.radians(3.0)


@dataclass(frozen=True, slots=True)
class Kinematics:
    """Limits of the vehicle: acceleration along and across the path (m/s^2), heading rate
    (rad/s), whether the body tilts with the acceleration, how far before a waypoint a
    turn may begin (m), and the gimbal's slew rate per axis (rad/s)."""

    max_accel_mps2: float = 2.5
    max_yaw_rate_rad_s: float = math.radians(60.0)
    tilt: bool = True
    corner_cut_m: float = 2.0
    gimbal_rate_rad_s: float = math.radians(90.0)

    def __post_init__(self) -> None:
        if not (self.max_accel_mps2 > 0 and self.max_yaw_rate_rad_s > 0
                and self.corner_cut_m >= 0 and self.gimbal_rate_rad_s > 0):
            raise ValueError(f"kinematic limits must be positive, got {self}")


@dataclass(frozen=True, slots=True)
class Flight:
    """Vehicle states at the sample times.

    t_s (N,): seconds from the start. r_body_enu (N, 3): ENU metres. R_ned_body (N, 3, 3):
    attitude (FRD -> NED). speed_mps (N,). duration_s: time to fly the whole plan, including
    hovers. path_length_m: length of the flown (corner-rounded) path in 3-D.
    around: the states RATE_STEP_S / 2 before and after each sample (clipped to the
    flight), (t_s (2, N), r_body_enu (2, N, 3), R_ned_body (2, N, 3, 3)), from which
    ``camera_poses`` gives each pose its velocity and angular rate; None: unknown.
    waypoint_index (N,): the plan's waypoint each sample flies towards, rounds or holds at
    (where the gimbal pointing it carries is in force); None: unknown.
    """

    t_s: np.ndarray
    r_body_enu: np.ndarray
    R_ned_body: np.ndarray
    speed_mps: np.ndarray
    duration_s: float
    path_length_m: float
    around: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    waypoint_index: np.ndarray | None = None


def _path_samples(plan: Plan, a: float, cut_m: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Dense samples of the rounded path: points (K, 3), speed limit (K,), hover time (K,),
    signed curvature (K,) (positive turning left), waypoint index (K,: the waypoint a
    sample flies towards, rounds or holds at)."""
    P = plan.xyz_enu_m
    n = len(P)
    # Per corner: tangent distance d, radius, turn sign, corner speed limit.
    d = np.zeros(n)
    radius = np.zeros(n)
    turn = np.zeros(n)
    v_corner = np.full(n, np.inf)
    for i in range(1, n - 1):
        u_in, u_out = P[i, :2] - P[i - 1, :2], P[i + 1, :2] - P[i, :2]
        l_in, l_out = float(np.linalg.norm(u_in)), float(np.linalg.norm(u_out))
        if plan.waypoints[i].hover_s > 0 or l_in < 1e-9 or l_out < 1e-9:
            v_corner[i] = 0.0 if plan.waypoints[i].hover_s > 0 else v_corner[i]
            continue
        u_in, u_out = u_in / l_in, u_out / l_out
        cross = u_in[0] * u_out[1] - u_in[1] * u_out[0]
        delta = math.atan2(abs(cross), float(u_in @ u_out))
        if delta < 1e-6:
            continue
        v = min(plan.waypoints[i].speed_mps, plan.waypoints[i + 1].speed_mps)
        tan_half = math.tan(delta / 2)
        d_cap = min(0.5 * min(l_in, l_out), cut_m)
        rho = min(v * v / a, d_cap / tan_half)
        if rho < 1e-3:
            v_corner[i] = 0.0
            continue
        d[i], radius[i], turn[i] = rho * tan_half, rho, math.copysign(1.0, cross)
        v_corner[i] = math.sqrt(a * rho)
    v_corner[0] = v_corner[-1] = 0.0

    pts: list[np.ndarray] = [P[0]]
    vlim: list[float] = [0.0]
    hover: list[float] = [plan.waypoints[0].hover_s]
    kappa: list[float] = [0.0]
    wp: list[int] = [0]
    for i in range(n - 1):
        u = P[i + 1, :2] - P[i, :2]
        lh = np.linalg.norm(u)
        u = u / lh if lh > 1e-9 else np.zeros(2)
        start = np.concatenate([P[i, :2] + d[i] * u, P[i, 2:]])
        end = np.concatenate([P[i + 1, :2] - d[i + 1] * u, P[i + 1, 2:]])
        speed = plan.waypoints[i + 1].speed_mps
        m = max(1, math.ceil(np.linalg.norm(end - start) / _STEP_M))
        f = np.linspace(0.0, 1.0, m + 1)[1:]
        pts.extend(start + f[:, None] * (end - start))
        vlim.extend([speed] * m)
        hover.extend([0.0] * m)
        kappa.extend([0.0] * m)
        wp.extend([i + 1] * m)
        j = i + 1
        if radius[j] > 0:
            u_out = P[j + 1, :2] - P[j, :2]
            u_out /= np.linalg.norm(u_out)
            normal = turn[j] * np.array([-u[1], u[0]])  # towards the centre of the turn
            centre = end[:2] + radius[j] * normal
            a0 = math.atan2(end[1] - centre[1], end[0] - centre[0])
            sweep = math.acos(float(np.clip(u @ u_out, -1.0, 1.0)))
            k = max(2, math.ceil(sweep / _ARC_STEP_RAD))
            ang = a0 + turn[j] * sweep * np.arange(1, k + 1) / k
            arc = centre + radius[j] * np.column_stack([np.cos(ang), np.sin(ang)])
            pts.extend(np.column_stack([arc, np.full(k, P[j, 2])]))
            vlim.extend([min(speed, v_corner[j])] * k)
            hover.extend([0.0] * k)
            kappa.extend([turn[j] / radius[j]] * k)
            wp.extend([j] * k)
        else:
            vlim[-1] = min(vlim[-1], v_corner[j])
            hover[-1] = plan.waypoints[j].hover_s
    return np.array(pts), np.array(vlim), np.array(hover), np.array(kappa), np.array(wp)


def fly(plan: Plan, rate_hz: float, kinematics: Kinematics = Kinematics()) -> Flight:
    """The vehicle states at ``rate_hz`` (the camera frame rate) while flying ``plan``."""
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    a = kinematics.max_accel_mps2
    pts, vlim, hover, kappa, wp = _path_samples(plan, a, kinematics.corner_cut_m)
    ds = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    v = vlim.copy()
    for k in range(1, len(v)):
        v[k] = min(v[k], math.sqrt(v[k - 1] ** 2 + 2 * a * ds[k - 1]))
    for k in range(len(v) - 2, -1, -1):
        v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + 2 * a * ds[k]))
    dxy = np.diff(pts[:, :2], axis=0)
    moving = np.linalg.norm(dxy, axis=1) > 1e-9
    seg_heading = np.arctan2(dxy[:, 0], dxy[:, 1])  # bearing, clockwise from north
    # Heading at a sample: of the segment ending there; held where the vehicle stands still.
    heading = np.zeros(len(pts))
    last = float(seg_heading[moving][0]) if moving.any() else 0.0
    heading[0] = last
    for k in range(1, len(pts)):
        if moving[k - 1]:
            last = float(seg_heading[k - 1])
        heading[k] = last
    heading = np.unwrap(heading)
    v_mid = 0.5 * (v[1:] + v[:-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(ds > 0, ds / np.maximum(v_mid, 1e-9), 0.0)
    # Turning takes |dpsi| / rate; on a hover the vehicle turns towards the next leg while
    # it holds (as the simulator's guidance, pdcov_sitl/guidance.py), the rest of the turn
    # on the way.
    rate = kinematics.max_yaw_rate_rad_s
    dpsi = np.diff(heading)
    turn_in_hover_s = np.minimum(np.abs(dpsi) / rate, hover[:-1])
    dt = np.maximum(dt, np.abs(dpsi) / rate - turn_in_hover_s)
    t_arrive = np.concatenate([[0.0], np.cumsum(dt)])
    # Hover: the sample is reached at t_arrive (+ earlier hovers) and left after hover_s.
    hover_before = np.concatenate([[0.0], np.cumsum(hover)[:-1]])
    t_in = t_arrive + hover_before
    t_out = t_in + hover
    knots_t = np.column_stack([t_in, t_out]).ravel()
    duration = float(knots_t[-1])
    t = np.arange(0.0, duration + 1e-9, 1.0 / rate_hz)
    with np.errstate(divide="ignore", invalid="ignore"):
        a_seg = np.where(ds > 0, (v[1:] ** 2 - v[:-1] ** 2) / (2 * ds), 0.0)
    # At rest on a hover the vehicle is level: no acceleration from reaching to leaving it
    # (the arriving segment's braking would otherwise tilt it for the whole hover).
    a_knots = np.repeat(np.concatenate([a_seg[:1], a_seg]), 2)
    a_knots.reshape(-1, 2)[hover > 0] = 0.0
    # Heading knots per sample: reached, turned during the hover, left.
    turned = heading + np.concatenate([np.sign(dpsi) * rate * turn_in_hover_s, [0.0]])
    t_turned = t_in + np.concatenate([turn_in_hover_s, [0.0]])
    psi_t = np.column_stack([t_in, t_turned, t_out]).ravel()
    psi_v = np.column_stack([heading, turned, turned]).ravel()

    def states(tq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, attitude and speed at the times ``tq``."""
        def interp(values: np.ndarray) -> np.ndarray:
            return np.interp(tq, knots_t, np.repeat(values, 2))

        r = np.column_stack([interp(pts[:, i]) for i in range(3)])
        speed = interp(v)
        R = _attitudes(np.interp(tq, psi_t, psi_v), np.interp(tq, knots_t, a_knots),
                       speed ** 2 * interp(kappa), kinematics.tilt)
        return r, R, speed

    r, R, speed = states(t)
    t_pm = np.stack([np.maximum(t - 0.5 * RATE_STEP_S, 0.0),
                     np.minimum(t + 0.5 * RATE_STEP_S, duration)])
    (r_m, R_m, _), (r_p, R_p, _) = states(t_pm[0]), states(t_pm[1])
    # At a sample while t_in <= t <= t_out, else on the way to the next sample.
    at = np.clip(np.searchsorted(t_in, t, side="right") - 1, 0, len(pts) - 1)
    ahead = np.where(t <= t_out[at] + 1e-9, wp[at], wp[np.minimum(at + 1, len(pts) - 1)])
    return Flight(t, r, R, speed, duration, float(ds.sum()),
                  (t_pm, np.stack([r_m, r_p]), np.stack([R_m, R_p])), ahead)


def _attitudes(yaw_rad: np.ndarray, a_along_mps2: np.ndarray, a_left_mps2: np.ndarray,
               tilt: bool) -> np.ndarray:
    """R_ned_body (N, 3, 3): yaw = the direction of travel; with ``tilt`` the body's -z axis
    along the specific force (acceleration minus gravity)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    if not tilt:
        R = np.zeros((len(c), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        return R
    fwd = np.column_stack([c, s, np.zeros_like(c)])  # NED
    left = np.column_stack([s, -c, np.zeros_like(c)])  # NED
    acc = a_along_mps2[:, None] * fwd + a_left_mps2[:, None] * left
    z_b = np.column_stack([-acc[:, 0], -acc[:, 1], np.full(len(c), G_MPS2)])
    z_b /= np.linalg.norm(z_b, axis=1, keepdims=True)
    x_b = fwd - np.sum(fwd * z_b, axis=1, keepdims=True) * z_b
    x_b /= np.linalg.norm(x_b, axis=1, keepdims=True)
    y_b = np.cross(z_b, x_b)
    return np.stack([x_b, y_b, z_b], axis=2)


def camera_poses(flight: Flight, mount: FixedMount | GimbalMount,
                 gimbal_pitch_rad: float = -math.pi / 2,
                 pointing: Sequence[GimbalPointing | None] | None = None,
                 gimbal_rate_rad_s: float | None = None) -> list[CameraPose]:
    """Camera poses along a flight, with their velocity and angular rate when the flight
    has its ``around`` states (core/pose.camera_motion over them). A fixed mount turns and
    tilts with the body; a gimbal holds zero roll against the horizon and, per sample, the
    ``pointing`` given (a sample's None, or no ``pointing``: ``gimbal_pitch_rad``, -pi/2
    nadir, with the yaw following the vehicle's heading), reached at most at
    ``gimbal_rate_rad_s`` per axis (``slewed``; None: at once)."""
    n = len(flight.t_s)
    aims = [p or GimbalPointing(gimbal_pitch_rad) for p in (pointing or [None] * n)]
    if isinstance(mount, GimbalMount) and gimbal_rate_rad_s is not None:
        aims = slewed(aims, flight, gimbal_rate_rad_s)
    poses = _poses(flight.t_s, flight.r_body_enu, flight.R_ned_body, mount, aims)
    if flight.around is None:
        return poses
    t_pm, r_pm, R_pm = flight.around
    ends = [_poses(t_pm[k], r_pm[k], R_pm[k], mount, aims) for k in (0, 1)]
    (R_a, r_a), (R_b, r_b) = ((np.array([p.R_enu_cam for p in end]),
                               np.array([p.r_cam_enu for p in end])) for end in ends)
    v, omega = camera_motion(R_a, r_a, R_b, r_b, t_pm[1] - t_pm[0])
    return [CameraPose(p.R_enu_cam, p.r_cam_enu, p.t_s, *known_motion(v_k, w_k))
            for p, v_k, w_k in zip(poses, v, omega, strict=True)]


def slewed(aims: Sequence[GimbalPointing], flight: Flight, rate_rad_s: float
           ) -> list[GimbalPointing]:
    """Per sample, where a gimbal commanded ``aims`` points when it slews at most
    ``rate_rad_s`` per axis from the first sample's aim: the pitch, and the yaw the short
    way round in the frame of the sample's aim (a change between a locked and a following
    yaw converts the gimbal's yaw with the vehicle's heading there). A sample whose aim is
    reached keeps it (the same object)."""
    out = [aims[0]]
    pitch, yaw, earth = aims[0].pitch_rad, aims[0].yaw_rad, aims[0].earth_yaw
    for k in range(1, len(aims)):
        aim = aims[k]
        if aim.earth_yaw != earth:
            h = heading_rad(flight.R_ned_body[k])
            yaw, earth = (yaw + h, True) if aim.earth_yaw else (yaw - h, False)
        step = rate_rad_s * float(flight.t_s[k] - flight.t_s[k - 1])
        d_pitch = aim.pitch_rad - pitch
        d_yaw = _turn_rad(yaw, aim.yaw_rad)
        if abs(d_pitch) <= step and abs(d_yaw) <= step:
            out.append(aim)
            pitch, yaw = aim.pitch_rad, aim.yaw_rad
        else:
            pitch += math.copysign(min(abs(d_pitch), step), d_pitch)
            yaw += math.copysign(min(abs(d_yaw), step), d_yaw)
            out.append(GimbalPointing(pitch, yaw, earth))
    return out


def _turn_rad(from_rad: float, to_rad: float) -> float:
    """The turn (rad, in [-pi, pi)) from one angle to another the short way round, of the
    angles taken in [-pi, pi) first, so that half a turn goes the same way whichever turn
    the angles are written in."""
    def wrap(a: float) -> float:
        return (a + math.pi) % (2 * math.pi) - math.pi
    return wrap(wrap(to_rad) - wrap(from_rad))


def slew_time_s(a: GimbalPointing | None, b: GimbalPointing | None, rate_rad_s: float
                ) -> float:
    """Time (s) a gimbal slewing at ``rate_rad_s`` per axis takes from pointing ``a`` to
    ``b`` (None: not known, 0 s): the larger axis' change, the yaw's the short way round
    when both are in one frame, else half a turn at most."""
    if a is None or b is None:
        return 0.0
    d_yaw = abs(_turn_rad(a.yaw_rad, b.yaw_rad)) if a.earth_yaw == b.earth_yaw else math.pi
    return max(abs(b.pitch_rad - a.pitch_rad), d_yaw) / rate_rad_s


def _poses(t_s: np.ndarray, r_body_enu: np.ndarray, R_ned_body: np.ndarray,
           mount: FixedMount | GimbalMount, aims: Sequence[GimbalPointing]
           ) -> list[CameraPose]:
    if isinstance(mount, FixedMount):
        return [fixed_mount_pose(R, r, mount, float(t))
                for t, r, R in zip(t_s, r_body_enu, R_ned_body, strict=True)]
    arm = np.asarray(mount.lever_arm_frd_m, dtype=float)
    tilt = {aim: R_from_euler_zyx(0.0, aim.pitch_rad, 0.0) for aim in set(aims)}
    return [camera_pose(R, r, Rz(aim.yaw_rad + (0.0 if aim.earth_yaw else heading_rad(R)))
                        @ tilt[aim], arm, float(t))
            for t, r, R, aim in zip(t_s, r_body_enu, R_ned_body, aims, strict=True)]


def flight_pointing(plan: Plan, flight: Flight) -> list[GimbalPointing | None]:
    """Per sample of ``flight`` (flown from ``plan``), the gimbal pointing the plan's
    mission commands there (``Plan.pointings`` at the sample's waypoint)."""
    if flight.waypoint_index is None:
        raise ValueError("the flight has no waypoint index (not flown by fly)")
    per_wp = plan.pointings()
    return [per_wp[int(k)] for k in flight.waypoint_index]
