"""The abstract engine adapter and the explicit, lazily imported registry of engines.

An adapter builds one free-body :class:`~freebody.reference_impl.problem.Problem` in its engine,
applies the case's loads before each step, steps, and reads the state back in freebody's
canonical convention (``reference_impl/conventions.py``).  Engines are imported only inside their
adapter module, and adapter modules only when a run needs them: ``import freebody`` imports no
engine.  Third parties add an engine through the entry-point group ``freebody.adapters``
(``name = "package.module:AdapterClass"``).
"""
from __future__ import annotations

import contextlib
import importlib
import importlib.util
import re
import json
import os
import signal
import subprocess
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Callable, ClassVar, Iterator, NamedTuple

import numpy as np

from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.problem import Problem
from freebody.reference_impl.sampling import LOAD_SAMPLING_PER_STAGE, LOAD_SAMPLING_PER_STEP, LOAD_SAMPLINGS
from .capture import capture_output
from .loads import LoadSchedule, Segment

ENTRY_POINT_GROUP = "freebody.adapters"

# One live check of an engine trap (:meth:`Adapter.trap_checks`): builds what it needs, runs the
# engine and returns (passed, measured value or None, bound, one sentence).
TrapCheck = Callable[[], tuple[bool, float | None, float, str]]


class EngineMissing(Exception):
    """The engine's Python package is not installed (the run is ``skipped``)."""


class UnknownEngine(KeyError):
    """No adapter is registered under that name (bad input)."""


class PluginImportFailed(Exception):
    """Importing a plug-in's adapter module did not finish in time, crashed or exited (see
    :func:`probe_plugin`): its runs are failed with this message."""


class UnsupportedOption(ValueError):
    """The engine does not offer the requested integrator or precision (raised by the base, once)."""


class EngineDiverged(Exception):
    """The simulated state blew up: non-finite, beyond the case's bounds, or the engine's own
    instability warning.  Carries the time it happened and the trajectory up to that point."""

    def __init__(self, t: float, reason: str, trajectory: Trajectory | None = None):
        super().__init__(f"diverged at t = {t:.6g} s: {reason}")
        self.t = t
        self.reason = reason
        self.trajectory = trajectory


@dataclass
class BatchRun:
    """What :meth:`Adapter.simulate_batch` returns for B problems stepped together.

    trajectories : one canonical :class:`Trajectory` per problem (steps + 1 samples; non-finite
        samples after a body's blow-up kept as computed).
    diverged_at_s : per problem, the time of the first non-finite sample, or None.
    compile_time_s : s spent compiling (0.0 when cached).  step_time_s : s spent stepping.
    engine_settings : per problem, the engine defaults changed (as ``Adapter.settings``).
    """

    trajectories: list[Trajectory]
    diverged_at_s: list[float | None]
    compile_time_s: float
    step_time_s: float
    engine_settings: list[dict] = field(default_factory=list)


