"""The reference integrators ``implicit-midpoint`` and ``rkmk4`` (reference_impl/lie_integrators.py):
their observed orders (2 and 4), the implicit midpoint's conservation of energy and L torque-free
(to its solver's tolerance, which is round-off), its Cayley reconstruction, time-reversibility and
kick-drift-kick loads; rkmk4's L (exact torque-free, as rk4's), its energy drift, its exactness on a
sphere, and that it is not MuJoCo 4's RK4 (the engine map rkmk4-body).
Compiled == readable step by step: tests/test_compiled_maps.py (every integrator)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from freebody.input.casefile import load_case
from freebody.reference_impl.dynamics import wrench_function
from freebody.reference_impl.integrators import INTEGRATORS, simulate
from freebody.reference_impl.lie_integrators import (MIDPOINT_RTOL, cayley_quat, implicit_midpoint_step,
                                                     midpoint_momentum)
from freebody.reference_impl.problem import InitialState, Problem
from freebody.reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec
from freebody.reference_impl.truth import truth_trajectory
from freebody.run.metrics import energies
from freebody.testing import assert_same_rotation

from test_splitting import AREA_CHANGE_MIN, _energy_error, _jacobian_det, _reduced_map

MIDPOINT, RKMK4 = "implicit-midpoint", "rkmk4"
DT = 0.01  # s: the default suite's coarse step
SHORT_S, LONG_S, VERY_LONG_S = 10.0, 200.0, 1000.0

# Fitted order of the orientation error on the convergence cases at their four time steps (0.04 to
# 0.005 s, 1 s).  Measured: implicit-midpoint 1.9987 (tumbling) and 1.9983 (body torque); rkmk4
# 4.0287 and 4.0290 (its largest step, 0.04 s, is still a little outside the asymptotic range).
ORDER_TOLERANCE = {MIDPOINT: 0.05, RKMK4: 0.1}
EXPECTED_ORDER = {MIDPOINT: 2.0, RKMK4: 4.0}
# implicit-midpoint, torque-free: Newton stops at a correction below MIDPOINT_RTOL |Pi| (1e-13), so
# the accepted step solves the midpoint equation to round-off, and the energy and |L| are kept to
# round-off.  Measured on dzhanibekov at dt 0.01 s: energy at most 4.8e-15 of KE(0) over 10 s,
# 8.7e-15 over 200 s, 1.3e-14 over 1000 s (round-off's random walk); L 3.7e-15 relative.  The bound
# is ten times the solver's tolerance: a step solved only to that tolerance every time could not
# pass it by much, a first-order drift (rk4's is 1.6e-7 over 200 s) fails it by 1e5.
MIDPOINT_ENERGY_RTOL = 10 * MIDPOINT_RTOL
# L (world) recomputed from the output w = R I^-1 R^T L: L to a few roundings of the products
# (measured 3.7e-15 relative over 1000 s for both integrators).
L_RTOL = 1e-13
# rkmk4 is not energy-conserving: on dzhanibekov at dt 0.01 s it loses energy slowly, like rk4
# (measured -1.02e-7 of KE(0) at 200 s, -4.98e-7 at 1000 s; rk4: -1.55e-7 and -7.41e-7).
RKMK4_ENERGY_AT_200_S = (-2e-7, -5e-8)
# Time-reversibility: forward 500 steps, back 500 steps of -dt, to round-off (measured 7.3e-15 rad
# for implicit-midpoint; rkmk4 is not symmetric: 1.4e-8 rad).
REVERSIBLE_RAD = 1e-12
RKMK4_IRREVERSIBLE_MIN_RAD = 1e-10
# On a sphere rkmk4's step is the exact rotation (every stage rate is L / I): round-off only
# (measured 4.9e-15 rad over 200 steps); the implicit midpoint's Cayley turn is not (0.037 rad).
EXACT_RAD = 1e-12
CAYLEY_NOT_EXACT_MIN_RAD = 1e-3
# A constant force on the COM: kick-drift-kick gives the parabola exactly (measured 1.2e-14 m), and
# RK4 integrates a quadratic exactly too (1.6e-14 m).
PARABOLA_M = 1e-12
# rkmk4 against the engine map rkmk4-body (MuJoCo 4's RK4) on convergence_tumbling: both fourth
# order, different methods, so they differ by O(h^4) over the second: measured 5.1e-6, 3.1e-7,
# 1.9e-8 and 1.2e-9 rad at dt 0.04 to 0.005 s: far above round-off (1e-14).
DISTINCT_FROM_RKMK4_BODY_MIN_RAD = 1e-10
# One step of the midpoint rule from a random body momentum (|Pi| ~ 3, h |w| up to ~1): Pi+ = R+^T L
# satisfies Pi+ = Pi + h Pi_mid x I^-1 Pi_mid to round-off (measured residual 2e-15 relative).
MIDPOINT_RESIDUAL_RTOL = 1e-13


def _angular_momentum(pb: Problem, tr) -> np.ndarray:
    """L = R I_b R^T w (N, 3) kg m^2/s world, from a trajectory's outputs."""
    R = matrix_from_quat(tr.quaternion_wxyz)
    return np.einsum("nij,jk,nlk,nl->ni", R, pb.body.I_body, R, tr.angular_velocity)


