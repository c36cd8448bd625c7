"""Findings and the verdict page: what in a results document deserves a reader's attention,
computed from the runs alone (nothing is written by hand per engine).  What a finding says of one
run it reads from the run's stored ``judgement`` (:mod:`freebody.results.judgement`: the map it
reproduces or comes closest to, a lost orientation, its formal order, a blow-up, the rotation
cap), judged once when the run was recorded; what this module computes is the comparison of runs
with each other (scheme groups, pairs, outliers, majorities, disagreements) and the words.

Every engine run (not the reference engine's: its runs *are* the reference maps) that scheme
identification judged (``matches_reference``, :func:`freebody.run.judge.identify`) belongs, on its
case, to the group of the map it reproduces, or, reproducing none, to the group of the map it
comes closest to (:func:`scheme_groups`).  Runs of one group that reproduce its map should agree
with each other to round-off; runs of two groups differ by their schemes.  A finding is raised by

- ``no-map``: a run that reproduces no reference map (its distance to the closest map is beyond
  that map's round-off level, ``matches_reference["ratios"]`` > 1): an unknown scheme, or an engine
  bug or convention trap on this case;
- ``same-map-disagreement``: two runs of one group, at one dt and precision, whose final
  orientations differ by more than the sum of their round-off levels (both reproduce the map, so
  they cannot, unless the records contradict each other);
- ``scheme-switch``: an engine run that reproduces on this case another map than on its other
  runs (e.g. a per-step cap that only high spins reach);
- ``undecidable``: a run whose nearest maps identify nothing on its case (their round-off levels
  reach the cap, or their perturbed copies blow up: ``matches_reference["verdict"]``);
- ``outlier``: an orientation error :data:`OUTLIER_FACTOR` times above the median of the other
  engines' runs of the same or lower formal order at the same case and dt (a clamp, a cap, a
  convention trap); it names the map the run reproduces and points at the engine's conventions;
- ``vs-engine``: a ported engine (e.g. MJX) farther from its original than round-off, or not
  compared with it;
- ``non-unit-quaternion``: an ok run whose quaternions, as its engine handed them out, are not unit
  beyond round-off (``judgement["non_unit_quaternion"]``, metric ``quaternion_norm_error_max``);
- ``failed``, ``diverged``, ``unsupported-version`` (skipped: the adapter does not drive this
  engine version) and ``not-installed`` (skipped) runs.

Each :class:`Finding` carries its severity, one sentence, the size of the disagreement (rad) and,
where the saved trajectories tell it, the time of its first sample (s), and names the results
field that raised it.  Pure functions of run dicts (results.json ``runs`` entries in the newest
shape, as :func:`freebody.results.document.load_results` gives them: every key of a run, its
``judgement`` included); the times come from an optional ``trajectory(run)`` callable (the report
reads the trajectory files).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .. import tolerances as tol
from ..adapters.base import REFERENCE_ENGINE
from ..numbers import finite_or_none
from ..run.metrics import (ORIENTATION_ERROR_MAX, ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE, QUATERNION_NORM_ERROR_MAX,
                           STATE_GROWTH)
from ..run.records import Status
from ..results import identification
from ..results.judgement import JUDGEMENT, map_distance
from .summary import run_label

SEVERITIES = ("error", "warning", "info")  # most severe first
# kind -> (severity, short title shown in the findings list)
KINDS = {
    "failed": ("error", "failed"),
    "same-map-disagreement": ("error", "same map, different results"),
    "version-change": ("warning", "changed between engine versions"),  # report/version_findings.py
    "no-map": ("warning", "reproduces no reference map"),
    "outlier": ("warning", "error far above the other engines'"),
    "blow-up": ("warning", "|w| or energy blew up"),
    "rotation-cap": ("warning", "rotation per step beyond the engine's cap"),
    "non-unit-quaternion": ("warning", "engine returns non-unit quaternions"),
    "order": ("warning", "observed order far from the expected one"),
    "diverged": ("warning", "diverged"),
    "unsupported-version": ("warning", "engine version not supported"),
    "vs-engine": ("warning", "differs from its original engine"),
    "scheme-switch": ("info", "reproduces another map on this case"),
    "undecidable": ("info", "no map can be identified on this case"),
    "reference-diverged": ("info", "reference map diverged"),
    "reference-blow-up": ("info", "reference map blew up"),
    "vs-engine-unavailable": ("info", "not compared with its original engine"),
    "not-installed": ("info", "engine not installed"),
}
# An orientation error this many times the median of the other engines' runs of the same or lower
# formal order (same case, dt and precision) is an outlier.  On the default suite every other
# engine run is at most 2.4x its peers' median (first-order maps with an explicit or an implicit
# gyroscopic term); PyBullet's per-step rotation cap at 150 rad/s and dt = 10 ms is 3e9x (3.1 rad
# against the floor below), DART's truncated exponential map on a slow spin 210x.
OUTLIER_FACTOR = 100.0
# Errors below the truth's own accuracy are not compared: the median is floored there (per precision).
OUTLIER_FLOOR_RAD = {"float64": tol.CONVERGENCE_ORIENTATION_FLOOR_RAD,
                     "float32": tol.CONVERGENCE_ORIENTATION_FLOOR_FLOAT32_RAD}

TIE_NAMES_SHOWN = 2  # a group name lists the maps of a tie up to this many (else 'X = N more')

# What a trajectory provider returns: (t (n,) s, q (n, 4) wxyz body -> world, q_truth (n, 4)) at
# the run's saved samples, or None when its trajectory cannot be read.
SavedSamples = tuple[np.ndarray, np.ndarray, np.ndarray]
TrajectoryOf = Callable[[dict], "SavedSamples | None"]


@dataclass(frozen=True)
class Finding:
    """One finding about one run (or a pair of runs) of a case at one dt.

    severity : one of :data:`SEVERITIES`.  kind : a key of :data:`KINDS`.
    case, dt (s), label (engine/integrator[/precision]), engine : the run.  other : the other run of
    a pair ('' for one run).
    text : one sentence saying what and why, without the run's name (shown before it).
    size_rad : the size of the disagreement (rad), None when it has none (a failed run).
    t_s : the time of its first sample (s), None when the saved data do not tell it.
    source : the results.json field or metric that raised it.
    """

    severity: str
    kind: str
    case: str
    dt: float | None
    label: str
    engine: str
    text: str
    size_rad: float | None = None
    t_s: float | None = None
    source: str = ""
    other: str = ""

    @property
    def title(self) -> str:
        return KINDS[self.kind][1]


def _finding(kind: str, run: dict, text: str, **kw) -> Finding:
    return Finding(KINDS[kind][0], kind, str(run["case"]), finite_or_none(run["dt"]), label(run), str(run["engine"]),
                   text, **kw)


def label(run: dict) -> str:
    """engine/integrator[/precision] (float64 omitted): one engine run across cases and dts (of a
    run, or of a convergence entry, whose ``precision`` is optional)."""
    return run_label({**run, "precision": run.get("precision") or "float64"})


def _precision(run: dict) -> str:
    return run["precision"]


def _ok(run: dict) -> bool:
    return run["status"] == Status.OK


def _metric(run: dict, key: str) -> float | None:
    return finite_or_none(run["metrics"].get(key))  # a metric is optional


def _e(x: float | None) -> str:
    return "-" if x is None else format(x, ".1e")


# --- the judgement of a run: stored with it (results.json ``judgement``), read here -------------------

def judged(run: dict) -> dict:
    """The run's ``judgement`` (:func:`freebody.results.judgement.run_judgement`: computed when the
    run was recorded, or by the schema-5 migration of an older document)."""
    return run[JUDGEMENT]


def scheme_set(run: dict) -> tuple[str, ...]:
    """The maps a run reproduces (its tie, in candidate order), () when none or not identified."""
    return tuple(judged(run)["schemes"])


def scheme_key(run: dict) -> tuple[str, bool] | None:
    """(map, reproduced) of a judged ok engine run: the map it reproduces (the first of a tie), or
    the closest map and False; None for a run that was not judged (the reference engine, a run
    that is not ok, a results file without identification)."""
    j = judged(run)
    return None if j["scheme"] is None else (j["scheme"], j["reproduced"])


def saturated(run: dict) -> bool:
    """Whether a run that reproduces no map is as far from the closest map as a lost orientation
    is (beyond CONVERGENCE_ORIENTATION_SATURATED_RAD): every map is then about as far, and which
    one is closest says nothing about the scheme."""
    return judged(run)["saturated"]


def blew_up(run: dict) -> bool:
    """Whether an ok run's |w| or kinetic energy went beyond the blow-up bounds
    (``state_growth["blow_up_t_s"]``: BLOW_UP_OMEGA_FACTOR x the truth's max |w| or
    BLOW_UP_ENERGY_FACTOR x its max KE)."""
    return judged(run)["blew_up"]


def capped(run: dict) -> bool:
    """Whether an ok run turned faster than its engine's declared rotation cap per step allows
    (``state_growth["rotation_cap_t_s"]``)."""
    return judged(run)["capped"]


def run_order(run: dict) -> int | None:
    """The formal order of a run: its integrator's for a reference run; for an engine run the
    lowest order of the maps it reproduces (or of its closest map); None when unknown."""
    return judged(run)["order"]


def map_summary(name: str) -> str:
    """A map's one-line description ('' for an unknown name)."""
    from ..reference_impl.engine_maps import ENGINE_MAPS
    from ..reference_impl.integrators import INTEGRATORS

    entry = INTEGRATORS.get(name) or ENGINE_MAPS.get(name)
    return entry.summary if entry is not None else ""


