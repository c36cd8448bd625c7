"""The reference integrators of :mod:`integrators`, one body, as compiled scalar code (numba).

Each scheme is the same map as its numpy function in :mod:`integrators` (``euler_matrix_step``,
``euler_quat_step``, ``lie_euler_step``, ``rk4_step``, ``semi_implicit_step``,
``splitting_step`` of :mod:`splitting`, and ``implicit_midpoint_step`` and ``rkmk4_step`` of
:mod:`lie_integrators`), written
line for line with the same formulas in the same order of operations, on plain floats: a vector is
a tuple (x, y, z), a quaternion (w, x, y, z), a matrix a tuple of its three rows.  The helpers below
(``cross``, ``matvec``, ``quat_multiply``, ...) are the textbook formulas written out component by
component, and each scheme's driver is a plain loop over the steps that writes each state into the
output arrays.  :mod:`integrators` stays the readable numpy reference; this module is what
:func:`integrators.simulate` runs (``compiled=False`` runs the numpy loops).
``tests/test_compiled_maps.py`` checks every step against the numpy step to a few ulps: numpy's 3x3
products go through BLAS (fused multiply-adds on most CPUs, BLAS's own summation order),
``np.linalg.solve`` through LAPACK and the nearest rotation through an SVD (here: Newton's polar
iteration), so the two agree to rounding, not always bit for bit.  With OpenBLAS on kernels without
fused multiply-adds (``OPENBLAS_CORETYPE=Sandybridge``) the numpy loops of euler-quat,
lie-euler, rk4 and semi-implicit-explicit-gyro give these maps' trajectories bit for bit.

Why numba.  The maps are a few hundred flops per step; a Python loop over numpy calls on 3-vectors
costs about 75 us per step in interpreter and call overhead, against about 1.5 us for MuJoCo's own
step.  ``@njit`` compiles the same Python source to machine code: 0.12 us per step for the engines'
semi-implicit maps, 0.13-0.21 us for the Euler family, 0.41 us for the symplectic splitting,
0.42 us for the implicit midpoint (Newton), 0.55 us for RK4, 1.1 us for RKMK4 (CPU time, one
body, ``scripts/bench_reference_maps.py``).  It needs no C compiler or build step (numba and llvmlite
install as binary wheels on a fresh machine), and ``cache=True`` keeps the machine code on disk
(``__pycache__`` beside this file, or ``NUMBA_CACHE_DIR``): the first use on a machine compiles every
map (with compiled_engine_maps' and the reference adapter's drivers and the truth's rhs, 126
compilations: about 20-26 s CPU in one process on 2 loaded cores, 35-41 s before the helpers lost
their Python wrappers, see :class:`CompiledHelper`), later processes load them (about 1.2 s,
``import numba`` included).  Where a cold compilation goes (numba's event API, exclusive of nested
compilations): about 80% numba's native lowering (LLVM IR built in Python, LLVM's optimisation of
the function with every callee it links, machine code), 8% type inference; each of the ~110
helpers costs 0.05-0.35 s, each driver 0.4-0.9 s, since a driver's module holds its callees' code.

Loads.  A case's loads are piecewise constant over steps: :class:`Loads` cuts the steps into
segments at the steps where the set of active loads changes (``Load.step_range``) and lists each
segment's active loads in case order, as arrays.  :func:`wrench` sums them exactly as
``Problem.wrench`` does (the torque arm of a force at a point from the state it is given: every RK4
stage sees the active set of its step, the arms at the stage's state).

Blow-ups are not errors (``error_model="numpy"``): a division by zero gives inf/NaN, as numpy's
does, and the harness calls the run diverged.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, objmode
from numba.core.registry import CPUDispatcher

from . import rotations
from .compiled_lock import serialize_if_asked
from .conventions import Trajectory
from .lie_integrators import MIDPOINT_MAX_ITERATIONS, MIDPOINT_RTOL, RK4_B, RK4_C
from .problem import Problem
from .rotations import EXP_SERIES_ANGLE_RAD

__all__ = ["Loads", "loads_of", "simulate_compiled", "wrench", "euler_matrix_step", "euler_quat_step",
           "lie_euler_step", "rk4_step", "semi_implicit_step", "free_rotation", "splitting_step",
           "implicit_midpoint_step", "rkmk4_step", "matrix_outputs"]

# Every function here: compiled on first use, cached on disk, inf/NaN rather than exceptions.
# ``jit``: a function Python calls (the drivers); ``helper`` (below): one only compiled code calls.
jit = njit(cache=True, error_model="numpy")
HELPER_OPTIONS = {"nopython": True, "error_model": "numpy", "no_cpython_wrapper": True,
                  "no_cfunc_wrapper": True}


class CompiledHelper(CPUDispatcher):
    """A numba function for compiled callers only: compiled without the CPython and C wrappers
    that let Python call it.  Those wrappers unbox and box every tuple argument and result, and
    LLVM optimises and emits them with the function: they were about 30% of a cold first
    compilation (40 -> 29 s CPU for what the quick start compiles, 1 process) and no driver uses
    them.  Called from Python (tests, an interactive session) it runs through a second, plainly
    jitted copy of the same source, compiled on that first call (not cached): the same code,
    the same numbers.  A compiled caller links this dispatcher's own compilation, as any."""

    def __call__(self, *args):
        entry = self.__dict__.get("python_entry")
        if entry is None:
            entry = self.python_entry = njit(error_model="numpy")(self.py_func)
        return entry(*args)


