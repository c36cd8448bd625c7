"""The engine-equivalent maps of :mod:`engine_maps`, one body, as compiled scalar code (numba).

Each function is its numpy namesake in :mod:`engine_maps` written with the same formulas in the same
order of operations on plain floats, with the tuple helpers of :mod:`compiled` (a vector is a tuple
(x, y, z), a quaternion (w, x, y, z), a matrix a tuple of its rows) and its :func:`compiled.wrench`
for the loads.  :mod:`engine_maps` stays the readable reference; this module is what
``integrators.simulate(problem, name, ...)`` runs for an engine map; ``tests/test_engine_maps.py``
checks each step against the numpy step to a few ulps (numpy's 3x3 products go through BLAS, so the
two round differently in a few places).  Blow-ups give inf/NaN (``error_model="numpy"``).
"""
from __future__ import annotations

import math

import numpy as np

from .compiled import (add, add4, cross, div, dot, helper, jit, loads_of, mat, mat_add, mat_scale, mat_sub,
                       matmul, matrix_from_quat, matvec, put_row, quat_from_rotvec, quat_multiply, scale, scale4,
                       semi_implicit_velocities, skew, sub, transpose, vec, wrench)
from .conventions import Trajectory
from .engine_maps import (BULLET_ANGULAR_MOTION_THRESHOLD, BULLET_SERIES_BELOW, BULLET_SIMD_EPSILON,
                          DART_EXPMAP_SERIES_BELOW, DEXPINV_SERIES_BELOW, ENGINE_MAPS, MJ_MINVAL,
                          dart_log_map as _numpy_dart_log_map, physx_principal_frame, principal_frame)
from .lie_integrators import RK4_B
from .problem import Problem
from .rotations import matrix_from_quat as _numpy_matrix_from_quat, quat_conjugate
from .sampling import LOAD_SAMPLING_PER_STAGE, check_load_sampling

__all__ = ["simulate_compiled_engine_map", "mujoco_rk4_step", "implicit_gyro_split_torque_step",
           "explicit_gyro_truncated_exp_step", "explicit_gyro_rescaled_momentum_step"]

_B1, _B2, _B3, _B4 = RK4_B


# --- MuJoCo RK4 ----------------------------------------------------------------------------------

@helper
def _mj_normalize4(q):
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if abs(norm - 1.0) > MJ_MINVAL:
        return scale4(1.0 / norm, q)
    return q


@helper
def mujoco_quat_integrate(q, w, h, normalize_first):
    """engine_maps.mujoco_quat_integrate: q * Exp(h w), MuJoCo's way."""
    norm = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    axis = (1.0, 0.0, 0.0) if norm < MJ_MINVAL else scale(1.0 / norm, w)
    angle = h * norm
    if angle == 0.0:
        dq = (1.0, 0.0, 0.0, 0.0)
    else:
        s = math.sin(0.5 * angle)
        dq = (math.cos(0.5 * angle), axis[0] * s, axis[1] * s, axis[2] * s)
    if normalize_first:
        return quat_multiply(_mj_normalize4(q), dq)
    return _mj_normalize4(quat_multiply(q, dq))


@helper
def dexpinv(u, w):
    """engine_maps.dexpinv: w + 1/2 u x w + c(|u|) u x (u x w)."""
    t = math.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    c = 1.0 / 12.0 if t < DEXPINV_SERIES_BELOW else (1.0 - 0.5 * t / math.tan(0.5 * t)) / (t * t)
    return add(add(w, scale(0.5, cross(u, w))), scale(c, cross(u, cross(u, w))))


@helper
def _mj_acceleration(q, w_b, M, I_b, I_inv, g, f, tau):
    """(f / M + g, I^-1 (R(q)^T tau - w_b x I w_b))."""
    R = matrix_from_quat(q)
    rhs = sub(matvec(transpose(R), tau), cross(w_b, matvec(I_b, w_b)))
    return add(div(f, M), g), matvec(I_inv, rhs)


@helper
def _mj_stage(q, v, w_b, h, c, K_prev, a_prev, alpha_prev, M, I_b, I_inv, g, f, tau, munthe_kaas,
              normalize_first):
    """Stage i of mujoco_rk4_step from stage i-1's slopes: (v_i, K_i, a_i, alpha_i)."""
    dK = scale(c, K_prev)
    q_i = mujoco_quat_integrate(q, dK, h, normalize_first)
    v_i = add(v, scale(h, scale(c, a_prev)))
    w_i = add(w_b, scale(h, scale(c, alpha_prev)))
    a_i, alpha_i = _mj_acceleration(q_i, w_i, M, I_b, I_inv, g, f, tau)
    K_i = dexpinv(scale(h, dK), w_i) if munthe_kaas else w_i
    return v_i, K_i, a_i, alpha_i


