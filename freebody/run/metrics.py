"""Metrics of a run against its truth, and the one place that decides a run's divergence.

All series are arrays of shape (N,) over the samples t_k; maxima and finals are floats or None
(None where a value is undefined, e.g. a relative error whose scale is zero).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..reference_impl.conventions import Trajectory, angular_momentum, kinetic_energy, potential_energy
from ..reference_impl.problem import Problem
from ..reference_impl.rotations import geodesic_angle
from .. import tolerances as tol
from ..numbers import finite_or_none
from ..results.document import finite_argmax, prefix_end

# The keys of a results.json ``metrics`` dict, defined once (they are the schema: every module
# names a metric through these constants).
ORIENTATION_ERROR_MAX = "orientation_error_max_rad"
ORIENTATION_ERROR_FINAL = "orientation_error_final_rad"
ANGULAR_MOMENTUM_ERROR_MAX_REL = "angular_momentum_error_max_rel"
ENERGY_ERROR_MAX_REL = "energy_error_max_rel"
POSITION_ERROR_MAX = "position_error_max_m"
ROTATION_ORTHONORMALITY_ERROR_MAX = "rotation_orthonormality_error_max"
ANGULAR_MOMENTUM_ERROR_MAX_ABS = "angular_momentum_error_max_abs"  # instead of _rel when the truth's L is 0
ENERGY_ERROR_MAX_ABS = "energy_error_max_abs_J"  # instead of _rel when the truth's KE is 0
# diverged runs: the orientation error over the samples before the divergence
ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE = "orientation_error_max_before_divergence_rad"
# max_k |1 - |q_k||, the quaternions as the engine handed them out (before anything normalises
# them: the other metrics use q / |q|); a diverged run's: its largest finite value (schema 6)
QUATERNION_NORM_ERROR_MAX = "quaternion_norm_error_max"

METRIC_KEYS = (  # the keys every judged run's metrics have
    ORIENTATION_ERROR_MAX,
    ORIENTATION_ERROR_FINAL,
    ANGULAR_MOMENTUM_ERROR_MAX_REL,
    ENERGY_ERROR_MAX_REL,
    POSITION_ERROR_MAX,
    ROTATION_ORTHONORMALITY_ERROR_MAX,
    QUATERNION_NORM_ERROR_MAX,
)
METRIC_NAMES = METRIC_KEYS + (  # every metric a run may have
    ANGULAR_MOMENTUM_ERROR_MAX_ABS,
    ENERGY_ERROR_MAX_ABS,
    ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE,
)
# Metrics that are recorded and judged (a finding) but that ``freebody compare`` does not gate on:
# the quaternion's norm error is round-off (1e-16 .. 1e-7) on every engine that normalises, its
# changes below the finding's bound (tolerances.QUATERNION_NORM_ROUNDOFF) mean nothing, and a
# baseline written before schema 6 has none (each of its runs would read as "changed").
DIAGNOSTIC_METRICS = (QUATERNION_NORM_ERROR_MAX,)


def quaternion_norm_error(q: np.ndarray) -> np.ndarray:
    """|1 - |q_k|| (N,) of quaternions q (N, 4) as given (not normalised)."""
    with np.errstate(all="ignore"):
        return np.abs(1.0 - np.linalg.norm(q, axis=-1))


@dataclass(frozen=True)
class Series:
    """Per-sample errors of a run, shape (N,) each.

    orientation_error : rad, geodesic angle to the truth.
    angular_momentum_error : |L - L_truth| / max_t |L_truth| (or kg m^2/s absolute if that is 0).
    energy_error : |E - E_truth| / max_t KE_truth (or J absolute if that is 0).
    position_error : m, |x - x_truth|.
    """

    t: np.ndarray
    orientation_error: np.ndarray
    angular_momentum_error: np.ndarray
    energy_error: np.ndarray
    position_error: np.ndarray
    angular_momentum_relative: bool
    energy_relative: bool


def energies(problem: Problem, tr: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(kinetic (N,), total (N,)) energy in J of a trajectory, canonical formulas."""
    M, I_b = problem.body.mass, problem.body.I_body
    ke = kinetic_energy(M, I_b, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity)
    return ke, ke + potential_energy(M, problem.gravity, tr.position)


