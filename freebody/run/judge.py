"""Judging a simulated run, top-down: :func:`judge_run` takes what an engine produced
(:class:`~freebody.run.records.Simulated`) to its recorded result; :class:`RunJudge` feeds the
samples (whole, or chunk by chunk for a long run) to the computations on arrays of
:mod:`freebody.run.metrics` (error series, running maxima, divergence, state growth) and to scheme
identification (:class:`Identification`) and the comparison of a ported engine with its original
(:class:`VsEngine`); :func:`recorded` adds the facts the findings present
(:func:`freebody.results.judgement.run_judgement`).  The one place a run's status is decided, and
the one place its judgement is made: reports present it, they do not re-judge.

Also the builders of a run's records: :func:`run_identity` (which run, which experiment),
:func:`no_samples` (a run without samples: skipped, failed, stopped at once),
:func:`describe_error` (an exception as a run's message)."""
from __future__ import annotations

import dataclasses
import itertools
import traceback
from typing import Callable, Iterator

import numpy as np

from .. import tolerances as tol
from ..adapters.base import EngineDiverged, load_adapter
from ..adapters.capture import cap_line
from ..reference_impl.conventions import Trajectory
from ..reference_impl.engine_maps import ENGINE_MAPS, map_load_sampling
from ..reference_impl.sampling import LOAD_SAMPLING_PER_STAGE
from ..reference_impl.integrators import INTEGRATORS
from ..reference_impl.prepared_maps import MapStart, map_orientations, map_start, run_map
from ..reference_impl.problem import InitialState, Problem
from ..reference_impl.rotations import geodesic_angle
from ..reference_impl.truth import truth_chunks, truth_kind, truth_trajectory
from ..results.document import select_saved
from ..results import identification  # the verdicts' names, read by every reader
from ..results.judgement import run_judgement
from .experiment import experiment
from .metrics import STAT_ARRAYS, RunMetrics, Scales, Series, Terms, truth_scales
from .records import RunOutput, RunResult, RunSpec, Simulated, Status

# The engines' maps: what an engine integrator plausibly implements (rk4 only for an RK4 of its
# own); the self-checks bound an engine by these (:func:`engine_schemes`).
ENGINE_SCHEMES = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")
# Reference maps an engine run is compared with (scheme identification): every reference
# integrator and every engine-equivalent map (reference_impl.engine_maps: MuJoCo 4 RK4, MuJoCo 3 /
# MJX RK4, PyBullet maximal, DART).  A tie is named by its first map in this order: the engines'
# semi-implicit maps, rk4, the engine-equivalent maps (each one engine's exact scheme), then the
# other reference integrators (textbook schemes no engine is known to use).
SCHEME_CANDIDATES = (*ENGINE_SCHEMES, "rk4", *ENGINE_MAPS,
                     *(n for n in INTEGRATORS if n not in (*ENGINE_SCHEMES, "rk4")))
# A run judged whole is compared with every candidate map stacked (:class:`CandidateMaps`, one more
# copy of the maps' orientations: 32 MB at most) when the candidates x samples are at most this many;
# a longer run is compared with one map after another (the same numbers), which bounds its memory.
STACKED_SAMPLES_MAX = 1 << 20
# The comparisons of a run (or of a map's perturbed copies) with several maps go block by block,
# about this many samples a block: each temporary array (128 KB) stays in the CPU's cache, and a
# short run's maps all go in one block (the per-call cost of numpy, not the arithmetic, is a 10-step
# run's; a long run's blocks hold one map each, as one map after another).
BLOCK_SAMPLES = 1 << 14


def judge_run(spec: RunSpec, sim: Simulated, cache: "TruthCache", identify_scheme: bool = True,
              compare_with: str | None = None) -> RunOutput:
    """Judge a simulated run: truth, divergence (the one place it is decided), metrics, scheme
    identification, the comparison with a ported engine's original, and the facts of its
    findings (:func:`recorded`).  Used for runs stepped one by one
    (:func:`freebody.run.execute.execute`) and for runs stepped as a batch (``freebody sweep
    --engine mjx``).

    The run is judged as one chunk by :class:`RunJudge`, which a long run goes through chunk by
    chunk (:func:`freebody.run.execute.execute`): the same rules, the same numbers."""
    pb = spec.problem
    base = run_identity(spec, sim.settings)
    trajectory, diverged_at, version, settings = sim.trajectory, sim.diverged_at, sim.version, sim.settings
    status, message = (Status.OK, "") if diverged_at is None else (Status.DIVERGED, sim.reason)
    try:
        truth = cache.get(pb, spec.dt, spec.steps)
    except Exception as e:
        return no_samples(base, Status.FAILED, f"truth oracle failed: {describe_error(e)}", sim.wall_time_s,
                          version, settings)
    if trajectory is None or len(trajectory) == 0:
        return no_samples(base, status, message, sim.wall_time_s, version, settings, diverged_at)
    whole_truth, truth = truth, truth.head(len(trajectory))
    truth_terms = cache.terms(pb, whole_truth).of(pb, truth)  # the group's truth's, formed once
    scheme = identify_scheme and not spec.is_reference
    judge = RunJudge(spec, truth_terms.scales,
                     Identification(spec, cached_map_pieces(spec, cache),
                                    lambda: cached_candidate_maps(spec, cache)) if scheme else None,
                     VsEngine(spec, compare_with, cached_engine_pieces(spec, cache)) if scheme and compare_with else None)
    judge.feed(trajectory, truth, diverged_at, truth_terms)
    result = recorded(RunResult(**base, **judge.outcome(sim.reason), wall_time_s=sim.wall_time_s,
                                engine_version=version, engine_settings=settings or {},
                                compile_time_s=sim.compile_time_s))
    return RunOutput(result, trajectory, whole_truth, judge.whole_series)


def recorded(result: RunResult) -> RunResult:
    """The run's result with its ``judgement``: the facts its findings present (blow-up, rotation
    cap, the map it reproduces or comes closest to, saturation, its formal order...), computed
    here once from its judged fields by :func:`freebody.results.judgement.run_judgement` (which
    the schema-5 migration applies to older documents)."""
    return dataclasses.replace(result, judgement=run_judgement(result.to_json()))


def no_samples(base: dict, status: Status, message: str, wall: float, version: str | None = None,
               settings: dict | None = None, diverged_at: float | None = None) -> RunOutput:
    """The output of a run without samples (skipped, failed, or stopped before its first sample):
    ``base`` is its :func:`run_identity`, the rest its fields; no metrics, no arrays."""
    result = RunResult(**base, status=status, message=message, metrics={}, final_state=None,
                       wall_time_s=wall, engine_version=version, engine_settings=settings or {},
                       diverged_at_s=diverged_at)
    return RunOutput(recorded(result), None, None, None)


