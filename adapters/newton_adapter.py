"""Newton (NVIDIA Warp's physics engine, ``newton``) as a freebody engine, on Warp's CPU device.

One model per run: a ``newton.ModelBuilder`` with the case's gravity, one body added with
``add_body`` (a link, a FREE joint to the world and its articulation), COM at the body origin, the
full inertia tensor, no collision shape (no ground, no contacts: ``step`` gets ``contacts=None``),
finalized on ``"cpu"``.  The solver is the integrator:

=================  ==========================  =================================================
integrator         Newton solver               what it does to a lone free body
=================  ==========================  =================================================
``semi-implicit``  ``SolverSemiImplicit``      maximal coordinates (``body_q``/``body_qd``):
                                               v+ = v + h (f/M + g), w+ = w + h I_w^-1 (tau -
                                               w x I_w w) (formed in the body frame), x+ = x +
                                               h v+, q+ = normalize(q + h/2 (0, w+) q)
``featherstone``   ``SolverFeatherstone``      generalized coordinates (``joint_q``/``joint_qd``
                                               of the FREE joint), CRBA + Cholesky, the same
                                               update on the spatial twist at the world origin
``xpbd``           ``SolverXPBD``              ``SemiImplicit``'s body integration, then a
                                               constraint projection with nothing to project
``steel``          ``SolverSteel`` (exp.)      reduced coordinates, CRBA, PGS with no rows: the
                                               same update but for the gyroscopic term, taken
                                               by energy-preserving Cayley (implicit-midpoint)
                                               microsteps in the body frame
``vbd``            ``SolverVBD`` (exp.)        ``SemiImplicit``'s body step as the inertial
                                               target, an AVBD solve with nothing to solve, then
                                               the velocities re-derived from the poses:
                                               v+ = (x+ - x) / h, w+ = Log(q+ q^-1) / h
``kamino``         ``SolverKamino`` (beta)     semi-implicit Euler ("euler" integrator), the
                                               gyroscopic term explicit on L = I_w w and
                                               rescaled to |L| (as PhysX), q+ = Exp(h w+) q;
                                               opt-in: ~30 ms a step (one PADMM solve each)
``mujoco-<name>``  ``SolverMuJoCo``            MuJoCo's own step (C MuJoCo, ``use_mujoco_cpu``)
                                               with MuJoCo's integrator ``<name>`` (euler, rk4,
                                               implicit, implicitfast), state copied through
                                               Newton's float32 ``State`` each step; offered only
                                               where ``mujoco_warp`` imports (see below)
=================  ==========================  =================================================

The maps of ``semi-implicit``, ``featherstone`` and ``xpbd`` are one map in exact arithmetic:
Drake's discrete step (freebody's engine-equivalent map ``quat-rate-semi-implicit``: semi-implicit
Euler on world w, the quaternion moved along its rate 1/2 (0, w+) q, renormalised here but not in
Drake, which leaves the rotation unchanged).  ``steel``, ``vbd`` and ``kamino`` have maps of their
own: ``quat-rate-cayley-gyro``, ``quat-rate-pose-velocity``, ``explicit-gyro-rescaled-torque-last``
(``reference_impl/engine_maps.py``, ``docs/engine-maps.md``).  Their float32 round-off differs:
``semi-implicit`` and ``xpbd`` (and ``steel``'s gyroscopic update) take w to the body frame and
back every step with a normalised float32 quaternion whose norm stays ~2.5e-8 above 1, which grows
|w| of a steady spin by 1.5e-7 to 2.4e-7 a step; ``featherstone`` stays in the world frame but
carries the spatial inertia and twist about the world origin (v_o = v - w x x), so a body far from
the origin loses digits: about 1 km out (far_from_origin) its first step is non-finite, a divergence.

Solvers that cannot step a lone rigid body: ``SolverStyle3D`` (cloth), ``SolverImplicitMPM``
(material point method), the ``experimental.coupled`` solvers (couplings of the others).

Newton's MuJoCo solver needs ``mujoco_warp`` even for its C backend (``import_mujoco`` imports
both), and Newton 1.8 declares ``mujoco~=3.17.0`` and ``mujoco-warp~=3.17.0`` (extra ``sim``),
which conflicts with MuJoCo 4 in freebody's main environment.  The ``mujoco-*`` integrators are
therefore offered only where ``mujoco_warp`` is importable: an isolated environment with
``newton[sim]==1.8.0`` (checked with mujoco 3.17.0 and mujoco-warp 3.17.0).

Newton's conventions and what this adapter converts (Newton 1.8.0, Warp 1.19.0):

- ``State.body_q`` (N,) ``transformf`` = [position (3,) m world of the body origin, quaternion
  (x, y, z, w) body -> world]: the origin is the COM here (``body_com`` = 0), the quaternion is
  reordered with ``quat_wxyz_from_xyzw`` / ``quat_xyzw_from_wxyz``.
- ``State.body_qd`` (N,) ``spatial_vectorf`` = [linear velocity (3,) m/s of the COM, world;
  angular velocity (3,) rad/s, WORLD frame]: canonical, no conversion.  (Newton's conventions
  changed before 1.0: older releases used (w, v) and body-origin velocities.)
- The FREE joint's ``joint_q`` (7,) = [x (3,), q (x, y, z, w)] and ``joint_qd`` (6,) = [v COM (3,)
  world, w (3,) world] for the identity joint frames ``add_body`` makes; the adapter writes both
  (``featherstone``, ``steel``, ``kamino`` integrate them and compute ``body_q`` from them) and
  reads ``body_q``/``body_qd`` for every solver: ``semi-implicit``, ``xpbd`` and ``vbd`` never
  update ``joint_q`` (a run read from it would stand still).
- Loads: ``State.body_f`` (N,) ``spatial_vectorf`` = [force (3,) N world at the COM, torque (3,)
  N m world about the COM], read by the solvers from the step's input state and never cleared by
  them: advance() writes the step's wrench (or zeros) into the input state before every step,
  from the segments of ``self.loads``, torque arms from the state at the step's start.
- Inertia: the full 3x3 tensor about the COM in the body frame (``add_body(inertia=...)``); no
  diagonalisation.  ``finalize`` validates it (and would correct an invalid one): build() checks
  that mass, inertia, COM and gravity read back as given.
- Gravity: the builder's, -9.81 along its up axis (Z) by default: set to the case's.

Engine defaults changed (recorded in ``settings``, read back): gravity; ``angular_damping`` of
``SolverSemiImplicit`` (0.05 [1/s]: w *= 1 - 0.05 h each step, 63% of a spin's rotational energy
lost in 10 s) -> 0; of ``SolverFeatherstone`` (0.05, stored and ignored by Newton 1.8) -> 0; of
``SolverXPBD`` (0 already) -> 0; Steel's custom attribute ``steel:rigid_body_angular_damping``
(0.05, PhysX's default) -> 0 (its linear damping and velocity limits, 0 and unbounded, checked);
Kamino's ``angular_velocity_damping`` (0) -> 0; the MuJoCo solver's contacts disabled.

Precision: float32 only.  Newton's models and states are single precision (Warp ``float32``
types throughout; Warp has float64 types, Newton does not use them): mass, inertia, dt (passed
as a float32 kernel argument: 1e-3 is 0.0010000000475 s), gravity, the initial state and the loads
are rounded to float32, and the trajectory is returned widened to float64.

Stepping: ``solver.step(state_in, state_out, control, None, dt)`` from Python, one step a call,
the two states swapped after each; the per-step Python and launch overhead is most of a step
(SemiImplicit ~90-150 us, of which the body integration kernel is a few us).  State is read through
zero-copy numpy views of the CPU arrays.

Compilation: Warp compiles each solver's kernels to native CPU code on first use (5 to 40 s per
solver on 2 shared cores) and keeps them in its kernel cache on disk (``warp.config.
kernel_cache_dir``: ``$WARP_CACHE_PATH`` or the user cache folder, ``~/.cache/warp/<version>``;
already persistent and per user, so freebody adds no cache of its own), so later processes only
load them (milliseconds).  ``compile_time_s`` is the time this run spent building the solver and
in its first step beyond a regular step: the compilation, or the loading from the disk cache.
Warp's log messages (its banner, one line per module loaded) are turned off by setting
``warp.config.log_level`` to warnings when this module is imported, unless it was changed already.

Instability: Newton signals none; a blow-up comes back as computed (non-finite or huge samples),
for the harness to detect.
"""
from __future__ import annotations

