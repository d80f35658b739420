"""Guidance as in AUTO mode: the reference trajectory (position, velocity, acceleration,
heading) the controller follows through a FlightPlan, computed once when the flight starts.

What it does, as ArduCopter's waypoint navigation (AC_WPNav with S-curves) does:

* **Pass-through corners.** At an intermediate waypoint without a hold time the path is
  rounded by a circular arc tangent to both legs that starts at most ``corner_cut_m``
  before the waypoint (WPNAV_RADIUS) and within half of each leg, and whose radius is at
  most v^2 / a; the speed on the arc is sqrt(a * radius) (lateral acceleration ``accel``),
  so a gentle corner is flown at the leg's speed and only a sharp one slows the vehicle.
  This is the corner model of pdcov's planner (planning/trajectory.py; the limits default
  to its ``Kinematics``), so both agree on what a corner costs.
* **Stops** only where the mission says: at the top of the take-off, at a waypoint with a
  hold time (held for it), at the last waypoint, after the return and on the ground.
* **Speed profile**: at most ``accel_mps2`` along the path (WPNAV_ACCEL), braking early
  enough for every corner and stop ahead (the look-ahead), climbing at most 2.5 m/s and
  descending at most 1.5 m/s (WPNAV_SPEED_UP/DN); then the whole 3-D reference is
  averaged twice over ``smooth_s`` (a moving box; a triangular window), which limits the
  jerk to about accel / smooth_s (S-curves; ~5 m/s^3 by default), keeps it continuous and
  leaves straight legs exact (corners move inwards by a few cm). A stop lasts 2 * smooth_s
  (1 s) longer than its hold, so that the reference rests exactly on its waypoint for it.
* **Acceleration feed-forward** leads the reference by ``accel_lead_s`` (0.2 s), the lag
  of the lean-angle shaping and the rate loop, so that the vehicle is tilted when the
  reference accelerates rather than after it (without it the velocity error that builds
  up overshoots the lean angle by ~8 deg at a stop).
* **Heading** towards the path's direction of travel (WP_YAW_BEHAVIOR 2), slewed at
  ``yaw_rate_rps``; held while climbing or descending vertically.
* **Terrain following** on legs flown above the terrain (``Leg.above_terrain``): the path's
  height is the leg's height above the terrain (linear from its start to its waypoint) plus
  the terrain under the path (``terrain.LocalGround``), before the speed profile, which then
  slows where the terrain makes the path climb faster than 2.5 m/s or sink faster than
  1.5 m/s. ArduCopter adds the terrain under the vehicle; the vehicle tracks the path within
  centimetres, so the two agree; the averaging smooths the terrain over ~2 s of travel.

Pure: no clock or I/O; ``setpoint(t_s)`` is a table look-up (the reference is sampled every
``REF_DT_S``). NED metres about home, simulated seconds.
"""

from __future__ import annotations

import math

import numpy as np

from pdcov.planning.trajectory import Kinematics

from .control import Setpoint
from .mission import FlightPlan, Leg
from .terrain import LocalGround

REF_DT_S = 0.02
PATH_STEP_M = 0.1
CLIMB_MAX_MPS = 2.5
DESCENT_MAX_MPS = 1.5
VERTICAL_ACCEL_MPS2 = 1.0
LAND_SETTLE_S = 1.0
_PLANNER = Kinematics()


def _unit(v: np.ndarray) -> tuple[np.ndarray, float]:
    n = float(np.linalg.norm(v))
    return (v / n if n > 1e-9 else np.zeros(3)), n


def _corner(a: Leg, b: Leg, accel: float, cut_m: float
            ) -> tuple[float, float, float] | None:
    """(tangent distance m, radius m, speed m/s) of the arc rounding the waypoint between
    legs a and b ((0, inf, speed) straight on), or None where the vehicle stops there."""
    if a.kind != "waypoint" or b.kind != "waypoint" or a.hover_s > 0:
        return None
    u_in, l_in = _unit(np.subtract(a.end_ned_m, a.start_ned_m))
    u_out, l_out = _unit(np.subtract(b.end_ned_m, b.start_ned_m))
    if l_in < 1e-6 or l_out < 1e-6:
        return None
    delta = math.acos(max(-1.0, min(1.0, float(u_in @ u_out))))
    v = min(a.speed_mps, b.speed_mps)
    if delta < 1e-6:
        return 0.0, math.inf, v
    tan_half = math.tan(delta / 2)
    radius = min(v * v / accel, min(0.5 * min(l_in, l_out), cut_m) / tan_half)
    if radius < 1e-3:
        return None  # a reversal: stop and turn back
    return radius * tan_half, radius, min(v, math.sqrt(accel * radius))