# --- scheme groups (the verdict page) ----------------------------------------------------------------

@dataclass(frozen=True)
class Member:
    """One run of a scheme group.

    distance_rad : its largest orientation difference from the group's map (rad).
    level_rad : the map's round-off level on this run (rad, at the last sample).
    ratio : distance / level, max over samples (<= 1: reproduces).
    error_rad : its orientation error max against the truth (rad).
    """

    run: dict
    label: str
    dt: float
    distance_rad: float | None
    level_rad: float | None
    ratio: float | None
    error_rad: float | None


@dataclass(frozen=True)
class SchemeGroup:
    """The engine runs of one case that reproduce one map (``reproduced``) or, reproducing none,
    come closest to it.  tie : the maps indistinguishable from it on every member's run ((scheme,)
    when none).  members : in run order."""

    case: str
    scheme: str
    reproduced: bool
    tie: tuple[str, ...]
    members: tuple[Member, ...]

    @property
    def name(self) -> str:
        """The group's map: 'X', 'X = Y' (a tie of two), 'X = N more' (a larger tie, see
        :attr:`tie_text`), or 'none (closest X)'."""
        if not self.reproduced:
            if self.members and all(saturated(m.run) for m in self.members):
                return "none (orientation lost)"  # every map is as far: no closest map is named
            return f"none (closest {self.scheme})"
        if len(self.tie) > TIE_NAMES_SHOWN:
            return f"{self.scheme} = {len(self.tie) - 1} more"
        return " = ".join(self.tie)

    @property
    def tie_text(self) -> str:
        """Every map of the tie: 'X = Y = Z ...'."""
        return " = ".join(self.tie)

    def dts(self) -> list[float]:
        return sorted({m.dt for m in self.members}, reverse=True)

    def at(self, dt: float) -> list[Member]:
        return [m for m in self.members if m.dt == dt]