def run_identity(spec: RunSpec, settings: dict | None = None) -> dict:
    """The fields of a RunResult that say which run it is, and which experiment (``settings``:
    the adapter's, None when the engine was not built)."""
    return dict(case=spec.problem.name, engine=spec.engine, integrator=spec.integrator,
                precision=spec.precision, dt=spec.dt, steps=spec.steps, truth=truth_kind(spec.problem),
                experiment=experiment(spec.problem, spec.dt, spec.steps, settings),
                load_sampling=run_load_sampling(spec) if settings is not None else None)


def describe_error(e: BaseException) -> str:
    """An exception as a run's message: 'Type: first line (at file.py:line)', the line capped."""
    msg = str(e).strip().splitlines()
    where = traceback.extract_tb(e.__traceback__)[-1] if e.__traceback__ else None
    loc = f" (at {where.filename.rsplit('/', 1)[-1]}:{where.lineno})" if where else ""
    return f"{type(e).__name__}: {cap_line(msg[0]) if msg else ''}{loc}"  # a 50 MB message: cut


def whole_truth_scales(spec: RunSpec, chunk: int) -> Scales:
    """The truth's maxima over a run judged in chunks (:class:`~freebody.run.metrics.Scales`),
    from a first pass over its truth chunk by chunk (nothing of the whole truth is kept)."""
    scales = None
    for piece in truth_chunks(spec.problem, spec.dt, spec.steps, chunk):
        scales = truth_scales(spec.problem, piece).merged(scales)
    return scales


def run_load_sampling(spec: RunSpec) -> str | None:
    """The run's load sampling as its engine's adapter declares it for this case
    (``Adapter.run_load_sampling``), or None: the case has no loads, or the adapter cannot be
    loaded."""
    if not spec.problem.loads:
        return None
    try:  # the engine's module is imported already (it ran)
        return load_adapter(spec.engine).run_load_sampling(spec.problem)
    except Exception:
        return None


def identification_sampling(spec: RunSpec) -> str:
    """The variant of the multi-stage engine maps a run is compared with: its engine's load
    sampling (:func:`run_load_sampling`), per-stage when there is none."""
    return run_load_sampling(spec) or LOAD_SAMPLING_PER_STAGE


def step_rotation_cap(spec: RunSpec) -> float | None:
    """The largest rotation one step of the run's engine turns a body through (rad), as its adapter
    declares it (``Adapter.step_rotation_cap_rad``); None for none, the reference engine, or an
    adapter that cannot be loaded here."""
    if spec.is_reference:
        return None
    try:
        return load_adapter(spec.engine).step_rotation_cap_rad
    except Exception:
        return None


