"""Camera mounts: a stabilised 2/3-axis gimbal, an ArduPilot-style servo mount, a fixed mount.

Frames (docs/frames.md): gimbal x along the optical axis, y right, z down; R_ned_gimbal maps
it into NED; R_ned_body is the vehicle attitude (FRD -> NED). The command is an earth-frame
pitch (rad, -pi/2 = nadir) and a yaw relative to the vehicle's heading (rad), or, locked
(GIMBAL_MANAGER_FLAGS_YAW_LOCK), relative to north.

* ``stabilised``: the gimbal holds roll 0 and the commanded pitch against the horizon, and
  its yaw at the commanded angle from the vehicle's heading, or locked at the commanded
  earth-frame yaw whatever the heading (it stabilises yaw as it does pitch: the lag is on
  the earth-frame yaw; a 2-axis gimbal has no yaw motor: yaw 0 from the heading). Each
  axis follows its target with a first-order lag (``tau_s``) limited to
  ``rate_limit_rps``, plus a small seeded random tracking error (Ornstein-Uhlenbeck,
  ``noise_rad`` standard deviation). It measures its own attitude, so what it reports is
  its true attitude. True attitude: Rz(heading + yaw) Ry(pitch) Rx(roll).
* ``servo``: servos on the body, axes yaw -> roll -> pitch from the body outwards, no
  feedback. At 50 Hz the autopilot computes the servo demand that would put the camera at
  the earth-frame target, clipped to the servo limits (what ArduPilot's AP_Mount_Servo
  drives and reports); the servos follow the demand with a lag and a rate limit. True
  attitude: R_ned_body Rz(yaw_s) Rx(roll_s) Ry(pitch_s) of the servos' actual angles.
* ``fixed``: R_ned_body @ R_body_gimbal of the configured mount.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

import numpy as np

from pdcov.core.rotations import R_from_euler_zyx

MODES = ("stabilised", "servo", "fixed")
SERVO_UPDATE_HZ = 50.0


@dataclass(frozen=True, slots=True)
class GimbalConfig:
    """mode: one of MODES. axes: 2 or 3 (stabilised). rate_limit_rps: slew limit per axis.
    tau_s: first-order lag of each axis. noise_rad: standard deviation of the tracking error
    (stabilised). limits_rad: servo limits, rows roll/pitch/yaw, columns min/max (servo).
    R_body_gimbal: the fixed mount's rotation (fixed)."""

    mode: str = "stabilised"
    axes: int = 3
    rate_limit_rps: float = math.radians(90)
    tau_s: float = 0.08
    noise_rad: float = math.radians(0.15)
    limits_rad: tuple[tuple[float, float], ...] = (
        (math.radians(-30), math.radians(30)), (math.radians(-90), math.radians(20)),
        (math.radians(-180), math.radians(180)))
    R_body_gimbal: np.ndarray = field(default_factory=lambda: R_from_euler_zyx(
        0.0, -math.pi / 2, 0.0))

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"gimbal mode: expected one of {MODES}, got {self.mode!r}")
        if self.axes not in (2, 3):
            raise ValueError(f"gimbal axes: expected 2 or 3, got {self.axes!r}")


def _wrap(a: float) -> float:
    """An angle in [-pi, pi) (rad)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _Rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _Rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _Ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def quat_from_euler_zyx(roll: float, pitch: float, yaw: float
                        ) -> tuple[float, float, float, float]:
    """(w, x, y, z) of Rz(yaw) Ry(pitch) Rx(roll), in plain floats (per-message use)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def quat_from_R(R: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) with w >= 0 of a rotation matrix (Shepperd's method), plain floats."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    tr = a + e + i
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (h - f) / s, (c - g) / s, (d - b) / s)
    elif a > e and a > i:
        s = math.sqrt(1.0 + a - e - i) * 2
        q = ((h - f) / s, 0.25 * s, (b + d) / s, (c + g) / s)
    elif e > i:
        s = math.sqrt(1.0 + e - a - i) * 2
        q = ((c - g) / s, (b + d) / s, 0.25 * s, (f + h) / s)
    else:
        s = math.sqrt(1.0 + i - a - e) * 2
        q = ((d - b) / s, (c + g) / s, (f + h) / s, 0.25 * s)
    return q if q[0] >= 0 else (-q[0], -q[1], -q[2], -q[3])


