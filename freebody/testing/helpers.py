"""Helpers for an engine's tests (numpy only, no pytest): a general problem, a full inertia
tensor, and a rotation assertion in the canonical convention
(``reference_impl/conventions.py``: quaternions (w, x, y, z), body -> world; q and -q are one
rotation).

    from freebody.testing import assert_same_rotation, general_problem

    pb = general_problem(w=(0.0, 0.0, 2.0), gravity=(0.0, 0.0, 0.0))
    assert_same_rotation(tr.quaternion_wxyz, expected, 1e-12, "steady spin")
"""
from __future__ import annotations

import numpy as np

from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec


def full_inertia(moments=(1.0, 2.0, 3.0), axes_rotvec=(0.4, -0.7, 0.2)) -> np.ndarray:
    """An inertia tensor whose principal axes are not the body axes.

    moments : (3,) principal moments, kg m^2.
    axes_rotvec : (3,) rad, rotation vector of the principal axes in the body frame (R).
    Returns R diag(moments) R^T, shape (3, 3), kg m^2, about the COM, body frame.
    """
    R = matrix_from_quat(quat_from_rotvec(np.asarray(axes_rotvec, dtype=float)))
    return R @ np.diag(moments) @ R.T


# The general problem's body and state: nothing is zero, aligned or diagonal.
I_FULL = full_inertia()  # kg m^2: diag(1, 2, 3) in principal axes turned by (0.4, -0.7, 0.2) rad
GENERAL_MASS = 2.0  # kg
GENERAL_X0 = (1.0, -2.0, 3.0)  # m, world
GENERAL_Q0 = quat_from_rotvec(np.array([0.9, 0.3, -1.1]))  # wxyz, body -> world
GENERAL_V0 = (0.3, -0.2, 0.5)  # m/s, world
GENERAL_W0 = (0.7, -2.0, 1.3)  # rad/s, world
GENERAL_DURATION = 1.0  # s, when neither duration nor steps is given


def general_problem(loads: tuple[Load, ...] | list = (), *, gravity=(0.0, 0.0, -9.81),
                    duration: float | None = None, steps: int | None = None,
                    dts: tuple[float, ...] = (0.01,), mass: float = GENERAL_MASS,
                    I_body=I_FULL, x=GENERAL_X0, q=GENERAL_Q0, v=GENERAL_V0, w=GENERAL_W0,
                    name: str = "general") -> Problem:
    """A free-body problem with a full inertia tensor, rotated, offset, moving and spinning
    (every default non-trivial, so a wrong frame, order or sign shows); each part overridable.

    loads : the case's loads.  gravity : (3,) m/s^2, world.
    duration : s; or steps, a number of steps at every dt (``Problem.duration_steps``); 1 s when
        neither is given.  dts : the problem's default time steps, s.
    mass : kg.  I_body : (3, 3) kg m^2, about the COM, body frame.
    x, v : (3,) m, m/s: COM position and velocity, world.  q : (4,) wxyz, body -> world (unit).
    w : (3,) rad/s, angular velocity, world.
    """
    if duration is None and steps is None:
        duration = GENERAL_DURATION
    return Problem(name, "", Body(mass, I_body), InitialState(x, q, v, w), gravity, tuple(loads),
                   duration=duration, duration_steps=steps, dts=dts)


def assert_same_rotation(qa, qb, atol: float, what: str = "") -> None:
    """Fail unless the rotations qa and qb are within ``atol`` rad of each other (geodesic angle,
    ``reference_impl.rotations.geodesic_angle``: q and -q are the same rotation).

    qa, qb : (4,) or (n, 4) quaternions (w, x, y, z), broadcast against each other (a (n, 4)
        trajectory against one (4,) rotation).  atol : rad, the largest angle allowed (inclusive).
    The message says at which sample the first excess is, by how much, and the largest angle; a
    non-finite angle is an excess.
    """
    __tracebackhide__ = True  # pytest: show the failure, not this frame
    angle = np.atleast_1d(geodesic_angle(np.asarray(qa, dtype=float), np.asarray(qb, dtype=float)))
    bad = ~(angle <= atol)
    if not bad.any():
        return
    first = int(np.flatnonzero(bad)[0])
    prefix = f"{what}: " if what else ""
    msg = f"{prefix}rotations differ by {float(angle[first]):.3g} rad (atol {atol:g} rad)"
    if angle.size > 1:
        finite = np.flatnonzero(np.isfinite(angle))
        worst = (f"largest {float(angle[finite].max()):.3g} rad at sample "
                 f"{int(finite[np.argmax(angle[finite])])}") if finite.size else "none finite"
        msg += f" at sample {first}: {int(bad.sum())} of {angle.size} samples over; {worst}"
    raise AssertionError(msg)