class Adapter(ABC):
    """One engine's free body: the contract between an engine and the harness.

    Class attributes (capabilities, read by the harness):
      name : engine name as used on the command line.
      import_name : the engine's top-level Python module (checked with ``find_spec``).
      integrators : integrator names the engine offers, its default first, spelt as the engine does
        (``offered_integrators()`` may narrow them to the installed version).
      precisions : floating-point precisions offered ("float64" unless the engine says otherwise).
      conventions : engine convention facts shown by ``freebody conventions``.
      compare_with : the engine this one ports, compared run by run (or None).
      opt_in_integrators : offered integrators that run only when named with ``--integrator`` (or
        with ``--all-integrators``): slow ones, e.g. error-controlled implicit schemes.
      supported_versions : the engine versions this adapter can drive, a version specifier
        (``">=6.19"``), or None for any; a run on another version is ``skipped``, naming the range
        (see :func:`unsupported_version`).
      load_sampling : where inside a step the engine evaluates the case's loads, one of
        :data:`LOAD_SAMPLINGS`: :data:`LOAD_SAMPLING_PER_STAGE` (from the state of every stage or
        substep its scheme evaluates) or :data:`LOAD_SAMPLING_PER_STEP` (the world wrench from the
        state at the step's start, held over the step); ``load_sampling_note`` says how, in one
        line (``freebody conventions``).  Identification compares a run with the engine maps'
        variant of the same rule (:meth:`run_load_sampling` may refine it per case).
      integrator_aliases : old integrator names still taken, old -> current (never offered).
      step_rotation_cap_rad : the engine's cap on the angle one step turns through, or None.
      supports_batch : whether :meth:`simulate_batch` steps many bodies at once.
      steps_runs_together : whether :meth:`step_runs` steps many built runs in one program, each
        bit for bit as alone (``freebody run`` then steps them together: freebody/run/batching.py).

    Every member the harness reads is declared here with its default (docs/adapters.md, "Members",
    lists them; tests/test_adapter_contract_docs.py keeps the two in step), so the harness reads
    them directly, never with ``getattr`` and a default of its own.

    An instance is one run: ``Adapter(problem, dt, integrator, precision)`` takes an old integrator
    name for its current one (``integrator_aliases``), checks the integrator
    and precision (:class:`UnsupportedOption`), builds the load schedule ``self.loads`` and calls
    :meth:`build`.  The one required way to step is :meth:`advance`; the harness calls
    :meth:`chunks` (a long run delivered piece by piece) or :meth:`simulate` (whole).  ``settings``
    records every engine default the adapter changed: ``{key: {"default": d, "set": v}}``.

    What an adapter must define: ``name``, ``import_name``, ``integrators``, :meth:`engine_version`,
    :meth:`build`, :meth:`advance`.  Everything else has a default.
    """

    name: ClassVar[str]
    import_name: ClassVar[str]
    integrators: ClassVar[tuple[str, ...]]
    precisions: ClassVar[tuple[str, ...]] = ("float64",)
    conventions: ClassVar[dict[str, str]] = {}
    # Another engine this one ports (e.g. mjx -> mujoco): each run is also compared with that
    # engine's run of the same integrator and dt (results.json "vs_engine").
    compare_with: ClassVar[str | None] = None
    supported_versions: ClassVar[str | None] = None
    opt_in_integrators: ClassVar[tuple[str, ...]] = ()
    # Old integrator names the engine still takes, old -> current (the reference engine's
    # "symplectic-euler" -> "lie-euler"): never offered; ``--integrator`` and the constructor
    # take an old name for its current one (with a deprecation warning on the command line).
    integrator_aliases: ClassVar[dict[str, str]] = {}
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STEP
    load_sampling_note: ClassVar[str] = ""
    # The largest angle (rad) one step turns the body through, when the engine caps it (Bullet's
    # ANGULAR_MOTION_THRESHOLD, pi/4); None: no cap.  A run whose |w| dt exceeds it is recorded
    # (results.json state_growth) and its findings name the cap.
    step_rotation_cap_rad: ClassVar[float | None] = None
    # Whether :meth:`simulate_batch` steps many bodies at once (``freebody sweep`` asks).
    supports_batch: ClassVar[bool] = False
    steps_runs_together: ClassVar[bool] = False

    def __init__(self, problem: Problem, dt: float, integrator: str, precision: str = "float64"):
        integrator = self.integrator_aliases.get(integrator, integrator)
        offered = self.offered_integrators()
        if integrator not in offered:
            raise UnsupportedOption(f"{self.name} {self.engine_version()} has no integrator "
                                    f"{integrator!r}; offered: {', '.join(offered)}")
        if precision not in self.precisions:
            raise UnsupportedOption(f"{self.name} offers the precisions "
                                    f"{', '.join(self.precisions)}, not {precision!r}")
        self.problem = problem
        self.dt = float(dt)
        self.integrator = integrator
        self.precision = precision
        self.settings: dict[str, dict] = {}
        self.k = 0  # index of the next step; advance() moves it
        # s spent compiling the engine's step (JIT engines; 0.0 when cached); None: no JIT
        self.compile_time_s: float | None = None
        self.loads = LoadSchedule(problem, self.dt)
        self.build()

    # --- what every adapter must do ------------------------------------------------------------
    @classmethod
    @abstractmethod
    def engine_version(cls) -> str:
        """The installed engine's version string."""

    @abstractmethod
    def build(self) -> None:
        """Create the engine world for ``self.problem`` at ``self.dt`` with ``self.integrator``
        and ``self.precision`` (both already checked), recording changed defaults."""

    @abstractmethod
    def advance(self, steps: int) -> Trajectory:
        """Step ``steps`` (>= 0) times from the current state (step index ``self.k``, at
        t = k dt) with the loads of ``self.loads``; return the steps + 1 canonical samples
        t = (k + i) dt, the current state first, and set ``self.k += steps``.

        On the engine's own instability warning raise :class:`EngineDiverged` with the samples up
        to and including the bad one (the harness detects non-finite and out-of-bounds states
        itself: an adapter may simply return them).
        """

    # --- optional, with defaults ---------------------------------------------------------------
    @classmethod
    def load_sampling_text(cls) -> str:
        """The load sampling in one line, as ``freebody conventions`` and reports show it: the
        rule, what it means, and how this engine does it (``load_sampling_note``)."""
        text = f"{cls.load_sampling}: {LOAD_SAMPLINGS[cls.load_sampling]}"
        return f"{text}; {cls.load_sampling_note}" if cls.load_sampling_note else text

    @classmethod
    def run_load_sampling(cls, problem: Problem) -> str | None:
        """This engine's load sampling on ``problem`` (None when the case has no loads); default:
        the declared ``load_sampling``.  An engine that samples some kinds of load per stage and
        others per step returns the rule that holds for the case's loads as it applies them."""
        return cls.load_sampling if problem.loads else None

    @classmethod
    def offered_integrators(cls) -> tuple[str, ...]:
        """Integrators available in the installed version (default first)."""
        return cls.integrators

    @classmethod
    def trap_checks(cls) -> dict[str, TrapCheck]:
        """Live checks of the engine's own traps that the adapter handles (a hidden damping, a
        velocity clamp, sleeping, a quaternion never renormalised...): name -> a function that
        builds what it needs, runs the engine and returns (passed, measured value, bound, one
        sentence).  Each must fail if the adapter stops handling its trap.  Run by ``freebody
        conventions`` and the test suite (:func:`freebody.run.selfcheck.run_trap_checks`); default: none."""
        return {}

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        """Integrators ``freebody conventions`` self-checks (default: every offered one)."""
        return cls.offered_integrators()

    @classmethod
    def output_capture(cls):
        """A context manager around anything that may make the engine print (import, build,
        stepping); yields an object with ``lines`` and ``total``.  Default: the C-level
        stdout/stderr captured into the run's ``engine_output``."""
        return capture_output()

    def prepare(self, steps: int) -> None:
        """Told before stepping how many steps the run will take from here (an adapter that
        integrates whole trajectories at once can do so here).  Default: nothing."""

    def close(self) -> None:
        """Release the engine's resources."""

    def bare_loop(self, steps: int) -> Callable[[], object] | None:
        """For ``freebody bench``: a callable running the engine's own step and its minimal state
        reads ``steps`` times on this adapter's world, with none of the adapter's work; None
        when the engine has no such loop (bench then skips its overhead figure)."""
        return None

    @classmethod
    def simulate_batch(cls, problems: list[Problem], dt: float, steps: int, integrator: str,
                       precision: str = "float64") -> BatchRun:
        """Step many problems of one integrator, precision, dt and horizon together; each body's
        trajectory equals what :meth:`simulate` gives for it alone, to round-off (a vectorised
        kernel may order its floating-point operations differently)."""
        raise NotImplementedError(f"{cls.name} does not step bodies as a batch")

    @classmethod
    def step_runs(cls, adapters: list["Adapter"], steps: list[int],
                  on_steps: Callable[[int, int], None] | None = None) -> list[Trajectory]:
        """With ``steps_runs_together``: step each built adapter ``steps[i]`` steps from its current
        state in one program, each run's samples those of :meth:`simulate` alone, bit for bit;
        ``on_steps(done, total)`` as the steps of all the runs progress.  Returns the
        trajectories in order."""
        raise NotImplementedError(f"{cls.name} does not step runs together")

    @classmethod
    def runs_scope(cls, precision: str):
        """A context manager in which many runs of ``precision`` are built and stepped together
        (an engine with a per-precision global mode enters it once); default: nothing."""
        return contextlib.nullcontext()

    def record_setting(self, key: str, default, value) -> None:
        """Note that the adapter changed an engine default (stored as results.json engine_settings)."""
        self.settings[key] = {"default": _plain(default), "set": _plain(value)}

    # --- what the harness calls (not overridden) -----------------------------------------------
    def chunks(self, steps: int, chunk_steps: int | None = None) -> Iterator[Trajectory]:
        """Step ``steps`` times, delivering the samples in consecutive pieces of at most
        ``chunk_steps`` steps (None: one piece).  The first piece starts with the current state;
        together the pieces hold the steps + 1 samples once each.  An :class:`EngineDiverged`
        carries the samples of its own piece only (after the pieces already delivered)."""
        if steps < 0:
            raise ValueError(f"steps must be >= 0, got {steps}")
        n = steps if chunk_steps is None else max(1, int(chunk_steps))
        self.prepare(steps)
        if steps == 0:
            yield self.advance(0)
            return
        done = 0
        while done < steps:
            m = min(n, steps - done)
            try:
                piece = self.advance(m)
            except EngineDiverged as e:
                if done and e.trajectory is not None:
                    e.trajectory = e.trajectory.tail(1)
                raise
            yield piece if done == 0 else piece.tail(1)
            done += m

    def simulate(self, steps: int, chunk_steps: int | None = None,
                 on_piece: Callable[[int], None] | None = None) -> Trajectory:
        """The whole run: the steps + 1 samples from the current state (t = (k0 + i) dt).
        Raises :class:`EngineDiverged` carrying every sample up to the blow-up.  ``on_piece(done)``
        is called after each piece of ``chunk_steps`` steps with the steps done so far (the
        harness's progress of a long run)."""
        pieces: list[Trajectory] = []
        done = 0
        try:
            for piece in self.chunks(steps, chunk_steps):
                pieces.append(piece)
                if on_piece is not None:
                    # the first piece holds its steps + 1 samples, the others their steps
                    done += len(piece) - (1 if len(pieces) == 1 else 0)
                    on_piece(done)
        except EngineDiverged as e:
            if e.trajectory is not None:
                pieces.append(e.trajectory)
            e.trajectory = Trajectory.concatenate(pieces) if pieces else None
            raise
        return pieces[0] if len(pieces) == 1 else Trajectory.concatenate(pieces)


