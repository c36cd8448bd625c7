"""Yardsticks for the compiled maps: each a loop of one map's arithmetic alone, torque-free.

A floor is what a map's step costs with nothing but its arithmetic: no loads, no segment look-ups,
the state written straight into the output rows.  The floors of the semi-implicit maps and of rk4
are flat scalar code (one loop, scalar locals); those of symplectic-splitting, implicit-midpoint and
rkmk4 are one loop over :mod:`compiled`'s formula helpers (cross, quat_multiply, ...: LLVM inlines
them) with the zero wrench in place of ``compiled.wrench``.  Each performs exactly the
floating-point operations of its map in :mod:`compiled` on a torque-free problem, in the same order
(the zero wrench included: ``R^T 0`` gives signed zeros the map's arithmetic carries), so its
trajectory is the map's bit for bit (``tests/test_floors.py``); ``freebody bench`` times a map's
driver (:func:`integrators.simulate`) against its floor, side by side (:func:`time_floor`).

Arguments of every floor (SI units, canonical frames, see :mod:`conventions`):
x, v : (3,) tuples, m and m/s, world (the quaternion schemes carry p = M v, kg m/s, and L, kg m^2/s,
    world, about the COM, instead of v and w_b).  q : (4,) tuple (w, x, y, z), body -> world, unit.
w_b : (3,) tuple, rad/s, body frame.  dt : s.  steps : int.  M : kg.
I_b, I_inv : 3x3 tuples of rows, kg m^2 and its inverse, body frame.  axes, moments (splitting):
    the principal axes (rows, body frame) and moments I_1 <= I_2 <= I_3, kg m^2.  g : (3,) tuple, m/s^2, world.
out_x, out_v, out_w : (steps + 1, 3) float64 C arrays; out_q : (steps + 1, 4): rows 1..steps are
written (x, q, v, and w = R w_b in the world frame, rad/s); row 0 is the caller's.
"""
from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from .compiled import (rkmk_sum, add, cayley_quat, dexpinv_world, div, free_rotation, matrix_from_quat,
                       matvec, midpoint_momentum, omega_world, quat_from_rotvec, quat_multiply, quat_normalize,
                       scale, transpose)
from .lie_integrators import RK4_B, RK4_C
from .rotations import EXP_SERIES_ANGLE_RAD

__all__ = ["floor_semi_implicit", "floor_rk4", "floor_splitting", "floor_midpoint", "floor_rkmk4", "FLOORS", "run_floor", "time_floor"]

# Compiled on first use (a yardstick for the bench: never on a path `freebody run` takes).
jit = njit(cache=True, error_model="numpy")


