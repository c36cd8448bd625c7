"""Brax (``brax``, JAX) as a freebody engine: its three physics pipelines, float32 or float64.

Integrators: Brax's pipelines, each its own ``pipeline.step``:

- ``generalized``: generalized coordinates (``brax.generalized``).  Semi-implicit Euler on the
  free joint's (q, qd): qd += h M^-1 (tau - bias), the bias by recursive Newton-Euler, so the
  gyroscopic term is there, explicit; then x += h v, q = normalize(q * (cos(a/2), axis sin(a/2)))
  with axis = w_b / (|w_b| + 1e-8) and a = h (|w_b| + 1e-8): the body-frame exponential map with a
  regularised norm.  freebody's engine-equivalent map ``explicit-gyro-regularised-exp``
  (``reference_impl/engine_maps.py``); at dt 0.001 the 1e-8 is invisible and the run also reproduces
  ``semi-implicit-explicit-gyro`` (MuJoCo ``Euler``'s map), at dt 0.01 it is 3e-11 rad away on a
  steady spin (a per-step rotation error of about h^3 |w|^2 1e-8 / 6).
- ``positional``: maximal coordinates, position-based dynamics (``brax.positional``).
- ``spring``: maximal coordinates, impulse/spring dynamics (``brax.spring``).

(Brax's fourth pipeline, ``brax.mjx``, is MJX itself: the ``mjx`` engine.)

**Finding: positional and spring have no gyroscopic term.**  Both integrate the world-frame
angular velocity of the COM frame as w += h I_w^-1 tau: torque-free, w (world) never changes, so a
body spun near its intermediate axis keeps turning about the same world axis (no Dzhanibekov flip,
angular momentum L = I_w w not conserved).  The rotation is the quaternion-rate update
q += h/2 (0, w) q, normalised (a turn of 2 atan(h |w| / 2) a step, not h |w|).  ``positional`` then
re-derives the velocities from the positions (``project_xd``: w = 2 vec(q+ q^-1) / h), which shrinks
|w| by 1 / sqrt(1 + h^2 |w|^2 / 4) a step: kinetic energy is lost however the body spins.  Their
maps: ``semi-implicit-no-gyro`` (spring) and ``semi-implicit-no-gyro-projected`` (positional), so
scheme identification names the missing gyroscopic term instead of reporting a large error.  These
are Brax's own integrators, not adapter errors: the adapter states them (``conventions``) and a
trap check measures them (:func:`_check_no_gyroscopic_term`).  In float32, ``positional``'s
velocities are differences of float32 positions: 2 eps32 / h of w (1.2e-4 rad/s at dt 1e-3) and
eps32 |x| / h of v a step, far more round-off than a float32 run usually carries.

Brax's conventions and what this adapter converts:

- The model is MJCF (``brax.io.mjcf.loads``, which compiles it with MuJoCo's C compiler): one body
  at the origin with a free joint, ``<inertial pos="0 0 0" fullinertia=...>`` (the MuJoCo
  adapter's element; the compiler diagonalises it into ``body_inertia`` + ``body_iquat``, which
  Brax keeps as ``link.inertia``), ``alignfree="false"`` so the body frame stays the case's (Brax
  clears a free link's own transform), the case's ``timestep`` and ``gravity`` in ``<option>``.
- Brax requires a geom (``mjcf.validate_model`` reads geom 0): one sphere of radius 1 mm with
  ``contype="0" conaffinity="0"`` (no contacts; there is no ground either).  The explicit
  ``<inertial>`` overrides the geom's own mass (MuJoCo's ``inertiafromgeom="auto"``): the body's
  mass and inertia are the case's, read back from the System in build().
- q (7,) = [body origin = COM (3,) m world, quaternion (4,) (w, x, y, z) body -> world]: no
  reordering.  qd (6,) = [linear velocity (3,) m/s world, angular velocity (3,) rad/s BODY frame]
  in every pipeline (``kinematics.inverse`` turns the world w back into the body frame): written
  as R^T w_world.  Read back: ``generalized`` from (q, qd), w_world = R w_body; ``positional`` and
  ``spring`` from their own state, the COM frame ``x_i`` (pos, rot) and its world-frame motion
  ``xd_i`` (vel, ang): no conversion.
- Loads.  ``pipeline.step`` takes actuator inputs only.  ``generalized``: the adapter adds six
  joint-space actuators, one per free-joint dof (brax.base.Actuator, gain 1, gear 1, no bias, no
  ranges), so ``act`` is the generalized force [f (3,) N world, R^T tau (3,) N m body] (the free
  joint's dofs are world linear and body angular; build() checks ``actuator.to_tau`` passes it
  through).  ``positional`` and ``spring``: Brax's free joint ignores its generalized forces
  (``joints._free`` returns no force) and nothing else takes an external force, so the adapter adds
  the wrench [f, tau] (N, N m, world, at the COM) to the link force ``xf_i`` that the pipeline's own
  joint update returns (``joints.acceleration_update`` / ``joints.resolve``, wrapped while the step
  is traced); the pipeline then integrates it as any joint force: v += h f / M, w += h I_w^-1 tau.
  The wrapper is used only for ``pipeline.step`` sources it was checked against (sha256 below);
  another Brax refuses loaded cases on those pipelines (NotImplementedError) and still runs the
  torque-free ones.  The wrench of a step is evaluated at the state at its start, as for every
  engine (``adapters/loads.py``).  A torque-free run uses Brax's ``pipeline.step`` untouched.

Defaults read back from the System and recorded (``settings``): ``timestep`` (MuJoCo's 0.002 ->
dt), ``gravity`` ((0, 0, -9.81) -> the case's), ``ang_damping`` and ``vel_damping`` (Brax's
``<custom>`` numerics: each step multiplies the positional/spring velocities by exp(d h); 0 in
Brax 0.14, set to 0 explicitly so that another default cannot creep in), the geom's ``contype``
and ``conaffinity`` (1 -> 0), ``compiler.alignfree`` (kept false), ``jax_enable_x64`` (the
process-wide value -> the run's scoped value).  Checked zero and left alone: joint damping and
armature, ``spring_mass_scale``, ``spring_inertia_scale``, fluid forces.  ``matrix_inv_iterations``
(10: ``generalized`` updates M^-1 by Newton-Schulz iterations from the previous step's) is left
at Brax's default: on these runs it changes nothing above round-off (measured, docs/adapters.md).
``baumgarte_erp``, ``joint_scale_*``, ``collide_scale`` and ``elasticity`` act on joints and
contacts only.

Stepping, compilation and precision: as the MJX adapter (and with its helpers): ``jax.lax.scan``
of ``pipeline.step`` under ``jax.jit`` in chunks of ``CHUNK_STEPS`` (padded with steps that leave
the state as it is, so a run cut into pieces is the one-piece run bit for bit), compiled once per
(pipeline, precision, loaded or not) and process; JAX's persistent compilation cache in the
per-user folder of :mod:`~freebody.adapters.mjx_adapter` (``CACHE_DIR``); ``compile_time_s`` is
the time this run spent tracing and compiling (0 when cached).  So that bodies share a
compilation, the System's static MJX structure (the mass-matrix sparsity fields, which Brax's
pipelines never read) is replaced by one template's and ``mj_model`` is dropped after build()
has validated the model.  ``float32`` (JAX's default) or ``float64`` inside JAX's thread-local
x64 scope (the process-wide flag is never changed); a float32 compilation is checked to hold no
f64 type; the trajectory is returned widened to float64.  Brax signals no instability: a blow-up
comes back as computed (non-finite samples), for the harness to detect.

``brax.io.mjcf.loads`` warns that Brax's System and pipelines are no longer actively maintained
(MJX is the maintained JAX engine): that one UserWarning is silenced.
"""
from __future__ import annotations