def _speed_limit(leg: Leg, u: np.ndarray) -> float:
    """The leg's speed, capped so that the climb or descent stays within its limits."""
    v = leg.speed_mps
    if u[2] < -1e-6:
        v = min(v, CLIMB_MAX_MPS / -u[2])
    elif u[2] > 1e-6:
        v = min(v, DESCENT_MAX_MPS / u[2])
    return v


def _sample_path(plan: FlightPlan, accel: float, cut_m: float, stop_s: float):
    """The rounded path every ~PATH_STEP_M: points (K, 3), unit tangents (K, 3), speed
    limit (K,), acceleration limit (K,), hold time at the sample (K,; stop_s more than the
    mission's at a stop), leg index (K,). Sample 0 is the start, at rest."""
    legs = plan.legs
    corners = [_corner(a, b, accel, cut_m) for a, b in zip(legs[:-1], legs[1:], strict=True)]
    pts, tan, vlim, alim, hold, leg_ix = [], [], [], [], [], []

    def add(p, t, v, a, k):
        pts.append(p)
        tan.append(t)
        vlim.append(v)
        alim.append(a)
        hold.append(0.0)
        leg_ix.append(k)

    u0, _ = _unit(np.subtract(legs[0].end_ned_m, legs[0].start_ned_m))
    add(np.asarray(legs[0].start_ned_m, float), u0, 0.0, VERTICAL_ACCEL_MPS2, 0)
    for k, leg in enumerate(legs):
        p0, p1 = np.asarray(leg.start_ned_m, float), np.asarray(leg.end_ned_m, float)
        u, length = _unit(p1 - p0)
        a_leg = accel if leg.kind in ("waypoint", "return") else VERTICAL_ACCEL_MPS2
        v_leg = _speed_limit(leg, u)
        into = corners[k - 1] if k > 0 else None
        d_in = into[0] if into is not None else 0.0
        out = corners[k] if k < len(corners) else None
        d_out = out[0] if out is not None else 0.0
        a, b = p0 + d_in * u, p1 - d_out * u
        straight = max(0.0, length - d_in - d_out)
        # At least its end: a leg of no length (a second hover at the same point, with
        # another gimbal pointing or zoom) keeps its own sample, hold and pointing.
        m = max(1, math.ceil(straight / PATH_STEP_M))
        for f in np.linspace(0.0, 1.0, m + 1)[1:]:
            add(a + f * (b - a), u, v_leg, a_leg, k)
        if out is not None and out[0] > 0:
            d, radius, v_c = out
            u_out, _ = _unit(np.subtract(legs[k + 1].end_ned_m, legs[k + 1].start_ned_m))
            n, _ = _unit(u_out - float(u @ u_out) * u)  # in the turn's plane, towards centre
            delta = math.acos(max(-1.0, min(1.0, float(u @ u_out))))
            centre = b + radius * n
            m = max(2, math.ceil(radius * delta / PATH_STEP_M))
            for phi in delta * np.arange(1, m + 1) / m:
                c, s = math.cos(phi), math.sin(phi)
                add(centre + radius * (s * u - c * n), c * u + s * n, min(v_leg, v_c), a_leg, k)
        elif out is None:
            vlim[-1] = 0.0
            hold[-1] += leg.hover_s + stop_s
    return (np.array(pts), np.array(tan), np.array(vlim), np.array(alim), np.array(hold),
            np.array(leg_ix))