@helper
def _rk4_combine(s1, s2, s3, s4):
    """b_1 s_1 + b_2 s_2 + b_3 s_3 + b_4 s_4, summed left to right."""
    return add(add(add(scale(_B1, s1), scale(_B2, s2)), scale(_B3, s3)), scale(_B4, s4))


@helper
def _mj_stage_loads(k, x, q, h, c, v_prev, K_prev, loads, normalize_first, f, tau, per_stage):
    """The wrench stage i of mujoco_rk4_step sees: the loads of step k at the stage's state
    (x + h (c v_{i-1}), R(q_i)) when ``per_stage``, else (f, tau) as given (the step's start)."""
    if not per_stage:
        return f, tau
    q_i = mujoco_quat_integrate(q, scale(c, K_prev), h, normalize_first)
    return wrench(k, add(x, scale(h, scale(c, v_prev))), matrix_from_quat(q_i), loads)


@helper
def mujoco_rk4_step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, loads, munthe_kaas, normalize_first,
                    per_stage):
    """engine_maps.rkmk4_body_step (munthe_kaas, normalize_first) and rk4_body_exp_step (neither):
    the wrench of step k at the start (and, ``per_stage``, at every later stage's state), then
    mujoco_rk4_step."""
    h = dt
    f, tau = wrench(k, x, matrix_from_quat(q), loads)
    a1, alpha1 = _mj_acceleration(q, w_b, M, I_b, I_inv, g, f, tau)
    f2, tau2 = _mj_stage_loads(k, x, q, h, 0.5, v, w_b, loads, normalize_first, f, tau, per_stage)
    v2, K2, a2, alpha2 = _mj_stage(q, v, w_b, h, 0.5, w_b, a1, alpha1, M, I_b, I_inv, g, f2, tau2,
                                   munthe_kaas, normalize_first)
    f3, tau3 = _mj_stage_loads(k, x, q, h, 0.5, v2, K2, loads, normalize_first, f, tau, per_stage)
    v3, K3, a3, alpha3 = _mj_stage(q, v, w_b, h, 0.5, K2, a2, alpha2, M, I_b, I_inv, g, f3, tau3,
                                   munthe_kaas, normalize_first)
    f4, tau4 = _mj_stage_loads(k, x, q, h, 1.0, v3, K3, loads, normalize_first, f, tau, per_stage)
    v4, K4, a4, alpha4 = _mj_stage(q, v, w_b, h, 1.0, K3, a3, alpha3, M, I_b, I_inv, g, f4, tau4,
                                   munthe_kaas, normalize_first)
    v_new = add(v, scale(h, _rk4_combine(a1, a2, a3, a4)))
    w_new = add(w_b, scale(h, _rk4_combine(alpha1, alpha2, alpha3, alpha4)))
    x_new = add(x, scale(h, _rk4_combine(v, v2, v3, v4)))
    q_new = mujoco_quat_integrate(q, _rk4_combine(w_b, K2, K3, K4), h, normalize_first)
    return x_new, q_new, v_new, w_new


