"""Judging a simulated run: the truth, divergence (the one place a run's status is decided),
metrics, scheme identification against the reference maps, and the comparison of a ported engine
with its original.  :func:`finish` serves runs stepped one by one and runs stepped as a batch."""
from __future__ import annotations

import dataclasses

import numpy as np

from .. import tolerances as tol
from ..adapters.base import EngineDiverged, load_adapter
from ..reference_impl import integrators as _maps
from ..reference_impl.conventions import Trajectory
from ..reference_impl.integrators import INTEGRATORS
from ..reference_impl.integrators import simulate as reference_simulate
from ..reference_impl.problem import InitialState, Problem
from ..reference_impl.rotations import geodesic_angle
from ..reference_impl.truth import truth_trajectory
from .metrics import (ORIENTATION_ERROR_MAX, ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE,
                      ROTATION_ORTHONORMALITY_ERROR_MAX, divergence, summarize)
from .records import RunOutput, RunResult, RunSpec, Simulated, Status, _clean, _describe, _identity, _no_trajectory

# The engines' maps: what an engine integrator plausibly implements (rk4 only for an RK4 of its
# own); the self-checks bound an engine by these (:func:`engine_schemes`).
ENGINE_SCHEMES = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")
# Reference maps an engine run is compared with (scheme identification): every reference
# integrator, the engines' maps first (a tie is named by its first map in this order).
SCHEME_CANDIDATES = (*ENGINE_SCHEMES, "rk4", *(n for n in INTEGRATORS if n not in (*ENGINE_SCHEMES, "rk4")))


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

    def orientation(self, problem: Problem, integrator: str, dt: float, steps: int) -> np.ndarray:
        """The reference map's orientations q (steps + 1, 4), wxyz: all that identification
        compares (the rest of the map's trajectory is not kept)."""
        key = (id(problem), problem.name, dt, steps, integrator)
        if key in self._cache:  # the whole map is here already
            return self._cache[key].quaternion_wxyz
        if key + ("q",) not in self._cache:
            self._cache[key + ("q",)] = self._simulate_map(problem, integrator, dt, steps).quaternion_wxyz
        return self._cache[key + ("q",)]

    def roundoff(self, problem: Problem, integrator: str, dt: float, steps: int,
                 precision: str = "float64") -> np.ndarray:
        """The case's round-off amplification for this map: :func:`roundoff_spread` (N,) rad."""
        key = (id(problem), problem.name, dt, steps, integrator, "roundoff", precision)
        if key not in self._cache:
            q = self.orientation(problem, integrator, dt, steps)
            self._cache[key] = roundoff_spread(problem, integrator, dt, steps, precision, q)
        return self._cache[key]

    def _simulate_map(self, problem: Problem, integrator: str, dt: float, steps: int) -> Trajectory:
        return reference_simulate(problem, integrator, dt, steps)


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
        # but for R's orthonormality error: how far it went (its largest finite value, as it
        # becomes inf/NaN in the end)
        metrics = {k: (v if k == ROTATION_ORTHONORMALITY_ERROR_MAX else None) for k, v in metrics.items()}
        if trajectory.orthonormality_error is not None:
            ortho = trajectory.orthonormality_error[np.isfinite(trajectory.orthonormality_error)]
            metrics[ROTATION_ORTHONORMALITY_ERROR_MAX] = float(np.max(ortho)) if ortho.size else None
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
    """The reference maps an engine run with this integrator is compared with: every reference
    integrator, whatever the engine calls its integrator (a scheme is identified, not assumed)."""
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


# The directions of the one-ulp starts: signs of the moves of the components (x, y, z[, w]) and of
# dt (last).  The spread depends on the direction (a flip amplifies some far more than others at a
# given time): the largest over a few directions is the round-off level's base.
ULP_SIGN_PATTERNS = (
    np.array([1.0, -1.0, 1.0, -1.0, 1.0]),
    np.array([-1.0, 1.0, -1.0, 1.0, -1.0]),
    np.array([1.0, 1.0, -1.0, -1.0, 1.0]),
)