@jit
def floor_semi_implicit(x, q, v, w_b, dt, steps, M, I_b, I_inv, g, implicit_gyro,
                        out_x, out_q, out_v, out_w):
    """The engines' map (compiled.semi_implicit_step), torque-free, as one flat loop."""
    x0, x1, x2 = x
    qw, qx, qy, qz = q
    v0, v1, v2 = v
    w0, w1, w2 = w_b
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = I_b
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = I_inv
    g0, g1, g2 = g
    # R(q) of the start state (matrix_from_quat: q normalised first)
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    rw, rx, ry, rz = qw / n, qx / n, qy / n, qz / n
    r00, r01, r02 = 1.0 - 2.0 * (ry * ry + rz * rz), 2.0 * (rx * ry - rw * rz), 2.0 * (rx * rz + rw * ry)
    r10, r11, r12 = 2.0 * (rx * ry + rw * rz), 1.0 - 2.0 * (rx * rx + rz * rz), 2.0 * (ry * rz - rw * rx)
    r20, r21, r22 = 2.0 * (rx * rz - rw * ry), 2.0 * (ry * rz + rw * rx), 1.0 - 2.0 * (rx * rx + ry * ry)
    for k in range(steps):
        # tau_b = R^T tau with tau = 0 (signed zeros), rhs = tau_b - w_b x I w_b
        t0 = r00 * 0.0 + r10 * 0.0 + r20 * 0.0
        t1 = r01 * 0.0 + r11 * 0.0 + r21 * 0.0
        t2 = r02 * 0.0 + r12 * 0.0 + r22 * 0.0
        i0 = a00 * w0 + a01 * w1 + a02 * w2
        i1 = a10 * w0 + a11 * w1 + a12 * w2
        i2 = a20 * w0 + a21 * w1 + a22 * w2
        h0 = t0 - (w1 * i2 - w2 * i1)
        h1 = t1 - (w2 * i0 - w0 * i2)
        h2 = t2 - (w0 * i1 - w1 * i0)
        if implicit_gyro:
            d0, d1, d2 = _implicit_delta(w0, w1, w2, i0, i1, i2, a00, a01, a02, a10, a11, a12,
                                         a20, a21, a22, dt, h0, h1, h2)
        else:
            d0 = dt * (b00 * h0 + b01 * h1 + b02 * h2)
            d1 = dt * (b10 * h0 + b11 * h1 + b12 * h2)
            d2 = dt * (b20 * h0 + b21 * h1 + b22 * h2)
        w0, w1, w2 = w0 + d0, w1 + d1, w2 + d2
        v0 = v0 + dt * (0.0 / M + g0)
        v1 = v1 + dt * (0.0 / M + g1)
        v2 = v2 + dt * (0.0 / M + g2)
        x0, x1, x2 = x0 + dt * v0, x1 + dt * v1, x2 + dt * v2
        # q+ = normalize(q Exp(h w_b+))
        p0, p1, p2 = dt * w0, dt * w1, dt * w2
        angle = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        half = 0.5 * angle
        if angle < EXP_SERIES_ANGLE_RAD:
            s = 0.5 - angle * angle / 48.0 + angle ** 4 / 3840.0
        else:
            s = math.sin(half) / angle
        ew, ex, ey, ez = math.cos(half), s * p0, s * p1, s * p2
        nw = qw * ew - qx * ex - qy * ey - qz * ez
        nx = qw * ex + qx * ew + qy * ez - qz * ey
        ny = qw * ey - qx * ez + qy * ew + qz * ex
        nz = qw * ez + qx * ey - qy * ex + qz * ew
        n = math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
        qw, qx, qy, qz = nw / n, nx / n, ny / n, nz / n
        # R(q+), the output's and the next step's
        n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        rw, rx, ry, rz = qw / n, qx / n, qy / n, qz / n
        r00, r01, r02 = 1.0 - 2.0 * (ry * ry + rz * rz), 2.0 * (rx * ry - rw * rz), 2.0 * (rx * rz + rw * ry)
        r10, r11, r12 = 2.0 * (rx * ry + rw * rz), 1.0 - 2.0 * (rx * rx + rz * rz), 2.0 * (ry * rz - rw * rx)
        r20, r21, r22 = 2.0 * (rx * rz - rw * ry), 2.0 * (ry * rz + rw * rx), 1.0 - 2.0 * (rx * rx + ry * ry)
        j = k + 1
        out_x[j, 0], out_x[j, 1], out_x[j, 2] = x0, x1, x2
        out_q[j, 0], out_q[j, 1], out_q[j, 2], out_q[j, 3] = qw, qx, qy, qz
        out_v[j, 0], out_v[j, 1], out_v[j, 2] = v0, v1, v2
        out_w[j, 0] = r00 * w0 + r01 * w1 + r02 * w2
        out_w[j, 1] = r10 * w0 + r11 * w1 + r12 * w2
        out_w[j, 2] = r20 * w0 + r21 * w1 + r22 * w2


