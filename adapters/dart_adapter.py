"""DART (``dartpy``) as a freebody engine: one Skeleton with a FreeJoint and one BodyNode.

DART's conventions and what this adapter converts:

- No quaternion anywhere in the API.  Poses are ``Isometry3`` transforms (3x3 rotation matrix
  body -> world, translation of the body origin in world, m).  The FreeJoint's generalized
  positions are ``[rotation vector (log map, rad, 3), translation (m, 3)]``.  The adapter writes
  the pose with ``FreeJoint.setTransform(T, World)`` (checked against ``getWorldTransform()``)
  and reads it back as the joint positions converted with ``rotations.quat_from_rotvec`` (the
  FreeJoint's rotation is the exponential map of them).
- The BodyNode's COM offset is set to zero, so body origin = COM: translation = freebody position.
- Velocities: the FreeJoint's generalized velocities are ``[omega (3), v (3)]``; in DART 6.20 both
  are world-frame (omega in rad/s, v the body-origin velocity in m/s), older releases used the
  body-frame spatial velocity.  The adapter never relies on that: it writes velocities with the
  frame-explicit ``setAngularVelocity(w, World, World)`` / ``setLinearVelocity(v, World, World)``
  (checked with ``getAngularVelocity(World, World)`` / ``getCOMLinearVelocity(World, World)``),
  and ``advance`` uses the raw coordinates only after :func:`_coordinate_frames` has probed the
  installed version and found them world-frame (or body-frame, converted with ``R``).
- Inertia: the full 3x3 tensor about the COM in the body frame, given as
  ``dartpy.dynamics.Inertia(mass, com=0, moment=I_body)`` (no diagonalisation needed).
- Loads: ``addExtForce(f, offset, isForceLocal=False, isOffsetLocal=...)`` - the offset is a
  BODY-frame point by default; ``isOffsetLocal=False`` makes it a world point.  Couples go through
  ``addExtTorque(tau, isLocal)``.  DART clears external forces after every ``World.step``:
  ``advance`` applies each active load of the step's segment of ``self.loads``, one by one, before
  every step.
- Gravity: the World's own gravity (default (0, 0, -9.81) m/s^2), set to the case's.
- Integrator: one, semi-implicit Euler with an explicit gyroscopic term (freebody's reference map
  ``semi-implicit-explicit-gyro``).  Precision: float64 only.
- Defaults changed (``settings``): time step (default 1e-3 s), gravity, deactivation (sleeping,
  enabled by default; in 6.20 it only acts on bodies in contact islands, a lone free body never
  sleeps, but it is switched off so no version can freeze a slow body).
- Divergence: DART turns non-finite, then silently substitutes identity transforms and zero
  accelerations and prints three warning lines to the C++ stderr on every later step.  The
  adapter redirects file descriptor 2 to a temporary file around stepping (once around the whole
  ``advance`` loop), detects non-finite joint coordinates (or a pose that suddenly reads as
  identity at rest) and DART's own warnings, and puts the first captured lines into the
  :class:`EngineDiverged` reason.
"""
from __future__ import annotations

import re
import sys
from typing import Callable, ClassVar

import dartpy
import numpy as np

from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.rotations import matrix_from_quat, quat_from_rotvec
from .base import Adapter, EngineDiverged, LOAD_SAMPLING_PER_STAGE
from .capture import FdCapture

# --- this adapter's tolerances, each with its reason (the harness's rules: freebody/tolerances.py)
# DART: relative tolerance for the values the adapter wrote (mass, inertia, pose, velocities,
# gravity, time step), all copied or converted in float64.
DART_READBACK_RTOL = 1e-9
# DART: a probe state read back in DART's FreeJoint coordinates matches [log R; x] and [w; v] in
# the right frame to round-off (max abs difference); the wrong frame differs by O(1).
DART_FRAME_PROBE_ATOL = 1e-12

_WORLD = dartpy.dynamics.Frame.World()

# advance() checks the recorded coordinates for divergence every this many steps
# (a vectorised check; a diverged run overshoots by at most this many steps of DART warnings).
_CHECK_EVERY = 64

# At most this many captured stderr lines go into an EngineDiverged reason.
_MAX_REASON_LINES = 3

_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _dart_lines(lines: list[str]) -> list[str]:
    """Captured stderr lines as DART's messages: ANSI colour codes removed, stripped, blank ones dropped."""
    return [ln for ln in (_ANSI.sub("", s).strip() for s in lines) if ln]


def _is_dart_instability(lines: list[str]) -> bool:
    return any("Non-finite" in ln or "instability" in ln for ln in lines)


def _reason_lines(lines: list[str]) -> str:
    shown = lines[:_MAX_REASON_LINES]
    more = len(lines) - len(shown)
    tail = f" (+{more} more lines)" if more > 0 else ""
    return "; DART stderr: " + " | ".join(shown) + tail if shown else ""


