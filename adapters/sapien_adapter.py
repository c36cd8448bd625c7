"""SAPIEN (PhysX 5, CPU) as a freebody engine: one rigid dynamic actor, no shape, alone in a scene.

Integrators (PhysX's two solvers, SAPIEN's default first; ``PhysxSceneConfig.enable_tgs``):

- ``tgs``: PxSolverType::eTGS (SAPIEN 3.0 creates its scenes with TGS; PhysX's own default is PGS).
- ``pgs``: PxSolverType::ePGS.

Both integrate a body with no constraints by the same map (PhysX 5.3.1, ``DyDynamics.cpp``,
``DyTGSDynamics.cpp``, ``DyBodyCoreIntegrator.h``, ``DyRigidBodyToSolverBody.cpp``): the applied
force and torque become velocity changes h f / M and h I_w^-1 tau (``BodySim::updateForces``), then
gravity h g, then the gyroscopic term, explicit in the principal frame with the momentum rescaled to
its old length (PxRigidBodyFlag::eENABLE_GYROSCOPIC_FORCES, which SAPIEN sets on every dynamic body;
no API reads or changes it), then x+ = x + h v+ and q+ = normalize(Exp(h w+) q) with w world-frame.
TGS substeps its position iterations only when there are constraints; without them it integrates
once with the whole dt, so the solver iteration counts change nothing here (left at SAPIEN's 10 and
1).  freebody's engine-equivalent map is ``explicit-gyro-rescaled-momentum``
(``reference_impl/engine_maps.py``).  ``pgs`` follows it to float32 round-off: it is as far from the
float64 map as the map computed in float32 is (0.8-2.5x, five default cases, both time steps).
``tgs`` carries the velocities scaled by sqrt(I_w) (built from the float32 quaternion) and back,
which adds a float32 bias: the |w| of a steady spin grows by about 5e-7 a step
(``SAPIEN_TGS_SPIN_DRIFT_PER_STEP``; the per-step factor correlates with the quaternion's norm
error), so long ``tgs`` runs drift further from the map (still far closer to it than to any other
map on the loaded cases).  Scheme
identification therefore names the map for the shorter ``pgs`` runs and gives it as the closest
for long or chaotic float32 runs, whose per-step round-off outgrows one perturbed start's.
Float32 also means a smaller dt is not always better: on dzhanibekov at dt 0.001 the round-off of
10 000 steps moves the second flip 0.8 s early (orientation error 3.1 rad; the float64 map: 0.05).

Precision: float32 only.  PhysX stores and integrates everything in single precision: mass,
inertia, dt (``timestep`` 0.001 is 0.0010000000475 s), gravity, the initial state and the loads are
rounded to float32; the trajectory is returned widened to float64, the quaternion as read.

SAPIEN's conventions and what this adapter converts:

- ``Pose.q`` is (w, x, y, z), Hamilton, body -> world: freebody's order, no reordering.  The entity
  (actor) frame is freebody's body frame; its origin is the COM.
- Linear velocity of the COM and angular velocity, both WORLD frame: canonical, no conversion.
- Inertia is diagonal only: principal moments (``set_inertia``) in the frame ``cmass_local_pose``
  (the COM frame in the actor frame).  The adapter diagonalises ``I_body = V diag(moments) V^T``
  (numpy ``eigh``, V made proper, det +1; a diagonal I_body keeps its moments and V = 1) and sets
  ``cmass_local_pose = (0, q_V)``.  PhysX integrates that principal frame (body2World) and turns it
  back into the actor pose it reports (``body2World * cmass_local_pose^-1``, in float32).
- No collision shape: the actor's mass properties are set explicitly (``set_mass``/``set_inertia``/
  ``set_cmass_local_pose``, which also switch SAPIEN's ``auto_compute_mass`` off); with no shape and
  no ground there are no contacts.
- Gravity is the PhysX scene's, fixed when the scene is created from the global
  ``sapien.physx`` scene config (writing ``PhysxCpuSystem.config.gravity`` afterwards changes a copy
  and nothing else): build() sets the global config, creates the system and restores the config.
- Loads: ``add_force_at_point(f, p)`` at a world point (PhysX forms (p - COM) x f itself) and
  ``add_force_torque(f, tau)`` at the COM, world frame, mode "force" (an acceleration, I_w^-1 tau
  with the inertia at the pose of the call).  PhysX clears them after every step: advance() applies
  the step's loads before every step on which one acts.  Body points and body couples are turned
  into world ones with the pose read back at the start of the step.
- State read per step with ``PhysxCpuSystem.pack()`` (SAPIEN's own serialisation of every dynamic
  actor: pose (q (w, x, y, z), p), linear and angular velocity, 13 float32); build() checks the
  layout against the getters.

Engine defaults the adapter changes (each read back from the engine and recorded in ``settings``):
the solver (TGS -> the integrator's), gravity ((0, 0, -9.81) -> the case's), ``timestep`` (0.01 ->
dt), mass and inertia (1e-6 without a shape -> the case's), ``cmass_local_pose`` (identity ->
(0, q_V)), ``auto_compute_mass`` (on -> off), ``angular_damping`` (0.05 -> 0; linear damping is 0
already and set to 0), ``max_angular_velocity`` (100 rad/s, a clamp on |w| -> MAX_ANGULAR_VELOCITY),
``sleep_threshold`` (0.005: a slow body is put to sleep and stopped -> 0, never).
``max_linear_velocity`` (1e16 m/s) and ``max_depenetration_velocity`` (contacts only) are left as
they are.  A probe step in build() (a fast spin about a principal axis, then the initial state
restored) proves gravity, no damping and no clamp.

Not fixable here: PGS turns at most |w| = 1e7 rad/s per step (a clamp inside PhysX's integrator,
far beyond any bound at which the harness declares a divergence).  PhysX signals no instability of
its own (its checks are asserts of debug builds); the harness detects divergence from the state.
Importing SAPIEN needs no display: its renderer's Vulkan loader only warns that it falls back to
SAPIEN's own libvulkan, and the adapter silences that one warning (freebody never renders).
"""
from __future__ import annotations

