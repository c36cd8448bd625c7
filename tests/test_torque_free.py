"""Tests of reference_impl.torque_free: the closed-form torque-free rotation of a rigid body.

The truth is an independent numerical integration (scipy DOP853, rtol = atol = 1e-12) of the
body-frame equations  I_b w_b' = -w_b x I_b w_b,  q' = 1/2 q (x) (0, w_b),  q body -> world
(Hamilton, (w, x, y, z)), w_world = R(q) w_b.  Attitudes are compared by geodesic angle (rad),
angular velocities relative to |w0|.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from freebody.reference_impl.rotations import (
    geodesic_angle,
    matrix_from_quat,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
)
from freebody.reference_impl.torque_free import torque_free_rotation
from freebody.testing import assert_same_rotation

# --- tolerances -------------------------------------------------------------------------------
ODE_RTOL = 1e-12  # DOP853 relative tolerance of the truth (as specified for freebody's truth runs)
ODE_ATOL = 1e-12  # DOP853 absolute tolerance of the truth (same)
ANGLE_TOL = 2e-9  # rad; truth drifts <= 1.5e-10 rad/10 s through a flip, formula bugs give >= 1e-6
OMEGA_RTOL = 2e-9  # relative to |w0|; same budget as the attitude (truth's w error is smaller)
CONSERVATION_RTOL = 1e-12  # relative; L and E of the closed form drift by rounding only (~1e-14)
FRAME_TOL = 1e-11  # rad; rotated I_body's 1e-16 rounding, x ~1e3 by the flip dynamics (5e-13)
EXACT_TOL = 1e-12  # rad / relative; steady spins, spheres, t = 0: a few roundings per evaluation


# --- helpers ----------------------------------------------------------------------------------
def integrate_body_frame(I_body: np.ndarray, q0: np.ndarray, w0_world: np.ndarray,
                         t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DOP853 truth.  I_body (3, 3) kg m^2 body frame; q0 (4,) body -> world; w0_world (3,) rad/s
    world; t (N,) s ascending from 0.  Returns (q (N, 4) body -> world, w (N, 3) rad/s world)."""
    I_body = np.asarray(I_body, dtype=float)
    I_inv = np.linalg.inv(I_body)
    w_b0 = matrix_from_quat(q0).T @ np.asarray(w0_world, dtype=float)

    def rhs(_t, y):
        w_b, q = y[:3], y[3:]
        dw = I_inv @ (-np.cross(w_b, I_body @ w_b))
        dq = 0.5 * quat_multiply(q, np.r_[0.0, w_b])
        return np.r_[dw, dq]

    sol = solve_ivp(rhs, (float(t[0]), float(t[-1])), np.r_[w_b0, q0], method="DOP853",
                    rtol=ODE_RTOL, atol=ODE_ATOL, t_eval=t)
    assert sol.success, sol.message
    q = quat_normalize(sol.y[3:].T)
    w_b = sol.y[:3].T
    return q, np.einsum("nij,nj->ni", matrix_from_quat(q), w_b)


def ode_disagreement(I_body, q0, w0_world, t_end: float, n: int = 201):
    """Max geodesic angle (rad) and max |dw| / |w0| between closed form and DOP853 on [0, t_end]."""
    t = np.linspace(0.0, t_end, n)
    q_a, w_a = torque_free_rotation(I_body, q0, w0_world, t)
    q_n, w_n = integrate_body_frame(I_body, q0, w0_world, t)
    assert np.all(np.isfinite(q_a)) and np.all(np.isfinite(w_a))
    angle = float(np.max(geodesic_angle(q_a, q_n)))
    omega = float(np.max(np.linalg.norm(w_a - w_n, axis=-1)) / np.linalg.norm(w0_world))
    return angle, omega


def rotated_inertia(moments, q_frame) -> np.ndarray:
    """I_body = R diag(moments) R^T: principal axes given by the columns of R = R(q_frame)."""
    R = matrix_from_quat(q_frame)
    return R @ np.diag(np.asarray(moments, dtype=float)) @ R.T