def servo_angles_yrp(R_body_gimbal: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of R = Rz(yaw) Rx(roll) Ry(pitch), the servo chain yaw ->
    roll -> pitch from the body outwards (roll in [-pi/2, pi/2])."""
    R = R_body_gimbal
    roll = math.asin(_clip(float(R[2, 1]), -1.0, 1.0))
    pitch = math.atan2(-float(R[2, 0]), float(R[2, 2]))
    yaw = math.atan2(-float(R[0, 1]), float(R[1, 1]))
    return roll, pitch, yaw


def _follow(x: float, target: float, dt: float, tau: float, rate: float) -> float:
    """One step of a first-order lag towards target with a slew-rate limit."""
    step = (target - x) * min(1.0, dt / tau)
    lim = rate * dt
    return x + _clip(step, -lim, lim)


class GimbalModel:
    """The mount's state, stepped with the vehicle. Angles in radians.

    ``command(pitch, yaw)`` sets the target; ``step(dt, roll, pitch, yaw)`` advances with the
    vehicle's attitude; ``R_ned_gimbal(R_ned_body)`` is the true attitude; ``demand`` (servo)
    the last servo demand (roll, pitch, yaw) as the autopilot reports it; ``angles``
    (stabilised) the gimbal's (roll, pitch, yaw-from-heading).
    """

    def __init__(self, cfg: GimbalConfig, seed: int = 0) -> None:
        self.cfg = cfg
        self._rng = random.Random(seed)
        self.target_pitch_rad = -math.pi / 2
        self.target_yaw_rad = 0.0
        self.target_earth_yaw = False
        self._earth_yaw_rad: float | None = None  # stabilised, locked: the earth-frame yaw
        # stabilised: earth roll, earth pitch, yaw from heading (actual, without noise)
        self._angles = [0.0, -math.pi / 2, 0.0]
        self._noise = [0.0, 0.0, 0.0]
        # servo: actual servo angles and the demand (roll, pitch, yaw)
        self._servo = [0.0, -math.pi / 2, 0.0]
        self.demand = (0.0, -math.pi / 2, 0.0)
        self._servo_due_s = 0.0
        self._t_s = 0.0

    def command(self, pitch_rad: float, yaw_rad: float = 0.0, earth_yaw: bool = False) -> None:
        """Earth-frame pitch (-pi/2 nadir) and yaw from the vehicle's heading, or from north
        with ``earth_yaw``."""
        three = self.cfg.axes == 3
        self.target_pitch_rad = pitch_rad
        self.target_yaw_rad = yaw_rad if three else 0.0
        self.target_earth_yaw = earth_yaw and three

    def step(self, dt_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> None:
        cfg = self.cfg
        self._t_s += dt_s
        if cfg.mode == "stabilised":
            a = self._angles
            a[0] = _follow(a[0], 0.0, dt_s, cfg.tau_s, cfg.rate_limit_rps)
            a[1] = _follow(a[1], self.target_pitch_rad, dt_s, cfg.tau_s, cfg.rate_limit_rps)
            if self.target_earth_yaw:
                e = yaw_rad + a[2] if self._earth_yaw_rad is None else self._earth_yaw_rad
                e = _follow(e, e + _wrap(self.target_yaw_rad - e), dt_s, cfg.tau_s,
                            cfg.rate_limit_rps)
                self._earth_yaw_rad = e
                a[2] = _wrap(e - yaw_rad)
            else:
                self._earth_yaw_rad = None
                a[2] = _follow(a[2], self.target_yaw_rad, dt_s, cfg.tau_s, cfg.rate_limit_rps)
            # Ornstein-Uhlenbeck tracking error, correlation time 0.5 s.
            k = dt_s / 0.5
            s = cfg.noise_rad * math.sqrt(2 * k)
            g = self._rng.gauss
            n = self._noise
            n[0] += -k * n[0] + s * g(0.0, 1.0)
            n[1] += -k * n[1] + s * g(0.0, 1.0)
            n[2] += -k * n[2] + s * g(0.0, 1.0) if cfg.axes == 3 else 0.0
        elif cfg.mode == "servo":
            if self._t_s >= self._servo_due_s:
                self._servo_due_s += 1.0 / SERVO_UPDATE_HZ
                self.demand = self._servo_demand(roll_rad, pitch_rad, yaw_rad)
            sv = self._servo
            for i in range(3):
                sv[i] = _follow(sv[i], self.demand[i], dt_s, cfg.tau_s, cfg.rate_limit_rps)

    def _servo_demand(self, roll_rad: float, pitch_rad: float, yaw_rad: float
                      ) -> tuple[float, float, float]:
        R_ned_body = _Rz(yaw_rad) @ _Ry(pitch_rad) @ _Rx(roll_rad)
        yaw = self.target_yaw_rad + (0.0 if self.target_earth_yaw else yaw_rad)
        R_target = _Rz(yaw) @ _Ry(self.target_pitch_rad)
        r, p, y = servo_angles_yrp(R_ned_body.T @ R_target)
        (r0, r1), (p0, p1), (y0, y1) = self.cfg.limits_rad
        return _clip(r, r0, r1), _clip(p, p0, p1), _clip(y, y0, y1)

    @property
    def angles(self) -> tuple[float, float, float]:
        """Stabilised gimbal: (roll, pitch) against the horizon and yaw from the heading,
        as it measures them (tracking error included)."""
        a, n = self._angles, self._noise
        return a[0] + n[0], a[1] + n[1], a[2] + n[2]

    def R_ned_gimbal(self, R_ned_body: np.ndarray) -> np.ndarray:
        """The true camera mount attitude (gimbal frame -> NED)."""
        mode = self.cfg.mode
        if mode == "fixed":
            return R_ned_body @ self.cfg.R_body_gimbal
        if mode == "servo":
            r, p, y = self._servo
            return R_ned_body @ _Rz(y) @ _Rx(r) @ _Ry(p)
        heading = math.atan2(R_ned_body[1, 0], R_ned_body[0, 0])
        r, p, y = self.angles
        return _Rz(heading + y) @ _Ry(p) @ _Rx(r)