@dataclass(frozen=True)
class Scales:
    """The truth's maxima over the samples judged, which the relative errors (:class:`Series`) and
    the divergence bounds (:func:`divergence_bounds`) are scaled by: kinetic energy (J), |w|
    (rad/s), |v| (m/s), |L| (kg m^2/s).  A run judged in chunks takes them from a first pass over
    its whole truth (:func:`truth_scales` of each piece, :meth:`merged`)."""

    ke: float
    omega: float
    velocity: float
    momentum: float

    def merged(self, other: "Scales | None") -> "Scales":
        """The maxima of both (NaN propagates, as ``np.max`` does)."""
        if other is None:
            return self
        return Scales(*(float(np.maximum(a, b)) for a, b in zip(
            (self.ke, self.omega, self.velocity, self.momentum),
            (other.ke, other.omega, other.velocity, other.momentum))))


class Terms:
    """What the computations on one trajectory's samples share, each computed once when first
    asked for: a chunk's error series, divergence check and growth of the state take the run's; the
    truth's scales and series take the truth's (formed once per group for a whole truth,
    :meth:`freebody.run.judge.TruthCache.terms`).  The same functions on the same arrays as each
    computation alone: the same numbers.

    energies : (kinetic (N,), total (N,)) J (:func:`energies`).
    L : (N, 3) kg m^2/s, world, about the COM (``conventions.angular_momentum``).
    omega : (N,) rad/s, |w|.  speed : (N,) m/s, |v|.
    scales : the :class:`Scales` of these samples (:func:`truth_scales`).
    """

    def __init__(self, problem: Problem, tr: Trajectory):
        self.problem, self.tr = problem, tr

    def of(self, problem: Problem, tr: Trajectory) -> "Terms":
        """These terms when they are those of (problem, tr), else the terms of (problem, tr)."""
        return self if tr is self.tr and problem is self.problem else Terms(problem, tr)

    @functools.cached_property
    def energies(self) -> tuple[np.ndarray, np.ndarray]:
        return energies(self.problem, self.tr)

    @functools.cached_property
    def L(self) -> np.ndarray:
        return angular_momentum(self.problem.body.I_body, self.tr.quaternion_wxyz, self.tr.angular_velocity)

    @functools.cached_property
    def omega(self) -> np.ndarray:
        return np.linalg.norm(self.tr.angular_velocity, axis=1)

    @functools.cached_property
    def speed(self) -> np.ndarray:
        return np.linalg.norm(self.tr.linear_velocity, axis=1)

    @functools.cached_property
    def scales(self) -> Scales:
        return Scales(float(np.max(self.energies[0])), float(np.max(self.omega)), float(np.max(self.speed)),
                      float(np.max(np.linalg.norm(self.L, axis=-1))))


def truth_scales(problem: Problem, truth: Trajectory, terms: Terms | None = None) -> Scales:
    """The :class:`Scales` of a truth's samples (one or more); ``terms``: their :class:`Terms`, if formed."""
    return (Terms(problem, truth) if terms is None else terms.of(problem, truth)).scales


def series(problem: Problem, tr: Trajectory, truth: Trajectory, scales: Scales | None = None,
           terms: Terms | None = None, truth_terms: Terms | None = None) -> Series:
    """The error series of the samples of ``tr`` against the truth's (its first len(tr) samples),
    relative errors scaled by ``scales`` (None: the truth's own, :func:`truth_scales`): a run
    judged in chunks passes its whole truth's, so that each chunk's series are the whole run's.
    ``terms``, ``truth_terms``: the :class:`Terms` of ``tr`` and of those truth samples, if formed."""
    n = len(tr)
    truth = truth.head(n)
    run = Terms(problem, tr) if terms is None else terms.of(problem, tr)
    true = Terms(problem, truth) if truth_terms is None else truth_terms.of(problem, truth)
    if scales is None:
        scales = true.scales
    ori = geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz)
    L, L_true = run.L, true.L
    L_scale = scales.momentum
    dL = np.linalg.norm(L - L_true, axis=-1)
    _, E = run.energies
    _, E_true = true.energies
    E_scale = scales.ke
    dE = np.abs(E - E_true)
    return Series(
        t=tr.t, orientation_error=ori,
        angular_momentum_error=dL / L_scale if L_scale > 0 else dL,
        energy_error=dE / E_scale if E_scale > 0 else dE,
        position_error=np.linalg.norm(tr.position - truth.position, axis=-1),
        angular_momentum_relative=L_scale > 0, energy_relative=E_scale > 0,
    )