def scheme_groups(case_runs: list[dict]) -> list[SchemeGroup]:
    """The scheme groups of one case's runs (judged ok engine runs only), keyed by the map each run
    reproduces (the first of its tie, in candidate order, as identification names it) or, for a
    run that reproduces none, its closest map.  A group's tie: the maps every member reproduces.
    Groups in order of their first member, those of runs that reproduce no map last; members in
    run order.  (Two groups may still agree to round-off on this case, when their runs' ties
    overlap: :func:`between_groups` says so.)"""
    acc: dict[tuple[str, bool], list[dict]] = {}
    for r in case_runs:
        key = scheme_key(r)
        if key is not None:
            acc.setdefault(key, []).append(r)
    groups = []
    for (scheme, reproduced), rs in acc.items():
        tie = [scheme]
        if reproduced:
            sets = [set(scheme_set(r)) or {scheme} for r in rs]
            tie += [x for x in scheme_set(rs[0]) if x != scheme and all(x in st for st in sets)]
        members = tuple(Member(r, label(r), float(r["dt"]), judged(r)["scheme_distance_rad"],
                               judged(r)["scheme_level_rad"], judged(r)["scheme_ratio"],
                               _metric(r, ORIENTATION_ERROR_MAX)) for r in rs)
        groups.append(SchemeGroup(str(rs[0]["case"]), scheme, reproduced, tuple(tie), members))
    groups.sort(key=lambda g: not g.reproduced)
    return groups


@dataclass(frozen=True)
class GroupPair:
    """Two scheme groups of a case at one dt: the largest angle (rad) between the final orientations
    of a run of each (same precision), and those runs.  When the groups' ties share a map (every
    run of both reproduces it) they agree to round-off on this case; else they differ by their
    schemes."""

    dt: float
    a: SchemeGroup
    b: SchemeGroup
    angle_rad: float | None
    run_a: str
    run_b: str

    @property
    def agree(self) -> bool:
        return self.a.reproduced and self.b.reproduced and bool(set(self.a.tie) & set(self.b.tie))

    @property
    def attribution(self) -> str:
        if self.agree:
            return f"agree to round-off here ({self.a.name} ~ {self.b.name})"
        return f"differs by scheme ({self.a.name} vs {self.b.name})"


def final_angle(a: dict, b: dict) -> float | None:
    """Geodesic angle (rad) between two runs' final orientations (results.json ``final_state``)."""
    from ..reference_impl.rotations import geodesic_angle

    qs = []
    for r in (a, b):
        fs = r["final_state"]  # None for a run that is not ok
        try:
            q = np.asarray((fs or {})["quaternion_wxyz"], dtype=float)
        except (KeyError, TypeError, ValueError):
            return None
        if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.any(q):
            return None
        qs.append(q)
    return finite_or_none(float(geodesic_angle(qs[0], qs[1])))


def between_groups(groups: list[SchemeGroup]) -> list[GroupPair]:
    """Every two groups of a case at each dt both ran at: their largest final-state angle."""
    out = []
    for i, ga in enumerate(groups):
        for gb in groups[i + 1:]:
            for dt in ga.dts():
                best = None
                for ma in ga.at(dt):
                    for mb in gb.at(dt):
                        if _precision(ma.run) != _precision(mb.run):
                            continue
                        angle = final_angle(ma.run, mb.run)
                        if angle is not None and (best is None or angle > best[0]):
                            best = (angle, ma.label, mb.label)
                if best is not None:
                    out.append(GroupPair(dt, ga, gb, *best))
    out.sort(key=lambda p: (-p.dt, -(p.angle_rad or 0.0)))
    return out


def pair_relation(a: dict, b: dict) -> str:
    """How two runs of one case and dt relate: 'same map (X)' (X: the first map both reproduce),
    'differs by scheme (A vs B)' or '' (either not judged; a reference run is its own map)."""
    names, sets = [], []
    for r in (a, b):
        if r["engine"] == REFERENCE_ENGINE:
            names.append((str(r["integrator"]), True))
            sets.append((str(r["integrator"]),))
        else:
            key = scheme_key(r)
            if key is None:
                return ""
            names.append(key)
            sets.append(scheme_set(r) or (key[0],))
    (na, ra), (nb, rb) = names
    common = [x for x in sets[0] if x in sets[1]]
    if ra and rb and common:
        return f"same map ({common[0]})"
    text = [n if r else none_text(run, n, ", ") for (n, r), run in zip(names, (a, b))]
    return f"differs by scheme ({text[0]} vs {text[1]})"


# --- findings --------------------------------------------------------------------------------------

def _first_time(t: np.ndarray, values: np.ndarray, limit: float) -> float | None:
    """The first t where values > limit (finite samples; a non-finite value counts as beyond)."""
    beyond = ~(np.asarray(values, dtype=float) <= limit)
    idx = np.flatnonzero(beyond)
    return float(t[idx[0]]) if len(idx) else None


def _error_series(traj: SavedSamples) -> tuple[np.ndarray, np.ndarray]:
    from ..reference_impl.rotations import geodesic_angle

    t, q, q_truth = traj
    n = min(len(t), len(q), len(q_truth))
    with np.errstate(all="ignore"):
        return np.asarray(t[:n], float), geodesic_angle(np.asarray(q_truth[:n], float), np.asarray(q[:n], float))


def _pair_first_time(ta: SavedSamples, tb: SavedSamples, limit: float) -> float | None:
    """The first common sample time where two runs' orientations differ by more than ``limit``."""
    from ..reference_impl.rotations import geodesic_angle

    (t_a, q_a, _), (t_b, q_b, _) = ta, tb
    common, ia, ib = np.intersect1d(np.asarray(t_a, float), np.asarray(t_b, float), return_indices=True)
    if not len(common):
        return None
    with np.errstate(all="ignore"):
        d = geodesic_angle(np.asarray(q_a, float)[ia], np.asarray(q_b, float)[ib])
    return _first_time(common, d, limit)


def _safe(trajectory: TrajectoryOf | None, run: dict) -> SavedSamples | None:
    """The run's saved samples from the provider (which says None for an unreadable file: the
    finding then has no time), or None without a provider."""
    return None if trajectory is None else trajectory(run)