def test_they_are_reference_integrators_of_orders_two_and_four():
    assert INTEGRATORS[MIDPOINT].order == 2 and INTEGRATORS[RKMK4].order == 4
    assert not INTEGRATORS[MIDPOINT].uses_matrix and not INTEGRATORS[RKMK4].uses_matrix


@pytest.mark.parametrize("name", [MIDPOINT, RKMK4])
@pytest.mark.parametrize("case", ["convergence_tumbling", "convergence_body_torque"])
def test_observed_order_on_the_convergence_cases(name, case):
    pb = load_case(case)
    errs = []
    for dt in pb.dts:
        n = pb.steps(dt)
        truth = truth_trajectory(pb, dt, n)
        errs.append(geodesic_angle(truth.quaternion_wxyz, simulate(pb, name, dt, n).quaternion_wxyz).max())
    order = float(np.polyfit(np.log(pb.dts), np.log(errs), 1)[0])
    assert abs(order - EXPECTED_ORDER[name]) < ORDER_TOLERANCE[name], (order, errs)


def _conservation(duration: float):
    pb = load_case("dzhanibekov")
    n = int(round(duration / DT))
    tr = simulate(pb, MIDPOINT, DT, n)
    ke, E = energies(pb, tr)
    L = _angular_momentum(pb, tr)
    L0 = np.linalg.norm(L[0])
    assert np.abs(E - E[0]).max() <= MIDPOINT_ENERGY_RTOL * ke[0]
    assert np.abs(L - L[0]).max() <= L_RTOL * L0
    assert np.abs(np.linalg.norm(L, axis=1) - L0).max() <= L_RTOL * L0


def test_implicit_midpoint_keeps_energy_and_L_over_200_s():
    _conservation(LONG_S)
    # the contrast: rk4, fourth order, drifts
    assert abs(_energy_error(load_case("dzhanibekov"), "rk4", DT, LONG_S)[-1]) > 1e3 * MIDPOINT_ENERGY_RTOL


@pytest.mark.slow
def test_implicit_midpoint_keeps_energy_and_L_over_1000_s():
    _conservation(VERY_LONG_S)


def test_the_midpoint_equation_holds_and_the_cayley_turn_keeps_L():
    """One step from R = 1, L = Pi: R+^T L solves the midpoint rule on Pi (the Cayley map is the
    reconstruction the rule implies), and |Pi| and the energy are the same after it."""
    rng = np.random.default_rng(17)
    I_b = np.diag([1.0, 2.0, 3.0])
    I_inv = np.linalg.inv(I_b)
    no_loads = wrench_function(load_case("dzhanibekov"), DT)  # a case without loads
    assert not load_case("dzhanibekov").loads
    for _ in range(50):
        Pi = 3.0 * rng.normal(size=3)
        h = float(rng.uniform(0.01, 0.3))
        w_mid = midpoint_momentum(Pi, h, I_inv)
        Pi_new = matrix_from_quat(cayley_quat(h * w_mid)).T @ Pi
        Pi_mid = 0.5 * (Pi + Pi_new)
        residual = Pi_new - Pi - h * np.cross(Pi_mid, I_inv @ Pi_mid)
        assert np.linalg.norm(residual) <= MIDPOINT_RESIDUAL_RTOL * np.linalg.norm(Pi)
        assert np.allclose(I_inv @ Pi_mid, w_mid, rtol=0, atol=MIDPOINT_RESIDUAL_RTOL * np.linalg.norm(w_mid))
        assert Pi_new @ I_inv @ Pi_new == pytest.approx(Pi @ I_inv @ Pi, rel=MIDPOINT_RESIDUAL_RTOL)
        # the step itself, torque-free: L untouched, q turned by the Cayley map of h w_mid
        q0 = quat_from_rotvec(rng.normal(size=3))
        L = matrix_from_quat(q0) @ Pi
        x, q, p, L1 = implicit_midpoint_step(0, np.zeros(3), q0, np.zeros(3), L, h, 1.0, I_inv, np.zeros(3), no_loads)
        assert np.array_equal(L1, L)
        assert np.allclose(matrix_from_quat(q).T @ L, Pi_new, rtol=0, atol=MIDPOINT_RESIDUAL_RTOL * np.linalg.norm(Pi))


