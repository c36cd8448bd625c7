"""The reference integrators of :mod:`integrators`, vectorised over a batch of B bodies.

Each integrator here computes, for every body of the batch, the same map as its single-body
counterpart in :mod:`integrators` (same names, same formulas, same outputs) and reproduces it to
round-off; :mod:`integrators` stays the readable reference, this module is the fast path for
many bodies at once (:mod:`compiled` is the fast path for one body).

Bodies may differ in everything: mass, inertia, initial state, and a constant external wrench
(a force at the COM and a couple, both world frame, acting on every step).  Gravity is shared.

Layout and speed.  The API takes and returns bodies along the first axis ((B, 3), (B, 4));
inside, the state is stored structure-of-arrays, one row per component ((3, B), (4, B)), so
that one step is a few dozen whole-array numpy calls, each over B numbers, with no Python loop
over bodies and no temporaries: every call writes into a preallocated buffer (``out=``).
Cross products use "wrapped" buffers whose rows are (x, y, z, x, y): ``a x b`` is then
``a[1:4] * b[2:5] - a[2:5] * b[1:4]``, two calls on (3, B) blocks instead of six on rows.
Rotations are quaternions (no 3x3 products) except in the matrix integrators.

Frames.  The quaternion integrators (``euler-quat``, ``lie-euler``, the two
``semi-implicit-*`` maps, ``rk4``) are run in each body's principal frame, where the inertia is
diagonal: every one of these maps commutes with a constant change of body frame
(q_p = q q_P, w_p = P^T w_b, I_p = P^T I_b P = diag), so this changes their results by round-off
only, and saves the 3x3 inertia products.  A batch whose inertias are all diagonal uses the body
frame itself (q_P = 1, no conversion).  The matrix integrators stay in the body frame
(Gram-Schmidt does not commute with a change of body frame).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from .conventions import Trajectory
from .integrators import canonical_integrator
from .problem import Problem
from .rotations import (matrix_from_quat, nearest_rotation, orthonormality_error, quat_conjugate,
                        quat_multiply)

__all__ = ["BATCHED_INTEGRATORS", "BatchTrajectory", "simulate_batch", "supports_problem",
           "simulate_problem", "quat_from_matrix_batch", "torque_free_rotation_batch",
           "closed_form_batch"]

BATCHED_INTEGRATORS = ("euler-matrix", "euler-matrix-gs", "euler-quat", "lie-euler",
                       "semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro", "rk4")

# Floor of the rotation angle |h w| in sin(|h w|/2) / |h w| (Exp): only an exactly zero angle
# reaches it, where the factor multiplies a zero vector anyway.
_TINY_ANGLE = 1e-300


@dataclass(frozen=True)
class BatchTrajectory:
    """Sampled motions of B bodies, canonical convention, float64.

    t : ndarray, shape (N,), s (the recorded instants k dt).
    position : ndarray, shape (N, B, 3), COM, world, m.
    quaternion_wxyz : ndarray, shape (N, B, 4), Hamilton (w, x, y, z), body -> world.
    linear_velocity : ndarray, shape (N, B, 3), COM, world, m/s.
    angular_velocity : ndarray, shape (N, B, 3), world, rad/s.
    orthonormality_error : ndarray, shape (N, B), or None: ||R^T R - 1||_F of the integrated
        matrix (matrix integrators only; their quaternion is that of the nearest rotation).
    """

    t: np.ndarray
    position: np.ndarray
    quaternion_wxyz: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    orthonormality_error: np.ndarray | None = None

    @property
    def bodies(self) -> int:
        return self.position.shape[1]

    def body(self, b: int) -> Trajectory:
        """Body b's motion as a single-body :class:`Trajectory` (copies)."""
        ortho = None if self.orthonormality_error is None else self.orthonormality_error[:, b].copy()
        return Trajectory(self.t.copy(), self.position[:, b].copy(), self.quaternion_wxyz[:, b].copy(),
                          self.linear_velocity[:, b].copy(), self.angular_velocity[:, b].copy(), ortho)


# --- inputs ---------------------------------------------------------------------------------------

def _rows(a, n: int, B: int, name: str) -> np.ndarray:
    """(B, n) or (n,) input -> (n, B) or (n, 1) float64, C-contiguous (structure of arrays)."""
    a = np.asarray(a, dtype=float)
    if a.shape == (n,):
        return np.ascontiguousarray(a.reshape(n, 1))
    if a.shape == (B, n):
        return np.ascontiguousarray(a.T)
    raise ValueError(f"{name}: expected shape ({n},) or ({B}, {n}), got {a.shape}")


def _batch_size(per_body: dict[str, tuple[object, int]]) -> int:
    """B from the inputs given per body: {name: (array, ndim of one body's value)}."""
    B = None
    for name, (a, ndim) in per_body.items():
        if a is None or np.ndim(a) == ndim:
            continue
        n = np.shape(a)[0]
        if np.ndim(a) != ndim + 1 or (B is not None and n != B):
            raise ValueError(f"{name}: shape {np.shape(a)} does not fit a batch of "
                             f"{B if B is not None else 'B'} bodies")
        B = n
    return 1 if B is None else B