import contextlib
import contextvars
import hashlib
import inspect
import threading
import time
import warnings
from typing import Callable, ClassVar

import numpy as np

import brax  # ModuleNotFoundError "brax": the registry reports the engine missing (a skip)
import jax
import jax.numpy as jnp
from brax import actuator as _brax_actuator
from brax.base import Actuator
from brax.generalized import pipeline as _generalized
from brax.io import mjcf
from brax.positional import joints as _positional_joints
from brax.positional import pipeline as _positional
from brax.spring import joints as _spring_joints
from brax.spring import pipeline as _spring

from freebody.reference_impl.conventions import Trajectory, angular_velocity_body_from_world
from freebody.reference_impl.integrators import simulate
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.rotations import (geodesic_angle, matrix_from_quat, quat_from_matrix,
                                               quat_from_rotvec, quat_multiply)
from .base import Adapter, distribution_version, LOAD_SAMPLING_PER_STEP, TrapCheck
from .jax_runtime import LOAD_ROW, compiled, current_x64, load_rows, quat_matrix, x64_scope
from .mjcf import alignfree_default, format_floats, free_joint_trajectory, inertial_element
from .mjx_adapter import full_pattern

# --- this adapter's tolerances, each with its reason (the harness's rules: freebody/tolerances.py;
# the trap checks' bounds are with the trap checks below) ---------------------------------------
# Brax (JAX; float32 or float64).  Mass and the inertia tensor rebuilt from Brax's principal moments
# and frame (MuJoCo's compiler's diagonalisation) against the case's, relative to max(1, |value|):
# measured <= 3.8e-15 (float64) and 9e-8 (float32) on 30 random full tensors; a dropped principal
# frame or a geom's mass is O(1) off.
BRAX_READBACK_RTOL = {"float64": 1e-12, "float32": 1e-6}

PIPELINES: dict[str, object] = {"generalized": _generalized, "positional": _positional, "spring": _spring}
# Each pipeline's engine-equivalent map (reference_impl/engine_maps.py): what scheme identification
# names for its float64 runs, and what the trap checks hold the runs to.
PIPELINE_MAPS: dict[str, str] = {"generalized": "explicit-gyro-regularised-exp",
                                 "positional": "semi-implicit-no-gyro-projected",
                                 "spring": "semi-implicit-no-gyro"}
PRECISIONS: tuple[str, ...] = ("float32", "float64")
_DTYPE = {"float32": np.float32, "float64": np.float64}

# Steps per compiled scan call (as the MJX adapter: one compilation for runs of any length).
CHUNK_STEPS = 1000

# Brax's velocity damping of the maximal-coordinate pipelines (each step multiplies v and w by
# exp(d h)): set to these in the MJCF's <custom> numerics and read back.
ANG_DAMPING = 0.0
VEL_DAMPING = 0.0
# The required geom: a sphere this small (m), colliding with nothing.
GEOM_RADIUS = 1e-3

# The maximal-coordinate pipelines take the external wrench through the link force that their
# joint update returns: the function wrapped while the step is traced, and the sha256 of the
# pipeline.step source the wrapping was checked against (brax 0.14.2).
_JOINT_FORCE = {"positional": (_positional_joints, "acceleration_update"),
                "spring": (_spring_joints, "resolve")}
_STEP_SHA256 = {"positional": "36588ed86bfeb8061e8f194d21f9ebe5aa2991a20e426be8a0daee43a89d698a",
                "spring": "c5ae663dc880bec5041c0cec6b3202e22d6625c54a3fc6dc61374d3921da7895"}
_EXTERNAL: contextvars.ContextVar = contextvars.ContextVar("freebody_brax_wrench", default=None)
_HOOK_LOCK = threading.Lock()
_HOOK_CALLS = [0]  # wrapped joint-force calls that added a wrench (counted while tracing)

# The message of the warning brax.io.mjcf.loads gives on every load.
_UNMAINTAINED = "Brax System, piplines and environments are not actively being maintained"