import math
import struct
import warnings
from typing import Callable, ClassVar

import numpy as np

with warnings.catch_warnings():
    # sapien/_vulkan_tricks.py warns on import when the system has no libvulkan; rendering is
    # never used here, physics does not need it.
    warnings.filterwarnings("ignore", message="Failed to find system libvulkan",
                            category=UserWarning)
    import sapien
from sapien import physx

from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.engine_maps import physx_principal_frame
from freebody.reference_impl.problem import Body, InitialState, Problem
from freebody.reference_impl.rotations import (geodesic_angle, matrix_from_quat, quat_from_matrix, quat_from_rotvec,
                                               quat_multiply)
from .base import Adapter, distribution_version, LOAD_SAMPLING_PER_STEP, TrapCheck
from .loads import Segment

# --- this adapter's tolerances, each with its reason (the harness's rules: freebody/tolerances.py;
# the trap checks' bounds are with the trap checks below) ---------------------------------------
# SAPIEN (PhysX, float32 only).  Values set through the API come back as their float32 rounding
# (relative 6e-8); the initial state read back through pack() likewise.  1e-6 allows a few
# roundings (cmass_local_pose's quaternion is renormalised by PhysX).
SAPIEN_READBACK_RTOL = 1e-6
# SAPIEN's TGS solver scales |w| of a steady spin by about 1 + 5e-7 every step (measured 4.4e-7 to
# 5.4e-7, any dt, rate, inertia and axis; PGS: below 2e-8): a float32 bias of its solver-body
# velocities, which correlates with the quaternion's norm error after PhysX's normalisation.
SAPIEN_TGS_SPIN_DRIFT_PER_STEP = 6e-7
# build()'s probe step (300 rad/s about a principal axis, from linear rest): |w| keeps to float32
# round-off and one TGS drift (measured <= 5e-7), v = h g to an ulp; the 100 rad/s clamp changes
# |w| by 0.67, damping 0.05 by 5e-5 at dt = 1e-3 (damping is read back as well).
SAPIEN_PROBE_RTOL = 1e-5

# What the adapter sets for SAPIEN's traps (each read back in build(); the tests set them back to
# SAPIEN's defaults to show that the trap checks then fail).
# The angular velocity clamp is lifted to this (rad/s, on |w|): PhysX's own default linear cap
# (max_linear_velocity, 1e16), far beyond any bound at which the harness declares a divergence;
# its square (PhysX compares |w|^2) stays a finite float32.
MAX_ANGULAR_VELOCITY = 1.0e16
LINEAR_DAMPING = 0.0
ANGULAR_DAMPING = 0.0
SLEEP_THRESHOLD = 0.0  # PhysX sleeps a body whose energy stays below it: 0 never

