"""What the JAX engines' adapters (MJX, Brax) share: precision scopes, compiled programs, the
persistent compilation cache, the per-step load rows their scans read, and R(q) in JAX.

Precision.  :func:`x64_scope` runs a block under JAX's thread-local ``jax.enable_x64(on)``
without touching the process-wide ``jax_enable_x64`` flag, so float32 and float64 runs mix freely
in one process (and in spawned workers).  JAX's trace caches do not keep the two modes apart for
every function: they are cleared (``jax.clear_caches()``, which also drops the user's own jit
caches: a recompile, never a wrong result) when a scope's mode differs from the one outside.

Compiled programs.  :func:`compiled` lowers and compiles a jitted function once per (kind,
precision, argument structure, shapes and dtypes) and process, and keeps the executable in a
module-level cache; a float32 program is checked to contain no f64 type.  :data:`COMPILE_STATS`
counts this process's compilations and loads from disk.

Persistent compilation cache.  Importing this module points JAX's persistent compilation cache
at ``$XDG_CACHE_HOME/freebody/jax`` (default ``~/.cache/freebody/jax``, created with the user's
umask) unless ``JAX_COMPILATION_CACHE_DIR`` (or ``jax_compilation_cache_dir``) names another
folder, and lets JAX keep every compiled program however quick its compilation; JAX's own
``JAX_ENABLE_COMPILATION_CACHE=false`` turns it off.  Processes compiling the same program at
once take turns (:func:`machine_lock`, a lock file in the cache folder), so the later ones load
what the first compiled instead of compiling it again.

Load rows.  A scan step reads the step's loads as one row of :data:`LOAD_ROW` floats
(:func:`load_rows`, from a run's :class:`~freebody.adapters.loads.LoadSchedule`); the
state-dependent torques are formed inside the step from the current pose (see :data:`LOAD_ROW`).
"""
from __future__ import annotations

import contextlib
import contextvars
import os
import re
import time

import numpy as np

import jax  # ModuleNotFoundError "jax": the registry reports the engine missing (a skip)
import jax.numpy as jnp

try:
    import fcntl
except ImportError:  # no POSIX file locks (Windows): processes may compile the same program twice
    fcntl = None

from .loads import LoadSchedule

__all__ = ["CACHE_DIR", "COMPILE_STATS", "LOAD_ROW", "compiled", "current_x64", "default_cache_dir",
           "load_rows", "loads_reach_every_stage", "machine_lock", "outside_x64", "quat_matrix",
           "x64_scope"]

# One row of per-step loads (the step's load set):
# [0:3] force N world, [3:6] constant torque N m world, [6:9] anchor c m world,
# [9:12] F_point N world, [12:21] M = sum b_i f_i^T (3, 3) row-major (m N), [21:24] tau_body N m body
# turned by the step's start's R into the world wrench (per-step), [24:27] tau_body N m body applied
# as a body-frame couple at every stage (per-stage).  Inside a step at COM x and rotation R:
# world torque = const + (c - x) x F_point + axial(R M) + R tau_body, where ``c`` is the first
# world-point load's point (the other world-point loads' (p_i - c) x f_i are folded into const),
# and axial(R M) = sum (R b_i) x f_i.
LOAD_ROW = 27

# compiled executables: key -> jax.stages.Compiled
_COMPILED: dict = {}

# This process's compilations: "compiled" (XLA compiled it), "from_disk" (JAX's persistent cache
# had it), "seconds" (tracing, lowering, waiting for another process and compiling or loading).
COMPILE_STATS: dict = {"compiled": 0, "from_disk": 0, "seconds": 0.0}


# --- the persistent compilation cache -------------------------------------------------------------