def status_findings(runs: list[dict]) -> list[Finding]:
    """failed, diverged, skipped (unsupported version; not installed: once per engine)."""
    out = []
    missing: dict[str, list[dict]] = {}
    for r in runs:
        status, msg = r["status"], (r["message"] or "").strip()
        if status == Status.FAILED:
            out.append(_finding("failed", r, f"failed: {msg or '(no message)'}", source="status"))
        elif status == Status.DIVERGED:
            t = finite_or_none(r["diverged_at_s"])
            size = _metric(r, ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE)
            kind = "reference-diverged" if r["engine"] == REFERENCE_ENGINE else "diverged"
            why = msg.split(": ", 1)[1] if msg.startswith("diverged at") and ": " in msg else msg
            out.append(_finding(kind, r, f"diverged{'' if t is None else f' at t = {t:.4g} s'}"
                                         f"{f': {why}' if why else ''}"
                                         f"{'' if size is None else f' (orientation error before: {_e(size)} rad)'}",
                                size_rad=size, t_s=t, source="status, diverged_at_s"))
        elif status == Status.SKIPPED:
            if r["engine_version"]:
                out.append(_finding("unsupported-version", r, f"skipped: {msg or 'unsupported version'}",
                                    source="status, engine_version"))
            else:
                missing.setdefault(str(r["engine"]), []).append(r)
    for engine, rs in missing.items():
        msg = (rs[0]["message"] or "").strip()
        out.append(Finding(KINDS["not-installed"][0], "not-installed", "", None, engine, engine,
                           f"{len(rs)} runs skipped: {msg or 'not installed'}", source="status"))
    return out


# --- blow-ups, the rotation cap per step, saturated orientations ---------------------------------

def factor(x: float) -> str:
    """A ratio as '797' or '6.5e3' (three digits below 1000, else two in scientific notation)."""
    if x < 1e3:
        return f"{x:.3g}"
    mantissa, exponent = f"{x:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def angle_text(a: float) -> str:
    """An angle as a fraction of pi when it is one ('pi/4'), else in rad ('0.5 rad')."""
    for n in (1, 2, 3, 4, 6, 8):
        if math.isclose(a, math.pi / n, rel_tol=1e-9):
            return "pi" if n == 1 else f"pi/{n}"
    return f"{a:.3g} rad"


def cap_text(run: dict) -> str:
    """'the pi/4 rotation cap per step (|w| dt reaches 1.5 rad from t = 0 s)' of a capped run."""
    g = run[STATE_GROWTH]
    cap = float(g["step_rotation_cap_rad"])
    rot = finite_or_none(g["rotation_per_step_max_rad"])
    reach = "" if rot is None else f"|w| dt reaches {rot:.3g} rad"
    return (f"the {angle_text(cap)} rotation cap per step ({reach}{', ' if reach else ''}beyond "
            f"{cap:.3g} rad from t = {float(g['rotation_cap_t_s']):.4g} s; its conventions: rotation cap)")


def none_text(run: dict, name: str | None = None, sep: str = " (") -> str:
    """How a run that reproduces no map is shown: 'none (closest X)', or 'none (orientation lost)'
    when it is :func:`saturated` (no closest map is named for it); ``sep`` ', ' gives 'none, closest X'."""
    if saturated(run):
        return f"none{sep}orientation lost" + (")" if sep == " (" else "")
    name = name if name is not None else (scheme_key(run) or ("?",))[0]
    return f"none{sep}closest {name}" + (")" if sep == " (" else "")


def _scheme_text(run: dict) -> str:
    """What identification says of a run, for a finding's explanation: 'it reproduces X (summary)',
    'its orientation is lost (...)', 'it reproduces no map (closest X at d rad)', or ''."""
    key = scheme_key(run)
    if key is None:
        return ""
    name, reproduced = key
    if reproduced:
        summary = map_summary(name)
        return f"it reproduces {name}" + (f" ({summary})" if summary else "")
    d = judged(run)["scheme_distance_rad"]
    if saturated(run):
        return (f"its orientation is lost (every map is {_e(d)} rad or more away, beyond "
                f"{tol.CONVERGENCE_ORIENTATION_SATURATED_RAD:g} rad: no distance ranks a scheme)")
    return f"it reproduces no map (closest {name} at {_e(d)} rad)"


def blow_up_findings(runs: list[dict]) -> list[Finding]:
    """Ok runs whose |w| or kinetic energy grew beyond the blow-up bounds (``state_growth``): how far,
    from when, and what identification says of them (the map they reproduce blows up alike: the
    scheme's own instability); a reference map's blow-up is ``reference-blow-up`` (info)."""
    out = []
    for r in runs:
        if not blew_up(r):
            continue
        g = r[STATE_GROWTH]
        w, wr = finite_or_none(g["omega_max_rad_s"]), finite_or_none(g["omega_ratio"])
        ker, t_w = finite_or_none(g["kinetic_energy_ratio"]), finite_or_none(g["omega_max_t_s"])
        t0 = float(g["blow_up_t_s"])
        parts = []
        if w is not None:
            parts.append(f"|w| {w:,.0f} rad/s" + ("" if t_w is None else f" at t = {t_w:.4g} s")
                         + ("" if wr is None else f" ({factor(wr)}x the truth's max)"))
        if ker is not None:
            parts.append(f"kinetic energy x{factor(ker)} the truth's max")
        key = scheme_key(r)
        gyro = key is not None and key[1] and "explicit gyroscopic" in map_summary(key[0])
        text = (f"{'gyroscopic ' if gyro else ''}blow-up: {'; '.join(parts)} (beyond "
                f"{tol.BLOW_UP_OMEGA_FACTOR:g} x |w| or {tol.BLOW_UP_ENERGY_FACTOR:g} x KE from t = {t0:.4g} s)")
        err = _metric(r, ORIENTATION_ERROR_MAX)
        if r["engine"] == REFERENCE_ENGINE:
            out.append(_finding("reference-blow-up", r, text + ": the scheme's own instability on this case",
                                size_rad=err, t_s=t0, source=STATE_GROWTH))
            continue
        why = _scheme_text(r)
        if key is not None and key[1]:
            why += ", which blows up alike: the scheme's own instability, not an engine fault"
        if capped(r):
            why = f"{cap_text(r)} takes it away from every map; {why}"
        if err is not None and err > tol.CONVERGENCE_ORIENTATION_SATURATED_RAD:
            why += f"{'; ' if why else ''}its orientation error {_e(err)} rad measures the blow-up, not a phase error"
        out.append(_finding("blow-up", r, text + (f"; {why}" if why else ""), size_rad=err, t_s=t0,
                            source=STATE_GROWTH))
    return out