class SteppedAdapter(Adapter):
    """A helper base for engines stepped one call at a time: define :meth:`apply_loads`,
    :meth:`step` and :meth:`read_state` (and :meth:`instability` if the engine signals one);
    :meth:`advance` is the loop over them."""

    @abstractmethod
    def apply_loads(self, segment: Segment) -> None:
        """Put the segment's loads on the body for the next step, at the current state (cleared
        after the step, or overwritten: the engine's way)."""

    @abstractmethod
    def step(self) -> None:
        """Advance the engine by one step of dt (``advance`` moves ``self.k``)."""

    @abstractmethod
    def read_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(position (3,) m COM world, quaternion (4,) wxyz body -> world,
        linear velocity (3,) m/s COM world, angular velocity (3,) rad/s world)."""

    def instability(self) -> str | None:
        """The engine's own instability warning since the last call, or None."""
        return None

    def advance(self, steps: int) -> Trajectory:
        k0 = self.k
        out = Trajectory.empty(steps + 1)
        out.t[:] = (k0 + np.arange(steps + 1)) * self.dt
        pos, quat, vel, ang = out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity
        pos[0], quat[0], vel[0], ang[0] = self.read_state()
        for i in range(steps):
            self.apply_loads(self.loads.at(k0 + i))
            self.step()
            self.k = k0 + i + 1
            pos[i + 1], quat[i + 1], vel[i + 1], ang[i + 1] = self.read_state()
            warning = self.instability()
            if warning is not None:
                raise EngineDiverged(self.k * self.dt, warning, out.head(i + 2))
        return out


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, (list, tuple)):
        return [_plain(a) for a in v]
    return v


