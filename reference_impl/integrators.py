"""The lecture's integrators of the free rigid body, each selectable by name.

State Y = (x, R or q, p, L); dY/dt = (v, [w] R, f, tau) with v = p / M, I(t) = R I_b R^T,
w = I(t)^-1 L, f = sum f_i + M g, tau = sum (r_i - x) x f_i (see :mod:`dynamics`).

Integrators (``INTEGRATORS[name]``):

- ``euler-matrix``: explicit Euler on (x, R, p, L), R a 3x3 matrix with no correction.
- ``euler-matrix-gs``: the same, with Gram-Schmidt re-orthonormalisation of R after each step.
- ``euler-quat``: explicit Euler on (x, q, p, L), q renormalised after each step.
- ``lie-euler``: momenta first (kick), then x and q with the new velocities; the rotation by the
  world-frame exponential map q+ = Exp(h w+) q with w+ = R I_b^-1 R^T L+ (current R).  Symplectic
  Euler for the translation (H = |p|^2 / 2M + V(x) is separable), but not for the rotation: the
  rotational energy 1/2 L . R I_b^-1 R^T L depends on both R and L, and w is taken at the *old* R
  (symplectic Euler would need it at the new one, an implicit step).  Torque-free, L is constant
  and the map is the explicit Euler step on the rotation group, the Lie-Euler method (hence the
  name), which differs from ``euler-quat`` only in how q + h q' is brought back to a unit
  quaternion (Exp instead of normalising, O(h^3) a step): the two drift alike (dzhanibekov,
  dt = 0.01 s: energy errors 0.4851 and 0.4854 after 10 s).  Called ``symplectic-euler`` before
  0.2.0; that name is still accepted (:data:`INTEGRATOR_ALIASES`).
- ``semi-implicit-explicit-gyro``: the engines' map in body-frame variables (MuJoCo ``Euler``,
  PyBullet multibody, DART): w_b+ = w_b + h I^-1 (tau_b - w_b x I w_b), v+ = v + h (f/M + g),
  x+ = x + h v+, q+ = q Exp(h w_b+).
- ``semi-implicit-implicit-gyro``: the same with the gyroscopic term linearised implicitly
  (MuJoCo ``implicit``/``implicitfast``/``discrete``, PyBullet maximal coordinates):
  J = I + h ([w_b] I - [I w_b]), w_b+ = w_b + J^-1 h (tau_b - w_b x I w_b).
- ``rk4``: classic fourth-order Runge-Kutta on (x, q, p, L), q renormalised after each step.
- ``symplectic-splitting``: the structure-preserving one (:mod:`splitting`, Dullweber, Leimkuhler &
  McLachlan 1997): the free rotation split into exactly solved rotations (a sphere's about L, then
  corrections about principal axes), composed symmetrically, the loads' impulses kick-drift-kick.
  Second order, symplectic, time-reversible, L exact torque-free, energy error bounded (no drift).
- ``implicit-midpoint`` (:mod:`lie_integrators`, Hairer, Lubich & Wanner): the implicit midpoint
  rule on the body momentum Pi (Euler's equations), solved by Newton, the orientation by the Cayley
  map of the midpoint body rate, the loads' impulses kick-drift-kick.  Second order,
  time-reversible; torque-free it keeps L exactly and the energy to round-off.
- ``rkmk4`` (:mod:`lie_integrators`, Munthe-Kaas 1998/1999): classic RK4 on (x, p, L) and the
  Runge-Kutta-Munthe-Kaas method (exponential map, dexp^-1) for q; loads at every stage as ``rk4``.
  Fourth order; L exact torque-free, energy drifts at O(h^4).

Loads are held constant over a step (every RK4 stage sees the same active set; a load's torque
arm is evaluated at the stage's state).

Each scheme is one numpy function of a step (``euler_matrix_step``, ``euler_quat_step``,
``lie_euler_step``, ``rk4_step``, ``semi_implicit_step``, ``splitting.splitting_step``,
``lie_integrators.implicit_midpoint_step``, ``lie_integrators.rkmk4_step``): this
module is the readable reference.  :func:`simulate` runs the same maps compiled (:mod:`compiled`: scalar loops, numba),
150 to 600 times faster; ``simulate(..., compiled=False)`` runs the numpy loops here, which
the compiled maps are tested against step by step (``tests/test_compiled_maps.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .conventions import Trajectory
from .dynamics import Wrench, rigid_body_derivative, wrench_function
from .problem import Problem
from .rotations import (gram_schmidt, matrix_from_quat, nearest_rotation, orthonormality_error,
                        quat_from_matrix, quat_from_rotvec, quat_multiply, quat_normalize, skew)
from .lie_integrators import implicit_midpoint_step, rkmk4_step
from .splitting import principal_frame, splitting_step


@dataclass(frozen=True)
class Integrator:
    """A named integrator.

    name : the name used on the command line and in results.json.
    order : its formal order of accuracy in dt.
    uses_matrix : True when it integrates R as a 3x3 matrix (reports orthonormality error).
    summary : one line for ``freebody list`` and reports.
    """

    name: str
    order: int
    uses_matrix: bool
    summary: str
    simulate: Callable[[Problem, float, int], Trajectory]


def initial_arrays(problem: Problem):
    """(M, I_b, I_b^-1, x0, q0, R0, p0, L0, v0, w0) in canonical frames (q0 normalised): the
    start of every reference integrator (also the compiled ones and the reference adapter's)."""
    body, init = problem.body, problem.initial
    M = body.mass
    I_b = body.I_body
    q0 = quat_normalize(init.quaternion_wxyz)
    R0 = matrix_from_quat(q0)
    w0 = np.array(init.angular_velocity, dtype=float)
    v0 = np.array(init.linear_velocity, dtype=float)
    L0 = R0 @ I_b @ R0.T @ w0
    return M, I_b, body.I_body_inv, np.array(init.position, float), q0, R0, M * v0, L0, v0, w0


def time_grid(dt: float, steps: int) -> np.ndarray:
    """t_k = k dt, k = 0 .. steps (s), shape (steps + 1,)."""
    return np.arange(steps + 1) * dt


# --- one step of each scheme (numpy, the lecture's formulas) ------------------------------------
# Each takes the step index k (it picks the loads of step k), the state after k steps and the run's
# constants, and returns the state after k + 1 steps.  ``reference_impl.compiled`` has the same
# functions as scalar loops, compiled; tests/test_compiled_maps.py checks them equal step by step.

def euler_matrix_step(k: int, x, R, p, L, dt: float, M: float, I_inv, Mg, wrench: Wrench,
                      gram: bool = False):
    """Explicit Euler on (x, R, p, L): x (3,) m world, R (3, 3) body -> world as integrated,
    p (3,) kg m/s world, L (3,) kg m^2/s world about the COM; Mg (3,) N the weight; optionally
    Gram-Schmidt on R after the step."""
    f, tau = wrench(k, x, R)
    w = R @ I_inv @ R.T @ L  # I(t)^-1 L with R as integrated
    x, R, p, L = x + dt * p / M, R + dt * skew(w) @ R, p + dt * (f + Mg), L + dt * tau
    if gram:
        R = gram_schmidt(R)
    return x, R, p, L


def euler_quat_step(k: int, x, q, p, L, dt: float, M: float, I_inv, g, wrench: Wrench):
    """Explicit Euler on (x, q, p, L) (q (4,) body -> world), q renormalised after the step."""
    dx, dq, dp, dL = rigid_body_derivative(k, x, q, p, L, M, I_inv, g, wrench)
    return x + dt * dx, quat_normalize(q + dt * dq), p + dt * dp, L + dt * dL


def lie_euler_step(k: int, x, q, p, L, dt: float, M: float, I_inv, g, wrench: Wrench):
    """Momenta first (kick), then x and q with the new velocities: q+ = Exp(h w+) q (world frame),
    w+ = R I_b^-1 R^T L+ with the current R (so, torque-free, explicit Euler on the rotation group,
    the Lie-Euler method: symplectic Euler for the translation only, see the module docstring)."""
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R)
    p = p + dt * (f + M * g)
    L = L + dt * tau
    x = x + dt * p / M
    w = R @ I_inv @ R.T @ L
    q = quat_normalize(quat_multiply(quat_from_rotvec(dt * w), q))
    return x, q, p, L