def random_unit_quaternion(rng: np.random.Generator) -> np.ndarray:
    return quat_normalize(rng.normal(size=4))


def random_moments(rng: np.random.Generator) -> np.ndarray:
    """Distinct principal moments (kg m^2) obeying the triangle inequality I3 < I1 + I2."""
    while True:
        m = np.sort(rng.uniform(0.2, 2.0, 3))
        if m[2] < m[0] + m[1] and np.min(np.diff(m)) > 0.05:
            return m


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
DZH_I = np.diag([1.0, 2.0, 3.0])
DZH_W0 = np.array([0.01, 5.0, 0.0])


# --- tests ------------------------------------------------------------------------------------
def test_dzhanibekov_matches_integration():
    t = np.linspace(0.0, 10.0, 401)
    q_a, w_a = torque_free_rotation(DZH_I, IDENTITY, DZH_W0, t)
    # the case must really flip: the intermediate-axis body rate changes sign
    w_b = np.einsum("nji,nj->ni", matrix_from_quat(q_a), w_a)
    assert np.any(w_b[:, 1] < -4.0) and w_b[0, 1] > 4.0
    angle, omega = ode_disagreement(DZH_I, IDENTITY, DZH_W0, 10.0, n=401)
    assert angle <= ANGLE_TOL, angle
    assert omega <= OMEGA_RTOL, omega


def test_rotated_body_frame_gives_same_world_motion():
    # body frame rotated by Q: I_b = Q^T diag Q (non-diagonal), q0 = Q, so R0 I_b R0^T = diag.
    Q = quat_from_rotvec(np.deg2rad(40.0) * np.ones(3) / np.sqrt(3.0))
    RQ = matrix_from_quat(Q)
    I_b = RQ.T @ DZH_I @ RQ
    assert np.max(np.abs(I_b - np.diag(np.diag(I_b)))) > 0.1
    t = np.linspace(0.0, 10.0, 401)
    q_rot, w_rot = torque_free_rotation(I_b, Q, DZH_W0, t)
    q_dia, w_dia = torque_free_rotation(DZH_I, IDENTITY, DZH_W0, t)
    # same world motion: R_rot(t) = R_diag(t) Q
    assert_same_rotation(q_rot, quat_multiply(q_dia, Q), FRAME_TOL)
    assert np.max(np.abs(w_rot - w_dia)) <= FRAME_TOL * np.linalg.norm(DZH_W0)
    angle, omega = ode_disagreement(I_b, Q, DZH_W0, 10.0)
    assert angle <= ANGLE_TOL, angle
    assert omega <= OMEGA_RTOL, omega


@pytest.mark.parametrize("w0_principal, major", [
    ((0.3, 0.5, 2.0), True),     # L^2 > 2 E I2: polhode circulates about the major axis
    ((2.0, 0.5, -0.3), False),   # L^2 < 2 E I2: polhode circulates about the minor axis
    ((-0.4, 3.0, 0.6), True),
    ((1.5, -3.0, 0.2), False),
])
def test_both_polhode_families(w0_principal, major):
    rng = np.random.default_rng(1234)
    moments = np.array([1.0, 2.0, 3.0])
    m = moments * np.asarray(w0_principal)
    two_E = np.sum(m * m / moments)
    assert (np.sum(m * m) > two_E * moments[1]) == major
    q_frame = random_unit_quaternion(rng)            # principal -> body
    q_world = random_unit_quaternion(rng)            # principal -> world at t = 0
    q0 = quat_multiply(q_world, q_frame * np.array([1.0, -1.0, -1.0, -1.0]))
    w0_world = matrix_from_quat(q_world) @ np.asarray(w0_principal)
    angle, omega = ode_disagreement(rotated_inertia(moments, q_frame), q0, w0_world, 10.0)
    assert angle <= ANGLE_TOL, angle
    assert omega <= OMEGA_RTOL, omega