import importlib.util
import sys
import time
from typing import Callable, ClassVar

import numpy as np

import warp as wp  # newton requires it: missing beside an installed newton is a broken install

if wp.config.log_level == wp.LOG_INFO:  # Warp's default: a banner and a line per module load
    wp.config.log_level = wp.LOG_WARNING
import newton  # ModuleNotFoundError "newton": the registry reports the engine missing (a skip)

from freebody.reference_impl.conventions import Trajectory, quat_wxyz_from_xyzw, quat_xyzw_from_wxyz
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec, quat_multiply
from .base import Adapter, distribution_version, LOAD_SAMPLING_PER_STEP, TrapCheck
from .capture import capture_output
from .loads import Segment

# --- this adapter's tolerances, each with its reason (the harness's rules: freebody/tolerances.py;
# the trap checks' bounds are with the trap checks below) ---------------------------------------
# Newton (Warp, float32 only).  Mass, inertia, COM, gravity and damping come back as their float32
# rounding (relative 6e-8); 1e-6 allows a few roundings.
NEWTON_READBACK_RTOL = 1e-6

DEVICE = "cpu"
# What Warp's native library prints to stderr when it initialises on a machine without an NVIDIA
# driver: irrelevant on the CPU device, dropped (any other line of Warp's initialisation is passed on).
_NO_CUDA_DRIVER = "Could not find or load the NVIDIA CUDA driver"