@jit
def _implicit_delta(w0, w1, w2, i0, i1, i2, a00, a01, a02, a10, a11, a12, a20, a21, a22, dt, h0, h1, h2):
    """J^-1 (h rhs), J = I_b + h ([w_b] I_b - [I_b w_b]): compiled.solve's elimination written out
    (partial pivoting as LAPACK's), on (3,) rhs h (h0, h1, h2) and I_b w_b = (i0, i1, i2)."""
    # [w_b] I_b, row by row ([w] = ((0, -w2, w1), (w2, 0, -w0), (-w1, w0, 0)))
    m00 = 0.0 * a00 + -w2 * a10 + w1 * a20
    m01 = 0.0 * a01 + -w2 * a11 + w1 * a21
    m02 = 0.0 * a02 + -w2 * a12 + w1 * a22
    m10 = w2 * a00 + 0.0 * a10 + -w0 * a20
    m11 = w2 * a01 + 0.0 * a11 + -w0 * a21
    m12 = w2 * a02 + 0.0 * a12 + -w0 * a22
    m20 = -w1 * a00 + w0 * a10 + 0.0 * a20
    m21 = -w1 * a01 + w0 * a11 + 0.0 * a21
    m22 = -w1 * a02 + w0 * a12 + 0.0 * a22
    # J = I_b + h (M - [I w]) as rows of [J | h rhs]
    r0 = (a00 + dt * (m00 - 0.0), a01 + dt * (m01 - -i2), a02 + dt * (m02 - i1), dt * h0)
    r1 = (a10 + dt * (m10 - i2), a11 + dt * (m11 - 0.0), a12 + dt * (m12 - -i0), dt * h1)
    r2 = (a20 + dt * (m20 - -i1), a21 + dt * (m21 - i0), a22 + dt * (m22 - 0.0), dt * h2)
    if abs(r1[0]) > abs(r0[0]) and abs(r1[0]) >= abs(r2[0]):
        r0, r1 = r1, r0
    elif abs(r2[0]) > abs(r0[0]) and abs(r2[0]) > abs(r1[0]):
        r0, r2 = r2, r0
    m = r1[0] / r0[0]
    r1 = (r1[0] - m * r0[0], r1[1] - m * r0[1], r1[2] - m * r0[2], r1[3] - m * r0[3])
    m = r2[0] / r0[0]
    r2 = (r2[0] - m * r0[0], r2[1] - m * r0[1], r2[2] - m * r0[2], r2[3] - m * r0[3])
    if abs(r2[1]) > abs(r1[1]):
        r1, r2 = r2, r1
    m = r2[1] / r1[1]
    r2 = (r2[0] - m * r1[0], r2[1] - m * r1[1], r2[2] - m * r1[2], r2[3] - m * r1[3])
    y2 = r2[3] / r2[2]
    y1 = (r1[3] - r1[2] * y2) / r1[1]
    y0 = (r0[3] - r0[1] * y1 - r0[2] * y2) / r0[0]
    return y0, y1, y2



@jit
def _omega(q0, q1, q2, q3, L0, L1, L2, b):
    """compiled.omega_world(matrix_from_quat(q), I_inv, L), flat: w (rad/s, world)."""
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    w, x, y, z = q0 / n, q1 / n, q2 / n, q3 / n
    r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)
    r10, r11, r12 = 2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)
    r20, r21, r22 = 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)
    # A = R I_b^-1, then A R^T, then (A R^T) L (compiled.omega_world's order)
    a00, a01, a02 = b00 * r00 + b10 * r01 + b20 * r02, b01 * r00 + b11 * r01 + b21 * r02, b02 * r00 + b12 * r01 + b22 * r02
    a10, a11, a12 = b00 * r10 + b10 * r11 + b20 * r12, b01 * r10 + b11 * r11 + b21 * r12, b02 * r10 + b12 * r11 + b22 * r12
    a20, a21, a22 = b00 * r20 + b10 * r21 + b20 * r22, b01 * r20 + b11 * r21 + b21 * r22, b02 * r20 + b12 * r21 + b22 * r22
    c00, c01, c02 = r00 * a00 + r01 * a01 + r02 * a02, r10 * a00 + r11 * a01 + r12 * a02, r20 * a00 + r21 * a01 + r22 * a02
    c10, c11, c12 = r00 * a10 + r01 * a11 + r02 * a12, r10 * a10 + r11 * a11 + r12 * a12, r20 * a10 + r21 * a11 + r22 * a12
    c20, c21, c22 = r00 * a20 + r01 * a21 + r02 * a22, r10 * a20 + r11 * a21 + r12 * a22, r20 * a20 + r21 * a21 + r22 * a22
    return c00 * L0 + c01 * L1 + c02 * L2, c10 * L0 + c11 * L1 + c12 * L2, c20 * L0 + c21 * L1 + c22 * L2


