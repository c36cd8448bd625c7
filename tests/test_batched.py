"""The batched reference integrators reproduce the single-body ones, body by body, to round-off."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.input.casefile import load_case
from freebody.reference_impl.batched import (BATCHED_INTEGRATORS, _EXP_Z_LIMITS, _Work, _exp_into,
                                             quat_from_matrix_batch, simulate_batch,
                                             simulate_problem, supports_problem,
                                             torque_free_rotation_batch)
from freebody.reference_impl.integrators import INTEGRATORS, simulate
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.rotations import (geodesic_angle, quat_from_matrix, quat_from_rotvec,
                                               quat_multiply)
from freebody.reference_impl.torque_free import torque_free_rotation

# Batched vs single-body code: the same maps with the arithmetic reordered (principal frame,
# quaternion rotations, Exp from a series); measured <= 3e-14 over 40 steps of random bodies.
BATCH_VS_SINGLE = 1e-12
# Exp (as the normalised product it enters) vs rotations.quat_from_rotvec: a few ulps.
EXP_ULPS = 4
STEPS = 40
DT = 0.01


def _random_bodies(rng: np.random.Generator, B: int):
    """B random rigid bodies (full inertias obeying the triangle inequality) and states."""
    moments = rng.uniform(0.5, 2.0, size=(B, 3))
    moments[:, 2] = np.minimum(moments[:, 2], moments[:, 0] + moments[:, 1])
    axes = quat_from_rotvec(rng.normal(size=(B, 3)))
    from freebody.reference_impl.rotations import matrix_from_quat

    P = matrix_from_quat(axes)
    I = np.einsum("bij,bj,bkj->bik", P, moments, P)
    q = rng.normal(size=(B, 4))
    return dict(mass=rng.uniform(0.5, 3.0, size=B), I_body=I,
                position=rng.normal(size=(B, 3)), quaternion_wxyz=q / np.linalg.norm(q, axis=1)[:, None],
                linear_velocity=rng.normal(size=(B, 3)), angular_velocity=3.0 * rng.normal(size=(B, 3)))


def _problem(bodies: dict, b: int, gravity, force, torque) -> Problem:
    loads = ()
    if force is not None or torque is not None:
        loads = (Load(force=np.zeros(3) if force is None else force[b],
                      torque=np.zeros(3) if torque is None else torque[b]),)
    return Problem("body", "", Body(bodies["mass"][b], bodies["I_body"][b]),
                   InitialState(bodies["position"][b], bodies["quaternion_wxyz"][b],
                                bodies["linear_velocity"][b], bodies["angular_velocity"][b]),
                   gravity=gravity, loads=loads, duration_steps=STEPS, dts=(DT,))


def _assert_close(single, batch_body, name):
    scale = 1.0 + np.max(np.abs(single.angular_velocity))
    assert np.max(geodesic_angle(single.quaternion_wxyz, batch_body.quaternion_wxyz)) < BATCH_VS_SINGLE, name
    for f in ("position", "linear_velocity"):
        a, b = getattr(single, f), getattr(batch_body, f)
        assert np.max(np.abs(a - b)) < BATCH_VS_SINGLE * (1.0 + np.max(np.abs(a))), (name, f)
    w_err = np.max(np.abs(single.angular_velocity - batch_body.angular_velocity))
    assert w_err < BATCH_VS_SINGLE * scale, name
    np.testing.assert_array_equal(single.t, batch_body.t)
    if single.orthonormality_error is not None:
        np.testing.assert_allclose(batch_body.orthonormality_error, single.orthonormality_error,
                                   rtol=0, atol=BATCH_VS_SINGLE)


@pytest.mark.parametrize("name", BATCHED_INTEGRATORS)
@pytest.mark.parametrize("loads", ["free", "gravity", "wrench"])
def test_every_body_of_a_batch_matches_the_single_body_integrator(name, loads):
    rng = np.random.default_rng(7)
    B = 4
    bodies = _random_bodies(rng, B)
    gravity = np.zeros(3) if loads == "free" else np.array([0.0, 0.0, -9.81])
    force = rng.normal(size=(B, 3)) if loads == "wrench" else None
    torque = rng.normal(size=(B, 3)) if loads == "wrench" else None
    out = simulate_batch(name, dt=DT, steps=STEPS, gravity=gravity, force=force, torque=torque, **bodies)
    assert out.position.shape == (STEPS + 1, B, 3) and out.quaternion_wxyz.shape == (STEPS + 1, B, 4)
    assert (out.orthonormality_error is not None) == INTEGRATORS[name].uses_matrix
    for b in range(B):
        single = simulate(_problem(bodies, b, gravity, force, torque), name, DT, STEPS)
        _assert_close(single, out.body(b), f"{name} body {b}")


@pytest.mark.parametrize("name", BATCHED_INTEGRATORS)
@pytest.mark.parametrize("case", ["dzhanibekov", "dzhanibekov_rotated", "projectile"])
def test_one_problem_through_the_batched_path_matches_the_reference(name, case):
    pb = load_case(case)
    assert supports_problem(pb, DT, STEPS)
    _assert_close(simulate(pb, name, DT, STEPS), simulate_problem(pb, name, DT, STEPS), name)


def test_shared_inputs_broadcast_and_match_per_body_inputs():
    rng = np.random.default_rng(11)
    B = 3
    q = rng.normal(size=(B, 4))
    w = rng.normal(size=(B, 3))
    I = np.diag([1.0, 2.0, 3.0])
    shared = simulate_batch("semi-implicit-implicit-gyro", 2.0, I, np.zeros(3), q, np.zeros(3), w,
                            DT, STEPS, gravity=[0, 0, -9.81])
    per_body = simulate_batch("semi-implicit-implicit-gyro", np.full(B, 2.0), np.broadcast_to(I, (B, 3, 3)),
                              np.zeros((B, 3)), q, np.zeros((B, 3)), w, DT, STEPS, gravity=[0, 0, -9.81])
    for f in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(shared, f), getattr(per_body, f))


def test_every_keeps_the_samples_it_says_and_the_last():
    bodies = _random_bodies(np.random.default_rng(3), 2)
    full = simulate_batch("rk4", dt=DT, steps=10, **bodies)
    thin = simulate_batch("rk4", dt=DT, steps=10, every=4, **bodies)
    np.testing.assert_array_equal(thin.t, full.t[[0, 4, 8, 10]])
    np.testing.assert_array_equal(thin.quaternion_wxyz, full.quaternion_wxyz[[0, 4, 8, 10]])


def test_exp_series_and_its_sin_cos_fallback_match_the_exponential_map():
    rng = np.random.default_rng(5)
    scales = [0.0, 1e-9, 1e-4, 1e-2, 0.1, 0.3, 0.7, 1.0, 3.0]  # the last ones: sin/cos path
    assert np.sqrt(_EXP_Z_LIMITS[-1]) < 1.0
    q = quat_from_rotvec(rng.normal(size=(50, 3)))
    for scale in scales:
        phi = scale * rng.normal(size=(50, 3))
        wk = _Work(50)
        wk.e6[1:4] = phi.T
        wk.e6[4:6] = wk.e6[1:3]
        e = _exp_into(wk)[0:4].T
        got = quat_multiply(q, e)
        got /= np.linalg.norm(got, axis=1, keepdims=True)
        want = quat_multiply(q, quat_from_rotvec(phi))
        assert np.max(np.abs(got - want)) <= EXP_ULPS * np.finfo(float).eps, scale


def test_quat_from_matrix_batch_is_the_vectorised_twin():
    rng = np.random.default_rng(9)
    from freebody.reference_impl.rotations import matrix_from_quat

    R = matrix_from_quat(rng.normal(size=(64, 4)))
    R[3] = np.diag([1.0, -1.0, -1.0])  # each of Shepperd's four branches, among the random ones
    R[4] = np.diag([-1.0, 1.0, -1.0])
    R[5] = np.diag([-1.0, -1.0, 1.0])
    R[6, 0, 0] = np.nan
    got = quat_from_matrix_batch(R)
    want = quat_from_matrix(R)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    np.testing.assert_allclose(got[ok], want[ok], rtol=0, atol=4 * np.finfo(float).eps)


def test_a_blow_up_becomes_non_finite_samples_not_an_exception():
    out = simulate_batch("euler-matrix", 1.0, np.diag([1.0, 2.0, 3.0]), np.zeros(3), [1, 0, 0, 0],
                         np.zeros(3), [[1e3, 2e3, 5.0]], 1.0, 30)
    assert not np.all(np.isfinite(out.quaternion_wxyz[-1]))


def test_bad_shapes_are_value_errors_naming_the_input():
    with pytest.raises(ValueError, match="angular_velocity"):
        simulate_batch("rk4", 1.0, np.eye(3), np.zeros((3, 3)), np.tile([1.0, 0, 0, 0], (3, 1)),
                       np.zeros((3, 3)), np.zeros((2, 3)), DT, 1)
    with pytest.raises(ValueError, match="unknown integrator"):
        simulate_batch("leapfrog", 1.0, np.eye(3), np.zeros(3), [1, 0, 0, 0], np.zeros(3),
                       np.zeros(3), DT, 1)


def test_problems_with_loads_beyond_constant_wrenches_are_refused():
    pb = load_case("quiz")  # a one-step push at a world point
    assert not supports_problem(pb, pb.dts[0], pb.steps(pb.dts[0]))
    with pytest.raises(ValueError, match="quiz"):
        simulate_problem(pb, "rk4", pb.dts[0], pb.steps(pb.dts[0]))


def test_closed_form_truth_of_a_batch_is_the_single_body_closed_form():
    bodies = _random_bodies(np.random.default_rng(13), 3)
    bodies["I_body"][1] = np.diag([1.0, 1.0, 2.0])    # axisymmetric
    bodies["angular_velocity"][2] = 0.0               # at rest
    t = np.arange(6) * 0.1
    q, w = torque_free_rotation_batch(bodies["I_body"], bodies["quaternion_wxyz"],
                                      bodies["angular_velocity"], t)
    assert q.shape == (6, 3, 4) and w.shape == (6, 3, 3)
    for b in range(3):
        qb, wb = torque_free_rotation(bodies["I_body"][b], bodies["quaternion_wxyz"][b],
                                      bodies["angular_velocity"][b], t)
        np.testing.assert_array_equal(q[:, b], qb)
        np.testing.assert_array_equal(w[:, b], wb)


def test_closed_form_batch_is_the_closed_form_truth_of_each_body():
    from freebody.reference_impl.batched import closed_form_batch
    from freebody.reference_impl.truth import closed_form_trajectory

    pb = load_case("projectile")
    init = pb.initial
    out = closed_form_batch(pb.body.I_body, init.position[None], init.quaternion_wxyz[None],
                            init.linear_velocity[None], init.angular_velocity[None], pb.gravity,
                            np.arange(STEPS + 1) * DT)
    truth = closed_form_trajectory(pb, DT, STEPS)
    for f in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        got = getattr(out, f) if f == "t" else getattr(out, f)[:, 0]
        np.testing.assert_allclose(got, getattr(truth, f), rtol=0, atol=1e-15 * (1 + np.max(np.abs(got))))
