"""The compiled maps (``reference_impl/compiled.py``) against the numpy reference
(``reference_impl/integrators.py``): every scheme step by step from the same states, the loads, the
matrix integrators' outputs, whole runs, and ``simulate``'s wiring."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.reference_impl import compiled as C
from freebody.reference_impl import integrators as ref
from freebody.reference_impl.dynamics import wrench_function
from freebody.reference_impl.integrators import INTEGRATORS, simulate
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.splitting import principal_frame
from freebody.reference_impl.rotations import (matrix_from_quat, nearest_rotation, orthonormality_error,
                                               quat_from_matrix, quat_from_rotvec)

EPS = np.finfo(float).eps
# One step of a compiled map against its numpy step from the same state, in ulps of the largest
# component of each state vector.  numpy's 3x3 products go through BLAS (fused multiply-adds, its
# own order of summation; which kernel depends on the CPU) and np.linalg.solve through LAPACK, so a
# step rounds differently in a few places.  Measured here: at most 2 ulps (x and v: identical).
STEP_ULPS = 8
# What the matrix integrators report of a state: the nearest rotation (numpy: SVD; compiled:
# Newton's polar iteration) and its quaternion, in ulps times the polar factor's condition
# (polar_condition), and w = R I_b^-1 R^T L (three BLAS products).  Measured: at most 16 and 10.
OUTPUT_ULPS = 64
# ||R^T R - 1||_F of the same matrix, compiled vs numpy: the error is itself rounding of the
# entries of R^T R (about |R|_F^2 eps each), in units of eps |R|_F^2.  Measured: at most 0.52.
ORTHONORMALITY_ULPS = 4
# Whole runs of STEPS steps, compiled vs numpy, relative to each series' largest value: the
# per-step differences above, carried and amplified by the dynamics over the run (moderate rates,
# 200 steps, no chaotic case).  Measured: at most 5.2e-14.
RUN_RTOL = 1e-12
# Explicit Euler's R this far from a rotation is blowing up (|R| grows like (1 + h^2 |w|^2)^(k/2)
# and w like |R|^2): its steps then cancel ever larger terms, so rounding is no longer a few ulps of
# the result, and the harness calls the run diverged soon after.  Steps from there on are not compared.
BLOWN_UP_ORTHONORMALITY = 1.0
BODIES = 50
STEPS = 200
SCHEMES = tuple(INTEGRATORS)
LOAD_KINDS = ("com force", "world couple", "body couple", "force at a world point",
              "force at a body point")


def _window(rng, dt: float) -> dict:
    """A random on-interval within the run: from a step on for ever, for some steps, or to an end."""
    start = int(rng.integers(0, STEPS)) * dt
    r = int(rng.integers(0, 3))
    if r == 0:
        return {"start": start}
    if r == 1:
        return {"start": start, "steps": int(rng.integers(1, STEPS))}
    return {"start": start, "end": start + int(rng.integers(1, STEPS)) * dt}


def _load(rng, kind: str, dt: float, x0) -> Load:
    f = 3.0 * rng.normal(size=3)
    if kind == "com force":
        return Load(force=f, **_window(rng, dt))
    if kind == "world couple":
        return Load(torque=rng.normal(size=3), **_window(rng, dt))
    if kind == "body couple":
        return Load(body_torque=rng.normal(size=3), **_window(rng, dt))
    if kind == "force at a world point":
        return Load(force=f, point=x0 + 2.0 * rng.normal(size=3), torque=rng.normal(size=3), **_window(rng, dt))
    return Load(force=f, body_point=rng.normal(size=3), body_torque=rng.normal(size=3), **_window(rng, dt))


def random_problem(rng, i: int) -> tuple[Problem, float]:
    """Body i: a random full inertia, state, time step, gravity or none, and loads of every kind
    switching on and off within the run (the first few bodies torque-free)."""
    moments = rng.uniform(0.2, 3.0, 3)
    moments[2] = min(moments[2], moments[0] + moments[1])
    P = matrix_from_quat(quat_from_rotvec(rng.normal(size=3)))
    q = rng.normal(size=4)
    dt = float(rng.choice([1e-3, 5e-3, 1e-2]))
    kinds = [] if i < 5 else [LOAD_KINDS[j % 5] for j in range(i % 5, i % 5 + int(rng.integers(1, 7)))]
    gravity = [0.0, 0.0, -9.81] if rng.random() < 0.5 else [0.0, 0.0, 0.0]
    x0 = 10.0 * rng.normal(size=3)
    problem = Problem(f"body{i}", "", Body(rng.uniform(0.3, 5.0), P @ np.diag(moments) @ P.T),
                      InitialState(x0, q / np.linalg.norm(q), rng.normal(size=3), 2.0 * rng.normal(size=3)),
                      gravity=gravity, loads=tuple(_load(rng, k, dt, x0) for k in kinds),
                      duration_steps=STEPS, dts=(dt,))
    return problem, dt


PROBLEMS = [random_problem(np.random.default_rng(1000 + i), i) for i in range(BODIES)]


def ulps(a, b) -> float:
    """max |a - b| in ulps of a's largest component."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    return float(np.max(np.abs(a - b)) / (EPS * max(np.max(np.abs(a)), np.finfo(float).tiny)))