class RunJudge:
    """Judges one run from its samples, delivered whole (:func:`judge_run`: one :meth:`feed`) or in
    consecutive chunks (a long run, :func:`freebody.run.execute.execute`), with the same rules and
    the same numbers either way: the computations on its arrays (:class:`~freebody.run.metrics.RunMetrics`:
    error series scaled by the truth's maxima over the whole run ``scales``, running maxima,
    divergence, growth of the state), scheme identification (:class:`Identification`) and the
    comparison with a ported engine's original (:class:`VsEngine`), both fed only while no
    divergence is found; then :meth:`outcome` decides the run's status.

    every : keep the samples a trajectory file saves (:func:`~freebody.results.document.select_saved`
        with stride ``every``) as the chunks go by (a long run keeps no more); None: keep none
        (the caller has the whole run).
    """

    def __init__(self, spec: RunSpec, scales: Scales, identification: "Identification | None" = None,
                 vs_engine: "VsEngine | None" = None, every: int | None = None):
        self.spec = spec
        self.metrics = RunMetrics(spec.problem, scales, spec.dt, step_rotation_cap(spec))
        self.identification, self.vs_engine = identification, vs_engine
        self.n = 0
        self.last: Trajectory | None = None
        self.whole_series: Series | None = None  # of a run fed in one piece
        self.every = every
        self.diverged_index: int | None = None  # decided by outcome()
        self._rows: list = []

    def feed(self, tr: Trajectory, truth: Trajectory, diverged_at: float | None = None,
             truth_terms: Terms | None = None) -> None:
        """The next samples of the run (global indices n, n + 1, ...) and the truth's at them;
        ``diverged_at``: the engine reported a blow-up at that time (the last piece);
        ``truth_terms``: the truth samples' :class:`~freebody.run.metrics.Terms`, if formed."""
        k0, m = self.n, len(tr)
        if m == 0:
            return
        truth = truth.head(m)
        s, new, best_before = self.metrics.feed(tr, truth, k0, diverged_at, truth_terms)
        if self.every is not None:
            self._keep_saved(tr, truth, s, k0, new, best_before)
        if self.metrics.undiverged:
            q = tr.quaternion_wxyz
            if self.identification is not None:
                self.identification.update(q)
            if self.vs_engine is not None:
                self.vs_engine.update(q)
        self.whole_series = s if k0 == 0 else None
        self.n = k0 + m
        self.last = tr.take(np.array([m - 1]))

    def _keep_saved(self, tr: Trajectory, truth: Trajectory, s: Series, k0: int, new: list[int],
                    best_before: dict) -> None:
        """Keep this chunk's samples that the trajectory file may save: the stride's, its last, each
        new maximum, and the maxima before and the samples around a divergence found in it."""
        m, stats = len(tr), self.metrics.stats
        picks = [np.arange(-(-k0 // self.every) * self.every, k0 + m, self.every), [k0 + m - 1]]
        picks.append([v.best_index for name, v in stats.maxima.items()
                      if v.best_index is not None and v.best_index != best_before[name]])
        for d in new:
            picks.append(self.metrics.before[d].argmax_indices())
            picks.append([d - 1, d])
        g = np.unique(np.concatenate([np.asarray(p, dtype=np.int64) for p in picks]))
        g = g[(g >= k0) & (g < k0 + m)]
        local = g - k0
        self._rows.append((g, tr.take(local), truth.take(local),
                           [getattr(s, a)[local] for a in STAT_ARRAYS[:4]],
                           (s.angular_momentum_relative, s.energy_relative)))

    def engine_stopped(self, t: float) -> None:
        """The engine reported a blow-up at ``t`` after the samples fed, with no sample of its own:
        the divergence is at the next sample, the statistics before it those of every sample fed."""
        self.metrics.engine_stopped(self.n, t)

    def outcome(self, engine_reason: str = "") -> dict:
        """The judged fields of the run's RunResult (status, message, metrics, final_state,
        matches_reference, diverged_at_s, vs_engine, state_growth)."""
        found = self.metrics.divergence()
        status, message, d, diverged_at = Status.OK, "", None, None
        if found is not None:
            d, diverged_at, why = found
            status = Status.DIVERGED
            message = f"diverged at t = {diverged_at:.6g} s: {engine_reason if why is None else why}"
        self.diverged_index = d
        metrics, growth = self.metrics.result(d)
        ok = status == Status.OK
        return dict(status=status, message=message, metrics=metrics,
                    final_state=self.last.state(0).as_dict() if ok else None,
                    matches_reference=self.identification.result() if ok and self.identification else None,
                    vs_engine=self.vs_engine.result() if ok and self.vs_engine else None,
                    diverged_at_s=diverged_at, state_growth=growth)

    def saved(self) -> tuple[Trajectory, Trajectory, Series, np.ndarray]:
        """(run, truth, series, sample indices) at the samples its trajectory file keeps (after
        :meth:`outcome`; ``every`` given)."""
        d = self.diverged_index
        idx = select_saved(self.n, self.every, self.metrics.saved_maxima(d), d)
        g = np.concatenate([r[0] for r in self._rows])
        tr = Trajectory.concatenate([r[1] for r in self._rows])
        truth = Trajectory.concatenate([r[2] for r in self._rows])
        values = [np.concatenate([r[3][i] for r in self._rows]) for i in range(4)]
        _, first = np.unique(g, return_index=True)
        at = first[np.searchsorted(g[first], idx)]
        ser = Series(tr.t[at], *(v[at] for v in values), *self._rows[0][4])
        return tr.take(at), truth.take(at), ser, idx


class TruthCache:
    """Truth trajectories per (case, dt, steps), computed once per process."""

    def __init__(self):
        self._cache: dict = {}

    def get(self, problem: Problem, dt: float, steps: int) -> Trajectory:
        key = (id(problem), problem.name, dt, steps)
        if key not in self._cache:
            self._cache[key] = truth_trajectory(problem, dt, steps)
        return self._cache[key]

    def terms(self, problem: Problem, tr: Trajectory) -> Terms:
        """The :class:`~freebody.run.metrics.Terms` of a trajectory the cache holds (a group's
        truth: its energies, L and scales), formed once for every run judged against it."""
        key = (id(problem), problem.name, "terms", id(tr))
        hit = self._cache.get(key)
        if hit is None or hit.tr is not tr:  # (a cached Terms keeps its trajectory, and so its id)
            hit = self._cache[key] = Terms(problem, tr)
        return hit

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

    def reference(self, problem: Problem, integrator: str, dt: float, steps: int,
                  load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> Trajectory:
        load_sampling = map_load_sampling(problem, integrator, load_sampling)
        key = (id(problem), problem.name, dt, steps, integrator, load_sampling)
        if key not in self._cache:
            self._cache[key] = run_map(self.map_start(problem, dt), integrator, steps, load_sampling)
        return self._cache[key]

    def orientation(self, problem: Problem, integrator: str, dt: float, steps: int,
                    load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> np.ndarray:
        """The reference map's orientations q (steps + 1, 4), wxyz: all that identification
        compares (the rest of the map's trajectory is not kept); ``load_sampling``: the variant of
        a multi-stage engine map (the run's engine's rule, :func:`map_load_sampling`)."""
        load_sampling = map_load_sampling(problem, integrator, load_sampling)
        key = (id(problem), problem.name, dt, steps, integrator, load_sampling)
        if key in self._cache:  # the whole map is here already
            return self._cache[key].quaternion_wxyz
        if key + ("q",) not in self._cache:
            self._cache[key + ("q",)] = self._simulate_map(problem, integrator, dt, steps,
                                                           load_sampling).quaternion_wxyz
        return self._cache[key + ("q",)]

    def roundoff(self, problem: Problem, integrator: str, dt: float, steps: int,
                 precision: str = "float64", load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> np.ndarray:
        """The case's round-off amplification for this map: :func:`roundoff_spread` (N,) rad."""
        load_sampling = map_load_sampling(problem, integrator, load_sampling)
        key = (id(problem), problem.name, dt, steps, integrator, "roundoff", precision, load_sampling)
        if key not in self._cache:
            q = self.orientation(problem, integrator, dt, steps, load_sampling)
            self._cache[key] = roundoff_spread(problem, integrator, dt, steps, precision, q,
                                               load_sampling=load_sampling,
                                               starts=self.perturbed_map_starts(problem, dt, precision))
        return self._cache[key]

    def map_start(self, problem: Problem, dt: float) -> MapStart:
        """The case's own start at dt, prepared once for every map run from it (:func:`map_start`)."""
        key = (id(problem), problem.name, "map-start", float(dt))
        if key not in self._cache:
            self._cache[key] = map_start(problem, dt)
        return self._cache[key]

    def perturbed_map_starts(self, problem: Problem, dt: float, precision: str = "float64") -> tuple[MapStart, ...]:
        """The case's :meth:`perturbed_starts` at dt, each prepared once for every map's copy
        (:func:`map_start`; the loads are the case's: formed once)."""
        key = (id(problem), problem.name, "perturbed-map-starts", float(dt), precision)
        if key not in self._cache:
            loads = self.map_start(problem, dt).loads
            self._cache[key] = tuple(map_start(pb_u, dt, loads if pb_u.loads is problem.loads else None)
                                     for pb_u in self.perturbed_starts(problem, precision))
        return self._cache[key]

    def perturbed_starts(self, problem: Problem, precision: str = "float64") -> tuple[Problem, ...]:
        """The case's :func:`perturbed_starts`, built once (every map's spread starts from them)."""
        key = (id(problem), problem.name, "perturbed-starts", precision)
        if key not in self._cache:
            self._cache[key] = perturbed_starts(problem, precision)
        return self._cache[key]

    def map_piece(self, problem: Problem, integrator: str, dt: float, steps: int, precision: str = "float64",
                  load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> "MapPiece":
        """The map's whole run as identification compares it (:class:`MapPiece`: q and round-off
        level), prepared once from :meth:`orientation` and :meth:`roundoff` and shared by every run
        of the same (case, dt, steps, precision, load sampling); one object per variant of the map
        (:func:`map_load_sampling`), however the sampling was spelt."""
        key = (id(problem), problem.name, dt, steps, integrator, "piece", precision, load_sampling)
        if key not in self._cache:
            canonical = key[:-1] + (map_load_sampling(problem, integrator, load_sampling),)
            if canonical not in self._cache:
                self._cache[canonical] = map_piece(
                    self.orientation(problem, integrator, dt, steps, load_sampling),
                    self.roundoff(problem, integrator, dt, steps, precision, load_sampling), precision)
            self._cache[key] = self._cache[canonical]
        return self._cache[key]

    def candidate_maps(self, problem: Problem, dt: float, steps: int, precision: str, load_sampling: str,
                       names: tuple[str, ...]) -> "CandidateMaps | None":
        """Every candidate map ``names`` of the group (their :meth:`orientation` and
        :meth:`roundoff`, as :meth:`map_piece` takes them) stacked as one
        :class:`CandidateMaps`, prepared once and shared by every run of the same (case, dt, steps,
        precision, load sampling); None for a group too long to stack
        (:data:`STACKED_SAMPLES_MAX`: its runs compare with each map in turn)."""
        if len(names) * (int(steps) + 1) > STACKED_SAMPLES_MAX:
            return None
        key = (id(problem), problem.name, dt, steps, "candidates", precision, load_sampling, names)
        if key not in self._cache:
            qs = [self.orientation(problem, name, dt, steps, load_sampling) for name in names]
            spreads = [self.roundoff(problem, name, dt, steps, precision, load_sampling) for name in names]
            self._cache[key] = CandidateMaps.of(names, qs, spreads, precision)
        return self._cache[key]

    def _simulate_map(self, problem: Problem, integrator: str, dt: float, steps: int,
                      load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> Trajectory:
        """The map's whole run from the case's start (``integrators.simulate``'s, bit for bit), its
        set-up formed once per group (:meth:`map_start`)."""
        return run_map(self.map_start(problem, dt), integrator, steps, load_sampling)


def cached_candidate_maps(spec: RunSpec, cache: TruthCache) -> "CandidateMaps | None":
    """The candidate maps of a run judged whole, stacked (:meth:`TruthCache.candidate_maps`), or None."""
    return cache.candidate_maps(spec.problem, spec.dt, spec.steps, spec.precision, identification_sampling(spec),
                                scheme_candidates(spec.integrator, spec.steps))


def cached_map_pieces(spec: RunSpec, cache: TruthCache) -> Callable[[str], Iterator]:
    """The reference maps of a run judged whole: each map whole, as one :class:`MapPiece` from the
    cache (prepared once per (case, dt, steps, precision, load sampling), shared by the group's runs)."""
    sampling = identification_sampling(spec)

    def pieces(name: str):
        yield cache.map_piece(spec.problem, name, spec.dt, spec.steps, spec.precision, sampling)
    return pieces


def stepped_map_pieces(spec: RunSpec, chunk_steps: int) -> Callable[[str], Iterator]:
    """The reference maps of a run judged in chunks: each map and its runs from the
    :func:`perturbed_start` stepped chunk by chunk (the reference adapter continues where it
    stopped), yielding (q, spread) per chunk; nothing of a whole run is kept."""
    from ..adapters.reference import map_orientations

    pb, dt, steps = spec.problem, spec.dt, spec.steps
    sampling = identification_sampling(spec)

    starts = perturbed_starts(pb, spec.precision)  # every map's copies start from the same four

    def pieces(name: str):
        others = [map_orientations(pb_u, name, dt, steps, chunk_steps, sampling) for pb_u in starts]
        for q in map_orientations(pb, name, dt, steps, chunk_steps, sampling):
            spread = np.zeros(len(q))
            for other in others:
                spread = _spread_update(spread, q, next(other))
            yield q, spread
    return pieces


def cached_engine_pieces(spec: RunSpec, cache: TruthCache) -> Callable[[str, str], Iterator]:
    """Another engine's run of a run judged whole, whole, from the cache."""
    def pieces(other: str, integrator: str):
        yield cache.engine_run(spec.problem, other, integrator, spec.dt, spec.steps)
    return pieces


def stepped_engine_pieces(spec: RunSpec, chunk_steps: int) -> Callable[[str, str], Iterator]:
    """Another engine's run of a run judged in chunks, stepped chunk by chunk."""
    def pieces(other: str, integrator: str):
        adapter = load_adapter(other)(spec.problem, spec.dt, integrator)
        try:
            yield from adapter.chunks(spec.steps, chunk_steps)
        finally:
            adapter.close()
    return pieces


class VsEngine:
    """The comparison of a run with another engine's float64 run of the same integrator and dt,
    chunk by chunk (see :func:`compare_with_engine`)."""

    def __init__(self, spec: RunSpec, other: str, pieces: Callable[[str, str], Iterator]):
        self.out = {"engine": other, "integrator": spec.integrator, "precision": "float64"}
        self.message = None
        self.max = self.final = None
        self.finite = True
        self.other = other
        try:
            offered = load_adapter(other).offered_integrators()
            match = [i for i in offered if i.lower() == spec.integrator.lower()]
            if not match:
                self.message = f"{other} offers no {spec.integrator}"
            else:
                self.pieces = pieces(other, match[0])
        except KeyboardInterrupt:
            raise
        except BaseException as e:  # the other engine's sys.exit() included
            self.message = f"{other} could not run: {describe_error(e)}"

    def update(self, q: np.ndarray) -> None:
        if self.message is not None:
            return
        try:
            ref = next(self.pieces)
        except EngineDiverged as e:
            self.message = f"{self.other} diverged at t = {e.t:.6g} s"
            return
        except KeyboardInterrupt:
            raise
        except BaseException as e:  # the other engine's sys.exit() included
            self.message = f"{self.other} could not run: {describe_error(e)}"
            return
        d = geodesic_angle(ref.quaternion_wxyz, q)
        self.finite = self.finite and bool(np.all(np.isfinite(d)))
        m = float(np.max(d)) if len(d) else None
        self.max = m if self.max is None or m is None else max(self.max, m)
        if len(d):
            self.final = float(d[-1])

    def result(self) -> dict:
        if self.message is not None:
            return {**self.out, "message": self.message}
        return {**self.out, "max_orientation_diff_rad": self.max if self.finite else None,
                "final_orientation_diff_rad": self.final if self.finite else None}


def compare_with_engine(pb: Problem, trajectory: Trajectory, spec: RunSpec, other: str,
                        cache: TruthCache) -> dict:
    """How far this run is from ``other`` engine's float64 run of the same integrator and dt (rad):
    e.g. MJX against C MuJoCo.  A missing or failing other engine is said, not raised."""
    vs = VsEngine(spec, other, cached_engine_pieces(dataclasses.replace(spec, problem=pb), cache))
    vs.update(trajectory.quaternion_wxyz)
    return vs.result()


def scheme_candidates(integrator: str, steps: int = 0) -> tuple[str, ...]:
    """The reference maps an engine run with this integrator is compared with: every reference
    integrator, whatever the engine calls its integrator (a scheme is identified, not assumed),
    and the engine-equivalent maps, except for a run of more than ENGINE_MAP_CANDIDATES_MAX_STEPS
    steps: those maps are not continued chunk by chunk yet, and holding their whole runs would undo
    the bounded memory of a run judged in chunks."""
    if steps > tol.ENGINE_MAP_CANDIDATES_MAX_STEPS:
        return tuple(n for n in SCHEME_CANDIDATES if n not in ENGINE_MAPS)
    return SCHEME_CANDIDATES


def engine_schemes(integrator: str) -> tuple[str, ...]:
    """The reference maps an engine integrator of this name plausibly implements: the engines' maps,
    and rk4 for an integrator of the RK4 family (bounds of the self-checks, not identification)."""
    return ENGINE_SCHEMES + (("rk4",) if "rk4" in integrator.lower() else ())


def _ulp(x: float, precision: str) -> float:
    """One unit in the last place of |x| in the run's precision (0 for x = 0)."""
    if x == 0 or not np.isfinite(x):
        return 0.0
    return float(np.spacing(np.float32(abs(x)) if precision == "float32" else abs(float(x))))


def _nudged(v, pattern: np.ndarray, precision: str) -> np.ndarray:
    """v moved by one ulp of its largest entry, component by component, signs from ``pattern``."""
    v = np.asarray(v, dtype=float)
    u = _ulp(float(np.max(np.abs(v))), precision) if v.size else 0.0
    return v + u * pattern[:v.size].reshape(v.shape)


# The directions of the one-ulp starts: signs of the moves of the components (x, y, z[, w]).  The
# spread depends on the direction (at a given time a flip amplifies some directions far more than
# others): the largest over these is the round-off level's base.  The rows of a 4 x 4 Hadamard
# matrix: orthogonal, so none is another's negative (which, in the linear regime of round-off, gives
# the same spread again), and their first three columns span the three directions of w, x and v.
ULP_SIGN_PATTERNS = (
    np.array([1.0, 1.0, 1.0, 1.0]),
    np.array([1.0, -1.0, 1.0, -1.0]),
    np.array([1.0, 1.0, -1.0, -1.0]),
    np.array([1.0, -1.0, -1.0, 1.0]),
)


def perturbed_start(pb: Problem, precision: str = "float64",
                    signs: np.ndarray = ULP_SIGN_PATTERNS[0]) -> Problem:
    """The case one ulp away (of ``precision``): every component of the initial q (renormalised),
    w, x, v and of I_body (kept symmetric) moved by one ulp of its vector's largest entry, in the
    directions ``signs`` (4,).  What a float code that rounds differently starts from (see
    :data:`freebody.tolerances.SCHEME_ROUNDOFF_FACTOR`).  The step grid and the loads' timing are
    not perturbed: dt is the case's, so every load acts on the same steps (a dt one ulp away moves
    a load that starts or stops on a step boundary by a whole step, which is no round-off)."""
    ini = pb.initial
    q = _nudged(ini.quaternion_wxyz, signs, precision)
    start = InitialState(_nudged(ini.position, signs, precision), q / np.linalg.norm(q),
                         _nudged(ini.linear_velocity, signs, precision),
                         _nudged(ini.angular_velocity, signs, precision))
    I_b = np.array(pb.body.I_body, dtype=float)
    I_b = I_b + _ulp(float(np.max(np.abs(np.diag(I_b)))), precision) * np.diag(signs[:3])
    body = dataclasses.replace(pb.body, I_body=I_b)
    return dataclasses.replace(pb, initial=start, body=body)


def perturbed_starts(pb: Problem, precision: str = "float64") -> tuple[Problem, ...]:
    """The case's :func:`perturbed_start` in each direction of :data:`ULP_SIGN_PATTERNS`, in that order."""
    return tuple(perturbed_start(pb, precision, signs) for signs in ULP_SIGN_PATTERNS)


def roundoff_spread(pb: Problem, integrator: str, dt: float, steps: int, precision: str,
                    q_ref: np.ndarray, load_sampling: str = LOAD_SAMPLING_PER_STAGE,
                    starts: tuple[Problem | MapStart, ...] | None = None) -> np.ndarray:
    """(steps + 1,) rad: the orientation of the map ``integrator`` (its run's q_ref (steps + 1, 4))
    against the same map from each of the :func:`perturbed_start` of :data:`ULP_SIGN_PATTERNS`
    (same dt, same load steps), the largest sample by sample.  A sample where either is not finite
    is inf (a perturbed copy blew up: the map can identify nothing there, see :class:`Identification`).
    ``starts``: those starts, :func:`perturbed_starts` of (pb, precision), if built already, as
    Problems or prepared at dt (:func:`map_start`, :meth:`TruthCache.perturbed_map_starts`)."""
    runs = []
    for start in perturbed_starts(pb, precision) if starts is None else starts:
        if not isinstance(start, MapStart):
            start = map_start(start, dt)
        elif start.dt != float(dt):
            raise ValueError(f"a start prepared at dt = {start.dt!r} for a spread at dt = {dt!r}")
        runs.append(map_orientations(start, integrator, steps, load_sampling))
    spread = np.zeros(len(q_ref))
    size = BLOCK_SAMPLES // max(len(q_ref), 1)  # copies compared at once
    for i in range(0, len(runs), max(size, 1)):
        if size <= 1:  # a long run: one copy at a time
            spread = _spread_update(spread, q_ref, runs[i])
            continue
        with np.errstate(invalid="ignore"):
            s = _angle(q_ref, np.stack(runs[i:i + size]))  # (copies, N)
        # the largest over the copies (none is NaN: inf where not finite), as _spread_update one by one
        spread = np.maximum(spread, np.where(np.isfinite(s), s, np.inf).max(axis=0))
    return spread


def _spread_update(spread: np.ndarray, q_ref: np.ndarray, q_other: np.ndarray) -> np.ndarray:
    """The spread (N,) with one more perturbed run's orientations q_other (N, 4) taken in: the
    largest angle so far, inf where either is not finite."""
    with np.errstate(invalid="ignore"):
        s = _angle(q_ref, q_other)
    return np.maximum(spread, np.where(np.isfinite(s), s, np.inf))


def _angle(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation between quaternions qa and qb (..., N, 4), wxyz, broadcast
    against each other (e.g. (S, N, 4) perturbed copies and a map's (N, 4): (S, N)): 2
    atan2(|vec(d)|, |w(d)|) with d = conj(qa) qb, as
    :func:`~freebody.reference_impl.rotations.geodesic_angle` (to round-off) without its
    normalisations, which the ratio does not need: 8x faster, and identification compares every
    run with every candidate map.  Element by element the same floats whatever the shapes and
    layouts (numpy's ufuncs round each element alone): see :func:`_angle_parts`."""
    return _angle_parts((qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]),
                        (qb[..., 0], qb[..., 1], qb[..., 2], qb[..., 3]))


def _angle_parts(a, b) -> np.ndarray:
    """:func:`_angle` of quaternions given by component: ``a``, ``b`` each (w, x, y, z), four
    arrays of the same (broadcast) shape, e.g. the rows of a (4, C, N) array."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    w = aw * bw + ax * bx + ay * by + az * bz
    vx = aw * bx - bw * ax - (ay * bz - az * by)
    vy = aw * by - bw * ay - (az * bx - ax * bz)
    vz = aw * bz - bw * az - (ax * by - ay * bx)
    return 2.0 * np.arctan2(np.sqrt(vx * vx + vy * vy + vz * vz), np.abs(w))


def roundoff_level(spread: np.ndarray, before: float = 0.0, drift: np.ndarray | None = None) -> np.ndarray:
    """The round-off level (N,) rad at each sample from a map's :func:`roundoff_spread`:
    max(SCHEME_ROUNDOFF_FACTOR x the spread's running maximum, ``drift`` (a float32 run's
    :func:`rounding_drift`), SCHEME_ROUNDOFF_FLOOR_RAD), at most SCHEME_ROUNDOFF_LEVEL_MAX_RAD (a
    sample at the cap, or where a perturbed copy was not finite, is one where the map can identify
    nothing).  ``before``: the spread's maximum over the samples before these (a run judged in chunks).
    Several maps' at once: spread and drift (C, N), the running maxima along each row."""
    spread = np.asarray(spread, float)
    running = np.maximum(np.maximum.accumulate(spread, axis=-1), before) if spread.size else spread
    level = np.maximum(tol.SCHEME_ROUNDOFF_FACTOR * running, tol.SCHEME_ROUNDOFF_FLOOR_RAD)
    if drift is not None:
        level = np.maximum(level, drift)
    return np.minimum(level, tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD)


def rounding_drift(q_ref: np.ndarray, k0: int, theta0: float, q_before: np.ndarray | None,
                   precision: str) -> tuple[np.ndarray, float]:
    """(drift (N,) rad, theta at the last sample): how far a code of the map ``q_ref`` (N, 4) of
    samples k0 .. k0 + N - 1 may drift by rounding the same way at every step in ``precision``:
    SCHEME_ROUNDING_DRIFT_PER_STEP[precision] x k x theta_k / 2, theta_k the angle the map turned
    through up to sample k (rad, the sum of its steps' rotations from theta0 on; ``q_before``: the
    sample before these, None for the first chunk).  Zero in float64 (SCHEME_ROUNDOFF_FACTOR covers it)."""
    beta = tol.SCHEME_ROUNDING_DRIFT_PER_STEP.get(precision, 0.0)
    n = len(q_ref)
    if beta == 0.0 or n == 0:
        return np.zeros(n), theta0
    prev = q_ref[:-1] if q_before is None else np.concatenate([q_before[None, :], q_ref[:-1]])
    with np.errstate(invalid="ignore"):
        steps = _angle(prev, q_ref[1:] if q_before is None else q_ref)
    theta = theta0 + np.cumsum(np.where(np.isfinite(steps), steps, np.inf))
    if q_before is None:
        theta = np.concatenate([[theta0], theta])
    k = np.arange(k0, k0 + n, dtype=float)
    return beta * k * theta / 2.0, float(theta[-1])


def identification_rule(precision: str = "float64") -> str:
    """The identification rule in one line (results.json ``matches_reference["rule"]``)."""
    drift = tol.SCHEME_ROUNDING_DRIFT_PER_STEP.get(precision, 0.0)
    drift_text = f", {drift:.3g} x k x theta_k / 2 (a {precision} rounding drift)" if drift else ""
    return (f"reproduces: orientation within max({tol.SCHEME_ROUNDOFF_FACTOR:g} x the spread of a "
            f"1-ulp ({precision}) perturbed start{drift_text}, {tol.SCHEME_ROUNDOFF_FLOOR_RAD:g} rad) of the map "
            f"at every sample, and no other map nearer by more than round-off; a map whose level reaches "
            f"{tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD:g} rad (or whose run or perturbed copies are not finite) "
            f"identifies nothing (undecidable)")


def identify(pb: Problem, trajectory: Trajectory, spec: RunSpec, cache: TruthCache) -> dict:
    """Which reference map this engine run reproduces to round-off, or the closest and how far.

    A map is within round-off of the run when their orientations agree within the map's round-off
    level on this case at every sample (:func:`roundoff_level`; the rule in
    :mod:`freebody.tolerances`, SCHEME_ROUNDOFF_FACTOR), from four orthogonal one-ulp starts of the
    initial state (dt and the loads' steps are the case's).  A map whose level reaches
    SCHEME_ROUNDOFF_LEVEL_MAX_RAD, whose perturbed copies or own run are not finite, before the run
    left it, is undecidable here: it neither reproduces nor is excluded.  Returns (results.json
    ``matches_reference``):

    verdict : "reproduces" (one map within its level and no other map nearer than it by more than
        its round-off), "indistinguishable" (several maps within their levels of the run and of each
        other: the case, in this precision, cannot tell them apart), "closest" (no map reproduces the
        run: ``closest`` is the nearest) or "undecidable" (the maps that could match the run are
        undecidable here).
    integrator : the reproduced map (of a tie, the first in :data:`SCHEME_CANDIDATES` order) or None.
    closest : that map, or the map of smallest max difference when none reproduces the run.
    max_orientation_diff_rad : closest's max difference (rad).
    threshold_rad : closest's round-off level at the last sample (rad; the level grows with t).
    indistinguishable : the maps of the tie in candidate order ([integrator] alone, [] for none).
    undecidable : the maps that can identify nothing on this case (candidate order).
    candidates : name -> max difference (rad), None where either is not finite.
    levels_rad : name -> round-off level at the last sample (rad, at most the cap).
    ratios : name -> max over samples (below the cap) of difference / level (<= 1: within), or None.
    rule : the rule in words.

    The run is taken in as one chunk of :class:`Identification` (a long run: chunk by chunk).
    """
    spec = dataclasses.replace(spec, problem=pb)
    ident = Identification(spec, cached_map_pieces(spec, cache), lambda: cached_candidate_maps(spec, cache))
    ident.update(trajectory.quaternion_wxyz)
    return ident.result()


@dataclasses.dataclass(frozen=True)
class MapPiece:
    """A candidate map over samples k0 .. k0 + N - 1 with what identification derives from the map
    alone, the same for every run compared with it: for a run judged whole, prepared once per
    group by :meth:`TruthCache.map_piece` and shared by every engine run of the group; for a run
    judged in chunks, derived chunk by chunk by :class:`Identification`.

    q : (N, 4) wxyz, body -> world: the map's orientations.
    level : (N,) rad: its round-off level at each sample (:func:`roundoff_level` of its spread's
        running maximum and its rounding drift), at most SCHEME_ROUNDOFF_LEVEL_MAX_RAD; the samples
        where it is below that cap are those where the map can tell anything.
    raw : (N,) rad: the level without SCHEME_ROUNDOFF_FACTOR (max(spread's running maximum, drift,
        floor), at most the cap): the margin of "no other map nearer by more than round-off".
    spread_max, theta : the spread's running maximum and the angle the map turned through (rad), at
        its last sample: where the next piece starts.
    """

    q: np.ndarray
    level: np.ndarray
    raw: np.ndarray
    spread_max: float
    theta: float


def map_piece(q_ref: np.ndarray, spread: np.ndarray, precision: str, k0: int = 0, spread_max: float = 0.0,
              theta0: float = 0.0, q_before: np.ndarray | None = None) -> MapPiece:
    """The :class:`MapPiece` of a map's samples k0 .. k0 + N - 1: q_ref (N, 4), its round-off
    spread (N,) rad there (:func:`roundoff_spread`); ``spread_max``, ``theta0``, ``q_before``: the
    running state after the samples before these (0, 0, None for the first)."""
    if len(spread):
        base = np.maximum(np.maximum.accumulate(spread), spread_max)
        spread_max = float(base[-1])
    else:
        base = np.zeros(0)
    drift, theta = rounding_drift(q_ref, k0, theta0, q_before, precision)
    n = min(len(base), len(drift))
    return MapPiece(q_ref, *piece_levels(base[:n], drift[:n]), spread_max, theta)


def piece_levels(base: np.ndarray, drift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(:attr:`MapPiece.level`, :attr:`MapPiece.raw`) (N,) rad from the spread's running maximum
    ``base`` (N,) and the rounding drift (N,) (:func:`rounding_drift`); several maps' at once:
    (C, N) each."""
    # level < cap wherever max(factor x base, drift) < cap: the floor is below the cap
    level = roundoff_level(base, drift=drift)
    raw = np.minimum(np.maximum(np.maximum(base, drift), tol.SCHEME_ROUNDOFF_FLOOR_RAD),
                     tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD)
    return level, raw


@dataclasses.dataclass(frozen=True)
class CandidateMaps:
    """Every candidate map of a group over its whole run, stacked: what a run judged whole is
    compared with, all maps at once (:meth:`Identification.update`), prepared once per (case, dt,
    steps, precision, load sampling) by :meth:`TruthCache.candidate_maps`: what each map's
    :class:`MapPiece` holds, stacked.

    names : the C maps, in :func:`scheme_candidates` order.
    parts : (4, C, N): each map's orientations (wxyz, body -> world) by component, each (C, N) row
        contiguous (the comparison reads them so, block by block: :data:`BLOCK_SAMPLES`).
    level, raw : (C, N) rad: each map's :attr:`MapPiece.level` and :attr:`MapPiece.raw`.
    agree : which pairs of maps agree within their levels over a run's samples (:meth:`within`),
        found once for the group's runs.
    """

    names: tuple[str, ...]
    parts: np.ndarray
    level: np.ndarray
    raw: np.ndarray
    agree: dict = dataclasses.field(default_factory=dict, compare=False)

    @classmethod
    def of(cls, names: tuple[str, ...], qs: list[np.ndarray], spreads: list[np.ndarray],
           precision: str) -> "CandidateMaps | None":
        """The maps of their orientations q (N, 4) and round-off spreads (N,) (the group's: their
        levels as :func:`map_piece` forms them, all maps at once); None unless every map has N samples."""
        n = len(qs[0]) if qs else 0
        if not qs or any(len(q) != n for q in qs) or any(len(s) != n for s in spreads):
            return None
        base = np.maximum(np.maximum.accumulate(np.stack(spreads), axis=1), 0.0)
        if tol.SCHEME_ROUNDING_DRIFT_PER_STEP.get(precision, 0.0):
            drift = np.stack([rounding_drift(q, 0, 0.0, None, precision)[0] for q in qs])
        else:  # rounding_drift's zeros
            drift = np.zeros(base.shape)
        return cls(tuple(names), np.ascontiguousarray(np.stack(qs).transpose(2, 0, 1)),
                   *piece_levels(base, drift))

    def compare(self, q: np.ndarray, k0: int) -> tuple[np.ndarray, ...]:
        """A run's orientations q (n, 4) against every map's samples k0 .. k0 + n - 1 (as many):
        per map (C,), whether the map tells nothing at some sample (its level at the cap or either
        not finite), whether every difference is finite, the largest difference, whether it tells
        anything at some sample, and the largest difference over level there (-inf if nowhere)."""
        n, cap = len(q), tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD
        run = np.ascontiguousarray(q.T)  # (4, n): its components, contiguous
        out = []
        size = max(1, BLOCK_SAMPLES // n)  # maps compared at once
        for c in range(0, len(self.names), size):
            level = self.level[c:c + size, k0:k0 + n]
            with np.errstate(invalid="ignore", divide="ignore"):
                d = _angle_parts(self.parts[:, c:c + size, k0:k0 + n], run)  # (maps, n)
                finite = np.isfinite(d)
                open_ = (level < cap) & finite  # where each map can tell anything
                ratio = np.where(open_, d / level, -np.inf).max(axis=1)
            out.append((~open_.all(axis=1), finite.all(axis=1), d.max(axis=1), open_.any(axis=1), ratio))
        return tuple(np.concatenate(a) for a in zip(*out))

    def within(self, pairs: list[tuple[int, int]], k0: int, n: int) -> list[bool]:
        """For each pair (a, b) of map indices, whether the two maps agree within the larger of
        their levels at each of their samples k0 .. k0 + n - 1 (:func:`_within`), each pair found
        once for every run of the group."""
        todo = [p for p in pairs if (p, k0, n) not in self.agree]
        size = max(1, BLOCK_SAMPLES // max(n, 1))  # pairs compared at once
        parts, level = self.parts[:, :, k0:k0 + n], self.level[:, k0:k0 + n]
        for i in range(0, len(todo), size):
            a, b = np.array(todo[i:i + size]).T
            with np.errstate(invalid="ignore"):
                ok = np.all(_angle_parts(parts[:, a], parts[:, b]) <= np.maximum(level[a], level[b]), axis=1)
            self.agree.update(((p, k0, n), v) for p, v in zip(todo[i:i + size], ok.tolist()))
        return [self.agree[(p, k0, n)] for p in pairs]


class Identification:
    """Scheme identification (:func:`identify`) of a run taken in chunk by chunk: per candidate
    map, the running maxima of its difference and of the difference over its round-off level
    (on the samples below the cap), the level's running base, whether it reached the cap (undecidable), and for each pair of maps that
    still reproduce the run whether they are within their levels of each other so far (the tie).
    ``pieces(name)`` yields the map's q and round-off spread over the same samples as each chunk
    of the run.  ``maps``: called at the first update, the same maps stacked
    (:class:`CandidateMaps`, a run judged whole) or None: the run is then compared with all of them
    at once, with the same numbers."""

    def __init__(self, spec: RunSpec, pieces: Callable[[str], Iterator],
                 maps: Callable[[], CandidateMaps | None] | None = None):
        self.spec = spec
        self.names = scheme_candidates(spec.integrator, spec.steps)
        self._stacked = maps
        self.maps: CandidateMaps | None = None
        self.pieces = {name: pieces(name) for name in self.names}
        self.spread_max = {name: 0.0 for name in self.names}  # the map's own spread so far
        self.theta = {name: 0.0 for name in self.names}  # the angle the map turned through so far
        self.last_q: dict[str, np.ndarray] = {}
        self.levels: dict[str, float] = {}
        self.roundoff: dict[str, float] = {}  # the level without the factor, at the last sample
        self.closed = {name: False for name in self.names}  # a sample where the map tells nothing, so far
        self.diffs: dict[str, float | None] = {name: 0.0 for name in self.names}
        self.ratios: dict[str, float | None] = {name: 0.0 for name in self.names}
        self.apart: set[tuple[str, str]] = set()  # pairs of maps found apart (beyond their levels) so far
        self.n = 0

    def update(self, q: np.ndarray) -> None:
        """The run's orientations q (m, 4) of its next m samples."""
        if self._stacked is not None:  # the maps are prepared when first needed (not for a diverged run)
            maps, self._stacked = self._stacked(), None
            self.maps = maps if maps is not None and maps.names == self.names else None
        if self.maps is not None:
            return self._update_stacked(q)
        n, k0 = len(q), self.n
        kept = {}
        for name in self.names:
            piece = self._next_piece(name, k0)
            if n:
                self.levels[name] = float(piece.level[:n][-1])
                self.roundoff[name] = float(piece.raw[:n][-1])
            if len(piece.q) < n:  # the map has fewer samples than the run: nothing to compare
                self.diffs[name] = self.ratios[name] = None
                continue
            level = piece.level[:n]
            with np.errstate(invalid="ignore"):
                d = _angle(piece.q[:n], q)
                finite = np.isfinite(d)
                # the samples where the map can tell anything: its level below the cap, both finite
                open_ = (level < tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD) & finite
            if not open_.all():
                self.closed[name] = True
            if self.diffs[name] is not None:
                self.diffs[name] = max(self.diffs[name], float(d.max())) if finite.all() else None
            if self.ratios[name] is None:
                continue
            if open_.any():
                self.ratios[name] = max(self.ratios[name], float((d[open_] / level[open_]).max()))
            if self.ratios[name] <= 1.0 and not self.closed[name]:
                kept[name] = (piece.q[:n], level)
        # the tie: only maps that still reproduce the run matter (kept, in candidate order)
        for pair in itertools.combinations(kept, 2):
            if pair not in self.apart and not _within(kept[pair[0]], kept[pair[1]]):
                self.apart.add(pair)
        self.n += n

    def _update_stacked(self, q: np.ndarray) -> None:
        """:meth:`update` against every map at once (:attr:`maps`: whole runs, the samples from
        this update's first on): the same state, from the same floats, as one map after another."""
        n, k0, maps = len(q), self.n, self.maps
        if n == 0:
            return
        level, raw = maps.level[:, k0:k0 + n], maps.raw[:, k0:k0 + n]
        m = level.shape[1]  # the maps' samples among the run's
        for c, name in enumerate(self.names):
            if m:
                self.levels[name], self.roundoff[name] = float(level[c, m - 1]), float(raw[c, m - 1])
        if m < n:  # the maps have fewer samples than the run: nothing to compare
            self.diffs.update(dict.fromkeys(self.names))
            self.ratios.update(dict.fromkeys(self.names))
            self.n += n
            return
        shut, all_finite, d_max, any_open, ratio = maps.compare(q, k0)
        kept = []
        for c, name in enumerate(self.names):
            self.closed[name] = self.closed[name] or bool(shut[c])
            if self.diffs[name] is not None:
                self.diffs[name] = max(self.diffs[name], float(d_max[c])) if all_finite[c] else None
            if self.ratios[name] is None:
                continue
            if any_open[c]:
                self.ratios[name] = max(self.ratios[name], float(ratio[c]))
            if self.ratios[name] <= 1.0 and not self.closed[name]:
                kept.append(c)
        # the tie: only maps that still reproduce the run matter (kept, in candidate order)
        pairs = [p for p in itertools.combinations(kept, 2) if (self.names[p[0]], self.names[p[1]]) not in self.apart]
        for (a, b), ok in zip(pairs, maps.within(pairs, k0, n)):
            if not ok:
                self.apart.add((self.names[a], self.names[b]))
        self.n += n

    def _next_piece(self, name: str, k0: int) -> "MapPiece":
        """The map's next piece as a :class:`MapPiece` (one the cache prepared, or one derived here
        from the (q, spread) a chunked run's pieces yield), and the running state after it."""
        piece = next(self.pieces[name])
        if not isinstance(piece, MapPiece):
            q_ref, spread = piece
            piece = map_piece(q_ref, spread, self.spec.precision, k0, self.spread_max[name],
                              self.theta[name], self.last_q.get(name))
        self.spread_max[name], self.theta[name] = piece.spread_max, piece.theta
        if len(piece.q):
            self.last_q[name] = piece.q[-1]
        return piece

    def result(self) -> dict:
        ratios, diffs, levels = self.ratios, self.diffs, self.levels
        # undecidable: the map tells nothing at some sample and the run had not left it before
        undecidable = [k for k in self.names if self.closed[k] and ratios[k] is not None and ratios[k] <= 1.0]
        reproduced = sorted((k for k, r in ratios.items() if r is not None and r <= 1.0 and not self.closed[k]),
                            key=ratios.get)
        tie: list[str] = []
        for name in reproduced:  # the best first; each further map within round-off of those kept
            if all(_pair(self.names, name, other) not in self.apart for other in tie):
                tie.append(name)
        finite = {k: v for k, v in diffs.items() if v is not None}
        nearest = min(finite, key=finite.get) if finite else None
        if tie:
            best = tie[0]
            d_best = finite.get(best)
            margin = self.roundoff.get(best, tol.SCHEME_ROUNDOFF_FLOOR_RAD)
            nearer = d_best is None or any(v < d_best - margin for k, v in finite.items() if k not in tie)
            if nearer:  # another map is nearer the run by more than round-off: no verdict of a map
                tie = []
            elif len(tie) == 1 and any(
                    r is not None and k not in undecidable
                    and r < tol.SCHEME_SEPARATION_RATIO * max(ratios[best], tol.SCHEME_ROUNDOFF_FLOOR_RAD)
                    for k, r in ratios.items() if k != best):
                # a lone map must stand out: the run sits between maps, not on one, when the next
                # map (outside its level) is nearly as near in units of its own level
                tie = []
        tie = [k for k in SCHEME_CANDIDATES if k in tie]
        if tie:
            verdict = identification.REPRODUCES if len(tie) == 1 else identification.INDISTINGUISHABLE
        elif nearest is None or nearest in undecidable or (not reproduced and undecidable):
            verdict = identification.UNDECIDABLE
        else:
            verdict = identification.CLOSEST
        closest = tie[0] if tie else nearest
        return {"verdict": verdict, "integrator": tie[0] if tie else None, "closest": closest,
                "max_orientation_diff_rad": finite.get(closest), "candidates": dict(diffs),
                "threshold_rad": levels.get(closest), "indistinguishable": tie, "undecidable": undecidable,
                "levels_rad": dict(levels), "ratios": dict(ratios), "rule": identification_rule(self.spec.precision)}


def _pair(names: tuple, a: str, b: str) -> tuple[str, str]:
    return (a, b) if names.index(a) < names.index(b) else (b, a)


def _within(a: tuple, b: tuple) -> bool:
    """Whether two maps' orientations (q (N, 4), level (N,)) agree within the larger of their
    round-off levels at every sample."""
    with np.errstate(invalid="ignore"):
        return bool(np.all(_angle(a[0], b[0]) <= np.maximum(a[1], b[1])))
