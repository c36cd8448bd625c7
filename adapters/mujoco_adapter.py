"""MuJoCo as a freebody engine: one body with a free joint, nothing else in the world.

MuJoCo's conventions and what this adapter converts:

- Free-joint ``qpos`` (7,) = [body origin (3,) m world, quaternion (4,) Hamilton (w, x, y, z)
  body -> world].  The body frame is the case's body frame and its origin is the COM: the
  ``<inertial>`` sits at ``pos="0 0 0"`` and the compiler is told not to move the body frame onto
  the principal axes (``alignfree="false"``; build() checks that the compiled body frame is the
  XML one).  Quaternion order is already freebody's: no reordering.
- Free-joint ``qvel`` (6,) = [linear velocity (3,) m/s world, angular velocity (3,) rad/s BODY
  frame].  The adapter writes ``w_body = R^T w_world`` and reads ``w_world = R w_body`` with
  ``angular_velocity_body_from_world`` / ``angular_velocity_world_from_body``.
- Inertia: ``<inertial fullinertia="Ixx Iyy Izz Ixy Ixz Iyz">``, the full tensor about the COM in
  the body frame; the compiler diagonalises it into ``body_inertia`` (principal moments) and
  ``body_iquat`` (principal frame in the body frame).
- Loads reach every stage of MuJoCo's step as the case defines them (``load_sampling``
  per-stage): RK4 evaluates them at each of its four stages, the one-stage integrators at the
  step's start.  ``data.xfrc_applied[body]`` (6,) = [force (3,) N world, torque (3,) N m world
  about the COM] takes the forces and the world couples; ``data.qfrc_applied[3:6]`` (3,) N m takes
  the body-frame couples as they are (a free joint's rotational dofs are body frame, so MuJoCo
  turns them with every stage's orientation).  Both persist until overwritten: advance() writes
  them at the start of each stretch of steps with one set of active loads, and clears them at the
  end.  The torque of a force at a world point, (p - x) x f, or at a body point, (R b) x f, needs
  each stage's pose: while such a load acts under RK4, a ``mjcb_control`` callback (called by
  MuJoCo in every ``mj_forward``/``mj_forwardSkip``, so at every stage, with that stage's
  ``qpos``) writes ``xfrc_applied`` from the stage's qpos; under the one-stage integrators (Euler,
  implicit, implicitfast, ...: one evaluation, at the step's start) advance() writes it before
  every step, which is the same and cheaper.  The callback is process-global: it is installed
  only around those stretches, acts only on this adapter's data (another data goes to the
  callback it replaced) and the previous one is restored afterwards, even on an exception.
- ``xpos``/``xquat`` are one step stale after ``mj_step``: the state is read from ``qpos``/``qvel``.
- Instability: MuJoCo counts "Nan, Inf or huge value" warnings in ``data.warning`` and by default
  resets the body to ``qpos0`` at rest and carries on.  The adapter disables that auto-reset (so the
  last sample shows the blown-up state) and reports any increase of the watched warning counters,
  at the step that raised it.  MuJoCo before 3.2 has no switch for the auto-reset: it resets (its
  counters too), then counts the warning, so the blow-up is still detected at its step (the
  counter moves from 0, and the replay of a chunk sees the time go back to 0); the last sample is
  then the reset state, the body at rest at ``qpos0``.
- advance() is shaped for speed (see its docstring): stretches of steps without point forces
  (no loads, forces at the COM, world or body couples) run in C through ``mujoco.rollout`` (which
  stops at the first warning); the Python loop used under point forces reads the counters once per chunk of steps and replays a
  chunk whose counters moved, from a saved state, to find the step.  The trajectory, divergence
  time and counters are those of the step-by-step loop; only MuJoCo's printed log can differ (a
  chunk's steps after the bad one may print further warnings, e.g. BADQVEL, before being
  discarded).

Engine defaults this adapter changes (each recorded in ``settings`` and read back): ``timestep``
(0.002 -> dt), ``gravity`` ((0, 0, -9.81) -> the case's), ``integrator`` (Euler -> the chosen one),
the auto-reset on bad values (enabled -> disabled), and the compiler's ``alignfree`` (kept false,
recorded).  The model has no geoms, so there are no contacts to disable; damping, armature,
sleeping and fluid forces are zero/off by default and build() checks that they are.
"""
from __future__ import annotations

