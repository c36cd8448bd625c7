"""Truth oracles: the exact (or near-exact) motion a run is measured against.

- ``closed-form``: torque-free rotation of an arbitrary body (:mod:`torque_free`: Jacobi elliptic
  functions and Carlson's elliptic integrals) with ballistic COM motion under constant gravity.
  Used when a case has no loads.
- ``numerical``: scipy's DOP853 at rtol = atol = 1e-12 in body-frame variables (w_b and q, plus
  x and v), restarted at every load switch.  Integrating (R, L) or (q, L) directly loses two to
  three digits; body-frame variables keep about 1e-9 rad over 10 s.  Its right-hand side is
  compiled (:mod:`truth_rhs`, numba, about 1 us a call against 125 us for the numpy one kept
  here as :func:`_numpy_rhs`, ``compiled=False``): the same DOP853 steps, equal to rounding.

Both return a :class:`Trajectory` sampled at t_k = k dt, k = 0..steps, or deliver it in pieces
(:func:`truth_chunks`, the pieces of ``Adapter.chunks``) for a run judged chunk by chunk.
"""
from __future__ import annotations

import numpy as np

from typing import Iterator

from .conventions import Trajectory
from .problem import Load, Problem
from .rotations import matrix_from_quat, quat_multiply, quat_normalize


def solve_ivp(*args, **kwargs):
    """scipy's ``solve_ivp``, imported on first use: importing scipy.integrate costs about 0.35 s
    CPU, which a process that never integrates a numerical truth (a closed form) does not pay."""
    from scipy.integrate import solve_ivp as scipy_solve_ivp

    return scipy_solve_ivp(*args, **kwargs)


NUMERICAL_RTOL = 1e-12  # DOP853 relative tolerance (about 6e-10 rad over 10 s on Dzhanibekov)
NUMERICAL_ATOL = 1e-12  # DOP853 absolute tolerance


def truth_kind(problem: Problem) -> str:
    """The oracle used for a problem: closed form when no loads act, numerical otherwise."""
    return "closed-form" if problem.torque_free else "numerical"


def truth_trajectory(problem: Problem, dt: float, steps: int, kind: str | None = None) -> Trajectory:
    """The truth at t_k = k dt for k = 0..steps, by the problem's oracle (or ``kind``)."""
    return next(truth_chunks(problem, dt, steps, None, kind))


def piece_bounds(steps: int, chunk_steps: int | None) -> list[tuple[int, int]]:
    """The (first step, last step) of each piece of a run of ``steps`` steps delivered in pieces of
    at most ``chunk_steps`` steps (None: one piece), as ``Adapter.chunks`` delivers them: the first
    piece holds the samples k0..k1, every later one k0 + 1..k1."""
    n = steps if chunk_steps is None else max(1, int(chunk_steps))
    if steps <= 0:
        return [(0, 0)]
    return [(k0, min(k0 + n, steps)) for k0 in range(0, steps, n)]


def truth_chunks(problem: Problem, dt: float, steps: int, chunk_steps: int | None = None,
                 kind: str | None = None) -> Iterator[Trajectory]:
    """The truth at t_k = k dt, k = 0..steps, in the pieces of :func:`piece_bounds` (those of
    ``Adapter.chunks(steps, chunk_steps)``); ``chunk_steps`` None: one piece, the whole truth.

    The closed form is evaluated at each piece's times: the same numbers as the whole truth.  The
    numerical truth integrates piece after piece from the previous piece's end state (the
    integrator restarted there, as at a load switch, its quaternion renormalised): it differs from
    the whole-run truth by the integrator's tolerance at the joins (~1e-12 relative), not more.
    """
    kind = kind or truth_kind(problem)
    bounds = piece_bounds(steps, chunk_steps)
    if kind == "closed-form":
        for k0, k1 in bounds:
            yield _closed_form_samples(problem, dt, k0 if k0 == 0 else k0 + 1, k1)
        return
    yield from _numerical_pieces(problem, dt, steps, bounds)


def closed_form_trajectory(problem: Problem, dt: float, steps: int) -> Trajectory:
    """Closed-form torque-free rotation + ballistic COM (requires a problem without loads)."""
    return _closed_form_samples(problem, dt, 0, steps)


def _closed_form_samples(problem: Problem, dt: float, k0: int, k1: int) -> Trajectory:
    """The closed form at t_k = k dt for k = k0..k1."""
    from .torque_free import torque_free_rotation

    if not problem.torque_free:
        raise ValueError("the closed-form truth needs a case without loads")
    init = problem.initial
    t = np.arange(k0, k1 + 1) * dt
    q, w = torque_free_rotation(problem.body.I_body, init.quaternion_wxyz, init.angular_velocity, t)
    g = problem.gravity
    x = init.position + np.outer(t, init.linear_velocity) + 0.5 * np.outer(t * t, g)
    v = init.linear_velocity + np.outer(t, g)
    return Trajectory(t, x, q, v, w)