def rotation_cap_findings(runs: list[dict]) -> list[Finding]:
    """Ok engine runs whose |w| dt went beyond the rotation per step their engine caps
    (``state_growth``, ``Adapter.step_rotation_cap_rad``): the cap, not the scheme, sets their
    orientation from then on."""
    out = []
    for r in runs:
        if r["engine"] == REFERENCE_ENGINE or not capped(r) or blew_up(r):  # a blow-up's finding names it
            continue
        g = r[STATE_GROWTH]
        why = _scheme_text(r)
        text = (f"{cap_text(r)}: each step turns the body less than |w| dt, while the angular velocity is "
                f"kept; its orientation error {_e(_metric(r, ORIENTATION_ERROR_MAX))} rad is the cap's"
                + (f"; {why}" if why else ""))
        out.append(_finding("rotation-cap", r, text, size_rad=_metric(r, ORIENTATION_ERROR_MAX),
                            t_s=finite_or_none(g["rotation_cap_t_s"]), source=STATE_GROWTH))
    return out


def non_unit_quaternion_findings(runs: list[dict]) -> list[Finding]:
    """Ok runs whose engine handed out quaternions that are not unit (``judgement``: their largest
    |1 - |q|| beyond QUATERNION_NORM_ROUNDOFF of their precision).  The harness uses q / |q|
    wherever a rotation is needed, so the run's other metrics are those of that rotation."""
    out = []
    for r in runs:
        if not judged(r)["non_unit_quaternion"]:
            continue
        x = _metric(r, QUATERNION_NORM_ERROR_MAX)
        bound = tol.QUATERNION_NORM_ROUNDOFF.get(_precision(r), tol.QUATERNION_NORM_ROUNDOFF["float64"])
        text = (f"returns non-unit quaternions: max |1 - |q|| = {_e(x)}, beyond the {_precision(r)} "
                f"round-off {bound:g}; freebody judged the rotation q / |q|, but the engine's state as it "
                f"hands it out is no unit quaternion")
        out.append(_finding("non-unit-quaternion", r, text, source=QUATERNION_NORM_ERROR_MAX))
    return out


# --- expected orders of convergence ----------------------------------------------------------------

# An observed order (the fitted slope of the orientation error over >= 3 dts) this far from the
# expected one is a finding.  Measured on the bundled convergence cases, a scheme in its asymptotic
# range fits within 0.05 of its formal order (first-order maps 0.99-1.01, RK4 4.01-4.02,
# reference rk4 4.02); a load sampled once a step drives a fourth-order scheme to 1.00 on a body
# couple: 3 orders off.  Half an order separates the two.
ORDER_MISMATCH = 0.5
# The results.json run field saying where inside a step the engine evaluated the case's loads
# (reference_impl.sampling: "per-stage" | "per-step"; absent in older results).
PER_STEP = "per-step"


@dataclass(frozen=True)
class ExpectedOrder:
    """The order an engine run's observed order is set against, on one case or several.

    order : the expected order (1 when ``limited``).  scheme_order : the formal order of the maps.
    maps : the maps it comes from (reproduced, or the closest when ``closest``).
    limited : the engine samples the loads once a step (run field ``load_sampling`` "per-step")
        and the case's loads depend on the state: a multi-stage scheme is then first order.
    """

    order: int
    scheme_order: int
    maps: tuple[str, ...]
    closest: bool = False
    limited: bool = False
    own: bool = False  # a reference run: the order of its own integrator (shown without its name)

    @property
    def text(self) -> str:
        """'4 (rkmk4-body)', '1 (closest euler-quat)', '1 (limited by per-step load sampling;
        rkmk4-body is order 4)'."""
        names = " = ".join(self.maps) if len(self.maps) <= TIE_NAMES_SHOWN else f"{self.maps[0]} = ..."
        if self.own:
            return str(self.order)
        if self.limited:
            return f"1 (limited by per-step load sampling; {names} is order {self.scheme_order})"
        return f"{self.order} ({'closest ' if self.closest else ''}{names})"


def state_dependent_loads(cases: dict | None, case: str) -> bool | None:
    """Whether the case's loads depend on the state (a body couple, a force at a point: results.json
    ``cases[case]["state_dependent_loads"]``), None when the document does not say."""
    rec = (cases or {}).get(case)
    v = rec["state_dependent_loads"] if isinstance(rec, dict) else None
    return v if isinstance(v, bool) else None


def expected_order(runs: list[dict], state_dependent: bool | None = None) -> ExpectedOrder | None:
    """The expected order of these runs of one engine run (one case, or several): a reference run's
    integrator's; an engine run's, the order every one of its ok runs' maps share (the maps it
    reproduces, reference integrators and engine-equivalent maps alike, or its closest map when it
    reproduces none and its orientation is not lost), limited to 1 where the engine samples the loads
    per step on a case whose loads depend on the state.  None when the runs' maps have no common
    order (or no run was judged)."""
    ok = [r for r in runs if _ok(r)]
    if not ok:
        return None
    if ok[0]["engine"] == REFERENCE_ENGINE:
        name, o = str(ok[0]["integrator"]), run_order(ok[0])
        return None if o is None else ExpectedOrder(o, o, (name,), own=True)
    common: set[int] | None = None
    order_of: dict[str, int | None] = {}  # the maps in the order first seen -> formal order
    closest = False
    for r in ok:
        maps = judged(r)["order_maps"]  # [] for a run not judged, or whose orientation is lost
        if not maps:
            continue
        closest = closest or not judged(r)["reproduced"]
        orders = {o for _, o in maps if o is not None}
        common = orders if common is None else common & orders
        for n, o in maps:
            order_of.setdefault(n, o)
    if not common or len(common) != 1:
        return None
    o = common.pop()
    maps = tuple(n for n, order in order_of.items() if order == o)
    limited = o > 1 and bool(state_dependent) and any(r["load_sampling"] == PER_STEP for r in ok)
    return ExpectedOrder(1 if limited else o, o, maps, closest, limited)