def helper(fn):
    """``@jit`` for a function only compiled code calls (:class:`CompiledHelper`): cached on disk
    the same way.  ``NUMBA_DISABLE_JIT=1``: the plain Python function, as ``njit`` gives."""
    from numba.core import config

    if config.DISABLE_JIT:
        return fn
    disp = CompiledHelper(py_func=fn, locals={}, targetoptions=dict(HELPER_OPTIONS))
    disp.enable_caching()
    return disp

# Workers of one pool compile each function once between them (compiled_lock: a no-op unless
# the pool asks for it).
serialize_if_asked()

# Kinds of torque arm of a load's force (Loads.kind)
AT_COM, AT_WORLD_POINT, AT_BODY_POINT = 0, 1, 2

# Newton's iteration for the nearest rotation (see nearest_rotation): scaled while a step changes X
# by more than this (Frobenius norm), then plain Newton, which converges quadratically ...
NEWTON_SCALED_UNTIL = 1e-2
# ... and is done once a step changes X by less than this (the next one would change it by about
# its square: round-off).
NEWTON_CONVERGED = 1e-9
NEWTON_MAX_ITERATIONS = 100  # a safety bound: measured at most 6 (condition 1e16, scale 1e+-50)


# --- vectors (x, y, z), quaternions (w, x, y, z), matrices (row, row, row) ------------------------

@helper
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@helper
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@helper
def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


@helper
def div(a, s):
    return (a[0] / s, a[1] / s, a[2] / s)