def _step_source_checked(pipeline: str) -> bool:
    """Whether this Brax's ``pipeline.step`` is the one the joint-force wrapper was checked against."""
    try:
        source = inspect.getsource(PIPELINES[pipeline].step)
    except (OSError, TypeError):
        return False
    return hashlib.sha256(source.encode()).hexdigest() == _STEP_SHA256[pipeline]


def loads_supported(pipeline: str) -> bool:
    """Whether the adapter can apply external loads with this pipeline of the installed Brax."""
    return pipeline == "generalized" or _step_source_checked(pipeline)


def _with_external(original):
    """The joint-force function with the current external wrench (:data:`_EXTERNAL`, (6,) [f, tau]
    N, N m world at the COM) added to link 0's force, when one is set (while tracing a loaded step)."""
    def joint_force(sys, state, tau):
        xf = original(sys, state, tau)
        ext = _EXTERNAL.get()
        if ext is None:
            return xf
        _HOOK_CALLS[0] += 1
        return xf.replace(vel=xf.vel.at[0].add(ext[0:3]), ang=xf.ang.at[0].add(ext[3:6]))
    return joint_force


@contextlib.contextmanager
def _external_force_hook(pipeline: str):
    """The pipeline's joint-force function wrapped by :func:`_with_external` for the block (the
    adapter's tracing of a loaded step); nothing for ``generalized`` (it has actuators)."""
    if pipeline not in _JOINT_FORCE:
        yield
        return
    module, attr = _JOINT_FORCE[pipeline]
    with _HOOK_LOCK:
        original = getattr(module, attr)
        setattr(module, attr, _with_external(original))
        try:
            yield
        finally:
            setattr(module, attr, original)


# --- building -------------------------------------------------------------------------------------

def _mjcf(problem: Problem, dt: float, custom: bool = True) -> str:
    """The MJCF of one free body (see the module docstring); ``custom``: with the damping numerics."""
    body = problem.body
    compiler = '<compiler alignfree="false"/>' if alignfree_default() is not None else ""
    numerics = (f'<custom><numeric name="ang_damping" data="{format_floats(ANG_DAMPING)}"/>'
                f'<numeric name="vel_damping" data="{format_floats(VEL_DAMPING)}"/></custom>') if custom else ""
    return (f'<mujoco model="freebody">{compiler}{numerics}'
            f'<option timestep="{format_floats(dt)}" gravity="{format_floats(problem.gravity)}"/><worldbody>'
            f'<body name="body" pos="0 0 0" quat="1 0 0 0"><freejoint name="free"/>'
            f'{inertial_element(body.mass, body.I_body)}'
            f'<geom name="anchor" type="sphere" size="{format_floats(GEOM_RADIUS)}" contype="0" conaffinity="0"/>'
            f'</body></worldbody></mujoco>')


def _load_system(xml: str):
    """brax.io.mjcf.loads(xml) with its "not maintained" warning silenced (in the caller's x64 scope)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_UNMAINTAINED, category=UserWarning)
        return mjcf.loads(xml)


_DEFAULTS: dict = {}


def _brax_defaults() -> dict:
    """Brax's and MuJoCo's defaults of what the adapter sets, from a model without any setting
    (computed once)."""
    if not _DEFAULTS:
        sys = _load_system('<mujoco><worldbody><body><freejoint/><geom type="sphere" size="0.1"/>'
                           '</body></worldbody></mujoco>')
        _DEFAULTS.update({
            "timestep": float(sys.opt.timestep), "gravity": np.asarray(sys.gravity, dtype=float).tolist(),
            "ang_damping": float(sys.ang_damping), "vel_damping": float(sys.vel_damping),
            "geom contype": int(sys.mj_model.geom_contype[0]),
            "geom conaffinity": int(sys.mj_model.geom_conaffinity[0])})
    return _DEFAULTS


def _readback(what: str, got, want, rtol: float) -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    scale = np.maximum(1.0, np.abs(want))
    if got.shape != want.shape or np.any(np.abs(got - want) > rtol * scale):
        raise RuntimeError(f"brax did not take {what}: set {want.tolist()}, read back {got.tolist()}")


def _inertia_of(sys) -> np.ndarray:
    """The body's inertia tensor (3, 3) in the body frame as Brax holds it: R_i diag(i) R_i^T."""
    R_i = matrix_from_quat(np.asarray(sys.link.inertia.transform.rot[0], dtype=float))
    return R_i @ np.asarray(sys.link.inertia.i[0], dtype=float) @ R_i.T


def _dof_actuators(dtype) -> Actuator:
    """Six joint-space actuators, one per free-joint dof: act is the generalized force itself."""
    n = 6
    inf = np.full((n, 2), [-np.inf, np.inf])
    return Actuator(q_id=jnp.arange(n), qd_id=jnp.arange(n), ctrl_range=jnp.asarray(inf, dtype=dtype),
                    force_range=jnp.asarray(inf, dtype=dtype), gain=jnp.ones(n, dtype=dtype),
                    gear=jnp.ones(n, dtype=dtype), bias_q=jnp.zeros(n, dtype=dtype),
                    bias_qd=jnp.zeros(n, dtype=dtype))


