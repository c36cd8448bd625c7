"""Two more structure-aware reference integrators of the free rigid body: ``implicit-midpoint`` (the
implicit midpoint rule on the Lie-Poisson equations, second order, energy and |L| conserved
torque-free) and ``rkmk4`` (the Runge-Kutta-Munthe-Kaas method of classic RK4 on the rotation
group, fourth order).  Both work on the state (x, q, p, L) of the other quaternion schemes
(x (3,) m world, q (4,) wxyz body -> world, p (3,) kg m/s world, L (3,) kg m^2/s world about the
COM) and take I_b^-1 (3, 3) body frame.

``implicit-midpoint``.  Torque-free, the body angular momentum Pi = R^T L obeys the Lie-Poisson
(Euler) equations dPi/dt = Pi x w_b, w_b = I_b^-1 Pi, and the orientation dR/dt = R [w_b].  The
implicit midpoint rule on Pi (Hairer, Lubich & Wanner, *Geometric Numerical Integration*, 2nd ed.
2006: quadratic invariants, Theorem IV.2.1; Lie-Poisson systems and the rigid body, ch. VII; Austin,
Krishnaprasad & Wang, "Almost Poisson integration of rigid body systems", J. Comput. Phys. 107,
105-117 (1993), for this rule on the rigid body):

    Pi+ = Pi + h Pi_mid x I_b^-1 Pi_mid,      Pi_mid = (Pi + Pi+) / 2,

keeps every quadratic invariant of the equations (HLW Theorem IV.2.1): the Casimir |Pi|^2 and the
energy 1/2 Pi . I_b^-1 Pi.  It is solved by Newton's method (the Jacobian of the residual
F(Pi+) = Pi+ - Pi - h Pi_mid x w_mid is 1 - h/2 ([Pi_mid] I_b^-1 - [w_mid])), from Pi+ = Pi, until a
correction is below :data:`MIDPOINT_RTOL` |Pi|.  The orientation: R+ = R cay(h w_mid), w_mid =
I_b^-1 Pi_mid, with the Cayley map cay(A) = (1 - A/2)^-1 (1 + A/2) (as a quaternion: q+ = q *
(1, h w_mid / 2) / |(1, h w_mid / 2)|).  Cayley, not Exp, because it is the reconstruction the
midpoint equation implies: (1 + A/2) Pi+ = (1 - A/2) Pi with A = h [w_mid] is the equation above, so
Pi+ = cay(h w_mid)^T Pi and L+ = R+ Pi+ = R Pi = L: the world angular momentum is kept exactly (it is
never changed: the step carries L and recomputes Pi = R^T L), and the energy at R+ is the midpoint's
energy, conserved to the solver's residual.  cay(A) = Exp(A) + O(|A|^3), so the rotation is second
order like the rule on Pi; the whole map is symmetric (time-reversible), second order.  It is not
exact on a sphere (its turn per step is 2 atan(h |w| / 2), not h |w|).  It is not a Poisson map
(Austin et al. 1993: "almost Poisson"): the area on the momentum sphere |Pi| = const changes by up
to 3e-3 a step at h = 0.1 s (``symplectic-splitting`` keeps it); what it shows is exact
conservation of the energy and |L|.

Loads (and gravity): kick-drift-kick as in ``symplectic-splitting`` (:mod:`splitting`): half of step
k's impulse at the start state, the free motion above (x by p / M) with the kicked L, the other half
at the end state.  Exact for a constant force on the COM; second order.

``rkmk4``.  Classic RK4 (tableau c = 0, 1/2, 1/2, 1; b = 1/6, 1/3, 1/3, 1/6) on the vector parts
(x, p, L) and, for the orientation, the Runge-Kutta-Munthe-Kaas method (Munthe-Kaas, "Runge-Kutta
methods on Lie groups", BIT 38, 92-111 (1998) and "High order Runge-Kutta methods on manifolds",
Appl. Numer. Math. 29, 115-127 (1999); Iserles, Munthe-Kaas, Norsett & Zanna, "Lie-group methods",
Acta Numerica 9, 215-365 (2000), section 5; HLW section IV.8.2): with the world angular velocity
w = R I_b^-1 R^T L, dR/dt = [w] R, write R = exp([u]) R_0 and integrate u, du/dt = dexp^-1_u(w), in
the vector space so(3) = R^3 by RK4 from u = 0:

    u_i = h c_i K_{i-1},  R_i = exp([u_i]) R_0,  K_i = dexp^-1_{u_i}(w_i)  (w_i at stage i's R_i, L_i),
    R+ = exp([h (K_1 + 2 K_2 + 2 K_3 + K_4) / 6]) R_0,

with dexp^-1_u(w) = w - 1/2 u x w + 1/12 u x (u x w), the series truncated after the terms of order
p - 2 = 2 (enough for order 4: Munthe-Kaas 1999, HLW IV.8.2).  The loads are evaluated at every stage as ``rk4`` does
(the active set of step k, torque arms at the stage's x_i and R_i).  Fourth order.  q is unit by
construction (a product of unit quaternions); it is renormalised after the step only against
rounding.  Torque-free L' = 0, so L (hence |L| and |Pi|) is kept exactly, as by ``rk4``; the energy
is not conserved (an O(h^4) drift).  On a sphere w = L / I is constant, every u_i is parallel to it
and the step is the exact rotation Exp(h w): an exact rotation map there.

It is not MuJoCo 4's ``RK4`` (the engine map ``rkmk4-body``, :mod:`engine_maps`), even torque-free:
that integrates the body angular velocity w_b by RK4 on Euler's equations (so L is not exactly
constant) with a body-frame dexp^-1 and the wrench fixed over the step; this integrates L and
derives w at each stage from the stage's orientation.  Both are fourth order; they differ by
O(h^5) a step (measured in ``tests/test_lie_integrators.py``).
"""
from __future__ import annotations