@helper
def add4(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


@helper
def scale4(s, a):
    return (s * a[0], s * a[1], s * a[2], s * a[3])


@helper
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@helper
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@helper
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@helper
def transpose(A):
    return ((A[0][0], A[1][0], A[2][0]), (A[0][1], A[1][1], A[2][1]), (A[0][2], A[1][2], A[2][2]))


@helper
def matvec(A, v):
    """A v."""
    return (dot(A[0], v), dot(A[1], v), dot(A[2], v))


@helper
def matmul(A, B):
    """A B."""
    Bt = transpose(B)
    return (matvec(Bt, A[0]), matvec(Bt, A[1]), matvec(Bt, A[2]))


@helper
def mat_add(A, B):
    return (add(A[0], B[0]), add(A[1], B[1]), add(A[2], B[2]))


@helper
def mat_sub(A, B):
    return (sub(A[0], B[0]), sub(A[1], B[1]), sub(A[2], B[2]))


@helper
def mat_scale(s, A):
    return (scale(s, A[0]), scale(s, A[1]), scale(s, A[2]))


@helper
def skew(w):
    """[w]: [w] v = w x v."""
    return ((0.0, -w[2], w[1]), (w[2], 0.0, -w[0]), (-w[1], w[0], 0.0))


@helper
def quat_normalize(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


@helper
def quat_multiply(a, b):
    """Hamilton product a * b: rotate by b, then by a."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


@helper
def matrix_from_quat(q):
    """R(q), body -> world (q normalised here)."""
    w, x, y, z = quat_normalize(q)
    return ((1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)),
            (2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)),
            (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)))


@helper
def quat_from_rotvec(phi):
    """Exp: the unit quaternion of the rotation vector phi (axis * angle, rad); a series for small
    angles (as rotations.quat_from_rotvec)."""
    angle = norm(phi)
    half = 0.5 * angle
    if angle < EXP_SERIES_ANGLE_RAD:  # sin(a/2)/a = 1/2 - a^2/48 + a^4/3840 - ...
        k = 0.5 - angle * angle / 48.0 + angle ** 4 / 3840.0
    else:
        k = math.sin(half) / angle
    return (math.cos(half), k * phi[0], k * phi[1], k * phi[2])


@helper
def gram_schmidt(R):
    """The columns of R re-orthonormalised by classical Gram-Schmidt, in column order."""
    M = transpose(R)  # rows of M: the columns of R
    c0 = div(M[0], norm(M[0]))
    c1 = sub(M[1], scale(dot(c0, M[1]), c0))
    c1 = div(c1, norm(c1))
    c2 = sub(sub(M[2], scale(dot(c0, M[2]), c0)), scale(dot(c1, M[2]), c1))
    c2 = div(c2, norm(c2))
    return transpose((c0, c1, c2))


@helper
def _pivot(a, b, c, col):
    """Rows (a, b, c) with the pivot row first: the first row with the largest |entry| in column
    col, swapped with row a (as LAPACK's partial pivoting)."""
    if abs(b[col]) > abs(a[col]) and abs(b[col]) >= abs(c[col]):
        return b, a, c
    if abs(c[col]) > abs(a[col]) and abs(c[col]) > abs(b[col]):
        return c, b, a
    return a, b, c


@helper
def _eliminate(r, pivot_row, col):
    """r - (r[col] / pivot_row[col]) pivot_row: row r of [J | b] with column col zeroed."""
    m = r[col] / pivot_row[col]
    return (r[0] - m * pivot_row[0], r[1] - m * pivot_row[1], r[2] - m * pivot_row[2],
            r[3] - m * pivot_row[3])


@helper
def solve(J, b):
    """J^-1 b by Gaussian elimination with partial pivoting on [J | b] (numpy: LAPACK's dgesv)."""
    r0 = (J[0][0], J[0][1], J[0][2], b[0])
    r1 = (J[1][0], J[1][1], J[1][2], b[1])
    r2 = (J[2][0], J[2][1], J[2][2], b[2])
    r0, r1, r2 = _pivot(r0, r1, r2, 0)
    r1, r2 = _eliminate(r1, r0, 0), _eliminate(r2, r0, 0)
    if abs(r2[1]) > abs(r1[1]):
        r1, r2 = r2, r1
    r2 = _eliminate(r2, r1, 1)
    x2 = r2[3] / r2[2]
    x1 = (r1[3] - r1[2] * x2) / r1[1]
    x0 = (r0[3] - r0[1] * x1 - r0[2] * x2) / r0[0]
    return (x0, x1, x2)


@helper
def inverse_transpose(X):
    """X^-T, the cofactor matrix of X over det X."""
    a, b, c = X
    cof = (cross(b, c), cross(c, a), cross(a, b))  # row i of X^-T det X
    det = dot(a, cof[0])
    return mat_scale(1.0 / det, cof)


@helper
def frobenius(A):
    return math.sqrt(dot(A[0], A[0]) + dot(A[1], A[1]) + dot(A[2], A[2]))


@helper
def nearest_rotation(A):
    """The rotation closest to A in the Frobenius norm: the orthogonal polar factor of A, by
    Newton's iteration X <- (g X + (g X)^-T) / 2 (Higham 1986), g = sqrt(||X^-1|| / ||X||) while far
    from converged.  For det A > 0 (every matrix the matrix integrators produce) this is
    rotations.nearest_rotation's U V^T (SVD) to rounding; for det A <= 0 it is that function itself,
    called back; a non-finite A gives NaN, as there."""
    ok = True
    for i in range(3):
        for j in range(3):
            ok = ok and math.isfinite(A[i][j])
    if not ok:
        nan = (math.nan, math.nan, math.nan)
        return (nan, nan, nan)
    if dot(A[0], cross(A[1], A[2])) <= 0.0:
        return _nearest_rotation_svd(A)
    X = A
    change = math.inf
    for _ in range(NEWTON_MAX_ITERATIONS):
        Y = inverse_transpose(X)
        g = math.sqrt(frobenius(Y) / frobenius(X)) if change > NEWTON_SCALED_UNTIL else 1.0
        X_new = mat_scale(0.5, mat_add(mat_scale(g, X), mat_scale(1.0 / g, Y)))
        change = frobenius(mat_sub(X_new, X))
        X = X_new
        if change < NEWTON_CONVERGED:
            break
    return X


def _numpy_nearest_rotation(A: np.ndarray) -> np.ndarray:
    return rotations.nearest_rotation(A)


@helper
def _nearest_rotation_svd(A):
    """rotations.nearest_rotation (SVD), called back in numpy: only a blown-up matrix gets here,
    and numba's own SVD would add seconds to every first compilation."""
    M = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            M[i, j] = A[i][j]
    with objmode(N="float64[:, :]"):
        N = _numpy_nearest_rotation(M)
    return ((N[0, 0], N[0, 1], N[0, 2]), (N[1, 0], N[1, 1], N[1, 2]), (N[2, 0], N[2, 1], N[2, 2]))


@helper
def quat_from_matrix(R):
    """Unit quaternion with w >= 0 of a rotation matrix (Shepperd's method, as
    rotations.quat_from_matrix: the largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 picks the formula)."""
    m00, m11, m22 = R[0][0], R[1][1], R[2][2]
    d21, d02, d10 = R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1]
    s01, s02, s12 = R[0][1] + R[1][0], R[0][2] + R[2][0], R[1][2] + R[2][1]
    cands = (1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22)
    i = 0
    for j in range(1, 4):
        if cands[j] > cands[i]:
            i = j
    r = math.sqrt(max(cands[i], 0.0))
    h = 0.5 / r
    if i == 0:
        q = (0.5 * r, d21 * h, d02 * h, d10 * h)
    elif i == 1:
        q = (d21 * h, 0.5 * r, s01 * h, s02 * h)
    elif i == 2:
        q = (d02 * h, s01 * h, 0.5 * r, s12 * h)
    else:
        q = (d10 * h, s02 * h, s12 * h, 0.5 * r)
    q = quat_normalize(q)
    return scale4(-1.0, q) if q[0] < 0.0 else q


@helper
def orthonormality_error(R):
    """||R^T R - 1||_F."""
    E = mat_sub(matmul(transpose(R), R), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))
    return frobenius(E)


@helper
def omega_world(R, I_inv, L):
    """w = R I_b^-1 R^T L, world."""
    return matvec(matmul(matmul(R, I_inv), transpose(R)), L)


# --- loads --------------------------------------------------------------------------------------

Loads = namedtuple("Loads", "k0 first force torque body_torque kind arm")
Loads.__doc__ = """A case's loads at one time step dt, as arrays for the compiled maps.

k0 : (S,) int64, ascending, k0[0] = 0: segment s holds the steps k0[s] <= k < k0[s + 1] (the last
    one every step from k0[S-1] on), on which one set of loads is active.
first : (S + 1,) int64: segment s's active loads are the rows first[s] <= i < first[s + 1] of:
force : (n, 3) N world.  torque : (n, 3) N m world (a couple).  body_torque : (n, 3) N m body frame.
kind : (n,) int64, where the force acts: AT_COM, AT_WORLD_POINT or AT_BODY_POINT.
arm : (n, 3) m: the world point (AT_WORLD_POINT), the body point in the body frame
    (AT_BODY_POINT), zeros otherwise.
"""


def loads_of(problem: Problem, dt: float) -> Loads:
    """The problem's loads at time step dt as :class:`Loads` (segments cut where
    ``Problem.active_loads`` changes, the loads of each in case order)."""
    edges = sorted({0} | {int(k) for ld in problem.loads for k in ld.step_range(dt)
                          if np.isfinite(k) and k > 0})
    rows, first = [], [0]
    for k0 in edges:
        rows += problem.active_loads(k0, dt)
        first.append(len(rows))
    n = len(rows)
    force, torque, body_torque, arm = (np.zeros((n, 3)) for _ in range(4))
    kind = np.zeros(n, dtype=np.int64)
    for i, ld in enumerate(rows):
        force[i], torque[i], body_torque[i] = ld.force, ld.torque, ld.body_torque
        if ld.point is not None:
            kind[i], arm[i] = AT_WORLD_POINT, ld.point
        elif ld.body_point is not None:
            kind[i], arm[i] = AT_BODY_POINT, ld.body_point
    return Loads(np.array(edges, dtype=np.int64), np.array(first, dtype=np.int64), force, torque,
                 body_torque, kind, arm)


@helper
def _row(a, i):
    return (a[i, 0], a[i, 1], a[i, 2])


@helper
def segment_of(k, loads):
    """The segment of step k: the last s with loads.k0[s] <= k."""
    s = len(loads.k0) - 1
    while loads.k0[s] > k:
        s -= 1
    return s


@helper
def segment_end(s, steps, loads):
    """One past the last step of segment s within a run of ``steps`` steps."""
    return steps if s + 1 == len(loads.k0) else min(steps, loads.k0[s + 1])


@helper
def wrench(k, x, R, loads):
    """(force (3,) N world, torque about the COM (3,) N m world) of the loads of step k at COM
    position x and rotation R (body -> world), gravity excluded: Problem.wrench, summed in case
    order from zero."""
    return segment_wrench(segment_of(k, loads), x, R, loads)


@helper
def segment_wrench(s, x, R, loads):
    """:func:`wrench` of any step of segment s (a driver looks the segment up once per segment)."""
    f = (0.0, 0.0, 0.0)
    tau = (0.0, 0.0, 0.0)
    for i in range(loads.first[s], loads.first[s + 1]):
        f_i = _row(loads.force, i)
        tau_i = add(_row(loads.torque, i), matvec(R, _row(loads.body_torque, i)))
        if loads.kind[i] == AT_WORLD_POINT:
            tau_i = add(tau_i, cross(sub(_row(loads.arm, i), x), f_i))
        elif loads.kind[i] == AT_BODY_POINT:
            tau_i = add(tau_i, cross(matvec(R, _row(loads.arm, i)), f_i))
        f = add(f, f_i)
        tau = add(tau, tau_i)
    return f, tau


# --- one step of each scheme (integrators.*_step, same arguments but loads for wrench) ------------

@helper
def euler_matrix_step(k, x, R, p, L, dt, M, I_inv, Mg, loads, gram):
    """Explicit Euler on (x, R, p, L), optionally Gram-Schmidt on R after the step."""
    f, tau = wrench(k, x, R, loads)
    w = omega_world(R, I_inv, L)  # I(t)^-1 L with R as integrated
    x_new = add(x, div(scale(dt, p), M))
    R_new = mat_add(R, matmul(mat_scale(dt, skew(w)), R))
    p_new = add(p, scale(dt, add(f, Mg)))
    L_new = add(L, scale(dt, tau))
    if gram:
        R_new = gram_schmidt(R_new)
    return x_new, R_new, p_new, L_new


@helper
def rigid_body_derivative(k, x, q, p, L, M, I_inv, g, loads):
    """dY/dt = (p / M, 1/2 (0, w) * q, f + M g, tau) for Y = (x, q, p, L) on step k."""
    R = matrix_from_quat(q)
    w = omega_world(R, I_inv, L)
    f, tau = wrench(k, x, R, loads)
    dq = scale4(0.5, quat_multiply((0.0, w[0], w[1], w[2]), q))
    return div(p, M), dq, add(f, scale(M, g)), tau


@helper
def euler_quat_step(k, x, q, p, L, dt, M, I_inv, g, loads):
    """Explicit Euler on (x, q, p, L), q renormalised after the step."""
    dx, dq, dp, dL = rigid_body_derivative(k, x, q, p, L, M, I_inv, g, loads)
    return (add(x, scale(dt, dx)), quat_normalize(add4(q, scale4(dt, dq))),
            add(p, scale(dt, dp)), add(L, scale(dt, dL)))


@helper
def lie_euler_step(k, x, q, p, L, dt, M, I_inv, g, loads):
    """Momenta first (kick), then x and q with the new velocities: q+ = Exp(h w+) q (world frame)."""
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    p = add(p, scale(dt, add(f, scale(M, g))))
    L = add(L, scale(dt, tau))
    x = add(x, div(scale(dt, p), M))
    w = omega_world(R, I_inv, L)
    q = quat_normalize(quat_multiply(quat_from_rotvec(scale(dt, w)), q))
    return x, q, p, L


@helper
def _stage(x, q, p, L, c, d):
    """(x, q, p, L) + c d for a derivative d = (dx, dq, dp, dL)."""
    return add(x, scale(c, d[0])), add4(q, scale4(c, d[1])), add(p, scale(c, d[2])), add(L, scale(c, d[3]))


@helper
def _rk4_sum(y, h6, a, b, c, e):
    """y + h/6 (a + 2 b + 2 c + e), 3-vectors."""
    return add(y, scale(h6, add(add(add(a, scale(2.0, b)), scale(2.0, c)), e)))


@helper
def _rk4_sum4(y, h6, a, b, c, e):
    """y + h/6 (a + 2 b + 2 c + e), quaternions."""
    return add4(y, scale4(h6, add4(add4(add4(a, scale4(2.0, b)), scale4(2.0, c)), e)))


@helper
def rk4_step(k, x, q, p, L, dt, M, I_inv, g, loads):
    """Classic RK4 on (x, q, p, L), q renormalised after the step; every stage sees the loads of
    step k, their torque arms at the stage's state."""
    k1 = rigid_body_derivative(k, x, q, p, L, M, I_inv, g, loads)
    x2, q2, p2, L2 = _stage(x, q, p, L, 0.5 * dt, k1)
    k2 = rigid_body_derivative(k, x2, q2, p2, L2, M, I_inv, g, loads)
    x3, q3, p3, L3 = _stage(x, q, p, L, 0.5 * dt, k2)
    k3 = rigid_body_derivative(k, x3, q3, p3, L3, M, I_inv, g, loads)
    x4, q4, p4, L4 = _stage(x, q, p, L, dt, k3)
    k4 = rigid_body_derivative(k, x4, q4, p4, L4, M, I_inv, g, loads)
    h6 = dt / 6.0
    return (_rk4_sum(x, h6, k1[0], k2[0], k3[0], k4[0]),
            quat_normalize(_rk4_sum4(q, h6, k1[1], k2[1], k3[1], k4[1])),
            _rk4_sum(p, h6, k1[2], k2[2], k3[2], k4[2]), _rk4_sum(L, h6, k1[3], k2[3], k3[3], k4[3]))


@helper
def semi_implicit_step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, loads, implicit_gyro):
    """The engines' map on (x, q, v, w_b), w_b in the body frame: explicit or linearised implicit
    gyroscopic term, then v, x, and q+ = q Exp(h w_b+)."""
    x, v, w_b = semi_implicit_velocities(k, x, matrix_from_quat(q), v, w_b, dt, M, I_b, I_inv, g, loads,
                                         implicit_gyro)
    q = quat_normalize(quat_multiply(q, quat_from_rotvec(scale(dt, w_b))))
    return x, q, v, w_b