def _init_warp() -> None:
    """wp.init() (which does nothing once Warp is initialised) with the no-CUDA-driver notice of a
    CPU-only machine silenced; Warp's other output is passed on to stderr."""
    with capture_output() as captured:
        wp.init()
    for line in captured.lines:
        if _NO_CUDA_DRIVER not in line:
            print(line, file=sys.stderr)


_init_warp()

# freebody integrator -> Newton solver class name (offered_integrators() narrows to what imports)
_SOLVERS: dict[str, str] = {
    "semi-implicit": "SolverSemiImplicit",
    "featherstone": "SolverFeatherstone",
    "xpbd": "SolverXPBD",
    "steel": "SolverSteel",
    "vbd": "SolverVBD",
    "kamino": "SolverKamino",
}
# The MuJoCo solver's integrators: freebody name -> SolverMuJoCo(integrator=...), and the MuJoCo
# adapter's integrator of the same scheme (the C MuJoCo integrator a run of it ports; not compared
# run by run: ``compare_with`` is one engine per adapter class, so it is left None).
_MUJOCO_INTEGRATORS: dict[str, tuple[str, str]] = {
    "mujoco-euler": ("euler", "Euler"),
    "mujoco-rk4": ("rk4", "RK4"),
    "mujoco-implicit": ("implicit", "implicit"),
    "mujoco-implicitfast": ("implicitfast", "implicitfast"),
}

# What the adapter sets for Newton's traps (each read back in build(); the tests set them back to
# Newton's defaults to show that the trap checks then fail).
SEMI_IMPLICIT_ANGULAR_DAMPING = 0.0  # Newton's default 0.05 [1/s]
FEATHERSTONE_ANGULAR_DAMPING = 0.0   # Newton's default 0.05, ignored by Newton 1.8
XPBD_ANGULAR_DAMPING = 0.0           # Newton's default 0.0
STEEL_ANGULAR_DAMPING = 0.0          # steel:rigid_body_angular_damping, default 0.05
KAMINO_ANGULAR_DAMPING = 0.0         # Config.angular_velocity_damping, default 0.0
SET_GRAVITY = True                   # False: leave the builder's default (0, 0, -9.81)
READ_JOINT_Q = False                 # True: read the FREE joint's joint_q/joint_qd (wrong for some)

_NEWTON_DEFAULT_DAMPING = 0.05
_BODY = 0  # the body's index (the world is -1 in Newton)


def _quat_xyzw(q_wxyz) -> np.ndarray:
    """freebody's (w, x, y, z) -> Newton's/Warp's (x, y, z, w)."""
    return quat_xyzw_from_wxyz(np.asarray(q_wxyz, dtype=float))