def _build(problem: Problem, dt: float, pipeline: str, precision: str, loaded: bool, x64_default: bool):
    """(System for stepping, initial State, settings, s spent compiling pipeline.init) inside the
    caller's x64 scope; every setting read back from the System."""
    dtype = _DTYPE[precision]
    rtol = BRAX_READBACK_RTOL[precision]
    defaults = _brax_defaults()
    sys = _load_system(_mjcf(problem, dt))
    mj = sys.mj_model
    mjcf.validate_model(mj)  # what pipeline.init would check (the stepped System has no mj_model)
    if sys.link_types != "f" or sys.num_links() != 1:
        raise RuntimeError(f"brax built links {sys.link_types!r}, not one free link")
    if np.asarray(sys.opt.timestep).dtype != dtype:
        raise RuntimeError(f"brax System is {np.asarray(sys.opt.timestep).dtype}, not {precision}")
    _readback("timestep", sys.opt.timestep, dtype(dt), 0.0)
    _readback("gravity", sys.gravity, np.asarray(problem.gravity, dtype=dtype), 0.0)
    _readback("mass", sys.link.inertia.mass[0], problem.body.mass, rtol)
    _readback("inertia", _inertia_of(sys), problem.body.I_body, rtol)
    _readback("inertia position (COM at the body origin)", sys.link.inertia.transform.pos[0], np.zeros(3), 0.0)
    _readback("link transform (body frame kept)", np.concatenate([sys.link.transform.pos[0],
                                                                 sys.link.transform.rot[0]]),
              [0, 0, 0, 1, 0, 0, 0], 0.0)
    _readback("ang_damping", sys.ang_damping, ANG_DAMPING, 0.0)
    _readback("vel_damping", sys.vel_damping, VEL_DAMPING, 0.0)
    for what in ("damping", "armature"):
        _readback(f"joint {what} 0", getattr(sys.dof, what), np.zeros(6), 0.0)
    _readback("spring mass and inertia scales 0", [sys.spring_mass_scale, sys.spring_inertia_scale], [0, 0], 0.0)
    if sys.enable_fluid or sys.act_size() != 0 or mj.geom_contype[0] or mj.geom_conaffinity[0]:
        raise RuntimeError("brax model has fluid forces, actuators or a colliding geom")
    settings = {}

    def record(key, default, value):
        settings[key] = {"default": default, "set": value}

    record("timestep", defaults["timestep"], float(sys.opt.timestep))
    record("gravity", defaults["gravity"], np.asarray(sys.gravity, dtype=float).tolist())
    record("ang_damping", defaults["ang_damping"], float(sys.ang_damping))
    record("vel_damping", defaults["vel_damping"], float(sys.vel_damping))
    record("geom contype", defaults["geom contype"], int(mj.geom_contype[0]))
    record("geom conaffinity", defaults["geom conaffinity"], int(mj.geom_conaffinity[0]))
    align = alignfree_default()
    if align is not None:
        record("compiler.alignfree", align, False)
    record("jax_enable_x64", bool(x64_default), current_x64())
    if settings["jax_enable_x64"]["set"] != (precision == "float64"):
        raise RuntimeError("the x64 scope did not take effect")

    init = problem.initial
    q = jnp.asarray(np.concatenate([init.position, init.quaternion_wxyz]), dtype=dtype)
    qd = jnp.asarray(np.concatenate([init.linear_velocity, angular_velocity_body_from_world(
        init.quaternion_wxyz, init.angular_velocity)]), dtype=dtype)
    # one static structure for every body: the sparsity fields (read by MJX, never by these
    # pipelines) of a full-pattern model, no mj_model
    stepped = sys.replace(mj_model=None, **full_pattern())
    if loaded and pipeline == "generalized":
        stepped = stepped.replace(actuator=_dof_actuators(dtype), nu=6)  # act_size() is nu
        probe = jnp.arange(1, 7, dtype=dtype)
        if not np.array_equal(np.asarray(_brax_actuator.to_tau(stepped, probe, q, qd)), np.asarray(probe)):
            raise RuntimeError("brax actuator.to_tau does not pass a per-dof actuator's input through")
        record("actuators", 0, 6)
    init_fn, spent = compiled(f"brax-init-{pipeline}", _init_jit(pipeline), precision, (stepped, q, qd),
                              label=pipeline)
    return stepped, init_fn(stepped, q, qd), settings, spent


_INIT_JIT: dict = {}


def _init_jit(pipeline: str):
    """jit(pipeline.init) (the System's mj_model dropped, so init's validation is build()'s)."""
    if pipeline not in _INIT_JIT:
        _INIT_JIT[pipeline] = jax.jit(PIPELINES[pipeline].init)
    return _INIT_JIT[pipeline]


# --- the steps inside the scan ----------------------------------------------------------------------

def _wrench(row, x, q):
    """(force (3,) N world, torque about the COM (3,) N m world, R (3, 3)) of a load row (the layout
    of ``jax_runtime.LOAD_ROW``, shared with MJX) at COM position x and orientation q (w, x, y, z)."""
    R = quat_matrix(q)
    A = R @ row[12:21].reshape(3, 3)  # sum (R b_i) f_i^T
    tau = (row[3:6] + jnp.cross(row[6:9] - x, row[9:12])
           + jnp.stack([A[1, 2] - A[2, 1], A[2, 0] - A[0, 2], A[0, 1] - A[1, 0]]) + R @ row[21:24])
    return row[0:3], tau, R


def _read(pipeline: str, st):
    """(q (7,) [x, quaternion], v (6,) [v world, w]) of a State: w in the body frame for
    ``generalized`` (qd), world for the others (xd_i.ang)."""
    if pipeline == "generalized":
        return st.q, st.qd
    return (jnp.concatenate([st.x_i.pos[0], st.x_i.rot[0]]),
            jnp.concatenate([st.xd_i.vel[0], st.xd_i.ang[0]]))


def _step(pipeline: str, loaded: bool, sys, st, row):
    """One ``pipeline.step``; with ``loaded``, the row's wrench at the state at the step's start."""
    P = PIPELINES[pipeline]
    if not loaded:
        return P.step(sys, st, jnp.zeros(0, dtype=row.dtype))
    if pipeline == "generalized":
        f, tau, R = _wrench(row, st.q[0:3], st.q[3:7])
        return P.step(sys, st, jnp.concatenate([f, R.T @ tau]))
    f, tau, _ = _wrench(row, st.x_i.pos[0], st.x_i.rot[0])
    token = _EXTERNAL.set(jnp.concatenate([f, tau]))
    try:
        return P.step(sys, st, jnp.zeros(0, dtype=row.dtype))
    finally:
        _EXTERNAL.reset(token)