def test_implicit_midpoint_keeps_the_momentum_sphere_but_not_its_area():
    """Not a Poisson map (Austin, Krishnaprasad & Wang 1993): |Pi| is kept, the area on the sphere
    |Pi| = const is not (the Jacobian determinant of the reduced map, as in test_splitting: measured
    |det - 1| up to 2.9e-3 at h = 0.1 s; rkmk4 3.5e-5; the splitting 1e-10)."""
    rng = np.random.default_rng(3)
    I_b = np.diag([1.0, 2.0, 3.0])
    points = [3.0 * rng.normal(size=3) for _ in range(5)]
    for Pi in points:
        assert np.linalg.norm(_reduced_map(MIDPOINT, Pi, 0.1, I_b)) == pytest.approx(np.linalg.norm(Pi), rel=1e-14)
    assert max(abs(_jacobian_det(MIDPOINT, Pi, 0.1, I_b) - 1.0) for Pi in points) > AREA_CHANGE_MIN


def test_cayley_quat_is_the_cayley_transform():
    rng = np.random.default_rng(4)
    for _ in range(20):
        u = rng.normal(size=3)
        S = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
        cay = np.linalg.solve(np.eye(3) - 0.5 * S, np.eye(3) + 0.5 * S)
        np.testing.assert_allclose(matrix_from_quat(cayley_quat(u)), cay, rtol=0, atol=1e-14)


def test_implicit_midpoint_is_time_reversible_and_rkmk4_is_not():
    pb = load_case("convergence_tumbling")
    n = 500
    for name in (MIDPOINT, RKMK4):
        fwd = simulate(pb, name, DT, n)
        end = dataclasses.replace(pb, initial=InitialState(fwd.position[-1], fwd.quaternion_wxyz[-1],
                                                           fwd.linear_velocity[-1], fwd.angular_velocity[-1]))
        back = simulate(end, name, -DT, n)
        angle = geodesic_angle(back.quaternion_wxyz[-1], fwd.quaternion_wxyz[0])
        if name == MIDPOINT:
            assert angle < REVERSIBLE_RAD
        else:
            assert angle > RKMK4_IRREVERSIBLE_MIN_RAD


def test_rkmk4_keeps_L_and_drifts_in_energy_like_rk4():
    pb = load_case("dzhanibekov")
    n = int(round(LONG_S / DT))
    tr = simulate(pb, RKMK4, DT, n)
    L = _angular_momentum(pb, tr)
    assert np.abs(L - L[0]).max() <= L_RTOL * np.linalg.norm(L[0])
    ke, E = energies(pb, tr)
    lo, hi = RKMK4_ENERGY_AT_200_S
    assert lo < (E[-1] - E[0]) / ke[0] < hi


def test_rkmk4_is_exact_on_a_sphere_and_the_cayley_turn_is_not():
    pb = load_case("spinning_sphere")
    dt = pb.dts[0]
    n = pb.steps(dt)
    truth = truth_trajectory(pb, dt, n)
    assert_same_rotation(truth.quaternion_wxyz, simulate(pb, RKMK4, dt, n).quaternion_wxyz, EXACT_RAD)
    assert geodesic_angle(truth.quaternion_wxyz, simulate(pb, MIDPOINT, dt, n).quaternion_wxyz).max() > CAYLEY_NOT_EXACT_MIN_RAD


@pytest.mark.parametrize("name", [MIDPOINT, RKMK4])
def test_loads_keep_L_torque_free_and_a_constant_force_gives_the_parabola(name):
    pb = load_case("projectile")  # tumbling under gravity
    dt = pb.dts[0]
    n = pb.steps(dt)
    tr = simulate(pb, name, dt, n)
    L = _angular_momentum(pb, tr)
    assert np.abs(L - L[0]).max() <= L_RTOL * np.linalg.norm(L[0])
    assert np.abs(tr.position - truth_trajectory(pb, dt, n).position).max() < PARABOLA_M


def test_rkmk4_is_not_mujoco_4s_rk4():
    """rkmk4-body integrates w_b by RK4 on Euler's equations; rkmk4 integrates L and derives w at
    each stage: both fourth order, not the same map even torque-free."""
    pb = load_case("convergence_tumbling")
    n = pb.steps(DT)
    diff = geodesic_angle(simulate(pb, RKMK4, DT, n).quaternion_wxyz,
                          simulate(pb, "rkmk4-body", DT, n).quaternion_wxyz).max()
    assert diff > DISTINCT_FROM_RKMK4_BODY_MIN_RAD
