"""The verdict of ``freebody compare`` as text (the table it prints), as JSON (``--json``) and as
JUnit XML (``--junit FILE``).

The JSON verdict (schema :data:`VERDICT_SCHEMA_VERSION`, documented in docs/ci-gate.md)::

    {"kind": "freebody-compare-verdict", "schema_version": 1, "freebody_version",
     "verdict": "ok" | "regression", "exit_code": 0 | 1, "strict": bool,
     "baseline": {"source", "schema_version"}, "current": {"source", "schema_version"},
     "versions": [{"name", "baseline", "current"}],            # freebody and each engine
     "engine_defaults_changed": [{"engine", "setting", "baseline", "current"}],
     "settings_one_side": ["engine: setting K only in baseline|current (= V)"],
     "counts": {verdict: n, ..., "failed_current", "matched", "baseline_runs", "current_runs",
                "content_unchecked"},
     "engines_matched_across_names": [{"engine", "baseline", "current"}],  # one version a side
     "accept_command": "freebody baseline CURRENT --to BASELINE --force" | null,
     "groups": [{"engine", "integrator", "precision", "baseline_version", "current_version",
                 "baseline_scheme", "current_scheme", "worse", "better", "not_comparable",
                 "scheme_changed", "missing", "new", "failed", "text"}],
     "changes": [{"case", "engine", "integrator", "precision", "dt" (null: a whole group),
                  "what", "baseline", "current", "limit", "verdict", "fails", "note"}]}

``changes`` lists every change but the metrics within tolerance, and every run that failed in the
current results (``fails`` true, the reason in ``note``; ``counts.failed_current`` counts them).
``accept_command`` stores the current results as the new baseline, runnable as printed; null when
there is none (``--against``, a baseline that is a run directory).
"""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET

from .. import __version__
from ..errors import printable
from .compare import FAILING, VERDICTS, Change, Comparison

VERDICT_SCHEMA_VERSION = 1
JUNIT_MESSAGE_CHARS = 300  # a <failure> message attribute: one dashboard line; the text has it all
VERDICT_KIND = "freebody-compare-verdict"
ORDER = {v: i for i, v in enumerate(VERDICTS)}


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


def _sorted(changes: list[Change]) -> list[Change]:
    return sorted(changes, key=lambda c: (ORDER[c.verdict], c.key[0], c.key[1], c.key[2], c.key[3],
                                          -(c.key[4] if c.key[4] is not None else -1.0), c.what))


def _dt(c: Change) -> str:
    return "all" if c.key[4] is None else f"{c.key[4]:g}"


def _listed(c: Change) -> bool:
    """Whether a change is listed without ``--all``: every change but an unchanged one, and a run
    failed in the current results even when it failed in the baseline too."""
    return c.verdict != "same" or c.failed_now


# The columns of a comparison's changes (``freebody compare``, the report's comparison section).
CHANGE_COLUMNS = ("run", "dt", "what", "baseline", "current", "limit", "verdict", "note")


def change_rows(cmp, show_all: bool = False) -> list[tuple]:
    """The changes of a comparison as rows of :data:`CHANGE_COLUMNS`, failing first: every change
    but an unchanged one (every change with ``show_all``), as ``freebody compare`` lists them."""
    shown = _sorted([c for c in cmp.changes if show_all or _listed(c)])
    return [(c.label, _dt(c), c.what, _cell(c.baseline), _cell(c.current), _cell(c.limit),
             shown_verdict(c, cmp.strict), c.note) for c in shown]


def shown_verdict(c: Change, strict: bool = False) -> str:
    """The verdict column: upper case when the change fails the gate; a run failed in the
    current results whose own verdict does not fail (new, failed on both sides) says FAILED."""
    if c.failed_now and c.verdict not in FAILING:
        return "FAILED" + ("" if c.verdict == "same" else f" ({c.verdict})")
    return c.verdict.upper() if c.fails(strict) else c.verdict


def counts(cmp: Comparison) -> dict:
    return {v: sum(c.verdict == v for c in cmp.changes) for v in VERDICTS}