def test_axisymmetric_top():
    rng = np.random.default_rng(99)
    q_frame = random_unit_quaternion(rng)
    I_b = rotated_inertia([0.8, 0.8, 1.5], q_frame)   # symmetry axis = 3rd column of R(q_frame)
    q0 = random_unit_quaternion(rng)
    w0 = rng.normal(size=3) * 2.0
    angle, omega = ode_disagreement(I_b, q0, w0, 10.0)
    assert angle <= ANGLE_TOL, angle
    assert omega <= OMEGA_RTOL, omega
    # regular precession: the symmetry axis keeps a constant angle to L, |w| is constant
    t = np.linspace(0.0, 10.0, 301)
    q, w = torque_free_rotation(I_b, q0, w0, t)
    R = matrix_from_quat(q)
    axis_world = R @ matrix_from_quat(q_frame)[:, 2]
    L = np.einsum("nij,jk,nlk,nl->ni", R, I_b, R, w)
    cos_nut = np.sum(axis_world * L, axis=-1) / np.linalg.norm(L, axis=-1)
    assert np.ptp(cos_nut) <= EXACT_TOL
    assert np.ptp(np.linalg.norm(w, axis=-1)) <= EXACT_TOL * np.linalg.norm(w0)
    assert abs(cos_nut[0]) < 0.99                  # a genuine, tilted precession


def test_sphere_spins_steadily():
    rng = np.random.default_rng(7)
    I_b = rotated_inertia([1.3, 1.3, 1.3], random_unit_quaternion(rng))
    q0 = random_unit_quaternion(rng)
    w0 = rng.normal(size=3)
    t = np.linspace(0.0, 10.0, 101)
    q, w = torque_free_rotation(I_b, q0, w0, t)
    assert np.max(np.abs(w - w0)) <= EXACT_TOL * np.linalg.norm(w0)
    expected = quat_multiply(quat_from_rotvec(t[:, None] * w0), q0)
    assert_same_rotation(q, expected, EXACT_TOL)
    angle, omega = ode_disagreement(I_b, q0, w0, 10.0, n=51)
    assert angle <= ANGLE_TOL and omega <= OMEGA_RTOL


def test_random_bodies():
    rng = np.random.default_rng(20240611)
    for _ in range(5):
        moments = random_moments(rng)
        I_b = rotated_inertia(moments, random_unit_quaternion(rng))
        q0 = random_unit_quaternion(rng)
        w0 = rng.normal(size=3) * rng.uniform(0.5, 4.0)
        angle, omega = ode_disagreement(I_b, q0, w0, 5.0, n=101)
        assert angle <= ANGLE_TOL, (moments, w0, angle)
        assert omega <= OMEGA_RTOL, (moments, w0, omega)


def test_angular_momentum_and_energy_conserved():
    rng = np.random.default_rng(5)
    bodies = [(DZH_I, IDENTITY, DZH_W0)]
    for _ in range(3):
        bodies.append((rotated_inertia(random_moments(rng), random_unit_quaternion(rng)),
                       random_unit_quaternion(rng), rng.normal(size=3) * 3.0))
    t = np.linspace(0.0, 10.0, 1001)
    for I_b, q0, w0 in bodies:
        q, w = torque_free_rotation(I_b, q0, w0, t)
        R = matrix_from_quat(q)
        L = np.einsum("nij,jk,nlk,nl->ni", R, I_b, R, w)        # L = R I_b R^T w, world
        E = 0.5 * np.sum(w * L, axis=-1)
        L_ref = np.linalg.norm(L[0])
        assert np.max(np.linalg.norm(L - L[0], axis=-1)) <= CONSERVATION_RTOL * L_ref
        assert np.max(np.abs(E - E[0])) <= CONSERVATION_RTOL * E[0]


