"""The numbers a report shows, prepared from a results.json document (no plotting, no markup).

Everything here tolerates any run of any engine in any status: a value that is null or non-finite
becomes None (shown as "-"), never a NaN in a table or a plot.  A run has every key of the newest
schema (:func:`freebody.results.document.load_results` migrates what it reads; see
:data:`freebody.results.document.RUN_DEFAULTS`): a run built by hand passes through
``load_results`` (or has the keys itself).  Optional keys of the newest schema are read with
``.get``: the document's ``cases`` and ``convergence``, a case record's fields, a metric, a
final state's, an engine setting's and a ``vs_engine``'s fields, a convergence entry's.
"""
from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..adapters.base import REFERENCE_ENGINE
from ..errors import InputError
from ..numbers import finite_or_none
from ..reference_impl.conventions import angular_momentum, kinetic_energy, potential_energy
from ..reference_impl.problem import Body
from ..reference_impl.rotations import geodesic_angle
from ..run.metrics import ORIENTATION_ERROR_MAX
from ..run.records import STATUSES, Status
from .summary import reproduced_text, run_label
from ..results import identification

STATUS_ORDER = (Status.FAILED, Status.DIVERGED, Status.SKIPPED, Status.OK)  # worst first


def num(x, spec: str = ".3e") -> str:
    """A number in a fixed format (so text survives last-digit noise), '-' when not a finite number."""
    x = finite_or_none(x)
    return "-" if x is None else format(x, spec)


def label(run: dict) -> str:
    """engine/integrator[/precision]: one engine run across cases and time steps (of a run, or of
    a convergence entry, whose ``precision`` is optional)."""
    return run_label({**run, "precision": run.get("precision") or "float64"})


def metric(run: dict, key: str) -> float | None:
    return finite_or_none(run["metrics"].get(key))


def simulated_s(run: dict) -> float | None:
    """Simulated time of a run, s: steps * dt."""
    steps, dt = finite_or_none(run["steps"]), finite_or_none(run["dt"])
    return steps * dt if steps and dt else None


def wall_per_simulated_s(run: dict) -> float | None:
    """Wall-clock seconds per simulated second (lower is faster); None for a run that did not run."""
    if run["status"] in (Status.SKIPPED, Status.FAILED):
        return None
    wall, sim = finite_or_none(run["wall_time_s"]), simulated_s(run)
    return wall / sim if wall is not None and wall > 0 and sim else None


def reproduces(run: dict) -> str:
    """The reference map this engine run reproduces ('' for the reference engine / no check), and
    for a loaded run where inside a step its engine evaluated the loads (``load_sampling``: the
    maps it was compared with are that variant)."""
    m = run["matches_reference"]
    if not isinstance(m, dict):
        return ""
    text = _reproduces(run, m)
    sampling = run["load_sampling"]
    return f"{text} [loads {sampling}]" if sampling and text else text


def _reproduces(run: dict, m: dict) -> str:
    if identification.reproduced(m):
        return f"{reproduced_text(m, run['precision'])} ({num(m['max_orientation_diff_rad'], '.1e')} rad)"
    from .findings import saturated

    if saturated(run):  # every map is as far: no closest map is named
        return f"none (orientation lost: every map >= {num(m['max_orientation_diff_rad'], '.1e')} rad)"
    if identification.verdict(m) == identification.UNDECIDABLE:
        return identification.text(m)
    if m["closest"]:
        return f"none (closest {m['closest']}, {num(m['max_orientation_diff_rad'], '.1e')} rad)"
    return "none"


def by_case(runs: list[dict]) -> dict[str, list[dict]]:
    """Runs grouped by case, cases and runs in their order of appearance."""
    out: dict[str, list[dict]] = {}
    for r in runs:
        out.setdefault(r["case"], []).append(r)
    return out


def _anchor_text(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text)


def case_anchor(case: str) -> str:
    """The id of a case's section in report.html."""
    return "case-" + _anchor_text(case)


def figure_anchor(case: str, dt: float) -> str:
    """The id of a case's figure at one dt in report.html (the plots of its runs at that dt)."""
    return f"fig-{_anchor_text(case)}-dt{float(dt):g}"