@jit
def run_mujoco_rk4(x, q, v, w_b, dt, steps, M, I_b, I_inv, g, loads, munthe_kaas, normalize_first,
                   per_stage, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v, w = R(q) w_b (world)."""
    for k in range(steps):
        x, q, v, w_b = mujoco_rk4_step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, loads, munthe_kaas,
                                       normalize_first, per_stage)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, q)
        put_row(out_v, k + 1, v)
        put_row(out_w, k + 1, matvec(matrix_from_quat(q), w_b))


# --- PyBullet maximal ----------------------------------------------------------------------------

@helper
def solve33(J, b):
    """engine_maps.solve33: Bullet's Cramer's rule on J's columns."""
    Jt = transpose(J)
    c1, c2, c3 = Jt[0], Jt[1], Jt[2]
    det = dot(c1, cross(c2, c3))
    if abs(det) > BULLET_SIMD_EPSILON:
        det = 1.0 / det
    return (det * dot(b, cross(c2, c3)), det * dot(c1, cross(b, c3)), det * dot(c1, cross(c2, b)))


@jit
def bullet_matrix_from_quat(q):
    """engine_maps.bullet_matrix_from_quat (btMatrix3x3::setRotation)."""
    w, x, y, z = q
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return ((1.0 - (yy + zz), xy - wz, xz + wy),
            (xy + wz, 1.0 - (xx + zz), yz - wx),
            (xz - wy, yz + wx, 1.0 - (xx + yy)))


@helper
def _quat_from_matrix_about(m, i):
    """The quaternion (wxyz) of a rotation matrix with no positive trace, from its largest diagonal
    entry i (Shoemake's branch, as Bullet's getRotation and Eigen both compute it; they differ only
    in how they pick i)."""
    j = (i + 1) % 3
    k = (i + 2) % 3
    t = math.sqrt(m[i][i] - m[j][j] - m[k][k] + 1.0)
    qi = 0.5 * t
    t = 0.5 / t
    qw = (m[k][j] - m[j][k]) * t
    qj = (m[j][i] + m[i][j]) * t
    qk = (m[k][i] + m[i][k]) * t
    if i == 0:
        return (qw, qi, qj, qk)
    if i == 1:
        return (qw, qk, qi, qj)
    return (qw, qj, qk, qi)


@helper
def bullet_quat_from_matrix(m):
    """engine_maps.bullet_quat_from_matrix (btMatrix3x3::getRotation), wxyz."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > 0.0:
        s = math.sqrt(trace + 1.0)
        qw = s * 0.5
        s = 0.5 / s
        return (qw, (m[2][1] - m[1][2]) * s, (m[0][2] - m[2][0]) * s, (m[1][0] - m[0][1]) * s)
    if m[0][0] < m[1][1]:
        i = 2 if m[1][1] < m[2][2] else 1
    else:
        i = 2 if m[0][0] < m[2][2] else 0
    return _quat_from_matrix_about(m, i)


@helper
def bullet_quat_rotate(q, u):
    """engine_maps.bullet_quat_rotate: q (0, u) q^-1."""
    p = quat_multiply(quat_multiply(q, (0.0, u[0], u[1], u[2])), (q[0], -q[1], -q[2], -q[3]))
    return (p[1], p[2], p[3])


@helper
def bullet_integrate_rotation(B, w, h):
    """engine_maps.bullet_integrate_rotation: setRotation(normalize(dq * getRotation(B)))."""
    a2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    a = math.sqrt(a2) if a2 > BULLET_SIMD_EPSILON else 0.0
    if a * h > BULLET_ANGULAR_MOTION_THRESHOLD:
        a = BULLET_ANGULAR_MOTION_THRESHOLD / h
    if a < BULLET_SERIES_BELOW:
        axis = scale(0.5 * h - (h * h * h) * 0.020833333333 * a * a, w)
    else:
        axis = scale(math.sin(0.5 * a * h) / a, w)
    p = quat_multiply((math.cos(a * h * 0.5), axis[0], axis[1], axis[2]), bullet_quat_from_matrix(B))
    p = scale4(1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]), p)
    return bullet_matrix_from_quat(p)


@helper
def implicit_gyro_split_torque_step(k, x, B, v, w, dt, M, moments, Vt, g, loads):
    """engine_maps.implicit_gyro_split_torque_step (PyBullet maximal); B the principal basis."""
    h = dt
    f, tau = wrench(k, x, matmul(B, Vt), loads)
    dv = scale(h, scale(1.0 / M, add(f, scale(M, g))))
    inv = (1.0 / moments[0], 1.0 / moments[1], 1.0 / moments[2])
    B_scaled = ((B[0][0] * inv[0], B[0][1] * inv[1], B[0][2] * inv[2]),
                (B[1][0] * inv[0], B[1][1] * inv[1], B[1][2] * inv[2]),
                (B[2][0] * inv[0], B[2][1] * inv[1], B[2][2] * inv[2]))
    I_w_inv = matmul(B_scaled, transpose(B))
    dw = scale(h, matvec(transpose(I_w_inv), tau))  # tau^T I_w^-1
    q = bullet_quat_from_matrix(B)
    I = ((moments[0], 0.0, 0.0), (0.0, moments[1], 0.0), (0.0, 0.0, moments[2]))
    w_b = bullet_quat_rotate((q[0], -q[1], -q[2], -q[3]), w)
    I_w_b = matvec(I, w_b)
    J = mat_add(I, mat_scale(h, mat_sub(matmul(skew(w_b), I), skew(I_w_b))))
    w_b_new = sub(w_b, solve33(J, scale(h, cross(w_b, I_w_b))))
    dw = add(dw, sub(bullet_quat_rotate(q, w_b_new), w))
    v = add(v, dv)
    w = add(w, dw)
    return add(x, scale(h, v)), bullet_integrate_rotation(B, w, h), v, w


@jit
def run_bullet_maximal(x, B, v, w, dt, steps, M, moments, Vt, q_V_inv, g, loads,
                       out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q_body = getRotation(B) q_V^-1, v, w (world)."""
    for k in range(steps):
        x, B, v, w = implicit_gyro_split_torque_step(k, x, B, v, w, dt, M, moments, Vt, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, quat_multiply(bullet_quat_from_matrix(B), q_V_inv))
        put_row(out_v, k + 1, v)
        put_row(out_w, k + 1, w)


# --- DART ----------------------------------------------------------------------------------------

@helper
def dart_exp_map_rot(phi):
    """engine_maps.dart_exp_map_rot: Rodrigues, or I + [phi] + 1/2 [phi]^2 below 1e-3 rad."""
    t = math.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    S = skew(phi)
    S2 = matmul(S, S)
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    if t < DART_EXPMAP_SERIES_BELOW:
        return mat_add(mat_add(eye, S), mat_scale(0.5, S2))
    return mat_add(mat_add(eye, mat_scale(math.sin(t) / t, S)), mat_scale((1.0 - math.cos(t)) / (t * t), S2))


@helper
def _eigen_quat_from_matrix(m):
    """engine_maps._eigen_quat_from_matrix (Eigen's Shoemake), wxyz."""
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0.0:
        t = math.sqrt(tr + 1.0)
        w = 0.5 * t
        t = 0.5 / t
        return (w, (m[2][1] - m[1][2]) * t, (m[0][2] - m[2][0]) * t, (m[1][0] - m[0][1]) * t)
    i = 0
    if m[1][1] > m[0][0]:
        i = 1
    if m[2][2] > m[i][i]:
        i = 2
    return _quat_from_matrix_about(m, i)


@helper
def dart_log_map(R):
    """engine_maps.dart_log_map: Eigen::AngleAxisd(R).angle() * axis()."""
    q = _eigen_quat_from_matrix(R)
    n = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if n == 0.0:
        return (0.0, 0.0, 0.0)
    angle = 2.0 * math.atan2(n, abs(q[0]))
    vec_ = (q[1] / n, q[2] / n, q[3] / n) if q[0] >= 0.0 else (-q[1] / n, -q[2] / n, -q[3] / n)
    return scale(angle, vec_)


@helper
def explicit_gyro_truncated_exp_step(k, x, phi, v, w_b, dt, M, I_b, I_inv, g, loads):
    """engine_maps.explicit_gyro_truncated_exp_step (DART)."""
    R = dart_exp_map_rot(phi)
    # bool(False): typed bool, as semi_implicit_step's flag (a literal False compiles a second copy)
    x, v, w_b = semi_implicit_velocities(k, x, R, v, w_b, dt, M, I_b, I_inv, g, loads, bool(False))
    phi = dart_log_map(matmul(R, dart_exp_map_rot(scale(dt, w_b))))
    return x, phi, v, w_b


@jit
def run_dart(x, phi, v, w_b, dt, steps, M, I_b, I_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q = Exp(phi) (as the adapter reads the positions), v, w = expMapRot(phi) w_b."""
    for k in range(steps):
        x, phi, v, w_b = explicit_gyro_truncated_exp_step(k, x, phi, v, w_b, dt, M, I_b, I_inv, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, quat_from_rotvec(phi))
        put_row(out_v, k + 1, v)
        put_row(out_w, k + 1, matvec(dart_exp_map_rot(phi), w_b))


# --- PhysX 5 (SAPIEN) ----------------------------------------------------------------------------

@helper
def physx_integrate_rotation(q, w, h):
    """engine_maps.physx_integrate_rotation: normalize(dq * q), w world."""
    a2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if a2 == 0.0:
        return q
    a = math.sqrt(a2)
    s, c = math.sin(0.5 * h * a) / a, math.cos(0.5 * h * a)
    p = add4(quat_multiply((0.0, w[0] * s, w[1] * s, w[2] * s), q), scale4(c, q))
    return scale4(1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]), p)


@helper
def physx_gyroscopic_velocity(q, w, moments, h):
    """engine_maps.physx_gyroscopic_velocity: explicit, |L_body| kept."""
    R = matrix_from_quat(q)
    w_b = matvec(transpose(R), w)
    L = (moments[0] * w_b[0], moments[1] * w_b[1], moments[2] * w_b[2])
    L_new = sub(L, scale(h, cross(w_b, L)))
    n = math.sqrt(dot(L_new, L_new))
    L_new = scale(math.sqrt(dot(L, L)) / n, L_new) if n > 0.0 else (0.0, 0.0, 0.0)
    return add(w, matvec(R, sub((L_new[0] / moments[0], L_new[1] / moments[1], L_new[2] / moments[2]), w_b)))


@helper
def explicit_gyro_rescaled_momentum_step(k, x, q, v, w, dt, M, moments, Vt, g, loads):
    """engine_maps.explicit_gyro_rescaled_momentum_step (PhysX); q the principal frame."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, matmul(R, Vt), loads)
    v = add(v, scale(h, scale(1.0 / M, f)))
    tau_p = matvec(transpose(R), tau)
    w = add(w, scale(h, matvec(R, (tau_p[0] / moments[0], tau_p[1] / moments[1], tau_p[2] / moments[2]))))
    v = add(v, scale(h, g))
    w = physx_gyroscopic_velocity(q, w, moments, h)
    return add(x, scale(h, v)), physx_integrate_rotation(q, w, h), v, w


@jit
def run_physx(x, q, v, w, dt, steps, M, moments, Vt, q_V_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q_body = q_principal q_V^-1 (the actor pose), v, w (world)."""
    for k in range(steps):
        x, q, v, w = explicit_gyro_rescaled_momentum_step(k, x, q, v, w, dt, M, moments, Vt, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, quat_multiply(q, q_V_inv))
        put_row(out_v, k + 1, v)
        put_row(out_w, k + 1, w)


# --- Drake (pydrake MultibodyPlant) --------------------------------------------------------------
# (imported here, beside the only code that uses them)
from .compiled import solve  # noqa: E402
from .engine_maps import DRAKE_SEMI_IMPLICIT, DRAKE_TABLEAUS  # noqa: E402


@helper
def drake_time_derivatives(y, M, I_b, g, f, tau):
    """engine_maps.drake_time_derivatives: [1/2 (0, w) q, v, I_w^-1 (tau - w x I_w w), f / M + g]
    (13,) of Drake's state y = [q (as stored), x, w, v] (13,)."""
    q = (y[0], y[1], y[2], y[3])
    w = (y[7], y[8], y[9])
    R = matrix_from_quat(q)
    I_w = matmul(matmul(R, I_b), transpose(R))
    qdot = scale4(0.5, quat_multiply((0.0, w[0], w[1], w[2]), q))
    wdot = solve(I_w, sub(tau, cross(w, matvec(I_w, w))))
    vdot = add(div(f, M), g)
    out = np.empty(13)
    for i in range(4):
        out[i] = qdot[i]
    for i in range(3):
        out[4 + i] = y[10 + i]
        out[7 + i] = wdot[i]
        out[10 + i] = vdot[i]
    return out


@helper
def drake_explicit_rk_step(k, y, dt, M, I_b, g, loads, A, b, per_stage):
    """engine_maps.drake_explicit_rk_step: A (s, s) the tableau's rows (zeros above the
    diagonal), b (s,); ``per_stage``: the wrench at every stage's state, else the step's start's."""
    h = dt
    f, tau = wrench(k, (y[4], y[5], y[6]), matrix_from_quat((y[0], y[1], y[2], y[3])), loads)
    s = len(b)
    K = np.empty((s, 13))
    for i in range(s):
        y_i = y.copy()
        for j in range(i):
            if A[i, j] != 0.0:
                c = h * A[i, j]
                for n in range(13):
                    y_i[n] = y_i[n] + c * K[j, n]
        if per_stage and i > 0:
            f, tau = wrench(k, (y_i[4], y_i[5], y_i[6]),
                            matrix_from_quat((y_i[0], y_i[1], y_i[2], y_i[3])), loads)
        d = drake_time_derivatives(y_i, M, I_b, g, f, tau)
        for n in range(13):  # element by element: ``K[i] = d`` compiles numba's shape-error message (~1.5 s cold)
            K[i, n] = d[n]
    out = y.copy()
    for i in range(s):
        if b[i] != 0.0:
            c = h * b[i]
            for n in range(13):
                out[n] = out[n] + c * K[i, n]
    return out


@helper
def drake_semi_explicit_euler_step(k, y, dt, M, I_b, g, loads):
    """engine_maps.drake_semi_explicit_euler_step (Drake's discrete plant)."""
    h = dt
    q = (y[0], y[1], y[2], y[3])
    f, tau = wrench(k, (y[4], y[5], y[6]), matrix_from_quat(q), loads)
    d = drake_time_derivatives(y, M, I_b, g, f, tau)
    out = np.empty(13)
    for i in range(3):
        out[7 + i] = y[7 + i] + h * d[7 + i]
        out[10 + i] = y[10 + i] + h * d[10 + i]
        out[4 + i] = y[4 + i] + h * out[10 + i]
    dq = scale4(0.5, quat_multiply((0.0, out[7], out[8], out[9]), q))
    for i in range(4):
        out[i] = q[i] + h * dq[i]
    return out


@jit
def run_drake(y, dt, steps, M, I_b, g, loads, A, b, semi, per_stage, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q / |q|, v, w (world) from Drake's state y = [q, x, w, v]."""
    for k in range(steps):
        if semi:
            y = drake_semi_explicit_euler_step(k, y, dt, M, I_b, g, loads)
        else:
            y = drake_explicit_rk_step(k, y, dt, M, I_b, g, loads, A, b, per_stage)
        n = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
        for i in range(4):
            out_q[k + 1, i] = y[i] / n
        for i in range(3):
            out_x[k + 1, i] = y[4 + i]
            out_w[k + 1, i] = y[7 + i]
            out_v[k + 1, i] = y[10 + i]


def drake_tableau_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
    """DRAKE_TABLEAUS[name] as (A (s, s), b (s,)) float64 arrays for run_drake (a dummy for the
    semi-implicit map, which has none)."""
    if name == DRAKE_SEMI_IMPLICIT:
        return np.zeros((1, 1)), np.ones(1)
    rows, b = DRAKE_TABLEAUS[name]
    A = np.zeros((len(b), len(b)))
    for i, row in enumerate(rows):
        A[i, :len(row)] = row
    return A, np.array(b, dtype=float)


# --- Newton 1.8 (Warp): SolverSteel, SolverVBD, SolverKamino --------------------------------------
# (imported here, beside the only code that uses them)
from .compiled import inverse_transpose  # noqa: E402
from .engine_maps import (KAMINO_EXP_SERIES_BELOW, NEWTON_STEPS, STEEL_GYRO_ENERGY_RTOL,  # noqa: E402
                          STEEL_GYRO_ITERATIONS, STEEL_GYRO_MAX_MICROSTEPS)

_NEWTON_KIND = {name: i for i, name in enumerate(NEWTON_STEPS)}  # run_newton's switch


@helper
def newton_quat_rate_integrate(q, w, h):
    """engine_maps.newton_quat_rate_integrate: normalize(q + h/2 (0, w) q), w world."""
    p = add4(q, scale4(0.5 * h, quat_multiply((0.0, w[0], w[1], w[2]), q)))
    return scale4(1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]), p)


@helper
def steel_gyroscopic_velocity(I_b, u, h):
    """engine_maps.steel_gyroscopic_velocity: Cayley microsteps of the body rate u."""
    s = max(I_b[0][0], max(I_b[1][1], I_b[2][2]))
    A = mat_scale(1.0 / s, I_b)
    A_inv_t = inverse_transpose(A)
    speed = math.sqrt(max(dot(u, matvec(A, u)) * (A_inv_t[0][0] + A_inv_t[1][1] + A_inv_t[2][2]), 0.0))
    m = int(min(max(math.ceil(2.0 * abs(h) * speed), 1.0), float(STEEL_GYRO_MAX_MICROSTEPS)))
    h_m = h / m
    w = u
    for _ in range(m):
        u = w
        energy = dot(u, matvec(A, u))
        for _ in range(STEEL_GYRO_ITERATIONS):
            S = mat_scale(0.5 * h_m, skew(matvec(A, scale(0.5, add(u, w)))))
            candidate = solve(mat_sub(A, S), matvec(mat_add(A, S), u))
            delta = sub(candidate, w)
            w = candidate
            if dot(delta, matvec(A, delta)) <= STEEL_GYRO_ENERGY_RTOL * energy:
                break
    return w


@helper
def quat_rate_cayley_gyro_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads):
    """engine_maps.quat_rate_cayley_gyro_step (Newton Steel)."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    v = add(v, scale(h, add(div(f, M), g)))
    Rt = transpose(R)
    u = add(matvec(Rt, w), scale(h, matvec(I_inv, matvec(Rt, tau))))
    w = matvec(R, steel_gyroscopic_velocity(I_b, u, h))
    return add(x, scale(h, v)), newton_quat_rate_integrate(q, w, h), v, w


@helper
def quat_rate_pose_velocity_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads):
    """engine_maps.quat_rate_pose_velocity_step (Newton VBD)."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    v = add(v, scale(h, add(div(f, M), g)))
    Rt = transpose(R)
    w_b = matvec(Rt, w)
    w = matvec(R, add(w_b, scale(h, matvec(I_inv, sub(matvec(Rt, tau), cross(w_b, matvec(I_b, w_b)))))))
    q_next = newton_quat_rate_integrate(q, w, h)
    a = h * math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if a > 0.0:
        w = scale(2.0 * math.atan(0.5 * a) / a, w)
    return add(x, scale(h, v)), q_next, v, w


@helper
def kamino_quat_exp(phi):
    """engine_maps.kamino_quat_exp."""
    n = math.sqrt(dot(phi, phi))
    if n > KAMINO_EXP_SERIES_BELOW:
        s = math.sin(0.5 * n) / n
        return (math.cos(0.5 * n), s * phi[0], s * phi[1], s * phi[2])
    return (1.0, 0.5 * phi[0], 0.5 * phi[1], 0.5 * phi[2])


@helper
def explicit_gyro_rescaled_torque_last_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads):
    """engine_maps.explicit_gyro_rescaled_torque_last_step (Newton Kamino)."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    Rt = transpose(R)
    I_w = matmul(matmul(R, I_b), Rt)
    L = matvec(I_w, w)
    L_new = sub(L, scale(h, cross(w, L)))
    n = math.sqrt(dot(L_new, L_new))
    L_new = scale(math.sqrt(dot(L, L)) / n, L_new) if n > 0.0 else (0.0, 0.0, 0.0)
    v = add(v, scale(h, add(g, div(f, M))))
    I_w_inv = matmul(matmul(R, I_inv), Rt)
    w = add(w, scale(h, matvec(I_w_inv, add(div(sub(L_new, L), h), tau))))
    return add(x, scale(h, v)), quat_multiply(kamino_quat_exp(scale(h, w)), q), v, w


@jit
def run_newton(kind, x, q, v, w, dt, steps, M, I_b, I_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v, w (world) of the Newton map ``kind`` (_NEWTON_KIND)."""
    for k in range(steps):
        if kind == 0:
            x, q, v, w = quat_rate_cayley_gyro_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads)
        elif kind == 1:
            x, q, v, w = quat_rate_pose_velocity_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads)
        else:
            x, q, v, w = explicit_gyro_rescaled_torque_last_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, q)
        put_row(out_v, k + 1, v)
        put_row(out_w, k + 1, w)