import functools
from contextlib import contextmanager
from typing import Callable, ClassVar

import mujoco
import numpy as np

try:  # mujoco.rollout: many steps in one C call (advance's fast path); absent in old releases
    from mujoco.rollout import Rollout as _Rollout
except ImportError:  # pragma: no cover - MuJoCo < 3.1
    _Rollout = None

from freebody.reference_impl.conventions import Trajectory, angular_velocity_body_from_world
from .base import LOAD_SAMPLING_PER_STAGE, Adapter, EngineDiverged
from .loads import Segment
from .mjcf import alignfree_default, free_joint_trajectory, fullinertia_element, inertial_element

# freebody's integrator name (MuJoCo's own spelling) -> the mjtIntegrator member, default first.
_INTEGRATOR_ENUM: dict[str, str] = {
    "Euler": "mjINT_EULER",
    "RK4": "mjINT_RK4",
    "implicit": "mjINT_IMPLICIT",
    "implicitfast": "mjINT_IMPLICITFAST",
    "discrete": "mjINT_DISCRETE",
}

# MuJoCo's instability warnings (data.warning counters) that end a run.
_WATCHED_WARNINGS: tuple[str, ...] = ("mjWARN_BADQACC", "mjWARN_BADQVEL", "mjWARN_BADQPOS",
                                      "mjWARN_INERTIA")

_BODY = 1  # body id of the free body (0 is the world)


@functools.lru_cache(maxsize=1)
def _empty_model() -> mujoco.MjModel:
    """An empty model, compiled once per process: its mjOption holds the defaults build() records
    settings against (read only; a compile per build cost ~0.7 ms, a sweep body's)."""
    return mujoco.MjModel.from_xml_string("<mujoco/>")

# The integrators that evaluate the forces at more than one stage of a step (mj_RungeKutta); the
# others evaluate them once, in the mj_forward at the step's start.
_MULTI_STAGE: frozenset[str] = frozenset({"RK4"})

# advance() is shaped for speed (MuJoCo's step of a lone body is only ~2 us):
# - a stretch of steps without point forces (no loads, COM forces, world couples in
#   xfrc_applied, body couples in qfrc_applied) and at least this long goes through mujoco.rollout, which steps in C (~1.8 us/step against
#   ~2.4 for a Python loop over mj_step); a shorter stretch is not worth its set-up (~10 us);
_ROLLOUT_MIN_STEPS = 64
# - the Python loop (state-dependent loads) reads the warning counters once every this many
#   steps, not after every step (four counter reads cost ~0.3 us/step); when one moved, the chunk
#   is replayed step by step from a saved state to find the step that raised it.
_CHECK_EVERY = 64

_FULLPHYSICS = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
# What a replayed chunk restores: the full physics state, the solver's warm start and the applied
# loads (everything mj_step reads that the loop changes).
_CHECKPOINT_SPEC = (_FULLPHYSICS | int(mujoco.mjtState.mjSTATE_WARMSTART)
                    | int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
                    | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED))
# rollout's control_spec: with XFRC_APPLIED and QFRC_APPLIED in it and no control array, rollout
# keeps the xfrc_applied and qfrc_applied already in data (without them, rollout zeroes them);
# ctrl is zeroed (unused here).
_ROLLOUT_CONTROL_SPEC = (int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
                         | int(mujoco.mjtState.mjSTATE_QFRC_APPLIED))


