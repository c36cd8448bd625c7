"""MJX (MuJoCo's JAX port, ``mujoco-mjx``) as a freebody engine, in float32 or float64.

The world is the MuJoCo adapter's: :class:`~freebody.adapters.mujoco_adapter.MujocoAdapter` builds
the MJCF and the C ``MjModel``/``MjData`` (one body, a free joint, full inertia, alignfree off, the
case's timestep, gravity and integrator, initial state written and ``mj_forward`` done), and this
adapter moves them to JAX with ``mjx.put_model`` / ``mjx.put_data``.  So MJX's conventions are
MuJoCo's, converted the same way:

- ``qpos`` (7,) = [body origin = COM (3,) m world, quaternion (4,) (w, x, y, z) body -> world]:
  no reordering.
- ``qvel`` (6,) = [linear velocity (3,) m/s world, angular velocity (3,) rad/s BODY frame]:
  written as ``R^T w_world`` by the MuJoCo adapter, read back as ``R w_body``.
- Loads: ``xfrc_applied[1]`` (6,) = [force (3,) N world, torque (3,) N m world about the COM],
  rewritten before every step inside the scan (see below), and ``qfrc_applied[3:6]`` (3,) N m,
  the body-frame couples (a free joint's rotational dofs are body frame).  MJX's RK4 evaluates
  both at each of its four stages but cannot rewrite xfrc_applied between them, so the load
  sampling (``run_load_sampling``) depends on the case: without forces at points (COM forces,
  world and body couples only) every load reaches every stage as the case defines it
  (per-stage: the body couple turns with each stage's orientation through qfrc_applied); with a
  force at a world or body point anywhere in the case, the whole wrench (the body couple's R_k
  tau_b included) is the world value at the step's start held over the step (per-step), the
  MuJoCo adapter's old rule, arms from the state at the start of the step.

Stepping.  ``advance(n)`` is ``jax.lax.scan`` of ``mjx.step`` under ``jax.jit`` over chunks of
``CHUNK_STEPS`` steps (in lane 0 of the lanes program, see "Batches"), so n steps cost
ceil(n / CHUNK_STEPS) calls from Python and one compilation per (model structure, integrator,
precision) and process: the model is an argument of
the compiled function (not a constant), so bodies of different mass and inertia share it.  A chunk
of fewer real steps (the last one, or every one when the harness delivers a run in pieces) is
padded to ``CHUNK_STEPS`` with steps that leave the Data as it is (``lax.cond`` on the step
index), so the Data carried on is that of the last real step and a run cut into pieces of any
size is the one-piece run bit for bit.  The compiled executables are kept in a module-level
cache; ``compile_time_s`` on the adapter is the time this run spent tracing and compiling (0 when
the cache had it), ``step_time_s`` the time spent stepping.

One structure per (integrator, precision).  MJX keeps part of a model as static structure (numpy
arrays hashed into the pytree's aux data).  For one free body the only static facts that differ
between bodies are those of MuJoCo's "simple body" optimisation: a body whose principal frame is
its body frame (inertia diagonal with Ixx >= Iyy >= Izz: MuJoCo sorts the principal moments) gets
a diagonal mass-matrix sparsity (``M_rownnz``, ``M_rowadr``, ``M_colind``, ``nC``,
``dof_simplenum``, ``body_simple``, ``body_sameframe``); any other body the full lower triangle.
On CPU (dense mass matrix) MJX uses that sparsity in one place only, the mask that
``support.make_m`` multiplies the mass matrix by.  Giving every body the full pattern would keep
the round-off off-diagonal terms of a principal-frame body and change its trajectory in the last
bits, so instead :func:`_normalise` gives every model the full pattern's structure and passes the
body's own mask as a runtime argument, which a copy of ``make_m``'s dense branch (in force only
while the adapter traces, and only for the ``make_m`` source it was checked against) multiplies
by: the same arithmetic, one compilation for all bodies (bit for bit the un-normalised model's
trajectories: tests/test_mjx_structure.py, and the default suite's 210 mjx runs).

Persistent compilation cache (:mod:`freebody.adapters.jax_runtime`, shared with the Brax
adapter).  Importing this module points JAX's persistent compilation cache
at ``$XDG_CACHE_HOME/freebody/jax`` (default ``~/.cache/freebody/jax``, created with the user's
umask) unless ``JAX_COMPILATION_CACHE_DIR`` (or ``jax_compilation_cache_dir``) names another
folder, and lets JAX keep every compiled program however quick its compilation; JAX's own
``JAX_ENABLE_COMPILATION_CACHE=false`` turns it off.  A compilation found there costs only
tracing and loading (a few tenths of a second instead of seconds), in serial runs and in every
worker process alike, across invocations.  Processes compiling the same (kind, integrator,
precision) at once take turns (a lock file in the cache folder), so the second one loads what the
first compiled instead of compiling it again.  :data:`COMPILE_STATS` counts this process's
compilations and disk loads.

Per-step loads are a (steps, LOAD_ROW) float array (``jax_runtime.load_rows``) computed before
each chunk from the run's :class:`~freebody.adapters.loads.LoadSchedule` (``self.loads``); inside
the scan the state-dependent parts use the current ``qpos``:  world torque = const + (c - x) x
F_point + axial(R M) + R tau_body, where ``c`` is the first world-point load's point (the other world-point
loads' (p_i - c) x f_i are folded into const), F_point the sum of world-point forces, M = sum of
body_point (x) force (3, 3) (so axial(R M) = sum (R b_i) x f_i) and tau_body the body-frame
couples of a case with point forces (per-step); the body couples of a case without go to
qfrc_applied[3:6] as they are (per-stage).

Precision.  ``float64`` or ``float32`` (JAX's default).  Everything a run does (put_model,
put_data, tracing, compiling, stepping) runs inside JAX's thread-local ``jax.enable_x64(on)``
scope: the process-wide ``jax_enable_x64`` flag is never changed, so float32 and float64 runs mix
freely in one process (and in spawned workers).  Enabling x64 globally and casting the model and
data to float32 does NOT give a float32 run: MJX allocates float64 temporaries under x64 and
``qpos`` comes back float64.  A float32 run is verified at compile time (the lowered StableHLO has
no f64 type) and at run time (``qpos`` is float32); the trajectory is returned in float64 (the
float32 values, widened exactly).  Model numbers (mass, inertia, dt, gravity), the loads and the
initial state are rounded to float32 in a float32 run.  JAX's trace caches do not keep the two
modes apart for every function (see ``jax_runtime.x64_scope``): they are cleared (``jax.clear_caches()``, which
also drops the user's own jit caches: a recompile, never a wrong result) when a scope's mode
differs from the process-wide one.

Integrators: what ``mjx.step`` implements: ``Euler``, ``RK4``, ``implicitfast`` (MJX's
implicitfast has no RNE derivative: the gyroscopic term stays explicit, unlike C MuJoCo 4.0's, so
on a free body it is MJX's Euler; MJX 3.17's RK4 is second order on the free-joint orientation,
C MuJoCo 4.0's fourth order).
``implicit`` is rejected by ``put_model`` and ``discrete`` by ``mjx.step``.

Instability: MJX has no warnings counter (C MuJoCo's "Nan, Inf or huge value" checks) and no
auto-reset: a blow-up grows until the state is non-finite, and ``advance`` returns it as
computed (never raising :class:`~freebody.adapters.base.EngineDiverged`); the harness detects it
(non-finite values, and its bounds on a huge but finite state).

Batches.  Every run, alone or with others, is one lane of the same :data:`LANES`-wide program
(``jax.vmap`` of the chunk over every argument; the chunk itself for LANES = 1, the default): a
run alone is lane 0 beside idle copies of itself.  At a fixed width a lane's numbers depend neither on its position nor on the other lanes,
so :meth:`MjxAdapter.step_runs` (runs of one integrator and precision, any dt and length, a lane
refilled when its run ends; ``freebody run`` uses it through :mod:`freebody.run.batching`) and
:meth:`MjxAdapter.simulate_batch` (``supports_batch`` is True; ``freebody sweep``) give each run
its one-by-one samples bit for bit.

Engine defaults changed (recorded, read back): the MuJoCo adapter's (timestep, gravity,
integrator, alignfree, and the C auto-reset flag, which MJX ignores), and ``jax_enable_x64``
(the process-wide value -> the run's scoped value).  Importing ``mujoco.mjx`` prints "Failed to
import warp" on stdout when NVIDIA Warp is absent: the import is done with stdout captured.
"""
from __future__ import annotations