def run_anchor(run: dict) -> str:
    """The id of a run's row in its case's Runs table in report.html."""
    return f"run-{_anchor_text(run['case'])}-{_anchor_text(label(run))}-dt{float(run['dt']):g}"


# report.html's per-case Runs and engine-vs-engine tables go to this page next to it (the same
# folder) when their markup exceeds TABLES_INLINE_MAX_BYTES (issue 29: report.html <= 4 MB for the
# default suite, whose figures take 3.3 MB of it and whose tables 2.3 MB): each case section of
# report.html then points to its tables there, and links to a run's row lead there.
TABLES_PAGE = "report-tables.html"
TABLES_INLINE_MAX_BYTES = 500_000


def tables_anchor(case: str) -> str:
    """The id of a case's tables in :data:`TABLES_PAGE`."""
    return "tables-" + _anchor_text(case)


def anchor_href(anchor: str, tables: str | None, home: str = "") -> str:
    """The href of a report anchor: ``home`` + ``#anchor`` ("": a link in report.html itself,
    "report.html": from report.md), but a run's row (``run-...``) is on the page ``tables`` when
    the tables are apart (not None)."""
    return f"{tables if tables is not None and anchor.startswith('run-') else home}#{anchor}"


def conventions_anchor(engine: str) -> str:
    """The id of an engine's rows in the "Engine conventions and traps" section of report.html."""
    return "conventions-" + _anchor_text(engine)


def labels(runs: list[dict]) -> list[str]:
    """Distinct engine-run labels in order of appearance."""
    return list(dict.fromkeys(label(r) for r in runs))


def dts(runs: list[dict]) -> list[float]:
    """Distinct time steps, descending (coarsest first)."""
    return sorted({float(r["dt"]) for r in runs if finite_or_none(r["dt"])}, reverse=True)


def status_counts(runs: list[dict]) -> dict[str, int]:
    return {s: sum(r["status"] == s for r in runs) for s in STATUSES}


# --- the body of a case (for L and E from states) -------------------------------------------------

@dataclass(frozen=True)
class CasePhysics:
    """What a report needs of a case to compute L and E: the subset of a Problem that
    :func:`freebody.run.metrics.series` reads (``body``, ``gravity``) plus its description.

    body : Body (mass kg, I_body (3, 3) kg m^2, COM, body frame).  gravity : (3,) m/s^2, world.
    """

    name: str
    description: str
    truth: str
    body: Body
    gravity: np.ndarray
    defaults: tuple[str, ...] = ()  # optional case-file keys left out (results.json cases.<name>.defaults)

    def lines(self) -> list[str]:
        """The case's description, truth and the keys it left to their defaults, as report lines."""
        out = [self.description or "(no description)", "", f"Truth: {self.truth or '?'}."]
        if self.defaults:
            named = [f"{k} (no [world]: no gravity)" if k == "world.gravity" else k for k in self.defaults]
            out += ["", "Left to their defaults in the case file: " + ", ".join(named) + "."]
        return out


def state_dependent(problem) -> bool:
    """Whether any of the case's loads depends on the state: a body-frame couple (R tau_b) or a
    force at a point ((R b) x f at a body point, (p - x) x f at a world point)."""
    return any(np.any(ld.body_torque) or (np.any(ld.force) and (ld.point is not None or ld.body_point is not None))
               for ld in problem.loads)


def case_record(problem, truth: str) -> dict:
    """The results.json ``"cases"`` entry of a Problem: enough to recompute L and E from states."""
    return {"description": problem.description, "truth": truth, "mass": float(problem.body.mass),
            "inertia": np.asarray(problem.body.I_body, dtype=float).tolist(),
            "gravity": np.asarray(problem.gravity, dtype=float).tolist(),
            "torque_free": bool(problem.torque_free), "dts": list(problem.dts),
            "state_dependent_loads": state_dependent(problem),
            "duration": problem.duration, "duration_steps": problem.duration_steps}