def test_rest_and_principal_axis_spins():
    t = np.linspace(0.0, 10.0, 101)
    q0 = quat_normalize(np.array([0.3, -0.1, 0.8, 0.5]))
    q, w = torque_free_rotation(DZH_I, q0, np.zeros(3), t)
    assert np.all(w == 0.0)
    assert_same_rotation(q, q0, EXACT_TOL)
    R0 = matrix_from_quat(q0)
    for axis in range(3):                           # includes the (unstable) intermediate axis
        w0 = 4.0 * R0[:, axis]
        q, w = torque_free_rotation(DZH_I, q0, w0, t)
        expected = quat_multiply(quat_from_rotvec(t[:, None] * w0), q0)
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(w))
        if axis != 1:                                # rounding grows like exp(1.6 t) on axis 2
            assert_same_rotation(q, expected, EXACT_TOL, f"axis {axis}")
            assert np.max(np.abs(w - w0)) <= EXACT_TOL * 4.0, axis
    # exactly along the intermediate axis (body frame = principal frame, q0 = 1): an equilibrium
    w0 = np.array([0.0, 4.0, 0.0])
    q, w = torque_free_rotation(DZH_I, IDENTITY, w0, t)
    expected = quat_from_rotvec(t[:, None] * w0)
    assert_same_rotation(q, expected, EXACT_TOL)
    assert np.max(np.abs(w - w0)) <= EXACT_TOL * 4.0


@pytest.mark.parametrize("moments, w0", [
    ((3.0, 4.0, 6.0), (2.0, 0.7, 1.0)),       # exactly on the separatrix: L^2 = 2 E I2
    ((3.0, 4.0, 6.0), (-2.0, 0.7, 1.0)),
    ((1.0, 2.0, 3.0), (1e-10, 5.0, 0.0)),     # 1e-10 off the intermediate axis (k'^2 ~ 1e-21)
    ((1.0, 2.0, 3.0), (0.0, 5.0, 1e-9)),
    ((1.0, 2.0, 3.0), (1e-80, 5.0, 0.0)),     # beyond double precision of the separatrix
    ((1.0, 1.0 + 1e-13, 3.0), (1.0, 2.0, 1e-7)),   # nearly axisymmetric, m near the equator
    ((1.0, 3.0 - 1e-12, 3.0), (1e-6, 2.0, 1.0)),
    ((1.0, 1.0 + 1e-9, 1.0 + 2e-9), (1.3, -2.2, 0.9)),   # nearly a sphere
])
def test_separatrix_and_near_degenerate(moments, w0):
    # principal body frame and q0 = 1 so that the inputs are exact (these motions are very
    # sensitive to a rounding of w0 or I_body)
    I_b = np.diag(moments)
    if moments == (3.0, 4.0, 6.0):
        m1, m3 = 3.0 * w0[0], 6.0 * w0[2]
        assert m3 * m3 * (6.0 - 4.0) / 6.0 == m1 * m1 * (4.0 - 3.0) / 3.0   # exact separatrix
    angle, omega = ode_disagreement(I_b, IDENTITY, np.asarray(w0), 10.0)
    assert angle <= ANGLE_TOL, angle
    assert omega <= OMEGA_RTOL, omega


def test_initial_state_shapes_and_time_order():
    rng = np.random.default_rng(31)
    I_b = rotated_inertia(random_moments(rng), random_unit_quaternion(rng))
    q0 = random_unit_quaternion(rng)
    w0 = rng.normal(size=3) * 2.0
    t = np.array([3.0, 0.0, 7.5, 1.0, 2.0])         # unsorted
    q, w = torque_free_rotation(I_b, q0, w0, t)
    assert q.shape == (5, 4) and w.shape == (5, 3)
    assert np.max(np.abs(q[1] - q0)) <= EXACT_TOL   # q(0) = q0 with its sign
    assert np.max(np.abs(w[1] - w0)) <= EXACT_TOL * np.linalg.norm(w0)
    for k, tk in enumerate(t):
        q_k, w_k = torque_free_rotation(I_b, q0, w0, np.array([tk]))
        assert_same_rotation(q_k[0], q[k], EXACT_TOL)
        assert np.max(np.abs(w_k[0] - w[k])) <= EXACT_TOL * np.linalg.norm(w0)
    # the quaternion is continuous in t (no sign jumps): small steps for a dense grid
    t_dense = np.linspace(0.0, 20.0, 4001)
    q_dense, _ = torque_free_rotation(DZH_I, q0, DZH_W0, t_dense)
    assert np.max(np.linalg.norm(np.diff(q_dense, axis=0), axis=-1)) < 0.05