import contextlib
import contextvars
import hashlib
import importlib.util
import inspect
import io
import threading
import time
from typing import Callable, ClassVar

import numpy as np

import jax  # ModuleNotFoundError "jax": the registry reports the engine missing (a skip)

if importlib.util.find_spec("mujoco") is None or importlib.util.find_spec("mujoco.mjx") is None:
    # jax without mujoco-mjx is a missing engine too (the registry skips on the name "jax");
    # a broken mujoco-mjx install still fails loudly in the import below
    raise ModuleNotFoundError("mujoco-mjx is not installed: pip install 'freebody[jax]'", name="jax")
with contextlib.redirect_stdout(io.StringIO()):  # mjx prints Warp's absence on stdout
    from mujoco import mjx
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402

try:  # private: the one function whose mask _normalise turns into an argument
    from mujoco.mjx._src import support as _mjx_support  # noqa: E402
except ImportError:  # another MJX layout: no normalisation (one compilation per structure)
    _mjx_support = None

from freebody.reference_impl.conventions import Trajectory  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Problem  # noqa: E402
from .base import (LOAD_SAMPLING_PER_STAGE, LOAD_SAMPLING_PER_STEP, Adapter, BatchRun,  # noqa: E402
                   UnsupportedOption, distribution_version)
# CACHE_DIR, COMPILE_STATS and default_cache_dir are this module's names too (docs/mjx.md)
from .jax_runtime import (CACHE_DIR, COMPILE_STATS, LOAD_ROW, compiled, current_x64,  # noqa: E402,F401
                          default_cache_dir, load_rows, outside_x64, quat_matrix, x64_scope)