def perturbed_start(pb: Problem, dt: float, precision: str = "float64",
                    signs: np.ndarray = ULP_SIGN_PATTERNS[0]) -> tuple[Problem, float]:
    """The case one ulp away (of ``precision``), and dt one ulp away: every component of the initial
    q (renormalised), w, x, v and of I_body (kept symmetric) moved by one ulp of its vector's
    largest entry, in the directions ``signs`` (5,).  What a float code that rounds differently
    starts from (see :data:`freebody.tolerances.SCHEME_ROUNDOFF_FACTOR`)."""
    ini = pb.initial
    q = _nudged(ini.quaternion_wxyz, signs, precision)
    start = InitialState(_nudged(ini.position, signs, precision), q / np.linalg.norm(q),
                         _nudged(ini.linear_velocity, signs, precision),
                         _nudged(ini.angular_velocity, signs, precision))
    I_b = np.array(pb.body.I_body, dtype=float)
    I_b = I_b + _ulp(float(np.max(np.abs(np.diag(I_b)))), precision) * np.diag(signs[:3])
    body = dataclasses.replace(pb.body, I_body=I_b)
    return dataclasses.replace(pb, initial=start, body=body), dt + signs[4] * _ulp(dt, precision)


def roundoff_spread(pb: Problem, integrator: str, dt: float, steps: int, precision: str,
                    q_ref: np.ndarray) -> np.ndarray:
    """(steps + 1,) rad: the orientation of the map ``integrator`` (its run's q_ref (steps + 1, 4))
    against the same map from each of the :func:`perturbed_start` of :data:`ULP_SIGN_PATTERNS`, the
    largest sample by sample.  A sample where either is not finite counts as pi (the orientation is
    lost to round-off)."""
    spread = np.zeros(len(q_ref))
    for signs in ULP_SIGN_PATTERNS:
        pb_u, dt_u = perturbed_start(pb, dt, precision, signs)
        other = _maps.simulate(pb_u, integrator, dt_u, steps)  # not reference_simulate: no map the cache holds
        with np.errstate(invalid="ignore"):
            s = _angle(q_ref, other.quaternion_wxyz)
        spread = np.maximum(spread, np.where(np.isfinite(s), s, np.pi))
    return spread


