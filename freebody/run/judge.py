"""Judging a simulated run: the truth, divergence (the one place a run's status is decided),
metrics, scheme identification against the reference maps, and the comparison of a ported engine
with its original.  :func:`finish` serves runs stepped one by one and runs stepped as a batch."""
from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..adapters.base import EngineDiverged, load_adapter
from ..reference_impl.conventions import Trajectory
from ..reference_impl.integrators import simulate as reference_simulate
from ..reference_impl.problem import Problem
from ..reference_impl.rotations import geodesic_angle
from ..reference_impl.truth import truth_trajectory
from .metrics import (ORIENTATION_ERROR_MAX, ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE,
                      ROTATION_ORTHONORMALITY_ERROR_MAX, divergence, summarize)
from .records import RunOutput, RunResult, RunSpec, Simulated, Status, _clean, _describe, _identity, _no_trajectory

# Reference maps an engine run is compared with (scheme identification); rk4 only where the engine
# offers an RK4 of its own.
SCHEME_CANDIDATES = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")


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


def finish(spec: RunSpec, sim: Simulated, cache: TruthCache, identify_scheme: bool = True,
           compare_with: str | None = None) -> RunOutput:
    """Judge a simulated run: truth, divergence (the one place it is decided), metrics, scheme
    identification and the comparison with a ported engine's original.  Used for runs stepped one
    by one (:func:`execute`) and for runs stepped as a batch (``freebody sweep --engine mjx``)."""
    pb = spec.problem
    base = _identity(spec, sim.settings)
    trajectory, diverged_at, version, settings = sim.trajectory, sim.diverged_at, sim.version, sim.settings
    wall, compile_time = sim.wall_time_s, sim.compile_time_s
    status, message = (Status.OK, "") if diverged_at is None else (Status.DIVERGED, sim.reason)
    try:
        truth = cache.get(pb, spec.dt, spec.steps)
    except Exception as e:
        return _no_trajectory(base, Status.FAILED, f"truth oracle failed: {_describe(e)}", wall, version,
                              settings)
    if trajectory is None or len(trajectory) == 0:
        return _no_trajectory(base, status, message, wall, version, settings, diverged_at)
    if status == Status.OK:
        found = divergence(pb, trajectory, truth)
        if found is not None:
            diverged_at, message = found
            status = Status.DIVERGED
            message = f"diverged at t = {diverged_at:.6g} s: {message}"
    elif diverged_at is not None:
        message = f"diverged at t = {diverged_at:.6g} s: {message}"
    metrics, series = summarize(pb, trajectory, truth)
    if status == Status.DIVERGED:
        # metrics past a blow-up are meaningless: keep them up to the divergence only
        metrics = {k: (v if k == ROTATION_ORTHONORMALITY_ERROR_MAX else None) for k, v in metrics.items()}
        metrics.update(_prefix_metrics(pb, trajectory, truth, diverged_at))
    matches = vs_engine = None
    if identify_scheme and not spec.is_reference and status == Status.OK:
        matches = identify(pb, trajectory, spec, cache)
        if compare_with:
            vs_engine = compare_with_engine(pb, trajectory, spec, compare_with, cache)
    final = trajectory.state(-1).as_dict() if status == Status.OK else None
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
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # the other engine's sys.exit() included
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


def _prefix_metrics(pb, trajectory, truth, t_div) -> dict:
    """Metrics over the samples before the divergence (keys suffixed ``_before_divergence``)."""
    n = int(np.searchsorted(trajectory.t, t_div))
    if n < 1:
        return {}
    head = trajectory.head(n).without_orthonormality()
    m, _ = summarize(pb, head, truth)
    return {ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE: m[ORIENTATION_ERROR_MAX]}