def _wrench_row(force: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """A body_f entry: [force (3,) N world at the COM, torque (3,) N m world about the COM]."""
    return np.concatenate([force, torque])


def _w_to_engine(q_wxyz: np.ndarray, w_world: np.ndarray) -> np.ndarray:
    """The angular velocity as body_qd/joint_qd hold it: world frame, no conversion."""
    return w_world


def _w_from_engine(q_wxyz: np.ndarray, w_engine: np.ndarray) -> np.ndarray:
    """(N, 3) world angular velocities from body_qd's angular part (world: no conversion)."""
    return w_engine


def _solver_class(integrator: str):
    name = "SolverMuJoCo" if integrator in _MUJOCO_INTEGRATORS else _SOLVERS[integrator]
    return getattr(newton.solvers, name)


def _mujoco_available() -> bool:
    """Whether Newton's MuJoCo solver can be built: it imports mujoco_warp (and mujoco)."""
    return importlib.util.find_spec("mujoco_warp") is not None and importlib.util.find_spec("mujoco") is not None


class _Views:
    """Zero-copy numpy views of one State's arrays (CPU), re-made if a solver replaced an array."""

    def __init__(self, state):
        self.state = state
        self._arrays = (None, None, None)
        self.refresh()

    def refresh(self):
        s = self.state
        arrays = (s.body_q, s.body_qd, s.body_f)
        if any(a is not b for a, b in zip(arrays, self._arrays)):
            self._arrays = arrays
            self.q, self.qd, self.f = (a.numpy() for a in arrays)  # (1, 7), (1, 6), (1, 6) float32 views
        return self


class NewtonAdapter(Adapter):
    name: ClassVar[str] = "newton"
    import_name: ClassVar[str] = "newton"
    # verified on 1.8.0 (Warp 1.19.0); build() checks every setting it relies on
    supported_versions: ClassVar[str | None] = ">=1.8"
    integrators: ClassVar[tuple[str, ...]] = (*_SOLVERS, *_MUJOCO_INTEGRATORS)
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP
    load_sampling_note: ClassVar[str] = ("State.body_f world wrench from the step's start; one-stage solvers, but "
                                         "mujoco-rk4 holds it over its four stages")
    opt_in_integrators: ClassVar[tuple[str, ...]] = ("kamino",)
    precisions: ClassVar[tuple[str, ...]] = ("float32",)
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "body_q = (p, q) with q (x, y, z, w), Hamilton, body -> world: reordered",
        "position": "body_q's p: the body origin in world = the COM (body_com set to 0)",
        "angular velocity frame": "world (body_qd[3:6]); body_qd = (v, w): v the COM velocity in "
                                  "world first; no conversion",
        "state read": "body_q/body_qd for every solver: semi-implicit, xpbd and vbd never update "
                      "the FREE joint's joint_q/joint_qd (featherstone, steel, kamino integrate them "
                      "and compute body_q from them); both written at the start",
        "inertia input": "full 3x3 tensor about the COM, body frame (add_body); validated by "
                         "finalize, read back",
        "external loads": "State.body_f = (force at the COM, torque about the COM), world, on the "
                          "step's input state; never cleared by Newton: written before every step",
        "gravity": "builder default -9.81 along the up axis (Z); set to the case's",
        "damping": "SolverSemiImplicit and SolverFeatherstone angular_damping 0.05 by default "
                   "(Featherstone ignores it), Steel's steel:rigid_body_angular_damping 0.05: all set "
                   "to 0; XPBD and Kamino 0 already",
        "contacts": "none: no collision shape, no ground plane, contacts=None",
        "precision": "float32 only (Newton's Model/State): mass, inertia, dt, gravity, state, loads "
                     "rounded",
        "integrator": "the Newton solver: semi-implicit, featherstone, xpbd (Drake's map "
                      "quat-rate-semi-implicit), steel (Cayley gyroscopic microsteps), vbd (velocities "
                      "re-derived from poses), kamino (rescaled explicit gyroscopic term; opt-in, ~35 ms "
                      "a step), mujoco-* (only where mujoco_warp imports)",
        "compilation": "Warp JIT per solver (5-40 s cold), kept in Warp's kernel cache on disk; "
                       "compile_time_s reported apart",
        "instability signal": "none (the harness detects divergence from the state)",
    }

    # --- capabilities ---------------------------------------------------------------------------
    @classmethod
    def engine_version(cls) -> str:
        version = distribution_version("newton", lambda: getattr(newton, "__version__", "unknown"))
        return f"{version} (warp {wp.__version__})"

    @classmethod
    def offered_integrators(cls) -> tuple[str, ...]:
        """The solvers this Newton exports (by name: importing them all would define ~850 Warp
        kernels, 3.5 s); the MuJoCo solver's integrators where mujoco_warp imports."""
        exported = set(getattr(newton.solvers, "__all__", ()))
        offered = tuple(i for i, s in _SOLVERS.items() if s in exported)
        if _mujoco_available() and "SolverMuJoCo" in exported:
            offered += tuple(_MUJOCO_INTEGRATORS)
        return offered

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        """The solvers whose maps meet the self-checks' bounds, which are those of the
        exponential-map engines: high_spin allows 1e-2 rad in float32 for a 150 rad/s spin about a
        principal axis, which those maps turn exactly.  Newton's quaternion-rate update turns a
        step by 2 atan(h |w| / 2) instead of h |w|: semi-implicit, featherstone, xpbd and steel
        fail high_spin by design (5.6e-2 rad, as Drake's discrete plant); vbd also shortens the
        spin every step (|w| 150 -> 113 rad/s in 0.2 s: 3.1 rad) and turns a one-step push's
        small rotation into w through float32 finite differences (4.7e-3 against 1e-3).  Every
        solver passes the initial-state and torque-free-L checks (and all but vbd the pushes).
        Checked: kamino (exponential map, rescaled momentum), which passes all five: slow (about
        80 s, 2200 steps of ~35 ms)."""
        return tuple(i for i in cls.offered_integrators() if i == "kamino")

    # --- building -------------------------------------------------------------------------------
    def build(self) -> None:
        self._model = self._solver = self._states = None
        pb = self.problem
        cls = _solver_class(self.integrator)
        t0 = time.perf_counter()
        model = self._make_model(cls)
        self._model = model
        self._solver = self._make_solver(cls, model)
        self._build_s = time.perf_counter() - t0
        self._control = model.control()
        states = (model.state(), model.state())
        for s in states:
            self._write_state(s, pb.initial)
        self._views = [_Views(s) for s in states]
        self._zero = np.zeros(6, dtype=np.float32)
        self._f_written = [False, False]  # whether a state's body_f holds a nonzero wrench
        self._first_step_s = self._second_step_s = None
        self.compile_time_s = 0.0
        self.step_time_s = 0.0

    def _make_model(self, cls):
        """The finalized one-body model, its numbers read back."""
        pb = self.problem
        g = np.asarray(pb.gravity, dtype=float)
        builder = newton.ModelBuilder()
        g_default = np.asarray(builder.gravity, dtype=float)
        if SET_GRAVITY:
            builder.gravity = tuple(g)
        if hasattr(cls, "register_custom_attributes"):
            cls.register_custom_attributes(builder)
        init = pb.initial
        builder.add_body(xform=wp.transform(wp.vec3(*np.asarray(init.position, float)),
                                            wp.quat(*_quat_xyzw(init.quaternion_wxyz))),
                         com=wp.vec3(0.0, 0.0, 0.0), mass=float(pb.body.mass),
                         inertia=wp.mat33(*np.asarray(pb.body.I_body, float).ravel()),
                         label="freebody")
        if self.integrator == "vbd":
            builder.color()  # SolverVBD needs the bodies' coloring
        model = builder.finalize(device=DEVICE, requires_grad=False)
        f32 = np.float32
        _readback("mass", model.body_mass.numpy()[_BODY], f32(pb.body.mass))
        _readback("inertia", model.body_inertia.numpy()[_BODY], np.asarray(pb.body.I_body, f32))
        _readback("body_com", model.body_com.numpy()[_BODY], np.zeros(3))
        _readback("gravity", model.gravity.numpy()[0], np.asarray(g if SET_GRAVITY else g_default, f32))
        if model.body_count != 1 or model.joint_count != 1 or model.shape_count != 0:
            raise RuntimeError(f"newton model has {model.body_count} bodies, {model.joint_count} joints, "
                               f"{model.shape_count} shapes: expected 1, 1, 0")
        if int(model.joint_type.numpy()[0]) != int(newton.JointType.FREE):
            raise RuntimeError("newton add_body did not make a FREE joint")
        for name in ("joint_armature", "joint_damping", "joint_friction", "joint_target_ke", "joint_target_kd"):
            if np.any(getattr(model, name).numpy() != 0.0):
                raise RuntimeError(f"newton {name} of the FREE joint is not zero")
        if SET_GRAVITY:
            self.record_setting("gravity", g_default, model.gravity.numpy()[0])
        if self.integrator == "steel":
            self._set_steel_damping(model)
        return model

    def _set_steel_damping(self, model) -> None:
        steel = model.steel
        damping = steel.rigid_body_angular_damping
        default = float(damping.numpy()[_BODY])
        damping.fill_(STEEL_ANGULAR_DAMPING)
        _readback("steel:rigid_body_angular_damping", damping.numpy()[_BODY], STEEL_ANGULAR_DAMPING)
        self.record_setting("steel:rigid_body_angular_damping", default, float(damping.numpy()[_BODY]))
        # what Steel's defaults already are: no linear damping, no velocity limits
        _readback("steel:rigid_body_linear_damping", steel.rigid_body_linear_damping.numpy()[_BODY], 0.0)
        for limit in ("rigid_body_max_linear_velocity", "rigid_body_max_angular_velocity"):
            if np.isfinite(getattr(steel, limit).numpy()[_BODY]):
                raise RuntimeError(f"newton steel:{limit} is finite")

    def _make_solver(self, cls, model):
        integ = self.integrator
        if integ == "semi-implicit":
            solver = cls(model, angular_damping=SEMI_IMPLICIT_ANGULAR_DAMPING)
            self._record_damping(solver, SEMI_IMPLICIT_ANGULAR_DAMPING)
        elif integ == "featherstone":
            solver = cls(model, angular_damping=FEATHERSTONE_ANGULAR_DAMPING)
            self._record_damping(solver, FEATHERSTONE_ANGULAR_DAMPING)
            if solver.update_mass_matrix_interval != 1:
                raise RuntimeError("newton featherstone updates its mass matrix less than every step")
        elif integ == "xpbd":
            solver = cls(model, angular_damping=XPBD_ANGULAR_DAMPING)
            self._record_damping(solver, XPBD_ANGULAR_DAMPING, default=0.0)
        elif integ == "kamino":
            config = cls.Config()
            default = config.angular_velocity_damping
            config.angular_velocity_damping = KAMINO_ANGULAR_DAMPING
            solver = cls(model, config=config)
            self.record_setting("angular_velocity_damping", default, KAMINO_ANGULAR_DAMPING)
            self.record_setting("kamino integrator", config.integrator, config.integrator)
        elif integ in _MUJOCO_INTEGRATORS:
            solver = cls(model, use_mujoco_cpu=True, integrator=_MUJOCO_INTEGRATORS[integ][0],
                         disable_contacts=True)
            self.record_setting("integrator", "implicitfast", _MUJOCO_INTEGRATORS[integ][0])
            self.record_setting("use_mujoco_cpu", False, True)
            self.record_setting("disable_contacts", False, True)
        else:  # steel (damping set on the model), vbd
            solver = cls(model)
        return solver

    def _record_damping(self, solver, value: float, default: float = _NEWTON_DEFAULT_DAMPING) -> None:
        got = float(solver.angular_damping)
        if got != value:
            raise RuntimeError(f"newton {self.integrator} angular_damping read back {got}, set {value}")
        self.record_setting("angular_damping", default, got)

    def _write_state(self, state, init: InitialState) -> None:
        """The initial state into body_q/body_qd and the FREE joint's joint_q/joint_qd."""
        x = np.asarray(init.position, float)
        q_wxyz = np.asarray(init.quaternion_wxyz, float)
        v = np.asarray(init.linear_velocity, float)
        w = _w_to_engine(q_wxyz, np.asarray(init.angular_velocity, float))
        pose = np.concatenate([x, _quat_xyzw(q_wxyz)]).astype(np.float32)
        twist = np.concatenate([v, w]).astype(np.float32)
        state.body_q.assign(pose[None])
        state.body_qd.assign(twist[None])
        state.joint_q.assign(pose)
        state.joint_qd.assign(twist)
        state.body_f.zero_()

    # --- stepping -------------------------------------------------------------------------------
    def _rows(self, views: _Views) -> tuple[np.ndarray, np.ndarray]:
        if READ_JOINT_Q:
            s = views.state
            return s.joint_q.numpy(), s.joint_qd.numpy()
        return views.q[_BODY], views.qd[_BODY]

    def advance(self, steps: int) -> Trajectory:
        """Step by step with the schedule's loads; one float32 row of pose and twist per sample,
        converted once at the end.  Newton reports no instability: nothing raises here."""
        k0 = self.k
        P = np.empty((steps + 1, 7), dtype=np.float32)  # body_q rows: [x (3), q (x, y, z, w)]
        T = np.empty((steps + 1, 6), dtype=np.float32)  # body_qd rows: [v (3), w (3) world]
        cur = self._views[0].refresh()
        P[0], T[0] = self._rows(cur)
        step, control, dt = self._solver.step, self._control, self.dt
        i = 0
        for seg, ka, kb in self.loads.stretches(k0, k0 + steps):
            wrench = (None if seg.state_dependent or not seg.active
                      else _wrench_row(seg.force, seg.torque).astype(np.float32))
            for k in range(ka, kb):
                s_in, s_out = self._views[0].refresh(), self._views[1]
                if seg.active:
                    s_in.f[_BODY] = wrench if wrench is not None else _wrench_at(seg, P[i])
                    self._f_written[0] = True
                elif self._f_written[0]:
                    s_in.f[_BODY] = self._zero
                    self._f_written[0] = False
                t0 = time.perf_counter()
                step(s_in.state, s_out.state, control, None, dt)
                spent = time.perf_counter() - t0
                self._account(spent)
                self._views.reverse()
                self._f_written.reverse()
                i += 1
                P[i], T[i] = self._rows(self._views[0].refresh())
        self.k = k0 + steps
        return _trajectory(P, T, self.dt, k0)

    def _account(self, spent: float) -> None:
        """Time accounting: compile_time_s = the solver's build and first step beyond a regular
        step (the second); step_time_s = the steps, the first counted as a regular one."""
        if self._first_step_s is None:
            self._first_step_s = spent
            self.compile_time_s = self._build_s + spent
        elif self._second_step_s is None:
            self._second_step_s = spent
            self.compile_time_s = max(0.0, self._build_s + self._first_step_s - spent)
            self.step_time_s = 2.0 * spent
        else:
            self.step_time_s += spent

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """solver.step and copies of body_q/body_qd, ``steps`` times (``freebody bench``)."""
        solver, control, dt = self._solver, self._control, self.dt
        views = [v.refresh() for v in self._views]

        def loop():
            a, b = views
            P, T = np.empty((steps + 1, 7), np.float32), np.empty((steps + 1, 6), np.float32)
            P[0], T[0] = a.q[_BODY], a.qd[_BODY]
            for k in range(1, steps + 1):
                solver.step(a.state, b.state, control, None, dt)
                a, b = b, a
                P[k], T[k] = a.q[_BODY], a.qd[_BODY]
            return P, T
        return loop

    def close(self) -> None:
        self._solver = self._model = self._views = self._control = None

    # --- live checks of the traps this adapter handles ------------------------------------------
    @classmethod
    def trap_checks(cls) -> dict[str, TrapCheck]:
        return {
            "semi-implicit angular damping (0.05) off": _check_semi_implicit_damping,
            "steel angular damping (0.05) off": _check_steel_damping,
            "state read from body_q (semi-implicit, xpbd, vbd leave joint_q)": _check_read_body_q,
            "angular velocity in the world frame": _check_world_w,
            "body_f = (force, torque about the COM), world": _check_wrench_order,
            "gravity set (builder default -9.81 along Z)": _check_gravity,
        }