def test_random_problems_have_loads_of_every_kind():
    seen = set()
    for pb, _ in PROBLEMS:
        for ld in pb.loads:
            seen.add("force at a world point" if ld.point is not None else
                     "force at a body point" if ld.body_point is not None else
                     "com force" if np.any(ld.force) else
                     "body couple" if np.any(ld.body_torque) else "world couple")
    assert seen == set(LOAD_KINDS)
    assert any(not pb.loads for pb, _ in PROBLEMS)


@pytest.mark.parametrize("b", range(0, BODIES, 3))
def test_wrench_is_problem_wrench_on_every_step(b):
    pb, dt = PROBLEMS[b]
    rng = np.random.default_rng(b)
    loads = C.loads_of(pb, dt)
    for k in range(STEPS + 2):
        x, R = rng.normal(size=3), matrix_from_quat(rng.normal(size=4))
        f, tau = pb.wrench(pb.active_loads(k, dt), x, R)
        fc, tauc = C.wrench(k, C.vec(x), C.mat(R), loads)
        assert np.array_equal(f, fc), k  # forces: the same sums in the same order
        assert ulps(tau, tauc) <= STEP_ULPS if np.any(tau) else not np.any(tauc), k


def _initial_state(scheme: str, pb: Problem) -> tuple:
    M, I_b, I_inv, x, q, R, p, L, v, w = ref.initial_arrays(pb)
    if scheme.startswith("euler-matrix"):
        return x, R, p, L
    if scheme.startswith("semi-implicit"):
        return x, q, v, R.T @ w
    return x, q, p, L


def _steps(scheme: str, pb: Problem, dt: float):
    """(numpy step, compiled step) of ``scheme`` as functions of (k, state)."""
    M, I_b, I_inv = pb.body.mass, pb.body.I_body, pb.body.I_body_inv
    g, wrench, loads = pb.gravity, wrench_function(pb, dt), C.loads_of(pb, dt)
    I_b_c, I_inv_c, g_c, Mg_c = C.mat(I_b), C.mat(I_inv), C.vec(g), C.vec(M * g)

    def tuples(state):
        return tuple(C.mat(s) if np.ndim(s) == 2 else C.vec(s) for s in state)

    if scheme.startswith("euler-matrix"):
        gram = scheme == "euler-matrix-gs"
        return (lambda k, s: ref.euler_matrix_step(k, *s, dt, M, I_inv, M * g, wrench, gram),
                lambda k, s: C.euler_matrix_step(k, *tuples(s), dt, M, I_inv_c, Mg_c, loads, gram))
    if scheme.startswith("semi-implicit"):
        implicit = scheme == "semi-implicit-implicit-gyro"
        return (lambda k, s: ref.semi_implicit_step(k, *s, dt, M, I_b, I_inv, g, wrench, implicit),
                lambda k, s: C.semi_implicit_step(k, *tuples(s), dt, M, I_b_c, I_inv_c, g_c, loads, implicit))
    if scheme == "symplectic-splitting":
        frame = principal_frame(I_b)
        axes_c, moments_c = C.mat(frame.axes), C.vec(frame.moments)
        return (lambda k, s: ref.splitting_step(k, *s, dt, M, frame, g, wrench),
                lambda k, s: C.splitting_step(k, *tuples(s), dt, M, axes_c, moments_c, g_c, loads))
    numpy_step, compiled_step = {"euler-quat": (ref.euler_quat_step, C.euler_quat_step),
                                 "lie-euler": (ref.lie_euler_step, C.lie_euler_step),
                                 "rk4": (ref.rk4_step, C.rk4_step),
                                 "implicit-midpoint": (ref.implicit_midpoint_step, C.implicit_midpoint_step),
                                 "rkmk4": (ref.rkmk4_step, C.rkmk4_step)}[scheme]
    return (lambda k, s: numpy_step(k, *s, dt, M, I_inv, g, wrench),
            lambda k, s: compiled_step(k, *tuples(s), dt, M, I_inv_c, g_c, loads))