class RunningMax:
    """The maximum of an array seen piece by piece: ``max`` as ``np.max`` gives it over all the
    pieces (NaN propagates; None before any sample), and ``best``/``best_index`` the largest finite
    value and its first index (:func:`~freebody.results.document.finite_argmax`; None if none)."""

    __slots__ = ("max", "best", "best_index")

    def __init__(self):
        self.max = None
        self.best = None
        self.best_index = None

    def update(self, a: np.ndarray, k0: int) -> "RunningMax":
        """Take the samples ``a`` (global indices k0, k0 + 1, ...) in; returns self."""
        if len(a) == 0:
            return self
        m = np.max(a)
        self.max = m if self.max is None else np.maximum(self.max, m)
        i = finite_argmax(a)
        if i is not None and (self.best is None or a[i] > self.best):
            self.best, self.best_index = float(a[i]), k0 + i
        return self

    def copy(self) -> "RunningMax":
        c = RunningMax()
        c.max, c.best, c.best_index = self.max, self.best, self.best_index
        return c


# the arrays SeriesStats follows, in the order of saved_indices
STAT_ARRAYS = ("orientation_error", "angular_momentum_error", "energy_error", "position_error",
               "orthonormality_error")


class SeriesStats:
    """Running maxima (:class:`RunningMax`) of a run's error series and of its orthonormality
    error, and the final orientation error: what its ``metrics`` are made of, whether the run is
    judged whole (one update) or in chunks (one update per chunk, same numbers)."""

    def __init__(self):
        self.maxima = {name: RunningMax() for name in STAT_ARRAYS}
        self.final_orientation = None
        self.has_orthonormality = False
        self.n = 0

    def update(self, s: Series, orthonormality: np.ndarray | None, k0: int) -> None:
        for name in STAT_ARRAYS[:4]:
            self.maxima[name].update(getattr(s, name), k0)
        if orthonormality is not None:
            self.has_orthonormality = True
            self.maxima["orthonormality_error"].update(orthonormality, k0)
        if len(s.orientation_error):
            self.final_orientation = s.orientation_error[-1]
        self.n = k0 + len(s.orientation_error)

    def prefix(self, s: Series, orthonormality: np.ndarray | None, k0: int, end: int) -> "SeriesStats":
        """These statistics extended by the samples of this chunk (global index k0 on) before the
        global index ``end``: the statistics of the samples [0, end)."""
        out = SeriesStats()
        out.maxima = {k: v.copy() for k, v in self.maxima.items()}
        out.final_orientation, out.has_orthonormality, out.n = self.final_orientation, self.has_orthonormality, self.n
        m = max(0, end - k0)
        if m:
            head = Series(s.t[:m], *(getattr(s, a)[:m] for a in STAT_ARRAYS[:4]),
                          s.angular_momentum_relative, s.energy_relative)
            out.update(head, None if orthonormality is None else orthonormality[:m], k0)
        return out

    def metrics(self, momentum_relative: bool, energy_relative: bool) -> dict:
        """The results.json ``metrics`` of the samples taken in (relative errors where the truth's
        scale is not zero, else the absolute ones under their own keys)."""
        mx = {k: (finite_or_none(v.max) if v.max is not None else None) for k, v in self.maxima.items()}
        m = {
            ORIENTATION_ERROR_MAX: mx["orientation_error"],
            ORIENTATION_ERROR_FINAL: finite_or_none(self.final_orientation),
            ANGULAR_MOMENTUM_ERROR_MAX_REL: mx["angular_momentum_error"] if momentum_relative else None,
            ENERGY_ERROR_MAX_REL: mx["energy_error"] if energy_relative else None,
            POSITION_ERROR_MAX: mx["position_error"],
            ROTATION_ORTHONORMALITY_ERROR_MAX: mx["orthonormality_error"] if self.has_orthonormality else None,
        }
        if not momentum_relative:
            m[ANGULAR_MOMENTUM_ERROR_MAX_ABS] = mx["angular_momentum_error"]
        if not energy_relative:
            m[ENERGY_ERROR_MAX_ABS] = mx["energy_error"]
        return m

    def argmax_indices(self) -> list[int]:
        """The first index of each array's largest finite value (those that have one)."""
        return [v.best_index for v in self.maxima.values() if v.best_index is not None]


