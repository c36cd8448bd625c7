"""report.md: the report's tables as Markdown (the plots are in report.html).

It opens on the verdict (:mod:`.findings`): the findings, the comparison with a baseline when one
is given, and per case the engine runs grouped by the reference map they reproduce; then the
overview tables and one section per case.

Numbers are printed with fixed formats (%.3e for errors, %.2f for orders), so the text is stable
under last-digit noise and can be compared with golden files.
"""
from __future__ import annotations

from pathlib import Path

from . import data as rd
from . import findings as fd
from ..adapters.base import REFERENCE_ENGINE
from ..numbers import finite_or_none
from ..envs.versions import VERSIONS_NOTE, side_by_side, version_table
from .version_findings import KIND as VERSION_KIND, VERSIONS_ANCHOR
from ..run.convergence import SHORT_NAMES
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_FINAL,
                           ORIENTATION_ERROR_MAX, POSITION_ERROR_MAX, ROTATION_ORTHONORMALITY_ERROR_MAX)
from ..run.records import Status

RUN_COLUMNS = ("engine run", "dt (s)", "status", "orientation max (rad)", "orientation final (rad)",
               "L max (rel)", "E max (rel)", "position max (m)", "wall s / sim s", "reproduces")
# Shown before "reproduces" when a run of the table integrates R as a matrix (it has the metric).
ORTHONORMALITY_COLUMN = "orthonormality max (||R^T R - 1||_F)"


# A table whose padded text would be longer than this (bytes) is written unpadded (its cells
# only): column padding doubles the bytes of a long or wide table (the default suite's report.md:
# 1.37 MB unpadded against 2.79 MB) and a Markdown viewer lines the columns up without it; a
# short table stays aligned for the eye (every table of tests/golden/report.md is under 2.5 KB).
PADDED_MAX_BYTES = 4096
# report.md stays under this (issue 29: the default suite's report.md <= 200 KB): past it, the
# per-case tables report.html repeats (verdict groups, runs, engine-vs-engine differences) are
# left to report.html, and to results.json for the runs, each with a pointer (render_markdown).
MD_BUDGET_BYTES = 200_000


def md_table(header: tuple[str, ...] | list[str], rows: list) -> str:
    """A Markdown pipe table ('|' in cells escaped), columns padded to their widths unless that
    makes it longer than :data:`PADDED_MAX_BYTES`."""
    cells = [[str(c).replace("|", "\\|").replace("\n", " ") for c in row] for row in [header, *rows]]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    if (sum(widths) + 3 * len(widths) + 2) * (len(cells) + 1) > PADDED_MAX_BYTES:
        lines = ["| " + " | ".join(row) + " |" for row in cells]
        lines.insert(1, "|" + "|".join("---" for _ in header) + "|")
        return "\n".join(lines)
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(row, widths)) + " |" for row in cells]
    lines.insert(1, "| " + " | ".join("-" * w for w in widths) + " |")
    return "\n".join(lines)


def run_rows(runs: list[dict]) -> list[tuple]:
    """The per-case run table rows, grouped by engine run, coarsest dt first."""
    order = {lab: i for i, lab in enumerate(rd.labels(runs))}
    rows = []
    for r in sorted(runs, key=lambda r: (order[rd.label(r)], -float(r["dt"]))):
        rows.append((rd.label(r), f"{float(r['dt']):g}", r.get("status", "?"),
                     rd.num(rd.metric(r, ORIENTATION_ERROR_MAX)),
                     rd.num(rd.metric(r, ORIENTATION_ERROR_FINAL)),
                     rd.num(rd.metric(r, ANGULAR_MOMENTUM_ERROR_MAX_REL)),
                     rd.num(rd.metric(r, ENERGY_ERROR_MAX_REL)),
                     rd.num(rd.metric(r, POSITION_ERROR_MAX)),
                     rd.num(rd.wall_per_simulated_s(r), ".2e"), rd.reproduces(r)))
    return rows


def run_table(runs: list[dict]) -> tuple[tuple[str, ...], list[tuple]]:
    """(columns, rows) of the per-case run table: :data:`RUN_COLUMNS` and :func:`run_rows`, with a
    column of the orthonormality error ||R^T R - 1||_F (max over the run) when a run has it."""
    rows = run_rows(runs)
    if all(rd.metric(r, ROTATION_ORTHONORMALITY_ERROR_MAX) is None for r in runs):
        return RUN_COLUMNS, rows
    order = {lab: i for i, lab in enumerate(rd.labels(runs))}
    ortho = [rd.num(rd.metric(r, ROTATION_ORTHONORMALITY_ERROR_MAX))
             for r in sorted(runs, key=lambda r: (order[rd.label(r)], -float(r["dt"])))]
    return (*RUN_COLUMNS[:-1], ORTHONORMALITY_COLUMN, RUN_COLUMNS[-1]), \
        [(*row[:-1], o, row[-1]) for row, o in zip(rows, ortho)]