# --- the registry -------------------------------------------------------------------------------

class EngineEntry(NamedTuple):
    """A registered engine, known without importing it.

    import_name : the engine's top-level Python module (``find_spec`` says whether it is installed).
    module, cls : where its adapter class lives.  install_hint : how to install the engine.
    cache_env : an environment variable naming a folder where the engine keeps compiled code
        (JIT engines): worker processes of one invocation are given one shared folder.  None for
        an engine that keeps a persistent cache of its own (mjx).
    package : the engine's pip distribution, which a versioned engine name pins
        (``mujoco==3.1.6``, see :func:`split_engine_name`); None: ``import_name``.
    environment : a pip requirement: the engine always runs in an isolated environment of its own
        holding it (an engine whose package pins conflict with another engine's, e.g. one that
        pins an older MuJoCo), see :mod:`freebody.envs.engines`; None: this environment.
    default : in the engines ``freebody run`` runs when none is named (fast ones); False: only
        when named with ``--engine`` or with ``--all-engines`` (seconds per run, long first compiles).
    worker_env : ((variable, value), ...) set in the environment of the worker processes of an
        invocation that runs the engine, unless already set: a setting of the engine's import that
        a run does not need (MuJoCo's ``MUJOCO_GL=disable``: no OpenGL back-end imported, ~35 ms
        CPU a worker; nothing is drawn).  (): none.
    """

    import_name: str
    module: str
    cls: str
    install_hint: str = "pip install 'freebody[engines]'"
    cache_env: str | None = None
    package: str | None = None
    environment: str | None = None
    default: bool = True
    worker_env: tuple[tuple[str, str], ...] = ()

    @property
    def distribution(self) -> str:
        """The pip distribution of the engine."""
        return self.package or self.import_name