import numpy as np

from .dynamics import Wrench
from .rotations import matrix_from_quat, quat_from_rotvec, quat_multiply, quat_normalize, skew

__all__ = ["MIDPOINT_RTOL", "MIDPOINT_MAX_ITERATIONS", "midpoint_momentum", "cayley_quat",
           "implicit_midpoint_step", "dexpinv_world", "rkmk4_step", "RK4_C", "RK4_B"]

# Newton's iteration for Pi+ stops once a correction is below this times |Pi|.  It converges
# quadratically, so the correction after one this small would be of order its square: below
# round-off.  The accepted Pi+ therefore solves the midpoint equation to round-off (the residual F is
# evaluated to about 4 eps |Pi|, 1e-15 |Pi|: this bound is 100 times that, reachable on every step).
MIDPOINT_RTOL = 1e-13
# A safety bound on Newton's iterations (the last one's correction being below tolerance; measured
# over random momenta of I = diag(1, 2, 3): 3 at h |w| <= 0.03, 3 to 5 at h |w| = 1, 4 to 7 at 3):
# past it the step is returned as it stands and the harness judges the run.
MIDPOINT_MAX_ITERATIONS = 30

# The classic RK4 tableau, used by rkmk4 here and by the MuJoCo RK4 maps (engine_maps): stage i
# starts from h c_i times stage i-1's slope (c_1 = 0; only the subdiagonal of A is non-zero), and
# the step combines the slopes with the weights B.
RK4_C = (0.5, 0.5, 1.0)  # c_2, c_3, c_4
RK4_B = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)


def midpoint_momentum(Pi: np.ndarray, h: float, I_inv: np.ndarray) -> np.ndarray:
    """Pi+ of the implicit midpoint rule Pi+ = Pi + h Pi_mid x I_b^-1 Pi_mid, Pi_mid = (Pi + Pi+)/2,
    by Newton's method from Pi+ = Pi.  Pi (3,) kg m^2/s body frame; I_inv (3, 3) body frame.
    Returns w_mid = I_b^-1 Pi_mid (3,) rad/s body frame, of the accepted Pi+."""
    Pi_new = Pi.copy()
    tol = MIDPOINT_RTOL * np.linalg.norm(Pi)
    for _ in range(MIDPOINT_MAX_ITERATIONS):
        Pi_mid = 0.5 * (Pi + Pi_new)
        w_mid = I_inv @ Pi_mid
        F = Pi_new - Pi - h * np.cross(Pi_mid, w_mid)
        J = np.eye(3) - 0.5 * h * (skew(Pi_mid) @ I_inv - skew(w_mid))
        delta = np.linalg.solve(J, F)
        Pi_new = Pi_new - delta
        if not np.linalg.norm(delta) > tol:  # converged (or not finite: the harness judges)
            break
    return I_inv @ (0.5 * (Pi + Pi_new))


