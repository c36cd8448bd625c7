"""PyBullet (Bullet 3) as a freebody engine: one free body, one DIRECT physics client per adapter.

Integrators (PyBullet's two ways to build a free body, default first):

- ``multibody``: a btMultiBody with a floating base (PyBullet's default).  Semi-implicit Euler with
  an explicit gyroscopic term and an exponential-map rotation update: the map that freebody's
  reference integrator ``semi-implicit-explicit-gyro`` implements.
- ``maximal``: ``useMaximalCoordinates=True``, a btRigidBody.  The gyroscopic term is linearised
  implicitly in the body frame (one Newton step, Bullet's BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY);
  torque-free it is the reference ``semi-implicit-implicit-gyro``.  An external torque's impulse
  h I^-1 tau is added outside that implicit step (the reference puts it inside, through J^-1), so
  under a torque the two maps differ by O(h^2 |w| |tau| / I).

PyBullet's conventions and what this adapter converts:

- Quaternions are Hamilton, scalar last ``(x, y, z, w)``, body -> world: converted with
  ``quat_wxyz_from_xyzw`` / ``quat_xyzw_from_wxyz``.
- ``getBaseVelocity`` / ``resetBaseVelocity``: linear velocity of the COM and angular velocity,
  both in the WORLD frame: canonical, no conversion.
- Inertia is diagonal only: ``localInertiaDiagonal`` (3,) kg m^2 in the principal frame whose
  orientation in the link frame is ``baseInertialFrameOrientation``.  The adapter diagonalises
  ``I_body = V diag(moments) V^T`` (numpy ``eigh``, V made right-handed), uses the link frame as
  freebody's body frame (COM at its origin: ``baseInertialFramePosition = 0``) and sets
  ``baseInertialFrameOrientation = q_V``.
- ``getBasePositionAndOrientation`` / ``resetBasePositionAndOrientation`` work on the pose of the
  INERTIAL (COM, principal) frame, not the link frame: ``q_body = q_read * q_V^-1`` on read and
  ``q_written = q_body * q_V`` on write; the position is the COM either way.
- ``resetBasePositionAndOrientation`` zeroes the velocities: the adapter sets velocities after it.
- Loads: ``applyExternalForce(..., flags=WORLD_FRAME)`` at a world point (the engine forms the
  torque (point - COM) x f itself) and ``applyExternalTorque(..., flags=WORLD_FRAME)`` for couples
  (world frame in both variants in PyBullet 3.2.7, checked by the tests).  Both last one
  ``stepSimulation``: advance() applies them before every step on which a load acts, from the
  segments of ``self.loads``.
- Gravity: ``setGravity`` (engine gravity, world frame).

Engine defaults the adapter changes (each read back, or probed, and recorded in ``settings``):
time step (1/240 s -> dt), gravity ((0, 0, 0) -> the case's), inertia ((0, 0, 0) without a
collision shape -> the principal moments), multibody linear and angular damping (0.04, a linear and
a quadratic term -> 0), the multibody velocity clamp (+-100 on each world-frame base velocity
coordinate, linear and angular -> +-MAX_COORDINATE_VELOCITY), sleeping (off by default in PyBullet
3.2.7; set to ACTIVATION_STATE_DISABLE_SLEEPING).  PyBullet has no getter for damping, the clamp or
the activation state: ``build`` proves the first two by one probe step (a spin about a principal axis
above the clamp must keep its velocity exactly), then restores the initial state.

Not fixable here: both variants cap the rotation of one step at pi/4 (|w| dt > pi/4 turns the body
by less than |w| dt while the angular velocity read back is unchanged).  PyBullet signals no
instability of its own; the harness detects divergence from the state.
"""
from __future__ import annotations

import math
from typing import Callable, ClassVar

import numpy as np
import pybullet