# engine name -> its entry.  Order = report order.
ENGINES: dict[str, EngineEntry] = {
    "reference": EngineEntry("numpy", "freebody.adapters.reference", "ReferenceAdapter",
                             "always installed"),
    # workers: MuJoCo without its OpenGL back-end (glfw, ~35 ms CPU an import): no run draws
    "mujoco": EngineEntry("mujoco", "freebody.adapters.mujoco_adapter", "MujocoAdapter",
                          worker_env=(("MUJOCO_GL", "disable"),)),
    "pybullet": EngineEntry("pybullet", "freebody.adapters.pybullet_adapter", "PybulletAdapter"),
    "dart": EngineEntry("dartpy", "freebody.adapters.dart_adapter", "DartAdapter", package="dartpy"),
    # no cache_env: the mjx adapter keeps JAX's compilations in a persistent per-user folder
    # (JAX_COMPILATION_CACHE_DIR or ~/.cache/freebody/jax) shared by every process and invocation
    "mjx": EngineEntry("jax", "freebody.adapters.mjx_adapter", "MjxAdapter",
                       "pip install 'freebody[jax]'", package="mujoco-mjx", worker_env=(("MUJOCO_GL", "disable"),)),
    "drake": EngineEntry("pydrake", "freebody.adapters.drake_adapter", "DrakeAdapter",
                         "pip install 'freebody[drake]'", package="drake"),
    "sapien": EngineEntry("sapien", "freebody.adapters.sapien_adapter", "SapienAdapter",
                          "pip install 'freebody[sapien]'"),
    # opt-in (default=False): first compiles of 25-60 s per solver (warp) / seconds per run (JAX)
    "newton": EngineEntry("newton", "freebody.adapters.newton_adapter", "NewtonAdapter",
                          "pip install 'freebody[newton]'", default=False),
    "brax": EngineEntry("brax", "freebody.adapters.brax_adapter", "BraxAdapter",
                        "pip install 'freebody[brax]'", default=False),
}

# The engine whose runs are freebody's own reference maps: shared with scheme identification (so
# the planner orders them first) and never identified themselves.
REFERENCE_ENGINE = "reference"
# The engine ``freebody bench`` measures the reference maps against (its bare_loop is the yardstick).
BENCH_YARDSTICK = "mujoco"


def install_hint(name: str) -> str:
    """How to install an engine (from its registry entry)."""
    return registry_entry(name).install_hint


def registry_entry(name: str) -> EngineEntry:
    """The registry entry of an engine name (versioned or not; UnknownEngine otherwise), a built-in's
    without the entry-point scan (a built-in wins over a plug-in of its name, as in :func:`registry`)."""
    name = base_engine(name)
    return ENGINES[name] if name in ENGINES else registry()[name]


# The entry-point scan of this process (importlib.metadata reads every installed distribution's
# metadata: tens of ms), kept with what it depends on: the scanning function (a test may replace
# it) and the import path (a plug-in's folder added to sys.path joins the registry).
_entry_point_scan: tuple[object, tuple[str, ...], dict[str, EngineEntry]] | None = None


def reset_registry() -> None:
    """Forget this process's entry-point scan: the next :func:`registry` scans again (for tests
    that install or fake a plug-in; a change of ``sys.path`` or of
    ``importlib.metadata.entry_points`` is seen without it)."""
    global _entry_point_scan
    _entry_point_scan = None