# --- divergence ----------------------------------------------------------------------------------
# The kinds of divergence, each found at its first sample: the state not finite, then the bounds
# in this order, and a matrix's R no rotation (see divergence()).
DIVERGENCE_KINDS = ("not finite", "energy", "omega", "velocity", "orthonormality")


def divergence_bounds(scales: Scales) -> dict[str, float]:
    """The bounds of a run's state, from the truth's maxima over the run: kinetic energy (J),
    |w| (rad/s), |v| (m/s) (see :func:`divergence`)."""
    return {
        "energy": tol.DIVERGENCE_ENERGY_FACTOR * max(scales.ke, tol.DIVERGENCE_ENERGY_FLOOR_J),
        "omega": tol.DIVERGENCE_OMEGA_FACTOR * max(scales.omega, tol.DIVERGENCE_OMEGA_FLOOR_RAD_S),
        "velocity": tol.DIVERGENCE_VELOCITY_FACTOR * max(scales.velocity, tol.DIVERGENCE_VELOCITY_FLOOR_M_S),
    }


def divergence_firsts(problem: Problem, tr: Trajectory, bounds: dict[str, float],
                      wanted=DIVERGENCE_KINDS, terms: Terms | None = None) -> dict[str, int]:
    """{kind: index in ``tr`` of its first sample} of each of the ``wanted`` kinds of
    :data:`DIVERGENCE_KINDS` that occurs in these samples; ``terms``: their :class:`Terms`, if formed."""
    found = {}
    terms = Terms(problem, tr) if terms is None else terms.of(problem, tr)
    if "not finite" in wanted:
        arrays = (tr.position, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity)
        bad = ~np.all(np.concatenate([np.isfinite(a) for a in arrays], axis=1), axis=1)
        found["not finite"] = _first(bad)
    if "energy" in wanted:
        found["energy"] = _first(terms.energies[0] > bounds["energy"])
    if "omega" in wanted:
        found["omega"] = _first(terms.omega > bounds["omega"])
    if "velocity" in wanted:
        found["velocity"] = _first(terms.speed > bounds["velocity"])
    if "orthonormality" in wanted and tr.orthonormality_error is not None:
        found["orthonormality"] = _first(tr.orthonormality_error > tol.DIVERGENCE_ORTHONORMALITY_MAX)
    return {k: v for k, v in found.items() if v is not None}


def divergence_decision(firsts: dict[str, int], bounds: dict[str, float]) -> tuple[int, str] | None:
    """(index, reason) of a run's divergence from the first index of each kind over the whole run
    (:func:`divergence_firsts`), or None: a non-finite state first wherever it is, else the first
    bound exceeded in the order energy, |w|, |v|; a matrix's R no rotation when earlier than that."""
    found = None
    if "not finite" in firsts:
        found = (firsts["not finite"], "state is not finite (NaN or inf)")
    else:
        for kind, why in (("energy", f"kinetic energy beyond {bounds['energy']:.3g} J"),
                          ("omega", f"|w| beyond {bounds['omega']:.3g} rad/s"),
                          ("velocity", f"|v| beyond {bounds['velocity']:.3g} m/s")):
            if kind in firsts:
                found = (firsts[kind], why)
                break
    ortho = firsts.get("orthonormality")
    if ortho is not None and (found is None or ortho < found[0]):
        return (ortho, f"R is no rotation: ||R^T R - 1||_F beyond {tol.DIVERGENCE_ORTHONORMALITY_MAX:g}")
    return found


