"""The numerical truth's compiled right-hand side (reference_impl/truth_rhs.py) against the readable
numpy one it replaces by default (truth._numpy_rhs): the same equations, equal to rounding, call by
call and over whole truths, with the same DOP853 steps."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.input.casefile import load_case
from freebody.reference_impl import truth, truth_rhs
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.truth import numerical_trajectory

# One call: the two differ only in evaluation order (numpy's 3x3 products and norm go through
# BLAS, fused multiply-adds), a few ulps of the largest component of dy/dt.
RHS_RTOL = 1e-14
# A whole truth: DOP853 at rtol = atol = 1e-12 carries a few-ulp difference in the right-hand side
# to at most about its tolerance; measured 5e-14 (w, body_torque_spinup, 2 s at 1 ms).
TRUTH_ATOL = 1e-12

LOADS = {
    "none": (),
    "com force": (Load(force=[1.0, -2.0, 0.5]),),
    "world point": (Load(force=[3.0, 2.0, -1.0], point=[-1.0, 0.5, 0.2]),),
    "body point": (Load(force=[0.0, 0.0, 3.0], body_point=[0.2, 0.3, -0.1]),),
    "world torque": (Load(torque=[0.3, -0.1, 1.0]),),
    "body torque": (Load(body_torque=[0.1, 0.0, 1.2]),),
    "all, in order": (Load(force=[1.0, 2.0, 3.0], body_point=[0.1, -0.2, 0.3], torque=[0.5, 0.0, 0.1],
                           body_torque=[0.0, 0.4, -0.2]),
                      Load(force=[-2.0, 0.5, 1.0], point=[2.0, -1.0, 0.5]),
                      Load(body_torque=[0.2, 0.2, 0.2])),
}


def _problem(loads) -> Problem:
    I_b = np.array([[0.4, 0.02, -0.01], [0.02, 0.6, 0.03], [-0.01, 0.03, 0.8]])
    init = InitialState([0.1, -0.2, 1.0], [0.9, 0.1, -0.3, 0.2], [0.5, -1.0, 2.0], [1.0, 4.0, -0.5])
    return Problem("t", "", Body(2.5, I_b), init, np.array([0.0, 0.0, -9.81]), loads, duration=0.5)


@pytest.mark.parametrize("name", list(LOADS))
def test_rhs_agrees_with_numpy(name):
    pb = _problem(LOADS[name])
    numpy_rhs = truth._numpy_rhs(pb, pb.loads)
    compiled_rhs = truth._compiled_rhs(pb)(pb.loads)
    rng = np.random.default_rng(29)
    for _ in range(20):
        y = rng.normal(size=13) * [1, 1, 1, 2, 2, 2, 1, 1, 1, 1, 5, 5, 5]  # q left unnormalised
        a, b = numpy_rhs(0.0, y), compiled_rhs(0.0, y)
        assert b.shape == (13,)
        np.testing.assert_allclose(b, a, rtol=0, atol=RHS_RTOL * np.max(np.abs(a)))


def _counting_solver(monkeypatch):
    """Record solve_ivp's evaluations per call."""
    nfev = []

    def counted(*args, **kwargs):
        sol = solver(*args, **kwargs)
        nfev.append(sol.nfev)
        return sol
    solver = truth.solve_ivp
    monkeypatch.setattr(truth, "solve_ivp", counted)
    return nfev


@pytest.mark.parametrize("case, dt", [("body_torque_spinup", 0.01), ("offset_push", 0.01),
                                      ("quiz", 0.1), ("convergence_body_point_force", 0.02)])
def test_truth_agrees_with_numpy(monkeypatch, case, dt):
    """The case's loads (body couple; a body-point push switched on and off; a world-point kick of
    one step) through both right-hand sides: the same steps (evaluations), states equal to round-off."""
    pb = load_case(case)
    steps = pb.steps(dt)
    nfev = _counting_solver(monkeypatch)
    a = numerical_trajectory(pb, dt, steps, compiled=False)
    n_numpy = list(nfev)
    nfev.clear()
    b = numerical_trajectory(pb, dt, steps)
    assert nfev == n_numpy
    for field in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        np.testing.assert_allclose(getattr(b, field), getattr(a, field), rtol=0, atol=TRUTH_ATOL)
    np.testing.assert_array_equal(b.t, a.t)


def test_truths_use_the_compiled_rhs(monkeypatch):
    """truth_trajectory and truth_chunks (what the harness calls) evaluate the compiled rhs."""
    calls = []
    compiled = truth_rhs.body_frame_rhs

    def counted(y, body, loads):
        calls.append(loads.shape[0])
        return compiled(y, body, loads)
    monkeypatch.setattr(truth_rhs, "body_frame_rhs", counted)
    pb = load_case("offset_push")
    truth.truth_trajectory(pb, 0.01, 100)
    assert calls and set(calls) == {0, 1}  # before/after the push, and during it
    calls.clear()
    list(truth.truth_chunks(pb, 0.01, 100, 30))
    assert calls


def test_closed_form_truth_does_not_load_the_compiled_rhs():
    """Only a numerical truth imports truth_rhs (and numba with it): a closed-form truth's process
    does not pay for it."""
    import subprocess
    import sys

    code = ("import sys; from freebody.input.casefile import load_case; "
            "from freebody.reference_impl.truth import truth_trajectory; "
            "truth_trajectory(load_case('dzhanibekov'), 0.01, 10); "
            "print('freebody.reference_impl.truth_rhs' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