def case_physics(doc: dict, case: str, problems: dict | None = None) -> CasePhysics | None:
    """The case's body and gravity: from ``problems`` (name -> Problem), else results.json's
    ``"cases"``, else the bundled case of that name; None when none of these knows the case."""
    rec = (doc.get("cases") or {}).get(case)  # optional: an interrupted run's results have none
    # defaults: null when unknown (written before schema 3), absent when the run was not told
    defaults = tuple(str(k) for k in rec.get("defaults") or ()) if isinstance(rec, dict) else ()
    if problems and case in problems:
        pb = problems[case]
        from ..reference_impl.truth import truth_kind

        return CasePhysics(case, pb.description, truth_kind(pb), pb.body, np.asarray(pb.gravity, float), defaults)
    if isinstance(rec, dict):
        try:
            body = Body(float(rec["mass"]), np.asarray(rec["inertia"], dtype=float))
            g = np.asarray(rec.get("gravity", [0.0, 0.0, 0.0]), dtype=float).reshape(3)
            if body.mass > 0 and np.all(np.isfinite(body.I_body)) and np.all(np.isfinite(g)):
                return CasePhysics(case, str(rec.get("description", "")), str(rec.get("truth", "")), body, g,
                                   defaults)
        except (KeyError, TypeError, ValueError):
            pass
    from ..input.casefile import bundled_case_paths, load_case

    if case in bundled_case_paths():
        from ..reference_impl.truth import truth_kind

        pb = load_case(case)
        return CasePhysics(case, pb.description, truth_kind(pb), pb.body, np.asarray(pb.gravity, float))
    return None


# --- engine-vs-engine at the end ----------------------------------------------------------------

@dataclass(frozen=True)
class Pair:
    """Two engine runs of one case at one dt, compared at their final state.

    angle_rad : geodesic angle between the final orientations, rad.
    dL_rel : |L_a - L_b| / mean(|L_a|, |L_b|) (world, about the COM), or None.
    dE_rel : |E_a - E_b| / mean(KE_a, KE_b), or None.
    relation : whether both reproduce the same reference map or differ by scheme (see
        :func:`freebody.report.findings.pair_relation`).
    """

    dt: float
    a: str
    b: str
    angle_rad: float | None
    dL_rel: float | None
    dE_rel: float | None
    relation: str = ""  # 'same map (X)' or 'differs by scheme (A vs B)' (findings.pair_relation)


def _final(run: dict, out_dir: Path | None) -> dict | None:
    """The final state of an ok run: its results.json final_state, else the last trajectory sample."""
    if run["status"] != Status.OK:
        return None
    fs = run["final_state"]
    if isinstance(fs, dict) and fs.get("quaternion_wxyz") is not None:
        return fs
    if out_dir is not None and run["trajectory"]:
        from ..results.document import load_trajectory, trajectory_max_bytes, trajectory_path

        try:
            tr, _ = load_trajectory(trajectory_path(Path(out_dir), run["trajectory"]), trajectory_max_bytes(run))
            return tr.state(-1).as_dict()
        except (OSError, KeyError, ValueError, IndexError, InputError):  # InputError: FileRefused
            return None
    return None


def _state_arrays(fs: dict) -> tuple[np.ndarray, ...] | None:
    try:
        arrs = tuple(np.asarray(fs[k], dtype=float) for k in
                     ("quaternion_wxyz", "angular_velocity", "linear_velocity", "position"))
    except (KeyError, TypeError, ValueError):
        return None
    if any(a.shape != s for a, s in zip(arrs, ((4,), (3,), (3,), (3,)))) or not all(
            np.all(np.isfinite(a)) for a in arrs):
        return None
    return arrs


def pair_runs(runs: list[dict]) -> list[tuple[dict, dict]]:
    """Pairs of runs of different engines at the same dt and precision.  The reference engine is
    left out when two or more other engines ran (its relation to each engine is the
    'reproduces' column)."""
    engines = {r["engine"] for r in runs if r["status"] == Status.OK}
    skip_ref = len(engines - {REFERENCE_ENGINE}) >= 2
    chosen = [r for r in runs if not (skip_ref and r["engine"] == REFERENCE_ENGINE)]
    out = []
    for i, a in enumerate(chosen):
        for b in chosen[i + 1:]:
            if (a["engine"] != b["engine"] and a["dt"] == b["dt"]
                    and a["precision"] == b["precision"]):
                out.append((a, b))
    return out