def _entry_point_engines() -> dict[str, EngineEntry]:
    """The engines of the :data:`ENTRY_POINT_GROUP` entry points: scanned once per process (and
    again after :func:`reset_registry`, a change of ``sys.path`` or of the scanning function)."""
    global _entry_point_scan
    import importlib.metadata  # here: its import costs ~35 ms CPU, which a built-in engine's run need not pay

    scan, path = importlib.metadata.entry_points, tuple(sys.path)
    if _entry_point_scan is None or _entry_point_scan[0] is not scan or _entry_point_scan[1] != path:
        _entry_point_scan = (scan, path, _scan_entry_points(scan))
    return dict(_entry_point_scan[2])


def _scan_entry_points(scan) -> dict[str, EngineEntry]:
    found = {}
    for ep in scan(group=ENTRY_POINT_GROUP):
        module, _, cls = ep.value.partition(":")
        dist = getattr(ep, "dist", None)
        hint = f"pip install {dist.name}" if dist is not None else f"install the package of {module}"
        found.setdefault(ep.name, EngineEntry(module.split(".")[0], module, cls, hint))
    return found


def registry() -> dict[str, EngineEntry]:
    """All engines: the built-in ones, then third parties' (entry points)."""
    reg = dict(ENGINES)
    for name, spec in _entry_point_engines().items():
        reg.setdefault(name, spec)
    return reg


def engine_names() -> list[str]:
    return list(registry())


def default_engine_names() -> list[str]:
    """The engines ``freebody run`` runs when none is named (registry entries with ``default``)."""
    return [name for name, entry in registry().items() if entry.default]


# A versioned engine name: the engine (or its pip distribution) then a PEP 440 version specifier,
# e.g. "mujoco==3.1.6", "dartpy>=6.19,<6.20"
_VERSIONED = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*((?:===|~=|==|!=|<=|>=|<|>).*)?$")
_SPECIFIER = re.compile(r"^(===|~=|==|!=|<=|>=|<|>)\s*([A-Za-z0-9.*+!_-]+)$")  # one clause


def split_engine_name(name: str) -> tuple[str, str]:
    """(engine as given, version specifier) of an engine name: ``"mujoco==3.1.6"`` ->
    ``("mujoco", "==3.1.6")``, ``"mujoco"`` -> ``("mujoco", "")``.  The specifier is normalised
    (no spaces); UnknownEngine for a malformed one."""
    m = _VERSIONED.match(name)
    if m is None:
        raise UnknownEngine(f"{name!r} is neither an engine name nor ENGINE==VERSION "
                            f"(known engines: {', '.join(engine_names())})")
    raw = m.group(2) or ""
    clauses = raw.split(",") if raw.strip() else []
    for clause in clauses:
        if not _SPECIFIER.match(clause.strip()) or " " in clause.strip().lstrip("=<>!~").strip():
            raise UnknownEngine(f"{name!r}: {clause.strip()!r} is not a version specifier (e.g. ==3.1.6, "
                                f">=6.19,<6.20)")
    spec = ",".join(re.sub(r"\s+", "", c) for c in clauses)
    return m.group(1), spec


def base_engine(name: str) -> str:
    """The registered engine of a name, versioned or not (case-insensitive; an engine's pip
    distribution works too: ``dartpy==6.19.0`` -> ``"dart"``); UnknownEngine otherwise."""
    given, _ = split_engine_name(name)
    if given in ENGINES:  # a built-in's own spelling: no entry-point scan (registry() lists it first)
        return given
    reg = registry()
    for known in reg:
        if known.lower() == given.lower():
            return known
    for known, entry in reg.items():  # its pip distribution (dartpy, mujoco-mjx)
        if entry.distribution.lower().replace("_", "-") == given.lower().replace("_", "-"):
            return known
    raise UnknownEngine(f"unknown engine {given!r}; known engines: {', '.join(engine_names())}")


def resolve_engine(name: str) -> str:
    """The registered spelling of an engine name (case-insensitive), with its version specifier
    if it has one (``"MuJoCo == 3.1.6"`` -> ``"mujoco==3.1.6"``); UnknownEngine otherwise."""
    return base_engine(name) + split_engine_name(name)[1]


def engine_requirement(name: str) -> str | None:
    """The pip requirement of the isolated environment an engine's runs need (its distribution
    and version specifier for a versioned name, the registry's ``environment`` for an engine
    that always runs in its own), or None: this environment."""
    base = base_engine(name)
    spec = split_engine_name(name)[1]
    entry = registry_entry(base)
    if spec:
        if base == REFERENCE_ENGINE:
            raise UnknownEngine(f"{name!r}: the reference engine is freebody itself and has no versions")
        return entry.distribution + spec
    return entry.environment