def _wrench_at(seg: Segment, pose_row: np.ndarray) -> np.ndarray:
    """The body_f entry (6,) float32 of a segment at a body_q row (float32 [x, q (x, y, z, w)]): the
    wrench with torque arms from the state at the step's start."""
    x = pose_row[0:3].astype(float)
    q = quat_wxyz_from_xyzw(pose_row[3:7].astype(float))
    w = seg.wrench(x, matrix_from_quat(q / np.linalg.norm(q)))
    return _wrench_row(w[0:3], w[3:6]).astype(np.float32)


def _trajectory(P: np.ndarray, T: np.ndarray, dt: float, k0: int) -> Trajectory:
    """Canonical float64 samples from body_q rows P (N, 7) and body_qd rows T (N, 6)."""
    P, T = P.astype(float), T.astype(float)
    q = quat_wxyz_from_xyzw(P[:, 3:7])
    return Trajectory.on_grid(k0, dt, P[:, 0:3], q, T[:, 0:3], _w_from_engine(q, T[:, 3:6]))


def _readback(what: str, got, want) -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    scale = np.maximum(1.0, np.abs(want))
    if got.shape != want.shape or np.any(np.abs(got - want) > NEWTON_READBACK_RTOL * scale):
        raise RuntimeError(f"newton {what} read back {got.tolist()}, set {want.tolist()}")