def _end_quantities(fs: dict, physics: CasePhysics | None):
    """(q (4,), L (3,) kg m^2/s world or None, E J or None, KE J or None) of a final state, or None."""
    arrs = _state_arrays(fs)
    if arrs is None:
        return None
    q, w, v, x = arrs
    if physics is None:
        return q, None, None, None
    M, I_b = physics.body.mass, physics.body.I_body
    ke = float(kinetic_energy(M, I_b, q, v, w))
    return q, angular_momentum(I_b, q, w), ke + float(potential_energy(M, physics.gravity, x)), ke


def pairwise(runs: list[dict], physics: CasePhysics | None, out_dir: Path | None = None) -> list[Pair]:
    """Engine-vs-engine differences at the end of one case's runs: per dt (coarsest first), the
    pairs of runs that reproduce the same reference map first (there a difference beyond round-off
    is an engine's, not a scheme's), then the pairs that differ by scheme, each largest angle first
    (pairs whose angle is undefined last); only ok runs take part."""
    from .findings import pair_relation

    finals = {id(r): _final(r, out_dir) for r in runs}
    ends = {k: (_end_quantities(fs, physics) if fs is not None else None) for k, fs in finals.items()}
    rows = []
    for a, b in pair_runs([r for r in runs if finals[id(r)] is not None]):
        ea, eb = ends[id(a)], ends[id(b)]
        relation = pair_relation(a, b)
        if ea is None or eb is None:
            rows.append(Pair(float(a["dt"]), label(a), label(b), None, None, None, relation))
            continue
        angle = finite_or_none(geodesic_angle(ea[0], eb[0]))
        dL = dE = None
        if physics is not None:
            scale = 0.5 * (np.linalg.norm(ea[1]) + np.linalg.norm(eb[1]))
            dL = finite_or_none(np.linalg.norm(ea[1] - eb[1]) / scale) if scale > 0 else None
            kscale = 0.5 * (ea[3] + eb[3])
            dE = finite_or_none(abs(ea[2] - eb[2]) / kscale) if kscale > 0 else None
        rows.append(Pair(float(a["dt"]), label(a), label(b), angle, dL, dE, relation))
    rows.sort(key=lambda p: (-p.dt, not p.relation.startswith("same map"), p.angle_rad is None,
                             -(p.angle_rad or 0.0), p.a, p.b))
    return rows


# --- front page ---------------------------------------------------------------------------------

def error_cells(runs: list[dict]) -> dict[float, dict[tuple[str, str], tuple[str, float | None]]]:
    """dt -> {(case, label): (status, orientation_error_max_rad of the ok run, else None)}, dts
    coarsest first: the heat map's panels, one per time step (no maximum over time steps, where
    the coarsest would hide the others)."""
    out: dict[float, dict] = {}
    for r in runs:
        dt = finite_or_none(r["dt"])
        if dt is None:
            continue
        status = r["status"]
        v = metric(r, ORIENTATION_ERROR_MAX) if status == Status.OK else None
        cell = out.setdefault(float(dt), {})
        key = (r["case"], label(r))
        rank = STATUS_ORDER.index(status) if status in STATUS_ORDER else 0
        old = cell.get(key)
        if old is None or rank < (STATUS_ORDER.index(old[0]) if old[0] in STATUS_ORDER else 0):
            cell[key] = (status, v)  # two runs of a cell (not made by freebody run): the worst shows
    return {dt: out[dt] for dt in sorted(out, reverse=True)}


def _show(v) -> str:
    if isinstance(v, float):
        return format(v, "g") if math.isfinite(v) else "-"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_show(x) for x in v) + "]"
    return str(v)


def _settings_table(runs: list[dict]) -> dict[tuple[str, str], tuple[dict, dict, bool]]:
    """(engine, setting) -> (distinct defaults, distinct values set, changed on some run)."""
    table: dict[tuple[str, str], tuple[dict, dict, list]] = {}
    for r in runs:
        for key, val in sorted(r["engine_settings"].items()):
            defaults, sets, changed = table.setdefault((r["engine"], key), ({}, {}, [False]))
            if isinstance(val, dict) and ("default" in val or "set" in val):
                d, v = _show(val.get("default")), _show(val.get("set"))
                defaults[d] = None
                sets[v] = None
                changed[0] = changed[0] or d != v
            else:  # another shape: shown as it is
                sets[_show(val)] = None
                changed[0] = True
    return {k: (d, v, c[0]) for k, (d, v, c) in table.items()}


