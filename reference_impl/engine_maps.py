"""Engine-equivalent maps: one step of an engine's integrator on a lone free body, as readable numpy.

The reference integrators (:mod:`integrators`) are the lecture's schemes.  An engine's integrator is
often one of them with a twist: a Lie-group correction, a torque applied outside an implicit step, a
truncated series.  Each function here is the one-step map of one engine integrator, written from
the engine's source (cited in its docstring), on the engine's own state variables, so that a run
of the map reproduces the engine's run to round-off; each was checked against the installed engine
(versions in :data:`ENGINE_MAPS` summaries and ``docs/engine-maps.md``; ``tests/test_engine_maps.py``
repeats the check).  They are selectable by name like the reference integrators::

    integrators.simulate(problem, "rkmk4-body", dt, steps)

Maps (``ENGINE_MAPS[name]``):

- ``rkmk4-body`` (MuJoCo 4.x ``RK4``): classic RK4 on (x, v, w_b) and the orientation by the
  Runge-Kutta-Munthe-Kaas method: fourth order.
- ``rk4-body-exp`` (MuJoCo 3.x ``RK4``, MJX ``RK4``): the same stages without the dexp^-1
  correction: the orientation is second order.
- ``implicit-gyro-split-torque`` (PyBullet ``maximal``, a btRigidBody): semi-implicit Euler with
  the gyroscopic term linearised implicitly in the body frame, the external torque's impulse added
  outside that implicit step, and the world-frame exponential map with Bullet's pi/4 cap per step.
- ``explicit-gyro-truncated-exp`` (DART ``semi-implicit``): the engines' semi-implicit Euler with the
  explicit gyroscopic term (reference ``semi-implicit-explicit-gyro``), but the orientation kept as
  DART's FreeJoint rotation vector and re-formed each step by DART's ``expMapRot``, whose series
  below 1e-3 rad, I + [phi] + [phi]^2 / 2, is not a rotation (an error of |phi|^3 / 6).
- ``explicit-gyro-rescaled-momentum`` (PhysX 5 as SAPIEN drives it, ``pgs`` and ``tgs``): semi-implicit
  Euler whose explicit gyroscopic step, taken after the torque impulse in the principal frame,
  rescales the body momentum to its old length; the world-frame exponential map.
- ``quat-rate-cayley-gyro`` (Newton 1.8 ``SolverSteel``): Drake's discrete map with the explicit
  gyroscopic kick replaced by energy-preserving Cayley (implicit-midpoint) microsteps.
- ``quat-rate-pose-velocity`` (Newton 1.8 ``SolverVBD``): the pose of Drake's discrete map, the
  velocities re-derived from the poses (w = Log(q+ q^-1) / h: shorter than the w that turned it).
- ``explicit-gyro-rescaled-torque-last`` (Newton 1.8 ``SolverKamino``): PhysX's rescaled explicit
  gyroscopic step taken from the step's start, the torque impulse added after it.
- ``explicit-gyro-regularised-exp`` (Brax ``generalized``): the reference
  ``semi-implicit-explicit-gyro`` whose body-frame exponential map divides by |w_b| + 1e-8.
- ``semi-implicit-no-gyro`` (Brax ``spring``): semi-implicit Euler with NO gyroscopic term, world
  w += h I_w^-1 tau (torque-free, w is constant in the world), q += h/2 (0, w) q renormalised.
- ``semi-implicit-no-gyro-projected`` (Brax ``positional``): that step, then the velocities
  re-derived from the positions, w = 2 vec(q+ q^-1) / h (shorter than the w that turned it).
- ``quat-rate-semi-implicit``, ``quat-rate-euler``, ``quat-rate-rk2``, ``quat-rate-rk3``,
  ``quat-rate-bs3``, ``quat-rate-rk5`` (Drake 1.51: the discrete MultibodyPlant and
  ``semi_explicit_euler``; ``explicit_euler``, ``runge_kutta2``, ``runge_kutta3``,
  ``bogacki_shampine3``, ``runge_kutta5`` in fixed-step mode): generic explicit schemes on Drake's
  state [q, x, w, v] with w in the world frame and the quaternion integrated as a vector through
  its rate 1/2 (0, w) q, never renormalised (the rotation is that of q / |q|).

Loads, as the adapters apply them (``adapters/loads.py``, :mod:`sampling`): a load's on/off timing
is per step (the active set of step k is constant over the step).  Within a step, the multi-stage
maps (:data:`MULTI_STAGE_MAPS`: ``rkmk4-body``, ``rk4-body-exp``, ``quat-rate-rk2/rk3/bs3/rk5``) have
two variants, chosen by ``load_sampling``:

- ``per-stage`` (the default): the wrench of step k (force (3,) N world, torque about the COM (3,)
  N m world) is evaluated at every stage's own state (x_i, R(q_i)): a body couple is R(q_i) tau_b,
  a body-point force's arm R(q_i) b, a world-point force's arm p - x_i.  That is how the adapters
  now drive MuJoCo (body couples in ``qfrc_applied[3:6]``, point forces through ``mjcb_control``
  at every RK4 stage), Drake (a system computing the wrench from the plant's state), MJX on cases
  without point forces, and the reference ``rk4`` / ``rkmk4``.
- ``per-step``: the wrench is evaluated ONCE, at the state at the start of step k (arms from x_k
  and R_k), and held over the step: every stage sees the same world force and world torque.  That
  is what an adapter that writes a world wrench before each step gives a multi-stage scheme
  (Newton's mujoco-rk4, MJX with point forces; Drake's adapter before issue 26);
  such a run is first order under a load that turns with the body.

Identification compares each run with the variant of its engine's declared rule
(``Adapter.run_load_sampling``).  The one-stage maps evaluate the wrench once, at the step's start,
under either rule (PyBullet ``applyExternalForce``/``applyExternalTorque``, DART ``addExtForce``/
``addExtTorque``, PhysX, Newton, Brax): their two variants are the same trajectory.

Each map is one numpy function of a step, ``*_step(k, state..., dt, constants..., wrench)``, with
``wrench(k, x, R)`` from :func:`dynamics.wrench_function`.  :mod:`compiled_engine_maps` has the same
maps as compiled scalar code (numba), which :func:`integrators.simulate` runs;
``tests/test_engine_maps.py`` checks the two equal step by step to a few ulps.
"""
from __future__ import annotations

import math

import numpy as np

from .conventions import Trajectory
from .dynamics import Wrench, wrench_function
from .integrators import Integrator, semi_implicit_velocities
from .lie_integrators import RK4_B, RK4_C  # the classic tableau: MuJoCo's RK4_A subdiagonal and RK4_B
from .problem import Problem
from .sampling import LOAD_SAMPLING_PER_STAGE, LOAD_SAMPLING_PER_STEP, check_load_sampling
from .rotations import matrix_from_quat, quat_conjugate, quat_from_matrix, quat_from_rotvec, quat_multiply, skew

__all__ = ["ENGINE_MAPS", "MULTI_STAGE_MAPS", "LOAD_SAMPLING_PER_STAGE", "LOAD_SAMPLING_PER_STEP",
           "simulate_engine_map", "rkmk4_body_step", "rk4_body_exp_step",
           "implicit_gyro_split_torque_step", "explicit_gyro_truncated_exp_step", "dexpinv",
           "mujoco_quat_integrate", "bullet_integrate_rotation", "bullet_matrix_from_quat",
           "bullet_quat_from_matrix", "dart_exp_map_rot", "dart_log_map",
           "principal_frame", "explicit_gyro_rescaled_momentum_step", "physx_principal_frame",
           "physx_gyroscopic_velocity", "physx_integrate_rotation",
           "DRAKE_TABLEAUS", "DRAKE_SEMI_IMPLICIT", "drake_time_derivatives", "drake_explicit_rk_step",
           "drake_semi_explicit_euler_step", "NEWTON_STEPS", "newton_quat_rate_integrate",
           "steel_gyroscopic_velocity", "quat_rate_cayley_gyro_step", "quat_rate_pose_velocity_step",
           "kamino_quat_exp", "explicit_gyro_rescaled_torque_last_step"]

# MuJoCo's mjMINVAL (mjmodel.h): below it a norm counts as zero; a quaternion whose norm is within
# it of 1 is not rescaled (mju_normalize4).
MJ_MINVAL = 1e-15
# dexp^-1's coefficient c(t) = (1 - (t/2) cot(t/2)) / t^2 is 1/12 + t^2/720 + ...; below this angle
# the closed form cancels catastrophically and its limit 1/12 is exact to rounding (t^2/720 < 2e-15).
DEXPINV_SERIES_BELOW = 1e-6
# Bullet's ANGULAR_MOTION_THRESHOLD (btTransformUtil.h): 0.5 * SIMD_HALF_PI, the largest rotation
# of one step; a faster body turns by this much per step, however fast it spins.
BULLET_ANGULAR_MOTION_THRESHOLD = 0.25 * math.pi
# Bullet's integrateTransform uses a Taylor series of sin(a h / 2) / a below this |w| (rad/s).
BULLET_SERIES_BELOW = 0.001
BULLET_SIMD_EPSILON = float(np.finfo(float).eps)  # SIMD_EPSILON in double precision: DBL_EPSILON
# DART's EPSILON_EXPMAP_THETA (dart/math/Geometry.cpp): expMapRot's series below this angle (rad).
DART_EXPMAP_SERIES_BELOW = 1.0e-3



# --- MuJoCo RK4 ----------------------------------------------------------------------------------