class MujocoAdapter(Adapter):
    name: ClassVar[str] = "mujoco"
    import_name: ClassVar[str] = "mujoco"
    # the oldest release the adapter was run on (3.1.6: no auto-reset switch, see build())
    supported_versions: ClassVar[str | None] = ">=3.1"
    integrators: ClassVar[tuple[str, ...]] = tuple(_INTEGRATOR_ENUM)
    precisions: ClassVar[tuple[str, ...]] = ("float64",)
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STAGE
    load_sampling_note: ClassVar[str] = ("body couples in qfrc_applied[3:6] (body frame), point forces' "
                                         "torques written by mjcb_control at every RK4 stage")
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (free-joint qpos[3:7]); no reorder",
        "position": "qpos[0:3]: body origin in world = COM (inertial pos 0 0 0, alignfree=false)",
        "angular velocity frame": "BODY frame in qvel[3:6]; converted w_world = R w_body",
        "linear velocity frame": "world (qvel[0:3])",
        "inertia input": "full tensor via <inertial fullinertia='Ixx Iyy Izz Ixy Ixz Iyz'>, "
                         "diagonalised by the compiler (body_inertia + body_iquat)",
        "external loads": "xfrc_applied = (force, torque about the COM), world, and qfrc_applied[3:6] "
                          "= body-frame couple; both persist until cleared",
        "velocity clamp": "none",
        "damping": "none by default (dof_damping 0, armature 0)",
        "sleeping": "off by default (mjENBL_SLEEP not set)",
        "instability": "counts mjWARN_BADQACC/BADQVEL/BADQPOS in data.warning and by default "
                       "silently resets to qpos0 at rest",
        "freebody sets": "timestep = dt, gravity = case, integrator, auto-reset disabled, "
                         "alignfree = false; no geoms (no contacts)",
    }

    # --- capabilities --------------------------------------------------------------------------
    @classmethod
    def engine_version(cls) -> str:
        return mujoco.__version__

    @classmethod
    def offered_integrators(cls) -> tuple[str, ...]:
        return tuple(n for n, e in _INTEGRATOR_ENUM.items() if hasattr(mujoco.mjtIntegrator, e))

    # --- world ---------------------------------------------------------------------------------
    def build(self) -> None:
        """Compile the one-body model, set and read back its options, write the initial state and
        prepare advance()'s views and buffers."""
        defaults = _empty_model().opt
        model = self._compile_model()
        self._set_options(model, defaults)
        data = mujoco.MjData(model)
        init = self.problem.initial
        data.qpos[0:3] = init.position
        data.qpos[3:7] = init.quaternion_wxyz
        data.qvel[0:3] = init.linear_velocity
        data.qvel[3:6] = angular_velocity_body_from_world(init.quaternion_wxyz,
                                                          init.angular_velocity)
        mujoco.mj_forward(model, data)
        self.model, self.data = model, data
        self._prepare_advance(model, data)

    def _compile_model(self) -> mujoco.MjModel:
        """The model of one free body (alignfree off, recorded), checked to keep the XML body
        frame and to have no damping, armature, friction loss, sleeping or fluid forces."""
        body = self.problem.body
        align = alignfree_default()
        compiler = '<compiler alignfree="false"/>' if align is not None else ""

        def xml(inertial: str) -> str:
            return (f'<mujoco model="freebody">{compiler}<worldbody>'
                    f'<body name="body" pos="0 0 0" quat="1 0 0 0"><freejoint name="free"/>'
                    f'{inertial}</body></worldbody></mujoco>')
        try:  # the full tensor, which inertial_element returns whenever MuJoCo takes it: one compile
            model = mujoco.MjModel.from_xml_string(xml(fullinertia_element(body.mass, body.I_body)))
        except ValueError:  # inertial_element decides (a flat body's round-off), or raises its error
            model = mujoco.MjModel.from_xml_string(xml(inertial_element(body.mass, body.I_body)))
        if align is not None:
            self.record_setting("compiler.alignfree", align, False)
        if not (np.array_equal(model.body_pos[_BODY], np.zeros(3))
                and np.array_equal(model.body_quat[_BODY], [1.0, 0.0, 0.0, 0.0])
                and np.array_equal(model.body_ipos[_BODY], np.zeros(3))):
            raise RuntimeError("mujoco moved the body frame (free-joint alignment?): "
                               f"body_pos {model.body_pos[_BODY]}, "
                               f"body_quat {model.body_quat[_BODY]}, body_ipos "
                               f"{model.body_ipos[_BODY]}; qpos would not be the body frame")
        for field in ("dof_damping", "dof_armature", "dof_frictionloss"):
            if np.any(getattr(model, field)):
                raise RuntimeError(f"mujoco model has non-zero {field}: {getattr(model, field)}")
        if model.opt.enableflags & int(getattr(mujoco.mjtEnableBit, "mjENBL_SLEEP", 0)):
            raise RuntimeError("mujoco sleeping is enabled by default in this version")
        if model.opt.density != 0.0 or model.opt.viscosity != 0.0:
            raise RuntimeError("mujoco fluid forces are on by default in this version")
        return model

    def _set_options(self, model: mujoco.MjModel, defaults) -> None:
        """Time step, gravity, integrator and (where MuJoCo has it) the auto-reset disabled, each
        read back and recorded against ``defaults`` (the mjOption of an empty model)."""
        opt = model.opt
        opt.timestep = self.dt
        _check("timestep", opt.timestep, self.dt)
        self.record_setting("timestep", defaults.timestep, float(opt.timestep))
        opt.gravity[:] = self.problem.gravity
        _check("gravity", opt.gravity, self.problem.gravity)
        self.record_setting("gravity", defaults.gravity.copy(), opt.gravity.copy())
        enum = getattr(mujoco.mjtIntegrator, _INTEGRATOR_ENUM[self.integrator])
        opt.integrator = int(enum)
        _check("integrator", opt.integrator, int(enum))
        self.record_setting("integrator", _integrator_name(defaults.integrator),
                            _integrator_name(opt.integrator))
        autoreset = getattr(mujoco.mjtDisableBit, "mjDSBL_AUTORESET", None)
        if autoreset is not None:
            before = not (opt.disableflags & int(autoreset))
            opt.disableflags |= int(autoreset)
            _check("auto-reset disabled", bool(opt.disableflags & int(autoreset)), True)
            self.record_setting("autoreset", before, False)

    def _prepare_advance(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        """The warning counters, state-row layout, checkpoint buffer and views advance() uses."""
        self._warnings = [data.warning[int(getattr(mujoco.mjtWarning, w))]
                          for w in _WATCHED_WARNINGS]
        self._warning_counts = [w.number for w in self._warnings]
        self._all_warnings = [data.warning[i] for i in range(int(mujoco.mjtWarning.mjNWARNING))]
        # Layout of an mjSTATE_FULLPHYSICS row (time, qpos, qvel, ...): rollout's output rows.
        self._nstate = mujoco.mj_stateSize(model, _FULLPHYSICS)
        n_time = mujoco.mj_stateSize(model, int(mujoco.mjtState.mjSTATE_TIME))
        n_time_qpos = mujoco.mj_stateSize(
            model, int(mujoco.mjtState.mjSTATE_TIME | mujoco.mjtState.mjSTATE_QPOS))
        self._qpos_cols = slice(n_time, n_time_qpos)                  # 7 columns
        self._qvel_cols = slice(n_time_qpos, n_time_qpos + model.nv)  # 6 columns
        self._checkpoint = np.empty(mujoco.mj_stateSize(model, _CHECKPOINT_SPEC))
        self._roller = None  # mujoco.rollout.Rollout, made on first use
        self._xfrc = data.xfrc_applied[_BODY]  # (6,) view: force (3,) N, torque (3,) N m, world
        self._torque = self._xfrc[3:6]         # (3,) view: torque about the COM, N m, world
        self._body_couple = data.qfrc_applied[3:6]  # (3,) view: couple N m, BODY frame (free joint)
        self._x = data.qpos[0:3]               # (3,) view: COM position, m, world
        self._q = data.qpos[3:7]               # (4,) view: quaternion wxyz, body -> world
        self._arm = np.empty(3)                # scratch (3,)
        self._term = np.empty(3)               # scratch (3,)

    # --- loads -----------------------------------------------------------------------------------
    def _write_wrench(self, seg: Segment) -> None:
        """The segment's loads at the current state (zeros when none is active):
        qfrc_applied[3:6] = the body-frame couples, xfrc_applied[body] = the world (force, torque
        about the COM) of the rest (:meth:`_write_point_torques`)."""
        self._body_couple[:] = 0.0 if seg.body_torque is None else seg.body_torque
        self._write_point_torques(seg)

    def _write_point_torques(self, seg: Segment) -> None:
        """xfrc_applied[body] = the forces and world couples plus the torques about the COM of the
        point forces, (p - x) x f and (R b) x f, at the pose in qpos (a stage's, when called by
        the control callback), computed by MuJoCo's 3-vector helpers (numpy's cross on a (3,)
        array costs ~10 us)."""
        self._xfrc[:] = seg.constant
        tau, arm, term, x, q = self._torque, self._arm, self._term, self._x, self._q
        for point, f in seg.point_forces:          # (p - x) x f
            mujoco.mju_sub3(arm, point, x)
            mujoco.mju_cross(term, arm, f)
            mujoco.mju_addTo3(tau, term)
        for body_point, f in seg.body_point_forces:  # (R r_b) x f
            mujoco.mju_rotVecQuat(arm, body_point, q)
            mujoco.mju_cross(term, arm, f)
            mujoco.mju_addTo3(tau, term)

    def _rewrites_per_step(self, seg: Segment) -> bool:
        """Whether the loop rewrites the point forces' torques before every step: under a point
        force with a one-stage integrator (its one evaluation is at the step's start; a Python
        write costs ~3 us a step, the control callback ~8 us a stage)."""
        return _needs_stages(seg) and self.integrator not in _MULTI_STAGE

    @contextmanager
    def _stage_loads(self, seg: Segment):
        """While a point force acts under a multi-stage integrator (RK4): mjcb_control rewrites
        xfrc_applied from the qpos of every stage MuJoCo evaluates (for this adapter's data only;
        another data is passed to the callback this one replaced, which is restored on exit).
        Nothing to do otherwise."""
        if not _needs_stages(seg) or self.integrator not in _MULTI_STAGE:
            yield
            return
        data, write = self.data, self._write_point_torques
        previous = mujoco.get_mjcb_control()

        def control(m, d):
            if d is data:
                write(seg)
            elif previous is not None:
                previous(m, d)

        mujoco.set_mjcb_control(control)
        try:
            yield
        finally:
            mujoco.set_mjcb_control(previous)

    def _warning_message(self) -> str | None:
        """The first watched warning whose counter moved since the last call (updating the
        remembered counts), or None."""
        msg = None
        for i, w in enumerate(self._warnings):
            n = w.number
            if n != self._warning_counts[i]:
                self._warning_counts[i] = n
                if msg is None:
                    enum = getattr(mujoco.mjtWarning, _WATCHED_WARNINGS[i])
                    msg = (f"mujoco {_WATCHED_WARNINGS[i]}: "
                           f"{mujoco.mju_warningText(enum, w.lastinfo).strip()}")
        return msg

    def advance(self, steps: int) -> Trajectory:
        """Step by step with the schedule's loads, shaped for speed.

        Every step's raw qpos/qvel land in one preallocated (steps + 1, nstate) array of
        mjSTATE_FULLPHYSICS rows (time, qpos (7), qvel (6)); the frame conversion is done once for
        the whole run.  The steps go stretch by stretch, a stretch being steps with one set of
        active loads: the loads are written at its start (:meth:`_write_wrench`) and, while a
        point force acts, rewritten at every stage by the control callback (:meth:`_stage_loads`).
        A stretch without point forces of at least _ROLLOUT_MIN_STEPS steps runs in C through
        mujoco.rollout; the others run in a Python loop over mj_step that reads the warning
        counters every _CHECK_EVERY steps.  Both report
        a watched warning at the step that raised it, as the base loop does (EngineDiverged with
        the trajectory up to and including that step's sample).
        """
        k0 = self.k
        data = self.data
        S = np.empty((steps + 1, self._nstate))  # row i: state at t = (k0 + i) dt
        Q, V = S[:, self._qpos_cols], S[:, self._qvel_cols]  # (steps + 1, 7), (steps + 1, 6) views
        Q[0], V[0] = data.qpos, data.qvel
        for seg, ka, kb in self.loads.stretches(k0, k0 + steps):
            self._write_wrench(seg)
            if not _needs_stages(seg) and kb - ka >= _ROLLOUT_MIN_STEPS and _Rollout is not None:
                bad = self._rollout(seg, S, ka - k0, kb - ka)
            else:
                with self._stage_loads(seg):
                    bad = self._loop(seg, Q, V, ka - k0, kb - ka)
            if bad is not None:
                i, reason = bad  # the warning was raised by the step ending at row i
                self.k = k0 + i
                raise EngineDiverged(self.k * self.dt, reason,
                                     free_joint_trajectory(Q[:i + 1], V[:i + 1], self.dt, k0))
        self.k = k0 + steps
        self._xfrc[:] = 0.0
        self._body_couple[:] = 0.0
        return free_joint_trajectory(Q, V, self.dt, k0)

    def _loop(self, seg: Segment, Q: np.ndarray, V: np.ndarray, i0: int, n: int):
        """n steps by a Python loop over mj_step into rows i0 + 1 .. i0 + n of Q (N, 7) and
        V (N, 6) (raw qpos, qvel); the loads are written (and, for point forces, the control
        callback installed).  Returns (row, reason) of the first step that raised a watched
        warning, else None."""
        model, data, step = self.model, self.data, mujoco.mj_step
        qpos, qvel = data.qpos, data.qvel
        rewrite, write = self._rewrites_per_step(seg), self._write_point_torques
        warnings, counts = self._warnings, self._warning_counts
        for c0 in range(i0, i0 + n, _CHECK_EVERY):
            c1 = min(c0 + _CHECK_EVERY, i0 + n)
            mujoco.mj_getState(model, data, self._checkpoint, _CHECKPOINT_SPEC)
            for i in range(c0, c1):
                if rewrite and i > i0:
                    write(seg)
                step(model, data)
                Q[i + 1] = qpos
                V[i + 1] = qvel
            if any(w.number != c for w, c in zip(warnings, counts)):
                return self._replay(seg, Q, V, i0, c0, c1)
        return None

    def _replay(self, seg: Segment, Q: np.ndarray, V: np.ndarray, i0: int, c0: int, c1: int):
        """A watched counter moved during the chunk of rows c0 + 1 .. c1: restore the state saved
        at its start and step again, one step at a time, to the step that raises the warning.
        Returns (row, reason) and leaves data, the counters and self._warning_counts as the base
        loop would after that step.

        The counters are left at their moved values during the replay (MuJoCo prints a warning's
        text only when its counter is zero, so it is not printed twice) and set afterwards to
        their values before the chunk plus the replayed step's increments."""
        model, data, step = self.model, self.data, mujoco.mj_step
        qpos, qvel = data.qpos, data.qvel
        warnings = self._warnings
        after_chunk = [w.number for w in warnings]
        mujoco.mj_setState(model, data, self._checkpoint, _CHECKPOINT_SPEC)
        rewrite = self._rewrites_per_step(seg)
        for i in range(c0, c1):
            if rewrite and i > i0:
                self._write_point_torques(seg)
            t_before = data.time
            step(model, data)
            if not (np.array_equal(Q[i + 1], qpos, equal_nan=True)
                    and np.array_equal(V[i + 1], qvel, equal_nan=True)):
                raise RuntimeError("mujoco: replaying a chunk from its saved state gave another "
                                   f"state at step {i + 1} (the replay does not restore enough)")
            now = [w.number for w in warnings]
            # MuJoCo without the auto-reset switch (before 3.2) resets the data at the bad step,
            # counters included, then counts the warning: the counter reads 1 after the chunk and
            # again after this step, and the time went back to 0.  The reset is the warning's step.
            reset = data.time < t_before
            if now != after_chunk or reset:
                for w, before, moved, cur in zip(warnings, self._warning_counts, after_chunk, now):
                    w.number = before + (cur if reset else cur - moved)
                return i + 1, self._warning_message()
        raise RuntimeError("mujoco: a warning counter moved during a chunk but not when it was "
                           "replayed step by step")

    def _rollout(self, seg: Segment, S: np.ndarray, i0: int, n: int):
        """n steps in C by mujoco.rollout into rows i0 + 1 .. i0 + n of S (mjSTATE_FULLPHYSICS
        rows), with the constant wrench already written in xfrc_applied.  Returns (row, reason)
        of the step that raised a watched warning, else None.

        rollout starts from the current state and warm start (given explicitly), clears every
        warning counter before it starts, and stops stepping at the first warning of any kind,
        repeating the last state (time included) in the remaining rows.  So: the counters are
        restored afterwards (added back), a watched warning is reported at the last step taken,
        and a stop on another warning (which the base loop ignores) is finished by the Python
        loop."""
        model, data = self.model, self.data
        if self._roller is None:
            self._roller = _Rollout(nthread=0)  # nthread 0: runs on this thread, no pool
        state0 = np.empty((1, self._nstate))
        mujoco.mj_getState(model, data, state0[0], _FULLPHYSICS)
        before = [w.number for w in self._all_warnings]
        out = S[i0 + 1:i0 + 1 + n]
        self._roller.rollout([model], [data], state0, control_spec=_ROLLOUT_CONTROL_SPEC,
                             nstep=n, initial_warmstart=data.qacc_warmstart.copy()[None],
                             state=out[None], skip_checks=True)
        if not any(w.number for w in self._all_warnings):
            if any(before):
                for w, b in zip(self._all_warnings, before):
                    w.number = b
            return None
        time = out[:, 0]
        stalled = np.flatnonzero(time[1:] == time[:-1])  # rows repeated after rollout stopped
        taken = int(stalled[0]) + 1 if stalled.size else n
        for w, b in zip(self._all_warnings, before):
            w.number += b
        if any(w.number != c for w, c in zip(self._warnings, self._warning_counts)):
            return i0 + taken, self._warning_message()
        if taken < n:  # stopped by a warning the base loop does not watch: carry on as it would
            return self._loop(seg, S[:, self._qpos_cols], S[:, self._qvel_cols], i0 + taken,
                              n - taken)
        return None

    def bare_loop(self, steps: int) -> Callable[[], object]:
        """mj_step and copies of qpos/qvel, ``steps`` times on this world (``freebody bench``)."""
        model, data = self.model, self.data

        def loop():
            step, qpos, qvel = mujoco.mj_step, data.qpos, data.qvel
            Q, V = np.empty((steps + 1, qpos.size)), np.empty((steps + 1, qvel.size))
            Q[0], V[0] = qpos, qvel
            for k in range(1, steps + 1):
                step(model, data)
                Q[k] = qpos
                V[k] = qvel
            return Q, V
        return loop

    def close(self) -> None:
        if getattr(self, "_roller", None) is not None:
            self._roller.close()
            self._roller = None
        self.model = self.data = None


def _needs_stages(seg: Segment) -> bool:
    """Whether the segment's loads need each stage's pose (a force at a world or body point):
    the control callback then writes them; body couples go in qfrc_applied as they are."""
    return bool(seg.point_forces or seg.body_point_forces)


def _integrator_name(value: int) -> str:
    """MuJoCo's spelling ("Euler", "RK4", ...) of an mjtIntegrator value."""
    enum = mujoco.mjtIntegrator(value).name
    return next((n for n, e in _INTEGRATOR_ENUM.items() if e == enum), enum)


def _check(what: str, got, want) -> None:
    if not np.array_equal(np.asarray(got), np.asarray(want)):
        raise RuntimeError(f"mujoco did not take the setting {what}: set {want!r}, read back {got!r}")


def rollout_seconds(models: list, datas: list, steps: int, clock: Callable[[Callable[[], object]], float]) -> float:
    """Seconds (as ``clock(fn)`` measures a call of ``fn``) of one ``mujoco.rollout`` of every
    model from its data's current state for ``steps`` steps, on one thread (one data), the output
    array allocated before the clock: ``freebody bench``'s yardstick of MuJoCo's C loop.

    models, datas : lists of B ``MjModel`` / ``MjData`` (the state read from each data).
    """
    from mujoco import rollout

    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    size = mujoco.mj_stateSize(models[0], spec)
    state0 = np.empty((len(models), size))  # (B, nstate): mjSTATE_FULLPHYSICS rows
    for i, (m, d) in enumerate(zip(models, datas)):
        mujoco.mj_getState(m, d, state0[i], spec)
    out = np.empty((len(models), steps, size))  # (B, steps, nstate)
    with rollout.Rollout(nthread=0) as roller:
        return clock(lambda: roller.rollout(models, [datas[0]], state0, nstep=steps, state=out))