def version_in(version: str, specifier: str) -> bool | None:
    """Whether a version satisfies a PEP 440 specifier of comparison clauses (``">=6.19,<7"``),
    comparing release numbers (``"3.1.6"`` -> (3, 1, 6); a pre-release counts as its release);
    None when either cannot be read.  Enough for an adapter's supported range, without packaging."""
    def release(v: str):
        m = re.match(r"^\s*v?(\d+(?:\.\d+)*)", v)
        return tuple(int(x) for x in m.group(1).split(".")) if m else None

    def cmp(a, b):
        n = max(len(a), len(b))
        a, b = a + (0,) * (n - len(a)), b + (0,) * (n - len(b))
        return (a > b) - (a < b)

    have = release(version)
    if have is None:
        return None
    for clause in filter(None, specifier.replace(" ", "").split(",")):
        m = _SPECIFIER.match(clause)
        if m is None:
            return None
        op, want = m.groups()
        if op in ("==", "!=", "===") and want.endswith(".*"):
            w = release(want[:-2])
            ok = w is not None and have[:len(w)] == w
            ok = ok if op != "!=" else not ok
        else:
            w = release(want)
            if w is None:
                return None
            c = cmp(have, w)
            ok = {"==": c == 0, "===": c == 0, "!=": c != 0, "<=": c <= 0, ">=": c >= 0, "<": c < 0,
                  ">": c > 0, "~=": c >= 0 and have[:max(1, len(w) - 1)] == w[:max(1, len(w) - 1)]}[op]
        if not ok:
            return False
    return True


def unsupported_version(cls: type[Adapter], version: str | None) -> str | None:
    """Why the adapter class cannot drive this engine version (the reason a run is skipped), or
    None: the version is in ``cls.supported_versions`` (or either is unknown)."""
    supported = cls.supported_versions
    if not supported or version is None or version_in(str(version), supported) is not False:
        return None
    entry = registry().get(cls.name, None)
    dist = entry.distribution if entry is not None else cls.name
    return (f"{cls.name} {version} is not supported: freebody's {cls.name} adapter drives "
            f"{dist}{supported} (e.g. --engine '{cls.name}{supported.split(',')[0]}')")


def distribution_version(distribution: str, fallback: Callable[[], object]) -> str:
    """The installed version of an engine's pip distribution (what ``engine_version`` reports);
    ``str(fallback())`` when its metadata is missing (a source build)."""
    import importlib.metadata

    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return str(fallback())


def is_available(name: str) -> bool:
    """Whether the engine's package can be found, without importing it."""
    return importlib.util.find_spec(registry_entry(name).import_name) is not None


# --- plug-ins are imported in a child process first -----------------------------------------------

# The environment variable that overrides PLUGIN_IMPORT_TIMEOUT_S (seconds; ``run --timeout`` wins).
PLUGIN_IMPORT_TIMEOUT_ENV = "FREEBODY_PLUGIN_IMPORT_TIMEOUT"
_PROBE_MARK = "freebody-plugin-probe: "
# The child: import the module, say how it went on one marked line, leave without atexit handlers
_PROBE_CODE = "\n".join((
    "import importlib, json, os, sys",
    "sys.path[:] = json.loads(sys.argv[2])",
    "try:",
    "    importlib.import_module(sys.argv[1]); r = None",
    "except BaseException as e:",
    "    r = [type(e).__name__, str(e)[:500]]",
    "sys.stdout.write('\\n' + sys.argv[3] + json.dumps(r) + '\\n'); sys.stdout.flush(); os._exit(0)"))
_import_timeout_s: float | None = None  # set by run --timeout (set_plugin_import_timeout)
_probed: dict[str, str | None] = {}  # plug-in module -> why its import failed, None: it imports


def set_plugin_import_timeout(seconds: float | None) -> None:
    """Use ``seconds`` (``run --timeout``) as the plug-in import limit; None: the default."""
    global _import_timeout_s
    _import_timeout_s = seconds


def plugin_import_timeout() -> float:
    """How long a plug-in's module may take to import (s): ``run --timeout`` when given, else
    $FREEBODY_PLUGIN_IMPORT_TIMEOUT, else :data:`freebody.tolerances.PLUGIN_IMPORT_TIMEOUT_S`."""
    from freebody.tolerances import PLUGIN_IMPORT_TIMEOUT_S

    if _import_timeout_s is not None:
        return float(_import_timeout_s)
    try:
        value = float(os.environ.get(PLUGIN_IMPORT_TIMEOUT_ENV, ""))
    except ValueError:  # unset or not a number
        return PLUGIN_IMPORT_TIMEOUT_S
    return value if value > 0 else PLUGIN_IMPORT_TIMEOUT_S


