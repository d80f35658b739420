"""Rotation helpers on top of scipy's Rotation: Euler angles, quaternions, slerp.

Conventions: ``R_a_b`` maps vectors in frame b into frame a. Quaternions are scalar first
(w, x, y, z), as MAVLink sends them. Euler angles are the aerospace z-y-x sequence
(yaw about z, then pitch about the new y, then roll about the new x), so that
``R_parent_child = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, as MAVLink ATTITUDE and the gimbal
protocol define them. Angles are radians.

This is the one place that decomposes a rotation into Euler angles (``euler_zyx_from_R``,
``euler_zyx_from_R_many``);
everything else works with matrices or quaternions, which have no gimbal lock.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation


def R_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` as a 3x3 matrix (parent <- child)."""
    return Rotation.from_euler("ZYX", [yaw_rad, pitch_rad, roll_rad]).as_matrix()


def R_from_euler_zyx_many(roll_rad: np.ndarray, pitch_rad: np.ndarray,
                          yaw_rad: np.ndarray) -> np.ndarray:
    """Vectorised ``R_from_euler_zyx``: arrays of shape (N,) give (N, 3, 3)."""
    angles = np.stack([np.asarray(yaw_rad, float), np.asarray(pitch_rad, float),
                       np.asarray(roll_rad, float)], axis=-1)
    return Rotation.from_euler("ZYX", angles).as_matrix()


def euler_zyx_from_R(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    At pitch = +-90 deg roll and yaw are not separable (gimbal lock); scipy then sets the
    roll to zero and puts the whole rotation about the vertical into yaw.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # scipy's gimbal-lock warning
        yaw, pitch, roll = Rotation.from_matrix(R).as_euler("ZYX")
    return float(roll), float(pitch), float(yaw)


def R_from_quat_wxyz(q_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z); (..., 4) gives (..., 3, 3)."""
    return Rotation.from_quat(np.asarray(q_wxyz, dtype=float), scalar_first=True).as_matrix()


def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix (..., 3, 3)."""
    q = Rotation.from_matrix(R).as_quat(canonical=True, scalar_first=True)
    return np.asarray(q)


def Rz(angle_rad: float) -> np.ndarray:
    """Rotation about z by ``angle_rad`` (parent <- child)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def angle_between_R(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle in radians of the rotation taking ``R_b`` to ``R_a``."""
    return float(Rotation.from_matrix(R_a.T @ R_b).magnitude())


def quat_wxyz_from_euler_zyx(roll_rad: np.ndarray, pitch_rad: np.ndarray,
                             yaw_rad: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``; arrays (...) give
    (..., 4). Closed form (no scipy object per call) for the per-message telemetry adapter."""
    hr, hp, hy = (np.asarray(a, dtype=float) / 2.0 for a in (roll_rad, pitch_rad, yaw_rad))
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.stack([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy], axis=-1)


def euler_zyx_from_R_many(R: np.ndarray) -> np.ndarray:
    """Vectorised ``euler_zyx_from_R``: (N, 3, 3) gives (N, 3) columns roll, pitch, yaw in
    radians, pitch in [-pi/2, pi/2]; at gimbal lock roll is 0 and yaw takes the rest."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # scipy's gimbal-lock warning
        ypr = Rotation.from_matrix(np.asarray(R, float).reshape(-1, 3, 3)).as_euler("ZYX")
    return ypr[:, ::-1].copy()


def slerp_quat_wxyz(q0_wxyz: np.ndarray, q1_wxyz: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation from unit quaternions q0 to q1 (N, 4) by fractions
    ``w`` (N,) in [0, 1], along the shorter arc; returns (N, 4) unit quaternions (w, x, y, z)."""
    r0 = Rotation.from_quat(np.asarray(q0_wxyz, float), scalar_first=True)
    r1 = Rotation.from_quat(np.asarray(q1_wxyz, float), scalar_first=True)
    rotvec = (r0.inv() * r1).as_rotvec() * np.asarray(w, float)[:, None]
    return (r0 * Rotation.from_rotvec(rotvec)).as_quat(scalar_first=True)
