"""The lecture's dynamics of the free rigid body: loads and dY/dt.

Y = (x, q, p, L):  dx/dt = p / M,  dq/dt = 1/2 (0, w) * q  (w in the world frame),
dp/dt = f + M g,  dL/dt = tau,  with I(t) = R I_b R^T and w = I(t)^-1 L.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .problem import Problem
from .rotations import matrix_from_quat, quat_multiply

# (k, x (3,) m world, R (3, 3) body -> world) -> (force (3,) N world, torque about the COM (3,) N m
# world), the external loads acting on step k, gravity excluded.
Wrench = Callable[[int, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

_ZERO = np.zeros(3)


def wrench_function(problem: Problem, dt: float) -> Wrench:
    """The external wrench of ``problem`` at time step ``dt``, as a function of (k, x, R).

    The active set of loads is looked up once per step index (and cached per interval between
    switches), so a long run with a constant load costs no per-step bookkeeping.
    """
    if not problem.loads:
        return lambda k, x, R: (_ZERO, _ZERO)
    cache: dict[int, tuple] = {}

    def wrench(k: int, x: np.ndarray, R: np.ndarray):
        loads = cache.get(k)
        if loads is None:
            loads = problem.active_loads(k, dt)
            if len(cache) > 64:
                cache.clear()
            cache[k] = loads
        if not loads:
            return _ZERO, _ZERO
        return problem.wrench(loads, x, R)

    return wrench


def rigid_body_derivative(k: int, x, q, p, L, M: float, I_body_inv: np.ndarray,
                          gravity: np.ndarray, wrench: Wrench):
    """dY/dt for Y = (x, q, p, L) on step k (loads of step k).

    x : (3,) m world.  q : (4,) (w, x, y, z) body -> world (normalised here for R).
    p : (3,) kg m/s world.  L : (3,) kg m^2/s world, about the COM.
    Returns (dx (3,), dq (4,), dp (3,), dL (3,)).
    """
    R = matrix_from_quat(q)
    w = R @ I_body_inv @ R.T @ L
    f, tau = wrench(k, x, R)
    dq = 0.5 * quat_multiply(np.r_[0.0, w], q)
    return p / M, dq, f + M * gravity, tau