def divergence(problem: Problem, tr: Trajectory, truth: Trajectory) -> tuple[float, str] | None:
    """(time, reason) of the first sample that is non-finite or beyond the case's bounds, or None.

    Bounds: kinetic energy > DIVERGENCE_ENERGY_FACTOR x the truth's max KE, |w| or |v| beyond
    their factor x the truth's max, and for an integrated rotation matrix ||R^T R - 1||_F beyond
    DIVERGENCE_ORTHONORMALITY_MAX (see :mod:`freebody.tolerances`): the earlier of that and the
    others.  A non-finite state is reported first wherever it is; then the bounds in the order
    energy, |w|, |v| (:func:`divergence_decision`, which a run judged in chunks applies as well).
    """
    bounds = divergence_bounds(truth_scales(problem, truth.head(len(tr))))
    found = divergence_decision(divergence_firsts(problem, tr, bounds), bounds)
    return None if found is None else (float(tr.t[found[0]]), found[1])


# --- growth of the state beyond the truth's: blow-ups and the rotation per step ------------------
# The results.json run field ``state_growth`` (optional: absent in results written before it).
STATE_GROWTH = "state_growth"


class GrowthStats:
    """How far a run's |w| and kinetic energy grow beyond the truth's, and how far one step turns
    the body, taken in chunk by chunk (the same numbers whole or in chunks): the results.json run
    field ``state_growth`` (:meth:`result`).

    dt : the run's step, s.  cap : the engine's largest rotation per step (rad,
    ``Adapter.step_rotation_cap_rad``), None when it declares none.
    """

    def __init__(self, dt: float, cap: float | None = None):
        self.dt, self.cap = float(dt), cap
        self.omega = RunningMax()  # |w|, rad/s
        self.ke = RunningMax()  # kinetic energy, J
        self.t: dict[int, float] = {}  # global index -> t of the samples named in the result
        self.blow_up: int | None = None  # global index of the first sample beyond a blow-up bound
        self.capped: int | None = None  # ... of the first sample with |w| dt beyond the cap

    def update(self, problem: Problem, tr: Trajectory, k0: int, scales: Scales, terms: Terms | None = None) -> None:
        """The run's next samples ``tr`` (global indices k0, k0 + 1, ...); ``scales``: the truth's
        maxima over the whole run (the blow-up bounds, :func:`blow_up_bounds`); ``terms``: the
        samples' :class:`Terms`, if formed."""
        if len(tr) == 0:
            return
        terms = Terms(problem, tr) if terms is None else terms.of(problem, tr)
        with np.errstate(all="ignore"):
            w = terms.omega
            ke, _ = terms.energies
        self.omega.update(w, k0)
        self.ke.update(ke, k0)
        for v in (self.omega, self.ke):
            if v.best_index is not None and k0 <= v.best_index < k0 + len(tr):
                self.t[v.best_index] = float(tr.t[v.best_index - k0])
        bounds = blow_up_bounds(scales)
        if self.blow_up is None:
            i = _first((w > bounds["omega"]) | (ke > bounds["energy"]))
            if i is not None:
                self.blow_up = k0 + i
                self.t[k0 + i] = float(tr.t[i])
        if self.cap is not None and self.capped is None:
            i = _first(w * self.dt > self.cap)
            if i is not None:
                self.capped = k0 + i
                self.t[k0 + i] = float(tr.t[i])

    def result(self, scales: Scales) -> dict:
        """``state_growth``: omega_max_rad_s and omega_max_t_s (the run's largest finite |w| and its
        first time), omega_ratio (that over the truth's max |w|, floored at
        DIVERGENCE_OMEGA_FLOOR_RAD_S), kinetic_energy_ratio and kinetic_energy_max_t_s (likewise,
        floored at DIVERGENCE_ENERGY_FLOOR_J), blow_up_t_s (the first sample beyond
        BLOW_UP_OMEGA_FACTOR x or BLOW_UP_ENERGY_FACTOR x those, None: no blow-up),
        rotation_per_step_max_rad (omega_max dt: the largest angle one step turns the body at the
        run's own |w|) and, when the engine declares a cap, step_rotation_cap_rad and
        rotation_cap_t_s (the first sample with |w| dt beyond it, None: never)."""
        w_scale = max(scales.omega, tol.DIVERGENCE_OMEGA_FLOOR_RAD_S)
        ke_scale = max(scales.ke, tol.DIVERGENCE_ENERGY_FLOOR_J)
        w, ke = self.omega.best, self.ke.best
        out = {
            "omega_max_rad_s": w, "omega_max_t_s": self.t.get(self.omega.best_index),
            "omega_ratio": None if w is None else finite_or_none(w / w_scale),
            "kinetic_energy_ratio": None if ke is None else finite_or_none(ke / ke_scale),
            "kinetic_energy_max_t_s": self.t.get(self.ke.best_index),
            "blow_up_t_s": self.t.get(self.blow_up),
            "rotation_per_step_max_rad": None if w is None else finite_or_none(w * self.dt),
        }
        if self.cap is not None:
            out["step_rotation_cap_rad"] = float(self.cap)
            out["rotation_cap_t_s"] = self.t.get(self.capped)
        return out