from .loads import LoadSchedule  # noqa: E402
from .mjcf import free_joint_trajectory  # noqa: E402
from .mujoco_adapter import MujocoAdapter  # noqa: E402

# freebody's integrator name (MuJoCo's spelling) -> mjx.IntegratorType member, default first:
# the ones mjx.step implements (IntegratorType also has DISCRETE, which mjx.step rejects).
_INTEGRATOR_ENUM: dict[str, str] = {"Euler": "EULER", "RK4": "RK4", "implicitfast": "IMPLICITFAST"}

PRECISIONS: tuple[str, ...] = ("float32", "float64")
_DTYPE = {"float32": np.float32, "float64": np.float64}

# Steps per compiled scan call: the compiled function's length is static, so runs of any length
# share one compilation; a run pays at most CHUNK_STEPS - 1 padding steps.
CHUNK_STEPS = 1000

_BODY = 1  # body id of the free body (0 is the world)

# --- one structure for every free body: the mass-matrix mask as an argument -----------------------

# The fields of MuJoCo's "simple body" optimisation (see the module docstring), taken from a body
# whose principal frame is not its body frame.
SPARSITY_FIELDS = ("nC", "M_rownnz", "M_rowadr", "M_colind", "dof_simplenum", "body_simple",
                   "body_sameframe")
# sha256 of the source of mujoco.mjx._src.support.make_m whose dense branch _make_m_masked copies
# (mujoco-mjx 3.17.0); with any other source the models are left as they are.
_MAKE_M_SHA256 = "bc1ff2f7a212659abd782e30b62b7903de30a66484557e635d0a42ae2892cf0d"
_MASS_MASK: contextvars.ContextVar = contextvars.ContextVar("freebody_mjx_mass_mask", default=None)
_PATCH_LOCK = threading.Lock()
_TEMPLATE: dict = {}  # the full pattern's fields, built once


def _make_m_checked() -> bool:
    """Whether MJX's make_m is the one _make_m_masked copies."""
    try:
        source = inspect.getsource(_mjx_support.make_m)
    except (AttributeError, OSError, TypeError):
        return False
    return hashlib.sha256(source.encode()).hexdigest() == _MAKE_M_SHA256


NORMALISE = _mjx_support is not None and _make_m_checked()


def _make_m_masked(m, a, b, d=None):
    """MJX's ``support.make_m`` with the dense mask taken from :data:`_MASS_MASK` (a traced
    (nv, nv) bool array) instead of the model's static sparsity: the same operations."""
    mask = _MASS_MASK.get()
    if mask is None or _mjx_support.is_sparse(m):
        return _MAKE_M(m, a, b, d)
    qm = a @ b.T
    if d is not None:
        qm += jnp.diag(d)
    qm = qm * mask
    qm = qm + jnp.tril(qm, -1).T
    return qm


_MAKE_M = _mjx_support.make_m if _mjx_support is not None else None


@contextlib.contextmanager
def _masked_make_m():
    """MJX's make_m replaced by :func:`_make_m_masked` for the block (the adapter's tracing).
    Outside a traced call with a mask it behaves as MJX's own."""
    if _MAKE_M is None:
        yield
        return
    with _PATCH_LOCK:
        _mjx_support.make_m = _make_m_masked
        try:
            yield
        finally:
            _mjx_support.make_m = _MAKE_M


def full_pattern() -> dict:
    """The sparsity fields (:data:`SPARSITY_FIELDS`) of a free body whose principal frame is not
    its body frame (MuJoCo compiles it; built once).  Also the Brax adapter's: a Brax System is an
    MJX Model."""
    if not _TEMPLATE:
        inertia = np.array([[2.0, 0.3, 0.1], [0.3, 3.0, 0.2], [0.1, 0.2, 4.0]])
        pb = Problem("structure", "", Body(1.0, inertia),
                     InitialState([0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0, 0, 0]), [0, 0, 0],
                     duration=1.0)
        c = MujocoAdapter(pb, 0.01, "Euler", "float64")
        try:
            mx = mjx.put_model(c.model)
        finally:
            c.close()
        _TEMPLATE.update({f: getattr(mx, f) for f in SPARSITY_FIELDS})
    return _TEMPLATE