def rk4_step(k: int, x, q, p, L, dt: float, M: float, I_inv, g, wrench: Wrench):
    """Classic RK4 on (x, q, p, L), q renormalised after the step.  Every stage sees the loads of
    step k, their torque arms at the stage's state."""
    def d(x_, q_, p_, L_):
        return rigid_body_derivative(k, x_, q_, p_, L_, M, I_inv, g, wrench)
    k1 = d(x, q, p, L)
    k2 = d(*(y + 0.5 * dt * dy for y, dy in zip((x, q, p, L), k1)))
    k3 = d(*(y + 0.5 * dt * dy for y, dy in zip((x, q, p, L), k2)))
    k4 = d(*(y + dt * dy for y, dy in zip((x, q, p, L), k3)))
    x, q, p, L = (y + dt / 6.0 * (a + 2 * b + 2 * c + e)
                  for y, a, b, c, e in zip((x, q, p, L), k1, k2, k3, k4))
    return x, quat_normalize(q), p, L


def semi_implicit_step(k: int, x, q, v, w_b, dt: float, M: float, I_b, I_inv, g, wrench: Wrench,
                       implicit_gyro: bool = False):
    """The engines' map on (x, q, v, w_b): v (3,) m/s world, w_b (3,) rad/s body frame.
    w_b+ = w_b + h I^-1 (tau_b - w_b x I w_b) (explicit gyroscopic term) or, with
    ``implicit_gyro``, w_b+ = w_b + J^-1 h (tau_b - w_b x I w_b), J = I + h ([w_b] I - [I w_b]);
    then v+ = v + h (f/M + g), x+ = x + h v+, q+ = q Exp(h w_b+)."""
    x, v, w_b = semi_implicit_velocities(k, x, matrix_from_quat(q), v, w_b, dt, M, I_b, I_inv, g, wrench,
                                         implicit_gyro)
    q = quat_normalize(quat_multiply(q, quat_from_rotvec(dt * w_b)))
    return x, q, v, w_b


