"""Compare a current run with a baseline: what changed, and whether anything regressed.

Runs are matched by (case, engine, integrator, precision, dt).  A *regression* is:

- a run of the baseline missing from the current results;
- a run whose status got worse (ok > diverged > failed; a run with a result that is now
  ``skipped`` no longer runs);
- a metric (see :data:`COMPARED_METRICS`) worse beyond its tolerance,
  ``current > baseline + atol + rtol |baseline|``, or now undefined, in runs of the same status.

Improvements beyond the tolerance, status changes for the better and runs new in the current
results are listed but are not regressions.  Exit codes of ``freebody compare``: 0 nothing
regressed, 1 something regressed, 2 unusable input (:class:`~freebody.errors.InputError`).
"""
from __future__ import annotations

import difflib
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .. import tolerances as tol
from .io import read_regular_file
from ..errors import InputError, printable
from ..numbers import finite_or_none
from .document import load_results
from ..report.summary import run_label
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_ABS, ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_ABS,
                           ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_FINAL, ORIENTATION_ERROR_MAX,
                           ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE, POSITION_ERROR_MAX,
                           ROTATION_ORTHONORMALITY_ERROR_MAX)
from ..run.records import Status

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


@dataclass(frozen=True)
class Tolerance:
    """A metric regresses when current > baseline + atol + rtol * |baseline| (atol in the metric's unit)."""

    rtol: float
    atol: float

    def limit(self, baseline: float) -> float:
        return baseline + self.atol + self.rtol * abs(baseline)

    def floor(self, baseline: float) -> float:
        return baseline - self.atol - self.rtol * abs(baseline)


@dataclass(frozen=True)
class Change:
    """One line of the comparison.

    key : (case, engine, integrator, precision, dt).
    what : a metrics key, "status" or "run".
    verdict : "regressed", "missing" (both regressions), "improved", "new", "changed" or "same".
    limit : the largest current value within tolerance (metrics only), else None.
    """

    key: tuple
    label: str
    what: str
    baseline: object
    current: object
    verdict: str
    limit: float | None = None

    @property
    def regression(self) -> bool:
        return self.verdict in ("regressed", "missing")