def polar_condition(A) -> float:
    """How much the nearest rotation of A amplifies a rounding of A's entries (relative to |A|):
    sigma_1 / (sigma_2 + sigma_3), at least 1 (1/2 for a rotation)."""
    s = np.linalg.svd(A, compute_uv=False)
    return max(1.0, s[0] / (s[1] + s[2]))


def _same_up_to_sign(a, b) -> float:
    return min(ulps(a, b), ulps(a, -np.asarray(b)))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_every_step_equals_the_numpy_step(scheme):
    """From each state of a numpy run (BODIES bodies x STEPS steps), one compiled step lands on
    the numpy step's state to a few ulps; matrix integrators' outputs (nearest rotation's quaternion,
    w, orthonormality error) too."""
    worst = 0.0
    for pb, dt in PROBLEMS:
        numpy_step, compiled_step = _steps(scheme, pb, dt)
        state = _initial_state(scheme, pb)
        for k in range(STEPS):
            with np.errstate(all="ignore"):
                new = numpy_step(k, state)
            if scheme.startswith("euler-matrix") and orthonormality_error(new[1]) > BLOWN_UP_ORTHONORMALITY:
                break
            got = compiled_step(k, state)
            for name, a, b in zip("xyzw", new, got):
                worst = max(worst, ulps(a, b))
                assert ulps(a, b) <= STEP_ULPS, (pb.name, k, name, a, b)
            if scheme.startswith("euler-matrix"):
                R, L = new[1], new[3]
                q_c, w_c, ortho_c = C.matrix_outputs(C.mat(R), C.vec(L), C.mat(pb.body.I_body_inv))
                q, w, ortho = ref.matrix_outputs(R[None], L[None], pb.body.I_body_inv)
                assert _same_up_to_sign(q[0], q_c) <= OUTPUT_ULPS * polar_condition(R), (pb.name, k)
                assert ulps(w[0], w_c) <= OUTPUT_ULPS, (pb.name, k)
                assert abs(ortho[0] - ortho_c) <= ORTHONORMALITY_ULPS * EPS * np.sum(R * R), (pb.name, k)
            state = new
    print(f"{scheme}: at most {worst:.1f} ulps")


@pytest.mark.parametrize("scheme", SCHEMES)
def test_whole_runs_equal_the_numpy_loops(scheme):
    for pb, dt in PROBLEMS[::5]:
        a = simulate(pb, scheme, dt, STEPS, compiled=False)
        b = simulate(pb, scheme, dt, STEPS)
        np.testing.assert_array_equal(a.t, b.t)
        if a.orthonormality_error is not None:  # compare up to a blow-up of explicit Euler's R
            blown = np.flatnonzero(a.orthonormality_error > BLOWN_UP_ORTHONORMALITY)
            a, b = a.head(blown[0] if blown.size else len(a)), b.head(blown[0] if blown.size else len(b))
        for field in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
            x, y = getattr(a, field), getattr(b, field)
            assert np.max(np.abs(x - y)) <= RUN_RTOL * np.max(np.abs(x)), (pb.name, field)
        assert (a.orthonormality_error is None) == (b.orthonormality_error is None)
        if a.orthonormality_error is not None:
            assert np.max(np.abs(a.orthonormality_error - b.orthonormality_error)) <= RUN_RTOL