def _follow_terrain(legs: tuple[Leg, ...], pts: np.ndarray, vlim: np.ndarray,
                    leg_ix: np.ndarray, ground: LocalGround) -> tuple[np.ndarray, np.ndarray]:
    """The path samples of legs flown above the terrain raised by the terrain under them,
    less the terrain along the leg's chord (the chord's ends already include theirs), and
    their speed limits lowered to keep the climb/descent rates. Other samples unchanged."""
    on = np.array([legs[int(k)].above_terrain for k in leg_ix])
    if not on.any():
        return pts, vlim
    pts, vlim = pts.copy(), vlim.copy()
    idx = np.flatnonzero(on)
    a = np.array([legs[int(k)].start_ned_m for k in leg_ix[idx]], float)
    b = np.array([legs[int(k)].end_ned_m for k in leg_ix[idx]], float)
    ab = b[:, :2] - a[:, :2]
    length2 = np.einsum("ij,ij->i", ab, ab)
    f = np.where(length2 > 1e-12,
                 np.einsum("ij,ij->i", pts[idx, :2] - a[:, :2], ab) / np.maximum(length2, 1e-12),
                 0.0).clip(0.0, 1.0)
    t_a = ground.height_m(a[:, 0], a[:, 1])
    t_b = ground.height_m(b[:, 0], b[:, 1])
    t_p = ground.height_m(pts[idx, 0], pts[idx, 1])
    offset = t_p - (t_a + f * (t_b - t_a))
    if not np.isfinite(offset).all():
        raise ValueError("the path leaves the DEM: no terrain height under part of it")
    pts[idx, 2] -= offset
    # Climb/descent along the path: dz/ds per sample from its neighbours.
    ds = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    dz = np.diff(pts[:, 2])
    slope = np.zeros(len(pts))
    slope[1:] = np.where(ds > 1e-9, dz / np.maximum(ds, 1e-9), 0.0)  # + down
    up, down = -slope[idx], slope[idx]
    cap = np.where(up > 1e-6, CLIMB_MAX_MPS / np.maximum(up, 1e-6),
                   np.where(down > 1e-6, DESCENT_MAX_MPS / np.maximum(down, 1e-6), np.inf))
    vlim[idx] = np.minimum(vlim[idx], cap)
    return pts, vlim