def default_cache_dir() -> str:
    """Where freebody keeps JAX's compiled programs: ``$XDG_CACHE_HOME/freebody/jax``, else
    ``~/.cache/freebody/jax``."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):  # unset, empty or relative: the XDG default
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "freebody", "jax")


def _use_persistent_cache() -> str | None:
    """Point JAX's persistent compilation cache at :func:`default_cache_dir` unless a folder is
    configured already (``JAX_COMPILATION_CACHE_DIR`` or ``jax_compilation_cache_dir``), and cache
    programs of any compile time (JAX's default keeps only those over 1 s) unless the user chose a
    threshold.  Returns the folder in use, or None (the default folder cannot be created)."""
    folder = jax.config.jax_compilation_cache_dir
    if not folder:
        folder = default_cache_dir()
        try:
            os.makedirs(folder, exist_ok=True)  # mode 0o777 & ~umask
        except OSError:
            return None
        jax.config.update("jax_compilation_cache_dir", folder)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    if "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES" not in os.environ:
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)  # -1: any size
    return folder


CACHE_DIR = _use_persistent_cache()

_DISK_HITS = [0]  # JAX's persistent-cache hits in this process (its monitoring events)


def _count_disk_hit(event: str, **_kwargs) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _DISK_HITS[0] += 1


jax.monitoring.register_event_listener(_count_disk_hit)


@contextlib.contextmanager
def machine_lock(label: str):
    """Hold an exclusive lock named ``label`` in the cache folder while compiling, so that
    processes (parallel workers) compiling the same program take turns and the later ones load it
    from the cache.  No lock without a cache folder or POSIX locks (only compile time is lost)."""
    folder = jax.config.jax_compilation_cache_dir
    if not folder or fcntl is None or not jax.config.jax_enable_compilation_cache:
        yield
        return
    try:
        locks = os.path.join(folder, "freebody-locks")
        os.makedirs(locks, exist_ok=True)
        f = open(os.path.join(locks, re.sub(r"[^A-Za-z0-9_.-]", "_", label) + ".lock"), "a+b")
    except OSError:
        yield
        return
    with f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


# --- precision ------------------------------------------------------------------------------------

def _jax_x64(on: bool):
    """JAX's thread-local x64 scope (``jax.enable_x64`` in JAX >= 0.5; the experimental context
    managers before)."""
    state = getattr(jax, "enable_x64", None)
    if state is not None:
        return state(on)
    from jax.experimental import disable_x64, enable_x64
    return enable_x64() if on else disable_x64()


@contextlib.contextmanager
def x64_scope(on: bool):
    """Run the block with jax_enable_x64 = on, without touching the process-wide flag.

    JAX's trace/lowering caches do not tell the two x64 modes apart for every function (JAX
    0.10.2: MJX's RK4 calls ``jnp.tril`` on a numpy constant; traced under one mode, it fails to
    lower under the other with "operand type mismatch ... f32 ... f64").  So the caches are
    cleared on entering and on leaving a scope whose mode differs from the one in force outside,
    and code outside (later runs, the user's own JAX code) never meets a trace made under the
    other mode.  The compiled executables :func:`compiled` keeps are not affected."""
    outer = current_x64()
    token = _OUTSIDE_X64.set(outside_x64())  # the value outside the outermost scope
    if on != outer:
        jax.clear_caches()
    try:
        with _jax_x64(on):
            yield
    finally:
        _OUTSIDE_X64.reset(token)
        if on != outer:
            jax.clear_caches()


_OUTSIDE_X64: contextvars.ContextVar = contextvars.ContextVar("freebody_outside_x64", default=None)


def outside_x64() -> bool:
    """jax_enable_x64 outside every :func:`x64_scope` (what a run records as the default it
    changed, however many scopes it is built in)."""
    value = _OUTSIDE_X64.get()
    return current_x64() if value is None else value


def current_x64() -> bool:
    """jax_enable_x64 as in force here (the process-wide value outside any scope)."""
    return bool(jax.config.jax_enable_x64)


# --- compiled programs ----------------------------------------------------------------------------

def compiled(kind: str, fn, precision: str, args, extra=(), label: str = "",
             lowering=contextlib.nullcontext):
    """The compiled ``fn(*args)`` from the cache, compiling on a miss (or loading it from JAX's
    persistent cache).  Returns (compiled, seconds spent lowering and compiling: 0.0 on a hit).

    kind : names the program (part of the cache key and of the lock's name).
    fn : a ``jax.jit``-ed function.  precision : "float32" or "float64"; a float32 compilation is
        checked to contain no f64 type.  args : its arguments (their tree structure, shapes and
        dtypes are the key, with ``extra``).
    label : e.g. the integrator: names the lock that processes compiling the same program take
        turns on.
    lowering : a context-manager factory held while ``fn`` is traced and lowered (the MJX
        adapter's patch of ``make_m``); none by default."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    key = (kind, precision, treedef, extra,
           tuple((tuple(np.shape(a)), str(getattr(a, "dtype", type(a).__name__))) for a in leaves))
    hit = _COMPILED.get(key)
    if hit is not None:
        return hit, 0.0
    t0 = time.perf_counter()
    with machine_lock(f"{kind}-{label}-{precision}"):
        disk_hits = _DISK_HITS[0]
        with lowering():
            lowered = fn.lower(*args)
        if precision == "float32":
            text = lowered.as_text()
            if "f64" in text:
                raise RuntimeError(f"the float32 JAX computation {kind!r} contains float64 "
                                   "operations (jax_enable_x64 leaked into the float32 scope?)")
        program = lowered.compile()
        from_disk = _DISK_HITS[0] > disk_hits
    _COMPILED[key] = program
    spent = time.perf_counter() - t0
    COMPILE_STATS["from_disk" if from_disk else "compiled"] += 1
    COMPILE_STATS["seconds"] += spent
    return program, spent


# --- inside a scan step ---------------------------------------------------------------------------

def quat_matrix(q):
    """R(q) (3, 3) body -> world from a unit quaternion (w, x, y, z) (JAX arrays)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


def loads_reach_every_stage(loads: LoadSchedule) -> bool:
    """Whether the schedule has no force at a world or body point in any segment: its body
    couples then go to the per-stage slot of the rows (see :data:`LOAD_ROW`), else to the
    per-step one."""
    return not any(s.point_forces or s.body_point_forces for s in loads.segments)


def load_rows(loads: LoadSchedule, k0: int, k1: int, dtype) -> np.ndarray:
    """Per-step load rows (k1 - k0, LOAD_ROW) of ``dtype`` for the steps k0 <= k < k1 (see
    :data:`LOAD_ROW`)."""
    couple = slice(24, 27) if loads_reach_every_stage(loads) else slice(21, 24)
    rows = np.zeros((k1 - k0, LOAD_ROW))
    for seg, a, b in loads.stretches(k0, k1):
        row = np.zeros(LOAD_ROW)
        row[0:6] = seg.constant
        if seg.point_forces:
            anchor = seg.point_forces[0][0]
            row[6:9] = anchor
            for p, f in seg.point_forces:
                row[9:12] += f
                row[3:6] += np.cross(p - anchor, f)
        M = np.zeros((3, 3))
        for bp, f in seg.body_point_forces:
            M += np.outer(bp, f)
        row[12:21] = M.ravel()
        if seg.body_torque is not None:
            row[couple] = seg.body_torque
        rows[a - k0:b - k0] = row
    return rows.astype(dtype)
