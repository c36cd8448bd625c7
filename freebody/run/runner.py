"""Runs: expand the matrix (case x engine x integrator x precision x dt), execute one run, decide its
status in one place.

A run's status is data:
- ``ok``: the engine ran to the end and stayed within the case's bounds;
- ``diverged``: non-finite state, beyond the bounds (see :func:`freebody.run.metrics.divergence`), or the
  engine's own instability warning; ``diverged_at_s`` says when;
- ``failed``: the engine (or its adapter) raised; the message says what;
- ``skipped``: the engine is not installed; the message says how to install it.
"""
from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field, replace

import numpy as np

from ..adapters.base import (REFERENCE_ENGINE, EngineDiverged, EngineMissing, UnknownEngine,
                            is_available, load_adapter, resolve_engine, engine_names)
from ..adapters.capture import capture_output
from ..errors import InputError
from .metrics import Series, divergence, summarize
from ..reference_impl.conventions import Trajectory
from ..reference_impl.integrators import simulate as reference_simulate
from ..reference_impl.problem import Problem
from ..reference_impl.rotations import geodesic_angle
from ..reference_impl.truth import truth_kind, truth_trajectory
from .. import tolerances as tol

STATUSES = ("ok", "diverged", "failed", "skipped")
PRECISIONS = ("float32", "float64")  # floating-point precisions an engine may offer

# Reference maps an engine run is compared with (scheme identification); rk4 only where the engine
# offers an RK4 of its own.
SCHEME_CANDIDATES = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")


@dataclass(frozen=True)
class RunSpec:
    """One run to execute.  ``problem`` is the validated case; ``integrator`` is spelt as the engine
    spells it ("*" for an engine that is not installed)."""

    problem: Problem
    engine: str
    integrator: str
    dt: float
    steps: int
    precision: str = "float64"

    @property
    def is_reference(self) -> bool:
        """Whether this run is one of freebody's own reference maps (the registry's reference
        engine): shared with scheme identification, never identified itself."""
        return self.engine == REFERENCE_ENGINE

    @property
    def key(self) -> tuple:
        """A run's identity: (case, engine, integrator, precision, dt)."""
        return (self.problem.name, self.engine, self.integrator, self.precision, self.dt)


@dataclass(frozen=True)
class RunResult:
    """The outcome of one run: the serialised form is a ``runs`` entry of results.json."""

    case: str
    engine: str
    integrator: str
    precision: str
    dt: float
    steps: int
    status: str
    message: str
    truth: str
    metrics: dict
    final_state: dict | None
    wall_time_s: float
    engine_version: str | None = None
    engine_settings: dict = field(default_factory=dict)
    matches_reference: dict | None = None
    diverged_at_s: float | None = None
    trajectory: str | None = None
    engine_output: list = field(default_factory=list)
    vs_engine: dict | None = None
    # s spent compiling the engine's step (JIT engines, e.g. mjx; 0 when cached; None: no JIT),
    # included in wall_time_s
    compile_time_s: float | None = None

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class RunOutput:
    """A run's result with its arrays (for the Python API, trajectory files and reports)."""

    result: RunResult
    trajectory: Trajectory | None
    truth: Trajectory | None
    series: Series | None


# --- the matrix ---------------------------------------------------------------------------------

def select_engines(requested: list[str] | None) -> list[str]:
    """Requested engines (validated, case-insensitive), or every registered engine."""
    if not requested:
        return engine_names()
    try:
        out = []
        for name in requested:
            e = resolve_engine(name)
            if e not in out:
                out.append(e)
        return out
    except UnknownEngine as e:
        raise InputError(f"--engine: {e.args[0]}") from None


def engine_integrators(engine: str) -> tuple[str, ...] | None:
    """Integrators the installed engine offers (default first), or None if it is not installed or
    its adapter fails to load (its runs then record skipped or failed, with the reason)."""
    if not is_available(engine):
        return None
    try:
        with capture_output():  # some engines print a banner on import (pybullet)
            return load_adapter(engine).offered_integrators()
    except Exception:
        return None


def engine_precisions(engine: str) -> tuple[str, ...] | None:
    """Precisions the installed engine offers (``Adapter.precisions``), or None if it is not
    installed or its adapter fails to load."""
    if not is_available(engine):
        return None
    try:
        with capture_output():
            return tuple(load_adapter(engine).precisions)
    except Exception:
        return None