CONVERGENCE_COLUMNS = ("engine run", "metric", "order p", "fit rms (decades)", "dts fitted (s)", "note")
ORDER_NOTE = ("Each case: the observed order p of the orientation error / of the energy error "
              "(error ~ dt^p, least squares on log-log over the time steps inside the fit range; sat.: "
              "saturated, -: no order). Worst fit rms: the largest RMS residual of those fits in decades "
              "(about 0.01: the errors follow one power law; 0.05 and more: the slope changes across the "
              "time steps). Expected p: a reference integrator's formal order, or that of the map every "
              "run of the engine run on these cases reproduces (reference integrators and "
              "engine-equivalent maps alike; 'closest': it reproduces none, the closest map's), 1 where "
              "the engine samples the loads once a step on a case whose loads turn with the body "
              "('limited by per-step load sampling': not the engine's order); -: the maps' orders "
              "differ or none is known.")


def convergence_rows(entries: list[dict]) -> list[tuple]:
    """Rows of a case's "Observed order" table (:data:`CONVERGENCE_COLUMNS`)."""
    rows = []
    for e in entries:
        lab = rd.label(e)
        order = rd.num(e.get("order"), ".2f")
        rows.append((lab, SHORT_NAMES.get(e["metric"], e["metric"]),
                     order if order != "-" else ("saturated" if e.get("saturated") else "-"),
                     rd.num(e.get("fit_rms_decades"), ".3f"),
                     ", ".join(f"{d:g}" for d in (e.get("fitted_dts") or [])) or "-",
                     e.get("reason") or ""))
    return rows


def observed_order_lines(convergence: list[dict], runs: list[dict], cases: dict | None = None) -> list[str]:
    """The front page's "Observed order" section (nothing when no case ran at 3 or more dts);
    ``cases``: results.json ``cases`` (whether a case's loads depend on the state)."""
    columns, rows = rd.observed_orders(convergence, runs, cases)
    if not rows:
        return []
    return ["## Observed order of convergence per engine run", "", ORDER_NOTE, "", md_table(columns, rows), ""]


def not_ok_lines(runs: list[dict]) -> list[str]:
    out = []
    for r in runs:
        if r.get("status") != Status.OK:
            msg = (r.get("message") or "").strip() or "(no message)"
            out.append(f"- `{rd.label(r)}` dt = {float(r['dt']):g} s: **{r.get('status')}**: {msg}")
    return list(dict.fromkeys(out))


def header_lines(doc: dict, source: str) -> list[str]:
    runs = doc.get("runs") or []
    counts = rd.status_counts(runs)
    out = ["# freebody report", "",
           f"- results: `{source}` (schema {doc.get('schema_version')}), freebody "
           f"{doc.get('freebody_version', '?')}, created {doc.get('created', '?')}",
           f"- platform: {doc.get('platform', '?')}",
           f"- runs: {len(runs)} (" + ", ".join(f"{n} {s}" for s, n in counts.items()) + ")",
           "- plots: `report.html` (this file holds the tables)", ""]
    if doc.get("incomplete"):
        out += ["> **Incomplete:** the run was interrupted; only the finished runs are shown.", ""]
    return out


def finding_links(f: fd.Finding, runs_by_key: dict) -> list[tuple[str, str]]:
    """(text, anchor in report.html) of a finding: the run's plots (its case's figure at its dt), its
    row in the Runs table, its engine's conventions."""
    out = []
    run = runs_by_key.get((f.case, f.label, f.dt))
    if run is not None:
        if run.get("trajectory") and run.get("status") in (Status.OK, Status.DIVERGED):
            out.append(("plots", rd.figure_anchor(f.case, f.dt)))
        out.append(("run", rd.run_anchor(run)))
    if f.kind in fd.CONVENTION_KINDS and f.engine and f.engine != REFERENCE_ENGINE:
        out.append((f"{f.engine} conventions", rd.conventions_anchor(f.engine)))
    if f.kind == VERSION_KIND:
        out.append(("versions side by side", VERSIONS_ANCHOR))
    return out


def runs_by_key(runs: list[dict]) -> dict:
    """(case, label, dt) -> run: how a finding finds its run."""
    return {(r["case"], rd.label(r), float(r["dt"])): r for r in runs if finite_or_none(r.get("dt")) is not None}