@dataclass(frozen=True)
class Comparison:
    """The outcome of :func:`compare`: every change, engine versions side by side, counts."""

    changes: list[Change]
    versions: list[tuple[str, str, str]]
    matched: int
    baseline_runs: int
    current_runs: int
    tolerances: dict[str, Tolerance] = field(default_factory=dict)
    sources: tuple[str, str] = ("baseline", "current")

    @property
    def regressions(self) -> list[Change]:
        return [c for c in self.changes if c.regression]

    @property
    def exit_code(self) -> int:
        return 1 if self.regressions else 0

    def table(self, show_all: bool = False) -> str:
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
    return (run["case"], run["engine"], run["integrator"], run.get("precision") or "float64",
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
    out: dict[tuple, dict] = {}
    for r in runs:
        out.setdefault(run_key(r), r)  # a repeated run: the first one counts
    return out


def _versions(base: dict, cur: dict) -> list[tuple[str, str, str]]:
    def of(doc):
        v = {e: (str(x) if x else "not installed") for e, x in (doc.get("engines") or {}).items()}
        for r in doc.get("runs") or []:
            if r.get("engine_version"):
                v.setdefault(r["engine"], str(r["engine_version"]))
        return v

    b, c = of(base), of(cur)
    return [(e, b.get(e, "-"), c.get(e, "-")) for e in dict.fromkeys([*b, *c])]


def compare(baseline: dict, current: dict, tolerances: dict[str, Tolerance] | None = None,
            sources: tuple[str, str] = ("baseline", "current")) -> Comparison:
    """Compare two results documents (already loaded with :func:`load_side`)."""
    tols = tolerances or default_tolerances()
    b_runs, c_runs = _index(baseline.get("runs") or []), _index(current.get("runs") or [])
    changes: list[Change] = []
    matched = 0
    for key, b in b_runs.items():
        lab = f"{key[0]} {run_label({**b, 'precision': key[3]})}"
        c = c_runs.get(key)
        if c is None:
            changes.append(Change(key, lab, "run", b.get("status"), None, "missing"))
            continue
        matched += 1
        bs, cs = b.get("status"), c.get("status")
        if bs != cs:
            if bs == Status.SKIPPED:
                verdict = "changed"
            elif cs == Status.SKIPPED or STATUS_RANK.get(cs, 0) < STATUS_RANK.get(bs, 0):
                verdict = "regressed"
            else:
                verdict = "improved"
            changes.append(Change(key, lab, "status", bs, cs, verdict))
            continue
        bm, cm = b.get("metrics") or {}, c.get("metrics") or {}
        for m, mt in tols.items():
            bv = finite_or_none(bm.get(m))
            cv = finite_or_none(cm.get(m))
            if bv is None:
                if cv is not None:
                    changes.append(Change(key, lab, m, None, cv, "changed"))
                continue
            if cv is None:
                changes.append(Change(key, lab, m, bv, None, "regressed"))
            elif cv > mt.limit(bv):
                changes.append(Change(key, lab, m, bv, cv, "regressed", mt.limit(bv)))
            elif cv < mt.floor(bv):
                changes.append(Change(key, lab, m, bv, cv, "improved", mt.limit(bv)))
            else:
                changes.append(Change(key, lab, m, bv, cv, "same", mt.limit(bv)))
    for key, c in c_runs.items():
        if key not in b_runs:
            changes.append(Change(key, f"{key[0]} {run_label({**c, 'precision': key[3]})}", "run", None,
                                  c.get("status"), "new"))
    return Comparison(changes, _versions(baseline, current), matched, len(b_runs), len(c_runs), tols, sources)


# --- text -----------------------------------------------------------------------------------------

def _cell(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return format(x, ".3e")
    return str(x)


def _columns(header: tuple, rows: list[tuple]) -> list[str]:
    rows = [tuple(printable(c) for c in row) for row in rows]  # names from files: no terminal escapes
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(f"{h:<{w}}" for h, w in zip(header, widths)).rstrip(),
             "  ".join("-" * w for w in widths).rstrip()]
    lines += ["  ".join(f"{str(c):<{w}}" for c, w in zip(row, widths)).rstrip() for row in rows]
    return lines


ORDER = {"missing": 0, "regressed": 1, "improved": 2, "changed": 3, "new": 4, "same": 5}


def format_comparison(cmp: Comparison, show_all: bool = False) -> str:
    """The text ``freebody compare`` prints: engine versions side by side, the changes (regressions
    first), and a one-line verdict.  Numbers in %.3e."""
    out = [f"baseline: {printable(cmp.sources[0])}", f"current:  {printable(cmp.sources[1])}", ""]
    out += _columns(("engine", "baseline", "current", ""),
                    [(e, b, c, "" if b == c else "<- changed") for e, b, c in cmp.versions])
    out.append("")
    shown = [c for c in cmp.changes if show_all or c.verdict != "same"]
    shown.sort(key=lambda c: (ORDER[c.verdict], c.key[0], c.key[1], c.key[2], c.key[3], -c.key[4], c.what))
    if shown:
        out += _columns(("run", "dt", "what", "baseline", "current", "limit", "verdict"),
                        [(c.label, f"{c.key[4]:g}", c.what, _cell(c.baseline), _cell(c.current),
                          _cell(c.limit), c.verdict.upper() if c.regression else c.verdict) for c in shown])
    else:
        out.append("no change beyond the tolerances")
    out.append("")
    n = {v: sum(c.verdict == v for c in cmp.changes) for v in ORDER}
    worse_runs = len({c.key for c in cmp.changes if c.verdict == "regressed"})
    within = cmp.matched - len({c.key for c in cmp.changes if c.verdict != "same" and c.what != "run"})
    verdict = "REGRESSION" if cmp.regressions else "OK"
    out.append(f"{verdict}: {n['regressed']} worse ({worse_runs} runs), {n['missing']} missing, "
               f"{n['improved']} improved, {n['changed']} changed, {n['new']} new; "
               f"{cmp.matched} of {cmp.baseline_runs} baseline runs matched, {within} within tolerance")
    return "\n".join(out)