def order_findings(runs: list[dict], convergence: list[dict] | None,
                   cases: dict | None = None) -> list[Finding]:
    """Engine runs whose observed order of the orientation error (results.json ``convergence``) is
    more than ORDER_MISMATCH from the expected one (:func:`expected_order` over their runs of the
    case): a scheme that is not the one it reproduces in its asymptotic range, or a load sampling
    the map does not model."""
    out = []
    for e in convergence or []:
        if not isinstance(e, dict) or e.get("metric") != ORIENTATION_ERROR_MAX or e.get("engine") == REFERENCE_ENGINE:
            continue
        p = finite_or_none(e.get("order"))
        if p is None:
            continue
        lab = label(e)
        rs = [r for r in runs if r.get("case") == e.get("case") and label(r) == lab]
        exp = expected_order(rs, state_dependent_loads(cases, str(e.get("case"))))
        if exp is None or abs(p - exp.order) <= ORDER_MISMATCH:
            continue
        out.append(Finding(KINDS["order"][0], "order", str(e.get("case")), None, lab,
                           str(e.get("engine", "")),
                           f"observed order {p:.2f} of the orientation error over dt = "
                           f"{', '.join(format(d, 'g') for d in e.get('fitted_dts') or e.get('dts') or [])} s, "
                           f"expected {exp.text}", source="convergence"))
    return out


def no_map_findings(runs: list[dict]) -> list[Finding]:
    """Runs that reproduce no reference map: the closest, its distance and round-off level."""
    out = []
    for r in runs:
        key = scheme_key(r)
        if key is None or key[1]:
            continue
        if blew_up(r):  # its blow-up finding says what identification says
            continue
        name = key[0]
        j = judged(r)
        d, level, ratio = j["scheme_distance_rad"], j["scheme_level_rad"], j["scheme_ratio"]
        cause = f"; cause: {cap_text(r)}" if capped(r) else ""
        if saturated(r):  # before undecidable: no closest map of a lost orientation is named
            out.append(_finding("no-map", r, f"reproduces no map, and its orientation is lost: every map is "
                                             f"{_e(d)} rad or more away (beyond "
                                             f"{tol.CONVERGENCE_ORIENTATION_SATURATED_RAD:g} rad no distance "
                                             f"ranks a scheme){cause}", size_rad=d, source="matches_reference"))
            continue
        if identification.verdict(r["matches_reference"]) == identification.UNDECIDABLE:
            maps = [x for x in r["matches_reference"]["undecidable"] if isinstance(x, str)]
            out.append(_finding("undecidable", r, f"undecidable here: {', '.join(maps) or 'the maps near it'} "
                                                  f"identify nothing on this case (round-off level at "
                                                  f"{tol.SCHEME_ROUNDOFF_LEVEL_MAX_RAD:g} rad, or perturbed copies "
                                                  f"not finite); closest {name} at {_e(d)} rad",
                                size_rad=d, source="matches_reference"))
            continue
        out.append(_finding("no-map", r, f"reproduces no map; closest {name} at {_e(d)} rad"
                                         f"{'' if ratio is None else f', {ratio:.2g} x its round-off level'}"
                                         f"{'' if level is None else f' ({_e(level)} rad)'}{cause}",
                            size_rad=d, source="matches_reference"))
    return out


def disagreement_findings(runs: list[dict], trajectory: TrajectoryOf | None = None) -> list[Finding]:
    """Runs of one scheme group (same case, dt, precision; both reproduce the map) whose final
    orientations differ by more than the sum of their round-off levels of that map."""
    out = []
    for case, case_runs in _by_case(runs).items():
        for g in scheme_groups(case_runs):
            if not g.reproduced:
                continue
            for dt in g.dts():
                ms = g.at(dt)
                for i, a in enumerate(ms):
                    for b in ms[i + 1:]:
                        if _precision(a.run) != _precision(b.run):
                            continue
                        angle = final_angle(a.run, b.run)
                        if angle is None or a.level_rad is None or b.level_rad is None:
                            continue
                        limit = a.level_rad + b.level_rad
                        if angle <= limit:
                            continue
                        ta, tb = _safe(trajectory, a.run), _safe(trajectory, b.run)
                        t0 = _pair_first_time(ta, tb, limit) if ta is not None and tb is not None else None
                        out.append(_finding(
                            "same-map-disagreement", a.run,
                            f"and {b.label} both reproduce {g.scheme}, yet their final orientations differ by "
                            f"{_e(angle)} rad, beyond the sum of their round-off levels ({_e(limit)} rad)",
                            size_rad=angle, t_s=t0, source="final_state, matches_reference.levels_rad",
                            other=b.label))
    return out


def majority_map(rs: list[dict]) -> tuple[str | None, int, int]:
    """(the map most of these runs reproduce (on a tie of counts, the first seen), their number, all)."""
    sets = [scheme_set(r) for r in rs if scheme_key(r) is not None]
    counts: dict[str, int] = {}
    for s in sets:
        for name in s:
            counts[name] = counts.get(name, 0) + 1
    if not counts:
        return None, 0, len(sets)
    best = max(counts, key=lambda k: counts[k])
    return best, counts[best], len(sets)


def switch_findings(runs: list[dict]) -> list[Finding]:
    """Runs that reproduce a map other than the one most runs of their engine run reproduce."""
    out = []
    by_label: dict[str, list[dict]] = {}
    for r in runs:
        if scheme_key(r) is not None:
            by_label.setdefault(label(r), []).append(r)
    for lab, rs in by_label.items():
        best, n, total = majority_map(rs)
        if best is None or n == total:
            continue
        for r in rs:
            key = scheme_key(r)
            undecided = r["matches_reference"]["undecidable"]  # its usual map may still be it here
            if key[1] and best not in scheme_set(r) and best not in undecided:
                cause = f"; cause: {cap_text(r)}" if capped(r) else ""
                out.append(_finding("scheme-switch", r, f"reproduces {key[0]} here; {n} of its {total} runs "
                                                        f"reproduce {best}{cause}", size_rad=map_distance(r["matches_reference"], best),
                                    source="matches_reference"))
    return out


