"""Closed-form torque-free rotation of an arbitrary rigid body (Euler-Poinsot motion).

Public API: :func:`torque_free_rotation` ``(I_body, q0_wxyz, w0_world, t) -> (q_wxyz, w_world)``.

Conventions (freebody's canonical ones, see :mod:`conventions`): SI units; Hamilton quaternions
stored ``(w, x, y, z)``, rotating body -> world (``v_world = R(q) v_body``); angular velocity in
the WORLD frame; ``I_body`` about the COM in the body frame, symmetric positive definite,
possibly non-diagonal.  No forces or torques act; the COM motion is not part of this module.

Method
------
1. Principal frame.  ``I_body = P diag(I1, I2, I3) P^T`` (``eigh``, ascending, columns flipped to
   ``det P = +1``); the principal attitude is ``R_p = R P``, solved for and mapped back.
2. Angular momentum in the body.  ``m = diag(I) w_p``; ``L = |m|`` and ``2E = sum m_i^2 / I_i``
   are conserved.  The polhode circulates about the major axis if ``L^2 > 2E I2`` and about the
   minor axis if ``L^2 < 2E I2``; the minor family is relabelled by the proper rotation
   ``(x', y', z') = (x3, -x2, x1)`` (moments ``(I3, I2, I1)``) so one set of formulas serves both.
   In the frame ``(a, b, c)``, ``c`` the circulation axis (Landau & Lifshitz, Mechanics, s. 37):
   ``m_a = sigma A_a cn(tau)``, ``m_b = s_b A_b sn(tau)``, ``m_c = s A_c dn(tau)``,
   ``tau = tau0 + lambda t``, parameter ``k^2 = (Ib-Ia)(2E Ic - L^2) / ((Ic-Ib)(L^2 - 2E Ia))``,
   ``lambda^2 = (Ic-Ib)(L^2 - 2E Ia) / (Ia Ib Ic)``, signs ``s = sign m_c``,
   ``sigma = sign m_a(0)``, ``s_b = sign(Ic-Ib) sigma s``.  ``k^2``, ``1 - k^2``, ``lambda`` and
   the amplitudes are formed from ``m(0)`` with the large common terms cancelled analytically
   (e.g. ``L^2 - 2E I2 = m3^2 (I3-I2)/I3 - m1^2 (I2-I1)/I1``, the others sums of same-sign
   terms), so they keep full relative accuracy near the separatrix, a steady spin, or an
   axisymmetric body.
3. Jacobi functions (own implementation, vectorised): the argument is reduced modulo ``2K`` to
   ``|r| <= K``, reflected to ``|x| <= K/2`` with ``x = K - |r|`` (``sn = cd x``,
   ``cn = k' sd x``, ``dn = k' nd x``), then evaluated by the AGM / descending Landen scheme for
   ``1 - k^2 >= 0.05`` and by the ascending Landen transformation below (A&S 16.4, 16.14, 16.15).
   This keeps cn and dn accurate to a few ulps *relative* even where they are O(k') near the
   separatrix.  (scipy's ``ellipj`` uses a first-order expansion for ``k^2 > 1 - 1e-9`` that is
   wrong for large arguments, and an amplitude-based cn that is only absolutely accurate.)
4. Attitude.  Writing ``u = m / L = (sin th sin psi, sin th cos psi, cos th)`` in ``(a, b, c)``,
   ``R' = A Rz(phi) Rx(th) Rz(psi)`` with ``A`` constant (``A e3 = L_world / L``, fixed by the
   initial attitude).  ``th`` and ``psi`` come from the amplitude-free ratios
   ``sin psi : cos psi = sigma cn : s_b sqrt(1-n) sn`` (so a polhode shrunk to a point, i.e. a
   spin about ``c``, is still exact), ``psi`` unwrapped by ``pi`` per half period.  The precession
   angle about ``L`` obeys ``phi' = L/Ic + L (Ic-Ia)/(Ia Ic) / (1 - n sn^2 tau)``,
   ``n = Ic (Ia-Ib) / (Ia (Ic-Ib)) < 0`` (independent of ``E`` and ``L``), hence
   ``phi = L t / Ic + C [P(tau) - P(tau0)]``, ``C = L (Ic-Ia) / (Ia Ic lambda)``,
   ``P(u) = int_0^u dv / (1 - n sn^2 v) = Pi(n; am u | k^2)``, the incomplete elliptic integral of
   the third kind, with ``P(u + 2K) = P(u) + 2 Pi(n | k^2)``.  It is evaluated with Carlson's
   symmetric integrals (``scipy.special.elliprf``, ``elliprj``, ``elliprc``; ``s, c, d`` = sn, cn,
   dn at the reduced argument):
   - if ``n^2 <= k^2``: ``P = u + Q``, ``Q = n s^3 / 3 R_J(c^2, d^2, 1, 1 - n s^2)`` (DLMF
     19.25.14), and ``phi = L t / Ia + C [Q(tau) - Q(tau0)]``, whose rounding error does not grow
     like ``1 / lambda`` for a slow polhode (nearly axisymmetric bodies);
   - else the characteristic is swapped to ``N = k^2 / n`` (DLMF 19.7.9):
     ``P = -N s^3 / 3 R_J(c^2, d^2, 1, 1 - N s^2) + s R_C(c^2 d^2, (1 - n s^2)(1 - N s^2))``,
     which avoids the ``sqrt(-n)``-fold cancellation of the direct form (``n ~ -1 / (I2 - I1)``
     for a nearly axisymmetric body spinning near its equator).
   On the separatrix (``1 - k^2 < 1e-150``; scipy's ``R_J`` degrades when two arguments are below
   ~1e-155) sn, cn, dn = tanh, sech, sech and ``P(u) = (u + sqrt(p) atan(sqrt(p) tanh u)) / (1+p)``,
   ``p = -n``.
5. Special cases.  Two moments equal within ``EQUAL_MOMENTS_RTOL``: the exact regular
   precession ``R_p(t) = Exp(t L_world / I_t) R_p(0) Exp(t c e_s)``, ``c = m_s (1/I_s - 1/I_t)``;
   a sphere: ``R(t) = Exp(t w0) R0``, ``w`` constant; ``w0 = 0``: at rest; a spin exactly about
   the intermediate axis (the equilibrium on the separatrix): steady rotation.

Accuracy (measured against a 32-digit Taylor-series integration, mpmath ``odefun``): the
Dzhanibekov case ``I = diag(1, 2, 3)``, ``w0 = (0.01, 5, 0)``: <= 2e-14 rad attitude and
<= 4e-15 relative angular velocity over 10 s (4e-14 rad over 60 s; the error grows like rounding
times the elapsed phase).  The same <= ~1e-14 rad holds for both polhode families, the exact
separatrix, spins 1e-10 and 1e-80 off the intermediate axis, nearly axisymmetric bodies with
moment splits from 1e-5 down to one ulp (<= 1.2e-13 rad) and nearly spherical bodies.  The
result is exact for rounded inputs only: near the separatrix, the motion itself amplifies a
rounding of ``w0`` or ``I_body`` (e.g. a rotated body frame) by the flip dynamics.

Everything is vectorised over ``t`` (only the O(log log(1/k'^2)) AGM/Landen set-up is a scalar
Python loop).  Cost (CPU, loaded 2-core machine): a set-up of 0.4-0.8 ms a call (eigh, the
modulus, the scalar elliptic integrals) plus 0.3-0.7 us a sample, of which scipy's ``elliprj``
is 0.28 us (Dzhanibekov: 0.75 ms for 1 sample, 2.25 ms for 2001, 13.7 ms for 20001; a symmetric
top 1.06 ms for 2001; a sphere 0.54 ms).
"""
from __future__ import annotations

