"""Rotation helpers and the convention converters."""
from __future__ import annotations

import numpy as np

from freebody.reference_impl.conventions import (angular_momentum, angular_velocity_body_from_world,
                                                 angular_velocity_world_from_body, kinetic_energy,
                                                 quat_wxyz_from_xyzw, quat_xyzw_from_wxyz)
from freebody.reference_impl.rotations import (geodesic_angle, gram_schmidt, matrix_from_quat, nearest_rotation,
                                               orthonormality_error, quat_canonical, quat_conjugate,
                                               quat_from_matrix, quat_from_rotvec, quat_multiply,
                                               quat_normalize, rotvec_from_quat, skew)

ROUNDOFF = 1e-14  # a few ulps of O(1) quantities


def _random_quats(n, seed=3):
    return quat_canonical(quat_normalize(np.random.default_rng(seed).normal(size=(n, 4))))


def test_matrix_quaternion_round_trip_and_composition():
    q = _random_quats(500)
    np.testing.assert_allclose(quat_from_matrix(matrix_from_quat(q)), q, atol=ROUNDOFF)
    a, b = q[:250], q[250:]
    np.testing.assert_allclose(matrix_from_quat(quat_multiply(a, b)),
                               matrix_from_quat(a) @ matrix_from_quat(b), atol=ROUNDOFF)


def test_hamilton_convention_rotates_body_to_world():
    q = quat_from_rotvec(np.array([0.0, 0.0, np.pi / 2]))  # +90 deg about z
    np.testing.assert_allclose(matrix_from_quat(q) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=ROUNDOFF)
    np.testing.assert_allclose(q, [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=ROUNDOFF)


def test_exp_log_and_geodesic_angle_down_to_tiny_angles():
    rng = np.random.default_rng(5)
    for scale in (1e-12, 1e-6, 1.0, 3.0):
        phi = rng.normal(size=(50, 3))
        phi *= scale / np.linalg.norm(phi, axis=1, keepdims=True)
        np.testing.assert_allclose(rotvec_from_quat(quat_from_rotvec(phi)), phi, rtol=1e-12, atol=1e-300)
        q = _random_quats(50)
        d = geodesic_angle(q, quat_multiply(q, quat_from_rotvec(phi)))
        np.testing.assert_allclose(d, scale, rtol=1e-9, atol=4e-16)  # composing q costs ~1 ulp absolute
    q = _random_quats(10)
    assert np.all(geodesic_angle(q, -q) <= 4e-16)  # q and -q are the same rotation


def test_nearest_rotation_gram_schmidt_and_orthonormality():
    R = matrix_from_quat(_random_quats(20))
    noisy = R + 1e-3 * np.random.default_rng(9).normal(size=R.shape)
    for fix in (nearest_rotation, gram_schmidt):
        F = fix(noisy)
        assert np.all(orthonormality_error(F) < ROUNDOFF)
        assert np.all(np.abs(np.linalg.det(F) - 1) < ROUNDOFF)
        assert np.all(geodesic_angle(quat_from_matrix(F), quat_from_matrix(R)) < 1e-2)
    assert np.all(orthonormality_error(noisy) > 1e-4)


def test_convention_converters():
    q = _random_quats(5)
    np.testing.assert_array_equal(quat_wxyz_from_xyzw(quat_xyzw_from_wxyz(q)), q)
    np.testing.assert_array_equal(quat_xyzw_from_wxyz(q)[:, 3], q[:, 0])
    w_b = np.random.default_rng(2).normal(size=(5, 3))
    w = angular_velocity_world_from_body(q, w_b)
    np.testing.assert_allclose(angular_velocity_body_from_world(q, w), w_b, atol=ROUNDOFF)
    I_b = np.diag([1.0, 2.0, 3.0])
    L = angular_momentum(I_b, q, w)
    R = matrix_from_quat(q)
    np.testing.assert_allclose(L, np.einsum("nij,jk,nk->ni", R, I_b, w_b), atol=ROUNDOFF)
    ke = kinetic_energy(2.0, I_b, q, np.ones((5, 3)), w)
    np.testing.assert_allclose(ke, 3.0 + 0.5 * np.einsum("ni,ij,nj->n", w_b, I_b, w_b), rtol=ROUNDOFF)
    np.testing.assert_allclose(skew(w[0]) @ w_b[0], np.cross(w[0], w_b[0]), atol=ROUNDOFF)
    np.testing.assert_allclose(quat_multiply(q, quat_conjugate(q)), np.tile([1.0, 0, 0, 0], (5, 1)), atol=ROUNDOFF)