@jit
def _rk4_slopes(q0, q1, q2, q3, L0, L1, L2, p0, p1, p2, M, b, g0, g1, g2):
    """compiled.rigid_body_derivative torque-free, flat: (dx, dq, dp, dL) as 13 floats."""
    w0, w1, w2 = _omega(q0, q1, q2, q3, L0, L1, L2, b)
    # dq = 1/2 (0, w) q
    dq0 = 0.5 * (0.0 * q0 - w0 * q1 - w1 * q2 - w2 * q3)
    dq1 = 0.5 * (0.0 * q1 + w0 * q0 + w1 * q3 - w2 * q2)
    dq2 = 0.5 * (0.0 * q2 - w0 * q3 + w1 * q0 + w2 * q1)
    dq3 = 0.5 * (0.0 * q3 + w0 * q2 - w1 * q1 + w2 * q0)
    return (p0 / M, p1 / M, p2 / M, dq0, dq1, dq2, dq3,
            0.0 + M * g0, 0.0 + M * g1, 0.0 + M * g2, 0.0, 0.0, 0.0)


@jit
def floor_rk4(x, q, p, L, dt, steps, M, I_inv, g, out_x, out_q, out_v, out_w):
    """compiled.rk4_step's run (run_quat), torque-free, flat: rows 1..steps of x, q, v = p / M and
    w = R I_b^-1 R^T L (world)."""
    y = (x[0], x[1], x[2], q[0], q[1], q[2], q[3], p[0], p[1], p[2], L[0], L[1], L[2])
    g0, g1, g2 = g
    h6 = dt / 6.0
    for k in range(steps):
        k1 = _rk4_slopes(y[3], y[4], y[5], y[6], y[10], y[11], y[12], y[7], y[8], y[9], M, I_inv, g0, g1, g2)
        s = _rk4_add(y, 0.5 * dt, k1)
        k2 = _rk4_slopes(s[3], s[4], s[5], s[6], s[10], s[11], s[12], s[7], s[8], s[9], M, I_inv, g0, g1, g2)
        s = _rk4_add(y, 0.5 * dt, k2)
        k3 = _rk4_slopes(s[3], s[4], s[5], s[6], s[10], s[11], s[12], s[7], s[8], s[9], M, I_inv, g0, g1, g2)
        s = _rk4_add(y, dt, k3)
        k4 = _rk4_slopes(s[3], s[4], s[5], s[6], s[10], s[11], s[12], s[7], s[8], s[9], M, I_inv, g0, g1, g2)
        y = _rk4_combine(y, h6, k1, k2, k3, k4)
        n = math.sqrt(y[3] * y[3] + y[4] * y[4] + y[5] * y[5] + y[6] * y[6])
        y = (y[0], y[1], y[2], y[3] / n, y[4] / n, y[5] / n, y[6] / n, y[7], y[8], y[9], y[10], y[11], y[12])
        j = k + 1
        out_x[j, 0], out_x[j, 1], out_x[j, 2] = y[0], y[1], y[2]
        out_q[j, 0], out_q[j, 1], out_q[j, 2], out_q[j, 3] = y[3], y[4], y[5], y[6]
        out_v[j, 0], out_v[j, 1], out_v[j, 2] = y[7] / M, y[8] / M, y[9] / M
        out_w[j, 0], out_w[j, 1], out_w[j, 2] = _omega(y[3], y[4], y[5], y[6], y[10], y[11], y[12], I_inv)


@jit
def _rk4_add(y, c, d):
    """y + c d, 13 floats."""
    return (y[0] + c * d[0], y[1] + c * d[1], y[2] + c * d[2], y[3] + c * d[3], y[4] + c * d[4],
            y[5] + c * d[5], y[6] + c * d[6], y[7] + c * d[7], y[8] + c * d[8], y[9] + c * d[9],
            y[10] + c * d[10], y[11] + c * d[11], y[12] + c * d[12])



@jit
def _rk4_combine(y, h6, a, b, c, e):
    """y + h/6 (a + 2 b + 2 c + e), 13 floats (compiled._rk4_sum's order)."""
    return (y[0] + h6 * (((a[0] + 2.0 * b[0]) + 2.0 * c[0]) + e[0]), y[1] + h6 * (((a[1] + 2.0 * b[1]) + 2.0 * c[1]) + e[1]),
            y[2] + h6 * (((a[2] + 2.0 * b[2]) + 2.0 * c[2]) + e[2]), y[3] + h6 * (((a[3] + 2.0 * b[3]) + 2.0 * c[3]) + e[3]),
            y[4] + h6 * (((a[4] + 2.0 * b[4]) + 2.0 * c[4]) + e[4]), y[5] + h6 * (((a[5] + 2.0 * b[5]) + 2.0 * c[5]) + e[5]),
            y[6] + h6 * (((a[6] + 2.0 * b[6]) + 2.0 * c[6]) + e[6]), y[7] + h6 * (((a[7] + 2.0 * b[7]) + 2.0 * c[7]) + e[7]),
            y[8] + h6 * (((a[8] + 2.0 * b[8]) + 2.0 * c[8]) + e[8]), y[9] + h6 * (((a[9] + 2.0 * b[9]) + 2.0 * c[9]) + e[9]),
            y[10] + h6 * (((a[10] + 2.0 * b[10]) + 2.0 * c[10]) + e[10]),
            y[11] + h6 * (((a[11] + 2.0 * b[11]) + 2.0 * c[11]) + e[11]),
            y[12] + h6 * (((a[12] + 2.0 * b[12]) + 2.0 * c[12]) + e[12]))