import numpy as np
from scipy.special import elliprc, elliprf, elliprj

from .rotations import (
    matrix_from_quat,
    quat_conjugate,
    quat_from_matrix,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
)

__all__ = ["torque_free_rotation", "EQUAL_MOMENTS_RTOL"]

# Principal moments closer than this (relative to the largest) are treated as exactly equal
# (axisymmetric / spherical closed forms; the asymmetric formulas divide by the differences).
# The asymmetric formulas stay accurate to ~1e-14 rad for splits down to one ulp, so this only
# needs to catch the few-ulp splitting that eigh gives a repeated eigenvalue; the error of the
# symmetric form for a split below it is ~ rtol x (rotation angle).
EQUAL_MOMENTS_RTOL = 1e-15

# Relabelling (x', y', z') = (x3, -x2, x1): a proper rotation taking the minor axis to z'.
_FLIP_MINOR_TO_Z = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
_AGM_MAX_ITER = 64   # safety cap; convergence takes ~log2(log(1/(1 - k^2))) + 5 steps
# Below this 1 - k^2 the Jacobi functions come from the ascending Landen transformation (which
# keeps cn, dn ~ sqrt(k') near u = K/2 relatively accurate), above it from the AGM (both give
# ~1e-16 there).
_KP2_ASCENDING = 0.05
# Below this 1 - k^2 the separatrix (k^2 = 1) formulas are used: scipy's R_J loses accuracy when
# two arguments are both below ~1e-155.  The state is then within k' < 1e-75 of the separatrix
# and the two motions agree to rounding while k' e^tau < 1e-16, i.e. tau < ~130 (t < 130/lambda).
_KP2_SEPARATRIX = 1e-150