def finding_line_parts(line: fd.FindingLine, keyed: dict) -> tuple[str, list[tuple[str, list]]]:
    """(the line's lead: 'severity · title · run', [(one item's text, its links)]) of a findings line."""
    f0 = line.items[0]
    lead = f"{line.severity} · {f0.title} · {line.label}"
    items = []
    for f in line.items:
        if len(line.items) == 1:
            text = " ".join(x for x in (fd.where(f) + ":" if fd.where(f) else "", f.text) if x)
            first = "" if f.t_s is None or "t = " in f.text else f"first at t = {f.t_s:.4g} s; "
            text += f" ({first}from {f.source})"
        else:
            nums = fd.numbers(f)
            text = fd.where(f) + (f" ({nums})" if nums else "")
        items.append((text, finding_links(f, keyed)))
    return lead, items


def findings_lines(found: list[fd.Finding], runs: list[dict], comparison=None, tables: str | None = None) -> list[str]:
    out = ["## Findings", "", fd.FINDINGS_NOTE, ""]
    if comparison is not None:
        out += [f"- **baseline** · compare verdict · {verdict_line(comparison)} (see Compare with baseline)"]
    if not found:
        return out + ([""] if comparison is not None else []) + [fd.NO_FINDINGS, ""]
    out[2:2] = [fd.counts_text(found) + ".", ""]
    keyed = runs_by_key(runs)
    for line in fd.summarize(found):
        lead, items = finding_line_parts(line, keyed)
        f0 = line.items[0]
        if len(items) == 1:
            text, links = items[0]
            out.append(f"- **{lead}**: {text}" + _md_links(links, tables))
        else:
            out.append(f"- **{lead}** on {len(items)} runs (from {f0.source}): "
                       + "; ".join(text + _md_links(links, tables) for text, links in items))
    return out + [""]


def _md_links(links: list[tuple[str, str]], tables: str | None = None) -> str:
    """The links of a finding (``tables``: the page of the runs' rows when not report.html)."""
    return (" [" + ", ".join(f"[{t}]({rd.anchor_href(a, tables, 'report.html')})" for t, a in links)
            + "]") if links else ""


def verdict_line(comparison) -> str:
    """The one-line verdict of a comparison with a baseline (the last line of ``freebody compare``)."""
    from ..results.verdict import verdict_line as line

    return line(comparison)


COMPARE_COLUMNS = ("run", "dt", "what", "baseline", "current", "limit", "verdict", "note")
COMPARE_ROWS = 40  # changes shown; the rest: freebody compare


def compare_rows(comparison) -> list[tuple]:
    """The changes of a comparison (failing first), as ``freebody compare`` lists them."""
    from ..results.verdict import change_rows

    return change_rows(comparison)


def compare_lines(comparison) -> list[str]:
    """The "Compare with baseline" section (``freebody compare BASELINE RESULTS``)."""
    out = ["## Compare with baseline", "", f"`{comparison.sources[0]}` against this run: **{verdict_line(comparison)}**",
           ""]
    changed = [(e, b, c) for e, b, c in comparison.versions if b != c]
    if changed:
        out += [md_table(("", "baseline", "this run"), changed), ""]
    out += [f"- {g['text']}" for g in comparison.groups] + ([""] if comparison.groups else [])
    rows = compare_rows(comparison)
    if rows:
        out += [md_table(COMPARE_COLUMNS, rows[:COMPARE_ROWS]), ""]
        if len(rows) > COMPARE_ROWS:
            from ..results.verdict import compare_command

            out += [f"{len(rows) - COMPARE_ROWS} more changes: `{compare_command(comparison, '--all')}`.", ""]
    return out


def verdict_case_lines(case: str, case_runs: list[dict]) -> list[str]:
    """One case's scheme groups and the differences between them (nothing without a judged run)."""
    groups = fd.scheme_groups(case_runs)
    if not groups:
        return []
    rows = []
    for g in groups:
        for dt in g.dts():
            rows.append((g.name, f"{dt:g}", "; ".join(f"{m.label} {fd.member_text(m)}" for m in g.at(dt)),
                         fd.group_error(g, dt)))
    out = [f"### `{case}`", "", md_table(VERDICT_COLUMNS, rows), ""]
    columns, between = fd.between_table(groups)
    if between:
        out += [md_table(columns, between), ""]
    return out


VERDICT_COLUMNS = ("reproduces", "dt (s)", "engine runs: distance to the map (rad) (r: / round-off level)",
                   "orientation error max (rad)")