@helper
def semi_implicit_velocities(k, x, R, v, w_b, dt, M, I_b, I_inv, g, loads, implicit_gyro):
    """integrators.semi_implicit_velocities: (x+, v+, w_b+) at the orientation R."""
    f, tau = wrench(k, x, R, loads)
    return semi_implicit_update(f, tau, x, R, v, w_b, dt, M, I_b, I_inv, g, implicit_gyro)


@helper
def semi_implicit_update(f, tau, x, R, v, w_b, dt, M, I_b, I_inv, g, implicit_gyro):
    """:func:`semi_implicit_velocities` of a step whose wrench (f, tau) (N, N m, world) is given."""
    tau_b = matvec(transpose(R), tau)
    rhs = sub(tau_b, cross(w_b, matvec(I_b, w_b)))
    if implicit_gyro:
        J = mat_add(I_b, mat_scale(dt, mat_sub(matmul(skew(w_b), I_b), skew(matvec(I_b, w_b)))))
        w_b = add(w_b, solve(J, scale(dt, rhs)))
    else:
        w_b = add(w_b, scale(dt, matvec(I_inv, rhs)))
    v = add(v, scale(dt, add(div(f, M), g)))
    x = add(x, scale(dt, v))
    return x, v, w_b


@helper
def _axis_turn(q, L, h, part, a, I_i, I_2):
    """A_i of splitting.free_rotation: q Exp(part h (1/I_i - 1/I_2) Pi_i a), Pi_i = a . R^T L."""
    Pi_i = dot(a, matvec(transpose(matrix_from_quat(q)), L))
    rate = (1.0 / I_i - 1.0 / I_2) * Pi_i
    return quat_multiply(q, quat_from_rotvec(scale(part * h * rate, a)))