def settings_forced(runs: list[dict]) -> list[tuple[str, str, str, str]]:
    """(engine, setting, engine default, value(s) set) for every setting an adapter changed: set
    to a value other than the engine's default on at least one run.

    ``engine_settings`` entries are ``{key: {"default": d, "set": v}}``; other shapes are shown as
    they are.  Distinct values across runs are joined with ', '.  Settings freebody sets to the
    engine's own default on every run are left out (:func:`settings_unchanged` counts them).
    """
    return [(e, k, ", ".join(d) or "-", ", ".join(v) or "-")
            for (e, k), (d, v, changed) in _settings_table(runs).items() if changed]


def settings_unchanged(runs: list[dict]) -> int:
    """How many (engine, setting) freebody sets, on every run, to the engine's default value."""
    return sum(not changed for _, _, changed in _settings_table(runs).values())


def settings_note(runs: list[dict]) -> str:
    """The line under the settings table: the settings left out as unchanged."""
    n = settings_unchanged(runs)
    return (f"Only settings set to a value other than the engine's default are listed; {n} more "
            f"(engine, setting) pair{' is' if n == 1 else 's are'} set to the default value itself "
            f"(no change)." if n else "")


REPRODUCTION_COLUMNS = ("engine run", "reproduces", "runs", "elsewhere (case dt: map)", "max distance (rad)")


def reproduction_summary(runs: list[dict]) -> list[tuple[str, str, str, str, float | None]]:
    """One row per non-reference engine run whose scheme was identified: (engine run, the map most
    of its ok runs reproduce (or 'none'), 'n of N', the runs that reproduce another map or none
    ('case dt: map', with the case's name), the largest distance (rad) of its runs from the maps
    they reproduce or come closest to)."""
    from .findings import majority_map, none_text, saturated, scheme_key, scheme_set

    by_label: dict[str, list[dict]] = {}
    for r in runs:
        if scheme_key(r) is not None:
            by_label.setdefault(label(r), []).append(r)
    out = []
    for lab, rs in by_label.items():
        best, n, total = majority_map(rs)
        other = []
        for r in rs:
            if best is None or best not in scheme_set(r):
                name, reproduced = scheme_key(r)
                undecided = identification.verdict(r["matches_reference"]) == identification.UNDECIDABLE \
                    and not saturated(r)
                other.append(f"{r['case']} {float(r['dt']):g}: {name if reproduced else f'undecidable (closest {name})' if undecided else none_text(r, name)}")
        shown = best or "none"
        if best is not None:  # maps indistinguishable from it on every run that reproduces it: a tie
            sets = [scheme_set(r) for r in rs if best in scheme_set(r)]
            tie = [x for x in sets[0] if all(x in s_ for s_ in sets)]
            shown = f"tie: {' = '.join(tie)}" if len(tie) >= 2 else best
        dists = [finite_or_none(r["matches_reference"]["max_orientation_diff_rad"]) for r in rs
                 if r["matches_reference"]]
        dists = [d for d in dists if d is not None]
        out.append((lab, shown, f"{n if best else 0} of {total}", "; ".join(other) or "-",
                    max(dists) if dists else None))
    return out


PORT_COLUMNS = ("case", "engine run", "dt", "against", "max orientation diff (rad)",
                "final orientation diff (rad)", "own max error vs truth (rad)")


def port_comparison(runs: list[dict]) -> list[tuple]:
    """Rows comparing ported engines' runs (e.g. MJX) with their original engine's float64 run of
    the same integrator and dt (the run's ``vs_engine``), in run order."""
    rows = []
    for r in runs:
        v = r["vs_engine"]
        if not isinstance(v, dict):
            continue
        against = f"{v.get('engine')}/{v.get('integrator')}"
        if v.get("message"):
            rows.append((r["case"], label(r), f"{r['dt']:g}", against, v["message"], "-", "-"))
            continue
        rows.append((r["case"], label(r), f"{r['dt']:g}", against, num(v.get("max_orientation_diff_rad")),
                     num(v.get("final_orientation_diff_rad")), num(metric(r, ORIENTATION_ERROR_MAX))))
    return rows