# --- the Lie-group schemes: one loop each, compiled.py's formula helpers (LLVM inlines them) ------
# The same operations as their maps' steps with the zero wrench in place of compiled.wrench (which
# returns exactly these zeros torque-free): the floor of a driver is its loop without the loads.

ZERO3 = (0.0, 0.0, 0.0)


@jit
def _kick(p, L, h, M, g):
    """Half a kick of the zero wrench: p + h (0 + M g), L + h 0 (compiled.splitting_step's)."""
    return add(p, scale(h, add(ZERO3, scale(M, g)))), add(L, scale(h, ZERO3))


@jit
def _put_quat_state(j, x, q, p, L, M, I_inv, out_x, out_q, out_v, out_w):
    """Row j: x, q, v = p / M, w = R I_b^-1 R^T L (world)."""
    out_x[j, 0], out_x[j, 1], out_x[j, 2] = x
    out_q[j, 0], out_q[j, 1], out_q[j, 2], out_q[j, 3] = q
    out_v[j, 0], out_v[j, 1], out_v[j, 2] = div(p, M)
    out_w[j, 0], out_w[j, 1], out_w[j, 2] = omega_world(matrix_from_quat(q), I_inv, L)


@jit
def floor_splitting(x, q, p, L, dt, steps, M, axes, moments, I_inv, g, out_x, out_q, out_v, out_w):
    """compiled.run_splitting torque-free: kick, drift (free_rotation), kick."""
    for k in range(steps):
        p, L = _kick(p, L, 0.5 * dt, M, g)
        x = add(x, div(scale(dt, p), M))
        q = free_rotation(q, L, dt, axes, moments)
        p, L = _kick(p, L, 0.5 * dt, M, g)
        _put_quat_state(k + 1, x, q, p, L, M, I_inv, out_x, out_q, out_v, out_w)


@jit
def floor_midpoint(x, q, p, L, dt, steps, M, I_inv, g, out_x, out_q, out_v, out_w):
    """compiled.implicit_midpoint_step's run torque-free: kick, Newton on Pi, Cayley drift, kick."""
    for k in range(steps):
        p, L = _kick(p, L, 0.5 * dt, M, g)
        x = add(x, div(scale(dt, p), M))
        Pi = matvec(transpose(matrix_from_quat(q)), L)
        w_mid = midpoint_momentum(Pi, dt, I_inv)
        q = quat_normalize(quat_multiply(q, cayley_quat(scale(dt, w_mid))))
        p, L = _kick(p, L, 0.5 * dt, M, g)
        _put_quat_state(k + 1, x, q, p, L, M, I_inv, out_x, out_q, out_v, out_w)


@jit
def _rkmk_free_slopes(q, p, L, M, I_inv, g):
    """compiled._rkmk_slopes with the zero wrench: (dx, w (world), dp, dL)."""
    return div(p, M), omega_world(matrix_from_quat(q), I_inv, L), add(ZERO3, scale(M, g)), ZERO3


@jit
def _rkmk_free_stage(x, q, p, L, dt, c, d, K, M, I_inv, g):
    """compiled._rkmk_stage with the zero wrench."""
    u = scale(dt * c, K)
    s = _rkmk_free_slopes(quat_multiply(quat_from_rotvec(u), q), add(p, scale(dt * c, d[2])),
                          add(L, scale(dt * c, d[3])), M, I_inv, g)
    return s, dexpinv_world(u, s[1])