def mujoco_quat_integrate(q: np.ndarray, w: np.ndarray, h: float, normalize_first: bool) -> np.ndarray:
    """mju_quatIntegrate (MuJoCo ``engine_util_spatial.c``): q * Exp(h w), w (3,) rad/s in the body
    frame, q (4,) wxyz body -> world.

    As MuJoCo forms it: axis = w / |w| (mju_normalize3: times 1/|w|; (1, 0, 0) when |w| < mjMINVAL),
    angle = h |w|, Exp = (cos(angle/2), axis sin(angle/2)) (mju_axisAngle2Quat; the identity at angle
    0).  ``normalize_first``: MuJoCo 4.0 (and late 3.x) normalise q, then multiply; MuJoCo 3.1 and
    MJX (``mjx/_src/math.py`` quat_integrate) multiply, then normalise.  mju_normalize4 rescales
    only when |q| differs from 1 by more than mjMINVAL.
    """
    norm = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    axis = np.array([1.0, 0.0, 0.0]) if norm < MJ_MINVAL else w * (1.0 / norm)
    angle = h * norm
    if angle == 0.0:
        dq = np.array([1.0, 0.0, 0.0, 0.0])
    else:
        dq = np.concatenate([[np.cos(0.5 * angle)], axis * np.sin(0.5 * angle)])
    if normalize_first:
        return quat_multiply(_mj_normalize4(q), dq)
    return _mj_normalize4(quat_multiply(q, dq))


def _mj_normalize4(q: np.ndarray) -> np.ndarray:
    """mju_normalize4: q times 1/|q| when |q| is more than mjMINVAL from 1, else q as it is."""
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q * (1.0 / norm) if abs(norm - 1.0) > MJ_MINVAL else q


