"""Part "truth": freebody's numerical truth (``reference_impl.truth``: scipy's DOP853) against its
yardstick, the same scipy DOP853 at the same tolerances and sample times on the same equations
(body-frame w_b and q, plus x and v) with a numba-compiled right-hand side (:func:`compiled_rhs`).

The yardstick covers a case whose loads are constant over the run (no switch): their sum is one
force (world), couple (world), body couple (body frame) and, when applied at a point, its arm.
"""
from __future__ import annotations

import numpy as np

from .config import TRUTH_CASE, BenchConfig
from .core import cpu_timed, log, median

_RHS = None  # the compiled right-hand side, made on first use (numba imported then)


def compiled_rhs():
    """The numba right-hand side ``rhs(y, M, I_b, I_inv, g, f, tau_w, tau_b, p_w, r_b)``.

    y : (13,) x (3,) m world, v (3,) m/s world, q (4,) wxyz body -> world (not normalised),
        w_b (3,) rad/s BODY frame.  M kg; I_b, I_inv (3, 3) kg m^2 and its inverse, body frame;
    g (3,) m/s^2; f (3,) N world; tau_w (3,) N m world; tau_b (3,) N m body frame; p_w (4,):
    a world point of application (p_w[3] = 1 when used, else 0); r_b (4,): a body-frame arm
    (r_b[3] = 1 when used).  Returns dy/dt (13,), the equations of ``reference_impl.truth``.
    """
    global _RHS
    if _RHS is None:
        import numba

        @numba.njit(cache=True)
        def rhs(y, M, I_b, I_inv, g, f, tau_w, tau_b, p_w, r_b):  # pragma: no cover (compiled)
            w0, x1, y1, z1 = y[6], y[7], y[8], y[9]
            n = np.sqrt(w0 * w0 + x1 * x1 + y1 * y1 + z1 * z1)
            a, b, c, d = w0 / n, x1 / n, y1 / n, z1 / n
            R = np.empty((3, 3))
            R[0, 0] = 1 - 2 * (c * c + d * d); R[0, 1] = 2 * (b * c - a * d); R[0, 2] = 2 * (b * d + a * c)
            R[1, 0] = 2 * (b * c + a * d); R[1, 1] = 1 - 2 * (b * b + d * d); R[1, 2] = 2 * (c * d - a * b)
            R[2, 0] = 2 * (b * d - a * c); R[2, 1] = 2 * (c * d + a * b); R[2, 2] = 1 - 2 * (b * b + c * c)
            tau = tau_w + R @ tau_b
            if p_w[3] == 1.0:
                arm = p_w[:3] - y[0:3]
                tau = tau + np.cross(arm, f)
            if r_b[3] == 1.0:
                tau = tau + np.cross(R @ r_b[:3], f)
            wb = y[10:13]
            dw = I_inv @ (R.T @ tau - np.cross(wb, I_b @ wb))
            out = np.empty(13)
            out[0:3] = y[3:6]
            out[3:6] = f / M + g
            out[6] = 0.5 * (-x1 * wb[0] - y1 * wb[1] - z1 * wb[2])
            out[7] = 0.5 * (w0 * wb[0] + y1 * wb[2] - z1 * wb[1])
            out[8] = 0.5 * (w0 * wb[1] + z1 * wb[0] - x1 * wb[2])
            out[9] = 0.5 * (w0 * wb[2] + x1 * wb[1] - y1 * wb[0])
            out[10:13] = dw
            return out
        _RHS = rhs
    return _RHS


def _constant_loads(problem, dt: float, steps: int):
    """(f, tau_w, tau_b, p_w, r_b) of the case's loads, summed (see :func:`compiled_rhs`);
    ValueError when the loads switch during the run or two act at points."""
    if problem.switch_steps(dt, steps):
        raise ValueError(f"{problem.name}: its loads switch during the run (the yardstick is for "
                         f"constant loads)")
    f, tau_w, tau_b = np.zeros(3), np.zeros(3), np.zeros(3)
    p_w, r_b = np.zeros(4), np.zeros(4)
    for ld in problem.active_loads(0, dt):
        f, tau_w, tau_b = f + ld.force, tau_w + ld.torque, tau_b + ld.body_torque
        if ld.point is not None or ld.body_point is not None:
            if p_w[3] or r_b[3]:
                raise ValueError(f"{problem.name}: two loads at points")
            if ld.point is not None:
                p_w[:3], p_w[3] = ld.point, 1.0
            else:
                r_b[:3], r_b[3] = ld.body_point, 1.0
    return f, tau_w, tau_b, p_w, r_b