# One sample of PhysxCpuSystem.pack() for one dynamic actor: 13 float32 (SAPIEN's
# SapienBodyDataTest, static_assert 52 bytes): q (w, x, y, z), p (3,), v (3,), w (3,).
_PACK_FLOATS = 13
_PACK_DTYPE = np.dtype("<f4")

_PROBE_SPEED = 300.0  # rad/s about a principal axis: far above the 100 rad/s clamp


def _f32(a) -> np.ndarray:
    """As SAPIEN takes vectors: float32 (the rounding PhysX applies anyway)."""
    return np.asarray(a, dtype=np.float32)


class _EngineLoads:
    """A segment's loads as SAPIEN takes them, as tuples of Python floats (SAPIEN rounds them to
    float32; tuples skip numpy's conversions, which would cost more than the step itself).

    world_point_forces : ((force (3,) N world, point (3,) m world), ...), applied as they are.
    body_point_forces : ((force (3,) N world, body_point (3,) m body frame), ...), placed each step.
    com_force : (3,) N world, the sum of the forces at the COM (zeros if none).
    torque : (3,) N m world, the sum of the world couples; body_torque : (3,) N m body, or None.
    at_com : whether add_force_torque is needed (a COM force or a couple acts).
    """

    def __init__(self, seg: Segment):
        def t(a) -> tuple:
            return tuple(float(c) for c in a)

        self.world_point_forces = tuple((t(f), t(p)) for p, f in seg.point_forces if np.any(f != 0.0))
        self.body_point_forces = tuple((t(f), t(bp)) for bp, f in seg.body_point_forces if np.any(f != 0.0))
        self.com_force = t(seg.com_force if seg.com_force is not None else np.zeros(3))
        self.torque = t(seg.torque)
        self.body_torque = None if seg.body_torque is None else t(seg.body_torque)
        self.at_com = bool(any(self.com_force) or any(self.torque) or self.body_torque is not None)
        self.needs_pose = bool(self.body_point_forces) or self.body_torque is not None


def _pose_of_row(row: bytes) -> tuple[tuple, tuple]:
    """(x (3,) m world, R (3, 3) body -> world as row tuples) from a pack() row (q (w, x, y, z),
    p, ...): the float32 quaternion normalised in float64, then :func:`rotations.matrix_from_quat`'s
    formula, in plain floats (a step's loads need them at the step's start)."""
    w, x, y, z, px, py, pz = struct.unpack_from("<7f", row)
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w * n, x * n, y * n, z * n
    R = ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
         (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
         (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))
    return (px, py, pz), R


def _turn(R: tuple, b: tuple) -> tuple:
    """R b for R (3, 3) row tuples and b (3,)."""
    return tuple(r[0] * b[0] + r[1] * b[1] + r[2] * b[2] for r in R)


