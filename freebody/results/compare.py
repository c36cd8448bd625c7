"""Compare a current run with a baseline: what changed, and whether anything regressed.

Runs are matched by (case, engine, integrator, precision, dt) (a renamed reference integrator by
its current name: :func:`.document.upgrade_names`), and then must be the same
*experiment* (:mod:`freebody.run.experiment`: the case's content, dt, steps, duration and the values
freebody set in the engine).  A failing change (a *regression* in the gate's sense) is:

- a run of the baseline missing from the current results;
- a run that is ``not comparable``: another experiment under the same name (a shorter run, an
  edited case file); its metrics are not compared at all (a run whose experiment is unknown, null
  in a schema-1 baseline after the migration on load, is matched on steps, and the verdict says its
  content could not be checked);
- a run whose status got worse (ok > diverged > failed; a run with a result that is now
  ``skipped`` no longer runs);
- a ``scheme changed``: the reference map the run reproduces (``matches_reference``) is another
  one, even when every error went down (MuJoCo implicitfast 3.1 -> 4.0); and an ``order changed``:
  a fitted order of convergence moved by more than ``tol.COMPARE_ORDER_CHANGE``;
- a metric (see :data:`COMPARED_METRICS`) worse beyond its tolerance,
  ``current > baseline + atol + rtol |baseline|``, or now undefined, in runs of the same status.
  Orientation errors beyond ``tol.COMPARE_ORIENTATION_SATURATED_RAD`` on both sides are equal;
- a run that ``failed`` in the current results, whether new, failed in the baseline too or newly
  failed (its reason, e.g. an engine installed but failing to import, in the change's note; the
  baseline runs such an engine leaves missing say why).

An engine run under one name on each side, the names differing (``mujoco==3.1.6`` in the baseline,
``mujoco`` 4.0.0 in the current results), is matched across the names
(:func:`.versions.align_engine_names`): an upgrade gates against a baseline of the pinned version.

Improvements beyond the tolerance, status changes for the better and runs new in the current
results are listed but are not regressions, unless ``strict`` (then every change beyond tolerance
fails, improvements included).  An intended change is accepted by storing a new baseline.
Exit codes of ``freebody compare``: 0 nothing failed, 1 something failed, 2 unusable input
(:class:`~freebody.errors.InputError`).  Text, JSON and JUnit output: :mod:`.verdict`.
"""
from __future__ import annotations

import difflib
import tomllib
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

from .. import tolerances as tol
from . import identification
from .io import read_regular_file
from ..errors import InputError, printable
from ..numbers import finite_or_none
from .document import load_results
from ..report.summary import run_label
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_ABS, ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_ABS,
                           ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_FINAL, ORIENTATION_ERROR_MAX,
                           ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE, POSITION_ERROR_MAX,
                           ROTATION_ORTHONORMALITY_ERROR_MAX)
from ..run.experiment import differences, setting_notes
from ..run.records import Status, run_identity_key

VERSION_REASON_CHARS = 160  # why an engine has no version (it failed to load), in the versions table: one line
STATUS_RANK = {Status.OK: 3, Status.DIVERGED: 2, Status.FAILED: 1}  # skipped: not measured (no rank)

# Default absolute tolerance of each compared metric, in the metric's unit (the values and their
# reasons: the regression-gate section of freebody.tolerances); every metric's default rtol is
# tol.COMPARE_DEFAULT_RTOL.
METRIC_ATOL = {
    ORIENTATION_ERROR_MAX: tol.COMPARE_ORIENTATION_ATOL_RAD,
    ORIENTATION_ERROR_FINAL: tol.COMPARE_ORIENTATION_ATOL_RAD,
    ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE: tol.COMPARE_ORIENTATION_ATOL_RAD,
    ANGULAR_MOMENTUM_ERROR_MAX_REL: tol.COMPARE_MOMENTUM_ATOL_REL,
    ANGULAR_MOMENTUM_ERROR_MAX_ABS: tol.COMPARE_MOMENTUM_ATOL_ABS,
    ENERGY_ERROR_MAX_REL: tol.COMPARE_ENERGY_ATOL_REL,
    ENERGY_ERROR_MAX_ABS: tol.COMPARE_ENERGY_ATOL_ABS_J,
    POSITION_ERROR_MAX: tol.COMPARE_POSITION_ATOL_M,
    ROTATION_ORTHONORMALITY_ERROR_MAX: tol.COMPARE_ORTHONORMALITY_ATOL,
}
COMPARED_METRICS = tuple(METRIC_ATOL)  # wall time is never compared: it measures the machine
ORIENTATION_METRICS = (ORIENTATION_ERROR_MAX, ORIENTATION_ERROR_FINAL, ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE)