def cayley_quat(u: np.ndarray) -> np.ndarray:
    """cay([u]) = (1 - [u]/2)^-1 (1 + [u]/2) as a unit quaternion: (1, u/2) / |(1, u/2)| (the
    rotation about u by 2 atan(|u| / 2)).  u (3,) rad."""
    return quat_normalize(np.r_[1.0, 0.5 * u])


def implicit_midpoint_step(k: int, x, q, p, L, dt: float, M: float, I_inv, g, wrench: Wrench):
    """One step of ``implicit-midpoint``: kick (half of step k's impulse at the start state), drift
    (x by p / M; Pi = R^T L by the implicit midpoint rule, q+ = q cay(h w_mid), L unchanged), kick
    (the other half at the end state).  Arguments as :func:`integrators.rk4_step`."""
    f, tau = wrench(k, x, matrix_from_quat(q))
    p = p + 0.5 * dt * (f + M * g)
    L = L + 0.5 * dt * tau
    x = x + dt * p / M
    Pi = matrix_from_quat(q).T @ L
    w_mid = midpoint_momentum(Pi, dt, I_inv)
    q = quat_normalize(quat_multiply(q, cayley_quat(dt * w_mid)))
    f, tau = wrench(k, x, matrix_from_quat(q))
    p = p + 0.5 * dt * (f + M * g)
    L = L + 0.5 * dt * tau
    return x, q, p, L


def dexpinv_world(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """dexp^-1_u(w) for R = exp([u]) R_0 with world rate w (dR/dt = [w] R), truncated for order 4:
    w - 1/2 u x w + 1/12 u x (u x w).  u (3,) rad, w (3,) rad/s world."""
    uw = np.cross(u, w)
    return w - 0.5 * uw + np.cross(u, uw) / 12.0


def rkmk4_step(k: int, x, q, p, L, dt: float, M: float, I_inv, g, wrench: Wrench):
    """One step of ``rkmk4``: classic RK4 on (x, p, L), RKMK4 on q (module docstring).  Every stage
    sees the loads of step k, their torque arms at the stage's state.  Arguments as
    :func:`integrators.rk4_step`."""
    def slopes(x_, q_, p_, L_):
        R = matrix_from_quat(q_)
        f, tau = wrench(k, x_, R)
        return p_ / M, R @ I_inv @ R.T @ L_, f + M * g, tau  # dx, w (world), dp, dL

    dx, w, dp, dL = slopes(x, q, p, L)
    dxs, Ks, dps, dLs = [dx], [w], [dp], [dL]
    for c in RK4_C:
        u = dt * c * Ks[-1]
        dx, w, dp, dL = slopes(x + dt * c * dxs[-1], quat_multiply(quat_from_rotvec(u), q),
                               p + dt * c * dps[-1], L + dt * c * dLs[-1])
        dxs.append(dx)
        Ks.append(dexpinv_world(u, w))
        dps.append(dp)
        dLs.append(dL)
    b1, b2, b3, b4 = RK4_B
    x = x + dt * (b1 * dxs[0] + b2 * dxs[1] + b3 * dxs[2] + b4 * dxs[3])
    p = p + dt * (b1 * dps[0] + b2 * dps[1] + b3 * dps[2] + b4 * dps[3])
    L = L + dt * (b1 * dLs[0] + b2 * dLs[1] + b3 * dLs[2] + b4 * dLs[3])
    u = dt * (b1 * Ks[0] + b2 * Ks[1] + b3 * Ks[2] + b4 * Ks[3])
    return x, quat_normalize(quat_multiply(quat_from_rotvec(u), q)), p, L