@helper
def free_rotation(q, L, h, axes, moments):
    """splitting.free_rotation: S(h) A_1(h/2) A_3(h) A_1(h/2) (splitting.SPLITTING_SEQUENCE);
    axes: the principal axes (rows, body frame), moments: I_1 <= I_2 <= I_3."""
    I_2 = moments[1]
    q = quat_multiply(quat_from_rotvec(scale(h / I_2, L)), q)
    q = _axis_turn(q, L, h, 0.5, axes[0], moments[0], I_2)
    q = _axis_turn(q, L, h, 1.0, axes[2], moments[2], I_2)
    q = _axis_turn(q, L, h, 0.5, axes[0], moments[0], I_2)
    return quat_normalize(q)


@helper
def splitting_step(k, x, q, p, L, dt, M, axes, moments, g, loads):
    """splitting.splitting_step: kick (half of step k's impulse at the start state), drift (x, and
    q by free_rotation), kick (the other half at the end state)."""
    f, tau = wrench(k, x, matrix_from_quat(q), loads)
    p = add(p, scale(0.5 * dt, add(f, scale(M, g))))
    L = add(L, scale(0.5 * dt, tau))
    x = add(x, div(scale(dt, p), M))
    q = free_rotation(q, L, dt, axes, moments)
    f, tau = wrench(k, x, matrix_from_quat(q), loads)
    p = add(p, scale(0.5 * dt, add(f, scale(M, g))))
    L = add(L, scale(0.5 * dt, tau))
    return x, q, p, L