def _chunk(pipeline: str, loaded: bool, sys, st, rows, n):
    """Scan the pipeline's step over the first n of rows (C, LOAD_ROW); the C - n steps after them
    leave the State as it is.  Returns (State after step n, q (C, 7), v (C, 6))."""
    def body(s, x):
        i, row = x
        s = jax.lax.cond(i < n, lambda e: _step(pipeline, loaded, sys, e, row), lambda e: e, s)
        return s, _read(pipeline, s)
    st, (Q, V) = jax.lax.scan(body, st, (jnp.arange(rows.shape[0]), rows))
    return st, Q, V


_CHUNK_JIT: dict = {}


def _chunk_jit(pipeline: str, loaded: bool):
    key = (pipeline, loaded)
    if key not in _CHUNK_JIT:
        _CHUNK_JIT[key] = jax.jit(lambda sys, st, rows, n: _chunk(pipeline, loaded, sys, st, rows, n))
    return _CHUNK_JIT[key]


class BraxAdapter(Adapter):
    name: ClassVar[str] = "brax"
    import_name: ClassVar[str] = "brax"
    # verified on brax 0.14.2 (jax 0.10.2, mujoco 4.0.0); build() reads back every setting it
    # relies on, and the load wrapper checks the pipeline.step source it wraps
    supported_versions: ClassVar[str | None] = ">=0.14"
    integrators: ClassVar[tuple[str, ...]] = tuple(PIPELINES)
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP
    load_sampling_note: ClassVar[str] = ("world wrench from the step's start; one-stage pipelines, so the same as "
                                         "per-stage")
    precisions: ClassVar[tuple[str, ...]] = PRECISIONS
    conventions: ClassVar[dict[str, str]] = {
        "model": "MJCF via brax.io.mjcf.loads (MuJoCo's compiler): one free body, fullinertia "
                 "(diagonalised into link.inertia), alignfree=false, the case's timestep and gravity",
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (q[3:7]); no reorder",
        "position": "q[0:3] / x_i.pos: body origin = COM (inertial pos 0 0 0)",
        "angular velocity frame": "qd[3:6] is BODY frame in every pipeline: written R^T w_world; "
                                  "read back w_world = R qd[3:6] (generalized) or xd_i.ang, world "
                                  "(positional, spring)",
        "linear velocity frame": "world (qd[0:3], xd_i.vel)",
        "geom": "Brax needs one (validate_model reads geom 0): a 1 mm sphere, contype=conaffinity=0; "
                "its mass is overridden by the explicit <inertial>",
        "external loads": "pipeline.step takes actuators only: generalized through six per-dof "
                          "actuators (act = [f world, R^T tau body]); positional/spring ignore a "
                          "free joint's forces: the wrench is added to the link force of their "
                          "joint update (checked pipeline.step source only; otherwise loaded cases "
                          "are refused)",
        "gyroscopic term": "generalized: explicit (RNE bias). positional, spring: NONE (world w "
                           "integrated as w += h I_w^-1 tau: torque-free w_world is constant, no "
                           "Dzhanibekov flip, L not conserved); engine maps semi-implicit-no-gyro "
                           "(spring), semi-implicit-no-gyro-projected (positional)",
        "rotation update": "generalized: q * Exp(h w_b) with |w_b| regularised by +1e-8 (map "
                           "explicit-gyro-regularised-exp); positional, spring: q += h/2 (0, w) q, "
                           "normalised (turns 2 atan(h |w| / 2) a step)",
        "velocity projection": "positional re-derives w = 2 vec(q+ q^-1) / h after each step: |w| "
                               "shrinks by 1 / sqrt(1 + h^2 |w|^2 / 4) a step (energy lost)",
        "damping": "ang_damping, vel_damping (<custom> numerics, exp(d h) per step; 0 in 0.14) set "
                   "0 and read back; joint damping, armature 0",
        "mass matrix inverse": "generalized: Newton-Schulz iterations (matrix_inv_iterations 10) "
                               "from the previous step's inverse; left at Brax's default",
        "precision": "float32 (JAX's default) or float64 via the thread-local jax.enable_x64 "
                     "scope; the process-wide jax_enable_x64 is left alone",
        "float32 positional": "its velocities are differences of float32 positions: v to eps32 |x| "
                              "/ h, w to 2 eps32 / h (1.2e-4 rad/s at dt 1e-3) a step, so its "
                              "float32 runs at small dt or far from the origin carry far more "
                              "round-off than float32 usually does (far_from_origin, dt 1e-3: "
                              "energy error 0.105, float64 5e-4)",
        "stepping": f"jax.lax.scan of pipeline.step under jax.jit, {CHUNK_STEPS} steps per call; "
                    "JAX's persistent compilation cache (the mjx adapter's folder)",
        "instability": "no signal of its own: detected as non-finite state",
        "velocity clamp": "none",
        "sleeping": "none",
        "contacts": "none: a non-colliding geom, no ground",
    }

    # --- capabilities --------------------------------------------------------------------------
    @classmethod
    def engine_version(cls) -> str:
        version = distribution_version("brax", lambda: getattr(brax, "__version__", "unknown"))
        return f"{version} (jax {jax.__version__})"

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        """Only ``generalized``: positional and spring have no gyroscopic term and a
        quaternion-rate rotation, so they fail the torque-free L and high-spin checks by design;
        their trap check measures and labels that instead."""
        return ("generalized",)

    # --- world ---------------------------------------------------------------------------------
    def build(self) -> None:
        self._dtype = _DTYPE[self.precision]
        self._loaded = not self.loads.empty
        if self._loaded and not loads_supported(self.integrator):
            raise NotImplementedError(
                f"external loads on a free body are not supported by brax {self.engine_version()} "
                f"{self.integrator}: its pipeline.step takes no external force and its free joint "
                f"ignores generalized forces; freebody adds the wrench to the joint-update force "
                f"only for the pipeline.step source it was checked against (brax 0.14.2)")
        x64_default = current_x64()
        with x64_scope(self.precision == "float64"):
            self._sys, self._state, settings, spent = _build(self.problem, self.dt, self.integrator,
                                                             self.precision, self._loaded, x64_default)
        self.settings.update(settings)
        self.compile_time_s = spent  # tracing + compiling spent by this adapter (init, steps), s
        self.step_time_s = 0.0     # stepping, s (excludes compiling)

    # --- stepping ------------------------------------------------------------------------------
    def advance(self, steps: int) -> Trajectory:
        """``steps`` steps from the current state as ceil(steps / CHUNK_STEPS) compiled scans.
        Brax signals no instability: a blow-up comes back as computed, for the harness."""
        dtype, k0, pipeline = self._dtype, self.k, self.integrator
        Q = np.empty((steps + 1, 7))   # [x (3) m world, q (4) wxyz body -> world]
        V = np.empty((steps + 1, 6))   # [v (3) m/s world, w (3) rad/s: body (generalized) or world]
        with x64_scope(self.precision == "float64"):
            q0, v0 = _read(pipeline, self._state)
            Q[0], V[0] = np.asarray(q0, dtype=np.float64), np.asarray(v0, dtype=np.float64)
            sys, state = self._sys, self._state
            fn_jit = _chunk_jit(pipeline, self._loaded)
            i = 0
            while i < steps:
                n = min(CHUNK_STEPS, steps - i)
                rows = np.zeros((CHUNK_STEPS, LOAD_ROW), dtype=dtype)
                if self._loaded:
                    rows[:n] = load_rows(self.loads, k0 + i, k0 + i + n, dtype)
                args = (sys, state, jnp.asarray(rows), jnp.int32(n))
                traced = _HOOK_CALLS[0]
                with _external_force_hook(pipeline if self._loaded else ""):
                    fn, spent = compiled(f"brax-{pipeline}-{'loaded' if self._loaded else 'free'}", fn_jit,
                                         self.precision, args, label=pipeline)
                if spent and self._loaded and pipeline in _JOINT_FORCE and _HOOK_CALLS[0] - traced != 1:
                    raise RuntimeError(f"brax {pipeline}.step called its joint update "
                                       f"{_HOOK_CALLS[0] - traced} times while traced, not once: "
                                       f"the external wrench would be wrong")
                self.compile_time_s += spent
                t0 = time.perf_counter()
                state, Qc, Vc = fn(*args)
                Qc, Vc = np.asarray(Qc), np.asarray(Vc)
                self.step_time_s += time.perf_counter() - t0
                if Qc.dtype != dtype:
                    raise RuntimeError(f"brax computed q in {Qc.dtype}, not {self.precision}")
                Q[i + 1:i + 1 + n], V[i + 1:i + 1 + n] = Qc[:n], Vc[:n]
                i += n
        self._state = state
        self.k = k0 + steps
        if pipeline == "generalized":
            return free_joint_trajectory(Q, V, self.dt, k0)
        return Trajectory.on_grid(k0, self.dt, Q[:, 0:3], Q[:, 3:7], V[:, 0:3], V[:, 3:6])

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """For ``freebody bench``: Brax's compiled scans of ``steps`` steps from the current state
        (the step's loads included, their rows formed beforehand), outputs left as JAX arrays."""
        dtype, pipeline, precision = self._dtype, self.integrator, self.precision
        kind = f"brax-{pipeline}-{'loaded' if self._loaded else 'free'}"
        with x64_scope(precision == "float64"):
            chunks = []
            for i in range(0, steps, CHUNK_STEPS):
                n = min(CHUNK_STEPS, steps - i)
                rows = np.zeros((CHUNK_STEPS, LOAD_ROW), dtype=dtype)
                if self._loaded:
                    rows[:n] = load_rows(self.loads, self.k + i, self.k + i + n, dtype)
                chunks.append((jnp.asarray(rows), jnp.int32(n)))
            with _external_force_hook(pipeline if self._loaded else ""):
                fn, _ = compiled(kind, _chunk_jit(pipeline, self._loaded), precision,
                                 (self._sys, self._state, *chunks[0]), label=pipeline) if chunks else (None, 0.0)
        sys, state0 = self._sys, self._state

        def loop():
            state, out = state0, None
            for rows, n in chunks:
                state, Q, V = fn(sys, state, rows, n)
                out = (Q, V)
            return jax.block_until_ready(out)
        return loop

    def close(self) -> None:
        self._sys = self._state = None

    # --- live checks of the traps this adapter handles -------------------------------------------
    @classmethod
    def trap_checks(cls) -> dict[str, TrapCheck]:
        return {
            "angular velocity: qd[3:6] is body frame": _check_body_frame_w,
            "no damping left on (ang/vel_damping, exp(d h) per step)": _check_damping,
            "full inertia: body frame kept, principal frame in link.inertia": _check_full_inertia,
            "external wrench reaches the free body (all pipelines)": _check_loads,
            "float64 runs are float64 (x64 scope), float32 runs float32": _check_precision,
            "positional/spring: no gyroscopic term (finding, identified)": _check_no_gyroscopic_term,
        }