def format_comparison(cmp: Comparison, show_all: bool = False) -> str:
    """The text ``freebody compare`` prints: versions side by side, what changed per engine
    integrator, the changes (failing ones first) and a one-line verdict.  Numbers in %.3e."""
    out = [f"baseline: {printable(cmp.sources[0])}", f"current:  {printable(cmp.sources[1])}", ""]
    out += _columns(("", "baseline", "current", ""),
                    [(e, b, c, "" if b == c else "<- changed") for e, b, c in cmp.versions])
    if cmp.settings:
        out += ["", "engine defaults that changed (freebody sets these, so the runs do not use them):"]
        out += [f"  {e} {k}: {b} -> {c}" for e, k, b, c in cmp.settings]
    if cmp.one_sided:
        out += ["", "settings freebody set on one side only (an option the other engine version lacks):"]
        out += [f"  {n}" for n in cmp.one_sided]
    if cmp.renamed:
        out += ["", "runs matched across engine names (one version on each side):"]
        out += [f"  {b} (baseline) = {c} (current), shown as {n}" for n, b, c in cmp.renamed]
    if cmp.groups:
        out += ["", "what changed:"] + [f"  {g['text']}" for g in cmp.groups]
    out.append("")
    rows = change_rows(cmp, show_all)
    if rows:
        out += _columns(CHANGE_COLUMNS, rows)
    else:
        out.append("no change beyond the tolerances")
    out.append("")
    out.append(verdict_line(cmp))
    if cmp.unchecked:
        out.append(f"note: {cmp.unchecked} matched runs come from schema-1 results without an experiment "
                   f"record: matched on case, engine, integrator, precision, dt and steps; their content "
                   f"(body, initial state, loads, settings) could not be checked")
    accept = accept_command(cmp)
    if accept and (any(c.verdict in ("not comparable", "scheme changed", "order changed") for c in cmp.regressions)
                   or (cmp.strict and cmp.regressions)):
        out.append(f"if this change is intended, store a new baseline: {accept}")
    return "\n".join(out)


def failed_now(cmp: Comparison) -> int:
    """How many runs failed in the current results (each one fails the gate)."""
    return len({c.key for c in cmp.changes if c.failed_now})


def accept_command(cmp: Comparison) -> str | None:
    """The command that stores the current results as the new baseline, runnable as printed
    (paths shell-quoted), or None when there is none: the current side is not a results file or
    run directory (``--against``: two versions of one file; a run's own ``--baseline`` verdict
    before its folder is published), or the baseline is not a file that can be replaced."""
    import shlex
    from pathlib import Path

    base, cur = cmp.sources
    try:
        if not Path(cur).exists() or (Path(base).exists() and not Path(base).is_file()):
            return None
    except (OSError, ValueError):  # an unreadable path, a NUL byte
        return None
    to = base if Path(base).is_file() else None
    if to is None:
        return None
    command = f"freebody baseline {shlex.quote(cur)} --to {shlex.quote(to)} --force"
    return command if printable(command) == command else None  # a name with control characters


def compare_command(cmp: Comparison, *options: str) -> str:
    """``freebody compare BASELINE CURRENT [options]`` of this comparison, runnable as printed
    (paths shell-quoted; a side that is no path, e.g. a results dict, stays a placeholder in capitals)."""
    import shlex

    sides = [shlex.quote(s) if printable(s) == s and s not in ("baseline", "this run") else name
             for s, name in zip(cmp.sources, ("BASELINE", "RESULTS"))]
    return " ".join(["freebody compare", *sides, *options])


def verdict_line(cmp: Comparison) -> str:
    """The one-line verdict (the last line of the table): OK or REGRESSION and the counts."""
    n = counts(cmp)
    worse_runs = len({c.key for c in cmp.changes if c.verdict == "regressed"})
    within = cmp.matched - len({c.key for c in cmp.changes if c.verdict != "same" and c.what != "run"
                                and c.key[4] is not None})
    failed = failed_now(cmp)
    verdict = "REGRESSION" if cmp.regressions else "OK"
    return (f"{verdict}: {n['regressed']} worse ({worse_runs} runs), {n['missing']} missing, "
            f"{n['not comparable']} not comparable, {n['scheme changed']} scheme changed, "
            f"{n['order changed']} order changed, {n['improved']} improved, {n['changed']} changed, "
            f"{n['new']} new; {cmp.matched} of {cmp.baseline_runs} baseline runs matched, {within} within "
            f"tolerance" + (f"; {failed} run{'' if failed == 1 else 's'} failed in the current results"
                            if failed else "")
            + (" (--strict: improvements fail too)" if cmp.strict else ""))


def _plain(x):
    return x if x is None or isinstance(x, (str, int, float, bool)) else str(x)