def engine_versions(doc: dict) -> list[tuple[str, str, int]]:
    """(engine, version or 'not installed', number of runs) for every engine of the document."""
    runs = doc["runs"]
    versions = dict(doc.get("engines") or {})  # a report page of runs alone (no document) has none
    for r in runs:
        versions.setdefault(r["engine"], r["engine_version"])
    return [(e, str(v) if v else "not installed", sum(r["engine"] == e for r in runs))
            for e, v in versions.items()]


CONVENTIONS_NOTE = ("Each engine's conventions and the traps its adapter handles, as the run's adapters "
                    "stated them (results.json `conventions`; for an older results.json, as this "
                    "freebody's adapters state them: `freebody conventions --engine NAME` shows them "
                    "with their live self-checks); an engine that is not installed here, or that ran "
                    "in an isolated environment, is listed without them.")


def engine_conventions(doc: dict) -> list[tuple[str, str, str]]:
    """(engine, convention, text) for every engine of the document: as the run recorded them
    (results.json ``conventions``, schema 7: no engine imported), else from its adapter when it
    loads here (the adapter's ``conventions``), else one row saying why not."""
    from ..adapters.base import base_engine, is_available, is_plugin, load_adapter, split_engine_name
    from ..adapters.capture import capture_output

    out = []
    recorded = doc.get("conventions") if isinstance(doc.get("conventions"), dict) else {}
    for engine, _, _ in engine_versions(doc):
        rows = recorded.get(engine)
        if isinstance(rows, list) and rows and all(isinstance(r, list) and len(r) == 2 for r in rows):
            out += [(engine, str(k), str(v)) for k, v in rows]
            continue
        if is_plugin(engine):  # a third party's module: the report imports none (its import may hang)
            out.append((engine, "-", f"a plug-in, not imported by the report: see freebody conventions "
                                     f"--engine {engine}"))
            continue
        try:
            if split_engine_name(engine)[1] or not is_available(engine):
                raise LookupError
            from ..run.suite import convention_rows

            with capture_output():
                rows = convention_rows(load_adapter(base_engine(engine)))  # load sampling last
        except Exception:
            out.append((engine, "-", "not installed here (or run in an isolated environment): see "
                                     f"freebody conventions --engine {engine}"))
            continue
        out += [(engine, k, str(v)) for k, v in rows]
    return out


# --- observed order of convergence per engine run (the front page) ---------------------------------

ORDER_FIT_COLUMN = "worst fit rms (decades)"
ORDER_EXPECTED_COLUMN = "expected p"


def _order_cell(entry: dict | None) -> str:
    """One fitted order as the table shows it: 'p' (2 decimals), 'sat.' (saturated), '-' (none)."""
    if entry is None:
        return "-"
    p = finite_or_none(entry.get("order"))
    return format(p, ".2f") if p is not None else ("sat." if entry.get("saturated") else "-")


def expected_order(runs: list[dict], cases: dict | None = None) -> str:
    """The expected order of these runs of one engine run (over the cases they ran), '' when
    unknown: :func:`freebody.report.findings.expected_order` per case (the map it reproduces or
    comes closest to, engine-equivalent maps included; 1 where per-step load sampling limits it on
    a case whose loads depend on the state, results.json ``cases``): the text of the most common
    one, then each case whose expected order (or its limitation) differs ('4 (rkmk4-body);
    convergence_body_torque: 1 (limited by per-step load sampling; ...)')."""
    from .findings import expected_order as expected, state_dependent_loads

    per_case = {}
    for case in dict.fromkeys(r["case"] for r in runs):
        e = expected([r for r in runs if r["case"] == case], state_dependent_loads(cases, str(case)))
        if e is not None:
            per_case[str(case)] = e
    if not per_case:
        return ""
    kinds = [(e.order, e.limited) for e in per_case.values()]
    common = max(dict.fromkeys(kinds), key=kinds.count)
    first = next(e for e in per_case.values() if (e.order, e.limited) == common)
    others = [f"{c}: {e.text}" for c, e in per_case.items() if (e.order, e.limited) != common]
    return "; ".join([first.text, *others])


