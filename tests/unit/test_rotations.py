"""core.rotations' closed forms against scipy's Rotation (the independent oracle) at 1e-12,
and the property live-equals-offline rests on: a row converts to the same bits alone or in a
batch."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pdcov.core.rotations import (
    R_from_quat_wxyz,
    quat_norm,
    quat_wxyz_from_R,
    slerp_quat_wxyz,
)

TOL = 1e-12


def random_quats(n: int, seed: int) -> np.ndarray:
    """Non-unit quaternions (w, x, y, z), some with a negative w, plus the axis cases."""
    q = np.random.default_rng(seed).normal(size=(n, 4)) * 3.0
    special = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1],
                        [-1, 0, 0, 0], [0, -1e-9, 0, 1], [1e-12, 1, 1, 0]], float)
    return np.concatenate([special, q])


def scipy_slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    r0 = Rotation.from_quat(q0, scalar_first=True)
    r1 = Rotation.from_quat(q1, scalar_first=True)
    step = Rotation.from_rotvec((r0.inv() * r1).as_rotvec() * w[:, None])
    return (r0 * step).as_quat(scalar_first=True)


def same_rotation(qa: np.ndarray, qb: np.ndarray) -> float:
    """Largest distance between unit quaternions up to sign (q and -q are one rotation)."""
    return float(np.minimum(np.abs(qa - qb).max(axis=1), np.abs(qa + qb).max(axis=1)).max())


def test_matrix_of_quaternion_equals_scipy() -> None:
    q = random_quats(5000, 1)
    np.testing.assert_allclose(R_from_quat_wxyz(q),
                               Rotation.from_quat(q, scalar_first=True).as_matrix(),
                               rtol=0, atol=TOL)


def test_matrix_of_quaternion_shapes_and_zero() -> None:
    assert R_from_quat_wxyz([2.0, 0, 0, 0]).shape == (3, 3)
    np.testing.assert_array_equal(R_from_quat_wxyz([2.0, 0, 0, 0]), np.eye(3))
    assert R_from_quat_wxyz(np.ones((2, 5, 4))).shape == (2, 5, 3, 3)
    # x = 1: a half turn about x (frames: R_a_b maps b vectors into a).
    np.testing.assert_array_equal(R_from_quat_wxyz([0.0, 1, 0, 0]), np.diag([1.0, -1, -1]))
    with pytest.raises(ValueError, match="zero-norm"):
        R_from_quat_wxyz(np.array([[1.0, 0, 0, 0], [0, 0, 0, 0]]))


def test_quaternion_of_matrix_equals_scipy() -> None:
    R = Rotation.from_quat(random_quats(5000, 2), scalar_first=True).as_matrix()
    # Half turns about each axis and near them: every branch of Markley's method, and w = 0.
    half = Rotation.from_rotvec(np.pi * np.eye(3)).as_matrix()
    near = Rotation.from_rotvec((np.pi - 1e-7) * np.eye(3)).as_matrix()
    R = np.concatenate([half, near, np.eye(3)[None], R])
    expected = Rotation.from_matrix(R).as_quat(canonical=True, scalar_first=True)
    q = quat_wxyz_from_R(R)
    np.testing.assert_allclose(q, expected, rtol=0, atol=TOL)
    assert (q[:, 0] >= 0).all()
    assert quat_wxyz_from_R(np.eye(3)).shape == (4,)
    np.testing.assert_allclose(R_from_quat_wxyz(q), R, rtol=0, atol=TOL)


def test_quaternion_of_non_rotation_goes_through_scipy() -> None:
    skewed = np.diag([1.0, 1.0, 1.001]) @ Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    np.testing.assert_allclose(quat_wxyz_from_R(skewed),
                               Rotation.from_matrix(skewed).as_quat(canonical=True,
                                                                    scalar_first=True),
                               rtol=0, atol=TOL)
    with pytest.raises(ValueError, match="determinant"):
        quat_wxyz_from_R(-np.eye(3))  # orthonormal, but a reflection


def test_slerp_equals_scipy() -> None:
    rng = np.random.default_rng(3)
    q0 = random_quats(3000, 4)
    q1 = random_quats(3000, 5)
    w = rng.uniform(0, 1, len(q0))
    w[:3] = [0.0, 1.0, 0.5]
    # Equal, opposite (the same rotation) and nearly equal ends.
    q1[3], q1[4], q1[5] = q0[3], -q0[4], q0[5] + 1e-9
    got = slerp_quat_wxyz(q0, q1, w)
    np.testing.assert_allclose(got, scipy_slerp(q0, q1, w), rtol=0, atol=TOL)
    np.testing.assert_allclose(quat_norm(got), 1.0, rtol=0, atol=TOL)
    # The ends: w = 0 gives q0's rotation, w = 1 q1's.
    unit0 = q0 / quat_norm(q0)[:, None]
    unit1 = q1 / quat_norm(q1)[:, None]
    assert same_rotation(slerp_quat_wxyz(q0, q1, np.zeros(len(q0))), unit0) < TOL
    assert same_rotation(slerp_quat_wxyz(q0, q1, np.ones(len(q0))), unit1) < 1e-11


def test_slerp_takes_the_shorter_arc() -> None:
    q0 = np.array([[1.0, 0, 0, 0]])
    q1 = -np.array([[np.cos(0.5), np.sin(0.5), 0, 0]])  # 1 rad about x, written with w < 0
    got = slerp_quat_wxyz(q0, q1, np.array([0.5]))
    np.testing.assert_allclose(got, [[np.cos(0.25), np.sin(0.25), 0, 0]], rtol=0, atol=TOL)


def test_a_row_gives_the_same_bits_alone_or_in_a_batch() -> None:
    """Live evaluates one frame per call, offline thousands: the same bits either way."""
    q0, q1 = random_quats(257, 6), random_quats(257, 7)
    w = np.random.default_rng(8).uniform(0, 1, len(q0))
    R = R_from_quat_wxyz(q0)
    batch = (R_from_quat_wxyz(q0), quat_wxyz_from_R(R), slerp_quat_wxyz(q0, q1, w),
             quat_norm(q0))
    for i in (0, 5, 100, 256):
        alone = (R_from_quat_wxyz(q0[i:i + 1]), quat_wxyz_from_R(R[i:i + 1]),
                 slerp_quat_wxyz(q0[i:i + 1], q1[i:i + 1], w[i:i + 1]),
                 quat_norm(q0[i:i + 1]))
        for b, a in zip(batch, alone, strict=True):
            np.testing.assert_array_equal(b[i:i + 1], a)
