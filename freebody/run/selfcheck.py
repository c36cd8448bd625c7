"""Convention self-checks: does an engine, through its adapter, build the case we asked for and
read it back in freebody's convention?  Used by the test suite and shown live by
``freebody conventions``.

Each check builds a small problem, runs it on the engine and compares with what the canonical
convention predicts; each returns a :class:`CheckResult` (never raises for an engine's failure).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import tolerances as tol
from ..adapters.base import load_adapter
from ..reference_impl.conventions import angular_momentum
from .judge import engine_schemes
from ..reference_impl.integrators import simulate as reference_simulate
from ..reference_impl.problem import Body, InitialState, Load, Problem
from ..reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec, quat_multiply

# The checks' bounds (SELFCHECK_*) and their reasons: the self-checks section of freebody.tolerances.

CHECKS = ("initial_state", "push_world_point", "push_body_point", "torque_free_L", "high_spin")


@dataclass(frozen=True)
class CheckResult:
    """One check on one engine/integrator: passed, the measured value, its bound, a sentence."""

    check: str
    engine: str
    integrator: str
    passed: bool
    value: float | None
    bound: float
    detail: str


def _generic_initial() -> InitialState:
    q = quat_from_rotvec(np.array([0.4, -0.7, 0.25]))
    return InitialState(position=[1.5, -2.0, 0.75], quaternion_wxyz=q,
                        linear_velocity=[0.3, -0.4, 1.2], angular_velocity=[0.7, -1.1, 2.3])


def _non_diagonal_body() -> Body:
    Q = matrix_from_quat(quat_from_rotvec(np.array([0.3, 0.2, -0.5])))
    return Body(1.7, Q.T @ np.diag([0.9, 1.6, 2.1]) @ Q)


def precision_of(engine: str) -> str:
    """The precision the checks run an engine in: float64 when it offers it, else the first it
    offers (SAPIEN: float32 only)."""
    precisions = tuple(load_adapter(engine).precisions)
    return "float64" if "float64" in precisions else precisions[0]


def _run(engine, integrator, problem, dt, steps):
    cls = load_adapter(engine)
    adapter = cls(problem, dt, integrator, precision_of(engine))
    try:
        return adapter.simulate(steps)
    finally:
        adapter.close()


def check_initial_state(engine: str, integrator: str) -> CheckResult:
    pb = Problem("selfcheck-initial", "", _non_diagonal_body(), _generic_initial(), gravity=[0, 0, -9.81],
                 duration_steps=1)
    tr = _run(engine, integrator, pb, 1e-3, 0)
    init = pb.initial
    errs = [np.max(np.abs(tr.position[0] - init.position)),
            float(geodesic_angle(tr.quaternion_wxyz[0], init.quaternion_wxyz)),
            np.max(np.abs(tr.linear_velocity[0] - init.linear_velocity)),
            np.max(np.abs(tr.angular_velocity[0] - init.angular_velocity))]
    worst = float(max(errs))
    names = ("position", "orientation", "linear velocity", "angular velocity")
    detail = ", ".join(f"{n} {e:.1e}" for n, e in zip(names, errs))
    bound = (tol.SELFCHECK_INITIAL_STATE_ATOL if precision_of(engine) == "float64"
             else tol.SELFCHECK_INITIAL_STATE_FLOAT32_ATOL)
    return CheckResult("initial_state", engine, integrator, worst <= bound, worst, bound,
                       f"state read back at t = 0 vs the case: {detail}")


def _check_push(engine: str, integrator: str, world_point: bool) -> CheckResult:
    h = 1e-3
    f = np.array([0.0, 3.0, -2.0])
    init = _generic_initial()
    init = InitialState(init.position, init.quaternion_wxyz, init.linear_velocity, np.zeros(3))
    b = np.array([0.5, 0.2, -0.3])  # body-frame offset
    R0 = matrix_from_quat(init.quaternion_wxyz)
    if world_point:
        point = init.position + R0 @ b
        load = Load(force=f, point=point, start=0.0, steps=1)
    else:
        load = Load(force=f, body_point=b, start=0.0, steps=1)
    pb = Problem("selfcheck-push", "", _non_diagonal_body(), init, gravity=[0, 0, 0], loads=(load,),
                 duration_steps=1)
    tr = _run(engine, integrator, pb, h, 1)
    L = angular_momentum(pb.body.I_body, tr.quaternion_wxyz, tr.angular_velocity)
    expected = h * np.cross(R0 @ b, f)
    err = float(np.linalg.norm(L[1] - L[0] - expected) / np.linalg.norm(expected))
    name = "push_world_point" if world_point else "push_body_point"
    where = "a world point" if world_point else "a body-frame point"
    return CheckResult(name, engine, integrator, err <= tol.SELFCHECK_PUSH_TORQUE_RTOL, err,
                       tol.SELFCHECK_PUSH_TORQUE_RTOL,
                       f"one-step push at {where} on a rotated, moving body: |dL - h (r - x) x f| / |h tau| = {err:.1e}")


def check_push_world_point(engine: str, integrator: str) -> CheckResult:
    return _check_push(engine, integrator, world_point=True)


def check_push_body_point(engine: str, integrator: str) -> CheckResult:
    return _check_push(engine, integrator, world_point=False)


def check_torque_free_L(engine: str, integrator: str) -> CheckResult:
    h, steps = 1e-3, 2000
    pb = Problem("selfcheck-L", "", _non_diagonal_body(), _generic_initial(), gravity=[0, 0, 0],
                 duration_steps=steps)
    tr = _run(engine, integrator, pb, h, steps)
    I_b = pb.body.I_body

    def drift(t):
        L = angular_momentum(I_b, t.quaternion_wxyz, t.angular_velocity)
        return float(np.max(np.linalg.norm(L - L[0], axis=1)) / np.linalg.norm(L[0]))

    ref = {c: drift(reference_simulate(pb, c, h, steps)) for c in engine_schemes(integrator)}
    bound = tol.SELFCHECK_L_DRIFT_FACTOR * max(ref.values()) + tol.SELFCHECK_L_DRIFT_ATOL
    got = drift(tr)
    ok = bool(np.isfinite(got) and got <= bound)
    refs = ", ".join(f"{k} {v:.1e}" for k, v in ref.items())
    return CheckResult("torque_free_L", engine, integrator, ok, got, bound,
                       f"max relative L drift over 2 s at dt = 1e-3: {got:.1e} (reference maps: {refs})")


def check_high_spin(engine: str, integrator: str) -> CheckResult:
    h, steps, rate = 1e-3, 200, 150.0
    q0 = quat_from_rotvec(np.array([0.2, 0.1, -0.3]))
    axis_body = np.array([0.0, 0.0, 1.0])
    w_world = rate * (matrix_from_quat(q0) @ axis_body)
    pb = Problem("selfcheck-spin", "", Body(1.0, np.diag([1.0, 2.0, 2.5])),
                 InitialState(np.zeros(3), q0, np.zeros(3), w_world), gravity=[0, 0, 0], duration_steps=steps)
    tr = _run(engine, integrator, pb, h, steps)
    exact = quat_multiply(quat_from_rotvec(np.outer(tr.t, w_world)), q0)
    err = float(np.max(geodesic_angle(exact, tr.quaternion_wxyz)))
    bound = tol.SELFCHECK_HIGH_SPIN_RAD if precision_of(engine) == "float64" else tol.SELFCHECK_HIGH_SPIN_FLOAT32_RAD
    if "rk4" in integrator.lower():
        ref = reference_simulate(pb, "rk4", h, steps)
        bound += tol.SELFCHECK_L_DRIFT_FACTOR * float(np.max(geodesic_angle(exact, ref.quaternion_wxyz)))
    ok = bool(np.isfinite(err) and err <= bound)
    return CheckResult("high_spin", engine, integrator, ok, err, bound,
                       f"150 rad/s about one body axis, dt = 1e-3, 0.2 s: orientation error {err:.1e} rad "
                       f"(|w| read back {np.linalg.norm(tr.angular_velocity[-1]):.6g} rad/s)")


CHECK_FUNCTIONS = {
    "initial_state": check_initial_state,
    "push_world_point": check_push_world_point,
    "push_body_point": check_push_body_point,
    "torque_free_L": check_torque_free_L,
    "high_spin": check_high_spin,
}


def run_check(check: str, engine: str, integrator: str) -> CheckResult:
    """Run one check; an engine error becomes a failed check with the error as its detail."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            return CHECK_FUNCTIONS[check](engine, integrator)
    except Exception as e:
        return CheckResult(check, engine, integrator, False, None, float("nan"),
                           f"raised {type(e).__name__}: {e}")


def run_trap_checks(engine: str) -> list[CheckResult]:
    """The adapter's own trap checks (``Adapter.trap_checks``), each a CheckResult (integrator
    "-"); an engine error is a failed check with the error as its detail."""
    cls = load_adapter(engine)
    out = []
    for name, check in cls.trap_checks().items():
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                passed, value, bound, detail = check()
            out.append(CheckResult(name, engine, "-", bool(passed), value, bound, detail))
        except Exception as e:
            out.append(CheckResult(name, engine, "-", False, None, float("nan"), f"raised {type(e).__name__}: {e}"))
    return out