@dataclass(frozen=True)
class Tolerance:
    """A metric regresses when current > baseline + atol + rtol * |baseline| (atol in the metric's unit)."""

    rtol: float
    atol: float

    def limit(self, baseline: float) -> float:
        return baseline + self.atol + self.rtol * abs(baseline)

    def floor(self, baseline: float) -> float:
        return baseline - self.atol - self.rtol * abs(baseline)


FAILING = ("missing", "not comparable", "regressed", "scheme changed", "order changed")
STRICT_FAILING = FAILING + ("improved", "changed")
VERDICTS = FAILING + ("improved", "changed", "new", "same")  # the order changes are listed in


@dataclass(frozen=True)
class Change:
    """One line of the comparison.

    key : (case, engine, integrator, precision, dt); dt is None for a change of a whole
        (case, engine, integrator, precision) group (a fitted order).
    what : a metrics key, "status", "run", "experiment", "scheme" or "order (<metric>)".
    verdict : one of :data:`VERDICTS`.
    limit : the largest current value within tolerance (metrics only), else None.
    note : what else a reader needs (the experiment's differing fields, an unchecked content).
    """

    key: tuple
    label: str
    what: str
    baseline: object
    current: object
    verdict: str
    limit: float | None = None
    note: str = ""

    @property
    def failed_now(self) -> bool:
        """Whether this is the status line of a run that ``failed`` in the current results (new,
        failed in the baseline too, or newly failed): such a run always fails the gate, with its
        reason in ``note``."""
        return self.what in ("status", "run") and self.current == Status.FAILED

    def fails(self, strict: bool = False) -> bool:
        """Whether this change fails the gate (:data:`FAILING`, or a run failed in the current
        results: :attr:`failed_now`; with ``strict``: STRICT_FAILING too)."""
        return self.verdict in (STRICT_FAILING if strict else FAILING) or self.failed_now


@dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`: every change, versions side by side, counts.

    versions : (name, baseline, current) for freebody and each engine.
    settings : (engine, setting, baseline default, current default): an engine default that freebody
        overrides and that changed between the two sides (freebody sets it, so it does not change
        the numbers; shown because an upgrade moved it).
    unchecked : matched runs whose experiment could not be checked (unknown on a side: schema-1 results).
    one_sided : "engine: setting K only in baseline|current (= V)": an option freebody sets that one
        engine version lacks (not a different experiment; shown beside the versions).
    """

    changes: list[Change]
    versions: list[tuple[str, str, str]]
    matched: int
    baseline_runs: int
    current_runs: int
    tolerances: dict[str, Tolerance] = field(default_factory=dict)
    sources: tuple[str, str] = ("baseline", "current")
    strict: bool = False
    settings: list[tuple[str, str, str, str]] = field(default_factory=list)
    unchecked: int = 0
    groups: list[dict] = field(default_factory=list)
    schema_versions: tuple = (None, None)
    one_sided: list[str] = field(default_factory=list)
    # (common name, baseline name, current name): an engine whose runs were matched across the
    # names each side ran it under (mujoco==3.1.6 in the baseline, mujoco in the current results)
    renamed: list[tuple[str, str, str]] = field(default_factory=list)

    @property
    def regressions(self) -> list[Change]:
        """The changes that fail the gate (with ``strict``: improvements too)."""
        return [c for c in self.changes if c.fails(self.strict)]

    @property
    def exit_code(self) -> int:
        return 1 if self.regressions else 0

    def table(self, show_all: bool = False) -> str:
        from .verdict import format_comparison

        return format_comparison(self, show_all)


# --- input ----------------------------------------------------------------------------------------

def load_side(source, role: str) -> dict:
    """A results document from a run directory, a results.json or baseline file, or a dict.

    role : "baseline" or "current", named in error messages.  InputError on anything unusable.
    """
    return load_results(source, role)


def run_key(run: dict) -> tuple:
    """(case, engine, integrator, precision, dt): dt rounded to tol.COMPARE_DT_SIGNIFICANT_DIGITS (12)
    significant digits."""
    return run_identity_key(run["case"], run["engine"], run["integrator"], run["precision"],
                            float(f"{float(run['dt']):.{tol.COMPARE_DT_SIGNIFICANT_DIGITS}g}"))


# --- tolerances -----------------------------------------------------------------------------------

def default_tolerances() -> dict[str, Tolerance]:
    return {m: Tolerance(tol.COMPARE_DEFAULT_RTOL, a) for m, a in METRIC_ATOL.items()}


def _tol_value(value, where: str) -> float:
    x = finite_or_none(value)
    if x is None or x < 0:
        raise InputError(f"{where}: must be a finite number >= 0, got {value!r}")
    return x


def _unknown(where: str, dotted: str, key: str, known, kind: str = "key") -> InputError:
    near = difflib.get_close_matches(key, list(known), n=1)
    hint = f"; did you mean {near[0]!r}" if near else f"; known: {', '.join(known)}"
    return InputError(f"{where}: {dotted}: unknown {kind}{hint}")


def resolve_tolerances(path: str | Path | None = None, rtol: float | None = None,
                       atol: float | None = None) -> dict[str, Tolerance]:
    """Per-metric tolerances.  From lowest to highest precedence: the defaults (:data:`METRIC_ATOL`
    and ``COMPARE_DEFAULT_RTOL`` of :mod:`freebody.tolerances`); the file's top-level
    ``rtol``/``atol`` (every metric); the command line's ``--rtol``/``--atol`` (every metric); the
    file's ``[metrics.NAME]`` tables.

    File format (TOML)::

        rtol = 0.05                          # every metric
        [metrics.orientation_error_max_rad]  # one metric (a results.json metrics key)
        atol = 1e-8
    """
    tols = default_tolerances()
    per_metric: dict = {}
    top: dict = {}
    if path is not None:
        p = Path(path)
        try:
            data = tomllib.loads(read_regular_file(p, tol.TOLERANCES_FILE_MAX_BYTES,
                                                   f"--tolerances {p}").decode("utf-8"))
        except FileNotFoundError:
            raise InputError(f"--tolerances {p}: no such file") from None
        except OSError as e:
            raise InputError(f"--tolerances {p}: cannot read: {e.strerror or e}") from None
        except UnicodeDecodeError as e:  # a binary file, UTF-16, Latin-1
            raise InputError(f"--tolerances {p}: not UTF-8 text (byte {e.start}); a tolerances file is "
                             f"TOML (see docs/ci-gate.md)") from None
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"--tolerances {p}: invalid TOML: {printable(e)}") from None
        except (ValueError, RecursionError) as e:  # an integer of more than 4300 digits; deep nesting
            why = "nested too deeply" if isinstance(e, RecursionError) else str(e).split(";")[0]
            raise InputError(f"--tolerances {p}: invalid TOML: {why}") from None
        for k, v in data.items():
            if k in ("rtol", "atol"):
                top[k] = _tol_value(v, f"--tolerances {p}: {k}")
            elif k == "metrics":
                if not isinstance(v, dict):
                    raise InputError(f"--tolerances {p}: metrics: must be a table of [metrics.NAME] tables")
                for m, spec in v.items():
                    if m not in tols:
                        raise _unknown(f"--tolerances {p}", f"metrics.{m}", m, COMPARED_METRICS, "metric")
                    if not isinstance(spec, dict):
                        raise InputError(f"--tolerances {p}: metrics.{m}: must be a table with rtol and/or atol")
                    for sk, sv in spec.items():
                        if sk not in ("rtol", "atol"):
                            raise _unknown(f"--tolerances {p}", f"metrics.{m}.{sk}", sk, ("rtol", "atol"))
                        per_metric.setdefault(m, {})[sk] = _tol_value(sv, f"--tolerances {p}: metrics.{m}.{sk}")
            else:
                raise _unknown(f"--tolerances {p}", k, k, ("rtol", "atol", "metrics"))
    if rtol is not None:
        top["rtol"] = _tol_value(rtol, "--rtol")
    if atol is not None:
        top["atol"] = _tol_value(atol, "--atol")
    out = {}
    for m, t in tols.items():
        spec = {"rtol": t.rtol, "atol": t.atol, **top, **per_metric.get(m, {})}
        out[m] = Tolerance(spec["rtol"], spec["atol"])
    return out


# --- the comparison -------------------------------------------------------------------------------

def _index(runs: list[dict]) -> dict[tuple, dict]:
    """The runs by :func:`run_key` (each key once: :func:`check_unique_runs` has refused repeats)."""
    return {run_key(r): r for r in runs}


def check_unique_runs(doc: dict, where: str) -> None:
    """InputError (one line naming ``where``, the document) if two of its runs have one identity
    (:func:`run_key`): compare would have to drop one of them without a word."""
    first: dict[tuple, int] = {}
    for i, r in enumerate(doc["runs"]):
        j = first.setdefault(run_key(r), i)
        if j != i:
            k = run_key(r)
            copies = sum(run_key(x) == k for x in doc["runs"])
            raise InputError(f"{where}: runs[{j}] and runs[{i}]"
                             + (f" (and {copies - 2} more)" if copies > 2 else "")
                             + f" are one run twice: {printable(f'{k[0]} {k[1]}/{k[2]} {k[3]} dt={k[4]:g}')}"
                             + " (case, engine, integrator, precision, dt); compare needs each run once")


def engine_version_words(doc: dict) -> dict[str, str]:
    """engine -> its version in a results document, or why it has none: 'failed (<reason>)' for an
    engine whose runs failed without a version (e.g. installed but failing to import), else
    'not installed'."""
    failed: dict[str, str] = {}  # engine -> why its runs failed (an engine that fails to import)
    for r in doc["runs"]:
        if r["status"] == Status.FAILED:
            failed.setdefault(r["engine"], str(r["message"] or "no reason recorded"))
    v = {e: (str(x) if x else f"failed ({cap(failed[e], VERSION_REASON_CHARS)})" if e in failed
             else "not installed") for e, x in doc["engines"].items()}
    for r in doc["runs"]:
        if r["engine_version"]:
            v.setdefault(r["engine"], str(r["engine_version"]))
    return v


def _versions(base: dict, cur: dict) -> list[tuple[str, str, str]]:
    b, c = engine_version_words(base), engine_version_words(cur)
    rows = [("freebody", *(str(d.get("freebody_version") or "-") for d in (base, cur)))]  # optional: hand-made files
    return rows + [(e, b.get(e, "-"), c.get(e, "-")) for e in dict.fromkeys([*b, *c])]


def cap(text: str, n: int) -> str:
    """``text`` on one line, cut to ``n`` characters with an ellipsis."""
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[:n - 3] + "..."


def load_failures(doc: dict) -> dict[tuple, str]:
    """(case, engine, precision, dt) -> the reason of a run that ran no integrator because its
    engine's adapter failed to load (integrator ``*``, status ``failed``: an engine installed but
    broken), for the note of the baseline runs this leaves missing."""
    out = {}
    for r in doc["runs"]:
        if r["status"] == Status.FAILED and r["integrator"] == "*":
            k = run_key(r)
            out.setdefault((k[0], k[1], k[3], k[4]), str(r["message"] or ""))
    return out


def _default_changes(b_runs: dict, c_runs: dict) -> list[tuple[str, str, str, str]]:
    """(engine, setting, baseline default, current default) of the engine defaults freebody
    overrides whose default differs between the two sides (first run of each engine that has it)."""
    def defaults(runs):
        out: dict = {}
        for r in runs.values():
            for k, v in r["engine_settings"].items():
                if isinstance(v, dict) and "default" in v:
                    out.setdefault((r["engine"], k), v["default"])
        return out

    b, c = defaults(b_runs), defaults(c_runs)
    return [(e, k, str(b[(e, k)]), str(c[(e, k)])) for (e, k) in b if (e, k) in c and b[(e, k)] != c[(e, k)]]


def scheme_of(run: dict) -> tuple[str, ...] | None:
    """The reference maps a run reproduces (several: indistinguishable on its case), () when it
    reproduces none (closest), None when it was not identified (a reference run, a run not ok) or
    identification could not decide on its case (``verdict`` undecidable: no scheme to compare)."""
    m = run["matches_reference"]
    v = identification.verdict(m)
    if v is None or v == identification.UNDECIDABLE:
        return None
    return identification.reproduced(m)


def scheme_text(scheme: tuple[str, ...] | None, run: dict | None = None) -> str:
    if scheme is None:
        return "-"
    if not scheme:
        if run is None:
            return "none"
        m = run["matches_reference"]  # judged (a scheme), so an object
        d = finite_or_none(m["max_orientation_diff_rad"])
        if m["closest"] and (d is None or d > tol.CONVERGENCE_ORIENTATION_SATURATED_RAD):
            return "none (orientation lost)"  # every map is about as far: naming the closest misleads
        return f"none (closest {m['closest']})" if m["closest"] else "none"
    return " = ".join(scheme)


def _scheme_change(b: dict, c: dict) -> tuple[str, str] | None:
    """(baseline scheme, current scheme) when the reproduced map changed, else None.  A tie that
    still holds the other side's map is no change; so is a run that is not identified on a side."""
    sb, sc = scheme_of(b), scheme_of(c)
    if sb is None or sc is None or set(sb) & set(sc) or (not sb and not sc):
        return None
    return scheme_text(sb, b), scheme_text(sc, c)


def _saturated(m: str, bv: float, cv: float) -> bool:
    return (m in ORIENTATION_METRICS and bv > tol.COMPARE_ORIENTATION_SATURATED_RAD
            and cv > tol.COMPARE_ORIENTATION_SATURATED_RAD)


def _metric_changes(key, lab, b: dict, c: dict, tols: dict[str, Tolerance]) -> list[Change]:
    out = []
    bm, cm = b["metrics"], c["metrics"]  # a metric absent from a run's metrics is undefined
    for m, mt in tols.items():
        bv = finite_or_none(bm.get(m))
        cv = finite_or_none(cm.get(m))
        if bv is None:
            if cv is not None:
                out.append(Change(key, lab, m, None, cv, "changed"))
            continue
        if cv is None:
            out.append(Change(key, lab, m, bv, None, "regressed"))
        elif _saturated(m, bv, cv):
            out.append(Change(key, lab, m, bv, cv, "same", mt.limit(bv), "both saturated (orientation lost)"))
        elif cv > mt.limit(bv):
            out.append(Change(key, lab, m, bv, cv, "regressed", mt.limit(bv)))
        elif cv < mt.floor(bv):
            out.append(Change(key, lab, m, bv, cv, "improved", mt.limit(bv)))
        else:
            out.append(Change(key, lab, m, bv, cv, "same", mt.limit(bv)))
    return out


def _experiment_differences(b: dict, c: dict) -> tuple[list[str], bool]:
    """(the differing fields, whether the content was checked) of two matched runs: a run whose
    experiment is unknown (None: a schema-1 run) is checked on its steps only."""
    be, ce = b["experiment"], c["experiment"]
    if be is not None and ce is not None:
        return differences(be, ce), True
    bs, cs = b["steps"], c["steps"]
    diff = [f"steps {bs} -> {cs}"] if isinstance(bs, int) and isinstance(cs, int) and bs != cs else []
    return diff, False


def _status_change(key, lab, bs, cs) -> Change:
    if bs == Status.SKIPPED:
        verdict = "changed"
    elif cs == Status.SKIPPED or STATUS_RANK.get(cs, 0) < STATUS_RANK.get(bs, 0):
        verdict = "regressed"
    else:
        verdict = "improved"
    return Change(key, lab, "status", bs, cs, verdict)


def _order_changes(baseline: dict, current: dict, keep) -> list[Change]:
    """Fitted orders (results.json ``convergence``) that moved by more than COMPARE_ORDER_CHANGE."""
    def index(doc):
        out = {}
        for e in doc.get("convergence") or []:
            if isinstance(e, dict) and finite_or_none(e.get("order")) is not None:
                k = (e.get("case"), e.get("engine"), e.get("integrator"), e.get("precision") or "float64")
                out.setdefault((k, e.get("metric")), float(e["order"]))
        return out

    b, c = index(baseline), index(current)
    out = []
    for (k, metric), bo in b.items():
        co = c.get((k, metric))
        if co is None or not keep({"case": k[0], "engine": k[1]}):
            continue
        if abs(co - bo) > tol.COMPARE_ORDER_CHANGE:
            lab = f"{k[0]} {run_label({'engine': k[1], 'integrator': k[2], 'precision': k[3]})}"
            out.append(Change((*k, None), lab, f"order ({metric})", round(bo, 3), round(co, 3), "order changed"))
    return out


def _kept(doc: dict, keep) -> dict:
    """The document with only the runs (and fitted orders) that ``keep`` keeps."""
    out = {**doc, "runs": [r for r in doc["runs"] if keep(r)]}
    if isinstance(doc.get("convergence"), list):
        out["convergence"] = [e for e in doc["convergence"] if isinstance(e, dict) and keep(e)]
    return out


def _filter(engines, cases):
    engines, cases = set(engines or ()), set(cases or ())

    def keep(run: dict) -> bool:
        return (not engines or run["engine"] in engines) and (not cases or run["case"] in cases)
    return keep


def compare(baseline: dict, current: dict, tolerances: dict[str, Tolerance] | None = None,
            sources: tuple[str, str] = ("baseline", "current"), *, strict: bool = False,
            engines: list[str] | None = None, cases: list[str] | None = None) -> Comparison:
    """Compare two results documents (as :func:`load_side` reads them; a document given otherwise,
    e.g. built in memory, is validated and migrated to the newest shape here as well:
    :func:`.document.load_results`).

    strict : every change beyond tolerance fails (improvements included).
    engines, cases : compare only the runs of these engines / cases (on both sides)."""
    from ..envs.versions import align_engine_names

    baseline, current = load_results(baseline, "baseline"), load_results(current, "current")
    check_unique_runs(baseline, f"baseline {sources[0]}")
    check_unique_runs(current, f"current {sources[1]}")
    tols = tolerances or default_tolerances()
    keep = _filter(engines, cases)
    # the filters apply to the names as run; then an engine's versions are matched across the sides
    baseline, current, renamed = align_engine_names(_kept(baseline, keep), _kept(current, keep))
    keep = _filter(None, None)
    b_runs = _index([r for r in baseline["runs"] if keep(r)])
    c_runs = _index([r for r in current["runs"] if keep(r)])
    changes: list[Change] = []
    one_sided: dict[str, None] = {}  # settings freebody set on one side only, per engine (ordered)
    matched = unchecked = 0
    broken = load_failures({"runs": list(c_runs.values())})
    for key, b in b_runs.items():
        lab = f"{key[0]} {run_label({**b, 'precision': key[3]})}"
        c = c_runs.get(key)
        if c is None:
            why = broken.get((key[0], key[1], key[3], key[4]))
            changes.append(Change(key, lab, "run", b["status"], None, "missing",
                                  note=f"the engine failed in the current results: {why}" if why else ""))
            continue
        matched += 1
        diff, checked = _experiment_differences(b, c)
        unchecked += not checked
        for note in setting_notes(b["experiment"], c["experiment"]):
            one_sided.setdefault(f"{key[1]}: {note}", None)
        if diff:
            note = "; ".join(diff) + ("" if checked else " (content not checked: schema-1 results)")
            changes.append(Change(key, lab, "experiment", b["steps"], c["steps"], "not comparable",
                                  note=note))
            continue
        bs, cs = b["status"], c["status"]
        why = str(c["message"] or "") if cs == Status.FAILED else ""
        if bs != cs:
            changes.append(replace(_status_change(key, lab, bs, cs), note=why))
            continue
        changes.append(Change(key, lab, "status", bs, cs, "same", note=why))  # every matched run has a line
        moved = _scheme_change(b, c)
        if moved:
            changes.append(Change(key, lab, "scheme", moved[0], moved[1], "scheme changed"))
        changes += _metric_changes(key, lab, b, c, tols)
    for key, c in c_runs.items():
        if key not in b_runs:
            changes.append(Change(key, f"{key[0]} {run_label({**c, 'precision': key[3]})}", "run", None,
                                  c["status"], "new",
                                  note=str(c["message"] or "") if c["status"] == Status.FAILED else ""))
    changes += _order_changes(baseline, current, keep)
    cmp = Comparison(changes, _versions(baseline, current), matched, len(b_runs), len(c_runs), tols, sources,
                     strict, _default_changes(b_runs, c_runs), unchecked, one_sided=list(one_sided),
                     schema_versions=(baseline["schema_version"], current["schema_version"]),
                     renamed=renamed)
    return replace(cmp, groups=group_summaries(cmp, b_runs, c_runs))


def group_summaries(cmp: Comparison, b_runs: dict, c_runs: dict) -> list[dict]:
    """One entry per (engine, integrator, precision) with a change: its versions, its scheme on
    each side (the most frequent one among its runs), and how many runs got worse, better, were
    not comparable or changed scheme.  ``text`` is the line the verdict prints, e.g.
    ``mujoco/implicitfast 3.1.6 -> 4.0.0: scheme semi-implicit-explicit-gyro -> semi-implicit-implicit-gyro; 3 runs worse, 2 better``."""
    groups: dict[tuple, dict] = {}
    for ch in cmp.changes:
        if ch.verdict == "same" and not ch.failed_now:
            continue
        g = groups.setdefault(ch.key[1:4], {"worse": set(), "better": set(), "not comparable": set(),
                                             "scheme changed": set(), "missing": set(), "new": set(),
                                             "failed": set(), "orders": []})
        if ch.failed_now:  # failed in the current results (new, newly or still failed)
            g["failed"].add(ch.key)
        if ch.verdict == "order changed":
            g["orders"].append(f"order {ch.baseline:g} -> {ch.current:g} on {ch.key[0]}")
            continue
        bucket = {"regressed": "worse", "improved": "better"}.get(ch.verdict, ch.verdict)
        if bucket in g:
            g[bucket].add(ch.key)
    out = []
    for (engine, integrator, precision), g in groups.items():
        def side(runs):
            rs = [r for k, r in runs.items() if k[1:4] == (engine, integrator, precision)]
            versions = Counter(str(r["engine_version"] or "-") for r in rs)
            schemes = Counter(scheme_text(scheme_of(r), r) for r in rs if scheme_of(r) is not None)
            return (versions.most_common(1)[0][0] if versions else "-",
                    schemes.most_common(1)[0][0] if schemes else None)
        (bv, bsch), (cv, csch) = side(b_runs), side(c_runs)
        label = run_label({"engine": engine, "integrator": integrator, "precision": precision})
        parts = []
        orders = g.pop("orders")
        if g["scheme changed"] and bsch != csch:
            parts.append(f"scheme {bsch} -> {csch}")
        elif g["scheme changed"]:
            parts.append(f"scheme changed in {len(g['scheme changed'])} of its runs")
        parts += orders
        for name, word in (("worse", "worse"), ("better", "better"), ("not comparable", "not comparable"),
                           ("missing", "missing"), ("new", "new"), ("failed", "failed now")):
            if g[name]:
                n = len(g[name])
                parts.append(f"{n} run{'' if n == 1 else 's'} {word}")
        versions = bv if bv == cv else f"{bv} -> {cv}"
        out.append({"engine": engine, "integrator": integrator, "precision": precision,
                    "baseline_version": bv, "current_version": cv, "baseline_scheme": bsch,
                    "current_scheme": csch, **{k.replace(" ", "_"): len(v) for k, v in g.items()},
                    "text": f"{label} {versions}: " + "; ".join(parts)})
    return out