def select_precisions(offered: dict[str, tuple[str, ...] | None],
                      requested: list[str] | None) -> dict[str, list[str]]:
    """Apply ``--precision`` selections to every engine: engine -> its precisions to run.

    None: every precision each engine offers.  Otherwise an engine runs the requested ones it
    offers and is left out of the matrix when it offers none; a requested precision that no
    selected engine offers is bad input.  An engine that is not installed (offered None) keeps one
    run (float64, or the first requested), to be recorded as skipped.
    """
    if requested:
        for p in requested:
            if p not in PRECISIONS:
                raise InputError(f"--precision: unknown precision {p!r}; known: {', '.join(PRECISIONS)}")
        known = {e: o for e, o in offered.items() if o is not None}
        if len(known) == len(offered):
            for p in requested:
                if not any(p in o for o in known.values()):
                    have = "; ".join(f"{e}: {', '.join(o)}" for e, o in known.items())
                    raise InputError(f"--precision: no selected engine offers {p} ({have})")
    out = {}
    for engine, o in offered.items():
        if o is None:
            out[engine] = ["float64" if not requested or "float64" in requested else requested[0]]
        elif requested:
            out[engine] = [p for p in o if p in requested]
        else:
            out[engine] = list(o)
    return out


def select_integrators(engine: str, offered: tuple[str, ...], requested: list[str] | None) -> list[str]:
    """Apply ``--integrator`` selections: NAME applies to every engine, ENGINE:NAME to one engine.

    An engine to which no selection applies runs all its integrators; one to which selections
    apply but which offers none of them is bad input (the message lists what it offers).
    """
    names = []
    for item in requested or []:
        eng, sep, name = item.partition(":")
        if not sep:
            names.append(item)
            continue
        try:
            target = resolve_engine(eng)
        except UnknownEngine:
            raise InputError(f"--integrator: unknown engine {eng!r} in {item!r}; "
                             f"known engines: {', '.join(engine_names())}") from None
        if target == engine:
            if not any(o.lower() == name.lower() for o in offered):
                raise InputError(f"--integrator: {engine} has no integrator {name!r}; "
                                 f"it offers: {', '.join(offered)}")
            names.append(name)
    if not names:
        return list(offered)
    chosen = [o for o in offered if any(o.lower() == n.lower() for n in names)]
    if not chosen:
        raise InputError(f"--integrator: {engine} offers none of {', '.join(repr(n) for n in names)}; "
                         f"it offers: {', '.join(offered)}")
    return chosen


def expand(problems: list[Problem], engines: list[str], integrators: list[str] | None,
           dts: list[float] | None, duration: float | None,
           precisions: list[str] | None = None) -> list[RunSpec]:
    """Every run of the matrix, in a stable order (case, dt, engine, integrator, precision).

    precisions : None for every precision each engine offers (``Adapter.precisions``), else the
    ones to run (see :func:`select_precisions`)."""
    if dts is not None:
        for d in dts:
            if not (np.isfinite(d) and d > 0):
                raise InputError(f"--dt: must be a finite number > 0, got {d}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration: must be a finite number > 0, got {duration}")
    per_engine: dict[str, list[str]] = {}
    for engine in engines:
        offered = engine_integrators(engine)
        if offered is None:
            per_engine[engine] = ["*"]
        else:
            per_engine[engine] = select_integrators(engine, offered, integrators)
    per_precision = select_precisions({e: engine_precisions(e) for e in engines}, precisions)
    specs = []
    for pb in problems:
        for d in (dts or pb.dts):
            if duration is not None and duration < d:
                raise InputError(f"--duration: {duration} s is shorter than dt = {d} s")
            if duration is None and pb.duration is not None and pb.duration < d * (1 - 1e-12):
                raise InputError(f"--dt: {d} s is longer than case {pb.name}'s duration ({pb.duration} s)")
            steps = pb.steps(d, duration)
            for engine in engines:
                for integ in per_engine[engine]:
                    for prec in per_precision[engine]:
                        specs.append(RunSpec(pb, engine, integ, float(d), steps, prec))
    return specs


# --- one run ------------------------------------------------------------------------------------

class TruthCache:
    """Truth trajectories per (case, dt, steps), computed once per process."""

    def __init__(self):
        self._cache: dict = {}

    def get(self, problem: Problem, dt: float, steps: int) -> Trajectory:
        key = (id(problem), problem.name, dt, steps)
        if key not in self._cache:
            self._cache[key] = truth_trajectory(problem, dt, steps)
        return self._cache[key]

    def engine_run(self, problem: Problem, engine: str, integrator: str, dt: float, steps: int) -> Trajectory:
        """Another engine's float64 trajectory of the same case (for ported engines' comparison)."""
        key = (id(problem), problem.name, dt, steps, engine, integrator)
        if key not in self._cache:
            adapter = load_adapter(engine)(problem, dt, integrator)
            try:
                self._cache[key] = adapter.simulate(steps)
            finally:
                adapter.close()
        return self._cache[key]

    def reference(self, problem: Problem, integrator: str, dt: float, steps: int) -> Trajectory:
        key = (id(problem), problem.name, dt, steps, integrator)
        if key not in self._cache:
            self._cache[key] = reference_simulate(problem, integrator, dt, steps)
        return self._cache[key]