def quat_from_matrix_batch(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of (..., 3, 3) rotation matrices (Shepperd's method).

    The vectorised twin of :func:`rotations.quat_from_matrix` (same branch choice, same formulas);
    a non-finite matrix gives NaN.  Returns shape (..., 4).
    """
    R = np.asarray(R, dtype=float)
    m00, m01, m02 = R[..., 0, 0], R[..., 0, 1], R[..., 0, 2]
    m10, m11, m12 = R[..., 1, 0], R[..., 1, 1], R[..., 1, 2]
    m20, m21, m22 = R[..., 2, 0], R[..., 2, 1], R[..., 2, 2]
    tr = m00 + m11 + m22
    with np.errstate(invalid="ignore", divide="ignore"):
        cands = np.stack([tr, m00, m11, m22], axis=-1)
        finite = np.all(np.isfinite(R), axis=(-2, -1))
        k = np.argmax(np.where(np.isfinite(cands), cands, -np.inf), axis=-1)
        s0 = 2.0 * np.sqrt(1.0 + tr)
        s1 = 2.0 * np.sqrt(1.0 + m00 - m11 - m22)
        s2 = 2.0 * np.sqrt(1.0 + m11 - m00 - m22)
        s3 = 2.0 * np.sqrt(1.0 + m22 - m00 - m11)
        q = np.stack([
            np.stack([0.25 * s0, (m21 - m12) / s0, (m02 - m20) / s0, (m10 - m01) / s0], axis=-1),
            np.stack([(m21 - m12) / s1, 0.25 * s1, (m01 + m10) / s1, (m02 + m20) / s1], axis=-1),
            np.stack([(m02 - m20) / s2, (m01 + m10) / s2, 0.25 * s2, (m12 + m21) / s2], axis=-1),
            np.stack([(m10 - m01) / s3, (m02 + m20) / s3, (m12 + m21) / s3, 0.25 * s3], axis=-1),
        ], axis=-2)
        q = np.take_along_axis(q, k[..., None, None], axis=-2)[..., 0, :]
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    q[~finite] = np.nan
    return q


def _principal(I_body: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(principal moments (B, 3) kg m^2, q_P (B, 4) or None): I_b = P diag(I_p) P^T, q_P = quat(P).

    None when every inertia is already diagonal (the body frame is then used as it is).
    """
    off = I_body[:, [0, 0, 1], [1, 2, 2]]
    if not np.any(off):
        return np.ascontiguousarray(np.diagonal(I_body, axis1=1, axis2=2)), None
    moments, P = np.linalg.eigh(0.5 * (I_body + np.swapaxes(I_body, 1, 2)))
    P[np.linalg.det(P) < 0, :, 2] *= -1.0
    return moments, quat_from_matrix_batch(P)


def _rotate(q: np.ndarray, v: np.ndarray, inverse: bool = False) -> np.ndarray:
    """R(q) v (or R(q)^T v) for unit quaternions q (..., 4) wxyz and vectors v (..., 3)."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v - w * t + np.cross(u, t) if inverse else v + w * t + np.cross(u, t)


def _normalized(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


# --- the structure-of-arrays kernels --------------------------------------------------------------

class _Work:
    """Preallocated buffers of one batch run (all float64, B columns)."""

    def __init__(self, B: int):
        self.B = B
        e = np.empty
        self.t3a, self.t3b, self.t3c = e((3, B)), e((3, B)), e((3, B))
        self.t4, self.t2 = e((4, B)), e((2, B))
        self.t5a, self.t5b = e((5, B)), e((5, B))
        # a quaternion proportional to Exp(phi), rows (s, x, y, z, x, y): see _exp_into
        self.e6 = e((6, B))
        self.tq = e((3, B))
        self.s1, self.s2, self.s3 = e(B), e(B), e(B)


def _wrap(a5: np.ndarray) -> None:
    """Refresh the wrapped rows 3, 4 (= rows 0, 1) of a (5, B) buffer."""
    a5[3:5] = a5[0:2]


def _full(a: np.ndarray, B: int) -> np.ndarray:
    """A (k, 1) or (k, B) coefficient array as a C-contiguous (k, B) one: numpy's ufuncs are
    several times slower on a broadcast (k, 1) operand than on a full one."""
    return np.ascontiguousarray(np.broadcast_to(a, (a.shape[0], B)))


def _sum3(t: np.ndarray, out: np.ndarray, axis: int = 0) -> None:
    """out = the sum of the 3 entries of t along ``axis`` (two calls; faster than np.sum)."""
    if axis == 0:
        np.add(t[0], t[1], out=out)
        out += t[2]
    else:
        np.add(t[:, 0], t[:, 1], out=out)
        out += t[:, 2]


def _normalize_q6(Q6: np.ndarray, wk: _Work) -> None:
    """Q6 (6, B) = (w, x, y, z, x, y) rows: normalise rows 0..3 in place and refresh the wrap."""
    q = Q6[0:4]
    np.multiply(q, q, out=wk.t4)
    np.add(wk.t4[0:2], wk.t4[2:4], out=wk.t2)
    n = wk.s3
    np.add(wk.t2[0], wk.t2[1], out=n)
    np.sqrt(n, out=n)
    np.divide(q, n, out=q)
    Q6[4:6] = Q6[1:3]


# Exp(phi) = (cos(|phi|/2), sin(|phi|/2) phi/|phi|) is only ever used inside a product that is
# normalised right after, so it is computed up to a positive factor as E = (s, phi) with
# s = |phi| cot(|phi|/2) = 2 (x cot x), x = |phi|/2: the product q E normalised is the same rotation
# as q Exp(phi) normalised (|E| = 2x / sin x >= 2, so the factor is harmless).  s is the series
# sum_n c_n z^n in z = |phi|^2, c_n = 2 (-1)^n B_2n / (2n)! (B_2n Bernoulli numbers), evaluated by
# Horner to the lowest degree n whose tail, below |c_(n+1)| z^(n+1) / (1 - z / (4 pi^2)) (the
# coefficients fall by at least 4 pi^2 per degree), is under 2^-54 for the largest z of the batch:
# s is then exact to round-off, from one row of arithmetic instead of sin, cos (each costs more than
# ten arithmetic ufuncs), a division and a rescaling of phi.  Beyond degree _EXP_MAX_DEGREE
# (|phi| > 0.7 rad per step): E = Exp(phi) from sin and cos.
_BERNOULLI_2N = (Fraction(1), Fraction(1, 6), Fraction(-1, 30), Fraction(1, 42), Fraction(-1, 30),
                 Fraction(5, 66), Fraction(-691, 2730), Fraction(7, 6), Fraction(-3617, 510),
                 Fraction(43867, 798))
_EXP_MAX_DEGREE = 8
_EXP_COEFFS = [float(2 * (-1) ** n * _BERNOULLI_2N[n] / math.factorial(2 * n))
               for n in range(_EXP_MAX_DEGREE + 2)]
_EXP_GEOMETRIC_Z = 0.05 * 4.0 * math.pi ** 2     # the tail's geometric factor stays below 1/0.95
_EXP_Z_LIMITS = [min(_EXP_GEOMETRIC_Z, (2.0 ** -54 * 0.95 / abs(_EXP_COEFFS[n + 1])) ** (1.0 / (n + 1)))
                 for n in range(_EXP_MAX_DEGREE + 1)]


def _exp_scalar_part(z: np.ndarray, phi5: np.ndarray, s: np.ndarray) -> None:
    """E = (s, phi) proportional to Exp(phi): s (B,) written, phi5 (5, B) rescaled only beyond
    the series' range.  z (B,) = |phi|^2 (overwritten on the sin/cos path)."""
    z_max = z.max()
    degree = next((n for n, lim in enumerate(_EXP_Z_LIMITS) if z_max <= lim), None)
    if degree is not None:
        c = _EXP_COEFFS
        if degree == 0:
            s.fill(c[0])
            return
        np.multiply(z, c[degree], out=s)
        for n in range(degree - 1, 0, -1):
            s += c[n]
            s *= z
        s += c[0]
        return
    # large angles (or NaN: the result is NaN either way): E = Exp(phi) itself
    ang = z
    np.sqrt(z, out=ang)
    half = np.multiply(ang, 0.5)
    np.cos(half, out=s)
    np.sin(half, out=half)
    np.maximum(ang, _TINY_ANGLE, out=ang)
    half /= ang
    phi5 *= half


def _exp_into(wk: _Work) -> np.ndarray:
    """E proportional to Exp(phi) for the rotation vectors phi in wk.e6 rows 1..5 (wrapped):
    wk.e6 becomes (s, phi) (see _exp_scalar_part), wrapped (6, B)."""
    e6 = wk.e6
    np.multiply(e6[1:4], e6[1:4], out=wk.t3a)
    _sum3(wk.t3a, wk.s1)
    _exp_scalar_part(wk.s1, e6[1:6], e6[0])
    return e6


def _qmul(A6: np.ndarray, B6: np.ndarray, out6: np.ndarray, wk: _Work, e_left: bool) -> None:
    """Hamilton product of wrapped (6, B) quaternions into out6 rows 0..3 (not normalised).

    With q = A6 and e = B6:  q * e (e_left False) or e * q (e_left True):
    r_w = q_w e_w - q_v . e_v,  r_v = q_w e_v + e_w q_v +- q_v x e_v.
    """
    np.multiply(B6[0:4], A6[0], out=out6[0:4])              # (q_w e_w, q_w e_v)
    rv = out6[1:4]
    np.multiply(A6[1:4], B6[0], out=wk.t3a)
    rv += wk.t3a                                             # + e_w q_v
    if e_left:
        np.multiply(B6[2:5], A6[3:6], out=wk.t3a)
        np.multiply(B6[3:6], A6[2:5], out=wk.t3b)
    else:
        np.multiply(A6[2:5], B6[3:6], out=wk.t3a)
        np.multiply(A6[3:6], B6[2:5], out=wk.t3b)
    wk.t3a -= wk.t3b
    rv += wk.t3a                                             # +- q_v x e_v
    np.multiply(A6[1:4], B6[1:4], out=wk.t3a)
    _sum3(wk.t3a, wk.s2)
    out6[0] -= wk.s2                                         # - q_v . e_v


def _rotate_soa(Q6: np.ndarray, v5: np.ndarray, out: np.ndarray, wk: _Work, inverse: bool) -> None:
    """out (3, B) = R(q) v, or R(q)^T v, for a unit q = Q6 (6, B) and v5 (5, B), both wrapped.

    t = 2 q_v x v;  R v = v + q_w t + q_v x t;  R^T v = v - q_w t + q_v x t.
    """
    t5 = wk.t5b
    t = t5[0:3]
    np.multiply(Q6[2:5], v5[2:5], out=t)
    np.multiply(Q6[3:6], v5[1:4], out=wk.t3b)
    t -= wk.t3b
    t *= 2.0
    _wrap(t5)
    np.multiply(t, Q6[0], out=out)
    if inverse:
        np.subtract(v5[0:3], out, out=out)
    else:
        out += v5[0:3]
    np.multiply(Q6[2:5], t5[2:5], out=wk.t3b)
    np.multiply(Q6[3:6], t5[1:4], out=wk.t3c)
    wk.t3b -= wk.t3c
    out += wk.t3b


def _omega_world(Q6: np.ndarray, L5: np.ndarray, inv_I: np.ndarray, out5: np.ndarray, wk: _Work) -> None:
    """out5 (5, B) wrapped = R I_p^-1 R^T L for a unit principal-frame q = Q6 and L5 (5, B)."""
    lb5 = wk.t5a
    _rotate_soa(Q6, L5, lb5[0:3], wk, inverse=True)
    lb5[0:3] *= inv_I
    _wrap(lb5)
    _rotate_soa(Q6, lb5, out5[0:3], wk, inverse=False)
    _wrap(out5)


class _Recorder:
    """Which samples to keep and the (n, rows, B) arrays they go to."""

    def __init__(self, steps: int, every: int, shapes: dict[str, int], B: int):
        self.keep = np.unique(np.r_[np.arange(0, steps + 1, every), steps])
        self.slot = {int(k): i for i, k in enumerate(self.keep)}
        self.arrays = {name: np.empty((len(self.keep), n, B)) for name, n in shapes.items()}

    def __call__(self, k: int, **rows: np.ndarray) -> None:
        i = self.slot.get(k)
        if i is not None:
            for name, a in rows.items():
                self.arrays[name][i] = a


def _soa_to_aos(a: np.ndarray) -> np.ndarray:
    """(n, rows, B) -> (n, B, rows), C-contiguous."""
    return np.ascontiguousarray(np.swapaxes(a, 1, 2))


# --- the integrators ------------------------------------------------------------------------------

class _ImplicitGyro:
    """dw of the implicitly linearised gyroscopic step in principal-frame variables, in closed form.

    J dw = rho with J = I + h ([w] I - [I w]), rho = h (tau_p - w x I w).  With I = diag(I1, I2, I3)
    and (a, b, c) = h (I3 - I2, I1 - I3, I2 - I1):
    J = [[I1, a wz, a wy], [b wz, I2, b wx], [c wy, c wx, I3]], rho = -(a, b, c) * P + h tau_p,
    P = (wy wz, wz wx, wx wy).  Cramer's rule: with G = I w - (a, b, c) * P,
    adj J = [[I2 I3 - bc wx^2, -a G3, -a G2], [-b G3, I1 I3 - ac wy^2, -b G1],
             [-c G2, -c G1, I1 I2 - ab wz^2]],
    det J = I1 I2 I3 - bc I1 wx^2 - ac I2 wy^2 - ab I3 wz^2 + 2 abc wx wy wz,
    so dw_i = ((adj J)_ii rho_i - abc_i (G_(i+2) rho_(i+1) + G_(i+1) rho_(i+2))) / det J.
    Coefficients are stored per body, wrapped (rows x, y, z, x, y) where they meet wrapped buffers.

    I : (3, B) principal moments, kg m^2.  W7 : (7, B) the angular velocity buffer, rows
    (x, y, z, x, y, z, x), rad/s, read by every call.
    """

    def __init__(self, I: np.ndarray, h: float, W7: np.ndarray):
        B = W7.shape[1]
        w5 = lambda rows: np.concatenate([rows, rows[0:2]])  # noqa: E731
        abc = h * np.stack([I[2] - I[1], I[0] - I[2], I[1] - I[0]])
        Kc = np.stack([abc[1] * abc[2], abc[0] * abc[2], abc[0] * abc[1]])
        self.nabc5, self.I5, self.abc = w5(-abc), w5(I), abc
        self.K = np.stack([I[1] * I[2], I[0] * I[2], I[0] * I[1]])
        self.Kc = Kc
        self.C4 = np.concatenate([Kc * I, -2.0 * abc[0:1] * abc[1:2] * abc[2:3]])  # (4, B)
        self.I123 = I[0] * I[1] * I[2]
        e = np.empty
        self.P5, self.rho5, self.G5, self.U = e((5, B)), e((5, B)), e((5, B)), e((4, B))
        self.D, self.t3a, self.t3b, self.t4, self.t2, self.det = (
            e((3, B)), e((3, B)), e((3, B)), e((4, B)), e((2, B)), e(B))
        self.W7 = W7
        # every view a call uses, sliced once
        P5, rho5, G5, U, t4, t2 = self.P5, self.rho5, self.G5, self.U, self.t4, self.t2
        self._views = (W7[1:6], W7[2:7], W7[0:5], W7[0:3], W7[0], P5[0], rho5[0:3], rho5[3:5],
                       rho5[1:4], rho5[2:5], U[0:3], U[3], G5[1:4], G5[2:5], t4[0:2], t4[2:4],
                       t2[0], t2[1])

    def __call__(self, h_tau_p: np.ndarray | None) -> np.ndarray:
        """dw (3, B), rad/s, for the current w and h tau_p (3, B) N m s (or None)."""
        mul, add, sub = np.multiply, np.add, np.subtract
        (W16, W27, W05, W03, Wx, Px, rho03, rho35, rho14, rho25, U03, U3, G14, G25,
         t4a, t4b, t2a, t2b) = self._views
        P5, rho5, G5, U, D, t3a, t3b, det = (self.P5, self.rho5, self.G5, self.U, self.D,
                                             self.t3a, self.t3b, self.det)
        mul(W16, W27, out=P5)                                # P, wrapped
        mul(self.nabc5, P5, out=rho5)                        # -(a, b, c) P
        mul(self.I5, W05, out=G5)
        add(G5, rho5, out=G5)                                # G = I w - (a, b, c) P
        if h_tau_p is not None:
            add(rho03, h_tau_p, out=rho03)
            rho35[...] = rho03[0:2]
        mul(W03, W03, out=U03)                               # w_i^2
        mul(Px, Wx, out=U3)                                  # wx wy wz
        mul(self.C4, U, out=self.t4)                         # det J = I1 I2 I3 - sum C4_i U_i
        add(t4a, t4b, out=self.t2)
        add(t2a, t2b, out=det)
        sub(self.I123, det, out=det)
        mul(self.Kc, U03, out=D)                             # adj J rho
        sub(self.K, D, out=D)
        mul(D, rho03, out=D)
        mul(G25, rho14, out=t3a)
        mul(G14, rho25, out=t3b)
        add(t3a, t3b, out=t3a)
        mul(t3a, self.abc, out=t3a)
        sub(D, t3a, out=D)
        np.divide(1.0, det, out=det)
        for i in range(3):
            mul(D[i], det, out=D[i])
        return D


class _ExpRotation:
    """q+ = normalize(q E), E = (s, phi) proportional to Exp(phi), phi = h w (see
    _exp_scalar_part): the rotation update of _run_semi_implicit for the whole batch, written out
    flat (every call writes into a buffer made here once).

    Quaternions live in wrapped (6, B) buffers, rows (w, x, y, z, x, y), seen through the tuple of
    views that :meth:`views` makes once per buffer.
    """

    def __init__(self, B: int):
        self.t3, self.t3b = np.empty((3, B)), np.empty((3, B))
        self.t4, self.t2 = np.empty((4, B)), np.empty((2, B))
        self.z, self.dot, self.norm = np.empty(B), np.empty(B), np.empty(B)
        # E = (s, phi) proportional to Exp(phi), phi = h w_p, rows (s, x, y, z, x, y)
        E6 = np.empty((6, B))
        self.E = (E6[0], E6[0:4], E6[1:4], E6[1:6], E6[2:5], E6[3:6])

    @staticmethod
    def views(Q6: np.ndarray) -> tuple:
        """(Q6, w, (w, x, y, z), (x, y, z), rows 2:5, rows 3:6, rows 4:6, rows 1:3) of a wrapped
        (6, B) quaternion buffer."""
        return (Q6, Q6[0], Q6[0:4], Q6[1:4], Q6[2:5], Q6[3:6], Q6[4:6], Q6[1:3])

    def __call__(self, W05: np.ndarray, h: float, qa: tuple, qb: tuple) -> None:
        """qb = normalize(qa Exp(h w)), w wrapped in W05 (5, B) rows (x, y, z, x, y); qa, qb
        are :meth:`views` of two buffers."""
        mul, add, sub = np.multiply, np.add, np.subtract
        t3, t3b, t4, t2, z, dot, norm = self.t3, self.t3b, self.t4, self.t2, self.z, self.dot, self.norm
        s, E04, phi, phi5, E25, E36 = self.E
        mul(W05, h, out=phi5)
        mul(phi, phi, out=t3)
        add(t3[0], t3[1], out=z)
        add(z, t3[2], out=z)
        _exp_scalar_part(z, phi5, s)
        _, qw, _, qv, q25, q36, _, _ = qa
        _, rw, r04, rv, _, _, r46, r13 = qb
        # (row by row: numpy's ufuncs are several times slower on a broadcast (B,) operand)
        for i in range(4):
            mul(E04[i], qw, out=r04[i])                      # (q_w s, q_w phi)
        for i in range(3):
            mul(qv[i], s, out=t3[i])
        add(rv, t3, out=rv)                                  # + s q_v
        mul(q25, E36, out=t3)
        mul(q36, E25, out=t3b)
        sub(t3, t3b, out=t3)
        add(rv, t3, out=rv)                                  # + q_v x phi
        mul(qv, phi, out=t3)
        add(t3[0], t3[1], out=dot)
        add(dot, t3[2], out=dot)
        sub(rw, dot, out=rw)                                 # - q_v . phi
        mul(r04, r04, out=t4)
        add(t4[0:2], t4[2:4], out=t2)
        add(t2[0], t2[1], out=norm)
        np.sqrt(norm, out=norm)
        np.divide(1.0, norm, out=norm)
        for i in range(4):
            mul(r04[i], norm, out=r04[i])
        r46[...] = r13


def _run_semi_implicit(p: dict, h: float, steps: int, rec: _Recorder, implicit: bool) -> None:
    """The engines' map in principal-frame variables (x, q_p, v, w_p); see integrators.py.

    w_p+ = w_p + h I^-1 (tau_p - w_p x I w_p) (explicit) or J^-1 h (...) (implicit, _ImplicitGyro),
    v+ = v + h (f/M + g), x+ = x + h v+, q_p+ = normalize(q_p Exp(h w_p+)) (_ExpRotation).

    The hottest loop of the module, so written out flat: every view it uses is sliced once before
    the loop (slicing costs as much as a small ufunc call) and every call writes into a buffer.
    """
    B = p["B"]
    wk = _Work(B)
    mul, add = np.multiply, np.add
    X, V = p["x"].copy(), p["v"].copy()
    W7 = np.empty((7, B))                                    # w_p rows (x, y, z, x, y, z, x)
    W7[0:3] = p["w_p"]
    W7[3:6] = W7[0:3]
    W7[6] = W7[0]
    W, W05, W12, W14, W24, W25 = W7[0:3], W7[0:5], W7[0:2], W7[1:4], W7[2:4], W7[2:5]
    W35, W57 = W7[3:5], W7[5:7]
    I = _full(p["I_p"], B)                                   # (3, B) kg m^2, principal moments
    dv = _full(h * (p["f"] / p["M"] + p["g"]), B)            # (3, B) m/s per step
    tau = p["tau"]                                           # (5, B|1) N m world, wrapped, or None
    # explicit: h I^-1 (-w x I w) = h ((I2 - I3)/I1 wy wz, (I3 - I1)/I2 wz wx, (I1 - I2)/I3 wx wy)
    gyro = h * np.stack([(I[1] - I[2]) / I[0], (I[2] - I[0]) / I[1], (I[0] - I[1]) / I[2]])
    implicit_dw = _ImplicitGyro(I, h, W7) if implicit else None
    rotate = _ExpRotation(B)
    dw, t3 = np.empty((3, B)), np.empty((3, B))
    qa, qb = rotate.views(np.empty((6, B))), rotate.views(np.empty((6, B)))
    qa[2][:] = p["q_p"]
    qa[6][:] = qa[7]
    rec(0, x=X, q=qa[2], v=V, w=W)
    for k in range(steps):
        # angular velocity: the gyroscopic term (explicit or linearised implicitly), the couple
        h_tau_p = None
        if tau is not None:
            h_tau_p = wk.tq
            _rotate_soa(qa[0], tau, h_tau_p, wk, inverse=True)
            h_tau_p *= h
        if implicit:
            add(W, implicit_dw(h_tau_p), out=W)
        else:
            mul(W14, W25, out=dw)                            # (wy wz, wz wx, wx wy)
            mul(dw, gyro, out=dw)
            if h_tau_p is not None:
                h_tau_p /= I
                dw += h_tau_p
            add(W, dw, out=W)
        W35[...] = W12
        if implicit:
            W57[...] = W24
        # linear motion: v+ = v + h (f/M + g), x+ = x + h v+
        add(V, dv, out=V)
        mul(V, h, out=t3)
        add(X, t3, out=X)
        rotate(W05, h, qa, qb)                               # q+ = normalize(q Exp(h w+))
        qa, qb = qb, qa
        rec(k + 1, x=X, q=qa[2], v=V, w=W)


def _run_quat_momentum(p: dict, h: float, steps: int, rec: _Recorder, scheme: str) -> None:
    """euler-quat, lie-euler and rk4 on (x, q_p, p, L), see integrators._simulate_quat."""
    B = p["B"]
    wk = _Work(B)
    M = p["M"]
    X, Pm = p["x"].copy(), p["p"].copy()
    L5 = np.empty((5, B))
    L5[0:3] = p["L"]
    _wrap(L5)
    L = L5[0:3]
    Q6, R6 = np.empty((6, B)), np.empty((6, B))
    Q6[0:4] = p["q_p"]
    Q6[4:6] = Q6[1:3]
    inv_I = 1.0 / p["I_p"]
    dp = p["f"] + M * p["g"]                                 # (3, B|1) N: f + M g, constant
    dL = p["tau"][0:3] if p["tau"] is not None else None     # (3, B|1) N m: tau, constant
    rec(0, x=X, q=Q6[0:4], p=Pm, L=L)
    if scheme == "rk4":
        _run_rk4(X, Q6, Pm, L5, M, inv_I, dp, dL, h, steps, rec, wk)
        return
    W5, phi5, e6 = np.empty((5, B)), wk.e6[1:6], wk.e6
    for k in range(steps):
        if scheme == "euler-quat":
            # dq = 1/2 (0, w) q with w from the current (q, L); explicit Euler on (x, q, p, L)
            _omega_world(Q6, L5, inv_I, W5, wk)
            e6[0] = 0.0
            np.multiply(W5, 0.5 * h, out=phi5)
            _qmul(Q6, e6, R6, wk, e_left=True)               # h/2 (0, w) q
            R6[0:4] += Q6[0:4]
            Q6, R6 = R6, Q6
            _normalize_q6(Q6, wk)
            np.divide(Pm, M, out=wk.t3a)
            wk.t3a *= h
            X += wk.t3a
            np.multiply(dp, h, out=wk.t3a)
            Pm += wk.t3a
            if dL is not None:
                np.multiply(dL, h, out=wk.t3a)
                L += wk.t3a
                _wrap(L5)
        else:  # lie-euler: momenta, then x with the new p, q with w(current q, new L)
            np.multiply(dp, h, out=wk.t3a)
            Pm += wk.t3a
            if dL is not None:
                np.multiply(dL, h, out=wk.t3a)
                L += wk.t3a
                _wrap(L5)
            np.divide(Pm, M, out=wk.t3a)
            wk.t3a *= h
            X += wk.t3a
            _omega_world(Q6, L5, inv_I, W5, wk)
            np.multiply(W5, h, out=phi5)
            _qmul(Q6, _exp_into(wk), R6, wk, e_left=True)    # Exp(h w) q
            Q6, R6 = R6, Q6
            _normalize_q6(Q6, wk)
        rec(k + 1, x=X, q=Q6[0:4], p=Pm, L=L)


def _run_rk4(X, Q6, Pm, L5, M, inv_I, dp, dL, h, steps, rec, wk) -> None:
    """Classic RK4 on (x, q, p, L), q renormalised after each step; as the single-body code, a
    stage's w comes from its normalised quaternion and its dq = 1/2 (0, w) q from the stage q.

    p and L have constant derivatives (f + M g, tau): their stages are not needed."""
    B = wk.B
    L = L5[0:3]
    W5, phi5, e6 = np.empty((5, B)), wk.e6[1:6], wk.e6
    Qs6, Qn6 = np.empty((6, B)), np.empty((6, B))            # stage q, its normalised copy
    Ls5 = np.empty((5, B))
    Ps = np.empty((3, B))
    kx = [np.empty((3, B)) for _ in range(4)]
    kq = [np.empty((6, B)) for _ in range(4)]
    acc, tmp = np.empty((4, B)), np.empty((4, B))

    def deriv(i: int, q6: np.ndarray, pm: np.ndarray, l5: np.ndarray) -> None:
        np.divide(pm, M, out=kx[i])
        Qn6[:] = q6
        _normalize_q6(Qn6, wk)
        _omega_world(Qn6, l5, inv_I, W5, wk)
        e6[0] = 0.0
        np.multiply(W5, 0.5, out=phi5)
        _qmul(q6, e6, kq[i], wk, e_left=True)                # 1/2 (0, w) q

    for k in range(steps):
        deriv(0, Q6, Pm, L5)
        for i, c in ((1, 0.5), (2, 0.5), (3, 1.0)):
            ch = c * h
            np.multiply(kq[i - 1][0:4], ch, out=Qs6[0:4])
            Qs6[0:4] += Q6[0:4]
            Qs6[4:6] = Qs6[1:3]
            np.multiply(dp, ch, out=Ps)
            Ps += Pm
            if dL is not None:
                np.multiply(dL, ch, out=Ls5[0:3])
                Ls5[0:3] += L
                _wrap(Ls5)
            deriv(i, Qs6, Ps, Ls5 if dL is not None else L5)
        # y+ = y + h/6 (k1 + 2 k2 + 2 k3 + k4), summed in the single-body code's order
        for y, ks in ((X, kx), (Q6[0:4], [a[0:4] for a in kq])):
            n = y.shape[0]
            a, t = acc[0:n], tmp[0:n]
            np.multiply(ks[1], 2.0, out=a)
            a += ks[0]
            np.multiply(ks[2], 2.0, out=t)
            a += t
            a += ks[3]
            a *= h / 6.0
            y += a
        Pm += (h / 6.0) * (dp + 2 * dp + 2 * dp + dp)
        if dL is not None:
            L += (h / 6.0) * (dL + 2 * dL + 2 * dL + dL)
            _wrap(L5)
        _normalize_q6(Q6, wk)
        rec(k + 1, x=X, q=Q6[0:4], p=Pm, L=L)


def _run_euler_matrix(p: dict, h: float, steps: int, rec: _Recorder, gram: bool) -> None:
    """Explicit Euler on (x, R, p, L) in the body frame, see integrators.integrate_euler_matrix."""
    B = p["B"]
    M, inv_Ib = p["M"], p["I_inv_b"]                         # (1, B|1), (3, 3, B|1)
    X, Pm, L = p["x"].copy(), p["p"].copy(), p["L"].copy()
    R5 = np.empty((5, 3, B))                                 # rows of R, wrapped: R5[i, j] = R_ij
    R5[0:3] = p["R"]
    R5[3:5] = R5[0:2]
    R = R5[0:3]
    W5 = np.empty((5, B))
    t33a, t33b = np.empty((3, 3, B)), np.empty((3, 3, B))
    a, b = np.empty((3, B)), np.empty((3, B))
    dp = p["f"] + M * p["g"]
    tau = p["tau"]
    rec(0, x=X, R=R.reshape(9, B), p=Pm, L=L)
    for k in range(steps):
        # w = R I_b^-1 R^T L with R as integrated
        np.multiply(R, L[:, None, :], out=t33a)
        _sum3(t33a, a, axis=0)                               # R^T L
        np.multiply(inv_Ib, a[None, :, :], out=t33a)
        _sum3(t33a, b, axis=1)                               # I^-1 R^T L
        np.multiply(R, b[None, :, :], out=t33a)
        _sum3(t33a, W5[0:3], axis=1)
        _wrap(W5)
        np.divide(Pm, M, out=a)
        a *= h
        X += a
        # R += h [w] R: column j of [w] R is w x R[:, j]
        np.multiply(W5[1:4, None, :], R5[2:5], out=t33a)
        np.multiply(W5[2:5, None, :], R5[1:4], out=t33b)
        t33a -= t33b
        t33a *= h
        R += t33a
        np.multiply(dp, h, out=a)
        Pm += a
        if tau is not None:
            L += h * tau[0:3]
        if gram:
            _gram_schmidt_soa(R)
        R5[3:5] = R5[0:2]
        rec(k + 1, x=X, R=R.reshape(9, B), p=Pm, L=L)


def _gram_schmidt_soa(R: np.ndarray) -> None:
    """Classical Gram-Schmidt on the columns of R (3, 3, B) in place, in column order."""
    c0, c1, c2 = R[:, 0], R[:, 1], R[:, 2]
    c0 /= np.sqrt(np.sum(c0 * c0, axis=0))
    c1 -= np.sum(c0 * c1, axis=0) * c0
    c1 /= np.sqrt(np.sum(c1 * c1, axis=0))
    d0, d1 = np.sum(c0 * c2, axis=0), np.sum(c1 * c2, axis=0)
    c2 -= d0 * c0 + d1 * c1
    c2 /= np.sqrt(np.sum(c2 * c2, axis=0))


# --- the public entry points ----------------------------------------------------------------------

def simulate_batch(integrator: str, mass, I_body, position, quaternion_wxyz, linear_velocity,
                   angular_velocity, dt: float, steps: int, gravity=(0.0, 0.0, 0.0),
                   force=None, torque=None, every: int = 1) -> BatchTrajectory:
    """Integrate B free bodies at once with the named reference integrator.

    integrator : a name of :data:`BATCHED_INTEGRATORS` (every integrator of
        ``integrators.INTEGRATORS`` but symplectic-splitting, implicit-midpoint and rkmk4, which are not
        batched), or an old name of one (``integrators.INTEGRATOR_ALIASES``).
    mass : float or ndarray, shape (B,), kg.
    I_body : ndarray, shape (3, 3) or (B, 3, 3), kg m^2, about the COM, body frame.
    position : ndarray, shape (B, 3) or (3,), COM, world, m.
    quaternion_wxyz : ndarray, shape (B, 4) or (4,), body -> world (normalised here).
    linear_velocity : ndarray, shape (B, 3) or (3,), COM, world, m/s.
    angular_velocity : ndarray, shape (B, 3) or (3,), world, rad/s.
    dt : s.  steps : number of steps.
    gravity : ndarray, shape (3,), world, m/s^2 (shared by the batch).
    force : ndarray, shape (B, 3) or (3,), N, world, at the COM, on every step; or None.
    torque : ndarray, shape (B, 3) or (3,), N m, world, a couple on every step; or None.
    every : keep every ``every``-th sample (and always the last one); 1 keeps all.

    Returns a :class:`BatchTrajectory` with N = number of kept samples.  A blow-up is not an
    error: its samples become inf/NaN, as in :func:`integrators.simulate`.
    """
    integrator = canonical_integrator(integrator)
    if integrator not in BATCHED_INTEGRATORS:
        raise ValueError(f"unknown integrator {integrator!r}; known: {', '.join(BATCHED_INTEGRATORS)}")
    steps, every = int(steps), max(1, int(every))
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    I_body = np.asarray(I_body, dtype=float)
    B = _batch_size({"mass": (mass, 0), "I_body": (I_body, 2), "position": (position, 1),
                     "quaternion_wxyz": (quaternion_wxyz, 1), "linear_velocity": (linear_velocity, 1),
                     "angular_velocity": (angular_velocity, 1), "force": (force, 1),
                     "torque": (torque, 1)})
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _simulate_batch(integrator, B, mass, I_body, position, quaternion_wxyz,
                               linear_velocity, angular_velocity, float(dt), steps, gravity,
                               force, torque, every)


def _simulate_batch(integrator, B, mass, I_body, position, quaternion_wxyz, linear_velocity,
                    angular_velocity, h, steps, gravity, force, torque, every) -> BatchTrajectory:
    """simulate_batch after its checks: the inputs broadcast to the batch and laid out in rows
    (the dict ``p`` the _run_* kernels take), then the matrix or the quaternion integrators."""
    M = np.broadcast_to(np.asarray(mass, dtype=float).reshape(-1), (B,)).copy()
    Ib = np.broadcast_to(I_body, (B, 3, 3)).copy()
    x0 = np.broadcast_to(np.asarray(position, dtype=float), (B, 3))
    q0 = _normalized(np.broadcast_to(np.asarray(quaternion_wxyz, dtype=float), (B, 4)))
    v0 = np.broadcast_to(np.asarray(linear_velocity, dtype=float), (B, 3))
    w0 = np.broadcast_to(np.asarray(angular_velocity, dtype=float), (B, 3))
    g = _rows(gravity, 3, B, "gravity")
    f = np.zeros((3, 1)) if force is None else _rows(force, 3, B, "force")
    tau5 = None
    if torque is not None and np.any(np.asarray(torque)):
        t = _rows(torque, 3, B, "torque")
        tau5 = np.concatenate([t, t[0:2]])
    Mrow = M.reshape(1, B) if np.ndim(mass) else np.full((1, 1), float(M[0]))
    p = {"B": B, "M": Mrow, "x": np.ascontiguousarray(x0.T), "f": f, "g": g, "tau": tau5}
    if integrator.startswith("euler-matrix"):
        return _simulate_matrix(integrator, p, M, I_body, Ib, q0, v0, w0, h, steps, every)
    return _simulate_principal(integrator, p, M, I_body, Ib, q0, v0, w0, h, steps, every)


def _simulate_matrix(integrator, p, M, I_body, Ib, q0, v0, w0, h, steps,
                     every) -> BatchTrajectory:
    """euler-matrix and euler-matrix-gs in the body frame on (x, R, p, L); w = R I_b^-1 R^T L and
    the quaternion of the nearest rotation from the samples."""
    B = p["B"]
    shared_inertia = I_body.ndim == 2
    R0 = matrix_from_quat(q0)                                        # (B, 3, 3)
    inv_Ib = np.linalg.inv(I_body if shared_inertia else Ib)
    L0 = np.einsum("bij,bjk,blk,bl->bi", R0, np.broadcast_to(Ib, (B, 3, 3)), R0, w0)
    p.update(R=np.ascontiguousarray(np.moveaxis(R0, 0, -1)),
             I_inv_b=(inv_Ib[:, :, None] if shared_inertia else np.moveaxis(inv_Ib, 0, -1).copy()),
             p=np.ascontiguousarray((M[:, None] * v0).T), L=np.ascontiguousarray(L0.T))
    rec = _Recorder(steps, every, {"x": 3, "R": 9, "p": 3, "L": 3}, B)
    _run_euler_matrix(p, h, steps, rec, gram=integrator == "euler-matrix-gs")
    a = rec.arrays
    Rs = np.moveaxis(a["R"].reshape(-1, 3, 3, B), -1, 1)            # (N, B, 3, 3)
    Ls = _soa_to_aos(a["L"])
    inv = np.broadcast_to(inv_Ib, (B, 3, 3))
    ws = np.einsum("nbij,bjk,nblk,nbl->nbi", Rs, inv, Rs, Ls)
    quats = quat_from_matrix_batch(nearest_rotation(Rs))
    t = rec.keep * h
    return BatchTrajectory(t, _soa_to_aos(a["x"]), quats, _soa_to_aos(a["p"]) / M[:, None],
                           ws, orthonormality_error(Rs))


def _simulate_principal(integrator, p, M, I_body, Ib, q0, v0, w0, h, steps,
                        every) -> BatchTrajectory:
    """The quaternion integrators, run in each body's principal frame (see the module docstring;
    a shared inertia is diagonalised once, a diagonal one keeps the body frame)."""
    B = p["B"]
    if I_body.ndim == 2:
        I_p, q_P = _principal(I_body[None])
        I_p_rows = np.ascontiguousarray(I_p.T)                           # (3, 1)
        q_Pb = None if q_P is None else np.broadcast_to(q_P, (B, 4))
    else:
        I_p, q_P = _principal(Ib)
        I_p_rows = np.ascontiguousarray(I_p.T)                           # (3, B)
        q_Pb = q_P
    q_p0 = q0 if q_Pb is None else quat_multiply(q0, q_Pb)
    p.update(q_p=np.ascontiguousarray(q_p0.T), I_p=I_p_rows)
    if integrator.startswith("semi-implicit"):
        w_p0 = _rotate(q_p0, w0, inverse=True)
        p.update(v=np.ascontiguousarray(v0.T), w_p=np.ascontiguousarray(w_p0.T))
        rec = _Recorder(steps, every, {"x": 3, "q": 4, "v": 3, "w": 3}, B)
        _run_semi_implicit(p, h, steps, rec, implicit=integrator.endswith("implicit-gyro"))
        a = rec.arrays
        q_p = _soa_to_aos(a["q"])
        ws = _rotate(q_p, _soa_to_aos(a["w"]))
        vs = _soa_to_aos(a["v"])
    else:
        L0 = _rotate(q_p0, I_p_rows.T * _rotate(q_p0, w0, inverse=True))
        p.update(p=np.ascontiguousarray((M[:, None] * v0).T), L=np.ascontiguousarray(L0.T))
        rec = _Recorder(steps, every, {"x": 3, "q": 4, "p": 3, "L": 3}, B)
        _run_quat_momentum(p, h, steps, rec, integrator)
        a = rec.arrays
        q_p = _soa_to_aos(a["q"])
        ws = _rotate(q_p, _rotate(q_p, _soa_to_aos(a["L"]), inverse=True) / I_p_rows.T)
        vs = _soa_to_aos(a["p"]) / M[:, None]
    ws[0] = w0
    quats = q_p if q_Pb is None else quat_multiply(q_p, quat_conjugate(q_Pb))
    return BatchTrajectory(rec.keep * h, _soa_to_aos(a["x"]), quats, vs, ws)


def supports_problem(problem: Problem, dt: float, steps: int) -> bool:
    """Whether :func:`simulate_problem` can integrate ``problem``: no loads, or loads that all act
    on every one of the ``steps`` steps as a force at the COM and/or a world couple."""
    for ld in problem.loads:
        k0, k1 = ld.step_range(dt)
        if k0 > 0 or k1 < steps or ld.point is not None or ld.body_point is not None \
                or np.any(ld.body_torque):
            return False
    return True


def simulate_problem(problem: Problem, integrator: str, dt: float, steps: int) -> Trajectory:
    """One problem through the batched kernels (B = 1): the same trajectory as
    ``integrators.simulate(problem, integrator, dt, steps)`` to round-off.

    Raises ValueError when :func:`supports_problem` is False.
    """
    if not supports_problem(problem, dt, steps):
        raise ValueError(f"case {problem.name!r}: its loads are not constant COM forces and world "
                         "couples over the whole run; use integrators.simulate")
    body, init = problem.body, problem.initial
    force = sum((ld.force for ld in problem.loads), np.zeros(3)) if problem.loads else None
    torque = sum((ld.torque for ld in problem.loads), np.zeros(3)) if problem.loads else None
    out = simulate_batch(integrator, body.mass, body.I_body, init.position[None],
                         init.quaternion_wxyz[None], init.linear_velocity[None],
                         init.angular_velocity[None], dt, steps, problem.gravity,
                         None if force is None else force[None],
                         None if torque is None else torque[None])
    return out.body(0)


# --- the closed-form truth of a batch -------------------------------------------------------------

def torque_free_rotation_batch(I_body, q0_wxyz, w0_world, t) -> tuple[np.ndarray, np.ndarray]:
    """:func:`torque_free.torque_free_rotation` for B bodies at the same times.

    I_body : (3, 3) or (B, 3, 3) kg m^2, about the COM, body frame.
    q0_wxyz : (B, 4) body -> world at t = 0.  w0_world : (B, 3) rad/s, world, at t = 0.
    t : (N,) s.
    Returns (q (N, B, 4) wxyz body -> world, w (N, B, 3) rad/s world), body by body identical to
    the single-body function: each body's motion is vectorised over t, the bodies are looped over
    (the closed form's set-up - principal axes, branch, elliptic parameter, AGM depth - is scalar
    per body, about 0.1 ms).
    """
    from .torque_free import torque_free_rotation

    q0 = np.atleast_2d(np.asarray(q0_wxyz, dtype=float))
    w0 = np.atleast_2d(np.asarray(w0_world, dtype=float))
    I_body = np.asarray(I_body, dtype=float)
    B = _batch_size({"I_body": (I_body, 2), "q0_wxyz": (q0, 1), "w0_world": (w0, 1)})
    I_all = np.broadcast_to(I_body, (B, 3, 3))
    q0, w0 = np.broadcast_to(q0, (B, 4)), np.broadcast_to(w0, (B, 3))
    t = np.asarray(t, dtype=float)
    q = np.empty(t.shape + (B, 4))
    w = np.empty(t.shape + (B, 3))
    for b in range(B):
        q[..., b, :], w[..., b, :] = torque_free_rotation(I_all[b], q0[b], w0[b], t)
    return q, w


def closed_form_batch(I_body, position, quaternion_wxyz, linear_velocity, angular_velocity,
                      gravity, t) -> BatchTrajectory:
    """The closed-form truth of B load-free bodies (:func:`truth.closed_form_trajectory` per body):
    torque-free rotation and ballistic COM motion under the shared gravity (3,) m/s^2.

    Shapes as in :func:`simulate_batch`; t (N,) s.  Returns a :class:`BatchTrajectory`.
    """
    q, w = torque_free_rotation_batch(I_body, quaternion_wxyz, angular_velocity, t)
    B = q.shape[-2]
    t = np.asarray(t, dtype=float)
    x0 = np.broadcast_to(np.asarray(position, dtype=float), (B, 3))
    v0 = np.broadcast_to(np.asarray(linear_velocity, dtype=float), (B, 3))
    g = np.asarray(gravity, dtype=float)
    x = x0 + t[:, None, None] * v0 + 0.5 * (t * t)[:, None, None] * g
    v = v0 + t[:, None, None] * g
    return BatchTrajectory(t, x, q, v, w)