_FRAMES_CACHE: dict[str, str] = {}


def _coordinate_frames() -> str:
    """How the installed DART's FreeJoint coordinates relate to freebody's: probed once.

    Sets a rotated, moving pose through the frame-explicit API on a throwaway FreeJoint and
    compares the raw generalized coordinates.  Returns "world" (velocities = [w_world; v_world],
    DART 6.20) or "body" (velocities = [w_body; v_body], older releases); positions must be
    [log(R); translation] in both.  Raises RuntimeError if neither matches.
    """
    if "frames" in _FRAMES_CACHE:
        return _FRAMES_CACHE["frames"]
    skel = dartpy.dynamics.Skeleton("freebody_probe")
    joint, body = skel.createFreeJointAndBodyNodePair()
    body.setInertia(dartpy.dynamics.Inertia(1.0, np.zeros(3), np.diag([1.0, 2.0, 3.0])))
    R = matrix_from_quat(np.array([0.8, 0.3, -0.4, 0.2]))
    x, v, w = np.array([1.0, -2.0, 3.0]), np.array([0.5, -0.2, 0.3]), np.array([0.3, -1.1, 2.0])
    T = dartpy.math.Isometry3()
    T.set_rotation(R)
    T.set_translation(x)
    joint.setTransform(T, _WORLD)
    joint.setLinearVelocity(v, _WORLD, _WORLD)
    joint.setAngularVelocity(w, _WORLD, _WORLD)
    pos, vel = np.asarray(skel.getPositions()), np.asarray(skel.getVelocities())
    tol = DART_FRAME_PROBE_ATOL
    pos_ok = (np.abs(matrix_from_quat(quat_from_rotvec(pos[:3])) - R).max() < tol
              and np.abs(pos[3:] - x).max() < tol)
    if pos_ok and np.abs(vel - np.r_[w, v]).max() < tol:
        frames = "world"
    elif pos_ok and np.abs(vel - np.r_[R.T @ w, R.T @ v]).max() < tol:
        frames = "body"
    else:
        raise RuntimeError(
            f"dartpy {dartpy.__version__}: FreeJoint coordinates match neither [log R; x] with "
            f"world- nor body-frame [w; v] velocities (positions {pos}, velocities {vel})")
    _FRAMES_CACHE["frames"] = frames
    return frames