def semi_implicit_velocities(k: int, x, R, v, w_b, dt: float, M: float, I_b, I_inv, g, wrench: Wrench,
                             implicit_gyro: bool = False):
    """The velocity half of :func:`semi_implicit_step` at the orientation R (3, 3) body -> world:
    (x+, v+, w_b+), the orientation update left to the caller (DART's map, engine_maps, forms R
    and R+ its own way)."""
    f, tau = wrench(k, x, R)
    tau_b = R.T @ tau
    rhs = tau_b - np.cross(w_b, I_b @ w_b)
    if implicit_gyro:
        J = I_b + dt * (skew(w_b) @ I_b - skew(I_b @ w_b))
        w_b = w_b + np.linalg.solve(J, dt * rhs)
    else:
        w_b = w_b + dt * (I_inv @ rhs)
    v = v + dt * (f / M + g)
    x = x + dt * v
    return x, v, w_b


# --- whole runs, one Python loop over the steps --------------------------------------------------

def integrate_euler_matrix(problem: Problem, dt: float, steps: int, gram: bool = False):
    """Explicit Euler on (x, R, p, L) with R a 3x3 matrix, optionally Gram-Schmidt after each step.

    Returns the states as integrated: x (steps+1, 3) m world, R (steps+1, 3, 3) body -> world (it
    drifts from orthonormal without Gram-Schmidt), p (steps+1, 3) kg m/s world, L (steps+1, 3)
    kg m^2/s world about the COM.
    """
    M, I_b, I_inv, x, q, R, p, L, _, _ = initial_arrays(problem)
    wrench = wrench_function(problem, dt)
    Mg = M * problem.gravity
    xs = np.empty((steps + 1, 3)); Rs = np.empty((steps + 1, 3, 3))
    ps = np.empty((steps + 1, 3)); Ls = np.empty((steps + 1, 3))
    xs[0], Rs[0], ps[0], Ls[0] = x, R, p, L
    for k in range(steps):
        x, R, p, L = euler_matrix_step(k, x, R, p, L, dt, M, I_inv, Mg, wrench, gram)
        xs[k + 1], Rs[k + 1], ps[k + 1], Ls[k + 1] = x, R, p, L
    return xs, Rs, ps, Ls