# --- Brax 0.14 --------------------------------------------------------------------------------------
# (imported here, beside the only code that uses it)
from .engine_maps import BRAX_ANGULAR_NORM_EPS  # noqa: E402

# The Brax maps, in run_brax's ``kind`` order.
BRAX_MAPS = ("explicit-gyro-regularised-exp", "semi-implicit-no-gyro", "semi-implicit-no-gyro-projected")


@helper
def brax_integrate_free_rotation(q, w_b, h):
    """engine_maps.brax_integrate_free_rotation: normalize(q * (cos(a/2), w_b / n sin(a/2))),
    n = |w_b| + 1e-8, a = h n."""
    n = math.sqrt(w_b[0] * w_b[0] + w_b[1] * w_b[1] + w_b[2] * w_b[2]) + BRAX_ANGULAR_NORM_EPS
    axis = div(w_b, n)
    a = h * n
    s = math.sin(0.5 * a)
    p = quat_multiply(q, (math.cos(0.5 * a), axis[0] * s, axis[1] * s, axis[2] * s))
    return scale4(1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]), p)


@helper
def explicit_gyro_regularised_exp_step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, loads):
    """engine_maps.explicit_gyro_regularised_exp_step (Brax generalized)."""
    x, v, w_b = semi_implicit_velocities(k, x, matrix_from_quat(q), v, w_b, dt, M, I_b, I_inv, g, loads,
                                         bool(False))  # typed bool: see explicit_gyro_truncated_exp_step
    return x, brax_integrate_free_rotation(q, w_b, dt), v, w_b