def _quat_axis(angle: np.ndarray, axis: int) -> np.ndarray:
    """Quaternion (..., 4) of a rotation by ``angle`` (rad, shape (...)) about body axis 0/1/2."""
    angle = np.asarray(angle, dtype=float)
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(0.5 * angle)
    q[..., 1 + axis] = np.sin(0.5 * angle)
    return q


def _jacobi_agm(u: np.ndarray, k2: float, kp2: float):
    """Jacobi sn, cn, dn (each shaped like u) for parameter m = k2 in [0, 1), kp2 = 1 - k2.

    u : array, dimensionless, meant for |u| <= K/2.  ``kp2`` is passed separately so that it
    keeps full relative accuracy when k2 is close to 1.  AGM + descending Landen transformation
    (Abramowitz & Stegun 16.4), iterated until c_N / a_N < eps (no iteration cap in practice:
    it needs ~log2(log(1/kp2)) + 5 steps).
    """
    a_list = [1.0]
    c_list = [float(np.sqrt(k2))]
    a, b = 1.0, float(np.sqrt(kp2))
    for _ in range(_AGM_MAX_ITER):
        if c_list[-1] <= np.finfo(float).eps * a_list[-1]:
            break
        a, b, c = 0.5 * (a + b), float(np.sqrt(a * b)), 0.5 * (a - b)
        a_list.append(a)
        c_list.append(c)
    n_levels = len(a_list) - 1
    phi = (2.0 ** n_levels) * a_list[-1] * u
    for i in range(n_levels, 0, -1):
        phi = 0.5 * (np.arcsin(np.clip(c_list[i] / a_list[i] * np.sin(phi), -1.0, 1.0)) + phi)
    cn = np.cos(phi)
    return np.sin(phi), cn, np.sqrt(kp2 + k2 * cn * cn)