def verdict_json(cmp: Comparison) -> dict:
    """The machine-readable verdict (see the module docstring)."""
    n = counts(cmp)
    return {
        "kind": VERDICT_KIND, "schema_version": VERDICT_SCHEMA_VERSION, "freebody_version": __version__,
        "verdict": "regression" if cmp.regressions else "ok", "exit_code": cmp.exit_code, "strict": cmp.strict,
        "baseline": {"source": cmp.sources[0], "schema_version": cmp.schema_versions[0]},
        "current": {"source": cmp.sources[1], "schema_version": cmp.schema_versions[1]},
        "versions": [{"name": e, "baseline": b, "current": c} for e, b, c in cmp.versions],
        "engine_defaults_changed": [{"engine": e, "setting": k, "baseline": b, "current": c}
                                    for e, k, b, c in cmp.settings],
        "settings_one_side": cmp.one_sided,
        "counts": {**{k.replace(" ", "_"): v for k, v in n.items()}, "failed_current": failed_now(cmp),
                   "matched": cmp.matched,
                   "baseline_runs": cmp.baseline_runs, "current_runs": cmp.current_runs,
                   "content_unchecked": cmp.unchecked},
        "groups": cmp.groups,
        "changes": [{"case": c.key[0], "engine": c.key[1], "integrator": c.key[2], "precision": c.key[3],
                     "dt": c.key[4], "what": c.what, "baseline": _plain(c.baseline), "current": _plain(c.current),
                     "limit": c.limit, "verdict": c.verdict, "fails": c.fails(cmp.strict), "note": c.note}
                    for c in _sorted([c for c in cmp.changes if _listed(c)])],
        "engines_matched_across_names": [{"engine": n, "baseline": b, "current": c} for n, b, c in cmp.renamed],
        "accept_command": accept_command(cmp),
    }


def write_json(cmp: Comparison) -> str:
    return json.dumps(verdict_json(cmp), indent=1, sort_keys=False, allow_nan=False)


def junit_xml(cmp: Comparison) -> bytes:
    """JUnit XML as CI dashboards read it: one <testsuite> per engine/integrator/precision, one
    <testcase> per compared run (classname ``freebody.<engine>.<integrator>``, name ``<case> dt=<dt>``)
    and per changed fitted order; a failing change is a <failure> (message: the changes), and so
    is every run that failed in the current results (new, failed in the baseline too, newly
    failed; its reason in the text) and every baseline run missing from them (with the engine's
    load failure when that is why); a run that is new and not failed, or skipped on the current
    side, is a passing test case with its status in <system-out>."""
    by_run: dict[tuple, list[Change]] = {}
    for c in cmp.changes:
        by_run.setdefault(c.key, []).append(c)
    suites: dict[tuple, list[tuple[tuple, list[Change]]]] = {}
    for key, chs in sorted(by_run.items(), key=lambda kv: (kv[0][1], kv[0][2], kv[0][3], kv[0][0],
                                                           kv[0][4] if kv[0][4] is not None else -1.0)):
        suites.setdefault(key[1:4], []).append((key, chs))
    root = ET.Element("testsuites", name="freebody compare")
    total = failures = 0
    for (engine, integrator, precision), cases in suites.items():
        name = f"{engine}/{integrator}" + ("" if precision == "float64" else f"/{precision}")
        suite = ET.SubElement(root, "testsuite", name=name)
        n_fail = 0
        for key, chs in cases:
            case = ET.SubElement(suite, "testcase", classname=f"freebody.{engine}.{integrator}",
                                 name=f"{key[0]} dt={'all' if key[4] is None else format(key[4], 'g')}"
                                      + (" order" if key[4] is None else ""))
            failing = [c for c in chs if c.fails(cmp.strict)]
            if failing:
                n_fail += 1
                text = "\n".join(printable(f"{c.what}: {_cell(c.baseline)} -> {_cell(c.current)} ({c.verdict})"
                                 + (f"; limit {_cell(c.limit)}" if c.limit is not None else "")
                                 + (f"; {c.note}" if c.note else "")) for c in failing)
                head = failing[0]
                kind = "failed" if head.failed_now and head.verdict not in FAILING else head.verdict
                message = f"{kind}: {head.what}" + (f": {head.note}" if head.note else "")
                fail = ET.SubElement(case, "failure", message=printable(message)[:JUNIT_MESSAGE_CHARS], type=kind)
                fail.text = text
            else:
                other = [c for c in chs if c.verdict != "same"]
                if other:
                    ET.SubElement(case, "system-out").text = "\n".join(
                        f"{c.what}: {_cell(c.baseline)} -> {_cell(c.current)} ({c.verdict})" for c in other)
        suite.set("tests", str(len(cases)))
        suite.set("failures", str(n_fail))
        suite.set("errors", "0")
        total += len(cases)
        failures += n_fail
    root.set("tests", str(total))
    root.set("failures", str(failures))
    root.set("errors", "0")
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)