def outlier_findings(runs: list[dict], trajectory: TrajectoryOf | None = None) -> list[Finding]:
    """Engine runs whose orientation error max is OUTLIER_FACTOR times the median of the other
    engines' runs of the same or lower formal order at the same case, dt and precision (the
    reference maps' runs when no other engine ran), floored at the truth's accuracy."""
    out = []
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        if _ok(r) and _metric(r, ORIENTATION_ERROR_MAX) is not None:
            groups.setdefault((r["case"], float(r["dt"]), _precision(r)), []).append(r)
    for (case, dt, precision), rs in groups.items():
        for r in rs:
            if r["engine"] == REFERENCE_ENGINE or blew_up(r):  # a blow-up's finding gives its error
                continue
            order = run_order(r)
            peers = [p for p in rs if p["engine"] not in (r["engine"], REFERENCE_ENGINE)]
            whose = "the other engines' runs"
            if not peers:
                peers, whose = [p for p in rs if p["engine"] == REFERENCE_ENGINE], "the reference maps' runs"
            peers = [p for p in peers if order is None or run_order(p) is None or run_order(p) <= order]
            if not peers:
                continue
            err = _metric(r, ORIENTATION_ERROR_MAX)
            median = float(np.median([_metric(p, ORIENTATION_ERROR_MAX) for p in peers]))
            base = max(median, OUTLIER_FLOOR_RAD.get(precision, OUTLIER_FLOOR_RAD["float64"]))
            if err <= OUTLIER_FACTOR * base:
                continue
            traj = _safe(trajectory, r)
            t0 = None
            if traj is not None:
                t, e = _error_series(traj)
                t0 = _first_time(t, e, OUTLIER_FACTOR * base)
            key = scheme_key(r)
            if capped(r):  # the mechanism, then the map it happens to reproduce with it
                why = f"cause: {cap_text(r)}" + (f"; it reproduces {key[0]} here" if key and key[1] else "")
            elif key is None:
                why = "no scheme identified"
            elif key[1]:
                summary = map_summary(key[0])
                why = f"it reproduces {key[0]}" + (f": {summary}" if summary else "")
            elif saturated(r):
                why = "its orientation is lost (every map is as far: no distance ranks a scheme)"
            else:
                why = f"reproduces no map (closest {key[0]})"
            floored = "" if median >= base else f", floored at the truth's accuracy {base:g} rad"
            out.append(_finding(
                "outlier", r,
                f"orientation error {_e(err)} rad, {err / base:.2g} x the median of {whose} of the same or "
                f"lower order ({_e(median)} rad, {len(peers)} runs{floored}); {why}",
                size_rad=err, t_s=t0, source=ORIENTATION_ERROR_MAX))
    return out


def vs_engine_findings(runs: list[dict]) -> list[Finding]:
    """Ported engines against their original (``vs_engine``): beyond the run's round-off level
    (of its closest map: the level of its precision), or not compared."""
    out = []
    for r in runs:
        v = r["vs_engine"]
        if not isinstance(v, dict) or not _ok(r):
            continue
        other = f"{v['engine']}/{v['integrator']}"
        if v.get("message"):  # optional: the comparison could not be made
            out.append(_finding("vs-engine-unavailable", r, f"not compared with {other}: {v['message']}",
                                source="vs_engine", other=other))
            continue
        d = finite_or_none(v["max_orientation_diff_rad"])
        key = scheme_key(r)
        level = judged(r)["scheme_level_rad"] if key else None
        limit = level if level is not None else tol.SCHEME_ROUNDOFF_FLOOR_RAD
        if d is None:
            out.append(_finding("vs-engine-unavailable", r, f"its difference from {other} is not finite",
                                source="vs_engine", other=other))
        elif d > limit:
            final = finite_or_none(v["final_orientation_diff_rad"])
            out.append(_finding("vs-engine", r, f"differs from {other} by up to {_e(d)} rad (final {_e(final)} rad), "
                                                f"beyond its round-off level ({_e(limit)} rad)",
                                size_rad=d, source="vs_engine", other=other))
    return out