@helper
def brax_quat_rate_integrate(q, w, h):
    """engine_maps.brax_quat_rate_integrate: normalize(q + (0, w h / 2) q), w world."""
    hh = 0.5 * h
    p = add4(q, quat_multiply((0.0 * hh, w[0] * hh, w[1] * hh, w[2] * hh), q))
    return scale4(1.0 / math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]), p)


@helper
def semi_implicit_no_gyro_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads, project):
    """engine_maps.semi_implicit_no_gyro_step (Brax spring; positional with ``project``)."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    w_next = add(w, scale(h, matvec(R, matvec(I_inv, matvec(transpose(R), tau)))))
    v_next = add(v, scale(h, add(g, div(f, M))))
    x_next = add(x, scale(h, v_next))
    q_next = brax_quat_rate_integrate(q, w_next, h)
    if project:
        v_next = div(sub(x_next, x), h)
        dq = quat_multiply(q_next, (q[0], -q[1], -q[2], -q[3]))
        sign = 1.0 if dq[0] >= 0.0 else -1.0
        w_next = ((2.0 * dq[1] / h) * sign, (2.0 * dq[2] / h) * sign, (2.0 * dq[3] / h) * sign)
    return x_next, q_next, v_next, w_next


@jit
def run_brax(x, q, v, w, dt, steps, M, I_b, I_inv, g, loads, kind, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v and w (world) of BRAX_MAPS[kind]; kind 0 carries w in the body
    frame (Brax's qd) and reports R w_b."""
    for k in range(steps):
        if kind == 0:
            x, q, v, w = explicit_gyro_regularised_exp_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads)
            put_row(out_w, k + 1, matvec(matrix_from_quat(q), w))
        else:
            x, q, v, w = semi_implicit_no_gyro_step(k, x, q, v, w, dt, M, I_b, I_inv, g, loads, kind == 2)
            put_row(out_w, k + 1, w)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, q)
        put_row(out_v, k + 1, v)