def _jacobi_landen_up(u: np.ndarray, kp2: float):
    """Jacobi sn, cn, dn of u for a parameter close to 1 (kp2 = 1 - m small), meant for |u| <= K/2.

    Ascending Landen (Gauss) transformation (Abramowitz & Stegun 16.14): with
    e = (1 - k) / (1 + k) = kp2 / (1 + k)^2, the parameter mu = 1 - e^2 is much closer to 1 and
    sn(u|m) = (1 + e) sn cn / dn,  cn(u|m) = (dn^2 - e) / ((1 - e) dn),
    dn(u|m) = (dn^2 + e) / ((1 + e) dn)   [right-hand sides at (u / (1 + e) | mu)].
    At least one step is taken and the recursion stops once 1 - mu <= 1e-12, where the
    first-order expansion about m = 1 (A&S 16.15) is exact to rounding for |u| <= K/2.  Unlike
    the AGM route, cn and dn keep full relative accuracy although they are O(sqrt(k')) there.
    """
    es = []
    kp2_i = kp2
    while True:
        k = float(np.sqrt(1.0 - kp2_i))
        e = kp2_i / (1.0 + k) ** 2
        es.append(e)
        kp2_i = e * e
        if kp2_i <= 1e-12:
            break
    v = u
    for e in es:
        v = v / (1.0 + e)
    ch = np.cosh(v)
    th = np.tanh(v)
    sech = 1.0 / ch
    corr = 0.25 * kp2_i * sech
    shch = np.sinh(v) * ch
    sn = th + corr * (shch - v) * sech
    cn = sech - corr * (shch - v) * th
    dn = sech + corr * (shch + v) * th
    for e in reversed(es):
        sn, cn, dn = (1.0 + e) * sn * cn / dn, (dn * dn - e) / ((1.0 - e) * dn), \
            (dn * dn + e) / ((1.0 + e) * dn)
    return sn, cn, dn


def _jacobi_sn_cn_dn(r: np.ndarray, k2: float, kp2: float, K: float):
    """Jacobi sn, cn, dn of r (|r| <= K) for parameter k2 < 1, kp2 = 1 - k2, K = K(k2).

    For |r| > K/2 the functions are obtained from x = K - |r| by the quarter-period reflection
    sn(K - x) = cd x, cn(K - x) = k' sd x, dn(K - x) = k' nd x, and for small k' the ascending
    Landen transformation is used, so cn and dn keep a few ulps of *relative* accuracy even where
    they are O(k') (near r = +-K); the Carlson integrals, whose arguments are cn^2 and dn^2, need
    that to stay accurate near the separatrix.
    """
    r = np.asarray(r, dtype=float)
    ar = np.abs(r)
    refl = ar > 0.5 * K
    x = np.where(refl, K - ar, ar)
    if kp2 < _KP2_ASCENDING:
        sn_x, cn_x, dn_x = _jacobi_landen_up(x, kp2)
    else:
        sn_x, cn_x, dn_x = _jacobi_agm(x, k2, kp2)
    kp = float(np.sqrt(kp2))
    sn = np.copysign(np.where(refl, cn_x / dn_x, sn_x), r)
    cn = np.where(refl, kp * sn_x / dn_x, cn_x)
    dn = np.where(refl, kp / dn_x, dn_x)
    return sn, cn, dn


def _steady(q_p0: np.ndarray, w_world0: np.ndarray, t: np.ndarray):
    """Steady spin about a fixed world axis (sphere, or spin about a principal axis).

    q_p0 : (4,) principal -> world at t = 0.  w_world0 : (3,) rad/s, world.  t : (...) s.
    Returns (q (..., 4) principal -> world, w (..., 3) rad/s world).
    """
    q = quat_multiply(quat_from_rotvec(t[..., None] * w_world0), q_p0)
    w = np.broadcast_to(w_world0, t.shape + (3,)).copy()
    return q, w


def _axisymmetric(I_t: float, I_s: float, axis: int, q_p0: np.ndarray, m0: np.ndarray,
                  L_world: np.ndarray, t: np.ndarray):
    """Exact precession of a body with two equal moments I_t and symmetry axis ``axis`` (I_s).

    q_p0 : (4,) principal -> world at t = 0.  m0 : (3,) kg m^2/s, principal frame.
    L_world : (3,) kg m^2/s.  Returns (q (..., 4) principal -> world, w (..., 3) rad/s world).
    """
    c = m0[axis] * (1.0 / I_s - 1.0 / I_t)           # rad/s, body spin relative to L-precession
    e_s = np.zeros(3)
    e_s[axis] = 1.0
    q = quat_multiply(quat_multiply(quat_from_rotvec(t[..., None] * (L_world / I_t)), q_p0),
                      quat_from_rotvec(t[..., None] * (c * e_s)))
    e_s_world = matrix_from_quat(q)[..., :, axis]
    w = L_world / I_t + c * e_s_world
    return q, w