class DartAdapter(Adapter):
    name: ClassVar[str] = "dart"
    import_name: ClassVar[str] = "dartpy"
    # 6.16-6.18 lack World.getDeactivationOptions (every run failed with an AttributeError)
    supported_versions: ClassVar[str | None] = ">=6.19"
    integrators: ClassVar[tuple[str, ...]] = ("semi-implicit-euler",)
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STAGE
    load_sampling_note: ClassVar[str] = ("DART turns body-frame couples and body-point forces itself "
                                         "(addExtForce/addExtTorque, local flags) at its one stage, the step's "
                                         "start")
    precisions: ClassVar[tuple[str, ...]] = ("float64",)
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "none: rotation matrices (Isometry3); FreeJoint positions are "
                            "[rotation vector (log map), translation]",
        "angular velocity frame": "FreeJoint velocities [w; v] are world-frame in 6.20 (body-frame "
                                  "in older releases); freebody uses the frame-explicit "
                                  "setAngularVelocity/getAngularVelocity(World, World)",
        "inertia input": "full 3x3 tensor about the COM, body frame (dynamics.Inertia); "
                         "COM offset 0",
        "velocity clamp": "none (FreeJoint velocity limits +-inf, not enforced)",
        "damping": "none (joint damping, spring stiffness and Coulomb friction 0)",
        "sleeping": "deactivation enabled by default (acts on contact islands only in 6.20); "
                    "freebody disables it",
        "point forces": "addExtForce offset is body-frame by default; freebody passes "
                        "isOffsetLocal=False for world points; cleared after every step",
    }

    @classmethod
    def engine_version(cls) -> str:
        return str(dartpy.__version__)

    # --- building --------------------------------------------------------------------------------
    def build(self) -> None:
        pb = self.problem
        world = dartpy.simulation.World()

        dt_default = world.getTimeStep()
        world.setTimeStep(self.dt)
        _check("time step", world.getTimeStep(), self.dt)
        self.record_setting("time_step", dt_default, world.getTimeStep())

        g_default = np.array(world.getGravity(), dtype=float)
        g = np.array(pb.gravity, dtype=float)
        world.setGravity(g)
        _check("gravity", world.getGravity(), g)
        self.record_setting("gravity", g_default, np.array(world.getGravity(), dtype=float))

        opts = world.getDeactivationOptions()
        sleeping_default = bool(opts.mEnabled)
        opts.mEnabled = False
        world.setDeactivationOptions(opts)
        sleeping = bool(world.getDeactivationOptions().mEnabled)
        if sleeping:
            raise RuntimeError("dart: World.setDeactivationOptions(mEnabled=False) "
                               "did not take effect")
        self.record_setting("deactivation_enabled", sleeping_default, sleeping)

        skel = dartpy.dynamics.Skeleton("freebody")
        joint, body = skel.createFreeJointAndBodyNodePair()
        M, I_b = float(pb.body.mass), np.array(pb.body.I_body, dtype=float)
        body.setInertia(dartpy.dynamics.Inertia(M, np.zeros(3), I_b))
        inertia = body.getInertia()
        _check("mass", inertia.getMass(), M)
        _check("inertia", inertia.getMoment(), I_b)
        _check("COM offset", inertia.getLocalCOM(), np.zeros(3))
        _check_joint_defaults(joint, body)
        world.addSkeleton(skel)

        init = pb.initial
        T = dartpy.math.Isometry3()
        T.set_rotation(pb.R0)
        T.set_translation(np.array(init.position, dtype=float))
        joint.setTransform(T, _WORLD)
        joint.setLinearVelocity(np.array(init.linear_velocity, dtype=float), _WORLD, _WORLD)
        joint.setAngularVelocity(np.array(init.angular_velocity, dtype=float), _WORLD, _WORLD)
        Tw = body.getWorldTransform()
        _check("initial rotation", Tw.rotation(), pb.R0)
        _check("initial position", Tw.translation(), init.position)
        _check("initial linear velocity", body.getCOMLinearVelocity(_WORLD, _WORLD),
               init.linear_velocity)
        _check("initial angular velocity", body.getAngularVelocity(_WORLD, _WORLD),
               init.angular_velocity)

        self.world, self.skeleton, self.joint, self.body = world, skel, joint, body
        self._frames = _coordinate_frames()
        # segment k0 -> the (bound method, args) calls putting its loads on the body, load by load
        self._calls = {seg.k0: tuple(c for ld in seg.loads for c in _load_calls(body, ld))
                       for seg in self.loads.segments}

    # --- stepping --------------------------------------------------------------------------------
    def advance(self, steps: int) -> Trajectory:
        """Step ``steps`` times from the current state, shaped for speed.

        Per step: the loads of the step (precomputed calls per load segment), ``World.step``, and
        a copy of the FreeJoint's 6 positions and 6 velocities; conversion to quaternions and
        world-frame velocities happens once at the end.  fd 2 is captured around the whole loop.
        Every ``_CHECK_EVERY`` steps (counted from this call's first step) and at the last step
        the new rows are checked for non-finite values, a sudden identity-at-rest state and DART's
        own warnings; EngineDiverged carries the trajectory up to and including the first bad
        sample (and ``self.k`` is that sample's step).
        """
        skel, world = self.skeleton, self.world
        # FreeJoint coordinates as recorded, one row per sample (converted once at the end):
        # P (steps + 1, 6) = [rotation vector (rad), translation (m, world)],
        # V (steps + 1, 6) = [w (rad/s), v (m/s)] in the frame probed by _coordinate_frames().
        P = np.empty((steps + 1, 6))
        V = np.empty((steps + 1, 6))
        P[0], V[0] = skel.getPositions(), skel.getVelocities()
        k0 = self.k
        checked = 0  # rows 0..checked have been checked
        diverged: tuple[int, str] | None = None
        with FdCapture((2,)) as cap:
            for seg, ka, kb in self.loads.stretches(k0, k0 + steps):
                calls = self._calls[seg.k0]
                for i in range(ka - k0, kb - k0):
                    for fn, args in calls:
                        fn(*args)
                    world.step()
                    P[i + 1] = skel.getPositions()
                    V[i + 1] = skel.getVelocities()
                    if (i + 1) % _CHECK_EVERY == 0 or i + 1 == steps:
                        diverged = _first_bad_row(P, V, checked, i + 1)
                        if diverged is None and cap.has_output():
                            if _is_dart_instability(_dart_lines(cap.read_lines())):
                                diverged = (i + 1, "DART reported non-finite values")
                        checked = i + 1
                        if diverged is not None:
                            break
                if diverged is not None:
                    break
        n = (diverged[0] + 1) if diverged is not None else steps + 1
        self.k = k0 + n - 1
        out = self._trajectory(P[:n], V[:n], k0)
        lines = _dart_lines(cap.lines)
        if diverged is not None:
            raise EngineDiverged(self.k * self.dt, diverged[1] + _reason_lines(lines), out)
        if lines:  # unexpected output that was no instability: do not hide it
            sys.stderr.write("\n".join(lines) + "\n")
        return out

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """world.step + getPositions/getVelocities into preallocated arrays, ``steps`` times on
        this adapter's world (``freebody bench``)."""
        world, skel = self.world, self.skeleton

        def loop():
            P, V = np.empty((steps + 1, 6)), np.empty((steps + 1, 6))
            P[0], V[0] = skel.getPositions(), skel.getVelocities()
            for k in range(1, steps + 1):
                world.step()
                P[k] = skel.getPositions()
                V[k] = skel.getVelocities()
            return P, V
        return loop

    def _trajectory(self, P: np.ndarray, V: np.ndarray, k0: int) -> Trajectory:
        """Canonical trajectory from FreeJoint coordinates as recorded, the first row at t = k0 dt.

        P : (n, 6) [rotation vector of R body -> world (rad), body origin = COM (m, world)].
        V : (n, 6) [w (rad/s), v of the COM (m/s)], world frame (DART 6.20) or body frame
            (``self._frames == "body"``, rotated to world here).
        Non-finite rows stay non-finite (never replaced by DART's identity substitute).
        """
        with np.errstate(invalid="ignore", over="ignore"):
            quat = quat_from_rotvec(P[:, :3])
            if self._frames == "world":
                w, v = V[:, :3], V[:, 3:]  # copied by Trajectory.on_grid
            else:
                R = matrix_from_quat(quat)
                w = np.einsum("nij,nj->ni", R, V[:, :3])
                v = np.einsum("nij,nj->ni", R, V[:, 3:])
        return Trajectory.on_grid(k0, self.dt, P[:, 3:], quat, v, w)