def _normalise(mx):
    """(model with the full pattern's structure, its own dense mass-matrix mask (nv, nv) bool),
    or (mx, None) when this MJX's make_m is not the checked one, the mass matrix is sparse or the
    model is not one free body."""
    if (not NORMALISE or _mjx_support.is_sparse(mx) or mx.nbody != 2 or mx.nv != 6
            or mx.njnt != 1):
        return mx, None
    i = np.repeat(np.arange(mx.nv), mx.M_rownnz)
    mask = np.zeros((mx.nv, mx.nv), dtype=bool)
    mask[i, mx.M_colind] = True
    return mx.replace(**full_pattern()), jnp.asarray(mask)


# --- the step inside the scan ---------------------------------------------------------------------

def _loaded_step(m, d, row):
    """xfrc_applied[body] = the row's wrench at the current state, qfrc_applied[3:6] = its
    body couple for every stage, then mjx.step."""
    x, q = d.qpos[0:3], d.qpos[3:7]
    R = quat_matrix(q)
    A = R @ row[12:21].reshape(3, 3)                      # sum (R b_i) f_i^T
    tau = (row[3:6] + jnp.cross(row[6:9] - x, row[9:12])
           + jnp.stack([A[1, 2] - A[2, 1], A[2, 0] - A[0, 2], A[0, 1] - A[1, 0]])
           + R @ row[21:24])
    xfrc = d.xfrc_applied.at[_BODY, 0:3].set(row[0:3]).at[_BODY, 3:6].set(tau)
    qfrc = d.qfrc_applied.at[3:6].set(row[24:27])
    return mjx.step(m, d.replace(xfrc_applied=xfrc, qfrc_applied=qfrc))


def _chunk(m, d, rows, n, mask=None):
    """Scan _loaded_step over the first n of rows (C, LOAD_ROW); the C - n steps after them leave the
    Data as it is.  mask: the body's mass-matrix mask (see :func:`_normalise`), or None for the
    model's own.  Returns (Data after step n, qpos (C, 7), qvel (C, 6)): rows n.. repeat the
    state of step n."""
    def body(dd, x):
        i, row = x
        dd = jax.lax.cond(i < n, lambda e: _loaded_step(m, e, row), lambda e: e, dd)
        return dd, (dd.qpos, dd.qvel)
    token = _MASS_MASK.set(mask)  # read by _make_m_masked while this is traced
    try:
        d, (Q, V) = jax.lax.scan(body, d, (jnp.arange(rows.shape[-2]), rows))
    finally:
        _MASS_MASK.reset(token)
    return d, Q, V


# Every MJX run, alone or stepped with others, is one lane of a LANES-wide program: for LANES > 1
# the chunk vmapped over every argument (model, data, load rows, real steps, mass-matrix mask); for
# LANES = 1 the chunk itself (the unbatched program, the runs stepped one after another).  XLA's
# CPU code for a vmapped computation depends on the batch width (measured with mujoco-mjx 3.17,
# jax 0.10: the unbatched program and widths 1, 3, 4, 7 give other last bits than widths 2, 8,
# 16), but a lane's numbers do not depend on its position nor on the other lanes' contents at a
# fixed width; so with one fixed width a run is bit for bit the same alone or stepped with others.
# LANES = 1 keeps every MJX number of freebody 0.2.0 before issue 29 bit for bit, and is as fast
# as any width on the default suite: its 282 MJX runs step together in 43.3 s CPU at width 1,
# 43.1 s at 2, 55 s at 4, 61 s at 8 (each (integrator, precision) has one run of 100 000 steps,
# which sets the number of calls); a width > 1 pays off only for many runs of similar length (a
# sweep), and moves every MJX trajectory by round-off (at width 2: 14 of those 282 runs' verdicts
# changed, 10 float32 scheme identifications at the margin and 4 blow-up times).
LANES = 1
_lanes_jit = jax.jit(jax.vmap(_chunk, in_axes=(0, 0, 0, 0, 0)))
_chunk_jit = jax.jit(_chunk)  # LANES = 1: the run alone, unbatched


# --- building -----------------------------------------------------------------------------------

def _check(what: str, got, want) -> None:
    if not np.array_equal(np.asarray(got), np.asarray(want)):
        raise RuntimeError(f"mjx did not take the setting {what}: set {want!r}, read back {got!r}")