from freebody.reference_impl.conventions import Trajectory, quat_wxyz_from_xyzw, quat_xyzw_from_wxyz
from freebody.reference_impl.rotations import (geodesic_angle, matrix_from_quat, quat_conjugate,
                                               quat_from_matrix, quat_multiply, quat_normalize)
from .base import Adapter, distribution_version, LOAD_SAMPLING_PER_STEP
from .loads import Segment

# --- this adapter's tolerances, each with its reason (the harness's rules: freebody/tolerances.py)
# PyBullet.  Values set through the API come back bit-exact or to a few ulps; the probe step of a
# spin about a principal axis keeps |w| to ~1e-14 relative (the gyroscopic term of a spin about a
# rounded principal axis), while damping 0.04 or the clamp change it by > 1e-6 at any dt.
PYBULLET_READBACK_RTOL = 1e-12
PYBULLET_PROBE_RTOL = 1e-9
PYBULLET_INITIAL_STATE_RTOL = 1e-9  # build() re-reads the initial state (measured ~5e-16)
# PyBullet: I_body = V diag(d) V^T rebuilt from numpy's eigen-decomposition agrees to round-off
# (relative, and absolute in units of the largest principal moment).
PYBULLET_EIGEN_RTOL = 1e-12
PYBULLET_EIGEN_ATOL_REL = 1e-14

# The multibody velocity clamp is lifted to this (rad/s on each world angular-velocity coordinate,
# m/s on each linear one): far beyond any bound at which the harness declares a divergence.
MAX_COORDINATE_VELOCITY = 1.0e6

# Engine defaults PyBullet offers no getter for (values of PyBullet 3.2.7, checked by
# tests/test_pybullet_adapter.py::test_engine_defaults_are_as_documented).
DEFAULT_DAMPING = {"multibody": 0.04, "maximal": 0.0}
DEFAULT_MAX_COORDINATE_VELOCITY = 100.0  # multibody only; maximal bodies have no clamp

# Read-back and probe tolerances (PYBULLET_*, with their reasons): freebody.tolerances.
_PROBE_SPEED = 300.0  # m/s and rad/s: one world coordinate >= 300 / sqrt(3) > 100 in any frame


class _EngineLoads:
    """A segment's loads as PyBullet takes them (lists for its calls; forces of zero dropped).

    com_force : [3] N world, the sum of the forces at the COM, or None.
    world_point_forces : [(force [3] N world, point [3] m world)], applied as they are.
    body_point_forces : [(force [3] N world, body_point (3,) m body frame)].
    torque : (3,) N m world, the sum of the world couples; torque_list its list, or None when zero.
    body_torque : (3,) N m body frame, the sum of the body couples, or None.
    """

    def __init__(self, seg: Segment):
        self.com_force = None if seg.com_force is None else seg.com_force.tolist()
        self.world_point_forces = [(f.tolist(), p.tolist()) for p, f in seg.point_forces
                                   if np.any(f != 0.0)]
        self.body_point_forces = [(f.tolist(), bp) for bp, f in seg.body_point_forces
                                  if np.any(f != 0.0)]
        self.torque = seg.torque
        self.torque_list = self.torque.tolist() if np.any(self.torque != 0.0) else None
        self.body_torque = seg.body_torque
        self.needs_rotation = bool(self.body_point_forces) or self.body_torque is not None
        self.needs_pose = self.needs_rotation or self.com_force is not None