# --- trap checks (BraxAdapter.trap_checks) ------------------------------------------------------------

# The adapter's live trap checks (BraxAdapter.trap_checks), float64 runs; measured values in
# parentheses, the untreated trap's after the semicolon.
# A rotated body spun about a body axis, every pipeline, 50 steps: w and orientation against the
# spin about that world axis, rad (7.5e-13; w written in the wrong frame: 1.3).
BRAX_TRAP_FRAME_RAD = 1e-9
# spring, a moving spin about the major axis, 200 steps: relative change of |w| and |v| (0: Brax
# multiplies them by exp(0 h) = 1 exactly; ang/vel_damping -0.05: 0.095).
BRAX_TRAP_DAMPING_RTOL = 1e-12
# diag(1, 2, 3) given as a rotated full tensor against the diagonal body, 100 steps at dt 0.01,
# non-chaotic (2.9e-15; the diagonal part alone, or the body frame moved: O(1)).
BRAX_TRAP_FULL_INERTIA_RAD = 1e-9
# One 1 ms push at a body point from angular rest, every pipeline: |dL - h (R b) x f| / |h tau| and
# |dp - h f| / |h f| (1.6e-7: the body turns during the step; an ignored load: 1).
BRAX_TRAP_PUSH_RTOL = 1e-4
# generalized, 200 steps of a tumbling body at dt 0.01 against its float64 map: the float64 run
# (1.2e-15 rad) and the float32 one (7.3e-7 rad, float32 round-off: a float32 System) ...
BRAX_TRAP_FLOAT64_RAD = 1e-11
BRAX_TRAP_FLOAT32_MIN_RAD = 1e-9
# ... spring and positional on dzhanibekov's body, 400 steps at dt 0.01: against their no-gyroscopic
# maps (4.2e-13 rad) and the turn of their world w axis (2.4e-16), and how far they must stay from
# the gyroscopic map semi-implicit-explicit-gyro (3.1 rad: the flip they never make).
BRAX_TRAP_NO_GYRO_RAD = 1e-9
BRAX_TRAP_GYRO_GAP_MIN_RAD = 0.1