def _build(problem: Problem, dt: float, integrator: str, precision: str, x64_default: bool):
    """(mjx.Model, mjx.Data, settings, mass-matrix mask or None) for a problem, inside the
    caller's x64 scope: the MuJoCo adapter's C model and data moved to JAX and normalised
    (:func:`_normalise`), settings read back from the mjx.Model.
    x64_default: jax_enable_x64 outside the scope.  The integrator and precision are already
    checked (by Adapter.__init__, or simulate_batch)."""
    c = MujocoAdapter(problem, dt, integrator, "float64")
    try:
        settings = dict(c.settings)
        mx = mjx.put_model(c.model)
        dx = mjx.put_data(c.model, c.data)
    finally:
        c.close()
    dtype = _DTYPE[precision]
    _check("timestep", mx.opt.timestep, dtype(dt))
    _check("gravity", mx.opt.gravity, np.asarray(problem.gravity, dtype=dtype))
    _check("integrator", int(mx.opt.integrator), int(getattr(mjx.IntegratorType,
                                                             _INTEGRATOR_ENUM[integrator])))
    if dx.qpos.dtype != dtype:
        raise RuntimeError(f"mjx data is {dx.qpos.dtype}, not {precision}")
    settings["jax_enable_x64"] = {"default": bool(x64_default), "set": current_x64()}
    _check("jax_enable_x64 (scoped)", settings["jax_enable_x64"]["set"], precision == "float64")
    mx, mask = _normalise(mx)
    return mx, dx, settings, mask


def _first_bad(Q: np.ndarray, V: np.ndarray) -> int | None:
    """Index of the first row with a non-finite qpos or qvel, or None."""
    bad = ~(np.isfinite(Q).all(axis=-1) & np.isfinite(V).all(axis=-1))
    return int(np.argmax(bad)) if bad.any() else None


