"""The numerical truth's right-hand side, compiled (numba): the equations of :mod:`truth` on plain floats.

:func:`truth.numerical_trajectory` integrates, in body-frame variables,

    x' = v,   v' = f / M + g,   q' = 1/2 q (0, w_b),   I w_b' = R^T tau - w_b x I w_b,

with (f, tau) the sum of the step's active loads (``Problem.wrench``: world force, world couple,
body couple turned by R, the arm of a force at a world point or at a body point) and R = R(q / |q|).
Its readable numpy right-hand side (``truth._numpy_rhs``) builds R with the batched
``rotations.matrix_from_quat`` and calls ``np.cross``/``np.concatenate``: about 100-600 us a call,
mostly interpreter and small-array overhead.  :func:`body_frame_rhs` is the same formulas in the
same order written component by component (about 1 us a call, dispatch included), so scipy's DOP853
takes the same steps with the same number of evaluations; the two agree to rounding (numpy's
3x3 products and norms go through BLAS, whose summation order and fused multiply-adds may differ):
``tests/test_truth_compiled.py`` checks both the right-hand sides and whole truths.

The loads of one segment between load switches are passed as an array (:func:`loads_array`), the
body and gravity as another (:func:`body_array`), so a call unboxes three arrays and nothing else.
Compiled on first use (only a numerical truth needs it), cached on disk (``cache=True``, as in
:mod:`compiled`); inf/NaN rather than exceptions (``error_model="numpy"``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .problem import Load

__all__ = ["body_frame_rhs", "body_array", "loads_array", "AT_COM", "AT_WORLD_POINT", "AT_BODY_POINT"]

jit = njit(cache=True, error_model="numpy")

# Kinds of torque arm of a load's force (column 0 of loads_array)
AT_COM, AT_WORLD_POINT, AT_BODY_POINT = 0.0, 1.0, 2.0
LOAD_COLUMNS = 13  # kind, force (3), torque (3), body_torque (3), point or body_point (3)
BODY_ENTRIES = 22  # M, I_body (9, row-major), I_body^-1 (9, row-major), g (3)


def body_array(M: float, I_b: np.ndarray, I_inv: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(22,) float: M kg; I_b (3, 3) kg m^2 and I_inv (3, 3) 1/(kg m^2), COM, body frame, each
    row-major; g (3,) m/s^2, world."""
    return np.concatenate([[float(M)], np.asarray(I_b, float).ravel(), np.asarray(I_inv, float).ravel(),
                           np.asarray(g, float)])


def loads_array(loads: tuple[Load, ...]) -> np.ndarray:
    """(n, 13) float, one row per load in the given (case) order: kind (AT_COM, AT_WORLD_POINT,
    AT_BODY_POINT), force (3) N world, torque (3) N m world, body_torque (3) N m body frame, and
    the point (3) m, world (AT_WORLD_POINT) or body frame (AT_BODY_POINT), else zeros."""
    out = np.zeros((len(loads), LOAD_COLUMNS))
    for i, ld in enumerate(loads):
        out[i, 1:4], out[i, 4:7], out[i, 7:10] = ld.force, ld.torque, ld.body_torque
        if ld.point is not None:
            out[i, 0], out[i, 10:13] = AT_WORLD_POINT, ld.point
        elif ld.body_point is not None:
            out[i, 0], out[i, 10:13] = AT_BODY_POINT, ld.body_point
    return out