def _run(problem: Problem, dt: float, steps: int, pipeline: str, precision: str = "float64") -> Trajectory:
    adapter = BraxAdapter(problem, dt, pipeline, precision)
    try:
        return adapter.simulate(steps)
    finally:
        adapter.close()


def _check_body_frame_w():
    """A rotated body spinning about a principal axis (world w = R e_z 3 rad/s), every pipeline:
    it must turn about that world axis at that rate; w written or read in the wrong frame spins it
    about R^T w (an O(1) error)."""
    dt, steps, rate = 0.01, 50, 3.0
    q0 = quat_from_rotvec(np.array([0.9, -0.4, 0.6]))
    w0 = rate * (matrix_from_quat(q0) @ np.array([0.0, 0.0, 1.0]))
    pb = Problem("trap-frame", "", Body(1.0, np.diag([1.0, 2.0, 2.5])),
                 InitialState(np.zeros(3), q0, np.zeros(3), w0), gravity=(0, 0, 0), duration_steps=steps)
    worst = 0.0
    for pipeline in PIPELINES:
        tr = _run(pb, dt, steps, pipeline)
        axis_err = float(np.max(np.linalg.norm(tr.angular_velocity - w0, axis=1))) / rate
        # the turn per step: exact for generalized, 2 atan(h |w| / 2) for the quaternion-rate ones
        turn = rate * dt if pipeline == "generalized" else 2.0 * np.arctan(0.5 * rate * dt)
        if pipeline == "positional":  # |w| shrinks by the projection; compare the axis only
            axis_err = float(np.max(np.linalg.norm(tr.angular_velocity / np.linalg.norm(
                tr.angular_velocity, axis=1)[:, None] - w0 / rate, axis=1)))
            exact = None
        else:
            exact = quat_multiply(quat_from_rotvec(np.outer(np.arange(steps + 1) * turn / rate, w0)), q0)
        angle_err = 0.0 if exact is None else float(np.max(geodesic_angle(exact, tr.quaternion_wxyz)))
        worst = max(worst, axis_err, angle_err)
    bound = BRAX_TRAP_FRAME_RAD
    return (worst <= bound, worst, bound,
            f"a rotated body spun about its body z axis (3 rad/s world), 0.5 s, every pipeline: its "
            f"w and orientation stay those of a spin about that world axis to {worst:.1e} (w in the "
            f"wrong frame: O(1))")


def _check_damping():
    """Spring (velocities carried as they are): a moving spin about the major axis, torque-free,
    no gravity, 2 s: |w| and |v| keep exactly; ang/vel_damping d would scale them by exp(d t)."""
    dt, steps = 0.01, 200
    v0, w0 = np.array([1.0, -2.0, 0.5]), np.array([0.0, 0.0, 3.0])
    pb = Problem("trap-damping", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), [1, 0, 0, 0], v0, w0), gravity=(0, 0, 0), duration_steps=steps)
    tr = _run(pb, dt, steps, "spring")
    err = max(float(np.max(np.abs(np.linalg.norm(tr.angular_velocity, axis=1) / 3.0 - 1.0))),
              float(np.max(np.abs(np.linalg.norm(tr.linear_velocity, axis=1) / np.linalg.norm(v0) - 1.0))))
    bound = BRAX_TRAP_DAMPING_RTOL
    return (err <= bound, err, bound,
            f"spring, a moving spin about the major axis, 2 s: |w| and |v| change by {err:.1e} "
            f"(relative; a damping of -0.05 would take 0.1)")


def _check_full_inertia():
    """diag(1, 2, 3) given as a rotated full tensor moves as given diagonal (generalized, 1 s)."""
    dt, steps = 0.01, 100
    Q = matrix_from_quat(quat_from_rotvec(np.array([0.3, -1.2, 0.7])))  # body axes -> principal axes
    q_p = quat_from_rotvec(np.array([0.4, 0.2, -0.1]))
    w0 = np.array([0.3, 2.0, -0.4])
    diag = Problem("trap-diag", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                   InitialState(np.zeros(3), q_p, np.zeros(3), w0), gravity=(0, 0, 0), duration_steps=steps)
    full = Problem("trap-full", "", Body(1.0, Q.T @ np.diag([1.0, 2.0, 3.0]) @ Q),
                   InitialState(np.zeros(3), quat_multiply(q_p, quat_from_matrix(Q)), np.zeros(3), w0),
                   gravity=(0, 0, 0), duration_steps=steps)
    a, b = _run(diag, dt, steps, "generalized"), _run(full, dt, steps, "generalized")
    back = quat_multiply(b.quaternion_wxyz, quat_from_matrix(Q.T))
    err = max(float(np.max(geodesic_angle(a.quaternion_wxyz, back))),
              float(np.max(np.abs(a.angular_velocity - b.angular_velocity))) / np.linalg.norm(w0))
    bound = BRAX_TRAP_FULL_INERTIA_RAD
    return (err <= bound, err, bound,
            f"diag(1, 2, 3) given as a rotated full tensor moves as given diagonal, 1 s at dt 0.01: "
            f"orientation (rad) and w (relative) differ by {err:.1e} (body frame moved to the "
            f"principal axes, or the diagonal alone: O(1))")