# --- trap checks (NewtonAdapter.trap_checks): each builds its own runs through the adapter --------

# The adapter's live trap checks (NewtonAdapter.trap_checks), float32 runs (measured values in
# parentheses: the worst of the solvers each check runs).
# A moving torque-free spin about the major axis, 200 steps at dt 0.01: relative kinetic energy
# change (3.0e-5 semi-implicit, 9.8e-6 steel: a float32 bias grows |w| by ~2e-7 a step, see
# docs/adapters.md); angular damping 0.05 takes 0.15 in 2 s.
NEWTON_TRAP_ENERGY_RTOL = 1e-3
# Free flight for 1 s: |x - x0 - v0 t| / |v0 t| (5.8e-7); read from joint_q, which semi-implicit
# and xpbd never update: 1.
NEWTON_TRAP_FREE_FLIGHT_RTOL = 1e-5
# A spin about a principal axis of a rotated body, 100 steps at dt 0.01: orientation (rad) against
# the map's exact rotation of 2 atan(h |w| / 2) a step, and w (relative) (2.1e-6); a body-frame w:
# O(1).
NEWTON_TRAP_SPIN_RAD = 1e-4
# One step of a COM force and a world couple from rest: p and L change by h f and h tau, relative
# (1.1e-6); a (torque, force) order or a body-frame torque: O(1).
NEWTON_TRAP_PUSH_RTOL = 1e-4
# Free fall for 1 s: v = g t to float32 round-off, relative (7.4e-7); the default gravity: O(1).
NEWTON_TRAP_GRAVITY_RTOL = 1e-5