def verdict_lines(runs: list[dict], compact: bool = False) -> list[str]:
    """The "Verdict per case" section: per case its scheme groups (:func:`verdict_case_lines`); with
    ``compact``, a pointer to report.html's tables instead (:data:`MD_BUDGET_BYTES`)."""
    if compact:  # one judged run is enough to need the pointer
        judged = any(fd.scheme_groups(case_runs) for case_runs in rd.by_case(runs).values())
        body = ["judged"] if judged else []
    else:
        body = [line for case, case_runs in rd.by_case(runs).items() for line in verdict_case_lines(case, case_runs)]
    if not body:
        return ["## Verdict per case", "", "No engine run was judged against the reference maps (only the "
                "reference engine ran, or no engine run was ok).", ""]
    if compact:
        return ["## Verdict per case", "", fd.VERDICT_NOTE, "", VERDICT_MOVED, ""]
    return ["## Verdict per case", "", fd.VERDICT_NOTE, "", fd.BETWEEN_NOTE, "", *body]


VERDICT_MOVED = ("The tables of each case's groups (engine runs per reference map and time step, with their "
                 "distances to the map, and the differences between the groups) are in "
                 "[report.html](report.html#verdict): with them, report.md would exceed its size budget. "
                 "Each run's verdict is also in results.json (`runs[].judgement`); the reference map each "
                 "engine run reproduces is tabled below.")


ERROR_TABLES_NOTE = ("One table per time step (a maximum over time steps would show the coarsest only); "
                     "a status word instead of a number: the run was not ok.")


def error_table_lines(runs: list[dict]) -> list[str]:
    out = ["## Orientation error max (rad) per case, engine run and time step", "", ERROR_TABLES_NOTE, ""]
    by_dt = rd.error_cells(runs)
    if not by_dt:
        return out + ["No runs.", ""]
    cases = list(rd.by_case(runs))
    for dt, cells in by_dt.items():
        cs = [c for c in cases if any(k[0] == c for k in cells)]
        labs = [lab for lab in rd.labels(runs) if any(k[1] == lab for k in cells)]
        rows = []
        for lab in labs:
            row = [lab]
            for c in cs:
                status, v = cells.get((c, lab), ("", None))
                row.append("" if not status else (rd.num(v) if status == Status.OK else status))
            rows.append(row)
        out += [f"### dt = {dt:g} s", "", md_table(["engine run", *cs], rows), ""]
    return out


def overview_lines(doc: dict) -> list[str]:
    runs = doc.get("runs") or []
    out = ["## Engines", "", md_table(("engine", "version", "runs"), rd.engine_versions(doc)), ""]
    versions = side_by_side(doc)
    if versions:
        out += ["## Engine versions side by side", "", VERSIONS_NOTE, "", md_table(*version_table(versions)), ""]
    out += error_table_lines(runs)
    forced = rd.settings_forced(runs)
    note = rd.settings_note(runs)
    out += ["## Settings the adapters forced", "",
            md_table(("engine", "setting", "engine default", "set to"), forced) if forced
            else "No adapter changed an engine default.", ""] + ([note, ""] if note else [])
    repro = rd.reproduction_summary(runs)
    out += ["## Reference map each engine run reproduces", "",
            md_table(rd.REPRODUCTION_COLUMNS, [(*row[:4], rd.num(row[4], ".1e")) for row in repro]) if repro
            else "No engine run was compared with the reference maps (only the reference engine ran, "
                 "or no engine run was ok).", ""]
    ports = rd.port_comparison(runs)
    if ports:
        out += ["## Ported engines against their originals (e.g. MJX vs C MuJoCo)", "",
                md_table(rd.PORT_COLUMNS, ports), ""]
    conventions = rd.engine_conventions(doc)
    if conventions:
        out += ["## Engine conventions and traps", "", rd.CONVENTIONS_NOTE, "",
                md_table(("engine", "convention", "what the adapter does"), conventions), ""]
    return out


def front_matter(doc: dict, source: str, found: list[fd.Finding] | None = None, comparison=None,
                 compact: bool = False, tables: str | None = None) -> list[str]:
    """The report's first part: header, findings, comparison with a baseline, the verdict per case
    (with ``compact``: a pointer to report.html's tables), then the overview tables."""
    runs = doc.get("runs") or []
    if found is None:
        found = fd.find(runs, convergence=doc.get("convergence"), cases=doc.get("cases"))
    out = header_lines(doc, source) + findings_lines(found, runs, comparison, tables)
    if comparison is not None:
        out += compare_lines(comparison)
    return out + verdict_lines(runs, compact) + overview_lines(doc)