def observed_orders(convergence: list[dict], runs: list[dict],
                    case_records: dict | None = None) -> tuple[list[str], list[list[str]]]:
    """(columns, rows) of the front page's "Observed order" table: one row per engine run (engine,
    integrator, precision) that ran a case at 3 or more time steps; per such case the fitted order
    of the orientation error and of the energy error ("p_orientation / p_energy", see
    :func:`_order_cell`); the largest ``fit_rms_decades`` of those fits; and
    :func:`expected_order` over the engine run's runs of the cases it was fitted on
    (``case_records``: results.json ``cases``, which say whether a case's loads depend on the
    state).  ([], []) without fits."""
    from ..run.metrics import ENERGY_ERROR_MAX_REL

    fits: dict[tuple[str, str], dict[str, dict]] = {}
    for e in convergence:
        if isinstance(e, dict) and e.get("case") is not None:
            fits.setdefault((label(e), e["case"]), {})[e.get("metric")] = e
    if not fits:
        return [], []
    cases = list(dict.fromkeys(c for _, c in fits))
    labs = [lab for lab in labels(runs) if any((lab, c) in fits for c in cases)]
    labs += [lab for lab in dict.fromkeys(lab for lab, _ in fits) if lab not in labs]
    rows = []
    for lab in labs:
        row, worst = [lab], None
        for c in cases:
            by_metric = fits.get((lab, c))
            if by_metric is None:
                row.append("")
                continue
            o, en = by_metric.get(ORIENTATION_ERROR_MAX), by_metric.get(ENERGY_ERROR_MAX_REL)
            row.append(f"{_order_cell(o)} / {_order_cell(en)}")
            for e in (o, en):
                rms = finite_or_none((e or {}).get("fit_rms_decades"))
                if rms is not None:
                    worst = rms if worst is None else max(worst, rms)
        row.append(num(worst, ".3f"))
        fitted = {c for c in cases if (lab, c) in fits}
        row.append(expected_order([r for r in runs if label(r) == lab and r["case"] in fitted],
                                  case_records) or "-")
        rows.append(row)
    return ["engine run", *cases, ORDER_FIT_COLUMN, ORDER_EXPECTED_COLUMN], rows


def trajectory_reader(out_dir: Path | None):
    """A findings trajectory provider (:data:`freebody.report.findings.TrajectoryOf`): run ->
    (t (n,) s, q (n, 4), q_truth (n, 4)) at its saved samples, read from its trajectory file under
    ``out_dir``; None when it has none or it cannot be read."""
    def read(run: dict):
        if out_dir is None or not run["trajectory"]:
            return None
        from ..results.document import open_run_trajectory

        try:
            with open_run_trajectory(Path(out_dir), run) as z:
                return (np.asarray(z["t"]), np.asarray(z["quaternion_wxyz"]), np.asarray(z["truth_quaternion_wxyz"]))
        except (OSError, KeyError, ValueError, zipfile.BadZipFile, InputError):  # InputError: FileRefused
            return None
    return read


# --- error series of the per-case figures ---------------------------------------------------------

# The trajectory file's arrays the figures need (its orthonormality error is not drawn).
_DRAWN_FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


@dataclass(frozen=True)
class RunSeries:
    """One run's curves in a per-case figure, from its trajectory file.

    t : (n,) s.  keep : (n,) bool, False after the run's divergence.
    orientation_error : (n,) rad, geodesic angle to the truth.
    energy_error, angular_momentum_error : (n,), as :func:`freebody.run.metrics.series` defines
        them (relative to the truth's max KE and max |L|, absolute where that scale is 0), or None
        without the case's mass and inertia.
    angular_velocity : (n, 3) rad/s, world.
    """

    run: dict
    t: np.ndarray
    keep: np.ndarray
    orientation_error: np.ndarray
    energy_error: np.ndarray | None
    angular_momentum_error: np.ndarray | None
    angular_velocity: np.ndarray