@pytest.mark.parametrize("implicit", [False, True])
def test_semi_implicit_driver_is_its_step_iterated_bit_for_bit(implicit):
    """run_semi_implicit looks the loads' segment up once per segment and forms R(q) once a step:
    the same numbers as semi_implicit_step called step by step (loads switching on and off)."""
    scheme = "semi-implicit-implicit-gyro" if implicit else "semi-implicit-explicit-gyro"
    for pb, dt in PROBLEMS[5::4]:
        _, compiled_step = _steps(scheme, pb, dt)
        run = simulate(pb, scheme, dt, STEPS)
        state = tuple(C.vec(s) for s in _initial_state(scheme, pb))
        for k in range(STEPS):
            state = compiled_step(k, state)
            x, q, v, w_b = state
            got = (run.position[k + 1], run.quaternion_wxyz[k + 1], run.linear_velocity[k + 1],
                   run.angular_velocity[k + 1])
            want = (x, q, v, C.matvec(C.matrix_from_quat(q), w_b))
            for a, b in zip(got, want):
                assert np.asarray(a).tobytes() == np.asarray(b, float).tobytes(), (pb.name, k)


def test_nearest_rotation_equals_the_svd_polar_factor():
    rng = np.random.default_rng(5)
    for _ in range(2000):
        R = matrix_from_quat(rng.normal(size=4))
        A = R @ np.diag(np.exp(rng.uniform(-2.0, 2.0, 3))) @ matrix_from_quat(rng.normal(size=4))
        if rng.random() < 0.1:
            A = -A  # det < 0: the SVD path
        want = nearest_rotation(A[None])[0]
        got = np.array(C.nearest_rotation(C.mat(A)))
        assert np.max(np.abs(got - want)) <= OUTPUT_ULPS * EPS * polar_condition(A)
        q = quat_from_matrix(want)
        assert _same_up_to_sign(q, C.quat_from_matrix(C.mat(want))) <= OUTPUT_ULPS
    assert np.all(np.isnan(C.nearest_rotation(C.mat(np.full((3, 3), np.nan)))))
    assert np.isclose(C.orthonormality_error(C.mat(2.0 * np.eye(3))), orthonormality_error(2.0 * np.eye(3)))


def test_simulate_runs_the_compiled_maps_and_keeps_the_numpy_loops():
    pb, dt = PROBLEMS[7]
    for scheme in SCHEMES:
        default = simulate(pb, scheme, dt, 20)
        comp = C.simulate_compiled(pb, scheme, dt, 20)
        for field in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
            np.testing.assert_array_equal(getattr(default, field), getattr(comp, field))
        numpy_run = INTEGRATORS[scheme].simulate(pb, dt, 20)
        np.testing.assert_array_equal(simulate(pb, scheme, dt, 20, compiled=False).position,
                                      numpy_run.position)
    with pytest.raises(KeyError):
        simulate(pb, "leapfrog", dt, 2)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_a_blow_up_is_inf_or_nan_not_an_error(scheme):
    pb = Problem("spin", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), [1, 0, 0, 0], np.zeros(3), [1e3, 2e3, 3e3]),
                 gravity=np.zeros(3), duration_steps=400, dts=(1.0,))
    out = simulate(pb, scheme, 1.0, 400)
    assert len(out) == 401  # no exception; the harness judges non-finite or huge samples diverged


# The functions Python calls (the drivers, and bullet_matrix_from_quat for a run's start); every
# other compiled function of the two modules is a helper that only compiled code calls.
PYTHON_ENTRIES = {"run_euler_matrix", "run_quat", "run_splitting", "run_semi_implicit", "run_mujoco_rk4",
                  "run_bullet_maximal", "run_dart", "run_physx", "run_drake", "run_newton", "run_brax",
                  "bullet_matrix_from_quat"}


def test_helpers_are_compiled_without_python_wrappers_and_still_answer_python():
    """A function only compiled code calls is a CompiledHelper (no CPython/C wrapper: about 30% of a
    cold first compilation); the drivers are plain dispatchers; a helper called from Python runs a
    jitted copy of its own source: the same numbers as that source."""
    from numba.core.registry import CPUDispatcher

    from freebody.reference_impl import compiled_engine_maps as CE

    seen = set()
    for module in (C, CE):
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module.__name__:
                assert isinstance(obj, C.CompiledHelper) == (name not in PYTHON_ENTRIES), name
                seen.add(name)
    assert PYTHON_ENTRIES <= seen and len(seen) > 2 * len(PYTHON_ENTRIES)
    a, b = (0.5, 0.5, -0.5, 0.5), (0.9, 0.1, 0.3, -0.2)
    assert C.quat_multiply(a, b) == C.quat_multiply.py_func(a, b)
    assert C.quat_multiply.python_entry.nopython_signatures  # ran compiled, not the Python source