class PybulletAdapter(Adapter):
    name: ClassVar[str] = "pybullet"
    import_name: ClassVar[str] = "pybullet"
    supported_versions: ClassVar[str | None] = ">=3.2.5"  # as the engines extra requires
    integrators: ClassVar[tuple[str, ...]] = ("multibody", "maximal")
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP
    load_sampling_note: ClassVar[str] = ("world force/torque computed at the step's start "
                                         "(applyExternalForce/Torque); one-stage schemes, so the same as per-stage")
    # both variants turn a body at most pi/4 a step (btTransformUtil::integrateTransform's
    # ANGULAR_MOTION_THRESHOLD; btMultiBody::integrateTransform applies the same), see "rotation cap"
    step_rotation_cap_rad: ClassVar[float | None] = math.pi / 4
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(x, y, z, w), Hamilton, body -> world; converted to (w, x, y, z)",
        "angular velocity frame": "world (getBaseVelocity/resetBaseVelocity), no conversion",
        "pose read back": "getBasePositionAndOrientation returns the inertial (COM, principal) "
                          "frame: body = read * inertial^-1",
        "inertia input": "diagonal only (localInertiaDiagonal) in baseInertialFrameOrientation; "
                         "freebody eigen-decomposes I_body (right-handed) and sets the principal "
                         "frame quaternion; (0,0,0) without a collision shape until set",
        "velocity clamp": "multibody: each world-frame base velocity coordinate (linear and "
                          "angular) clamped to +-100 by default; freebody lifts it to +-1e6 "
                          "(maxJointVelocity). maximal: no clamp",
        "damping": "multibody: linear and angular damping 0.04 (linear + quadratic terms) by "
                   "default; maximal: 0; freebody sets 0 on both",
        "sleeping": "off by default (a body sleeps only with ACTIVATION_STATE_ENABLE_SLEEPING); "
                    "freebody sets ACTIVATION_STATE_DISABLE_SLEEPING",
        "gravity, time step": "defaults (0, 0, 0) and 1/240 s; freebody sets the case's",
        "rotation cap": "both variants turn at most ~pi/4 per step: |w| dt > pi/4 rotates "
                        "less than |w| dt (angular velocity read back unchanged); not fixable",
        "integrator": "multibody: semi-implicit Euler, explicit gyroscopic term; maximal: "
                      "gyroscopic term implicit (body frame), torque impulse h I^-1 tau added "
                      "outside it",
        "loads": "applyExternalForce / applyExternalTorque with WORLD_FRAME; last one step",
        "instability signal": "none (the harness detects divergence from the state)",
    }

    @classmethod
    def engine_version(cls) -> str:
        return distribution_version("pybullet", lambda: f"API {pybullet.getAPIVersion()}")

    # --- building -----------------------------------------------------------------------------
    def build(self) -> None:
        self._maximal = self.integrator == "maximal"
        self._cid = -1
        cid = pybullet.connect(pybullet.DIRECT)
        if cid < 0:
            raise RuntimeError("pybullet.connect(DIRECT) failed")
        self._cid = cid
        try:
            self._build(cid)
        except BaseException:
            self.close()
            raise

    def _build(self, cid: int) -> None:
        """World, body, dynamics and initial state, each read back (or probed) and recorded."""
        init = self.problem.initial
        g = self._set_world(cid)
        moments = self._set_principal_frame()
        x0 = np.array(init.position, dtype=float)
        q0 = quat_normalize(init.quaternion_wxyz)
        v0 = np.array(init.linear_velocity, dtype=float)
        w0 = np.array(init.angular_velocity, dtype=float)
        mass = float(self.problem.body.mass)

        inertia_default = self._create_body(cid, x0, q0, mass)
        self._set_dynamics(cid, mass, moments)
        self._check_created_pose(x0, q0)
        self._record_dynamics(inertia_default, moments)

        self._probe(x0, q0, g)
        self._refresh_step(x0, q0)
        self._set_initial_state(x0, q0, v0, w0)

        # V^T: principal frame -> body frame, to turn PyBullet's inertial-frame matrix into R_body.
        self._Vt = matrix_from_quat(self._q_V).T
        self._engine_loads = {seg.k0: _EngineLoads(seg) for seg in self.loads.segments
                              if seg.active}

    def _set_world(self, cid: int) -> np.ndarray:
        """Time step and gravity, read back and recorded; returns the gravity (3,) m/s^2 world."""
        dt = self.dt
        params = pybullet.getPhysicsEngineParameters(physicsClientId=cid)
        g_default = [params["gravityAccelerationX"], params["gravityAccelerationY"],
                     params["gravityAccelerationZ"]]
        dt_default = params["fixedTimeStep"]
        g = np.array(self.problem.gravity, dtype=float)
        pybullet.setTimeStep(dt, physicsClientId=cid)
        pybullet.setGravity(*g, physicsClientId=cid)
        params = pybullet.getPhysicsEngineParameters(physicsClientId=cid)
        g_read = np.array([params["gravityAccelerationX"], params["gravityAccelerationY"],
                           params["gravityAccelerationZ"]])
        if params["fixedTimeStep"] != dt:
            raise RuntimeError(f"pybullet time step read back {params['fixedTimeStep']!r}, set {dt!r}")
        if not np.array_equal(g_read, g):
            raise RuntimeError(f"pybullet gravity read back {g_read}, set {g}")
        self.record_setting("fixedTimeStep", dt_default, dt)
        self.record_setting("gravity", g_default, g)
        return g

    def _set_principal_frame(self) -> np.ndarray:
        """I_body = V diag(moments) V^T with V right-handed; q_V is the principal frame's
        orientation in the body (link) frame.  Sets _q_V, _q_V_inv, _moments; returns the
        principal moments (3,) kg m^2."""
        I_body = self.problem.body.I_body
        moments, V = np.linalg.eigh(I_body)
        if np.linalg.det(V) < 0:
            V[:, 2] = -V[:, 2]
        if not np.allclose(V @ np.diag(moments) @ V.T, I_body, rtol=PYBULLET_EIGEN_RTOL,
                           atol=PYBULLET_EIGEN_ATOL_REL * np.max(moments)):
            raise RuntimeError("eigen-decomposition of I_body failed")
        q_V = quat_from_matrix(V)
        self._q_V = q_V
        self._q_V_inv = quat_conjugate(q_V)
        self._moments = moments
        return moments

    def _create_body(self, cid: int, x0: np.ndarray, q0: np.ndarray, mass: float) -> list:
        """createMultiBody (no collision shape) at the initial pose, inertial frame at the COM
        turned by q_V; sets _body and returns the engine's default inertia diagonal."""
        body = pybullet.createMultiBody(
            baseMass=mass, baseCollisionShapeIndex=-1, baseVisualShapeIndex=-1,
            basePosition=x0.tolist(), baseOrientation=quat_xyzw_from_wxyz(q0).tolist(),
            baseInertialFramePosition=[0.0, 0.0, 0.0],
            baseInertialFrameOrientation=quat_xyzw_from_wxyz(self._q_V).tolist(),
            useMaximalCoordinates=self._maximal, physicsClientId=cid)
        if body < 0:
            raise RuntimeError("pybullet.createMultiBody failed")
        self._body = body
        return list(pybullet.getDynamicsInfo(body, -1, physicsClientId=cid)[2])

    def _set_dynamics(self, cid: int, mass: float, moments: np.ndarray) -> None:
        """Mass and inertia (mass= is passed with localInertiaDiagonal: without it a maximal body
        freezes or turns NaN), damping, clamp, sleeping; mass, inertia and (multibody) inertial
        frame read back."""
        body, q_V = self._body, self._q_V
        kwargs = dict(mass=mass, localInertiaDiagonal=moments.tolist(), linearDamping=0.0,
                      angularDamping=0.0, activationState=pybullet.ACTIVATION_STATE_DISABLE_SLEEPING)
        if not self._maximal:
            kwargs["maxJointVelocity"] = MAX_COORDINATE_VELOCITY
        pybullet.changeDynamics(body, -1, physicsClientId=cid, **kwargs)

        info = pybullet.getDynamicsInfo(body, -1, physicsClientId=cid)
        mass_read, inertia_read = info[0], np.array(info[2])
        if abs(mass_read - mass) > PYBULLET_READBACK_RTOL * mass:
            raise RuntimeError(f"pybullet mass read back {mass_read}, set {mass}")
        if not np.allclose(inertia_read, moments, rtol=PYBULLET_READBACK_RTOL, atol=0.0):
            raise RuntimeError(f"pybullet localInertiaDiagonal read back {inertia_read}, "
                               f"set {moments}")
        if not self._maximal:
            # (getDynamicsInfo's inertial-frame fields are garbage for maximal bodies; the pose
            # check of _check_created_pose proves the inertial frame in both variants.)
            pos_i, orn_i = np.array(info[3]), quat_wxyz_from_xyzw(info[4])
            if np.any(pos_i != 0.0) or geodesic_angle(orn_i, q_V) > PYBULLET_READBACK_RTOL:
                raise RuntimeError(f"pybullet inertial frame read back {pos_i}, {orn_i}; "
                                   f"set (0, 0, 0), {q_V}")

    def _check_created_pose(self, x0: np.ndarray, q0: np.ndarray) -> None:
        """The pose read back right after creation is the inertial frame: q0 * q_V."""
        x_read, q_read = self._read_pose()
        if (np.max(np.abs(x_read - x0)) > PYBULLET_INITIAL_STATE_RTOL * (1.0 + np.max(np.abs(x0)))
                or geodesic_angle(q_read, q0) > PYBULLET_INITIAL_STATE_RTOL):
            raise RuntimeError("pybullet did not take the inertial frame as expected: created at "
                               f"{x0}, {q0}; read back (converted) {x_read}, {q_read}")

    def _record_dynamics(self, inertia_default: list, moments: np.ndarray) -> None:
        """record_setting for what _set_dynamics changed (PyBullet has no getter for damping,
        the clamp or the activation state: _probe proves the first two)."""
        damping_default = DEFAULT_DAMPING[self.integrator]
        self.record_setting("localInertiaDiagonal", inertia_default, moments)
        self.record_setting("baseInertialFrameOrientation_xyzw", [0.0, 0.0, 0.0, 1.0],
                            quat_xyzw_from_wxyz(self._q_V))
        self.record_setting("linearDamping", damping_default, 0.0)
        self.record_setting("angularDamping", damping_default, 0.0)
        if not self._maximal:
            self.record_setting("maxJointVelocity", DEFAULT_MAX_COORDINATE_VELOCITY,
                                MAX_COORDINATE_VELOCITY)
        self.record_setting("activationState", "sleeping not enabled (no getter)",
                            "ACTIVATION_STATE_DISABLE_SLEEPING")

    def _refresh_step(self, x0: np.ndarray, q0: np.ndarray) -> None:
        """A step at rest at the initial pose: a maximal body's world inverse inertia is only
        recomputed by a step, and the first step's torque impulse would use a stale one."""
        cid, body = self._cid, self._body
        self._write_pose(x0, q0)
        pybullet.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=cid)
        pybullet.stepSimulation(physicsClientId=cid)

    def _set_initial_state(self, x0: np.ndarray, q0: np.ndarray, v0: np.ndarray,
                           w0: np.ndarray) -> None:
        """The initial state, read back: pose first (resetBasePositionAndOrientation zeroes
        velocities)."""
        cid, body = self._cid, self._body
        self._write_pose(x0, q0)
        pybullet.resetBaseVelocity(body, v0.tolist(), w0.tolist(), physicsClientId=cid)
        x, q = self._read_pose()
        v, w = (np.array(a) for a in pybullet.getBaseVelocity(body, physicsClientId=cid))
        scale = 1.0 + max(np.max(np.abs(x0)), np.max(np.abs(v0)), np.max(np.abs(w0)))
        err = max(np.max(np.abs(x - x0)), np.max(np.abs(v - v0)), np.max(np.abs(w - w0)))
        if err > PYBULLET_INITIAL_STATE_RTOL * scale or geodesic_angle(q, q0) > PYBULLET_INITIAL_STATE_RTOL:
            raise RuntimeError(f"pybullet initial state read back {x}, {q}, {v}, {w}; "
                               f"set {x0}, {q0}, {v0}, {w0}")

    def _probe(self, x0: np.ndarray, q0: np.ndarray, g: np.ndarray) -> None:
        """One step of a fast spin about a principal axis: proves damping 0 and no clamp.

        Torque-free, a spin about a principal axis keeps its angular velocity and the linear
        velocity gains exactly h g; damping 0.04 or the +-100 clamp would change either by far
        more than PYBULLET_PROBE_RTOL.  The caller restores the state afterwards.
        """
        cid, b, h = self._cid, self._body, self.dt
        R_principal = matrix_from_quat(q0) @ matrix_from_quat(self._q_V)  # principal -> world
        w_p = _PROBE_SPEED * R_principal[:, 0]
        v_p = _PROBE_SPEED * np.ones(3) / np.sqrt(3.0)
        self._write_pose(x0, q0)
        pybullet.resetBaseVelocity(b, v_p.tolist(), w_p.tolist(), physicsClientId=cid)
        pybullet.stepSimulation(physicsClientId=cid)
        v, w = (np.array(a) for a in pybullet.getBaseVelocity(b, physicsClientId=cid))
        dv = np.max(np.abs(v - (v_p + h * g))) / _PROBE_SPEED
        dw = np.max(np.abs(w - w_p)) / _PROBE_SPEED
        if dv > PYBULLET_PROBE_RTOL or dw > PYBULLET_PROBE_RTOL:
            raise RuntimeError(
                "pybullet damping or velocity clamp did not take effect: one torque-free step of "
                f"v = {v_p}, w = {w_p} (a principal axis) gave v = {v} (expected {v_p + h * g}), "
                f"w = {w} (relative changes {dv:.3g}, {dw:.3g} > {PYBULLET_PROBE_RTOL})")

    def _write_pose(self, x: np.ndarray, q_body_wxyz: np.ndarray) -> None:
        """resetBasePositionAndOrientation of the inertial frame for a body pose (zeroes velocities)."""
        q_inertial = quat_multiply(q_body_wxyz, self._q_V)
        pybullet.resetBasePositionAndOrientation(self._body, x.tolist(),
                                                 quat_xyzw_from_wxyz(q_inertial).tolist(),
                                                 physicsClientId=self._cid)

    def _read_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(COM position (3,) m world, body quaternion (4,) wxyz body -> world)."""
        pos, orn = pybullet.getBasePositionAndOrientation(self._body, physicsClientId=self._cid)
        return np.array(pos), self._body_quat(orn)

    def _body_quat(self, q_inertial_xyzw) -> np.ndarray:
        """Body quaternion(s) (..., 4) wxyz from the inertial-frame quaternion(s) (..., 4) xyzw
        that PyBullet reads back: q_body = q_inertial * q_V^-1 (the same arithmetic for one
        sample and for a whole trajectory)."""
        return quat_multiply(quat_wxyz_from_xyzw(q_inertial_xyzw), self._q_V_inv)

    # --- loads ----------------------------------------------------------------------------------
    def _apply_loads(self, loads: _EngineLoads) -> None:
        """applyExternalForce at world points and applyExternalTorque (world couple), WORLD_FRAME,
        for the next step.

        A force at a fixed world point goes to the engine as is (the engine forms the torque
        (point - COM) x f); a force at a body point goes at x + R body_point and the sum of the
        forces at the COM at x, with x and R the pose at the start of the step (read from the
        engine now).  Couples: torque + R body_torque.
        """
        cid, b, world = self._cid, self._body, pybullet.WORLD_FRAME
        force = pybullet.applyExternalForce
        if loads.needs_pose:
            x, orn = pybullet.getBasePositionAndOrientation(b, physicsClientId=cid)
            if loads.needs_rotation:
                # R_body = R_inertial V^T (R_inertial from PyBullet's own xyzw conversion).
                R = np.reshape(pybullet.getMatrixFromQuaternion(orn), (3, 3)) @ self._Vt
                xa = np.array(x)
                for f, bp in loads.body_point_forces:
                    force(b, -1, f, (xa + R @ bp).tolist(), world, physicsClientId=cid)
            if loads.com_force is not None:
                force(b, -1, loads.com_force, x, world, physicsClientId=cid)
        for f, p in loads.world_point_forces:
            force(b, -1, f, p, world, physicsClientId=cid)
        if loads.body_torque is not None:
            tau = (loads.torque + R @ loads.body_torque).tolist()
        else:
            tau = loads.torque_list
        if tau is not None:
            pybullet.applyExternalTorque(b, -1, tau, world, physicsClientId=cid)

    # --- stepping -------------------------------------------------------------------------------
    def advance(self, steps: int) -> Trajectory:
        """Step by step with the schedule's loads, shaped for speed.

        PyBullet's step is only ~3.5 us: the engine's tuples are appended to ONE flat list of
        floats (13 per sample: position, inertial-frame quaternion xyzw, velocity, angular
        velocity) and converted by one np.array at the end; four lists of tuples converted by
        np.array cost ~1.5 us per step, the flat list ~0.2.  Stretches of steps on which no load
        acts skip the loads altogether.  PyBullet reports no instability of its own, so nothing
        raises EngineDiverged here.
        """
        cid, b = self._cid, self._body
        step, get_pose, get_vel = (pybullet.stepSimulation, pybullet.getBasePositionAndOrientation,
                                   pybullet.getBaseVelocity)
        apply = self._apply_loads
        k0 = self.k
        F: list[float] = []  # (steps + 1) x 13 floats, see above
        extend = F.extend
        pos, orn = get_pose(b, physicsClientId=cid)
        v, w = get_vel(b, physicsClientId=cid)
        extend(pos), extend(orn), extend(v), extend(w)
        for seg, ka, kb in self.loads.stretches(k0, k0 + steps):
            if seg.active:
                loads = self._engine_loads[seg.k0]
                for _ in range(ka, kb):
                    apply(loads)
                    step(physicsClientId=cid)
                    pos, orn = get_pose(b, physicsClientId=cid)
                    v, w = get_vel(b, physicsClientId=cid)
                    extend(pos), extend(orn), extend(v), extend(w)
            else:
                for _ in range(ka, kb):
                    step(physicsClientId=cid)
                    pos, orn = get_pose(b, physicsClientId=cid)
                    v, w = get_vel(b, physicsClientId=cid)
                    extend(pos), extend(orn), extend(v), extend(w)
        self.k = k0 + steps
        A = np.array(F).reshape(steps + 1, 13)
        return Trajectory.on_grid(k0, self.dt, A[:, 0:3], self._body_quat(A[:, 3:7]), A[:, 7:10],
                                  A[:, 10:13])

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """stepSimulation + getBasePositionAndOrientation + getBaseVelocity (kept in lists),
        ``steps`` times on this adapter's client and body (``freebody bench``)."""
        cid, body = self._cid, self._body

        def loop():
            step, pose, vel = (pybullet.stepSimulation, pybullet.getBasePositionAndOrientation,
                               pybullet.getBaseVelocity)
            P, V = [pose(body, physicsClientId=cid)], [vel(body, physicsClientId=cid)]
            for _ in range(steps):
                step(physicsClientId=cid)
                P.append(pose(body, physicsClientId=cid))
                V.append(vel(body, physicsClientId=cid))
            return P, V
        return loop

    def close(self) -> None:
        cid = getattr(self, "_cid", -1)
        if cid >= 0:
            self._cid = -1
            try:
                pybullet.disconnect(physicsClientId=cid)
            except pybullet.error:  # already disconnected
                pass

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: the module may already be gone
            pass