class SapienAdapter(Adapter):
    name: ClassVar[str] = "sapien"
    import_name: ClassVar[str] = "sapien"
    # verified on 3.0.3 (PhysX 5.3.1); build() checks every setting and the pack() layout it needs
    supported_versions: ClassVar[str | None] = ">=3.0"
    integrators: ClassVar[tuple[str, ...]] = ("tgs", "pgs")
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP
    load_sampling_note: ClassVar[str] = ("world force/torque computed at the step's start (add_force_torque); "
                                         "PhysX's one-stage step, so the same as per-stage")
    precisions: ClassVar[tuple[str, ...]] = ("float32",)
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "Pose.q is (w, x, y, z), Hamilton, body -> world: no reordering",
        "angular velocity frame": "world (angular_velocity), no conversion; linear velocity: COM, world",
        "inertia input": "diagonal only (set_inertia: principal moments) in cmass_local_pose; "
                         "freebody eigen-decomposes I_body (V made proper, det +1) and sets "
                         "cmass_local_pose = (0, q_V); no collision shape: mass and inertia set "
                         "explicitly (auto_compute_mass off), 1e-6 until set",
        "velocity clamp": "max_angular_velocity 100 rad/s on |w| by default; freebody lifts it "
                          "to 1e16 (max_linear_velocity is 1e16 already)",
        "damping": "angular_damping 0.05 by default (linear 0); freebody sets both to 0",
        "sleeping": "sleep_threshold 0.005: a slow body falls asleep (velocities zeroed) after "
                    "~0.4 s; freebody sets 0 (never)",
        "gravity, time step": "scene gravity fixed at scene creation from the global scene config "
                              "(default (0, 0, -9.81)); timestep 0.01 s; freebody sets the case's",
        "precision": "float32 only (PhysX): mass, inertia, dt, gravity, state and loads rounded",
        "integrator": "tgs (SAPIEN's default) or pgs: for a lone body the same map, semi-implicit "
                      "Euler, gyroscopic term explicit in the principal frame with |L_body| "
                      "rescaled (eENABLE_GYROSCOPIC_FORCES, set by SAPIEN), world-frame exp map "
                      "(engine map explicit-gyro-rescaled-momentum)",
        "loads": "add_force_at_point (world point) / add_force_torque (COM, world), mode force; "
                 "cleared after every step",
        "contacts": "none: no collision shape, no ground",
        "instability signal": "none (the harness detects divergence from the state)",
    }

    @classmethod
    def engine_version(cls) -> str:
        return distribution_version("sapien", lambda: sapien.__version__)

    @staticmethod
    def physx_version() -> str:
        """The PhysX build SAPIEN carries (``"105.1-physx-5.3.1.patch0"`` for SAPIEN 3.0.3)."""
        return str(physx.version())

    # --- building -------------------------------------------------------------------------------
    def build(self) -> None:
        self._system = self._scene = self._entity = self._body = None
        moments, q_V = self._principal_frame()
        system = self._make_system()
        scene = sapien.Scene([system])
        entity = sapien.Entity()
        body = physx.PhysxRigidDynamicComponent()
        entity.add_component(body)
        scene.add_entity(entity)
        self._system, self._scene, self._entity, self._body = system, scene, entity, body
        self._set_body(moments, q_V)
        self._probe()
        self._set_initial_state()
        self._engine_loads = {seg.k0: _EngineLoads(seg) for seg in self.loads.segments if seg.active}

    def _principal_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(principal moments (3,) kg m^2, q_V (4,) wxyz the principal frame in the body frame)."""
        moments, V, q_V = physx_principal_frame(self.problem.body.I_body)
        self._V = V
        return moments, q_V

    def _make_system(self):
        """A PhysxCpuSystem with the case's gravity and the integrator's solver: the global scene
        config is set for its creation and restored after; both read back from the system."""
        g = np.array(self.problem.gravity, dtype=float)
        tgs = self.integrator == "tgs"
        default = physx.get_scene_config()  # a copy of the global config
        g_default = np.array(default.gravity, dtype=float)
        tgs_default = bool(default.enable_tgs)
        system = _create_system(g, tgs)
        read = system.config
        if bool(read.enable_tgs) != tgs:
            raise RuntimeError(f"sapien scene created with enable_tgs={read.enable_tgs}, asked {tgs}")
        if not np.array_equal(np.asarray(read.gravity, dtype=np.float32), _f32(g)):
            raise RuntimeError(f"sapien scene gravity read back {read.gravity}, set {g}")
        self.record_setting("enable_tgs", tgs_default, bool(read.enable_tgs))
        self.record_setting("gravity", g_default, np.asarray(read.gravity, dtype=float))
        dt_default = float(system.timestep)
        system.timestep = self.dt
        if system.timestep != float(np.float32(self.dt)):
            raise RuntimeError(f"sapien timestep read back {system.timestep!r}, set {self.dt!r}")
        self.record_setting("timestep", dt_default, float(system.timestep))
        return system

    def _set_body(self, moments: np.ndarray, q_V: np.ndarray) -> None:
        """Mass properties, damping, clamp and sleeping: SAPIEN's defaults read from the fresh
        component first, each value read back after it is set."""
        b, M = self._body, float(self.problem.body.mass)
        default = {"mass": float(b.mass), "inertia": np.asarray(b.inertia, dtype=float),
                   "cmass_local_pose": _pose_list(b.cmass_local_pose),
                   "auto_compute_mass": bool(b.auto_compute_mass),
                   "linear_damping": float(b.linear_damping), "angular_damping": float(b.angular_damping),
                   "max_angular_velocity": float(b.max_angular_velocity),
                   "sleep_threshold": float(b.sleep_threshold)}
        b.set_mass(M)
        b.set_inertia(_f32(moments))
        b.set_cmass_local_pose(sapien.Pose(_f32(np.zeros(3)), _f32(q_V)))
        b.set_linear_damping(LINEAR_DAMPING)
        b.set_angular_damping(ANGULAR_DAMPING)
        b.set_max_angular_velocity(MAX_ANGULAR_VELOCITY)
        b.set_sleep_threshold(SLEEP_THRESHOLD)

        _readback("mass", b.mass, M)
        _readback("inertia", b.inertia, moments)
        pose = b.cmass_local_pose
        _readback("cmass_local_pose.p", pose.p, np.zeros(3))
        if geodesic_angle(np.asarray(pose.q, dtype=float), q_V) > SAPIEN_READBACK_RTOL:
            raise RuntimeError(f"sapien cmass_local_pose.q read back {pose.q}, set {q_V}")
        if b.auto_compute_mass:
            raise RuntimeError("sapien auto_compute_mass still on after set_mass")
        for key, want in (("linear_damping", LINEAR_DAMPING), ("angular_damping", ANGULAR_DAMPING),
                          ("sleep_threshold", SLEEP_THRESHOLD)):
            if getattr(b, key) != np.float32(want):
                raise RuntimeError(f"sapien {key} read back {getattr(b, key)}, set {want}")
        _readback("max_angular_velocity", b.max_angular_velocity, MAX_ANGULAR_VELOCITY)

        for key in ("mass", "inertia", "auto_compute_mass", "linear_damping", "angular_damping",
                    "max_angular_velocity", "sleep_threshold"):
            self.record_setting(key, default[key], getattr(b, key))
        self.record_setting("cmass_local_pose", default["cmass_local_pose"], _pose_list(pose))

    def _probe(self) -> None:
        """One step of a fast spin about a principal axis from the initial pose, at linear rest:
        with no gyroscopic term, |w| must stay 300 rad/s (not clamped to 100, not damped by
        0.05 h) and v must become h g (the scene's gravity).  The initial state is set after it."""
        b, h = self._body, float(np.float32(self.dt))
        init = self.problem.initial
        g = np.asarray(self._system.config.gravity, dtype=float)
        R_principal = matrix_from_quat(np.asarray(init.quaternion_wxyz, dtype=float)) @ self._V
        w_p = _PROBE_SPEED * R_principal[:, 0]
        b.set_entity_pose(sapien.Pose(_f32(init.position), _f32(init.quaternion_wxyz)))
        b.set_linear_velocity(_f32(np.zeros(3)))
        b.set_angular_velocity(_f32(w_p))
        self._system.step()
        v, w = np.asarray(b.linear_velocity, dtype=float), np.asarray(b.angular_velocity, dtype=float)
        dv = np.max(np.abs(v - h * g)) / max(1.0, h * np.linalg.norm(g))
        dw = abs(np.linalg.norm(w) - _PROBE_SPEED) / _PROBE_SPEED
        if dv > SAPIEN_PROBE_RTOL or dw > SAPIEN_PROBE_RTOL:
            raise RuntimeError(
                "sapien gravity, damping or angular velocity clamp did not take effect: one step of "
                f"w = {w_p} (a principal axis) from linear rest gave v = {v} (expected {h * g}), "
                f"|w| = {np.linalg.norm(w)} (expected {_PROBE_SPEED})")

    def _set_initial_state(self) -> None:
        """The case's initial state, read back through pack() (whose layout this checks against
        the getters)."""
        init, b = self.problem.initial, self._body
        b.set_entity_pose(sapien.Pose(_f32(init.position), _f32(init.quaternion_wxyz)))
        b.set_linear_velocity(_f32(init.linear_velocity))
        b.set_angular_velocity(_f32(init.angular_velocity))
        row = np.frombuffer(self._system.pack(), dtype=_PACK_DTYPE)
        pose = b.entity_pose
        getters = np.concatenate([pose.q, pose.p, b.linear_velocity, b.angular_velocity]).astype(_PACK_DTYPE)
        if row.shape != (_PACK_FLOATS,) or not np.array_equal(row, getters):
            raise RuntimeError(f"sapien {self.engine_version()}: PhysxCpuSystem.pack() is not "
                               f"[q wxyz, p, v, w] of the one actor (pack {row}, getters {getters})")
        want = np.concatenate([init.quaternion_wxyz, init.position, init.linear_velocity,
                               init.angular_velocity]).astype(float)
        scale = np.maximum(1.0, np.abs(want))
        if np.any(np.abs(row - want) > SAPIEN_READBACK_RTOL * scale):
            raise RuntimeError(f"sapien initial state read back {row}, set {want}")

    # --- loads ----------------------------------------------------------------------------------
    def _apply_loads(self, loads: _EngineLoads, last: bytes) -> None:
        """The step's loads, world frame, at the state ``last`` (the pack() row at the start of
        the step): world points as they are, body points placed at x + R b, the couples
        torque + R body_torque with the COM force."""
        b = self._body
        for f, p in loads.world_point_forces:
            b.add_force_at_point(f, p)
        tau = loads.torque
        if loads.needs_pose:
            x, R = _pose_of_row(last)
            for f, bp in loads.body_point_forces:
                Rb = _turn(R, bp)
                b.add_force_at_point(f, (x[0] + Rb[0], x[1] + Rb[1], x[2] + Rb[2]))
            if loads.body_torque is not None:
                Rt = _turn(R, loads.body_torque)
                tau = (tau[0] + Rt[0], tau[1] + Rt[1], tau[2] + Rt[2])
        if loads.at_com:
            b.add_force_torque(loads.com_force, tau)

    # --- stepping -------------------------------------------------------------------------------
    def advance(self, steps: int) -> Trajectory:
        """Step by step with the schedule's loads; one pack() per sample (13 float32), converted
        once at the end.  PhysX reports no instability: nothing raises EngineDiverged here."""
        step, pack = self._system.step, self._system.pack
        k0 = self.k
        rows = [pack()]
        append = rows.append
        for seg, ka, kb in self.loads.stretches(k0, k0 + steps):
            if seg.active:
                loads, apply = self._engine_loads[seg.k0], self._apply_loads
                for _ in range(ka, kb):
                    apply(loads, rows[-1])
                    step()
                    append(pack())
            else:
                for _ in range(ka, kb):
                    step()
                    append(pack())
        self.k = k0 + steps
        A = np.frombuffer(b"".join(rows), dtype=_PACK_DTYPE).reshape(steps + 1, _PACK_FLOATS).astype(float)
        return Trajectory.on_grid(k0, self.dt, A[:, 4:7], A[:, 0:4], A[:, 7:10], A[:, 10:13])

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """PhysxCpuSystem.step + pack() (kept in a list), ``steps`` times (``freebody bench``)."""
        system = self._system

        def loop():
            step, pack = system.step, system.pack
            rows = [pack()]
            for _ in range(steps):
                step()
                rows.append(pack())
            return rows
        return loop

    def close(self) -> None:
        scene = getattr(self, "_scene", None)
        if scene is not None:
            entity = getattr(self, "_entity", None)
            if entity is not None:
                scene.remove_entity(entity)
        self._system = self._scene = self._entity = self._body = None

    # --- live checks of the traps this adapter handles --------------------------------------------
    @classmethod
    def trap_checks(cls) -> dict[str, TrapCheck]:
        return {
            "angular velocity clamp (100 rad/s) lifted": _check_clamp,
            "angular damping (0.05) off": _check_damping,
            "sleeping (threshold 0.005) off": _check_sleep,
            "full inertia diagonalised (proper frame)": _check_full_inertia,
            "gravity set at scene creation": _check_gravity,
        }


def _create_system(gravity: np.ndarray, tgs: bool):
    """A PhysxCpuSystem whose PhysX scene has this gravity (3,) m/s^2 world and solver (TGS or PGS).

    PhysX takes both when the scene is created, from SAPIEN's global scene config: it is set for
    the creation and restored afterwards (``get_scene_config`` returns a copy).  Writing
    ``system.config.gravity`` later would change SAPIEN's copy and not the PhysX scene."""
    saved = physx.get_scene_config()
    config = physx.get_scene_config()
    config.gravity = _f32(gravity)
    config.enable_tgs = bool(tgs)
    physx.set_scene_config(config)
    try:
        return physx.PhysxCpuSystem()
    finally:
        physx.set_scene_config(saved)


def _pose_list(pose) -> list:
    """A SAPIEN Pose as [p (3,), q (4,) wxyz], plain floats (for settings)."""
    return [np.asarray(pose.p, dtype=float).tolist(), np.asarray(pose.q, dtype=float).tolist()]


def _readback(what: str, got, want) -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    scale = np.maximum(1.0, np.abs(want))
    if got.shape != want.shape or np.any(np.abs(got - want) > SAPIEN_READBACK_RTOL * scale):
        raise RuntimeError(f"sapien {what} read back {got.tolist()}, set {want.tolist()}")


# --- trap checks (SapienAdapter.trap_checks): each builds its own runs through the adapter, on
# both solvers, and returns the worse of the two -------------------------------------------------

# The adapter's live trap checks (SapienAdapter.trap_checks), float32 runs on both solvers, each
# bound 10x the TGS drift over the check's steps (measured values in parentheses).
# 150 rad/s about a principal axis, 1000 steps: | |w| / 150 - 1 | (5.3e-4); clamped: 0.33.
SAPIEN_TRAP_SPIN_RTOL = 10 * 1000 * SAPIEN_TGS_SPIN_DRIFT_PER_STEP
# A moving torque-free spin about the major axis, 200 steps: relative kinetic energy change
# (1.2e-4; E ~ |w|^2: twice the drift); angular damping 0.05 takes 0.18 in 2 s.
SAPIEN_TRAP_ENERGY_RTOL = 10 * 2 * 200 * SAPIEN_TGS_SPIN_DRIFT_PER_STEP
# A slow drift, 100 steps: relative change of the velocities (4.1e-5); asleep they would be 0 (1).
SAPIEN_TRAP_SLEEP_RTOL = 10 * 100 * SAPIEN_TGS_SPIN_DRIFT_PER_STEP
# A full inertia tensor against the same body given diagonal, 100 steps at dt 0.01, non-chaotic:
# orientation (rad) and w (relative) agree to round-off growth (2.6e-5); the diagonal part alone,
# or an improper principal frame, is O(1) off.
SAPIEN_TRAP_FULL_INERTIA_RAD = 1e-3
# Free fall for 1 s: v = g t to float32 round-off, relative (7.4e-7); the default gravity: O(1).
SAPIEN_TRAP_GRAVITY_RTOL = 1e-5


def _runs(problem: Problem, dt: float, steps: int) -> list[Trajectory]:
    out = []
    for integrator in SapienAdapter.integrators:
        adapter = SapienAdapter(problem, dt, integrator, "float32")
        try:
            out.append(adapter.simulate(steps))
        finally:
            adapter.close()
    return out


def _check_clamp():
    rate, dt, steps = 150.0, 1e-3, 1000
    q0 = quat_from_rotvec(np.array([0.2, 0.1, -0.3]))
    w0 = rate * (matrix_from_quat(q0) @ np.array([0.0, 0.0, 1.0]))  # a principal axis
    pb = Problem("trap-clamp", "", Body(1.0, np.diag([1.0, 2.0, 2.5])),
                 InitialState(np.zeros(3), q0, np.zeros(3), w0), gravity=(0, 0, 0), duration_steps=steps)
    err = max(float(np.max(np.abs(np.linalg.norm(tr.angular_velocity, axis=1) / rate - 1.0)))
              for tr in _runs(pb, dt, steps))
    return (err <= SAPIEN_TRAP_SPIN_RTOL, err, SAPIEN_TRAP_SPIN_RTOL,
            f"150 rad/s about a principal axis for 1 s (tgs, pgs): max | |w| / 150 - 1 | = {err:.1e} "
            f"(clamped to 100 rad/s: 0.33)")


def _check_damping():
    dt, steps = 0.01, 200
    I_b = np.diag([1.0, 2.0, 3.0])
    pb = Problem("trap-damping", "", Body(1.0, I_b), InitialState(np.zeros(3), [1, 0, 0, 0], [1.0, -2.0, 0.5],
                                                                  [0.0, 0.0, 3.0]),
                 gravity=(0, 0, 0), duration_steps=steps)
    worst = 0.0
    for tr in _runs(pb, dt, steps):
        w, v = tr.angular_velocity, tr.linear_velocity
        ke = 0.5 * np.einsum("ni,ij,nj->n", w, I_b, w) + 0.5 * np.einsum("ni,ni->n", v, v)
        worst = max(worst, float(np.max(np.abs(ke / ke[0] - 1.0))))
    return (worst <= SAPIEN_TRAP_ENERGY_RTOL, worst, SAPIEN_TRAP_ENERGY_RTOL,
            f"a moving spin about the major axis, torque-free, 2 s (tgs, pgs): max relative kinetic "
            f"energy change {worst:.1e} (angular damping 0.05: 0.18)")


def _check_sleep():
    dt, steps = 0.01, 100
    v0, w0 = np.array([5e-4, 0.0, 0.0]), np.array([0.0, 0.0, 1e-3])
    pb = Problem("trap-sleep", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), [1, 0, 0, 0], v0, w0), gravity=(0, 0, 0), duration_steps=steps)
    err = max(max(float(np.max(np.abs(tr.linear_velocity - v0))) / np.linalg.norm(v0),
                  float(np.max(np.abs(tr.angular_velocity - w0))) / np.linalg.norm(w0))
              for tr in _runs(pb, dt, steps))
    return (err <= SAPIEN_TRAP_SLEEP_RTOL, err, SAPIEN_TRAP_SLEEP_RTOL,
            f"a slow drift (5e-4 m/s, 1e-3 rad/s), 1 s (tgs, pgs): velocities change by {err:.1e} "
            f"(relative; put to sleep after ~0.4 s they would be 0: 1)")