def yardstick_truth(problem, dt: float, steps: int, rtol: float, atol: float):
    """scipy's DOP853 of the case with :func:`compiled_rhs`: (Y (steps + 1, 13) as in
    :func:`compiled_rhs`, sampled at k dt; number of right-hand side evaluations)."""
    from scipy.integrate import solve_ivp

    from ...reference_impl.rotations import matrix_from_quat, quat_normalize

    body, init = problem.body, problem.initial
    loads = _constant_loads(problem, dt, steps)
    q0 = quat_normalize(init.quaternion_wxyz)
    y0 = np.concatenate([init.position, init.linear_velocity, q0,
                         matrix_from_quat(q0).T @ init.angular_velocity])
    args = (float(body.mass), np.ascontiguousarray(body.I_body, dtype=float),
            np.ascontiguousarray(body.I_body_inv, dtype=float),
            np.asarray(problem.gravity, dtype=float), *loads)
    rhs = compiled_rhs()
    t_eval = np.arange(steps + 1) * dt
    sol = solve_ivp(lambda _t, y: rhs(y, *args), (t_eval[0], t_eval[-1]), y0, method="DOP853",
                    t_eval=t_eval, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"the yardstick DOP853 failed: {sol.message}")
    return sol.y.T, int(sol.nfev)


def truth(config: BenchConfig, progress: bool = False) -> dict:
    """CPU seconds of ``truth_trajectory`` (numerical) of :data:`TRUTH_CASE` at its smallest time
    step over its duration against :func:`yardstick_truth`, interleaved ``repeats`` (at least 5)
    times after an untimed call of each; medians.  Also the largest difference of their positions,
    quaternions (sign-aligned) and body rates, to show they compute the same motion."""
    from ...input.casefile import load_case
    from ...reference_impl.truth import NUMERICAL_ATOL, NUMERICAL_RTOL, truth_kind, truth_trajectory

    problem = load_case(TRUTH_CASE)
    dt = min(problem.dts)
    steps = int(round(problem.duration / dt))
    if truth_kind(problem) != "numerical":
        return {"truth_note": f"{TRUTH_CASE} no longer has a numerical truth"}
    ours = truth_trajectory(problem, dt, steps)
    Y, nfev = yardstick_truth(problem, dt, steps, NUMERICAL_RTOL, NUMERICAL_ATOL)
    mine, yard = [], []
    for r in range(max(config.repeats, 5)):
        mine.append(cpu_timed(lambda: truth_trajectory(problem, dt, steps)))
        yard.append(cpu_timed(lambda: yardstick_truth(problem, dt, steps, NUMERICAL_RTOL, NUMERICAL_ATOL)))
    log(f"truth: {median(mine) * 1e3:.2f} ms vs compiled rhs {median(yard) * 1e3:.2f} ms CPU", progress)
    q = Y[:, 6:10] / np.linalg.norm(Y[:, 6:10], axis=1)[:, None]
    q *= np.sign(np.sum(q * ours.quaternion_wxyz, axis=1))[:, None]
    return {"truth_case": TRUTH_CASE, "truth_dt": dt, "truth_steps": steps,
            "truth_cpu_s": median(mine), "truth_yardstick_cpu_s": median(yard),
            "truth_yardstick_nfev": nfev, "truth_rtol": NUMERICAL_RTOL, "truth_atol": NUMERICAL_ATOL,
            "truth_vs_yardstick_max_diff": {"x_m": float(np.max(np.abs(Y[:, 0:3] - ours.position))),
                                            "q": float(np.max(np.abs(q - ours.quaternion_wxyz)))}}