__all__ += ["BRAX_MAPS", "brax_integrate_free_rotation", "explicit_gyro_regularised_exp_step",
            "brax_quat_rate_integrate", "semi_implicit_no_gyro_step", "run_brax"]


# --- from a Problem --------------------------------------------------------------------------------

def simulate_compiled_engine_map(problem: Problem, name: str, dt: float, steps: int,
                                 load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> Trajectory:
    """``engine_maps.simulate_engine_map(problem, name, dt, steps, compiled=False, load_sampling)``
    by the compiled maps: the same Trajectory to rounding.  The initial state is formed in numpy
    as there."""
    from .engine_maps import initial_as_given, dart_exp_map_rot as _numpy_exp_map_rot
    from .rotations import quat_from_rotvec as _numpy_quat_from_rotvec, quat_multiply as _numpy_qmul

    if name not in ENGINE_MAPS:
        raise KeyError(name)
    per_stage = check_load_sampling(load_sampling) == LOAD_SAMPLING_PER_STAGE
    M, I_b, I_inv, x, q, v, w, g = initial_as_given(problem)
    loads = loads_of(problem, dt)
    dt, steps = float(dt), int(steps)  # one compiled signature whatever the caller passes
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    if name in ("rkmk4-body", "rk4-body-exp"):
        w_b = _numpy_matrix_from_quat(q).T @ w
        rkmk = name == "rkmk4-body"
        run_mujoco_rk4(vec(x), vec(q), vec(v), vec(w_b), dt, steps, M, mat(I_b), mat(I_inv), vec(g), loads,
                       rkmk, rkmk, per_stage, out.position, out.quaternion_wxyz, out.linear_velocity,
                       out.angular_velocity)
    elif name == "explicit-gyro-rescaled-momentum":
        moments, V, q_V = physx_principal_frame(I_b)
        run_physx(vec(x), vec(_numpy_qmul(q, q_V)), vec(v), vec(w), dt, steps, M, vec(moments), mat(V.T),
                  vec(quat_conjugate(q_V)), vec(g), loads, out.position, out.quaternion_wxyz,
                  out.linear_velocity, out.angular_velocity)
    elif name == DRAKE_SEMI_IMPLICIT or name in DRAKE_TABLEAUS:
        A, b = drake_tableau_arrays(name)
        run_drake(np.concatenate([q, x, w, v]), dt, steps, M, mat(I_b), vec(g), loads, A, b,
                  name == DRAKE_SEMI_IMPLICIT, per_stage, out.position, out.quaternion_wxyz, out.linear_velocity,
                  out.angular_velocity)
    elif name in _NEWTON_KIND:
        run_newton(_NEWTON_KIND[name], vec(x), vec(q), vec(v), vec(w), dt, steps, M, mat(I_b), mat(I_inv),
                   vec(g), loads, out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    elif name in BRAX_MAPS:
        kind = BRAX_MAPS.index(name)
        w0 = _numpy_matrix_from_quat(q).T @ w if kind == 0 else w  # generalized carries the body-frame w
        run_brax(vec(x), vec(q), vec(v), vec(w0), dt, steps, M, mat(I_b), mat(I_inv), vec(g), loads, kind,
                 out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    elif name == "implicit-gyro-split-torque":
        moments, V, q_V = principal_frame(I_b)
        B = bullet_matrix_from_quat(vec(_numpy_qmul(q, q_V)))
        run_bullet_maximal(vec(x), B, vec(v), vec(w), dt, steps, M, vec(moments), mat(V.T),
                           vec(quat_conjugate(q_V)), vec(g), loads, out.position, out.quaternion_wxyz,
                           out.linear_velocity, out.angular_velocity)
    else:
        phi = _numpy_dart_log_map(_numpy_matrix_from_quat(q))
        w_b = _numpy_exp_map_rot(phi).T @ w
        out.quaternion_wxyz[0] = _numpy_quat_from_rotvec(phi)
        run_dart(vec(x), vec(phi), vec(v), vec(w_b), dt, steps, M, mat(I_b), mat(I_inv), vec(g), loads,
                 out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    out.t[:] = np.arange(steps + 1) * dt
    return out
