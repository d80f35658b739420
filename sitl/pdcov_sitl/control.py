"""Multicopter flight control: position -> velocity -> attitude -> rate cascade and the X
mixer, in plain floats (it runs every 1/120 s step, so no numpy and no allocations beyond a
tuple).

Frames: positions and velocities NED (m, m/s) about the start point; attitude z-y-x Euler
angles body FRD -> NED; rates body FRD rad/s. The output is four ESC commands 0..1 in the
order of ``dynamics.MOTORS`` (FR, AL, FL, AR).

The loops (gains tuned on the JSBSim F450, whose hover throttle is ~0.47):

* position P -> velocity command (plus the guidance's feed-forward velocity);
* velocity PI -> acceleration command (plus feed-forward), horizontal limited to
  ``max_accel_mps2`` (the tilt limit);
* acceleration -> roll/pitch for the heading (thrust along body -z) and collective thrust,
  throttle ~ sqrt(thrust) (propeller thrust grows with the square of its speed);
* lean-angle input shaping (ArduPilot's ATC_INPUT_TC, 0.15 s): a critically damped
  second-order filter whose rate and angular acceleration are fed forward (ATC_RATE_FF_ENAB),
  so the attitude follows the shaped demand instead of lagging it and then overshooting;
* attitude P -> body rates; rate PID (+ the angular-acceleration feed-forward) ->
  normalised torques -> mixer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

G_MPS2 = 9.80665


@dataclass(frozen=True, slots=True)
class Setpoint:
    """What guidance asks for: position, feed-forward velocity and acceleration (NED) and
    heading (rad from north, clockwise). ``armed`` False stops the motors."""

    r_ned_m: tuple[float, float, float]
    v_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    a_ned_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rad: float = 0.0
    armed: bool = True


@dataclass(frozen=True, slots=True)
class Gains:
    """Loop gains (units per loop in the module docstring)."""

    pos_xy: float = 1.2
    pos_z: float = 1.5
    vel_xy: float = 2.5
    vel_xy_i: float = 0.6
    vel_z: float = 4.0
    vel_z_i: float = 2.0
    att: float = 7.0
    att_yaw: float = 3.0
    rate_rp: float = 0.045
    rate_rp_i: float = 0.02
    rate_rp_d: float = 0.0012
    rate_y: float = 0.25
    rate_y_i: float = 0.05
    max_accel_mps2: float = 4.0
    max_vel_correction_mps: float = 3.0
    max_yaw_rate_rps: float = math.radians(90)
    hover_throttle: float = 0.47
    input_tc_s: float = 0.15
    # Normalised torque per rad/s^2 of shaped angular acceleration (the F450 gains ~5.3
    # rad/s^2 per 0.01 of torque command, after the motors' ~60 ms lag).
    rate_accel_ff: float = 0.0019


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class Controller:
    """The cascade with its integrators; ``update`` once per step of ``dt_s`` seconds."""

    def __init__(self, dt_s: float, gains: Gains | None = None) -> None:
        self.dt_s = dt_s
        self.g = gains or Gains()
        self.reset()

    def reset(self) -> None:
        self._i_vel = [0.0, 0.0, 0.0]
        self._i_rate = [0.0, 0.0, 0.0]
        self._prev_rate = (0.0, 0.0, 0.0)
        self._att_d = (0.0, 0.0, 0.0, 0.0)  # shaped roll, pitch and their rates

    def update(self, sp: Setpoint, r_ned_m: tuple[float, float, float],
               v_ned_mps: tuple[float, float, float], roll_rad: float, pitch_rad: float,
               yaw_rad: float, p_rps: float, q_rps: float, r_rps: float
               ) -> tuple[float, float, float, float]:
        """ESC commands (FR, AL, FL, AR) in 0..1 for the true state given."""
        if not sp.armed:
            self.reset()
            return (0.0, 0.0, 0.0, 0.0)
        g, dt = self.g, self.dt_s
        # Position -> velocity command.
        cmax = g.max_vel_correction_mps
        vc_n = sp.v_ned_mps[0] + _clip(g.pos_xy * (sp.r_ned_m[0] - r_ned_m[0]), -cmax, cmax)
        vc_e = sp.v_ned_mps[1] + _clip(g.pos_xy * (sp.r_ned_m[1] - r_ned_m[1]), -cmax, cmax)
        vc_d = sp.v_ned_mps[2] + _clip(g.pos_z * (sp.r_ned_m[2] - r_ned_m[2]), -cmax, cmax)
        # Velocity -> acceleration command (PI; the integrators hold off wind and the
        # thrust model's error).
        iv = self._i_vel
        en, ee, ed = vc_n - v_ned_mps[0], vc_e - v_ned_mps[1], vc_d - v_ned_mps[2]
        iv[0] = _clip(iv[0] + g.vel_xy_i * en * dt, -3.0, 3.0)
        iv[1] = _clip(iv[1] + g.vel_xy_i * ee * dt, -3.0, 3.0)
        iv[2] = _clip(iv[2] + g.vel_z_i * ed * dt, -4.0, 4.0)
        an = sp.a_ned_mps2[0] + g.vel_xy * en + iv[0]
        ae = sp.a_ned_mps2[1] + g.vel_xy * ee + iv[1]
        ad = _clip(sp.a_ned_mps2[2] + g.vel_z * ed + iv[2], -6.0, 0.6 * G_MPS2)
        ah = math.hypot(an, ae)
        if ah > g.max_accel_mps2:
            an, ae = an * g.max_accel_mps2 / ah, ae * g.max_accel_mps2 / ah
        # Acceleration -> attitude and thrust (thrust along body -z).
        cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
        a_fwd = cy * an + sy * ae
        a_right = -sy * an + cy * ae
        fz = G_MPS2 - ad
        pitch_d = math.atan2(-a_fwd, fz)
        roll_d = math.atan2(a_right * math.cos(pitch_d), fz)
        # Input shaping (ArduPilot's ATC_INPUT_TC): the lean angles follow their demand
        # through a critically damped second-order filter; its rate and angular
        # acceleration are fed forward, so the attitude follows it without overshoot.
        w = 2.0 / g.input_tc_s
        sh_r, sh_p, w_r, w_p = self._att_d
        acc_r = w * w * (roll_d - sh_r) - 2.0 * w * w_r
        acc_p = w * w * (pitch_d - sh_p) - 2.0 * w * w_p
        w_r += acc_r * dt
        w_p += acc_p * dt
        sh_r += w_r * dt
        sh_p += w_p * dt
        self._att_d = (sh_r, sh_p, w_r, w_p)
        roll_d, pitch_d, roll_ff, pitch_ff = sh_r, sh_p, w_r, w_p
        thrust = math.sqrt(an * an + ae * ae + fz * fz) / G_MPS2  # in units of hover thrust
        collective = g.hover_throttle * math.sqrt(thrust)
        # Attitude -> body rates (Euler-rate demand mapped to FRD rates).
        yaw_rate = _clip(g.att_yaw * _wrap(sp.yaw_rad - yaw_rad), -g.max_yaw_rate_rps,
                         g.max_yaw_rate_rps)
        roll_rate = roll_ff + g.att * (roll_d - roll_rad)
        pitch_rate = pitch_ff + g.att * (pitch_d - pitch_rad)
        sphi, cphi = math.sin(roll_rad), math.cos(roll_rad)
        sth, cth = math.sin(pitch_rad), math.cos(pitch_rad)
        p_d = roll_rate - sth * yaw_rate
        q_d = cphi * pitch_rate + sphi * cth * yaw_rate
        r_d = -sphi * pitch_rate + cphi * cth * yaw_rate
        # Rate PID -> normalised torques.
        ir = self._i_rate
        ep, eq, er = p_d - p_rps, q_d - q_rps, r_d - r_rps
        ir[0] = _clip(ir[0] + g.rate_rp_i * ep * dt, -0.05, 0.05)
        ir[1] = _clip(ir[1] + g.rate_rp_i * eq * dt, -0.05, 0.05)
        ir[2] = _clip(ir[2] + g.rate_y_i * er * dt, -0.1, 0.1)
        pp, pq, _pr = self._prev_rate
        self._prev_rate = (p_rps, q_rps, r_rps)
        u_roll = (g.rate_rp * ep + ir[0] - g.rate_rp_d * (p_rps - pp) / dt
                  + g.rate_accel_ff * acc_r)
        u_pitch = (g.rate_rp * eq + ir[1] - g.rate_rp_d * (q_rps - pq) / dt
                   + g.rate_accel_ff * acc_p)
        u_yaw = _clip(g.rate_y * er + ir[2], -0.15, 0.15)
        return mix(collective, u_roll, u_pitch, u_yaw)


def mix(collective: float, roll: float, pitch: float, yaw: float
        ) -> tuple[float, float, float, float]:
    """X mixer of the F450 (its FlightControl.xml signs): positive roll lifts the left
    motors, positive pitch the front ones, positive yaw (nose right) the FR/AL pair.
    Returns (FR, AL, FL, AR) clipped to 0..1."""
    return (_clip(collective - roll + pitch + yaw, 0.0, 1.0),
            _clip(collective + roll - pitch + yaw, 0.0, 1.0),
            _clip(collective + roll + pitch - yaw, 0.0, 1.0),
            _clip(collective - roll - pitch - yaw, 0.0, 1.0))