def _by_case(runs: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in runs:
        out.setdefault(r["case"], []).append(r)
    return out


def find(runs: list[dict], trajectory: TrajectoryOf | None = None, convergence: list[dict] | None = None,
         cases: dict | None = None) -> list[Finding]:
    """Every finding of a results document's runs, most severe first, then by kind, case (in run
    order), dt (coarsest first) and run.  A run that is an ``outlier`` is not also listed as a
    ``scheme-switch`` (its outlier finding names the map it reproduces) nor as a ``rotation-cap``
    (its outlier finding names the cap).  ``convergence`` (results.json's fitted orders) and
    ``cases`` (results.json ``cases``): the ``order`` findings, none without them."""
    found = (status_findings(runs) + blow_up_findings(runs) + no_map_findings(runs)
             + disagreement_findings(runs, trajectory) + outlier_findings(runs, trajectory)
             + vs_engine_findings(runs) + order_findings(runs, convergence, cases)
             + non_unit_quaternion_findings(runs))
    from .version_findings import version_findings  # it imports this module

    found += version_findings(runs, convergence)
    outliers = {(f.case, f.dt, f.label) for f in found if f.kind == "outlier"}
    found += [f for f in switch_findings(runs) + rotation_cap_findings(runs)
              if (f.case, f.dt, f.label) not in outliers]
    cases = {c: i for i, c in enumerate(dict.fromkeys(r["case"] for r in runs))}
    kinds = {k: i for i, k in enumerate(KINDS)}
    found.sort(key=lambda f: (SEVERITIES.index(f.severity), kinds[f.kind], cases.get(f.case, -1),
                              -(f.dt or 0.0), f.label))
    return found


@dataclass(frozen=True)
class FindingLine:
    """Findings of one kind about one engine run, shown as one line of the findings list."""

    severity: str
    kind: str
    label: str
    items: tuple[Finding, ...]


def summarize(findings: list[Finding], separate: int = 3) -> list[FindingLine]:
    """The findings list: findings of one kind about one engine run on one line when there are
    more than ``separate`` of them (e.g. a reference map that diverges on 13 cases), else one line
    each; in the order of ``findings``."""
    by: dict[tuple[str, str], list[Finding]] = {}
    for f in findings:
        by.setdefault((f.kind, f.label), []).append(f)
    out, seen = [], set()
    for f in findings:
        key = (f.kind, f.label)
        items = by[key]
        if len(items) > separate:
            if key not in seen:
                seen.add(key)
                out.append(FindingLine(f.severity, f.kind, f.label, tuple(items)))
        else:
            out.append(FindingLine(f.severity, f.kind, f.label, (f,)))
    return out


def where(f: Finding) -> str:
    """'case dt = 0.01 s' of a finding ('' for one about no particular run)."""
    if not f.case:
        return ""
    return f.case + ("" if f.dt is None else f" dt = {f.dt:g} s")


def numbers(f: Finding) -> str:
    """The finding's numbers: 'size 3.1e+00 rad, from t = 0.01 s' (parts that are known)."""
    parts = []
    if f.size_rad is not None and math.isfinite(f.size_rad):
        parts.append(f"size {_e(f.size_rad)} rad")
    if f.t_s is not None:
        parts.append(f"from t = {f.t_s:.4g} s")
    return ", ".join(parts)


# --- what the verdict page shows ---------------------------------------------------------------------

# Kinds whose finding points at the engine's conventions (a trap or scheme of that engine).
CONVENTION_KINDS = ("outlier", "no-map", "scheme-switch", "same-map-disagreement", "diverged", "failed",
                    "rotation-cap", "blow-up", "order",
                    "vs-engine", "non-unit-quaternion")


def counts(findings: list[Finding]) -> dict[str, int]:
    """severity -> number of findings."""
    return {s: sum(f.severity == s for f in findings) for s in SEVERITIES}


def counts_text(findings: list[Finding]) -> str:
    """'0 errors, 3 warnings, 13 info'."""
    return ", ".join(f"{n} {s}{'' if n == 1 or s == 'info' else 's'}" for s, n in counts(findings).items())


def group_error(group: SchemeGroup, dt: float) -> str:
    """The orientation error max of a group's runs at one dt: one number when they agree to 3
    digits, else 'lowest - highest'."""
    errs = [m.error_rad for m in group.at(dt) if m.error_rad is not None]
    if not errs:
        return "-"
    lo, hi = min(errs), max(errs)
    return format(lo, ".3e") if format(lo, ".3e") == format(hi, ".3e") else f"{lo:.3e} - {hi:.3e}"


def member_text(m: Member) -> str:
    """'3.1e-10 (r 0.004)': a member's distance to its group's map and its ratio to round-off."""
    return _e(m.distance_rad) + ("" if m.ratio is None else f" (r {m.ratio:.2g})")


VERDICT_NOTE = ("Per case, the engine runs grouped by the reference map they reproduce (to round-off, at every "
                "sample) or, reproducing none, come closest to; per dt, each run's largest distance from "
                "the group's map (rad) and r, that distance over the map's round-off level (r <= 1: "
                "reproduces), and the group's orientation error max against the truth.  The runs of one "
                "group share their scheme, so a difference between them beyond round-off is an engine's "
                "(a finding); between groups the difference is the schemes'.  The reference engine's "
                "runs are the maps themselves (see each case's Runs).")
BETWEEN_NOTE = ("Between groups: the largest angle between the final orientations of a run of each group "
                "(rad), per dt; two groups whose ties share a map (every run of both reproduces it) agree "
                "to round-off on this case.")
FINDINGS_NOTE = ("Computed from the runs (nothing is written by hand per engine): a run reproducing no map, "
                 "runs of one map that disagree, an orientation error far above the other engines' "
                 "(x{:g} the median of the runs of the same or lower order at that case and dt), a run "
                 "that reproduces another map on one case, ported engines against their original, a |w| or "
                 "kinetic energy that blew up beyond {:g}x / {:g}x the truth's, a rotation per step beyond "
                 "the engine's cap, an observed order more than {:g} from the expected one, a scheme, order "
                 "or default that changed between two versions of an engine, runs that no map can "
                 "identify on their case (undecidable), and runs that failed, diverged or were skipped.  Each names the results field that raised it "
                 "and links to the run's plots.").format(OUTLIER_FACTOR, tol.BLOW_UP_OMEGA_FACTOR,
                                                          tol.BLOW_UP_ENERGY_FACTOR, ORDER_MISMATCH)
NO_FINDINGS = ("No finding: every engine run reproduces a reference map, runs of one map agree, no error "
               "stands out, and every run finished.")


def between_table(groups: list[SchemeGroup]) -> tuple[list[str], list[list[str]]]:
    """(columns, rows) of a case's between-groups table: one row per two groups, attributed to the
    scheme ('differs by scheme (A vs B)', or 'agree to round-off here (A ~ B)' when their ties share
    a map), with their largest final-orientation angle per dt.  ([], []) with fewer than two
    groups."""
    pairs = between_groups(groups)
    if not pairs:
        return [], []
    dts = sorted({p.dt for p in pairs}, reverse=True)
    rows: dict[tuple[str, str], dict] = {}
    for p in pairs:
        row = rows.setdefault((p.a.name, p.b.name), {"pairs": []})
        row["pairs"].append(p)
        row[p.dt] = _e(p.angle_rad)
    columns = ["between groups", *(f"dt = {d:g} s: final orientations apart (rad)" for d in dts)]
    return columns, [[row["pairs"][0].attribution, *(row.get(d, "") for d in dts)] for row in rows.values()]