def matrix_outputs(Rs: np.ndarray, Ls: np.ndarray, I_inv: np.ndarray):
    """What a matrix integrator reports of its integrated R (N, 3, 3) and L (N, 3): the quaternion
    (N, 4) of the nearest rotation, w = R I_b^-1 R^T L (N, 3) rad/s world, ||R^T R - 1||_F (N,)."""
    ws = np.einsum("nij,jk,nlk,nl->ni", Rs, I_inv, Rs, Ls)
    return quat_from_matrix(nearest_rotation(Rs)), ws, orthonormality_error(Rs)


def _simulate_euler_matrix(problem: Problem, dt: float, steps: int, gram: bool) -> Trajectory:
    xs, Rs, ps, Ls = integrate_euler_matrix(problem, dt, steps, gram)
    quats, ws, ortho = matrix_outputs(Rs, Ls, problem.body.I_body_inv)
    return Trajectory(time_grid(dt, steps), xs, quats, ps / problem.body.mass, ws, ortho)


_QUAT_STEPS = {"euler-quat": euler_quat_step, "lie-euler": lie_euler_step, "rk4": rk4_step,
               "symplectic-splitting": splitting_step, "implicit-midpoint": implicit_midpoint_step,
               "rkmk4": rkmk4_step}


def _simulate_quat(problem: Problem, dt: float, steps: int, scheme: str) -> Trajectory:
    """euler-quat, lie-euler, rk4, symplectic-splitting, implicit-midpoint and rkmk4: all on
    (x, q, p, L)."""
    M, I_b, I_inv, x, q, _, p, L, _, _ = initial_arrays(problem)
    wrench = wrench_function(problem, dt)
    g = problem.gravity
    step = _QUAT_STEPS[scheme]
    # what the step needs of the inertia: the splitting its principal frame, the others I_b^-1
    inertia = principal_frame(I_b) if scheme == "symplectic-splitting" else I_inv
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0] = x, q, p / M
    out.angular_velocity[0] = np.array(problem.initial.angular_velocity, float)
    for k in range(steps):
        x, q, p, L = step(k, x, q, p, L, dt, M, inertia, g, wrench)
        R = matrix_from_quat(q)
        out.position[k + 1], out.quaternion_wxyz[k + 1] = x, q
        out.linear_velocity[k + 1] = p / M
        out.angular_velocity[k + 1] = R @ I_inv @ R.T @ L
    out.t[:] = time_grid(dt, steps)
    return out


def _simulate_semi_implicit(problem: Problem, dt: float, steps: int, implicit_gyro: bool) -> Trajectory:
    M, I_b, I_inv, x, q, R, _, _, v, w = initial_arrays(problem)
    wrench = wrench_function(problem, dt)
    g = problem.gravity
    w_b = R.T @ w
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        x, q, v, w_b = semi_implicit_step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, wrench, implicit_gyro)
        out.position[k + 1], out.quaternion_wxyz[k + 1], out.linear_velocity[k + 1] = x, q, v
        out.angular_velocity[k + 1] = matrix_from_quat(q) @ w_b
    out.t[:] = time_grid(dt, steps)
    return out