def execute(spec: RunSpec, cache: TruthCache | None = None, identify_scheme: bool = True) -> RunOutput:
    """Run one spec; never raises for an engine's failure (that is the run's status).

    What the engine prints on the C level is captured into the result's ``engine_output``.
    """
    with capture_output() as captured:  # importing an engine may print (pybullet's banner)
        cls = _adapter_class(spec.engine)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        capture = cls.output_capture() if isinstance(cls, type) else capture_output()
        with capture as during:
            out = _execute(spec, cls, cache, identify_scheme)
    captured.lines.extend(during.lines)
    captured.total += during.total
    if captured.total:
        r = out.result
        message = r.message
        if r.status in ("failed", "diverged"):
            message = f"{message} [engine printed: {captured.lines[0][:200]}]"
        out = RunOutput(replace(r, engine_output=captured.summary(), message=message),
                        out.trajectory, out.truth, out.series)
    return out


def _adapter_class(engine: str):
    """The engine's adapter class, or the exception that loading it raised (recorded by
    _execute as a skipped or failed run)."""
    try:
        return load_adapter(engine)
    except Exception as e:
        return e


def _execute(spec: RunSpec, cls, cache: TruthCache | None, identify_scheme: bool) -> RunOutput:
    cache = cache or TruthCache()
    pb = spec.problem
    base = _identity(spec)
    t0 = time.perf_counter()
    if isinstance(cls, EngineMissing):
        return _no_trajectory(base, "skipped", str(cls), 0.0)
    if isinstance(cls, BaseException):  # a broken install is a failure, never a skip
        return _no_trajectory(base, "failed", f"importing the {spec.engine} adapter failed: {_describe(cls)}",
                              time.perf_counter() - t0)
    version = settings = adapter = None
    try:
        version = cls.engine_version()
        adapter = cls(pb, spec.dt, spec.integrator, spec.precision)
        settings = adapter.settings
        try:
            trajectory = adapter.simulate(spec.steps)
        finally:
            adapter.close()
        sim = Simulated(trajectory, None, "", version, settings, time.perf_counter() - t0,
                        adapter.compile_time_s)
    except EngineDiverged as e:
        sim = Simulated(e.trajectory, e.t, e.reason, version, settings, time.perf_counter() - t0,
                        adapter.compile_time_s if adapter is not None else None)
    except Exception as e:
        return _no_trajectory(base, "failed", _describe(e), time.perf_counter() - t0, version, settings)
    return finish(spec, sim, cache, identify_scheme, compare_with=cls.compare_with)


@dataclass(frozen=True)
class Simulated:
    """What an engine produced for one run, before it is judged against the truth.

    trajectory : the canonical samples (up to the blow-up when the engine reported one).
    diverged_at : s, when the engine itself reported an instability, else None.
    """

    trajectory: Trajectory | None
    diverged_at: float | None
    reason: str
    version: str | None
    settings: dict | None
    wall_time_s: float
    compile_time_s: float | None = None


def finish(spec: RunSpec, sim: Simulated, cache: TruthCache, identify_scheme: bool = True,
           compare_with: str | None = None) -> RunOutput:
    """Judge a simulated run: truth, divergence (the one place it is decided), metrics, scheme
    identification and the comparison with a ported engine's original.  Used for runs stepped one
    by one (:func:`execute`) and for runs stepped as a batch (``freebody sweep --engine mjx``)."""
    pb = spec.problem
    base = _identity(spec)
    trajectory, diverged_at, version, settings = sim.trajectory, sim.diverged_at, sim.version, sim.settings
    wall, compile_time = sim.wall_time_s, sim.compile_time_s
    status, message = ("ok", "") if diverged_at is None else ("diverged", sim.reason)
    try:
        truth = cache.get(pb, spec.dt, spec.steps)
    except Exception as e:
        return _no_trajectory(base, "failed", f"truth oracle failed: {_describe(e)}", wall, version,
                              settings)
    if trajectory is None or len(trajectory) == 0:
        return _no_trajectory(base, status, message, wall, version, settings, diverged_at)
    if status == "ok":
        found = divergence(pb, trajectory, truth)
        if found is not None:
            diverged_at, message = found
            status = "diverged"
            message = f"diverged at t = {diverged_at:.6g} s: {message}"
    elif diverged_at is not None:
        message = f"diverged at t = {diverged_at:.6g} s: {message}"
    metrics, series = summarize(pb, trajectory, truth)
    if status == "diverged":
        # metrics past a blow-up are meaningless: keep them up to the divergence only
        metrics = {k: (v if k == "rotation_orthonormality_error_max" else None) for k, v in metrics.items()}
        metrics.update(_prefix_metrics(pb, trajectory, truth, diverged_at))
    matches = vs_engine = None
    if identify_scheme and not spec.is_reference and status == "ok":
        matches = identify(pb, trajectory, spec, cache)
        if compare_with:
            vs_engine = compare_with_engine(pb, trajectory, spec, compare_with, cache)
    final = trajectory.state(-1).as_dict() if status == "ok" else None
    result = RunResult(**base, status=status, message=message, metrics=_clean(metrics), final_state=final,
                       wall_time_s=wall, engine_version=version, engine_settings=settings or {},
                       matches_reference=matches, diverged_at_s=diverged_at, compile_time_s=compile_time,
                       vs_engine=vs_engine)
    return RunOutput(result, trajectory, truth, series)