@jit
def body_frame_rhs(y, body, loads):
    """dy/dt (13,) of the numerical truth, in one function (one compilation: about 0.9 s CPU cold,
    against 1.2 s for the same code split into helpers).

    y : (13,) x (3) m world, v (3) m/s world, q (4) wxyz body -> world (not necessarily unit),
        w_b (3) rad/s body frame.  body : :func:`body_array`.  loads : :func:`loads_array` of the
        loads acting on this segment (0 rows: none).
    """
    # R = R(q / |q|), row by row (rotations.matrix_from_quat)
    qw, qx, qy, qz = y[6], y[7], y[8], y[9]
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    uw, ux, uy, uz = qw / n, qx / n, qy / n, qz / n  # q / |q|
    R00, R01, R02 = 1 - 2 * (uy * uy + uz * uz), 2 * (ux * uy - uw * uz), 2 * (ux * uz + uw * uy)
    R10, R11, R12 = 2 * (ux * uy + uw * uz), 1 - 2 * (ux * ux + uz * uz), 2 * (uy * uz - uw * ux)
    R20, R21, R22 = 2 * (ux * uz - uw * uy), 2 * (uy * uz + uw * ux), 1 - 2 * (ux * ux + uy * uy)
    # (f, tau) world: the loads summed in order as Problem.wrench, tau_i = torque + R body_torque
    # [+ (point - x) x f, or (R body_point) x f]
    f0 = f1 = f2 = 0.0
    t0 = t1 = t2 = 0.0
    for i in range(loads.shape[0]):
        a0, a1, a2 = loads[i, 1], loads[i, 2], loads[i, 3]
        b0, b1, b2 = loads[i, 7], loads[i, 8], loads[i, 9]
        u0 = loads[i, 4] + (R00 * b0 + R01 * b1 + R02 * b2)
        u1 = loads[i, 5] + (R10 * b0 + R11 * b1 + R12 * b2)
        u2 = loads[i, 6] + (R20 * b0 + R21 * b1 + R22 * b2)
        p0, p1, p2 = loads[i, 10], loads[i, 11], loads[i, 12]
        if loads[i, 0] != AT_COM:
            if loads[i, 0] == AT_WORLD_POINT:
                r0, r1, r2 = p0 - y[0], p1 - y[1], p2 - y[2]
            else:
                r0 = R00 * p0 + R01 * p1 + R02 * p2
                r1 = R10 * p0 + R11 * p1 + R12 * p2
                r2 = R20 * p0 + R21 * p1 + R22 * p2
            u0, u1, u2 = u0 + (r1 * a2 - r2 * a1), u1 + (r2 * a0 - r0 * a2), u2 + (r0 * a1 - r1 * a0)
        f0, f1, f2 = f0 + a0, f1 + a1, f2 + a2
        t0, t1, t2 = t0 + u0, t1 + u1, t2 + u2
    # R^T tau - w_b x I w_b (I = body[1:10]), then I^-1 (body[10:19]) of it
    w0, w1, w2 = y[10], y[11], y[12]
    s0 = R00 * t0 + R10 * t1 + R20 * t2
    s1 = R01 * t0 + R11 * t1 + R21 * t2
    s2 = R02 * t0 + R12 * t1 + R22 * t2
    h0 = body[1] * w0 + body[2] * w1 + body[3] * w2
    h1 = body[4] * w0 + body[5] * w1 + body[6] * w2
    h2 = body[7] * w0 + body[8] * w1 + body[9] * w2
    e0, e1, e2 = s0 - (w1 * h2 - w2 * h1), s1 - (w2 * h0 - w0 * h2), s2 - (w0 * h1 - w1 * h0)
    out = np.empty(13)
    M = body[0]
    out[0], out[1], out[2] = y[3], y[4], y[5]
    out[3], out[4], out[5] = f0 / M + body[19], f1 / M + body[20], f2 / M + body[21]
    # 1/2 q (0, w_b), the Hamilton product written out with its zero scalar part
    out[6] = 0.5 * (qw * 0.0 - qx * w0 - qy * w1 - qz * w2)
    out[7] = 0.5 * (qw * w0 + qx * 0.0 + qy * w2 - qz * w1)
    out[8] = 0.5 * (qw * w1 - qx * w2 + qy * 0.0 + qz * w0)
    out[9] = 0.5 * (qw * w2 + qx * w1 - qy * w0 + qz * 0.0)
    out[10] = body[10] * e0 + body[11] * e1 + body[12] * e2
    out[11] = body[13] * e0 + body[14] * e1 + body[15] * e2
    out[12] = body[16] * e0 + body[17] * e1 + body[18] * e2
    return out