def _third_kind_part(sn: np.ndarray, cn: np.ndarray, dn: np.ndarray, n: float, k2: float,
                     use_q: bool) -> np.ndarray:
    """The non-trivial part of int_0^r dv / (1 - n sn^2 v) = Pi(n; am r | k^2) for |r| <= K.

    sn, cn (>= 0), dn : arrays (same shape), the Jacobi functions at r.  n < 0, k2 in [0, 1).
    Returns Q(r) = Pi - F(am r) = n s^3 / 3 R_J(c^2, d^2, 1, 1 - n s^2) if ``use_q`` (Carlson,
    DLMF 19.25.14 scaled by s^2; F = r is split off exactly, so Q is small when n is), else
    Pi itself written with the swapped characteristic N = k^2 / n (DLMF 19.7.9):
    Pi = -N s^3 / 3 R_J(c^2, d^2, 1, 1 - N s^2) + s R_C(c^2 d^2, (1 - n s^2)(1 - N s^2)),
    which has no cancellation when n^2 > k^2 (the direct Carlson form of Pi loses ~sqrt(-n)
    there: a nearly axisymmetric body spinning near its equator has n ~ -1 / (I2 - I1)).
    """
    c2, d2, s2 = cn * cn, dn * dn, sn * sn
    if use_q:
        return n / 3.0 * sn * s2 * elliprj(c2, d2, 1.0, 1.0 - n * s2)
    N = k2 / n
    return (-N / 3.0 * sn * s2 * elliprj(c2, d2, 1.0, 1.0 - N * s2)
            + sn * elliprc(c2 * d2, (1.0 - n * s2) * (1.0 - N * s2)))


def _polhode_modulus(Ia: float, Ib: float, Ic: float, ma0: float, mb0: float, mc0: float):
    """(k^2, 1 - k^2, L^2 - 2E Ia) of the polhode through m0 = (ma0, mb0, mc0) (see _asymmetric).

    The conserved brackets 2E Ic - L^2, L^2 - 2E Ia, L^2 - 2E Ib are formed with their m_b^2
    (resp. m_a^2, m_c^2) terms cancelled analytically, so k^2 and 1 - k^2 (each clamped to
    [0, 1]) both have full relative accuracy.
    """
    twoE_Ic_m_L2 = ma0 * ma0 * (Ic - Ia) / Ia + mb0 * mb0 * (Ic - Ib) / Ib      # 2E Ic - L^2
    L2_m_twoE_Ia = mb0 * mb0 * (Ib - Ia) / Ib + mc0 * mc0 * (Ic - Ia) / Ic      # L^2 - 2E Ia
    L2_m_twoE_Ib = mc0 * mc0 * (Ic - Ib) / Ic - ma0 * ma0 * (Ib - Ia) / Ia      # L^2 - 2E Ib
    den = (Ic - Ib) * L2_m_twoE_Ia
    k2 = min(max((Ib - Ia) * twoE_Ic_m_L2 / den, 0.0), 1.0)     # Jacobi parameter m = k^2
    kp2 = min(max((Ic - Ia) * L2_m_twoE_Ib / den, 0.0), 1.0)    # 1 - k^2, to full accuracy
    return k2, kp2, L2_m_twoE_Ia


def _initial_phase(y0: float, x0: float, k2: float, kp2: float):
    """(sn0, cn0, dn0, tau0) of the start: am(tau0) = atan2(y0, x0), in [-pi/2, pi/2] (x0 >= 0).

    tau0 = F(am0 | k^2); on the separatrix with cn0 = 0 (a spin within 1e-75 of the
    intermediate axis) F is infinite: |tau0| = 700 is the saddle to rounding (sech 700 ~ 1e-304).
    """
    h = float(np.hypot(x0, y0))
    sn0, cn0 = (y0 / h, x0 / h) if h > 0.0 else (0.0, 1.0)
    dn0 = float(np.sqrt(kp2 + k2 * cn0 * cn0))
    with np.errstate(divide="ignore"):
        F0 = elliprf(cn0 * cn0, dn0 * dn0, 1.0)
    tau0 = float(np.clip(sn0 * F0, -700.0, 700.0))
    return sn0, cn0, dn0, tau0