class MjxAdapter(Adapter):
    name: ClassVar[str] = "mjx"
    import_name: ClassVar[str] = "jax"
    integrators: ClassVar[tuple[str, ...]] = tuple(_INTEGRATOR_ENUM)
    precisions: ClassVar[tuple[str, ...]] = PRECISIONS
    compare_with: ClassVar[str | None] = "mujoco"
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP  # with point forces; see run_load_sampling
    load_sampling_note: ClassVar[str] = ("per-stage for COM forces, world couples and body couples "
                                         "(qfrc_applied[3:6]) in a case without point forces; a case "
                                         "with a force at a point: the whole world wrench per step")
    conventions: ClassVar[dict[str, str]] = {
        "model": "the MuJoCo adapter's MJCF and MjModel, moved to JAX with mjx.put_model/put_data",
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (qpos[3:7]); no reorder",
        "position": "qpos[0:3]: body origin in world = COM",
        "angular velocity frame": "BODY frame in qvel[3:6]; converted w_world = R w_body",
        "linear velocity frame": "world (qvel[0:3])",
        "inertia input": "as the MuJoCo adapter (fullinertia, diagonalised by the C compiler)",
        "external loads": "xfrc_applied[body] = (force, torque about the COM), world, written "
                          "inside the scan before every mjx.step; body couples in qfrc_applied[3:6] "
                          "when the case has no point forces",
        "stepping": f"jax.lax.scan of mjx.step under jax.jit, {CHUNK_STEPS} steps per call",
        "precision": "float32 or float64 via the thread-local jax.enable_x64 scope; the "
                     "process-wide jax_enable_x64 is left alone",
        "instability": "no warnings counter and no auto-reset: detected as non-finite state",
        "velocity clamp": "none",
        "damping": "none (the MuJoCo adapter's model)",
        "sleeping": "none",
    }

    # --- capabilities --------------------------------------------------------------------------
    @classmethod
    def engine_version(cls) -> str:
        mjx_version = distribution_version("mujoco-mjx", lambda: "unknown")
        return f"{mjx_version} (mujoco {mujoco.__version__}, jax {jax.__version__})"

    @classmethod
    def offered_integrators(cls) -> tuple[str, ...]:
        return tuple(n for n, e in _INTEGRATOR_ENUM.items() if hasattr(mjx.IntegratorType, e))

    supports_batch: ClassVar[bool] = True
    steps_runs_together: ClassVar[bool] = True

    @classmethod
    def run_load_sampling(cls, problem: Problem) -> str | None:
        """Per-stage without forces at points (body couples through qfrc_applied reach every RK4
        stage), per-step with one (MJX's stages cannot rewrite xfrc_applied)."""
        if not problem.loads:
            return None
        point = any(ld.point is not None or ld.body_point is not None for ld in problem.loads)
        return LOAD_SAMPLING_PER_STEP if point else LOAD_SAMPLING_PER_STAGE

    # --- world ---------------------------------------------------------------------------------
    def build(self) -> None:
        self._dtype = _DTYPE[self.precision]
        x64_default = outside_x64()
        with x64_scope(self.precision == "float64"):
            self._m, self._d, settings, self._mask = _build(self.problem, self.dt, self.integrator,
                                                            self.precision, x64_default)
        self.settings.update(settings)
        self.compile_time_s = 0.0  # tracing + compiling spent by this adapter, s
        self.step_time_s = 0.0     # stepping, s (excludes compiling)

    # --- stepping ------------------------------------------------------------------------------
    def advance(self, steps: int) -> Trajectory:
        """``steps`` steps from the current state (t = (k0 + i) dt, k0 = self.k) as
        ceil(steps / CHUNK_STEPS) calls of the lanes program, this run in lane 0 (the other
        lanes idle copies; see :data:`LANES`).  MJX signals no instability: a blow-up comes back
        as computed (non-finite samples), for the harness to detect."""
        return self.step_runs([self], [steps])[0]

    @classmethod
    def step_runs(cls, adapters: list[MjxAdapter], steps: list[int],
                  on_steps: Callable[[int, int], None] | None = None) -> list[Trajectory]:
        """Step each adapter ``steps[i]`` steps from its current state, LANES runs at a time in
        the lanes program: a lane whose run ends takes the next run at the next chunk, so runs
        of any dt and length share the program's calls.  Each run's samples are those it has
        stepped alone (:meth:`advance`), bit for bit.  The adapters must share integrator and
        precision (ValueError) and, without :data:`NORMALISE`, their model structure
        (ValueError).  Each adapter's ``step_time_s`` grows by its share of the calls it was in,
        ``compile_time_s`` by its share of the compilation they waited for; its state moves on as
        :meth:`advance` moves it.  ``on_steps(done, total)``: after each call, the steps done
        of all the runs' total.  Returns the trajectories (steps[i] + 1 samples each, the
        current state first), in order."""
        if len({(a.integrator, a.precision) for a in adapters}) > 1:
            raise ValueError("step_runs: the runs must share integrator and precision")
        out: list[Trajectory | None] = [None] * len(adapters)
        if not adapters:
            return []
        with x64_scope(adapters[0].precision == "float64"):
            _LaneRuns(adapters, steps, out).run(on_steps)
        return out

    def close(self) -> None:
        self._m = self._d = self._mask = None

    # --- batched runs --------------------------------------------------------------------------
    @classmethod
    def runs_scope(cls, precision: str):
        """A block in which many runs of ``precision`` are built (and stepped) at the cost of one
        precision scope: the JAX caches are cleared on entering and leaving it, not per run
        (see ``jax_runtime.x64_scope``)."""
        return x64_scope(precision == "float64")

    @classmethod
    def simulate_batch(cls, problems: list[Problem], dt: float, steps: int,
                       integrator: str = "Euler", precision: str = "float64") -> BatchRun:
        """Run many free bodies together, LANES at a time in the lanes program (:meth:`step_runs`).

        problems : Problems whose MJX models have the same structure (ValueError otherwise: MJX
            keeps some facts of a model as static structure; every free body has the same one
            when :data:`NORMALISE` holds, see the module docstring); mass, inertia, initial
            state, gravity and loads may differ.
            dt : s, shared.  steps : number of steps, shared.
        integrator, precision : as for :class:`MjxAdapter`.
        Each body's trajectory is what :meth:`simulate` gives for it alone, bit for bit (the same
        program: see :data:`LANES`).  A body that blows up does not stop the batch: its samples
        turn non-finite and ``diverged_at_s`` says when.
        """
        cls._check_batch_options(integrator, precision)
        if not problems:
            return BatchRun([], [], 0.0, 0.0, [])
        adapters = [cls(problem, dt, integrator, precision) for problem in problems]
        try:
            trajectories = cls.step_runs(adapters, [steps] * len(adapters))
        finally:
            for a in adapters:
                a.close()
        diverged = []
        for tr in trajectories:
            bad = _first_bad(np.concatenate([tr.position, tr.quaternion_wxyz], axis=1),
                             np.concatenate([tr.linear_velocity, tr.angular_velocity], axis=1))
            diverged.append(None if bad is None else bad * dt)
        return BatchRun(trajectories, diverged, sum(a.compile_time_s for a in adapters),
                        sum(a.step_time_s for a in adapters), [dict(a.settings) for a in adapters])

    @classmethod
    def _check_batch_options(cls, integrator: str, precision: str) -> None:
        """UnsupportedOption for an integrator or precision this MJX does not offer
        (Adapter.__init__ checks single runs)."""
        if integrator not in cls.offered_integrators():
            raise UnsupportedOption(f"{cls.name} {cls.engine_version()} has no integrator "
                                    f"{integrator!r}; offered: {', '.join(cls.offered_integrators())}")
        if precision not in cls.precisions:
            raise UnsupportedOption(f"{cls.name} offers the precisions {', '.join(cls.precisions)}, "
                                    f"not {precision!r}")


# --- the lanes program: LANES runs side by side -----------------------------------------------------