def _check_loads():
    """One step of a force at a body point on a rotated body at angular rest, every pipeline: p and
    L change by the impulse h f and h (R b) x f; a wrench the pipeline ignores leaves them."""
    h = 1e-3
    f, b = np.array([0.0, 3.0, -2.0]), np.array([0.5, 0.2, -0.3])
    q0 = quat_from_rotvec(np.array([0.4, -0.7, 0.25]))
    R0 = matrix_from_quat(q0)
    I_b = np.diag([0.9, 1.6, 2.1])
    pb = Problem("trap-loads", "", Body(1.7, I_b), InitialState(np.zeros(3), q0, np.zeros(3), np.zeros(3)),
                 gravity=(0, 0, 0), loads=(Load(force=f, body_point=b, start=0.0, steps=1),), duration_steps=1)
    want_p, want_L = h * f, h * np.cross(R0 @ b, f)
    worst = 0.0
    for pipeline in PIPELINES:
        tr = _run(pb, h, 1, pipeline)
        R1 = matrix_from_quat(tr.quaternion_wxyz[1])
        L = R1 @ I_b @ R1.T @ tr.angular_velocity[1]
        p = pb.body.mass * tr.linear_velocity[1]
        worst = max(worst, float(np.linalg.norm(L - want_L) / np.linalg.norm(want_L)),
                    float(np.linalg.norm(p - want_p) / np.linalg.norm(want_p)))
    bound = BRAX_TRAP_PUSH_RTOL
    return (worst <= bound, worst, bound,
            f"one step (1 ms) of a force at a body point, every pipeline: p and L change by the "
            f"impulse to {worst:.1e} (relative; an ignored load: 1)")


def _check_precision():
    """The same 200 generalized steps in float64 and float32: the float64 run is within float64
    round-off of the float64 map, the float32 run is float32 round-off away from it."""
    dt, steps = 0.01, 200
    pb = Problem("trap-precision", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), [1, 0, 0, 0], np.zeros(3), [0.3, 1.0, -0.2]), gravity=(0, 0, 0),
                 duration_steps=steps)
    ref = simulate(pb, PIPELINE_MAPS["generalized"], dt, steps).quaternion_wxyz
    d64 = float(np.max(geodesic_angle(_run(pb, dt, steps, "generalized", "float64").quaternion_wxyz, ref)))
    d32 = float(np.max(geodesic_angle(_run(pb, dt, steps, "generalized", "float32").quaternion_wxyz, ref)))
    ok = d64 <= BRAX_TRAP_FLOAT64_RAD and d32 >= BRAX_TRAP_FLOAT32_MIN_RAD
    return (ok, d64, BRAX_TRAP_FLOAT64_RAD,
            f"generalized, 2 s at dt 0.01, against its float64 map: float64 run {d64:.1e} rad, "
            f"float32 run {d32:.1e} rad (float32 must be >= {BRAX_TRAP_FLOAT32_MIN_RAD:g}: the "
            f"x64 scope reached the run, and only the float64 one)")


def _check_no_gyroscopic_term():
    """Dzhanibekov's body (diag(1, 2, 3), w = (0.01, 5, 0)) for 4 s at dt 0.01, float64: spring's
    and positional's runs reproduce their no-gyroscopic-term maps (the finding), their world w
    axis never moves (no flip), and they are far from the gyroscopic map."""
    dt, steps = 0.01, 400
    w0 = np.array([0.01, 5.0, 0.0])
    pb = Problem("trap-gyro", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), [1, 0, 0, 0], np.zeros(3), w0), gravity=(0, 0, 0),
                 duration_steps=steps)
    gyro = simulate(pb, "semi-implicit-explicit-gyro", dt, steps).quaternion_wxyz
    worst, far, turned = 0.0, np.inf, 0.0
    for pipeline in ("spring", "positional"):
        name = PIPELINE_MAPS[pipeline]
        tr = _run(pb, dt, steps, pipeline)
        worst = max(worst, float(np.max(geodesic_angle(tr.quaternion_wxyz,
                                                       simulate(pb, name, dt, steps).quaternion_wxyz))))
        far = min(far, float(np.max(geodesic_angle(tr.quaternion_wxyz, gyro))))
        axes = tr.angular_velocity / np.linalg.norm(tr.angular_velocity, axis=1)[:, None]
        turned = max(turned, float(np.max(np.linalg.norm(axes - w0 / np.linalg.norm(w0), axis=1))))
    bound = BRAX_TRAP_NO_GYRO_RAD
    ok = worst <= bound and turned <= bound and far >= BRAX_TRAP_GYRO_GAP_MIN_RAD
    return (ok, worst, bound,
            f"dzhanibekov body, 4 s at dt 0.01: spring and positional reproduce semi-implicit-no-gyro(-"
            f"projected) to {worst:.1e} rad, their world w axis moves {turned:.1e} (no flip), and "
            f"they are {far:.2f} rad from semi-implicit-explicit-gyro (a gyroscopic term would flip "
            f"the body: this is Brax's scheme, stated in the conventions)")