def _periodic_phase(tau: np.ndarray, sn0: float, cn0: float, dn0: float, n: float, k2: float,
                    kp2: float, use_q: bool):
    """Jacobi functions and third-kind integral at tau off the separatrix (k^2 < 1).

    Returns (j, sn_r, cn_r, sn, cn, dn, G, G0): tau = 2K j + r with |r| <= K; sn_r, cn_r the
    functions at r; sn, cn, dn those at tau; G = P(tau) (or Q(tau) when ``use_q``) and G0 the
    same at tau0, from the start's sn0, cn0, dn0 (see _asymmetric).
    """
    K = float(elliprf(0.0, kp2, 1.0))
    j = np.rint(tau / (2.0 * K))                  # tau = 2K j + r, |r| <= K
    r = tau - 2.0 * K * j
    sn_r, cn_r, dn_r = _jacobi_sn_cn_dn(r, k2, kp2, K)
    sgn = 1.0 - 2.0 * np.mod(j, 2.0)              # sn, cn flip sign every 2K; dn does not
    sn, cn, dn = sgn * sn_r, sgn * cn_r, dn_r
    half_period = 2.0 * float(_third_kind_part(np.float64(1.0), np.float64(0.0),
                                               np.sqrt(np.float64(kp2)), n, k2, use_q))
    G = half_period * j + _third_kind_part(sn_r, cn_r, dn_r, n, k2, use_q)
    G0 = float(_third_kind_part(np.float64(sn0), np.float64(cn0), np.float64(dn0), n, k2,
                                use_q))
    return j, sn_r, cn_r, sn, cn, dn, G, G0


def _separatrix_phase(tau: np.ndarray, tau0: float, n: float, use_q: bool):
    """_periodic_phase on the separatrix, k^2 = 1: sn = tanh, cn = dn = sech, no period (j = 0).

    P(u) = (u + sqrt(p) atan(sqrt(p) tanh u)) / (1 + p) with p = -n;  Q = P - u.
    """
    j = np.zeros_like(tau)
    sn_r = sn = np.tanh(tau)
    ex = np.exp(-np.abs(tau))
    cn_r = cn = 2.0 * ex / (1.0 + ex * ex)        # sech, without overflow
    dn = cn
    p = -n
    sp = float(np.sqrt(p))

    def sep(u, tanh_u):
        if use_q:
            return (sp * np.arctan(sp * tanh_u) - p * u) / (1.0 + p)
        return (u + sp * np.arctan(sp * tanh_u)) / (1.0 + p)
    G = sep(tau, sn)
    G0 = sep(tau0, np.tanh(tau0))
    return j, sn_r, cn_r, sn, cn, dn, G, G0