def is_plugin(name: str) -> bool:
    """Whether an engine is a third party's (an entry point of :data:`ENTRY_POINT_GROUP`), not a
    built-in adapter (:data:`ENGINES`): its module is imported only after :func:`probe_plugin`,
    and only by what needs its adapter class (its runs, ``conventions``)."""
    try:
        return base_engine(name) not in ENGINES
    except UnknownEngine:
        return False


def plugin_probes() -> dict[str, str | None]:
    """The outcome of this process's plug-in probes: module -> why its import failed, or None when
    it imported (handed to worker processes by :func:`seed_plugin_probes`, so that none probes a
    plug-in again: neither waits for a broken one nor starts a process for a sound one)."""
    return dict(_probed)


def seed_plugin_probes(probes: dict[str, str | None]) -> None:
    """Take the probes of another process (:func:`plugin_probes`) as this one's."""
    _probed.update(probes)


def probe_plugin(name: str, entry: EngineEntry) -> None:
    """Import a plug-in's adapter module in a child process, under :func:`plugin_import_timeout`,
    once per process; PluginImportFailed (naming the plug-in, its entry point and what happened)
    when the import did not finish in time, crashed or exited.  An exception at import is left
    for the import in this process to raise (a broken install: a failed run with its error)."""
    module = entry.module
    if module not in _probed:
        _probed[module] = _probe(module)
    if _probed[module] is not None:
        raise PluginImportFailed(f"plug-in {name} (entry point {ENTRY_POINT_GROUP}: {name} = "
                                 f"{module}:{entry.cls}): {_probed[module]}")


def _probe(module: str) -> str | None:
    """Why importing ``module`` in a child process failed, None when it imported (or raised an
    ordinary exception, which the import here reproduces)."""
    timeout = plugin_import_timeout()
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE_CODE, module, json.dumps(sys.path), _PROBE_MARK],
                              stdin=subprocess.DEVNULL, capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"import did not finish within {timeout:g} s"
    except OSError as e:
        return f"cannot start a process to import it: {e.strerror or e}"
    for line in reversed(proc.stdout.decode("utf-8", "replace").splitlines()):
        if line.startswith(_PROBE_MARK):
            raised = json.loads(line[len(_PROBE_MARK):])
            if raised is not None and raised[0] in ("SystemExit", "KeyboardInterrupt"):
                return f"import exited ({raised[0]}: {raised[1] or 'no code'})"
            return None
    if proc.returncode < 0:
        try:
            sig = signal.Signals(-proc.returncode).name
        except ValueError:
            sig = f"signal {-proc.returncode}"
        return f"import crashed (killed by {sig})"
    return f"import exited with code {proc.returncode}"


def load_adapter(name: str) -> type[Adapter]:
    """Import and return the adapter class of an engine.

    Raises EngineMissing when the engine's own package is not installed (only that ImportError:
    a broken install raises its real error, to be recorded as a failed run).  A plug-in's module
    (an entry point's, not a built-in adapter) is first imported in a child process under
    :func:`plugin_import_timeout` (:func:`probe_plugin`): PluginImportFailed when that import
    hangs, crashes or exits, so that no plug-in can stall or end this process.
    """
    name = base_engine(name)
    # a built-in engine wins over a plug-in of its name (registry()), so only the others need the
    # entry-point scan (about 14 ms a call, and the judge asks per run)
    entry = ENGINES[name] if name in ENGINES else registry()[name]
    import_name, module, cls, hint = entry.import_name, entry.module, entry.cls, entry.install_hint
    if name not in ENGINES and importlib.util.find_spec(import_name) is not None:  # is_plugin
        probe_plugin(name, entry)  # a missing plug-in is EngineMissing below, as a built-in
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        # only "no module named <engine>" means missing; "cannot import name X from <engine>"
        # (also e.name == engine) is a broken install
        if isinstance(e, ModuleNotFoundError) and e.name == import_name:
            raise EngineMissing(f"{name} is not installed (import {import_name!r} failed): "
                                f"{hint}") from e
        raise
    return getattr(mod, cls)