def blow_up_bounds(scales: Scales) -> dict[str, float]:
    """The bounds of a blow-up (a finding, not a divergence): |w| (rad/s) and kinetic energy (J),
    BLOW_UP_OMEGA_FACTOR and BLOW_UP_ENERGY_FACTOR times the truth's maxima (floored as the
    divergence bounds are, :func:`divergence_bounds`)."""
    return {"omega": tol.BLOW_UP_OMEGA_FACTOR * max(scales.omega, tol.DIVERGENCE_OMEGA_FLOOR_RAD_S),
            "energy": tol.BLOW_UP_ENERGY_FACTOR * max(scales.ke, tol.DIVERGENCE_ENERGY_FLOOR_J)}


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


# --- a run's metrics, fed chunk by chunk -----------------------------------------------------------

class RunMetrics:
    """Everything computed on a run's arrays, fed whole (one :meth:`feed`) or in consecutive chunks
    with the same numbers either way: the error series of each chunk scaled by the truth's maxima
    over the whole run (``scales``), their running maxima and finals (:class:`SeriesStats`), the
    first sample of each kind of divergence (:func:`divergence_firsts`; :meth:`divergence` decides
    at the end, :func:`divergence_decision`), the statistics of the samples before each such sample
    (the ``*_before_divergence`` metrics and the saved samples of a diverged run) and the growth of
    the state (:class:`GrowthStats`).  :class:`freebody.run.judge.RunJudge` drives it.

    dt : the run's step, s.  cap : the engine's rotation cap per step (rad) or None.
    """

    def __init__(self, problem: Problem, scales: Scales, dt: float, cap: float | None = None):
        self.pb, self.scales = problem, scales
        self.bounds = divergence_bounds(scales)
        self.stats = SeriesStats()
        self.firsts: dict[str, int] = {}  # kind of divergence -> global index of its first sample
        self.times: dict[int, float] = {}  # global index -> t of the divergence samples
        self.before: dict[int, SeriesStats] = {}  # divergence index d -> statistics of [0, prefix_end(d))
        self.engine_diverged: int | None = None  # index where the engine reported its blow-up
        self.engine_t: float | None = None
        self.truth_max: Scales | None = None  # the truth's maxima over the samples fed
        self.growth = GrowthStats(dt, cap)
        self.quaternion_norm = RunningMax()  # |1 - |q||, the engine's q before any normalisation

    @property
    def undiverged(self) -> bool:
        """Whether no divergence has been found (nor reported by the engine) in the samples fed."""
        return not self.firsts and self.engine_diverged is None

    def feed(self, tr: Trajectory, truth: Trajectory, k0: int, diverged_at: float | None = None,
             truth_terms: Terms | None = None) -> tuple[Series, list[int], dict[str, int | None]]:
        """The run's next samples ``tr`` (global indices k0, k0 + 1, ...) and the truth's at them
        (as many); ``diverged_at``: the engine reported a blow-up at that time (the last piece);
        ``truth_terms``: those truth samples' :class:`Terms`, if formed (a group's truth).
        Returns (the chunk's :class:`Series`, the global indices of the divergences first found in
        it, each array's index of its largest finite value before this chunk)."""
        pb, m = self.pb, len(tr)
        run = Terms(pb, tr)  # what the series, the divergence check and the growth share
        true = Terms(pb, truth) if truth_terms is None else truth_terms.of(pb, truth)
        self.quaternion_norm.update(quaternion_norm_error(tr.quaternion_wxyz), k0)  # before series() uses q / |q|
        self.truth_max = true.scales.merged(self.truth_max)
        s = series(pb, tr, truth, self.scales, run, true)
        ortho = tr.orthonormality_error
        new: list[int] = []
        if diverged_at is not None:
            d = k0 + int(np.searchsorted(tr.t, diverged_at))
            self.engine_diverged, self.engine_t = d, float(diverged_at)
            new.append(d)
        elif self.engine_diverged is None:
            wanted = [k for k in DIVERGENCE_KINDS if k not in self.firsts]
            for kind, i in divergence_firsts(pb, tr, self.bounds, wanted, run).items():
                self.firsts[kind] = k0 + i
                self.times[k0 + i] = float(tr.t[i])
                new.append(k0 + i)
        for d in new:
            if d not in self.before:
                self.before[d] = self.stats.prefix(s, ortho, k0, prefix_end(d, k0 + m))
        best_before = {name: self.stats.maxima[name].best_index for name in STAT_ARRAYS}
        self.stats.update(s, ortho, k0)
        self.growth.update(pb, tr, k0, self.scales, run)
        return s, new, best_before

    def engine_stopped(self, n: int, t: float) -> None:
        """The engine reported a blow-up at ``t`` after the ``n`` samples fed, with no sample of its
        own: the divergence is at sample n, the statistics before it those of every sample fed."""
        self.engine_diverged, self.engine_t = n, float(t)
        self.before[n] = self.stats

    def divergence(self) -> tuple[int, float, str | None] | None:
        """(index, t, reason) of the run's divergence, or None: the engine's report first (reason
        None: the engine's own), else the harness's decision (:func:`divergence_decision`)."""
        if self.engine_diverged is not None:
            return self.engine_diverged, self.engine_t, None
        found = divergence_decision(self.firsts, self.bounds)
        return None if found is None else (found[0], self.times[found[0]], found[1])

    def result(self, diverged_index: int | None) -> tuple[dict, dict]:
        """(results.json ``metrics``, ``state_growth``) of the samples fed; ``diverged_index``: the
        run diverged there (:meth:`divergence`): its metrics are kept up to it only, but for R's
        orthonormality error and the quaternion's norm error (how far they went: their largest
        finite values, as the state becomes inf/NaN in the end)."""
        metrics = self.stats.metrics(self.truth_max.momentum > 0, self.truth_max.ke > 0)
        metrics[QUATERNION_NORM_ERROR_MAX] = self.quaternion_norm.max
        d = diverged_index
        if d is not None:  # metrics past a blow-up are meaningless
            metrics = {k: None for k in metrics}
            if self.stats.has_orthonormality:
                metrics[ROTATION_ORTHONORMALITY_ERROR_MAX] = self.stats.maxima["orthonormality_error"].best
            metrics[QUATERNION_NORM_ERROR_MAX] = self.quaternion_norm.best
            if d >= 1:
                metrics[ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE] = self.before[d].maxima["orientation_error"].max
        return {k: finite_or_none(v) for k, v in metrics.items()}, self.growth.result(self.scales)

    def saved_maxima(self, diverged_index: int | None) -> list[int]:
        """The indices of the maxima a trajectory file keeps: over the run, and before its divergence."""
        d = diverged_index
        return self.stats.argmax_indices() + (self.before[d].argmax_indices() if d is not None else [])