def _run(problem: Problem, dt: float, steps: int, integrator: str) -> Trajectory:
    adapter = NewtonAdapter(problem, dt, integrator, "float32")
    try:
        return adapter.simulate(steps)
    finally:
        adapter.close()


def _spin_energy_change(integrator: str) -> float:
    """Max relative kinetic-energy change of a moving spin about the major axis, torque-free, 2 s."""
    dt, steps = 0.01, 200
    I_b = np.diag([1.0, 2.0, 3.0])
    pb = Problem("trap-damping", "", Body(1.0, I_b), InitialState(np.zeros(3), [1, 0, 0, 0], [1.0, -2.0, 0.5],
                                                                  [0.0, 0.0, 3.0]),
                 gravity=(0, 0, 0), duration_steps=steps)
    tr = _run(pb, dt, steps, integrator)
    w, v = tr.angular_velocity, tr.linear_velocity
    ke = 0.5 * np.einsum("ni,ij,nj->n", w, I_b, w) + 0.5 * np.einsum("ni,ni->n", v, v)
    return float(np.max(np.abs(ke / ke[0] - 1.0)))


def _check_semi_implicit_damping():
    err = _spin_energy_change("semi-implicit")
    return (err <= NEWTON_TRAP_ENERGY_RTOL, err, NEWTON_TRAP_ENERGY_RTOL,
            f"semi-implicit, a moving spin about the major axis, torque-free, 2 s at dt 0.01: max relative "
            f"kinetic energy change {err:.1e} (angular_damping 0.05: 0.15)")


def _check_steel_damping():
    err = _spin_energy_change("steel")
    return (err <= NEWTON_TRAP_ENERGY_RTOL, err, NEWTON_TRAP_ENERGY_RTOL,
            f"steel, a moving spin about the major axis, torque-free, 2 s at dt 0.01: max relative "
            f"kinetic energy change {err:.1e} (steel:rigid_body_angular_damping 0.05: 0.15)")