# --- implicit-midpoint and rkmk4 (lie_integrators) ------------------------------------------------

@helper
def midpoint_momentum(Pi, h, I_inv):
    """lie_integrators.midpoint_momentum: Pi+ = Pi + h Pi_mid x I_b^-1 Pi_mid by Newton from Pi+ = Pi
    (the same tolerance and bound); returns w_mid = I_b^-1 Pi_mid of the accepted Pi+."""
    Pi_new = Pi
    tol = MIDPOINT_RTOL * norm(Pi)
    for _ in range(MIDPOINT_MAX_ITERATIONS):
        Pi_mid = scale(0.5, add(Pi, Pi_new))
        w_mid = matvec(I_inv, Pi_mid)
        F = sub(sub(Pi_new, Pi), scale(h, cross(Pi_mid, w_mid)))
        J = mat_sub(((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
                    mat_scale(0.5 * h, mat_sub(matmul(skew(Pi_mid), I_inv), skew(w_mid))))
        delta = solve(J, F)
        Pi_new = sub(Pi_new, delta)
        if not norm(delta) > tol:
            break
    return matvec(I_inv, scale(0.5, add(Pi, Pi_new)))


@helper
def cayley_quat(u):
    """cay([u]) as a unit quaternion: (1, u/2) / |(1, u/2)|."""
    return quat_normalize((1.0, 0.5 * u[0], 0.5 * u[1], 0.5 * u[2]))


@helper
def implicit_midpoint_step(k, x, q, p, L, dt, M, I_inv, g, loads):
    """lie_integrators.implicit_midpoint_step: kick, drift (Pi = R^T L by the implicit midpoint rule,
    q+ = q cay(h w_mid)), kick."""
    f, tau = wrench(k, x, matrix_from_quat(q), loads)
    p = add(p, scale(0.5 * dt, add(f, scale(M, g))))
    L = add(L, scale(0.5 * dt, tau))
    x = add(x, div(scale(dt, p), M))
    Pi = matvec(transpose(matrix_from_quat(q)), L)
    w_mid = midpoint_momentum(Pi, dt, I_inv)
    q = quat_normalize(quat_multiply(q, cayley_quat(scale(dt, w_mid))))
    f, tau = wrench(k, x, matrix_from_quat(q), loads)
    p = add(p, scale(0.5 * dt, add(f, scale(M, g))))
    L = add(L, scale(0.5 * dt, tau))
    return x, q, p, L


@helper
def dexpinv_world(u, w):
    """lie_integrators.dexpinv_world: w - 1/2 u x w + 1/12 u x (u x w)."""
    uw = cross(u, w)
    return add(sub(w, scale(0.5, uw)), div(cross(u, uw), 12.0))


@helper
def _rkmk_slopes(k, x, q, p, L, M, I_inv, g, loads):
    """(dx, w (world), dp, dL) at the stage state (x, q, p, L) of step k."""
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R, loads)
    return div(p, M), omega_world(R, I_inv, L), add(f, scale(M, g)), tau


@helper
def _rkmk_stage(k, x, q, p, L, dt, c, d, K, M, I_inv, g, loads):
    """Stage at h c times the previous stage's slopes d (dx, w, dp, dL) and orientation slope K:
    its slopes, the orientation's passed through dexp^-1."""
    u = scale(dt * c, K)
    dx, w, dp, dL = _rkmk_slopes(k, add(x, scale(dt * c, d[0])), quat_multiply(quat_from_rotvec(u), q),
                                 add(p, scale(dt * c, d[2])), add(L, scale(dt * c, d[3])), M, I_inv, g, loads)
    return (dx, w, dp, dL), dexpinv_world(u, w)


@helper
def rkmk_sum(y, dt, a, b, c, e):
    """y + h (b_1 a + b_2 b + b_3 c + b_4 e) in RK4_B's order of operations."""
    b1, b2, b3, b4 = RK4_B
    return add(y, scale(dt, add(add(add(scale(b1, a), scale(b2, b)), scale(b3, c)), scale(b4, e))))


@helper
def rkmk4_step(k, x, q, p, L, dt, M, I_inv, g, loads):
    """lie_integrators.rkmk4_step: classic RK4 on (x, p, L), RKMK4 on q; loads at every stage."""
    d1 = _rkmk_slopes(k, x, q, p, L, M, I_inv, g, loads)
    K1 = d1[1]
    d2, K2 = _rkmk_stage(k, x, q, p, L, dt, RK4_C[0], d1, K1, M, I_inv, g, loads)
    d3, K3 = _rkmk_stage(k, x, q, p, L, dt, RK4_C[1], d2, K2, M, I_inv, g, loads)
    d4, K4 = _rkmk_stage(k, x, q, p, L, dt, RK4_C[2], d3, K3, M, I_inv, g, loads)
    u = scale(dt, add(add(add(scale(RK4_B[0], K1), scale(RK4_B[1], K2)), scale(RK4_B[2], K3)),
                      scale(RK4_B[3], K4)))
    return (rkmk_sum(x, dt, d1[0], d2[0], d3[0], d4[0]), quat_normalize(quat_multiply(quat_from_rotvec(u), q)),
            rkmk_sum(p, dt, d1[2], d2[2], d3[2], d4[2]), rkmk_sum(L, dt, d1[3], d2[3], d3[3], d4[3]))


@helper
def matrix_outputs(R, L, I_inv):
    """What a matrix integrator reports of its R and L: the quaternion of the nearest rotation,
    w = R I_b^-1 R^T L (world) and ||R^T R - 1||_F."""
    return quat_from_matrix(nearest_rotation(R)), omega_world(R, I_inv, L), orthonormality_error(R)


# --- whole runs: a loop over the steps, each state written into the output rows -----------------

@helper
def put_row(out, k, a):
    """out[k, :] = a, element by element (compiled code; also the compiled engine maps')."""
    for i in range(len(a)):
        out[k, i] = a[i]


@jit
def run_euler_matrix(x, R, p, L, dt, steps, M, I_inv, Mg, loads, gram, out_x, out_q, out_v, out_w,
                     out_ortho):
    """Rows 0..steps of x, q (nearest rotation), v = p / M, w (world), ||R^T R - 1||."""
    for k in range(steps + 1):
        if k > 0:
            x, R, p, L = euler_matrix_step(k - 1, x, R, p, L, dt, M, I_inv, Mg, loads, gram)
        q, w, ortho = matrix_outputs(R, L, I_inv)
        put_row(out_x, k, x)
        put_row(out_q, k, q)
        put_row(out_v, k, div(p, M))
        put_row(out_w, k, w)
        out_ortho[k] = ortho


EULER_QUAT, LIE_EULER, RK4, IMPLICIT_MIDPOINT, RKMK4 = 0, 1, 2, 3, 4
QUAT_SCHEMES = {"euler-quat": EULER_QUAT, "lie-euler": LIE_EULER, "rk4": RK4,
                "implicit-midpoint": IMPLICIT_MIDPOINT, "rkmk4": RKMK4}


@jit
def run_quat(scheme, x, q, p, L, dt, steps, M, I_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v = p / M, w = R I_b^-1 R^T L (world) of a scheme on (x, q, p, L)."""
    for k in range(steps):
        if scheme == EULER_QUAT:
            x, q, p, L = euler_quat_step(k, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == LIE_EULER:
            x, q, p, L = lie_euler_step(k, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == IMPLICIT_MIDPOINT:
            x, q, p, L = implicit_midpoint_step(k, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == RKMK4:
            x, q, p, L = rkmk4_step(k, x, q, p, L, dt, M, I_inv, g, loads)
        else:
            x, q, p, L = rk4_step(k, x, q, p, L, dt, M, I_inv, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, q)
        put_row(out_v, k + 1, div(p, M))
        put_row(out_w, k + 1, omega_world(matrix_from_quat(q), I_inv, L))


@jit
def run_splitting(x, q, p, L, dt, steps, M, axes, moments, I_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v = p / M, w = R I_b^-1 R^T L (world) of symplectic-splitting."""
    for k in range(steps):
        x, q, p, L = splitting_step(k, x, q, p, L, dt, M, axes, moments, g, loads)
        put_row(out_x, k + 1, x)
        put_row(out_q, k + 1, q)
        put_row(out_v, k + 1, div(p, M))
        put_row(out_w, k + 1, omega_world(matrix_from_quat(q), I_inv, L))


@jit
def run_semi_implicit(x, q, v, w_b, dt, steps, M, I_b, I_inv, g, loads, implicit_gyro,
                      out_x, out_q, out_v, out_w):
    """Rows 1..steps of x, q, v, w = R w_b (world) of the engines' map (semi_implicit_step, step
    by step): the loads' segment looked up once per segment, a torque-free segment's wrench the
    zeros wrench() sums to, R(q) formed once a step (the output's is the next step's)."""
    R = matrix_from_quat(q)
    zero = (0.0, 0.0, 0.0)
    for s in range(len(loads.k0)):
        free = loads.first[s] == loads.first[s + 1]
        for k in range(min(loads.k0[s], steps), segment_end(s, steps, loads)):
            f, tau = (zero, zero) if free else segment_wrench(s, x, R, loads)
            x, v, w_b = semi_implicit_update(f, tau, x, R, v, w_b, dt, M, I_b, I_inv, g, implicit_gyro)
            q = quat_normalize(quat_multiply(q, quat_from_rotvec(scale(dt, w_b))))
            R = matrix_from_quat(q)
            j = k + 1
            out_x[j, 0], out_x[j, 1], out_x[j, 2] = x
            out_q[j, 0], out_q[j, 1], out_q[j, 2], out_q[j, 3] = q
            out_v[j, 0], out_v[j, 1], out_v[j, 2] = v
            out_w[j, 0], out_w[j, 1], out_w[j, 2] = matvec(R, w_b)


# --- from a Problem ----------------------------------------------------------------------------

def vec(a) -> tuple:
    """A numpy vector as a tuple of floats (what the compiled functions take)."""
    return tuple(np.asarray(a, dtype=float).tolist())  # tolist: the same Python floats, 3x faster


def mat(A) -> tuple:
    """A 3x3 numpy matrix as a tuple of its rows."""
    return tuple(map(tuple, np.asarray(A, dtype=float).tolist()))


def simulate_compiled(problem: Problem, integrator: str, dt: float, steps: int) -> Trajectory:
    """``integrators.simulate(problem, integrator, dt, steps)`` by the compiled maps: the same
    Trajectory to rounding.  The initial state is formed in numpy exactly as the numpy loops form it.
    An old integrator name (``integrators.INTEGRATOR_ALIASES``) runs the map it now stands for."""
    from .integrators import canonical_integrator, initial_arrays, time_grid

    integrator = canonical_integrator(integrator)

    M, I_b, I_inv, x, q, R, p, L, v, w = initial_arrays(problem)
    loads = loads_of(problem, dt)
    g = problem.gravity
    M, dt, steps = float(M), float(dt), int(steps)  # one compiled signature whatever the caller passes
    matrix = integrator in ("euler-matrix", "euler-matrix-gs")
    out = Trajectory.empty(steps + 1, with_orthonormality=matrix)
    if matrix:
        run_euler_matrix(vec(x), mat(R), vec(p), vec(L), dt, steps, M, mat(I_inv), vec(M * g), loads,
                         integrator == "euler-matrix-gs", out.position, out.quaternion_wxyz,
                         out.linear_velocity, out.angular_velocity, out.orthonormality_error)
    elif integrator.startswith("semi-implicit-"):
        out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
        run_semi_implicit(vec(x), vec(q), vec(v), vec(R.T @ w), dt, steps, M, mat(I_b), mat(I_inv),
                          vec(g), loads, integrator == "semi-implicit-implicit-gyro", out.position,
                          out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    elif integrator == "symplectic-splitting":
        from .splitting import principal_frame

        frame = principal_frame(I_b)
        out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0] = x, q, p / M
        out.angular_velocity[0] = np.array(problem.initial.angular_velocity, float)
        run_splitting(vec(x), vec(q), vec(p), vec(L), dt, steps, M, mat(frame.axes), vec(frame.moments),
                      mat(I_inv), vec(g), loads, out.position, out.quaternion_wxyz, out.linear_velocity,
                      out.angular_velocity)
    else:
        scheme = QUAT_SCHEMES[integrator]
        out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0] = x, q, p / M
        out.angular_velocity[0] = np.array(problem.initial.angular_velocity, float)
        run_quat(scheme, vec(x), vec(q), vec(p), vec(L), dt, steps, M, mat(I_inv), vec(g), loads,
                 out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
    out.t[:] = time_grid(dt, steps)
    return out