class _Lanes:
    """LANES > 1: the inputs of the lanes program, host side: per leaf of the MJX Model, Data and mass-matrix
    mask one numpy array (LANES, ...), lane j holding the world of the run in lane j.  Built from
    numpy arrays every call, so a run alone and a run among others give the program the same kind
    of arguments (shapes, dtypes, no weak types): the same compiled program."""

    def __init__(self, first: MjxAdapter):
        m_leaves, self.model_def = jax.tree_util.tree_flatten(first._m)
        d_leaves, self.data_def = jax.tree_util.tree_flatten(first._d)
        self.model = [np.stack([np.asarray(x)] * LANES) for x in m_leaves]
        self.data = [np.stack([np.asarray(x)] * LANES) for x in d_leaves]
        self.mask = None if first._mask is None else np.stack([np.asarray(first._mask)] * LANES)
        self.precision, self.integrator = first.precision, first.integrator

    def put(self, lane: int, a: MjxAdapter) -> None:
        """Lane ``lane`` takes run ``a``'s world (its current state)."""
        m_leaves, m_def = jax.tree_util.tree_flatten(a._m)
        d_leaves, d_def = jax.tree_util.tree_flatten(a._d)
        if m_def != self.model_def or d_def != self.data_def or (a._mask is None) != (self.mask is None):
            raise ValueError("step_runs: the runs' MJX models differ in structure")
        for stacked, x in zip(self.model, m_leaves):
            stacked[lane] = np.asarray(x)
        for stacked, x in zip(self.data, d_leaves):
            stacked[lane] = np.asarray(x)
        if self.mask is not None:
            self.mask[lane] = np.asarray(a._mask)

    def lane_data(self, lane: int):
        """The mjx.Data of lane ``lane`` (numpy leaves)."""
        return jax.tree_util.tree_unflatten(self.data_def, [x[lane].copy() for x in self.data])

    def step(self, rows: np.ndarray, ns: np.ndarray):
        """One call: lane j steps ns[j] (<= CHUNK_STEPS) steps with the load rows rows[j]
        (LANES, CHUNK_STEPS, LOAD_ROW).  Returns (qpos (LANES, CHUNK_STEPS, 7), qvel
        (LANES, CHUNK_STEPS, 6) in the run's precision, rows ns[j].. of lane j repeating its last
        state; seconds compiling; seconds stepping)."""
        args = (jax.tree_util.tree_unflatten(self.model_def, self.model),
                jax.tree_util.tree_unflatten(self.data_def, self.data), rows, ns, self.mask)
        fn, spent = compiled("lanes", _lanes_jit, self.precision, args, extra=(LANES,),
                             label=self.integrator, lowering=_masked_make_m)
        t0 = time.perf_counter()
        data, Q, V = fn(*args)
        Q, V = np.asarray(Q), np.asarray(V)
        self.data = [np.array(x) for x in jax.tree_util.tree_leaves(data)]
        stepped = time.perf_counter() - t0
        if Q.dtype != _DTYPE[self.precision]:
            raise RuntimeError(f"mjx computed qpos in {Q.dtype}, not {self.precision}")
        return Q, V, spent, stepped


class _OneLane:
    """LANES = 1: the unbatched chunk program (:data:`_chunk_jit`) with the lane's Model, Data and
    mass-matrix mask kept as device arrays: put once per run (from numpy copies of its leaves:
    the same shapes and dtypes, no weak types, as :class:`_Lanes` gives), and the Data each call
    returns passed as it is to the next.  The same program on the same values as host arrays
    every call, so the same numbers bit for bit; what it saves is moving the ~200 leaves of Model
    and Data across, both ways, at every call."""

    def __init__(self, first: MjxAdapter):
        self.model_def = jax.tree_util.tree_structure(first._m)
        self.data_def = jax.tree_util.tree_structure(first._d)
        self.masked = first._mask is not None
        self.precision, self.integrator = first.precision, first.integrator
        self.model = self.data = self.mask = self.fn = None

    def put(self, lane: int, a: MjxAdapter) -> None:
        """The lane takes run ``a``'s world (its current state)."""
        m_leaves, m_def = jax.tree_util.tree_flatten(a._m)
        d_leaves, d_def = jax.tree_util.tree_flatten(a._d)
        if m_def != self.model_def or d_def != self.data_def or (a._mask is None) == self.masked:
            raise ValueError("step_runs: the runs' MJX models differ in structure")
        host = [np.array(x) for x in m_leaves], [np.array(x) for x in d_leaves]
        m_dev, d_dev = jax.device_put(host)
        self.model = jax.tree_util.tree_unflatten(self.model_def, m_dev)
        self.data = jax.tree_util.tree_unflatten(self.data_def, d_dev)
        self.mask = None if a._mask is None else jax.device_put(np.array(a._mask))
        self.fn = None  # looked up again (the cache's key is the arguments')

    def lane_data(self, lane: int):
        """The lane's mjx.Data (device arrays, as the program returned them)."""
        return self.data

    def step(self, rows: np.ndarray, ns: np.ndarray):
        """As :meth:`_Lanes.step` for one lane: rows (1, CHUNK_STEPS, LOAD_ROW), ns (1,)."""
        args = (self.model, self.data, rows[0], jnp.int32(ns[0]), self.mask)
        spent = 0.0
        if self.fn is None:
            self.fn, spent = compiled("chunk", _chunk_jit, self.precision, args,
                                      label=self.integrator, lowering=_masked_make_m)
        t0 = time.perf_counter()
        self.data, Q, V = self.fn(*args)
        Q, V = np.asarray(Q)[None], np.asarray(V)[None]
        stepped = time.perf_counter() - t0
        if Q.dtype != _DTYPE[self.precision]:
            raise RuntimeError(f"mjx computed qpos in {Q.dtype}, not {self.precision}")
        return Q, V, spent, stepped