def dexpinv(u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """dexp^-1_u(w) on so(3) for q(s) = q0 Exp(u(s)) with body-frame rate w: u' = dexp^-1_u(w).

    u : (3,) rad, the rotation vector from the step's start (body frame).  w : (3,) rad/s body frame.
    Returns (3,) rad/s: w + 1/2 u x w + c(|u|) u x (u x w), c(t) = (1 - (t/2) cot(t/2)) / t^2 (the
    closed form of the series 1/12 + t^2/720 + ...; 1/12 below DEXPINV_SERIES_BELOW).  MuJoCo 4.0's
    RK4 passes each stage's rate through it (the Runge-Kutta-Munthe-Kaas correction).
    """
    t = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
    c = 1.0 / 12.0 if t < DEXPINV_SERIES_BELOW else (1.0 - 0.5 * t / np.tan(0.5 * t)) / (t * t)
    return w + 0.5 * np.cross(u, w) + c * np.cross(u, np.cross(u, w))


def _mj_acceleration(q, w_b, M: float, I_b, I_inv, g, f, tau):
    """MuJoCo's qacc of a lone free body whose COM is its origin, at stage state (q, w_b):
    (linear (3,) m/s^2 world = f / M + g, angular (3,) rad/s^2 body = I^-1 (R^T tau - w_b x I w_b)),
    f (3,) N and tau (3,) N m world, held over the step; R = R(q) (normalised, as mj_kinematics)."""
    R = matrix_from_quat(q)
    return f / M + g, I_inv @ (R.T @ tau - np.cross(w_b, I_b @ w_b))


def mujoco_rk4_step(x, q, v, w_b, dt: float, M: float, I_b, I_inv, g, f, tau,
                    munthe_kaas: bool, normalize_first: bool, stage_wrench=None):
    """One ``mj_RungeKutta(m, d, 4)`` (MuJoCo ``engine_forward.c``) of a lone free body.

    State in MuJoCo's free-joint variables: x (3,) m world (qpos[0:3]), q (4,) wxyz body -> world
    (qpos[3:7]), v (3,) m/s world (qvel[0:3]), w_b (3,) rad/s BODY frame (qvel[3:6]).  f (3,) N and
    tau (3,) N m world: the wrench at the step's start.  ``stage_wrench``: None (per-step loads,
    ``xfrc_applied`` written before the step: the same f, tau at every stage), or a function
    (x_i, R_i) -> (f, tau) evaluated at each later stage's state (per-stage loads: the adapter's
    ``mjcb_control`` or ``qfrc_applied``), with the stage position x_i = x + h (c_i v_{i-1}) as
    ``mj_integratePos`` forms it.

    Stage 1 is the start; stage i = 2, 3, 4 starts from the start moved by h c_i (c = 1/2, 1/2, 1)
    times stage i-1's slopes (mj_integratePos for x and q, qvel0 + h c_i qacc for the velocities):
    x_i = x + h (c_i v_{i-1}), q_i = quatIntegrate(q, c_i K_{i-1}, h), v_i, w_i likewise, and its
    slopes are (v_i, K_i, qacc_i).  ``munthe_kaas`` (MuJoCo 4.0, changelog 4.0.0 item 5): the
    orientation slope K_i = dexp^-1(h c_i K_{i-1}, w_i) (K_1 = w_b), Runge-Kutta-Munthe-Kaas, fourth
    order.  Without it (MuJoCo 3.x, MJX): K_i = w_i, second order in the orientation.  The step
    (mj_advance): v+ = v + h sum b_i a_i, w_b+ likewise, x+ = x + h sum b_i v_i,
    q+ = quatIntegrate(q, sum b_i K_i, h).  Sums in MuJoCo's order: b_1 X_1 + b_2 X_2 + ....
    """
    h = dt
    a1, alpha1 = _mj_acceleration(q, w_b, M, I_b, I_inv, g, f, tau)
    vs, Ks, accs, alphas = [v], [w_b], [a1], [alpha1]  # slopes of the stages so far
    for c in RK4_C:
        dK = c * Ks[-1]
        q_i = mujoco_quat_integrate(q, dK, h, normalize_first)
        if stage_wrench is not None:  # the loads at the stage's state (x_i, R(q_i))
            f, tau = stage_wrench(x + h * (c * vs[-1]), matrix_from_quat(q_i))
        v_i = v + h * (c * accs[-1])
        w_i = w_b + h * (c * alphas[-1])
        a_i, alpha_i = _mj_acceleration(q_i, w_i, M, I_b, I_inv, g, f, tau)
        vs.append(v_i)
        Ks.append(dexpinv(h * dK, w_i) if munthe_kaas else w_i)
        accs.append(a_i)
        alphas.append(alpha_i)
    b1, b2, b3, b4 = RK4_B
    v_new = v + h * (b1 * accs[0] + b2 * accs[1] + b3 * accs[2] + b4 * accs[3])
    w_new = w_b + h * (b1 * alphas[0] + b2 * alphas[1] + b3 * alphas[2] + b4 * alphas[3])
    x_new = x + h * (b1 * vs[0] + b2 * vs[1] + b3 * vs[2] + b4 * vs[3])
    q_new = mujoco_quat_integrate(q, b1 * Ks[0] + b2 * Ks[1] + b3 * Ks[2] + b4 * Ks[3], h,
                                  normalize_first)
    return x_new, q_new, v_new, w_new


def _stage_wrench(k: int, wrench: Wrench, per_stage: bool):
    """For a multi-stage map: the function (x_i, R_i) -> wrench of step k at a stage's state, or
    None when the loads are sampled per step (held at the step's start's value)."""
    return (lambda x_i, R_i: wrench(k, x_i, R_i)) if per_stage else None


def rkmk4_body_step(k: int, x, q, v, w_b, dt: float, M: float, I_b, I_inv, g, wrench: Wrench,
                    per_stage: bool = True):
    """``rkmk4-body``: MuJoCo 4.x ``RK4`` (verified on MuJoCo 4.0.0).

    Classic RK4 on (x, v, w_b) and, for the orientation, the Runge-Kutta-Munthe-Kaas method (Iserles,
    Munthe-Kaas, Norsett and Zanna 2000, "Lie-group methods", section 5): the stage orientations
    q_i = q Exp(h c_i K_{i-1}) and the slopes K_i = dexp^-1(h c_i K_{i-1}, w_i) in the body frame,
    the step q+ = q Exp(h sum b_i K_i).  Fourth order.  Source: ``mj_RungeKutta``
    (``engine_forward.c``), MuJoCo changelog 4.0.0 item 5; see :func:`mujoco_rk4_step`.

    x (3,) m world, q (4,) wxyz body -> world, v (3,) m/s world, w_b (3,) rad/s body frame;
    I_b, I_inv (3, 3) body frame; g (3,) m/s^2; wrench(k, x, R) of step k, evaluated at every
    stage's state (``per_stage``, how the MuJoCo adapter applies loads) or at the step's start only.
    """
    f, tau = wrench(k, x, matrix_from_quat(q))
    return mujoco_rk4_step(x, q, v, w_b, dt, M, I_b, I_inv, g, f, tau, munthe_kaas=True,
                           normalize_first=True, stage_wrench=_stage_wrench(k, wrench, per_stage))


def rk4_body_exp_step(k: int, x, q, v, w_b, dt: float, M: float, I_b, I_inv, g, wrench: Wrench,
                      per_stage: bool = True):
    """``rk4-body-exp``: MuJoCo 3.x ``RK4`` and MJX ``RK4`` (verified on MuJoCo 3.1.6 and MJX 3.17
    float64).

    The RK4 stages of :func:`rkmk4_body_step` with the body rates combined as they are (K_i = w_i,
    no dexp^-1): a Lie-group RK4 that composes the stage rates in one exponential, q+ = q Exp(h
    sum b_i w_i).  Fourth order in the velocities but only second order in the orientation (the
    missing 1/2 u x w terms are O(h^2) per unit time).  Sources: ``mj_RungeKutta``
    (``engine_forward.c``, MuJoCo 3.x), ``rungekutta4`` (``mjx/_src/forward.py``); their quaternion
    update multiplies, then normalises (3.1's mju_quatIntegrate, MJX's quat_integrate).
    Arguments as :func:`rkmk4_body_step`.
    """
    f, tau = wrench(k, x, matrix_from_quat(q))
    return mujoco_rk4_step(x, q, v, w_b, dt, M, I_b, I_inv, g, f, tau, munthe_kaas=False,
                           normalize_first=False, stage_wrench=_stage_wrench(k, wrench, per_stage))


# --- PyBullet maximal coordinates (btRigidBody) --------------------------------------------------

def principal_frame(I_body: np.ndarray):
    """As the PyBullet adapter builds the body: I_body = V diag(moments) V^T (numpy eigh, V made
    right-handed).  Returns (moments (3,) kg m^2 ascending, V (3, 3) principal axes as columns in the
    body frame, q_V (4,) wxyz the principal frame's orientation in the body frame)."""
    moments, V = np.linalg.eigh(np.asarray(I_body, dtype=float))
    if np.linalg.det(V) < 0:
        V[:, 2] = -V[:, 2]
    return moments, V, quat_from_matrix(V)


def solve33(J: np.ndarray, b: np.ndarray) -> np.ndarray:
    """btMatrix3x3::solve33 (Bullet ``LinearMath/btMatrix3x3.h``, from Box2D): J^-1 b by Cramer's rule
    on J's columns (1/det taken only when |det| > SIMD_EPSILON)."""
    c1, c2, c3 = J[:, 0], J[:, 1], J[:, 2]
    det = np.dot(c1, np.cross(c2, c3))
    if abs(det) > BULLET_SIMD_EPSILON:
        det = 1.0 / det
    return np.array([det * np.dot(b, np.cross(c2, c3)), det * np.dot(c1, np.cross(b, c3)),
                     det * np.dot(c1, np.cross(c2, b))])


def bullet_matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """btMatrix3x3::setRotation (``LinearMath/btMatrix3x3.h``): the basis (3, 3) of a quaternion q
    (4,) wxyz, with s = 2 / |q|^2 (q need not be unit)."""
    w, x, y, z = q
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return np.array([[1.0 - (yy + zz), xy - wz, xz + wy],
                     [xy + wz, 1.0 - (xx + zz), yz - wx],
                     [xz - wy, yz + wx, 1.0 - (xx + yy)]])


def bullet_quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """btMatrix3x3::getRotation (``LinearMath/btMatrix3x3.h``): the quaternion (4,) wxyz of a basis
    (3, 3) (Shoemake's method: the trace, or the largest diagonal entry i)."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    xyzw = np.zeros(4)
    if trace > 0.0:
        s = np.sqrt(trace + 1.0)
        xyzw[3] = s * 0.5
        s = 0.5 / s
        xyzw[0:3] = [(m[2, 1] - m[1, 2]) * s, (m[0, 2] - m[2, 0]) * s, (m[1, 0] - m[0, 1]) * s]
    else:
        if m[0, 0] < m[1, 1]:
            i = 2 if m[1, 1] < m[2, 2] else 1
        else:
            i = 2 if m[0, 0] < m[2, 2] else 0
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
        xyzw[i] = s * 0.5
        s = 0.5 / s
        xyzw[3] = (m[k, j] - m[j, k]) * s
        xyzw[j] = (m[j, i] + m[i, j]) * s
        xyzw[k] = (m[k, i] + m[i, k]) * s
    return np.array([xyzw[3], xyzw[0], xyzw[1], xyzw[2]])


def bullet_quat_rotate(q: np.ndarray, u: np.ndarray) -> np.ndarray:
    """quatRotate (``LinearMath/btQuaternion.h``): u (3,) turned by q (4,) wxyz, as q (0, u) q^-1."""
    p = quat_multiply(quat_multiply(q, np.array([0.0, u[0], u[1], u[2]])), quat_conjugate(q))
    return p[1:]


def bullet_integrate_rotation(B: np.ndarray, w: np.ndarray, h: float) -> np.ndarray:
    """The rotation part of btTransformUtil::integrateTransform (``LinearMath/btTransformUtil.h``):
    the world-frame exponential map q+ = normalize(dq * q), q = getRotation(B), w (3,) rad/s world;
    returns the new basis setRotation(q+) (3, 3).

    dq = (cos(a h / 2), w sin(a h / 2) / a) with a = |w| (0 when |w|^2 <= SIMD_EPSILON), capped at
    ANGULAR_MOTION_THRESHOLD / h: past the cap the body turns pi/4 a step and dq (axis still w,
    scaled by sin(a h/2)/a) is no unit quaternion until the product is normalised (safeNormalize:
    times 1/|q|).  Below a = 0.001, sin(a h / 2) / a is its series h/2 - h^3 a^2 / 48 (Bullet's
    0.020833333333)."""
    a2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    a = np.sqrt(a2) if a2 > BULLET_SIMD_EPSILON else 0.0
    if a * h > BULLET_ANGULAR_MOTION_THRESHOLD:
        a = BULLET_ANGULAR_MOTION_THRESHOLD / h
    if a < BULLET_SERIES_BELOW:
        axis = w * (0.5 * h - (h * h * h) * 0.020833333333 * a * a)
    else:
        axis = w * (np.sin(0.5 * a * h) / a)
    dq = np.array([np.cos(a * h * 0.5), axis[0], axis[1], axis[2]])
    p = quat_multiply(dq, bullet_quat_from_matrix(B))
    p = p * (1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]))
    return bullet_matrix_from_quat(p)


def implicit_gyro_split_torque_step(k: int, x, B, v, w, dt: float, M: float, moments, Vt, g,
                                    wrench: Wrench):
    """``implicit-gyro-split-torque``: PyBullet ``maximal`` (a btRigidBody with the default
    BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY; verified on PyBullet 3.2.7).

    Semi-implicit (symplectic) Euler whose gyroscopic term is one Newton step of the implicit
    body-frame Euler equation (Bullet's "implicit body" gyroscopic force), with the external torque's
    impulse h I^-1 tau added beside it, outside the implicit step (the reference
    ``semi-implicit-implicit-gyro`` puts it inside, through J^-1): torque-free the two are the same
    map.  The rotation by the world-frame exponential map, capped at pi/4 a step.

    State in Bullet's variables: x (3,) m COM world; B (3, 3) the basis of the body's PRINCIPAL
    frame (principal -> world, B = R_body V; Bullet stores a btTransform's rotation as this matrix
    and converts it to a quaternion where it needs one); v (3,) m/s world; w (3,) rad/s world.
    moments (3,) kg m^2 the principal moments, Vt (3, 3) = V^T (R_body = B V^T), g (3,) m/s^2.

    One stepSimulation (btDiscreteDynamicsWorld::internalSingleStepSimulation), zero damping, no
    contacts:
      applyGravity: total force F = f + M g, total torque tau (the applied loads of the step);
      btSequentialImpulseConstraintSolver::convertBodies / initSolverBody:
        external impulses dv = F (1/M) h and dw = tau I_w^-1 h, I_w^-1 = B diag(1/I) B^T
        (btRigidBody::updateInertiaTensor);
        btRigidBody::computeGyroscopicImpulseImplicit_Body(h): q = getRotation(B),
          w_b = quatRotate(q^-1, w), J = I + h ([w_b] I - [I w_b]),
          w_b' = w_b - J^-1 (h w_b x I w_b) (solve33), dw += quatRotate(q, w_b') - w;
      writeBackBodies: v+ = v + dv, w+ = w + dw;
      integrateTransforms: x+ = x + h v+, B+ = bullet_integrate_rotation(B, w+, h).
    """
    h = dt
    f, tau = wrench(k, x, B @ Vt)
    dv = (f + M * g) * (1.0 / M) * h
    I_w_inv = (B * (1.0 / moments)) @ B.T
    dw = (tau @ I_w_inv) * h
    q = bullet_quat_from_matrix(B)
    I = np.diag(moments)
    w_b = bullet_quat_rotate(quat_conjugate(q), w)
    I_w_b = I @ w_b
    J = I + (skew(w_b) @ I - skew(I_w_b)) * h
    w_b_new = w_b - solve33(J, h * np.cross(w_b, I_w_b))
    dw = dw + (bullet_quat_rotate(q, w_b_new) - w)
    v = v + dv
    w = w + dw
    return x + h * v, bullet_integrate_rotation(B, w, h), v, w


# --- DART (dartpy) -------------------------------------------------------------------------------

def dart_exp_map_rot(phi: np.ndarray) -> np.ndarray:
    """dart::math::expMapRot (``dart/math/Geometry.cpp``): R (3, 3) of a rotation vector phi (3,) rad.

    Rodrigues, I + sin(t)/t [phi] + (1 - cos t)/t^2 [phi]^2, for t = |phi| >= 1e-3; below, the
    truncated series I + [phi] + 1/2 [phi]^2, which is not orthogonal (R^T R - I = O(t^4), the
    rotation off by O(t^3 / 6) rad: up to 1.7e-10 rad)."""
    t = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    S = skew(phi)
    S2 = S @ S
    if t < DART_EXPMAP_SERIES_BELOW:
        return np.eye(3) + S + 0.5 * S2
    return np.eye(3) + (np.sin(t) / t) * S + ((1.0 - np.cos(t)) / (t * t)) * S2


def _eigen_quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Eigen's Quaternion from a 3x3 matrix (``Eigen/src/Geometry/Quaternion.h``,
    quaternionbase_assign_impl; Shoemake's method, orthogonality not assumed), as wxyz (4,)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        t = np.sqrt(tr + 1.0)
        w = 0.5 * t
        t = 0.5 / t
        return np.array([w, (m[2, 1] - m[1, 2]) * t, (m[0, 2] - m[2, 0]) * t, (m[1, 0] - m[0, 1]) * t])
    i = 0
    if m[1, 1] > m[0, 0]:
        i = 1
    if m[2, 2] > m[i, i]:
        i = 2
    j = (i + 1) % 3
    k = (j + 1) % 3
    t = np.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
    q = np.zeros(4)
    q[1 + i] = 0.5 * t
    t = 0.5 / t
    q[0] = (m[k, j] - m[j, k]) * t
    q[1 + j] = (m[j, i] + m[i, j]) * t
    q[1 + k] = (m[k, i] + m[i, k]) * t
    return q


def dart_log_map(R: np.ndarray) -> np.ndarray:
    """dart::math::logMap(Matrix3d) (``dart/math/Geometry.cpp``): Eigen::AngleAxisd(R).angle() *
    axis(), a rotation vector (3,) rad with angle in [0, pi]: the quaternion of R (Eigen's), then
    angle = 2 atan2(|vec|, |w|), axis = +-vec / |vec| (sign of w); (0, 0, 0) when vec = 0."""
    q = _eigen_quat_from_matrix(R)
    n = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if n == 0.0:
        return np.zeros(3)
    angle = 2.0 * np.atan2(n, abs(q[0]))
    return angle * (q[1:] / n if q[0] >= 0.0 else -q[1:] / n)


def explicit_gyro_truncated_exp_step(k: int, x, phi, v, w_b, dt: float, M: float, I_b, I_inv, g,
                                     wrench: Wrench):
    """``explicit-gyro-truncated-exp``: DART's ``World::step`` on a lone FreeJoint body (verified
    on DART 6.20.0, dartpy).

    Semi-implicit Euler with the explicit gyroscopic term, the reference
    ``semi-implicit-explicit-gyro`` (w_b+ = w_b + h I^-1 (tau_b - w_b x I w_b), v+ = v + h (f/M + g),
    x+ = x + h v+, R+ = R Exp(h w_b+)), except that the orientation lives in DART's FreeJoint
    positions, a rotation vector phi, and every rotation matrix is DART's expMapRot: R = expMapRot(phi)
    and R+ = R expMapRot(h w_b+), phi+ = logMap(R+) (FreeJoint::integratePositions,
    ``dart/dynamics/FreeJoint.cpp``; ``convertToTransform``/``convertToPositions``).  expMapRot's
    truncated series below 1e-3 rad (:func:`dart_exp_map_rot`) makes R and the increment
    slightly non-orthogonal: a per-step error of (h |w|)^3 / 6 whenever h |w| < 1e-3 (so at dt 0.001
    for |w| < 1 rad/s), and of |phi|^3 / 6 while the body is within 1e-3 rad of its identity pose.
    That explains DART's departure from ``semi-implicit-explicit-gyro`` (2e-7 rad on
    gazebo_boxes_simple, 2.6e-8 on body_torque_spinup at dt = 0.001).

    State: x (3,) m COM world, phi (3,) rad the FreeJoint rotation vector (body -> world), v (3,) m/s
    world, w_b (3,) rad/s body frame; I_b, I_inv (3, 3) body frame; g (3,) m/s^2.  The world torque
    enters as R^T tau with R = expMapRot(phi) (DART turns a world torque and force into its body
    frame with its transform).
    """
    R = dart_exp_map_rot(phi)
    x, v, w_b = semi_implicit_velocities(k, x, R, v, w_b, dt, M, I_b, I_inv, g, wrench)
    phi = dart_log_map(R @ dart_exp_map_rot(dt * w_b))
    return x, phi, v, w_b


# --- PhysX 5 (SAPIEN) ----------------------------------------------------------------------------

def physx_principal_frame(I_body: np.ndarray):
    """As the SAPIEN adapter gives PhysX the body: (moments (3,) kg m^2, V (3, 3) principal axes as
    columns in the body frame, q_V (4,) wxyz).  A diagonal I_body keeps its moments in its order and
    V = 1 (no rounding from an eigen-decomposition); otherwise :func:`principal_frame` (numpy eigh,
    V proper)."""
    I_body = np.asarray(I_body, dtype=float)
    if not np.any(I_body - np.diag(np.diag(I_body))):
        return np.diag(I_body).copy(), np.eye(3), np.array([1.0, 0.0, 0.0, 0.0])
    return principal_frame(I_body)


def physx_integrate_rotation(q: np.ndarray, w: np.ndarray, h: float) -> np.ndarray:
    """The rotation update of PhysX's integrateCore (``DyBodyCoreIntegrator.h``; TGS's
    integrateCoreStep and copyBackBodies compose the same rotation): q+ = normalize(dq * q) with
    dq = (cos(h |w| / 2), w sin(h |w| / 2) / |w|), w (3,) rad/s WORLD frame, q (4,) wxyz; q as it
    is when |w| = 0.  (PGS also caps |w| at 1e7 rad/s here: not modelled, far beyond any run.)"""
    a2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    if a2 == 0.0:
        return q
    a = np.sqrt(a2)
    s, c = np.sin(0.5 * h * a) / a, np.cos(0.5 * h * a)
    p = quat_multiply(np.array([0.0, w[0] * s, w[1] * s, w[2] * s]), q) + c * q
    return p * (1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]))


def physx_gyroscopic_velocity(q: np.ndarray, w: np.ndarray, moments: np.ndarray, h: float) -> np.ndarray:
    """PhysX's gyroscopic term (``copyToSolverBodyData``, ``DyRigidBodyToSolverBody.cpp``; TGS:
    ``copyToSolverBodyDataStep``), PxRigidBodyFlag::eENABLE_GYROSCOPIC_FORCES: in the principal
    frame, w_b = R^T w, L = I w_b, L' = L - h w_b x L rescaled to |L| (0 if L' = 0), and
    w+ = w + R (I^-1 L' - w_b).  q (4,) wxyz principal frame -> world, w (3,) rad/s world,
    moments (3,) kg m^2.  Explicit Euler on Euler's equations, with the body momentum's length kept."""
    R = matrix_from_quat(q)
    w_b = R.T @ w
    L = moments * w_b
    L_new = L - h * np.cross(w_b, L)
    n = np.sqrt(L_new @ L_new)
    L_new = L_new * (np.sqrt(L @ L) / n) if n > 0.0 else np.zeros(3)
    return w + R @ (L_new / moments - w_b)


def explicit_gyro_rescaled_momentum_step(k: int, x, q, v, w, dt: float, M: float, moments, Vt, g,
                                         wrench: Wrench):
    """``explicit-gyro-rescaled-momentum``: PhysX 5's step of a lone rigid dynamic body, PGS and TGS
    alike (SAPIEN ``pgs``/``tgs``; PhysX 5.3.1, verified on SAPIEN 3.0.3 in float32).

    One ``PxScene::simulate`` of a body with no constraints, zero damping, no velocity clamp:
      ``BodySim::updateForces``: the applied force and torque, stored as accelerations when added
        (f / M and I_w^-1 tau, I_w^-1 = R diag(1/I) R^T at the pose of the call: the step's
        start), become velocity changes v += h f / M, w += h I_w^-1 tau;
      ``bodyCoreComputeUnconstrainedVelocity``: v += h g;
      the gyroscopic term, :func:`physx_gyroscopic_velocity`;
      ``integrateCore``: x+ = x + h v+, q+ = :func:`physx_integrate_rotation` (q, w+, h).
    The reference ``semi-implicit-explicit-gyro`` uses w_b at the step's start in the gyroscopic
    term and does not rescale L': torque-free the two differ by the rescaling, a factor
    1 / sqrt(1 + h^2 |w_b x L|^2 / |L|^2) per step, which keeps |L| and bounds the spin where the
    plain explicit term blows up.

    State in PhysX's variables: x (3,) m COM world; q (4,) wxyz the PRINCIPAL frame -> world
    (body2World; R_body = R(q) V^T); v (3,) m/s world; w (3,) rad/s world.  moments (3,) kg m^2,
    Vt (3, 3) = V^T, g (3,) m/s^2; wrench(k, x, R_body) at the step's start.
    """
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R @ Vt)
    v = v + h * (f * (1.0 / M))
    w = w + h * (R @ ((R.T @ tau) / moments))
    v = v + h * g
    w = physx_gyroscopic_velocity(q, w, moments, h)
    return x + h * v, physx_integrate_rotation(q, w, h), v, w


# --- Drake (pydrake MultibodyPlant) --------------------------------------------------------------

# The Butcher tableaus of Drake's explicit integrators (``systems/analysis``), by map name:
# (A as its rows below the diagonal, b).  Stage i starts from y + h sum_j A[i][j] K_j; the step is
# y + h sum_i b_i K_i (the propagated solution; the embedded error estimates are not used).
DRAKE_TABLEAUS: dict[str, tuple[tuple[tuple[float, ...], ...], tuple[float, ...]]] = {
    # ExplicitEulerIntegrator
    "quat-rate-euler": (((),), (1.0,)),
    # RungeKutta2Integrator: Heun's method (the explicit trapezoid rule)
    "quat-rate-rk2": (((), (1.0,)), (0.5, 0.5)),
    # RungeKutta3Integrator: Kutta's third-order method (its 2nd-order midpoint only estimates errors)
    "quat-rate-rk3": (((), (0.5,), (-1.0, 2.0)), (1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0)),
    # BogackiShampine3Integrator: Bogacki-Shampine 3(2), 4 stages (the 4th serves the error estimate)
    "quat-rate-bs3": (((), (0.5,), (0.0, 0.75), (2.0 / 9.0, 1.0 / 3.0, 4.0 / 9.0)),
                      (2.0 / 9.0, 1.0 / 3.0, 4.0 / 9.0, 0.0)),
    # RungeKutta5Integrator: Dormand-Prince 5(4), the fifth-order solution propagated
    "quat-rate-rk5": (((), (1.0 / 5.0,), (3.0 / 40.0, 9.0 / 40.0),
                       (44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0),
                       (19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0),
                       (9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0,
                        -5103.0 / 18656.0),
                       (35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0,
                        11.0 / 84.0)),
                      (35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0,
                       11.0 / 84.0, 0.0)),
}
# Drake's discrete MultibodyPlant (time_step > 0) and its SemiExplicitEulerIntegrator: one map.
DRAKE_SEMI_IMPLICIT = "quat-rate-semi-implicit"


def drake_time_derivatives(y: np.ndarray, M: float, I_b: np.ndarray, g: np.ndarray,
                           f: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """MultibodyPlant's time derivatives (13,) of a lone body on its QuaternionFloatingJoint
    (Drake 1.51: ``QuaternionFloatingMobilizer``), body frame origin at the COM.

    y (13,): Drake's state [q (4) wxyz AS STORED (never renormalised), x (3) m world, w (3) rad/s
    world, v (3) m/s world].  f (3,) N, tau (3,) N m about the COM, world: the applied spatial
    force, held over the step.  Returns [qdot, xdot, wdot, vdot]:

    - qdot = N(q) w = 1/2 (0, w) * q (``AngularVelocityToQuaternionRateMatrix``): linear in q, so a
      stored q of norm s stays of norm s under the exact flow, and a scheme's step scales it;
    - xdot = v;
    - wdot = I_w^-1 (tau - w x I_w w), I_w = R I_b R^T with R the rotation of q / |q| (Drake's
      RotationMatrix of a quaternion divides by |q|^2): the forward dynamics of M(q) vdot = tau_ext
      - C(q, v) v for the mass matrix diag(I_w, M 1) of a body whose origin is its COM;
    - vdot = f / M + g.
    """
    q, w = y[0:4], y[7:10]
    R = matrix_from_quat(q)
    I_w = R @ I_b @ R.T
    qdot = 0.5 * quat_multiply(np.array([0.0, w[0], w[1], w[2]]), q)
    wdot = np.linalg.solve(I_w, tau - np.cross(w, I_w @ w))
    return np.concatenate([qdot, y[10:13], wdot, f / M + g])


def drake_explicit_rk_step(k: int, y: np.ndarray, dt: float, M: float, I_b, g, wrench: Wrench,
                           tableau, per_stage: bool = True) -> np.ndarray:
    """``quat-rate-euler``, ``-rk2``, ``-rk3``, ``-bs3``, ``-rk5``: one fixed step of Drake's explicit
    Runge-Kutta integrators on a continuous MultibodyPlant (time_step 0), verified on Drake 1.51.1.

    Classic explicit Runge-Kutta on Drake's own state y (13,) (see :func:`drake_time_derivatives`):
    stage i's state y + h sum_j A_ij K_j (added term by term, j ascending), K_i its derivatives,
    the step y + h sum_i b_i K_i.  The quaternion is integrated as a vector in R^4 through its rate
    1/2 (0, w) q and never renormalised (Drake's integrators are generic ODE solvers): the stored
    norm drifts (explicit Euler: by sqrt(1 + h^2 |w|^2 / 4) a step) while the rotation is that of
    q / |q|.  The wrench of step k is evaluated at every stage's state (``per_stage``: arms and
    R from that stage's x_i and q_i / |q_i|, a system whose output is computed from the current
    pose), or once, at the step's start, and held for every stage (the applied-force input port
    fixed before each step).  Sources:
    ``explicit_euler_integrator.h``, ``runge_kutta2_integrator.h``, ``runge_kutta3_integrator.h``,
    ``bogacki_shampine3_integrator.h``, ``runge_kutta5_integrator.h`` (``systems/analysis``).
    """
    A, b = tableau
    h = dt
    f, tau = wrench(k, y[4:7], matrix_from_quat(y[0:4]))
    K = []
    for i in range(len(b)):
        y_i = y
        for j, a in enumerate(A[i]):
            if a != 0.0:
                y_i = y_i + (h * a) * K[j]
        if per_stage and i > 0:
            f, tau = wrench(k, y_i[4:7], matrix_from_quat(y_i[0:4]))
        K.append(drake_time_derivatives(y_i, M, I_b, g, f, tau))
    out = y
    for b_i, K_i in zip(b, K):
        if b_i != 0.0:
            out = out + (h * b_i) * K_i
    return out


def drake_semi_explicit_euler_step(k: int, y: np.ndarray, dt: float, M: float, I_b, g,
                                   wrench: Wrench) -> np.ndarray:
    """``quat-rate-semi-implicit``: Drake's discrete MultibodyPlant step of a lone free body (any
    discrete contact solver: with no contact SAP and TAMSI both return the free-motion velocities)
    and its SemiExplicitEulerIntegrator (continuous plant, fixed step); verified on Drake 1.51.1.

    Velocities first, then positions with the new velocities: (w, v)+ = (w, v) + h (wdot, vdot) at
    the step's start, q+ = q + h 1/2 (0, w+) q, x+ = x + h v+.  The quaternion is never
    renormalised: its stored norm grows by sqrt(1 + h^2 |w+|^2 / 4) a step (1.41 after 10 s of
    dzhanibekov at dt 0.01), while the rotation is that of q / |q|.  Unlike the reference
    ``semi-implicit-explicit-gyro`` (q Exp(h w_b+)) the rotation of a step is 2 atan(h |w+| / 2),
    not h |w+|.  Sources: ``DiscreteUpdateManager``/``SapDriver`` (q_next = q + h N(q) v_next) and
    ``semi_explicit_euler_integrator.h``.  y (13,) as :func:`drake_time_derivatives`.
    """
    h = dt
    f, tau = wrench(k, y[4:7], matrix_from_quat(y[0:4]))
    d = drake_time_derivatives(y, M, I_b, g, f, tau)
    w = y[7:10] + h * d[7:10]
    v = y[10:13] + h * d[10:13]
    q = y[0:4] + h * (0.5 * quat_multiply(np.array([0.0, w[0], w[1], w[2]]), y[0:4]))
    return np.concatenate([q, y[4:7] + h * v, w, v])


# --- Newton 1.8 (Warp): SolverSteel, SolverVBD, SolverKamino --------------------------------------
# (SolverSemiImplicit, SolverFeatherstone and SolverXPBD step a lone body by Drake's discrete map,
# ``quat-rate-semi-implicit``: their renormalised q turns as Drake's unnormalised one does.)

# Steel's gyroscopic update (``_gyroscopic_velocity``, newton/_src/solvers/steel/kernels.py): at most
# this many microsteps a step, this many fixed-point iterations a microstep, stopped once the
# iterate's change delta has delta . A delta <= STEEL_GYRO_ENERGY_RTOL u . A u.
STEEL_GYRO_MAX_MICROSTEPS = 32
STEEL_GYRO_ITERATIONS = 8
STEEL_GYRO_ENERGY_RTOL = 1.0e-12
# Kamino's quat_exp (kamino/_src/core/math.py) takes the series (1, v / 2) below float32's epsilon.
KAMINO_EXP_SERIES_BELOW = float(np.finfo(np.float32).eps)


def newton_quat_rate_integrate(q: np.ndarray, w: np.ndarray, h: float) -> np.ndarray:
    """Newton's orientation update (``integrate_rigid_body`` of SolverSemiImplicit, SolverXPBD and
    SolverVBD; Featherstone's and Steel's ``jcalc_integrate`` of a FREE joint): q+ = normalize(q +
    h 1/2 (0, w) q), w (3,) rad/s WORLD frame, q (4,) wxyz.  A step turns by 2 atan(h |w| / 2)."""
    p = q + (0.5 * h) * quat_multiply(np.array([0.0, w[0], w[1], w[2]]), q)
    return p * (1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]))


def steel_gyroscopic_velocity(I_b: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
    """Steel's ``_gyroscopic_velocity``: the body rate after the gyroscopic part of a step, by
    energy-preserving Cayley updates (implicit midpoint on Euler's equations).

    u (3,) rad/s BODY frame: the rate after the torque impulse, w_b + h I^-1 tau_b (Steel's
    predictor with its explicit gyroscopic kick taken out again).  With A = I_b / max diag(I_b)
    (Steel's Cholesky-rebuilt effective inertia, equal to I_b with no armature) the step is cut into
    m = clamp(ceil(2 h sqrt(u.A u tr A^-1)), 1, 32) microsteps of h / m; each solves
    (A - S) w = (A + S) u, S = (h / 2m) [A (u + w) / 2]x, by fixed-point iteration from w = u (at
    most 8 iterations, stopped when the change delta has delta.A delta <= 1e-12 u.A u).  Every
    iterate keeps w.A w = u.A u (a Cayley transform): the kinetic energy of the rotation is kept,
    and the converged w is the implicit midpoint rule A (w - u) / h_m = (A w_mid) x w_mid."""
    scale = max(I_b[0, 0], I_b[1, 1], I_b[2, 2])
    A = I_b / scale
    speed = np.sqrt(max(float(u @ A @ u) * float(np.trace(np.linalg.inv(A))), 0.0))
    m = int(min(max(math.ceil(2.0 * abs(h) * speed), 1), STEEL_GYRO_MAX_MICROSTEPS))
    h_m = h / m
    w = u
    for _ in range(m):
        u = w
        energy = u @ A @ u
        for _ in range(STEEL_GYRO_ITERATIONS):
            S = (0.5 * h_m) * skew(A @ (0.5 * (u + w)))
            candidate = np.linalg.solve(A - S, (A + S) @ u)
            delta = candidate - w
            w = candidate
            if delta @ A @ delta <= STEEL_GYRO_ENERGY_RTOL * energy:
                break
    return w


def quat_rate_cayley_gyro_step(k: int, x, q, v, w, dt: float, M: float, I_b, I_inv, g, wrench: Wrench):
    """``quat-rate-cayley-gyro``: Newton 1.8 ``SolverSteel`` on a lone FREE body (verified on
    Newton 1.8.0 in float32; ``jcalc_integrate`` and ``apply_free_root_velocity_corrections`` in
    newton/_src/solvers/steel/kernels.py, no constraint rows, damping set to 0).

    Drake's discrete map (``quat-rate-semi-implicit``) with the explicit gyroscopic kick replaced:
    v+ = v + h (f/M + g); in the body frame at the step's start, u = w_b + h I^-1 tau_b, then
    w_b+ = :func:`steel_gyroscopic_velocity` (I_b, u, h) (energy-preserving implicit midpoint);
    w+ = R w_b+; x+ = x + h v+; q+ = :func:`newton_quat_rate_integrate` (q, w+, h).  Torque-free
    the rotational kinetic energy is kept to round-off.  State: x (3,) m COM world, q (4,) wxyz
    body -> world, v (3,) m/s world, w (3,) rad/s world."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R)
    v = v + h * (f / M + g)
    u = R.T @ w + h * (I_inv @ (R.T @ tau))
    w = R @ steel_gyroscopic_velocity(I_b, u, h)
    return x + h * v, newton_quat_rate_integrate(q, w, h), v, w


def quat_rate_pose_velocity_step(k: int, x, q, v, w, dt: float, M: float, I_b, I_inv, g, wrench: Wrench):
    """``quat-rate-pose-velocity``: Newton 1.8 ``SolverVBD`` on a lone free body (verified on Newton
    1.8.0 in float32; ``forward_step_rigid_bodies`` and ``update_body_velocity`` in
    newton/_src/solvers/vbd/rigid_vbd_kernels.py, an AVBD solve with no rows in between).

    The pose of Drake's discrete map (``quat-rate-semi-implicit``, as SolverSemiImplicit forms it:
    v' = v + h (f/M + g), w_b' = w_b + h I^-1 (tau_b - w_b x I w_b), x+ = x + h v', q+ = normalize(q
    + h 1/2 (0, w') q)), then the velocities re-derived from the poses as VBD does: v+ = (x+ - x) /
    h = v' and w+ = Log(q+ q^-1) / h, the rotation vector of the step's turn over h.  That turn is
    2 atan(h |w'| / 2) about w', so w+ = w' 2 atan(h |w'| / 2) / (h |w'|): every step shortens the
    spin by about (h |w'|)^2 / 12, which drains the rotational energy.  (Formed here in closed form;
    the engine's float32 finite differences round far worse.)  State as :func:`quat_rate_cayley_gyro_step`."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R)
    v = v + h * (f / M + g)
    w_b = R.T @ w
    w = R @ (w_b + h * (I_inv @ (R.T @ tau - np.cross(w_b, I_b @ w_b))))
    q_next = newton_quat_rate_integrate(q, w, h)
    a = h * np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if a > 0.0:
        w = w * (2.0 * math.atan(0.5 * a) / a)
    return x + h * v, q_next, v, w


def kamino_quat_exp(phi: np.ndarray) -> np.ndarray:
    """Kamino's ``quat_exp``: the unit quaternion (4,) wxyz of a rotation vector phi (3,) rad,
    (cos(|phi|/2), sin(|phi|/2) phi / |phi|); (1, phi / 2) (not normalised) at or below
    KAMINO_EXP_SERIES_BELOW."""
    n = np.sqrt(phi @ phi)
    if n > KAMINO_EXP_SERIES_BELOW:
        s = math.sin(0.5 * n) / n
        return np.array([math.cos(0.5 * n), s * phi[0], s * phi[1], s * phi[2]])
    return np.array([1.0, 0.5 * phi[0], 0.5 * phi[1], 0.5 * phi[2]])


def explicit_gyro_rescaled_torque_last_step(k: int, x, q, v, w, dt: float, M: float, I_b, I_inv, g,
                                            wrench: Wrench):
    """``explicit-gyro-rescaled-torque-last``: Newton 1.8 ``SolverKamino`` (integrator "euler") on a
    lone free body (verified on Newton 1.8.0 in float32; ``euler_semi_implicit_with_logmap``,
    ``compute_body_twist_update_with_eom``, ``compute_gyroscopic_torque`` in
    newton/_src/solvers/kamino/_src/, no constraints, angular_velocity_damping 0).

    In the world frame with I_w = R I_b R^T at the step's start: L = I_w w, L' = L - h w x L
    rescaled to |L| (0 if L' = 0); w+ = w + h I_w^-1 ((L' - L) / h + tau); v+ = v + h (g + f/M);
    x+ = x + h v+; q+ = Exp(h w+) q (:func:`kamino_quat_exp`, not renormalised).  Torque-free this
    is PhysX's map (``explicit-gyro-rescaled-momentum``: the same rescaled explicit step of L,
    formed in the principal frame); under a torque PhysX adds the impulse first and takes the
    gyroscopic step on the result, Kamino takes the gyroscopic step from the step's start and adds
    the impulse last.  State as :func:`quat_rate_cayley_gyro_step`."""
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R)
    I_w = R @ I_b @ R.T
    L = I_w @ w
    L_new = L - h * np.cross(w, L)
    n = np.sqrt(L_new @ L_new)
    L_new = L_new * (np.sqrt(L @ L) / n) if n > 0.0 else np.zeros(3)
    v = v + h * (g + f / M)
    w = w + h * ((R @ I_inv @ R.T) @ ((L_new - L) / h + tau))
    return x + h * v, quat_multiply(kamino_quat_exp(h * w), q), v, w


# --- Brax 0.14 (generalized, spring, positional pipelines) ----------------------------------------

# brax.generalized.integrator._integrate_q_free adds this to |w_b| before dividing by it (rad/s).
BRAX_ANGULAR_NORM_EPS = 1e-8


def brax_integrate_free_rotation(q: np.ndarray, w_b: np.ndarray, h: float) -> np.ndarray:
    """The rotation of Brax's free joint in ``generalized`` (``_integrate_q_free``,
    brax/generalized/integrator.py): n = |w_b| + 1e-8, axis = w_b / n, a = h n,
    q+ = normalize(q * (cos(a / 2), axis sin(a / 2))), w_b (3,) rad/s BODY frame, q (4,) wxyz.

    The axis is not a unit vector (|axis| = |w_b| / n): after the normalisation the step turns by
    2 atan(|w_b| / n tan(a / 2)) = h |w_b| + h^3 |w_b|^2 1e-8 / 6 + ..., the exact exponential map
    but for a bias of 4e-14 rad a step at |w| = 5 rad/s and h = 0.01 (1e3 times less at h = 0.001)."""
    n = np.sqrt(w_b[0] * w_b[0] + w_b[1] * w_b[1] + w_b[2] * w_b[2]) + BRAX_ANGULAR_NORM_EPS
    axis = w_b / n
    a = h * n
    s = np.sin(0.5 * a)
    p = quat_multiply(q, np.array([np.cos(0.5 * a), axis[0] * s, axis[1] * s, axis[2] * s]))
    return p * (1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]))


def explicit_gyro_regularised_exp_step(k: int, x, q, v, w_b, dt: float, M: float, I_b, I_inv, g,
                                       wrench: Wrench):
    """``explicit-gyro-regularised-exp``: Brax's ``generalized`` pipeline on a lone free body
    (verified on Brax 0.14.2, float64; ``generalized/pipeline.py`` step, ``dynamics.forward``,
    ``integrator.integrate``).

    Semi-implicit Euler in the free joint's (q, qd): the bias forces by recursive Newton-Euler (the
    gyroscopic term, explicit), qd+ = qd + h M^-1 (tau - bias), x+ = x + h v+, and the rotation by
    :func:`brax_integrate_free_rotation`: the reference ``semi-implicit-explicit-gyro``
    (w_b+ = w_b + h I^-1 (tau_b - w_b x I w_b), v+ = v + h (f/M + g)) with the regularised
    exponential map.  (M^-1 comes from Newton-Schulz iterations warm-started at the previous step's
    inverse, Brax's matrix_inv_iterations = 10: converged to round-off on a lone body.)

    State: x (3,) m COM world, q (4,) wxyz body -> world, v (3,) m/s world, w_b (3,) rad/s body
    frame (Brax's qd[3:6]); I_b, I_inv (3, 3) body frame; g (3,) m/s^2.
    """
    x, v, w_b = semi_implicit_velocities(k, x, matrix_from_quat(q), v, w_b, dt, M, I_b, I_inv, g, wrench)
    return x, brax_integrate_free_rotation(q, w_b, dt), v, w_b


def brax_quat_rate_integrate(q: np.ndarray, w: np.ndarray, h: float) -> np.ndarray:
    """The rotation of Brax's ``spring`` and ``positional`` integrators (``integrate``,
    ``integrate_xdd``): q+ = normalize(q + (0, w h / 2) q), w (3,) rad/s WORLD frame, q (4,) wxyz.
    A step turns by 2 atan(h |w| / 2) about w."""
    p = q + quat_multiply(np.array([0.0, w[0], w[1], w[2]]) * (0.5 * h), q)
    return p * (1.0 / np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3]))


def semi_implicit_no_gyro_step(k: int, x, q, v, w, dt: float, M: float, I_b, I_inv, g, wrench: Wrench,
                               project: bool = False):
    """``semi-implicit-no-gyro`` (Brax ``spring``) and, with ``project``,
    ``semi-implicit-no-gyro-projected`` (Brax ``positional``); verified on Brax 0.14.2, float64
    (``spring/pipeline.py``, ``spring/integrator.py``; ``positional/pipeline.py``,
    ``positional/integrator.py``).

    Semi-implicit Euler on the world-frame velocities of the COM frame WITHOUT a gyroscopic term:
    w+ = w + h I_w^-1 tau (I_w^-1 = R I_b^-1 R^T at the step's start; Brax forms it from the
    principal moments), v+ = v + h (g + f/M), x+ = x + h v+, q+ = :func:`brax_quat_rate_integrate`
    (q, w+, h).  Torque-free, w never changes in the world: the body turns about a fixed world axis
    whatever its inertia (no precession, no Dzhanibekov flip), and L = I_w w is not conserved.
    (Brax's velocity damping exp(d h), d = ang/vel_damping = 0, is a factor 1.)

    ``project``: ``positional`` then re-derives the velocities from the positions
    (``project_xd``): v+ = (x+ - x) / h, dq = q+ q^-1, w+ = sign(dq_w) 2 vec(dq) / h.  Since
    dq = (1, h w / 2) / sqrt(1 + h^2 |w|^2 / 4), that is w+ / sqrt(1 + h^2 |w+|^2 / 4): |w| shrinks
    every step and the rotational energy drains.  Formed as Brax forms it, by differences of the
    positions (their round-off, about eps / (h |w|) of w a step, is part of the map).

    State: x (3,) m COM world, q (4,) wxyz body -> world, v (3,) m/s world, w (3,) rad/s WORLD frame
    (Brax's x_i and xd_i); I_b, I_inv (3, 3) body frame; g (3,) m/s^2.
    """
    h = dt
    R = matrix_from_quat(q)
    f, tau = wrench(k, x, R)
    w_next = w + h * (R @ (I_inv @ (R.T @ tau)))
    v_next = v + h * (g + f / M)
    x_next = x + h * v_next
    q_next = brax_quat_rate_integrate(q, w_next, h)
    if project:
        v_next = (x_next - x) / h
        dq = quat_multiply(q_next, quat_conjugate(q))
        w_next = (2.0 * dq[1:] / h) * (1.0 if dq[0] >= 0.0 else -1.0)
    return x_next, q_next, v_next, w_next


__all__ += ["BRAX_ANGULAR_NORM_EPS", "brax_integrate_free_rotation", "explicit_gyro_regularised_exp_step",
            "brax_quat_rate_integrate", "semi_implicit_no_gyro_step"]


# --- whole runs -----------------------------------------------------------------------------------

def initial_as_given(problem: Problem):
    """(M, I_b, I_inv, x0, q0, v0, w0, g): the problem's constants and initial state as given (q0 not
    renormalised: an engine takes it as written)."""
    body, init = problem.body, problem.initial
    return (float(body.mass), np.array(body.I_body, float), body.I_body_inv,
            np.array(init.position, float), np.array(init.quaternion_wxyz, float),
            np.array(init.linear_velocity, float), np.array(init.angular_velocity, float),
            np.array(problem.gravity, float))


def _simulate_mujoco_rk4(problem: Problem, dt: float, steps: int, munthe_kaas: bool,
                         per_stage: bool = True) -> Trajectory:
    M, I_b, I_inv, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    step = rkmk4_body_step if munthe_kaas else rk4_body_exp_step
    w_b = matrix_from_quat(q).T @ w
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        x, q, v, w_b = step(k, x, q, v, w_b, dt, M, I_b, I_inv, g, wrench, per_stage)
        out.position[k + 1], out.quaternion_wxyz[k + 1], out.linear_velocity[k + 1] = x, q, v
        out.angular_velocity[k + 1] = matrix_from_quat(q) @ w_b
    out.t[:] = np.arange(steps + 1) * dt
    return out


def _simulate_bullet_maximal(problem: Problem, dt: float, steps: int) -> Trajectory:
    M, I_b, _, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    moments, V, q_V = principal_frame(I_b)
    q_V_inv = quat_conjugate(q_V)
    B = bullet_matrix_from_quat(quat_multiply(q, q_V))  # resetBasePositionAndOrientation
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        x, B, v, w = implicit_gyro_split_torque_step(k, x, B, v, w, dt, M, moments, V.T, g, wrench)
        out.position[k + 1], out.linear_velocity[k + 1], out.angular_velocity[k + 1] = x, v, w
        # getBasePositionAndOrientation: getRotation of the basis; the adapter: q_body = q_p q_V^-1
        out.quaternion_wxyz[k + 1] = quat_multiply(bullet_quat_from_matrix(B), q_V_inv)
    out.t[:] = np.arange(steps + 1) * dt
    return out


def _simulate_dart(problem: Problem, dt: float, steps: int) -> Trajectory:
    M, I_b, I_inv, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    phi = dart_log_map(matrix_from_quat(q))  # Joint::setTransform -> convertToPositions
    w_b = dart_exp_map_rot(phi).T @ w
    out = Trajectory.empty(steps + 1)
    out.position[0], out.linear_velocity[0], out.angular_velocity[0] = x, v, w
    out.quaternion_wxyz[0] = quat_from_rotvec(phi)  # the adapter reads the positions back so
    for k in range(steps):
        x, phi, v, w_b = explicit_gyro_truncated_exp_step(k, x, phi, v, w_b, dt, M, I_b, I_inv, g, wrench)
        out.position[k + 1], out.linear_velocity[k + 1] = x, v
        out.quaternion_wxyz[k + 1] = quat_from_rotvec(phi)
        out.angular_velocity[k + 1] = dart_exp_map_rot(phi) @ w_b
    out.t[:] = np.arange(steps + 1) * dt
    return out


def _simulate_physx(problem: Problem, dt: float, steps: int) -> Trajectory:
    M, I_b, _, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    moments, V, q_V = physx_principal_frame(I_b)
    q_V_inv = quat_conjugate(q_V)
    q_p = quat_multiply(q, q_V)  # setGlobalPose: body2World = actor2World * cmassLocalPose
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        x, q_p, v, w = explicit_gyro_rescaled_momentum_step(k, x, q_p, v, w, dt, M, moments, V.T, g, wrench)
        out.position[k + 1], out.linear_velocity[k + 1], out.angular_velocity[k + 1] = x, v, w
        out.quaternion_wxyz[k + 1] = quat_multiply(q_p, q_V_inv)  # the actor pose SAPIEN reports
    out.t[:] = np.arange(steps + 1) * dt
    return out


def _simulate_drake(problem: Problem, dt: float, steps: int, name: str,
                    per_stage: bool = True) -> Trajectory:
    """A Drake map on Drake's state y = [q, x, w, v] from the case's state as written (q not
    renormalised); the trajectory holds q / |q| as the adapter reads it (the stored norm drifts)."""
    M, I_b, _, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    y = np.concatenate([q, x, w, v])
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        if name == DRAKE_SEMI_IMPLICIT:
            y = drake_semi_explicit_euler_step(k, y, dt, M, I_b, g, wrench)
        else:
            y = drake_explicit_rk_step(k, y, dt, M, I_b, g, wrench, DRAKE_TABLEAUS[name], per_stage)
        out.quaternion_wxyz[k + 1] = y[0:4] / np.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2] + y[3] * y[3])
        out.position[k + 1], out.angular_velocity[k + 1], out.linear_velocity[k + 1] = y[4:7], y[7:10], y[10:13]
    out.t[:] = np.arange(steps + 1) * dt
    return out


# The Newton maps' steps on (x, q, v, w) in canonical variables (q body -> world, w world), by name
NEWTON_STEPS = {"quat-rate-cayley-gyro": quat_rate_cayley_gyro_step,
                "quat-rate-pose-velocity": quat_rate_pose_velocity_step,
                "explicit-gyro-rescaled-torque-last": explicit_gyro_rescaled_torque_last_step}


def _simulate_newton(problem: Problem, dt: float, steps: int, name: str) -> Trajectory:
    """A Newton map from the case's state as written (q not renormalised, as the adapter writes it)."""
    M, I_b, I_inv, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    step = NEWTON_STEPS[name]
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0], out.angular_velocity[0] = x, q, v, w
    for k in range(steps):
        x, q, v, w = step(k, x, q, v, w, dt, M, I_b, I_inv, g, wrench)
        out.position[k + 1], out.quaternion_wxyz[k + 1] = x, q
        out.linear_velocity[k + 1], out.angular_velocity[k + 1] = v, w
    out.t[:] = np.arange(steps + 1) * dt
    return out


def _simulate_brax(problem: Problem, dt: float, steps: int, name: str) -> Trajectory:
    """A Brax map from the case's state as written; ``explicit-gyro-regularised-exp`` carries the
    body-frame w (Brax's qd) and reports R w_b, the others the world-frame w (Brax's xd_i)."""
    M, I_b, I_inv, x, q, v, w, g = initial_as_given(problem)
    wrench = wrench_function(problem, dt)
    generalized = name == "explicit-gyro-regularised-exp"
    if generalized:
        w = matrix_from_quat(q).T @ w
    out = Trajectory.empty(steps + 1)
    out.position[0], out.quaternion_wxyz[0], out.linear_velocity[0] = x, q, v
    out.angular_velocity[0] = problem.initial.angular_velocity
    for k in range(steps):
        if generalized:
            x, q, v, w = explicit_gyro_regularised_exp_step(k, x, q, v, w, dt, M, I_b, I_inv, g, wrench)
        else:
            x, q, v, w = semi_implicit_no_gyro_step(k, x, q, v, w, dt, M, I_b, I_inv, g, wrench,
                                                    project=name == "semi-implicit-no-gyro-projected")
        out.position[k + 1], out.quaternion_wxyz[k + 1], out.linear_velocity[k + 1] = x, q, v
        out.angular_velocity[k + 1] = matrix_from_quat(q) @ w if generalized else w
    out.t[:] = np.arange(steps + 1) * dt
    return out


# Compiled kernel of each map (compiled_engine_maps.simulate_compiled_engine_map's switch)
# (the multi-stage maps, MULTI_STAGE_MAPS, take a 4th argument: per_stage, default True)
_NUMPY_RUNS = {
    "rkmk4-body": lambda pb, dt, n, per_stage=True: _simulate_mujoco_rk4(pb, dt, n, True, per_stage),
    "rk4-body-exp": lambda pb, dt, n, per_stage=True: _simulate_mujoco_rk4(pb, dt, n, False, per_stage),
    "implicit-gyro-split-torque": _simulate_bullet_maximal,
    "explicit-gyro-truncated-exp": _simulate_dart,
    **{name: (lambda pb, dt, n, per_stage=True, name=name: _simulate_drake(pb, dt, n, name, per_stage))
       for name in (DRAKE_SEMI_IMPLICIT, *DRAKE_TABLEAUS)},
    "explicit-gyro-rescaled-momentum": _simulate_physx,
    **{name: (lambda pb, dt, n, name=name: _simulate_newton(pb, dt, n, name)) for name in NEWTON_STEPS},
    **{name: (lambda pb, dt, n, name=name: _simulate_brax(pb, dt, n, name))
       for name in ("explicit-gyro-regularised-exp", "semi-implicit-no-gyro", "semi-implicit-no-gyro-projected")},
}

# The engine-equivalent maps, by name: candidates for scheme identification beside the reference
# integrators (``integrators.INTEGRATORS``), not integrators of the reference engine.  ``order``:
# of the orientation.
ENGINE_MAPS: dict[str, Integrator] = {
    i.name: i for i in [
        Integrator("rkmk4-body", 4, False,
                   "RK4 with the Munthe-Kaas dexp^-1 correction, body-frame w (MuJoCo 4.0 RK4)",
                   _NUMPY_RUNS["rkmk4-body"]),
        Integrator("rk4-body-exp", 2, False,
                   "RK4 stages on body-frame w, orientation without dexp^-1: 2nd order (MuJoCo 3.x, MJX RK4)",
                   _NUMPY_RUNS["rk4-body-exp"]),
        Integrator("implicit-gyro-split-torque", 1, False,
                   "implicit gyroscopic step, torque impulse outside it, capped world exp map "
                   "(PyBullet 3.2.7 maximal)", _NUMPY_RUNS["implicit-gyro-split-torque"]),
        Integrator("explicit-gyro-truncated-exp", 1, False,
                   "semi-implicit Euler, explicit gyroscopic term, DART's rotation-vector positions "
                   "and truncated expMapRot (DART 6.20)", _NUMPY_RUNS["explicit-gyro-truncated-exp"]),
        Integrator("explicit-gyro-rescaled-momentum", 1, False,
                   "semi-implicit Euler, explicit gyroscopic term with |L_body| rescaled, world exp map "
                   "(PhysX 5 / SAPIEN 3.0, PGS and TGS)", _NUMPY_RUNS["explicit-gyro-rescaled-momentum"]),
        Integrator(DRAKE_SEMI_IMPLICIT, 1, False,
                   "semi-implicit Euler on world w, quaternion rate 1/2 (0, w) q, never renormalised "
                   "(Drake 1.51 discrete plant, semi_explicit_euler)", _NUMPY_RUNS[DRAKE_SEMI_IMPLICIT]),
        Integrator("quat-rate-euler", 1, False,
                   "explicit Euler on Drake's (q, x, w, v), quaternion never renormalised "
                   "(Drake 1.51 explicit_euler)", _NUMPY_RUNS["quat-rate-euler"]),
        Integrator("quat-rate-rk2", 2, False,
                   "Heun (explicit trapezoid) on Drake's (q, x, w, v), quaternion never renormalised "
                   "(Drake 1.51 runge_kutta2)", _NUMPY_RUNS["quat-rate-rk2"]),
        Integrator("quat-rate-rk3", 3, False,
                   "Kutta's RK3 on Drake's (q, x, w, v), quaternion never renormalised "
                   "(Drake 1.51 runge_kutta3, fixed step)", _NUMPY_RUNS["quat-rate-rk3"]),
        Integrator("quat-rate-bs3", 3, False,
                   "Bogacki-Shampine 3 on Drake's (q, x, w, v), quaternion never renormalised "
                   "(Drake 1.51 bogacki_shampine3, fixed step)", _NUMPY_RUNS["quat-rate-bs3"]),
        Integrator("quat-rate-rk5", 5, False,
                   "Dormand-Prince 5 on Drake's (q, x, w, v), quaternion never renormalised "
                   "(Drake 1.51 runge_kutta5, fixed step)", _NUMPY_RUNS["quat-rate-rk5"]),
        Integrator("quat-rate-cayley-gyro", 1, False,
                   "semi-implicit Euler on world w, gyroscopic part by energy-preserving Cayley "
                   "(implicit-midpoint) microsteps, q + h/2 (0, w) q renormalised (Newton 1.8 Steel)",
                   _NUMPY_RUNS["quat-rate-cayley-gyro"]),
        Integrator("quat-rate-pose-velocity", 1, False,
                   "the pose of quat-rate-semi-implicit, velocities re-derived from the poses: "
                   "w = Log(q+ q^-1) / h (Newton 1.8 VBD)", _NUMPY_RUNS["quat-rate-pose-velocity"]),
        Integrator("explicit-gyro-rescaled-torque-last", 1, False,
                   "semi-implicit Euler, explicit gyroscopic step of L = I_w w rescaled to |L| from "
                   "the step's start, torque impulse after it, world exp map (Newton 1.8 Kamino)",
                   _NUMPY_RUNS["explicit-gyro-rescaled-torque-last"]),
        Integrator("explicit-gyro-regularised-exp", 1, False,
                   "semi-implicit Euler, explicit gyroscopic term, body exp map with |w_b| + 1e-8 "
                   "(Brax 0.14 generalized)", _NUMPY_RUNS["explicit-gyro-regularised-exp"]),
        Integrator("semi-implicit-no-gyro", 1, False,
                   "semi-implicit Euler with NO gyroscopic term: world w += h I_w^-1 tau, q + h/2 (0, w) q "
                   "renormalised (Brax 0.14 spring)", _NUMPY_RUNS["semi-implicit-no-gyro"]),
        Integrator("semi-implicit-no-gyro-projected", 1, False,
                   "semi-implicit-no-gyro, velocities re-derived from the positions: w = 2 vec(q+ q^-1) / h "
                   "(Brax 0.14 positional)", _NUMPY_RUNS["semi-implicit-no-gyro-projected"]),
    ]
}


# The maps with more than one stage per step, whose loads are sampled at every stage
# (LOAD_SAMPLING_PER_STAGE) or held at the step's start's value (LOAD_SAMPLING_PER_STEP); every
# other map evaluates the loads once, at the step's start, under either rule.
MULTI_STAGE_MAPS = ("rkmk4-body", "rk4-body-exp", "quat-rate-rk2", "quat-rate-rk3", "quat-rate-bs3",
                    "quat-rate-rk5")


def simulate_engine_map(problem: Problem, name: str, dt: float, steps: int,
                        compiled: bool = True, load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> Trajectory:
    """Run the engine-equivalent map ``name`` (``ENGINE_MAPS``) for ``steps`` steps of ``dt``:
    compiled (:mod:`compiled_engine_maps`, under a microsecond a step) or, with ``compiled=False``,
    the numpy loops of this module.  ``load_sampling`` (:mod:`sampling`): where a multi-stage map
    evaluates the loads (every stage, or the step's start held over the step).  Blow-ups become
    inf/NaN samples, never exceptions."""
    ENGINE_MAPS[name]  # KeyError for an unknown name
    per_stage = check_load_sampling(load_sampling) == LOAD_SAMPLING_PER_STAGE
    if compiled:
        from .compiled_engine_maps import simulate_compiled_engine_map
        return simulate_compiled_engine_map(problem, name, dt, steps, load_sampling)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        if name in MULTI_STAGE_MAPS:
            return _NUMPY_RUNS[name](problem, dt, steps, per_stage)
        return _NUMPY_RUNS[name](problem, dt, steps)


def map_load_sampling(problem: Problem, name: str, load_sampling: str) -> str:
    """The variant of map ``name`` that a run under ``load_sampling`` is compared with, in its
    canonical spelling: ``load_sampling`` for a multi-stage engine map (:data:`MULTI_STAGE_MAPS`) on
    a case with a load whose wrench depends on the state (a body couple, a force at a point), else
    ``per-stage`` (both rules give the same trajectory there: one name, one cached run)."""
    check_load_sampling(load_sampling)
    if name in MULTI_STAGE_MAPS and any(
            ld.point is not None or ld.body_point is not None or np.any(ld.body_torque != 0.0)
            for ld in problem.loads):
        return load_sampling
    return LOAD_SAMPLING_PER_STAGE


__all__ += ["map_load_sampling"]