def _asymmetric(I_abc: np.ndarray, m0: np.ndarray, t: np.ndarray):
    """Torque-free motion with distinct moments, polhode circulating about the third axis c.

    I_abc : (3,) kg m^2, the principal moments in a right-handed principal frame (a, b, c) where
        Ib lies strictly between Ia and Ic and the polhode circulates about c, i.e.
        (Ic - Ib) (L^2 - 2E Ib) >= 0  (either Ia < Ib < Ic or Ia > Ib > Ic).
    m0 : (3,) kg m^2/s, angular momentum at t = 0 in the (a, b, c) frame; not along b alone.
    t : (...) s.
    Returns
        m : (..., 3) kg m^2/s, angular momentum in the (a, b, c) frame at the times t;
        q_B0 : (4,) the quaternion of Rx(th0) Rz(psi0), i.e. of the body-frame rotation taking
            u(0) = m(0) / L to e3;
        q_M : (..., 4) the quaternion of Rz(phi) Rx(th) Rz(psi) with phi(0) = 0,
    so that the (a, b, c) -> world attitude is R'(t) = R'(0) conj(q_B0) q_M(t).
    """
    Ia, Ib, Ic = (float(v) for v in I_abc)
    ma0, mb0, mc0 = (float(v) for v in m0)
    k2, kp2, L2_m_twoE_Ia = _polhode_modulus(Ia, Ib, Ic, ma0, mb0, mc0)
    separatrix = kp2 < _KP2_SEPARATRIX
    if separatrix:
        k2, kp2 = 1.0, 0.0
    L = float(np.sqrt(ma0 * ma0 + mb0 * mb0 + mc0 * mc0))
    n = Ic * (Ia - Ib) / (Ia * (Ic - Ib))             # < 0, characteristic of the third kind
    lam = float(np.sqrt((Ic - Ib) * L2_m_twoE_Ia / (Ia * Ib * Ic)))   # d tau / dt, 1/s
    sq1n = float(np.sqrt(1.0 - n))                    # A_b / A_a
    A_a = float(np.sqrt(ma0 * ma0 + mb0 * mb0 / (1.0 - n)))
    A_b = sq1n * A_a
    A_c = float(np.sqrt(mc0 * mc0 + mb0 * mb0 * Ic * (Ib - Ia) / (Ib * (Ic - Ia))))
    s = 1.0 if mc0 >= 0.0 else -1.0                   # m_c never changes sign
    sigma = 1.0 if ma0 >= 0.0 else -1.0               # picks the half-period holding the start
    chi = 1.0 if Ic > Ib else -1.0                    # circulation sense: +1 major, -1 minor axis
    s_b = chi * sigma * s                             # m_b = s_b A_b sn(tau)
    # am(tau0) = atan2(s_b mb0 / sqrt(1 - n), sigma ma0), in [-pi/2, pi/2]
    sn0, cn0, dn0, tau0 = _initial_phase(s_b * mb0 / sq1n, sigma * ma0, k2, kp2)
    tau = tau0 + lam * t

    # phi(t) = L t / Ic + C [P(tau) - P(tau0)], P(u) = int_0^u dv / (1 - n sn^2 v), C as below.
    # With P = u + Q (use_q) this is phi = L t / Ia + C [Q(tau) - Q(tau0)], whose error does not
    # grow like 1 / lambda when the polhode is slow (nearly axisymmetric bodies).
    use_q = n * n <= k2
    C = L * (Ic - Ia) / (Ia * Ic * lam)
    if not separatrix:
        j, sn_r, cn_r, sn, cn, dn, G, G0 = _periodic_phase(tau, sn0, cn0, dn0, n, k2, kp2, use_q)
    else:                                             # separatrix, k^2 = 1: tanh / sech
        j, sn_r, cn_r, sn, cn, dn, G, G0 = _separatrix_phase(tau, tau0, n, use_q)

    m = np.stack([sigma * A_a * cn, s_b * A_b * sn, s * A_c * dn], axis=-1)
    phi = (L / Ia if use_q else L / Ic) * t + C * (G - G0)

    def quat_B(sn_r_, cn_r_, dn_, j_):
        # u = (sin th sin psi, sin th cos psi, cos th); the ratios below are amplitude-free.
        D = np.sqrt(1.0 - n * sn_r_ * sn_r_)
        psi = np.arctan2(sigma * cn_r_ / D, s_b * sq1n * sn_r_ / D) - chi * s * np.pi * j_
        th = np.arctan2(A_a * D / L, s * A_c * dn_ / L)
        return quat_multiply(_quat_axis(th, 0), _quat_axis(psi, 2))

    q_B0 = quat_B(np.float64(sn0), np.float64(cn0), np.float64(dn0), 0.0)
    q_M = quat_multiply(_quat_axis(phi, 2), quat_B(sn_r, cn_r, dn, j))
    return m, q_B0, q_M