class _LaneRuns:
    """Runs stepped through one :class:`_Lanes`, a run per lane, the next run taking a lane as
    soon as its run ends (at a chunk's end); ``out[i]`` gets run i's trajectory."""

    def __init__(self, adapters: list[MjxAdapter], steps: list[int], out: list):
        self.adapters, self.steps, self.out = adapters, [int(n) for n in steps], out
        self.lanes = _OneLane(adapters[0]) if LANES == 1 else _Lanes(adapters[0])
        self.queue = list(range(len(adapters)))[::-1]  # popped from the end: in order
        self.lane_run: list[int | None] = [None] * LANES
        self.done = [0] * len(adapters)
        self.Q: dict[int, np.ndarray] = {}  # run -> [x (3) m world, q (4) wxyz body -> world]
        self.V: dict[int, np.ndarray] = {}  # run -> [v (3) m/s world, w (3) rad/s BODY]

    def run(self, on_steps: Callable[[int, int], None] | None = None) -> None:
        total = sum(self.steps)
        while self._fill():
            self._call()
            if on_steps is not None:
                on_steps(sum(self.done), total)

    def _fill(self) -> bool:
        """Give every free lane the next run (a run of 0 steps ends at once); whether a lane
        has a run to step."""
        for lane in range(LANES):
            while self.lane_run[lane] is None and self.queue:
                i = self.queue.pop()
                a = self.adapters[i]
                self.Q[i] = np.empty((self.steps[i] + 1, 7))
                self.V[i] = np.empty((self.steps[i] + 1, 6))
                self.Q[i][0] = np.asarray(a._d.qpos, dtype=np.float64)
                self.V[i][0] = np.asarray(a._d.qvel, dtype=np.float64)
                if self.steps[i] == 0:
                    self._finish(i, None)
                    continue
                self.lanes.put(lane, a)
                self.lane_run[lane] = i
        return any(i is not None for i in self.lane_run)

    def _call(self) -> None:
        """One call of the lanes program for the runs in the lanes; ends those that are done."""
        dtype = _DTYPE[self.lanes.precision]
        rows = np.zeros((LANES, CHUNK_STEPS, LOAD_ROW), dtype=dtype)
        ns = np.zeros(LANES, dtype=np.int32)
        for lane, i in enumerate(self.lane_run):
            if i is not None:
                a, k = self.adapters[i], self.done[i]
                ns[lane] = n = min(CHUNK_STEPS, self.steps[i] - k)
                rows[lane, :n] = load_rows(a.loads, a.k + k, a.k + k + n, dtype)
        Q, V, spent, stepped = self.lanes.step(rows, ns)
        active = [(lane, i) for lane, i in enumerate(self.lane_run) if i is not None]
        for lane, i in active:
            a, k, n = self.adapters[i], self.done[i], int(ns[lane])
            a.compile_time_s += spent / len(active)
            a.step_time_s += stepped / len(active)
            self.Q[i][k + 1:k + 1 + n], self.V[i][k + 1:k + 1 + n] = Q[lane, :n], V[lane, :n]
            self.done[i] = k + n
            if self.done[i] == self.steps[i]:
                self._finish(i, lane)
                self.lane_run[lane] = None

    def _finish(self, i: int, lane: int | None) -> None:
        """Run i is done: its trajectory out, its adapter's state moved on (from lane ``lane``)."""
        a = self.adapters[i]
        if lane is not None:
            a._d = self.lanes.lane_data(lane)
        self.out[i] = free_joint_trajectory(self.Q.pop(i), self.V.pop(i), a.dt, a.k)
        a.k += self.steps[i]


# The function form of MjxAdapter.simulate_batch (docs/mjx.md); the harness asks the class.
simulate_batch = MjxAdapter.simulate_batch
