"""Rotation helpers: Euler angles, quaternions, slerp.

Conventions: ``R_a_b`` maps vectors in frame b into frame a. Quaternions are scalar first
(w, x, y, z), as MAVLink sends them. Euler angles are the aerospace z-y-x sequence
(yaw about z, then pitch about the new y, then roll about the new x), so that
``R_parent_child = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, as MAVLink ATTITUDE and the gimbal
protocol define them. Angles are radians.

This is the one place that decomposes a rotation into Euler angles (``euler_zyx_from_R``,
``euler_zyx_from_R_many``);
everything else works with matrices or quaternions, which have no gimbal lock.

The quaternion <-> matrix conversions and slerp are closed forms in numpy rather than scipy's
Rotation: the live daemon calls them for one or two frames at a time, where building Rotation
objects cost ~0.1 ms a call; tests pin them to scipy at 1e-12. They are elementwise, so a
frame gives the same bits whether converted alone or in a batch (live equals offline).
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
    """Rotation matrix of a quaternion (w, x, y, z), normalised first; (..., 4) gives
    (..., 3, 3). Raises ValueError for a zero quaternion."""
    q = np.asarray(q_wxyz, dtype=float)
    shape = q.shape[:-1]
    q = q.reshape(-1, 4)
    norm = quat_norm(q)
    if not np.all(norm):
        raise ValueError("zero-norm quaternion: no rotation")
    w, x, y, z = (q / norm[:, None]).T
    ww, xx, yy, zz = w * w, x * x, y * y, z * z
    R = np.stack([((ww + xx) - yy) - zz, (x * y - w * z) * 2, (x * z + w * y) * 2,
                  (x * y + w * z) * 2, ((ww - xx) + yy) - zz, (y * z - w * x) * 2,
                  (x * z - w * y) * 2, (y * z + w * x) * 2, ((ww - xx) - yy) + zz], axis=-1)
    return R.reshape(*shape, 3, 3)


def quat_norm(q_wxyz: np.ndarray) -> np.ndarray:
    """Euclidean norms (N,) of quaternions (N, 4), summed in one fixed order, so that a row
    gives the same bits whatever the number of rows (a numpy reduction's summation order
    may depend on the array's shape)."""
    sq = np.square(q_wxyz, dtype=float)
    return np.sqrt(((sq[:, 0] + sq[:, 1]) + sq[:, 2]) + sq[:, 3])


_ORTHO_ATOL = 1e-12  # as scipy's from_matrix: beyond it a matrix is first orthogonalised
_EYE3 = np.eye(3)
def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of rotation matrices (..., 3, 3), sign chosen so that the
    first nonzero of w, x, y, z is positive (w >= 0). Markley's method ("Unit Quaternion from
    Rotation Matrix", 2008), from the largest of the diagonal entries and the trace, as
    scipy's from_matrix. Matrices not orthonormal within 1e-12 go through scipy (nearest
    rotation by SVD; raises ValueError for a determinant <= 0)."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 9)
    n = len(m)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m.T
    trace = (m00 + m11) + m22
    choice = np.argmax(np.stack([m00, m11, m22, trace], axis=1), axis=1)
    # 4 |q_k| (w, x, y, z) for each case k: the largest of m00, m11, m22 and the trace.
    cases = np.array([
        [m21 - m12, ((1 + m00) - m11) - m22, m10 + m01, m20 + m02],
        [m02 - m20, m10 + m01, ((1 + m11) - m00) - m22, m21 + m12],
        [m10 - m01, m20 + m02, m21 + m12, ((1 + m22) - m00) - m11],
        [((1 + m00) + m11) + m22, m21 - m12, m02 - m20, m10 - m01]]).reshape(4, 4, n)
    q = cases[choice, :, np.arange(n)]
    q /= quat_norm(q)[:, None]
    first = np.argmax(q != 0, axis=1)
    q *= np.where(q[np.arange(n), first] < 0, -1.0, 1.0)[:, None]
    mm = m.reshape(-1, 3, 3)
    other = ~np.all(np.abs(mm @ mm.transpose(0, 2, 1) - _EYE3) <= _ORTHO_ATOL, axis=(1, 2))
    other |= np.linalg.det(mm) <= 0
    if other.any():
        q[other] = Rotation.from_matrix(mm[other]).as_quat(canonical=True, scalar_first=True)
    return q.reshape(*R.shape[:-2], 4)


def Rz(angle_rad: float) -> np.ndarray:
    """Rotation about z by ``angle_rad`` (parent <- child)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def R_from_rotvec(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) of the rotation vector ``rotvec_rad`` (axis times angle, rad):
    Rodrigues' formula, exp([rotvec]x)."""
    w = np.asarray(rotvec_rad, dtype=float).reshape(3)
    theta = float(np.sqrt(w @ w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:  # sin(t)/t and (1 - cos(t))/t^2 by their series
        return _EYE3 + K + 0.5 * (K @ K)
    return _EYE3 + (np.sin(theta) / theta) * K + ((1 - np.cos(theta)) / theta**2) * (K @ K)


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


_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])
# Hamilton product: each component (w, x, y, z) of a * b as the signed sum of four products
# a_i b_j, indexed 4 i + j (w, x, y, z = 0..3).
_MUL_PRODUCTS = np.array([[0, 5, 10, 15], [1, 4, 11, 14], [2, 7, 8, 13], [3, 6, 9, 12]])
_MUL_SIGNS = np.array([[1, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]], float)


def _quat_mul_wxyz(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a * b of quaternions (N, 4) (w, x, y, z): R(a b) = R(a) R(b)."""
    t = (a[:, :, None] * b[:, None, :]).reshape(-1, 16)[:, _MUL_PRODUCTS] * _MUL_SIGNS
    return ((t[..., 0] + t[..., 1]) + t[..., 2]) + t[..., 3]


def slerp_quat_wxyz(q0_wxyz: np.ndarray, q1_wxyz: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation from quaternions q0 to q1 (N, 4), normalised first, by
    fractions ``w`` (N,) in [0, 1], along the shorter arc; returns (N, 4) unit quaternions
    (w, x, y, z): q0 * exp(w log(q0^-1 q1))."""
    q0 = np.asarray(q0_wxyz, float).reshape(-1, 4)
    q1 = np.asarray(q1_wxyz, float).reshape(-1, 4)
    q0 = q0 / quat_norm(q0)[:, None]
    rel = _quat_mul_wxyz(q0 * _CONJUGATE, q1 / quat_norm(q1)[:, None])
    rel[rel[:, 0] < 0] *= -1.0  # the shorter arc
    v = rel[:, 1:]
    sin_half = np.sqrt((v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) + v[:, 2] * v[:, 2])
    half = np.arctan2(sin_half, rel[:, 0]) * np.asarray(w, float).reshape(-1)
    step = np.empty_like(rel)
    step[:, 0] = np.cos(half)
    step[:, 1:] = v * (np.sin(half) / np.where(sin_half > 0, sin_half, 1.0))[:, None]
    return _quat_mul_wxyz(q0, step)