def numerical_trajectory(problem: Problem, dt: float, steps: int,
                         rtol: float = NUMERICAL_RTOL, atol: float = NUMERICAL_ATOL,
                         compiled: bool = True) -> Trajectory:
    """High-accuracy integration in body-frame variables, restarted at every load switch.

    Variables y = (x (3) m world, v (3) m/s world, q (4) wxyz body -> world, w_b (3) rad/s body).
    Euler's equations I w_b' = tau_b - w_b x I w_b; q' = 1/2 q (0, w_b); x' = v; v' = f/M + g.
    ``compiled``: the right-hand side :func:`truth_rhs.body_frame_rhs` (numba), else the readable
    numpy one (:func:`_numpy_rhs`); the same equations, equal to rounding.
    """
    return next(_numerical_pieces(problem, dt, steps, [(0, steps)], rtol, atol, compiled))


def _numpy_rhs(problem: Problem, loads: tuple[Load, ...]):
    """The right-hand side ``rhs(t, y) -> dy/dt`` (13,) of :func:`numerical_trajectory` on a segment
    where ``loads`` act, in numpy: the readable form of :func:`truth_rhs.body_frame_rhs`."""
    body = problem.body
    M, I_b, I_inv, g = body.mass, body.I_body, body.I_body_inv, problem.gravity

    def rhs(_t, y):
        x, v, q, w_b = y[0:3], y[3:6], y[6:10], y[10:13]
        R = matrix_from_quat(q)
        f, tau = problem.wrench(loads, x, R) if loads else (np.zeros(3), np.zeros(3))
        dw = I_inv @ (R.T @ tau - np.cross(w_b, I_b @ w_b))
        dq = 0.5 * quat_multiply(q, np.r_[0.0, w_b])
        return np.concatenate([v, f / M + g, dq, dw])
    return rhs


def _compiled_rhs(problem: Problem):
    """``rhs_of(loads)``: the compiled right-hand side ``rhs(t, y)`` of a segment where ``loads``
    act (:func:`truth_rhs.body_frame_rhs`, the body's and the loads' arrays bound)."""
    from .truth_rhs import body_array, body_frame_rhs, loads_array

    b = problem.body
    body = body_array(b.mass, b.I_body, b.I_body_inv, problem.gravity)

    def rhs_of(loads):
        L = loads_array(loads)
        return lambda _t, y: body_frame_rhs(y, body, L)
    return rhs_of


def _numerical_pieces(problem: Problem, dt: float, steps: int, bounds: list[tuple[int, int]],
                      rtol: float = NUMERICAL_RTOL, atol: float = NUMERICAL_ATOL,
                      compiled: bool = True) -> Iterator[Trajectory]:
    """:func:`numerical_trajectory` over the pieces ``bounds`` (:func:`piece_bounds`), each
    integrated from the previous one's end state, restarted at the load switches inside it."""
    init = problem.initial
    rhs_of = _compiled_rhs(problem) if compiled else (lambda loads: _numpy_rhs(problem, loads))
    q0 = quat_normalize(init.quaternion_wxyz)
    w_b0 = matrix_from_quat(q0).T @ init.angular_velocity
    y = np.concatenate([init.position, init.linear_velocity, q0, w_b0])
    switches = problem.switch_steps(dt, steps)
    for s0, s1 in bounds:
        Y = np.empty((s1 - s0 + 1, 13))
        Y[0] = y
        cuts = [s0, *(k for k in switches if s0 < k < s1), s1]
        for k0, k1 in zip(cuts[:-1], cuts[1:]):
            rhs = rhs_of(problem.active_loads(k0, dt))
            t_eval = np.arange(k0, k1 + 1) * dt
            sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), Y[k0 - s0], method="DOP853", t_eval=t_eval,
                            rtol=rtol, atol=atol)
            if not sol.success:
                raise RuntimeError(f"numerical truth failed: {sol.message}")
            Y[k0 - s0 + 1:k1 - s0 + 1] = sol.y.T[1:]
            Y[k1 - s0, 6:10] = quat_normalize(Y[k1 - s0, 6:10])
        y = Y[-1].copy()
        q = quat_normalize(Y[:, 6:10])
        w = np.einsum("nij,nj->ni", matrix_from_quat(q), Y[:, 10:13])
        tr = Trajectory(np.arange(s0, s1 + 1) * dt, Y[:, 0:3], q, Y[:, 3:6], w)
        yield tr if s0 == 0 else tr.tail(1)