def _check_read_body_q():
    dt, steps = 0.01, 100
    x0, v0 = np.array([0.5, -1.0, 2.0]), np.array([1.0, 2.0, -0.5])
    pb = Problem("trap-body-q", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(x0, [1, 0, 0, 0], v0, [0.3, 0.0, 0.0]), gravity=(0, 0, 0), duration_steps=steps)
    worst = 0.0
    for integrator in ("semi-implicit", "xpbd"):
        tr = _run(pb, dt, steps, integrator)
        expected = x0 + np.outer(tr.t, v0)
        off = float(np.max(np.linalg.norm(tr.position - expected, axis=1)))
        worst = max(worst, off / (np.linalg.norm(v0) * tr.t[-1]))
    return (worst <= NEWTON_TRAP_FREE_FLIGHT_RTOL, worst, NEWTON_TRAP_FREE_FLIGHT_RTOL,
            f"free flight at 2.3 m/s for 1 s (semi-implicit, xpbd): |x - x0 - v0 t| / |v0 t| = {worst:.1e} "
            f"(read from joint_q, which they never update: 1)")


def _check_world_w():
    dt, steps, rate = 0.01, 100, 3.0
    q0 = quat_from_rotvec(np.array([0.4, -0.7, 0.25]))
    w0 = rate * (matrix_from_quat(q0) @ np.array([0.0, 0.0, 1.0]))  # about a principal axis
    pb = Problem("trap-w-frame", "", Body(1.0, np.diag([1.0, 2.0, 2.5])),
                 InitialState(np.zeros(3), q0, np.zeros(3), w0), gravity=(0, 0, 0), duration_steps=steps)
    worst = 0.0
    for integrator in ("semi-implicit", "featherstone"):
        tr = _run(pb, dt, steps, integrator)
        # no gyroscopic term: each step turns by 2 atan(h |w| / 2) about the fixed world axis
        angle = 2.0 * np.arctan(0.5 * dt * rate) * np.arange(steps + 1)
        exact = quat_multiply(quat_from_rotvec(np.outer(angle, w0 / rate)), q0)
        worst = max(worst, float(np.max(geodesic_angle(exact, tr.quaternion_wxyz))),
                    float(np.max(np.abs(tr.angular_velocity - w0))) / rate)
    return (worst <= NEWTON_TRAP_SPIN_RAD, worst, NEWTON_TRAP_SPIN_RAD,
            f"3 rad/s about a principal axis of a rotated body, 1 s at dt 0.01 (semi-implicit, featherstone): "
            f"orientation (rad) and w (relative) off by {worst:.1e} (w in the body frame: O(1))")


def _check_wrench_order():
    dt = 1e-3
    f, tau = np.array([0.0, 3.0, -2.0]), np.array([0.8, -1.5, 0.6])
    pb = Problem("trap-wrench", "", Body(2.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState([1.0, 2.0, 3.0], quat_from_rotvec(np.array([0.3, 0.2, -0.1])), np.zeros(3),
                              np.zeros(3)),
                 gravity=(0, 0, 0), loads=(Load(force=f, torque=tau, start=0.0, steps=1),), duration_steps=1)
    worst = 0.0
    for integrator in ("semi-implicit", "featherstone"):
        tr = _run(pb, dt, 1, integrator)
        I_w = matrix_from_quat(tr.quaternion_wxyz[0]) @ pb.body.I_body @ matrix_from_quat(tr.quaternion_wxyz[0]).T
        dp = pb.body.mass * (tr.linear_velocity[1] - tr.linear_velocity[0])
        dL = I_w @ (tr.angular_velocity[1] - tr.angular_velocity[0])
        worst = max(worst, float(np.linalg.norm(dp - dt * f)) / (dt * np.linalg.norm(f)),
                    float(np.linalg.norm(dL - dt * tau)) / (dt * np.linalg.norm(tau)))
    return (worst <= NEWTON_TRAP_PUSH_RTOL, worst, NEWTON_TRAP_PUSH_RTOL,
            f"one step of a COM force and a world couple from rest (semi-implicit, featherstone): momenta "
            f"change by h f and h tau to {worst:.1e} (relative; (torque, force) order: O(1))")


def _check_gravity():
    dt, steps, g = 0.01, 100, np.array([0.5, -1.0, -3.0])
    pb = Problem("trap-gravity", "", Body(1.0, np.eye(3)),
                 InitialState(np.zeros(3), [1, 0, 0, 0], np.zeros(3), np.zeros(3)), gravity=g, duration_steps=steps)
    tr = _run(pb, dt, steps, "semi-implicit")
    err = float(np.max(np.abs(tr.linear_velocity[-1] - g * tr.t[-1]))) / (np.linalg.norm(g) * tr.t[-1])
    return (err <= NEWTON_TRAP_GRAVITY_RTOL, err, NEWTON_TRAP_GRAVITY_RTOL,
            f"free fall in g = (0.5, -1, -3) from z = 0, 1 s (semi-implicit): |v - g t| / |g t| = {err:.1e} "
            f"(Newton's default (0, 0, -9.81): O(1); a ground or contact would stop it)")