def _angle(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation between quaternions qa and qb (N, 4), wxyz: 2 atan2(|vec(d)|,
    |w(d)|) with d = conj(qa) qb, as :func:`~freebody.reference_impl.rotations.geodesic_angle`
    (to round-off) without its normalisations, which the ratio does not need: 8x faster, and
    identification compares every run with seven maps."""
    aw, ax, ay, az = qa.T
    bw, bx, by, bz = qb.T
    w = aw * bw + ax * bx + ay * by + az * bz
    vx = aw * bx - bw * ax - (ay * bz - az * by)
    vy = aw * by - bw * ay - (az * bx - ax * bz)
    vz = aw * bz - bw * az - (ax * by - ay * bx)
    return 2.0 * np.arctan2(np.sqrt(vx * vx + vy * vy + vz * vz), np.abs(w))


def roundoff_level(spread: np.ndarray) -> np.ndarray:
    """The round-off level (N,) rad at each sample from a map's :func:`roundoff_spread`:
    max(SCHEME_ROUNDOFF_FACTOR x the spread's running maximum, SCHEME_ROUNDOFF_FLOOR_RAD)."""
    return np.maximum(tol.SCHEME_ROUNDOFF_FACTOR * np.maximum.accumulate(spread), tol.SCHEME_ROUNDOFF_FLOOR_RAD)


def identification_rule(precision: str = "float64") -> str:
    """The identification rule in one line (results.json ``matches_reference["rule"]``)."""
    return (f"reproduces: orientation within max({tol.SCHEME_ROUNDOFF_FACTOR:g} x the spread of a "
            f"1-ulp ({precision}) perturbed start, {tol.SCHEME_ROUNDOFF_FLOOR_RAD:g} rad) of the map "
            f"at every sample")


def identify(pb: Problem, trajectory: Trajectory, spec: RunSpec, cache: TruthCache) -> dict:
    """Which reference maps this engine run reproduces to round-off, or the closest and how far.

    A map reproduces the run when their orientations agree within the map's round-off level on
    this case at every sample (:func:`roundoff_level`; the rule in :mod:`freebody.tolerances`,
    SCHEME_ROUNDOFF_FACTOR).  Maps that reproduce it and are within their levels of each other are
    indistinguishable on this case (a tie).  Returns (results.json ``matches_reference``):

    integrator : the reproduced map (of a tie, the first in :data:`SCHEME_CANDIDATES` order) or None.
    closest : that map, or the map of smallest max difference when none reproduces the run.
    max_orientation_diff_rad : closest's max difference (rad).
    threshold_rad : closest's round-off level at the last sample (rad; the level grows with t).
    indistinguishable : the maps of the tie in candidate order ([integrator] alone, [] for none).
    candidates : name -> max difference (rad), None where either is not finite.
    levels_rad : name -> round-off level at the last sample (rad).
    ratios : name -> max over samples of difference / level (<= 1: reproduces), or None.
    rule : the rule in words.
    """
    n = len(trajectory)
    diffs, levels, ratios, kept = {}, {}, {}, {}
    for name in scheme_candidates(spec.integrator):
        q_ref = cache.orientation(pb, name, spec.dt, spec.steps)
        level = roundoff_level(cache.roundoff(pb, name, spec.dt, spec.steps, spec.precision))
        levels[name] = float(level[-1])
        if len(q_ref) < n:
            diffs[name] = ratios[name] = None
            continue
        with np.errstate(invalid="ignore"):
            d = _angle(q_ref[:n], trajectory.quaternion_wxyz)
        if not np.all(np.isfinite(d)):
            diffs[name] = ratios[name] = None
            continue
        diffs[name], ratios[name] = float(np.max(d)), float(np.max(d / level[:n]))
        kept[name] = (q_ref[:n], level[:n])
    reproduced = sorted((k for k, r in ratios.items() if r is not None and r <= 1.0), key=ratios.get)
    tie: list[str] = []
    for name in reproduced:  # the best first; each further map within round-off of those kept
        if all(_within(kept[name], kept[other]) for other in tie):
            tie.append(name)
    tie = [k for k in SCHEME_CANDIDATES if k in tie]
    finite = {k: v for k, v in diffs.items() if v is not None}
    closest = tie[0] if tie else (min(finite, key=finite.get) if finite else None)
    return {"integrator": tie[0] if tie else None, "closest": closest,
            "max_orientation_diff_rad": finite.get(closest), "candidates": diffs,
            "threshold_rad": levels.get(closest), "indistinguishable": tie, "levels_rad": levels,
            "ratios": ratios, "rule": identification_rule(spec.precision)}


def _within(a: tuple, b: tuple) -> bool:
    """Whether two maps' orientations (q (N, 4), level (N,)) agree within the larger of their
    round-off levels at every sample."""
    with np.errstate(invalid="ignore"):
        return bool(np.all(_angle(a[0], b[0]) <= np.maximum(a[1], b[1])))


def _prefix_metrics(pb, trajectory, truth, t_div) -> dict:
    """Metrics over the samples before the divergence (keys suffixed ``_before_divergence``)."""
    n = int(np.searchsorted(trajectory.t, t_div))
    if n < 1:
        return {}
    head = trajectory.head(n).without_orthonormality()
    m, _ = summarize(pb, head, truth)
    return {ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE: m[ORIENTATION_ERROR_MAX]}