@dataclass(frozen=True)
class TruthSeries:
    """A truth as the figures use it: t (N,) s, angular_velocity (N, 3) rad/s world, quaternion
    (N, 4), and (with the case's physics, else None) L (N, 3) kg m^2/s world, KE and E (N,) J."""

    t: np.ndarray
    quaternion_wxyz: np.ndarray
    angular_velocity: np.ndarray
    L: np.ndarray | None
    ke: np.ndarray | None
    E: np.ndarray | None


def _momentum_energy(physics: CasePhysics, q, w, v, x):
    """(L (N, 3), KE (N,), E (N,)) of states, with L computed once (kinetic_energy's formula)."""
    M, I_b = physics.body.mass, physics.body.I_body
    L = angular_momentum(I_b, q, w)
    ke = 0.5 * M * np.sum(v * v, axis=-1) + 0.5 * np.sum(w * L, axis=-1)
    return L, ke, ke + potential_energy(M, physics.gravity, x)


class NoTruth(Exception):
    """A trajectory file without a truth (or without samples): the run cannot be drawn."""


class SeriesReader:
    """Reads runs' trajectory files for the per-case figures: only the drawn arrays, and each
    distinct truth once.  The runs of a case at one dt share a truth (a format-2 file names its truth
    file); truths of equal ``truth_key`` (:meth:`freebody.results.document.TrajectoryArrays.truth_key`:
    the same arrays) are read and reduced (L, KE, E) once.

    physics : the case's CasePhysics, or None (then only the orientation error and the angular
    velocity are available)."""

    def __init__(self, physics: CasePhysics | None):
        self.physics = physics
        self._truths: dict[tuple, TruthSeries] = {}

    def _truth(self, z) -> TruthSeries | None:
        names = ["truth_" + f for f in _DRAWN_FIELDS]
        key = z.truth_key()
        if key is None:
            return None
        hit = self._truths.get(key)
        if hit is None:
            t, x, q, v, w = (np.asarray(z[n]) for n in names)
            L = ke = E = None
            if self.physics is not None:
                with np.errstate(all="ignore"):
                    L, ke, E = _momentum_energy(self.physics, q, w, v, x)
            hit = self._truths[key] = TruthSeries(t, q, w, L, ke, E)
        return hit

    def read(self, path: Path, run: dict) -> tuple[RunSeries, TruthSeries]:
        """(the run's series, its truth) from its trajectory file ``path`` (found by
        :func:`freebody.results.document.trajectory_path`).  OSError, KeyError or ValueError when
        the file is unreadable, InputError (FileRefused) when it is no regular file or too large for
        the run (:func:`freebody.results.document.trajectory_max_bytes`); NoTruth when it has no
        truth or no samples."""
        from ..results.document import open_trajectory, trajectory_max_bytes

        with open_trajectory(path, trajectory_max_bytes(run)) as z:
            truth = self._truth(z)
            if truth is None:
                raise NoTruth(path)
            t, x, q, v, w = (np.asarray(z[f]) for f in _DRAWN_FIELDS)
        n = min(len(t), len(truth.t))
        if n == 0:
            raise NoTruth(path)
        t, x, q, v, w = t[:n], x[:n], q[:n], v[:n], w[:n]
        t_end = finite_or_none(run["diverged_at_s"])
        keep = np.ones(n, bool) if t_end is None else (t <= t_end)
        energy = momentum = None
        with np.errstate(all="ignore"):
            ori = geodesic_angle(truth.quaternion_wxyz[:n], q)
            if self.physics is not None:
                L, _, E = _momentum_energy(self.physics, q, w, v, x)
                L_scale = float(np.max(np.linalg.norm(truth.L[:n], axis=-1)))
                dL = np.linalg.norm(L - truth.L[:n], axis=-1)
                momentum = dL / L_scale if L_scale > 0 else dL
                E_scale = float(np.max(truth.ke[:n]))
                dE = np.abs(E - truth.E[:n])
                energy = dE / E_scale if E_scale > 0 else dE
        return RunSeries(run, t, keep, ori, energy, momentum, w), truth