# --- helpers -----------------------------------------------------------------------------------

def _check(what: str, got, want) -> None:
    got = np.asarray(got, dtype=float)
    want = np.asarray(want, dtype=float)
    scale = max(1.0, float(np.abs(want).max(initial=0.0)))
    if got.shape != want.shape or not np.all(np.abs(got - want) <= DART_READBACK_RTOL * scale):
        raise RuntimeError(f"dart: {what} read back as {got.tolist()}, set {want.tolist()}")


def _check_joint_defaults(joint, body) -> None:
    """The FreeJoint/BodyNode defaults freebody relies on (not changed, so verified)."""
    damping = [joint.getDampingCoefficient(i) for i in range(6)]
    springs = [joint.getSpringStiffness(i) for i in range(6)]
    friction = [joint.getCoulombFriction(i) for i in range(6)]
    if any(damping) or any(springs) or any(friction):
        raise RuntimeError(f"dart: FreeJoint has damping {damping}, springs {springs}, "
                           f"friction {friction}; freebody expects none")
    if joint.areLimitsEnforced() and np.isfinite(np.r_[joint.getVelocityLowerLimits(),
                                                       joint.getVelocityUpperLimits()]).any():
        raise RuntimeError("dart: FreeJoint velocity limits are enforced; freebody expects none")
    if not body.getGravityMode():
        raise RuntimeError("dart: BodyNode gravity mode is off; freebody expects it on")


def _load_calls(body, ld) -> list[tuple]:
    """The (bound method, args) calls that put one Load on the BodyNode for one step."""
    calls = []
    f = np.array(ld.force, dtype=float)
    if f.any():
        if ld.point is not None:  # world point: offset NOT local (DART's default is local)
            calls.append((body.addExtForce, (f, np.array(ld.point, dtype=float), False, False)))
        elif ld.body_point is not None:
            calls.append((body.addExtForce, (f, np.array(ld.body_point, dtype=float), False, True)))
        else:
            calls.append((body.addExtForce, (f, np.zeros(3), False, True)))
    if ld.torque.any():
        calls.append((body.addExtTorque, (np.array(ld.torque, dtype=float), False)))
    if ld.body_torque.any():
        calls.append((body.addExtTorque, (np.array(ld.body_torque, dtype=float), True)))
    return calls


def _first_bad_row(P: np.ndarray, V: np.ndarray, a: int, b: int) -> tuple[int, str] | None:
    """First row in (a, b] that is non-finite, or identity-at-rest right after a non-trivial row."""
    rows = slice(a + 1, b + 1)
    finite = np.isfinite(P[rows]).all(axis=1) & np.isfinite(V[rows]).all(axis=1)
    if not finite.all():
        return a + 1 + int(np.argmin(finite)), "DART state turned non-finite"
    trivial = ~P[a:b + 1].any(axis=1) & ~V[a:b + 1].any(axis=1)
    sudden = trivial[1:] & ~trivial[:-1]
    if sudden.any():
        return (a + 1 + int(np.argmax(sudden)), "DART pose jumped to identity with zero velocity "
                "(its substitute for a non-finite state)")
    return None