def compare_with_engine(pb: Problem, trajectory: Trajectory, spec: RunSpec, other: str,
                        cache: TruthCache) -> dict:
    """How far this run is from ``other`` engine's float64 run of the same integrator and dt (rad):
    e.g. MJX against C MuJoCo.  A missing or failing other engine is said, not raised."""
    out = {"engine": other, "integrator": spec.integrator, "precision": "float64"}
    try:
        offered = load_adapter(other).offered_integrators()
        match = [i for i in offered if i.lower() == spec.integrator.lower()]
        if not match:
            return {**out, "message": f"{other} offers no {spec.integrator}"}
        ref = cache.engine_run(pb, other, match[0], spec.dt, spec.steps)
    except EngineDiverged as e:
        return {**out, "message": f"{other} diverged at t = {e.t:.6g} s"}
    except Exception as e:
        return {**out, "message": f"{other} could not run: {_describe(e)}"}
    d = geodesic_angle(ref.quaternion_wxyz, trajectory.quaternion_wxyz)
    finite = bool(np.all(np.isfinite(d)))
    return {**out, "max_orientation_diff_rad": float(np.max(d)) if finite else None,
            "final_orientation_diff_rad": float(d[-1]) if finite else None}


def scheme_candidates(integrator: str) -> tuple[str, ...]:
    """The reference maps an engine run with this integrator is compared with (rk4 only for an
    engine integrator of the RK4 family)."""
    return SCHEME_CANDIDATES + (("rk4",) if "rk4" in integrator.lower() else ())


def identify(pb: Problem, trajectory: Trajectory, spec: RunSpec, cache: TruthCache) -> dict:
    """The reference map this engine run reproduces most closely, and how closely (rad)."""
    diffs = {}
    for name in scheme_candidates(spec.integrator):
        ref = cache.reference(pb, name, spec.dt, spec.steps)
        d = geodesic_angle(ref.quaternion_wxyz, trajectory.quaternion_wxyz)
        diffs[name] = float(np.max(d)) if np.all(np.isfinite(d)) else None
    finite = {k: v for k, v in diffs.items() if v is not None}
    best = min(finite, key=finite.get) if finite else None
    return {"integrator": best if best and finite[best] <= tol.SCHEME_MATCH_RAD else None,
            "closest": best, "max_orientation_diff_rad": finite.get(best),
            "candidates": diffs, "threshold_rad": tol.SCHEME_MATCH_RAD}


def _identity(spec: RunSpec) -> dict:
    """The fields of a RunResult that say which run it is."""
    return dict(case=spec.problem.name, engine=spec.engine, integrator=spec.integrator,
                precision=spec.precision, dt=spec.dt, steps=spec.steps, truth=truth_kind(spec.problem))


def _prefix_metrics(pb, trajectory, truth, t_div) -> dict:
    """Metrics over the samples before the divergence (keys suffixed ``_before_divergence``)."""
    n = int(np.searchsorted(trajectory.t, t_div))
    if n < 1:
        return {}
    head = trajectory.head(n).without_orthonormality()
    m, _ = summarize(pb, head, truth)
    return {"orientation_error_max_before_divergence_rad": m["orientation_error_max_rad"]}


def _clean(metrics: dict) -> dict:
    return {k: (None if v is None or not np.isfinite(v) else float(v)) for k, v in metrics.items()}


def _describe(e: BaseException) -> str:
    msg = str(e).strip().splitlines()
    where = traceback.extract_tb(e.__traceback__)[-1] if e.__traceback__ else None
    loc = f" (at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})" if where else ""
    return f"{type(e).__name__}: {msg[0] if msg else ''}{loc}"


def _no_trajectory(base, status, message, wall, version=None, settings=None, diverged_at=None) -> RunOutput:
    result = RunResult(**base, status=status, message=message, metrics={}, final_state=None,
                       wall_time_s=wall, engine_version=version, engine_settings=settings or {},
                       diverged_at_s=diverged_at)
    return RunOutput(result, None, None, None)