@jit
def floor_rkmk4(x, q, p, L, dt, steps, M, I_inv, g, out_x, out_q, out_v, out_w):
    """compiled.rkmk4_step's run torque-free: RK4 on (x, p, L), RKMK4 on q."""
    for k in range(steps):
        d1 = _rkmk_free_slopes(q, p, L, M, I_inv, g)
        K1 = d1[1]
        d2, K2 = _rkmk_free_stage(x, q, p, L, dt, RK4_C[0], d1, K1, M, I_inv, g)
        d3, K3 = _rkmk_free_stage(x, q, p, L, dt, RK4_C[1], d2, K2, M, I_inv, g)
        d4, K4 = _rkmk_free_stage(x, q, p, L, dt, RK4_C[2], d3, K3, M, I_inv, g)
        u = scale(dt, add(add(add(scale(RK4_B[0], K1), scale(RK4_B[1], K2)), scale(RK4_B[2], K3)),
                          scale(RK4_B[3], K4)))
        x, q, p, L = (rkmk_sum(x, dt, d1[0], d2[0], d3[0], d4[0]),
                      quat_normalize(quat_multiply(quat_from_rotvec(u), q)),
                      rkmk_sum(p, dt, d1[2], d2[2], d3[2], d4[2]), rkmk_sum(L, dt, d1[3], d2[3], d3[3], d4[3]))
        _put_quat_state(k + 1, x, q, p, L, M, I_inv, out_x, out_q, out_v, out_w)


# --- from a Problem ------------------------------------------------------------------------------

FLOORS = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro", "rk4", "symplectic-splitting",
          "implicit-midpoint", "rkmk4")


def run_floor(problem, integrator: str, dt: float, steps: int):
    """The floor of ``integrator`` (one of :data:`FLOORS`) on a torque-free ``problem``: the same
    Trajectory as ``integrators.simulate(problem, integrator, dt, steps)``, bit for bit."""
    from .compiled import mat, vec
    from .conventions import Trajectory
    from .integrators import initial_arrays, time_grid

    if problem.loads:
        raise ValueError("a floor is the torque-free arithmetic: this problem has loads")
    if integrator not in FLOORS:
        raise KeyError(integrator)
    M, I_b, I_inv, x, q, R, p, L, v, w = initial_arrays(problem)
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    out.t[:] = time_grid(dt, steps)
    rows = (out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    state = (vec(x), vec(q), vec(p), vec(L), float(dt), int(steps), float(M))
    if integrator not in FLOORS[:2]:
        out.linear_velocity[0] = p / M
        out.angular_velocity[0] = np.array(problem.initial.angular_velocity, float)
    if integrator == "symplectic-splitting":
        from .splitting import principal_frame

        frame = principal_frame(I_b)
        floor_splitting(*state, mat(frame.axes), vec(frame.moments), mat(I_inv), vec(problem.gravity), *rows)
        return out
    if integrator in ("rk4", "implicit-midpoint", "rkmk4"):
        run = {"rk4": floor_rk4, "implicit-midpoint": floor_midpoint, "rkmk4": floor_rkmk4}[integrator]
        run(*state, mat(I_inv), vec(problem.gravity), *rows)
        return out
    floor_semi_implicit(vec(x), vec(q), vec(v), vec(R.T @ w), float(dt), int(steps), float(M), mat(I_b),
                        mat(I_inv), vec(problem.gravity), integrator == "semi-implicit-implicit-gyro",
                        out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    return out


def time_floor(problem, integrator: str, dt: float, steps: int, repeats: int = 5) -> tuple[float, float]:
    """(driver, floor) CPU seconds a step, medians of ``repeats`` interleaved runs of ``steps`` steps:
    ``integrators.simulate`` (the whole call, as ``freebody run`` makes it) against :func:`run_floor`
    (compiled, or loaded from numba's cache, before timing)."""
    from .integrators import simulate

    simulate(problem, integrator, dt, 2)
    run_floor(problem, integrator, dt, 2)
    driver, floor = [], []
    for _ in range(repeats):
        t = time.process_time()
        simulate(problem, integrator, dt, steps)
        driver.append((time.process_time() - t) / steps)
        t = time.process_time()
        run_floor(problem, integrator, dt, steps)
        floor.append((time.process_time() - t) / steps)
    return float(np.median(driver)), float(np.median(floor))