def case_section(case: str, runs: list[dict], convergence: list[dict],
                 physics: rd.CasePhysics | None, out_dir: Path | None,
                 pairs: list[rd.Pair] | None = None, compact: bool = False,
                 tables: str | None = None) -> list[str]:
    """One case's section: its description, runs, what was not ok, observed orders and the
    engines' differences at the end.  With ``compact`` (:data:`MD_BUDGET_BYTES`) the runs and the
    differences are pointers to report.html's tables (and results.json's runs), or to the page
    ``tables`` (:data:`freebody.report.data.TABLES_PAGE`) when report.html keeps them apart."""
    out = [f"## Case `{case}`", ""]
    where = (f"[{tables}]({tables}#{rd.tables_anchor(case)})" if tables is not None
             else f"[report.html](report.html#{rd.case_anchor(case)})")
    if physics is not None:
        out += [*physics.lines(), ""]
    if compact:
        out += ["### Runs", "", f"{len(runs)} runs: the table is in {where} and each run's metrics in "
                f"results.json (`runs[]`, case `{case}`).", ""]
    else:
        out += ["### Runs", "", md_table(*run_table(runs)), ""]
    bad = not_ok_lines(runs)
    if bad:
        out += ["Not ok:", "", *bad, ""]
    mine = [e for e in convergence if e.get("case") == case]
    out += ["### Observed order (error ~ dt^p)", ""]
    if mine:
        out += [md_table(CONVERGENCE_COLUMNS, convergence_rows(mine)), ""]
    else:
        out += [f"No engine run of this case ran at {3} or more time steps: no order fitted.", ""]
    out += ["### Engines at the end", ""]
    if pairs is None:
        pairs = rd.pairwise(runs, physics, out_dir)
    if pairs and compact:
        out += [f"{len(pairs)} pairs of runs of different engines at the same time step: their "
                f"final-state differences are tabled in {where}.", ""]
    elif pairs:
        if physics is None:
            out += ["L and E differences need the case's mass and inertia, which this results.json "
                    "does not hold (pass `--case PATH` to `freebody report`).", ""]
        out += [PAIRS_NOTE, "", md_table(PAIR_COLUMNS, pair_rows(pairs)), ""]
    else:
        out += ["No two engines both finished a run of this case at the same time step.", ""]
    return out


PAIRS_NOTE = ("Differences between the final states of runs of different engines: orientation angle, "
              "|L_a - L_b| / mean |L|, |E_a - E_b| / mean KE.  Per dt, the pairs that reproduce the same "
              "reference map first (a difference there beyond round-off is an engine's), then those that "
              "differ by scheme; largest angle first.")
PAIR_COLUMNS = ("dt (s)", "run A", "run B", "orientation (rad)", "L (rel)", "E (rel)", "relation")


def pair_rows(pairs: list[rd.Pair]) -> list[tuple]:
    return [(f"{p.dt:g}", p.a, p.b, rd.num(p.angle_rad), rd.num(p.dL_rel), rd.num(p.dE_rel), p.relation or "-")
            for p in pairs]


def render_markdown(doc: dict, convergence: list[dict], physics: dict[str, rd.CasePhysics | None],
                    out_dir: Path | None = None, source: str = "results.json",
                    pairs: dict[str, list[rd.Pair]] | None = None, found: list[fd.Finding] | None = None,
                    comparison=None, tables: str | None = None) -> str:
    """The whole report.md text.  ``physics``: case name -> CasePhysics (or None); ``pairs``: case
    name -> :func:`report_data.pairwise` (computed here when not given); ``found``: the findings
    (:func:`freebody.report.findings.find`, computed here without trajectories when not given);
    ``comparison``: a :class:`freebody.results.compare.Comparison` with a baseline, or None;
    ``tables``: the page of report.html's per-case tables when apart (data.TABLES_PAGE), or None."""
    runs = doc.get("runs") or []
    if found is None:
        found = fd.find(runs, convergence=doc.get("convergence"), cases=doc.get("cases"))
    pairs = {c: (pairs or {}).get(c) for c in rd.by_case(runs)}
    pairs = {c: rd.pairwise(rs, physics.get(c), out_dir) if pairs[c] is None else pairs[c]
             for c, rs in rd.by_case(runs).items()}
    text = ""
    for compact in (False, True):  # the whole report, or within its budget (MD_BUDGET_BYTES)
        lines = front_matter(doc, source, found, comparison, compact, tables) + observed_order_lines(
            convergence, runs, doc.get("cases"))
        for case, case_runs in rd.by_case(runs).items():
            lines += case_section(case, case_runs, convergence, physics.get(case), out_dir, pairs[case], compact,
                                  tables)
        text = "\n".join(lines).rstrip() + "\n"
        if len(text.encode("utf-8")) <= MD_BUDGET_BYTES:
            break
    return text
