"""Truth oracles: the exact (or near-exact) motion a run is measured against.

- ``closed-form``: torque-free rotation of an arbitrary body (:mod:`torque_free`: Jacobi elliptic
  functions and Carlson's elliptic integrals) with ballistic COM motion under constant gravity.
  Used when a case has no loads.
- ``numerical``: scipy's DOP853 at rtol = atol = 1e-12 in body-frame variables (w_b and q, plus
  x and v), restarted at every load switch.  Integrating (R, L) or (q, L) directly loses two to
  three digits; body-frame variables keep about 1e-9 rad over 10 s.

Both return a :class:`Trajectory` sampled at t_k = k dt, k = 0..steps.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from .conventions import Trajectory
from .problem import Problem
from .rotations import matrix_from_quat, quat_multiply, quat_normalize

NUMERICAL_RTOL = 1e-12  # DOP853 relative tolerance (about 6e-10 rad over 10 s on Dzhanibekov)
NUMERICAL_ATOL = 1e-12  # DOP853 absolute tolerance

TRUTH_KINDS = ("closed-form", "numerical")


def truth_kind(problem: Problem) -> str:
    """The oracle used for a problem: closed form when no loads act, numerical otherwise."""
    return "closed-form" if problem.torque_free else "numerical"


def truth_trajectory(problem: Problem, dt: float, steps: int, kind: str | None = None) -> Trajectory:
    """The truth at t_k = k dt for k = 0..steps, by the problem's oracle (or ``kind``)."""
    kind = kind or truth_kind(problem)
    if kind == "closed-form":
        return closed_form_trajectory(problem, dt, steps)
    return numerical_trajectory(problem, dt, steps)


def closed_form_trajectory(problem: Problem, dt: float, steps: int) -> Trajectory:
    """Closed-form torque-free rotation + ballistic COM (requires a problem without loads)."""
    from .torque_free import torque_free_rotation

    if not problem.torque_free:
        raise ValueError("the closed-form truth needs a case without loads")
    init = problem.initial
    t = np.arange(steps + 1) * dt
    q, w = torque_free_rotation(problem.body.I_body, init.quaternion_wxyz, init.angular_velocity, t)
    g = problem.gravity
    x = init.position + np.outer(t, init.linear_velocity) + 0.5 * np.outer(t * t, g)
    v = init.linear_velocity + np.outer(t, g)
    return Trajectory(t, x, q, v, w)


def numerical_trajectory(problem: Problem, dt: float, steps: int,
                         rtol: float = NUMERICAL_RTOL, atol: float = NUMERICAL_ATOL) -> Trajectory:
    """High-accuracy integration in body-frame variables, restarted at every load switch.

    Variables y = (x (3) m world, v (3) m/s world, q (4) wxyz body -> world, w_b (3) rad/s body).
    Euler's equations I w_b' = tau_b - w_b x I w_b; q' = 1/2 q (0, w_b); x' = v; v' = f/M + g.
    """
    body, init = problem.body, problem.initial
    M, I_b, I_inv, g = body.mass, body.I_body, body.I_body_inv, problem.gravity
    q0 = quat_normalize(init.quaternion_wxyz)
    w_b0 = matrix_from_quat(q0).T @ init.angular_velocity
    y = np.concatenate([init.position, init.linear_velocity, q0, w_b0])
    t_all = np.arange(steps + 1) * dt
    Y = np.empty((steps + 1, 13))
    Y[0] = y
    bounds = [0, *problem.switch_steps(dt, steps), steps]
    for k0, k1 in zip(bounds[:-1], bounds[1:]):
        loads = problem.active_loads(k0, dt)

        def rhs(_t, y, loads=loads):
            x, v, q, w_b = y[0:3], y[3:6], y[6:10], y[10:13]
            R = matrix_from_quat(q)
            f, tau = problem.wrench(loads, x, R) if loads else (np.zeros(3), np.zeros(3))
            dw = I_inv @ (R.T @ tau - np.cross(w_b, I_b @ w_b))
            dq = 0.5 * quat_multiply(q, np.r_[0.0, w_b])
            return np.concatenate([v, f / M + g, dq, dw])

        t_eval = t_all[k0:k1 + 1]
        sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), Y[k0], method="DOP853", t_eval=t_eval,
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"numerical truth failed: {sol.message}")
        Y[k0 + 1:k1 + 1] = sol.y.T[1:]
        Y[k1, 6:10] = quat_normalize(Y[k1, 6:10])
    q = quat_normalize(Y[:, 6:10])
    w = np.einsum("nij,nj->ni", matrix_from_quat(q), Y[:, 10:13])
    return Trajectory(t_all, Y[:, 0:3], q, Y[:, 3:6], w)