def torque_free_rotation(I_body, q0_wxyz, w0_world, t):
    """Closed-form torque-free rotation.

    I_body : (3, 3) kg m^2, about COM, body frame, symmetric positive definite, may be
        non-diagonal.
    q0_wxyz : (4,) unit quaternion (w, x, y, z) at t = 0, body -> world (normalised here).
    w0_world : (3,) rad/s, angular velocity at t = 0, world frame.
    t : (N,) s, times (t >= 0 typical, any order; any shape works, the outputs get t.shape + (4,)
        and t.shape + (3,)).
    Returns (q_wxyz (N, 4), w_world (N, 3)): attitude quaternion body -> world (Hamilton,
    scalar first, continuous in t and equal to q0_wxyz at t = 0) and angular velocity in the world
    frame, rad/s, at those times.
    """
    I_body = np.asarray(I_body, dtype=float)
    if I_body.shape != (3, 3):
        raise ValueError(f"I_body must have shape (3, 3), got {I_body.shape}")
    q0 = quat_normalize(np.asarray(q0_wxyz, dtype=float).reshape(4))
    w0 = np.asarray(w0_world, dtype=float).reshape(3)
    t = np.asarray(t, dtype=float)

    moments, P = np.linalg.eigh(0.5 * (I_body + I_body.T))     # ascending, P columns = axes
    if np.any(moments <= 0.0):
        raise ValueError(f"I_body must be positive definite, eigenvalues {moments}")
    if np.linalg.det(P) < 0.0:
        P[:, 2] = -P[:, 2]
    q_P = quat_from_matrix(P)                          # principal -> body
    q_p0 = quat_multiply(q0, q_P)                      # principal -> world at t = 0
    R_p0 = matrix_from_quat(q_p0)
    w_p0 = R_p0.T @ w0                                 # rad/s, principal frame
    I1, I2, I3 = (float(v) for v in moments)
    tol = EQUAL_MOMENTS_RTOL * I3

    if not np.any(w0):                                 # at rest
        q_p = np.broadcast_to(q_p0, t.shape + (4,)).copy()
        w = np.zeros(t.shape + (3,))
    elif I3 - I1 <= tol:                               # sphere: constant w
        q_p, w = _steady(q_p0, w0, t)
    elif I2 - I1 <= tol or I3 - I2 <= tol:             # axisymmetric: exact precession
        axis, I_s, I_t = (2, I3, 0.5 * (I1 + I2)) if I2 - I1 <= tol else (0, I1, 0.5 * (I2 + I3))
        I_p = np.full(3, I_t)
        I_p[axis] = I_s
        m0 = I_p * w_p0
        q_p, w = _axisymmetric(I_t, I_s, axis, q_p0, m0, R_p0 @ m0, t)
    else:
        m0 = moments * w_p0
        if m0[0] == 0.0 and m0[2] == 0.0:              # spin about the intermediate axis
            q_p, w = _steady(q_p0, w0, t)
        else:
            L2_m_twoE_I2 = m0[2] ** 2 * (I3 - I2) / I3 - m0[0] ** 2 * (I2 - I1) / I1
            G = np.eye(3) if L2_m_twoE_I2 >= 0.0 else _FLIP_MINOR_TO_Z   # principal -> (a, b, c)
            q_G = quat_from_matrix(G.T)                # (a, b, c) -> principal
            q_abc0 = quat_multiply(q_p0, q_G)          # (a, b, c) -> world at t = 0
            I_abc = np.abs(G) @ moments                # moments are permuted, not rotated
            m_abc, q_B0, q_M = _asymmetric(I_abc, G @ m0, t)
            q_abc = quat_multiply(quat_multiply(q_abc0, quat_conjugate(q_B0)), q_M)
            w_abc = m_abc / I_abc
            w = np.einsum("...ij,...j->...i", matrix_from_quat(q_abc), w_abc)
            q_p = quat_multiply(q_abc, quat_conjugate(q_G))
    q = quat_multiply(q_p, quat_conjugate(q_P))
    return q, w