INTEGRATORS: dict[str, Integrator] = {
    i.name: i for i in [
        Integrator("euler-matrix", 1, True, "explicit Euler, R as a 3x3 matrix, no correction",
                   lambda pb, dt, n: _simulate_euler_matrix(pb, dt, n, gram=False)),
        Integrator("euler-matrix-gs", 1, True, "explicit Euler, R re-orthonormalised by Gram-Schmidt",
                   lambda pb, dt, n: _simulate_euler_matrix(pb, dt, n, gram=True)),
        Integrator("euler-quat", 1, False, "explicit Euler on a renormalised quaternion",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "euler-quat")),
        Integrator("lie-euler", 1, False,
                   "momenta first (kick), then x and q by the exponential map; torque-free the Lie-Euler step",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "lie-euler")),
        Integrator("semi-implicit-explicit-gyro", 1, False,
                   "engines' map: body-frame w, explicit gyroscopic term (MuJoCo Euler, PyBullet, DART)",
                   lambda pb, dt, n: _simulate_semi_implicit(pb, dt, n, implicit_gyro=False)),
        Integrator("semi-implicit-implicit-gyro", 1, False,
                   "engines' map: body-frame w, gyroscopic term linearised implicitly (MuJoCo implicit)",
                   lambda pb, dt, n: _simulate_semi_implicit(pb, dt, n, implicit_gyro=True)),
        Integrator("rk4", 4, False, "classic Runge-Kutta 4 on (x, q, p, L), q renormalised",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "rk4")),
        Integrator("symplectic-splitting", 2, False,
                   "symplectic splitting: exact rotations about L and principal axes (Strang), loads kick-drift-kick",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "symplectic-splitting")),
        Integrator("implicit-midpoint", 2, False,
                   "implicit midpoint rule on the body momentum (Newton), q by Cayley, loads kick-drift-kick; "
                   "energy and L conserved torque-free",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "implicit-midpoint")),
        Integrator("rkmk4", 4, False,
                   "Runge-Kutta-Munthe-Kaas 4: classic RK4 on (x, p, L), q on the rotation group (dexp^-1)",
                   lambda pb, dt, n: _simulate_quat(pb, dt, n, "rkmk4")),
    ]
}


# Old integrator names -> current names.  A name changes when it was not honest (``symplectic-euler``
# is not symplectic for the rotation: it is the Lie-Euler step); the old one is kept here so that old
# commands (``--integrator symplectic-euler``), scripts and stored results and baselines keep working:
# :func:`simulate` and the reference engine take it, and results.json documents are read with their
# names brought up to date (:func:`freebody.results.document.upgrade_names`).
INTEGRATOR_ALIASES: dict[str, str] = {"symplectic-euler": "lie-euler"}


def canonical_integrator(name: str) -> str:
    """The current name of a reference integrator: ``name`` itself, or the name an old one
    (:data:`INTEGRATOR_ALIASES`) now stands for."""
    return INTEGRATOR_ALIASES.get(name, name)


def simulate(problem: Problem, integrator: str, dt: float, steps: int, compiled: bool = True,
             load_sampling: str = "per-stage") -> Trajectory:
    """Integrate ``problem`` for ``steps`` steps of ``dt`` with the named integrator.

    compiled : True (default): the compiled scalar maps of :mod:`compiled` (0.1-1.1 us a step);
        False: the numpy loops of this module (about 75 us a step), the readable reference they are
        tested against.  Both give the same trajectory to rounding.

    A blow-up is not an error here: its samples become inf/NaN and the harness calls it diverged.
    ``integrator`` may also name an engine-equivalent map (:data:`engine_maps.ENGINE_MAPS`) or be an
    old name (:data:`INTEGRATOR_ALIASES`).  load_sampling (:mod:`sampling`, "per-stage" or
    "per-step"): where an engine map of several stages evaluates the loads (the run's engine's
    declared rule); the reference integrators ignore it (loads at every stage, always).
    """
    integrator = canonical_integrator(integrator)
    if integrator not in INTEGRATORS:
        from .engine_maps import ENGINE_MAPS, simulate_engine_map  # imports this module
        if integrator in ENGINE_MAPS:
            return simulate_engine_map(problem, integrator, dt, steps, compiled, load_sampling)
    entry = INTEGRATORS[integrator]  # KeyError for an unknown name, either way
    if compiled:
        from .compiled import simulate_compiled  # numba loads on first use, not on import
        return simulate_compiled(problem, integrator, dt, steps)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return entry.simulate(problem, dt, steps)


__all__ = ["Integrator", "INTEGRATORS", "INTEGRATOR_ALIASES", "canonical_integrator", "simulate",
           "integrate_euler_matrix", "matrix_outputs",
           "euler_matrix_step", "euler_quat_step", "lie_euler_step", "rk4_step",
           "semi_implicit_step", "semi_implicit_velocities", "splitting_step", "implicit_midpoint_step",
           "rkmk4_step", "Wrench"]