def _box(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n (odd) samples along axis 0, the ends held."""
    h = n // 2
    padded = np.concatenate([np.repeat(x[:1], h, axis=0), x, np.repeat(x[-1:], h, axis=0)])
    c = np.cumsum(np.concatenate([np.zeros_like(x[:1]), padded]), axis=0)
    return (c[n:] - c[:-n]) / n


class Guidance:
    """Setpoints along a FlightPlan, by simulated time (module docstring). Pure.

    ground: the terrain about home that legs flown above the terrain follow (None: level).

    ``setpoint(t_s)`` gives the Setpoint at t_s (non-decreasing times); ``leg`` is the leg
    in force, ``done`` True once landed and disarmed; ``reference_end_s`` when the
    reference reaches the ground.
    """

    def __init__(self, plan: FlightPlan, *, ground: LocalGround | None = None,
                 start_s: float = 1.0,
                 accel_mps2: float = _PLANNER.max_accel_mps2,
                 corner_cut_m: float = _PLANNER.corner_cut_m,
                 yaw_rate_rps: float = _PLANNER.max_yaw_rate_rad_s, smooth_s: float = 0.5,
                 heading_rad: float = 0.0, accel_lead_s: float = 0.2) -> None:
        self.plan = plan
        self.start_s = start_s
        # A stop lasts the averaging window longer than the mission's hold, so that the
        # reference rests exactly on the waypoint for the hold (as a copter settles there).
        pts, tan, vlim, alim, hold, leg_ix = _sample_path(plan, accel_mps2, corner_cut_m,
                                                          2 * smooth_s)
        if ground is not None:
            pts, vlim = _follow_terrain(plan.legs, pts, vlim, leg_ix, ground)
        ds = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        v = vlim.copy()
        v[0] = 0.0
        # Forward (accelerate) and backward (brake for what is ahead) passes.
        for k in range(1, len(v)):
            v[k] = min(v[k], math.sqrt(v[k - 1] ** 2 + 2 * alim[k] * ds[k - 1]))
        for k in range(len(v) - 2, -1, -1):
            v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + 2 * alim[k + 1] * ds[k]))
        v_mid = 0.5 * (v[1:] + v[:-1])
        dt = np.where(ds > 0, ds / np.maximum(v_mid, 1e-9), 0.0)
        hold_before = np.concatenate([[0.0], np.cumsum(hold)[:-1]])
        t_in = np.concatenate([[0.0], np.cumsum(dt)]) + hold_before
        knots_t = np.column_stack([t_in, t_in + hold]).ravel()
        n_box = 2 * int(round(smooth_s / REF_DT_S / 2)) + 1
        lead_s = (n_box - 1) * REF_DT_S  # rest before the move: the averages start at rest
        t = np.arange(0.0, knots_t[-1] + 2 * lead_s + REF_DT_S, REF_DT_S) - lead_s
        idx = np.interp(t, knots_t, np.repeat(np.arange(len(pts), dtype=float), 2))
        i0 = np.minimum(idx.astype(int), len(pts) - 2)
        w = (idx - i0)[:, None]
        # Two passes of the box: a triangular average, whose jerk is continuous.
        self._r = _box(_box(pts[i0] * (1 - w) + pts[i0 + 1] * w, n_box), n_box)
        self._v = np.gradient(self._r, REF_DT_S, axis=0)
        self._a = np.gradient(self._v, REF_DT_S, axis=0)
        seg = i0 + 1  # the sample ahead: its tangent holds on the way to it
        self._leg = leg_ix[np.ceil(idx).astype(int)]  # held at a stop: the leg that ended
        self._yaw = self._headings(tan[seg], heading_rad, yaw_rate_rps)
        self._n = len(t)
        lead_n = int(round(accel_lead_s / REF_DT_S))
        if lead_n:
            self._a = np.concatenate([self._a[lead_n:], np.repeat(self._a[-1:], lead_n, axis=0)])
        self.reference_end_s = start_s + (self._n - 1) * REF_DT_S
        self._i = -1
        self.done = False

    @staticmethod
    def _headings(tangent: np.ndarray, yaw0: float, rate_rps: float) -> np.ndarray:
        """Heading per reference sample: towards the horizontal direction of travel,
        slewed at rate_rps, held where the path is (nearly) vertical."""
        out = np.empty(len(tangent))
        step = rate_rps * REF_DT_S
        yaw = target = yaw0
        for k, (n, e, _d) in enumerate(tangent.tolist()):
            if n * n + e * e > 0.01:
                target = math.atan2(e, n)
            err = (target - yaw + math.pi) % (2 * math.pi) - math.pi
            yaw += step if err > step else -step if err < -step else err
            out[k] = yaw
        return out

    @property
    def leg(self) -> Leg | None:
        if self.done or self._i < 0:
            return None
        return self.plan.legs[int(self._leg[self._i])]

    def setpoint(self, t_s: float) -> Setpoint:
        x = (t_s - self.start_s) / REF_DT_S
        if x < 0:
            return Setpoint((0.0, 0.0, 0.0), yaw_rad=float(self._yaw[0]), armed=False)
        i = int(x)
        if i >= self._n - 1:
            self._i = self._n - 1
            end = self._r[-1]
            if t_s >= self.reference_end_s + LAND_SETTLE_S:
                self.done = True
                return Setpoint(tuple(end), yaw_rad=float(self._yaw[-1]), armed=False)
            # Keep pushing down gently until the controller has settled on the gear.
            return Setpoint((float(end[0]), float(end[1]), float(end[2]) + 0.5),
                            yaw_rad=float(self._yaw[-1]))
        self._i = i
        w = x - i
        r0, r1 = self._r[i], self._r[i + 1]
        v0, v1 = self._v[i], self._v[i + 1]
        a0, a1 = self._a[i], self._a[i + 1]
        return Setpoint(tuple((r0 + w * (r1 - r0)).tolist()),
                        tuple((v0 + w * (v1 - v0)).tolist()),
                        tuple((a0 + w * (a1 - a0)).tolist()),
                        float(self._yaw[i] + w * (self._yaw[i + 1] - self._yaw[i])))