def _check_full_inertia():
    dt, steps = 0.01, 100
    Q = matrix_from_quat(quat_from_rotvec(np.array([0.3, -1.2, 0.7])))  # body axes -> principal axes
    q_p = quat_from_rotvec(np.array([0.4, 0.2, -0.1]))  # principal frame -> world
    w0 = np.array([0.3, 2.0, -0.4])
    diag = Problem("trap-diag", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                   InitialState(np.zeros(3), q_p, np.zeros(3), w0), gravity=(0, 0, 0), duration_steps=steps)
    # the same body and motion described in a body frame turned by Q: a full tensor Q^T D Q
    full = Problem("trap-full", "", Body(1.0, Q.T @ np.diag([1.0, 2.0, 3.0]) @ Q),
                   InitialState(np.zeros(3), quat_from_matrix(matrix_from_quat(q_p) @ Q), np.zeros(3), w0),
                   gravity=(0, 0, 0), duration_steps=steps)
    q_Qt = quat_from_matrix(Q.T)
    err = 0.0
    for a, b in zip(_runs(diag, dt, steps), _runs(full, dt, steps)):
        back = quat_multiply(b.quaternion_wxyz, q_Qt)  # the full body's frame turned onto the principal one
        err = max(err, float(np.max(geodesic_angle(a.quaternion_wxyz, back))),
                  float(np.max(np.abs(a.angular_velocity - b.angular_velocity))) / np.linalg.norm(w0))
    return (err <= SAPIEN_TRAP_FULL_INERTIA_RAD, err, SAPIEN_TRAP_FULL_INERTIA_RAD,
            f"diag(1, 2, 3) given as a rotated full tensor moves as given diagonal, 1 s at dt 0.01 "
            f"(tgs, pgs): orientation (rad) and w (relative) differ by {err:.1e} (its diagonal alone: O(1))")


def _check_gravity():
    dt, steps, g = 0.01, 100, np.array([0.5, -1.0, -3.0])
    pb = Problem("trap-gravity", "", Body(1.0, np.eye(3)),
                 InitialState(np.zeros(3), [1, 0, 0, 0], np.zeros(3), np.zeros(3)), gravity=g,
                 duration_steps=steps)
    err = max(float(np.max(np.abs(tr.linear_velocity[-1] - g * tr.t[-1]))) / (np.linalg.norm(g) * tr.t[-1])
              for tr in _runs(pb, dt, steps))
    return (err <= SAPIEN_TRAP_GRAVITY_RTOL, err, SAPIEN_TRAP_GRAVITY_RTOL,
            f"free fall in g = (0.5, -1, -3), 1 s (tgs, pgs): |v - g t| / |g t| = {err:.1e} "
            f"(SAPIEN's default (0, 0, -9.81): O(1))")
