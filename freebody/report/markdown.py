"""report.md: the report's tables as Markdown (the plots are in report.html).

Numbers are printed with fixed formats (%.3e for errors, %.2f for orders), so the text is stable
under last-digit noise and can be compared with golden files.
"""
from __future__ import annotations

from pathlib import Path

from . import data as rd
from ..results.versions import VERSIONS_NOTE, side_by_side, version_table
from ..run.convergence import SHORT_NAMES
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_FINAL,
                           ORIENTATION_ERROR_MAX, POSITION_ERROR_MAX, ROTATION_ORTHONORMALITY_ERROR_MAX)
from ..run.records import Status

RUN_COLUMNS = ("engine run", "dt (s)", "status", "orientation max (rad)", "orientation final (rad)",
               "L max (rel)", "E max (rel)", "position max (m)", "wall s / sim s", "reproduces")
# Shown before "reproduces" when a run of the table integrates R as a matrix (it has the metric).
ORTHONORMALITY_COLUMN = "orthonormality max (||R^T R - 1||_F)"


def md_table(header: tuple[str, ...] | list[str], rows: list) -> str:
    """A Markdown pipe table, columns padded to their widths ('|' in cells escaped)."""
    cells = [[str(c).replace("|", "\\|").replace("\n", " ") for c in row] for row in [header, *rows]]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
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
              "time steps). Expected p: a reference integrator's formal order, or that of the reference "
              "map every run of the engine run on these cases reproduces (-: none does).")


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


def observed_order_lines(convergence: list[dict], runs: list[dict]) -> list[str]:
    """The front page's "Observed order" section (nothing when no case ran at 3 or more dts)."""
    columns, rows = rd.observed_orders(convergence, runs)
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


def front_matter(doc: dict, source: str) -> list[str]:
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
    out += ["## Engines", "", md_table(("engine", "version", "runs"), rd.engine_versions(doc)), ""]
    versions = side_by_side(doc)
    if versions:
        out += ["## Engine versions side by side", "", VERSIONS_NOTE, "", md_table(*version_table(versions)), ""]

    cases = list(rd.by_case(runs))
    cells = rd.worst_cells(runs)
    out += ["## Worst orientation error (rad, max over time and time steps)", "",
            "A status word instead of a number: at least one of the cell's runs was not ok.", ""]
    rows = []
    for lab in rd.labels(runs):
        row = [lab]
        for c in cases:
            status, v = cells.get((c, lab), ("", None))
            row.append("" if not status else (rd.num(v) if status == Status.OK else status))
        rows.append(row)
    out += [md_table(["engine run", *cases], rows) if rows else "No runs.", ""]

    forced = rd.settings_forced(runs)
    out += ["## Settings the adapters forced", "",
            md_table(("engine", "setting", "engine default", "set to"), forced) if forced
            else "No adapter changed an engine default.", ""]
    repro = rd.reproduction_summary(runs)
    out += ["## Reference map each engine run reproduces", "",
            md_table(("engine run", "reproduces", "runs", "max difference (rad)"),
                     [(a, b, n, rd.num(d, ".1e")) for a, b, n, d in repro]) if repro
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


def case_section(case: str, runs: list[dict], convergence: list[dict],
                 physics: rd.CasePhysics | None, out_dir: Path | None,
                 pairs: list[rd.Pair] | None = None) -> list[str]:
    out = [f"## Case `{case}`", ""]
    if physics is not None:
        out += [physics.description, "", f"Truth: {physics.truth or '?'}.", ""]
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
    if pairs:
        if physics is None:
            out += ["L and E differences need the case's mass and inertia, which this results.json "
                    "does not hold (pass `--case PATH` to `freebody report`).", ""]
        out += ["Differences between the final states of runs of different engines, largest first: "
                "orientation angle, |L_a - L_b| / mean |L|, |E_a - E_b| / mean KE.", "",
                md_table(("dt (s)", "run A", "run B", "orientation (rad)", "L (rel)", "E (rel)"),
                         [(f"{p.dt:g}", p.a, p.b, rd.num(p.angle_rad), rd.num(p.dL_rel), rd.num(p.dE_rel))
                          for p in pairs]), ""]
    else:
        out += ["No two engines both finished a run of this case at the same time step.", ""]
    return out


def render_markdown(doc: dict, convergence: list[dict], physics: dict[str, rd.CasePhysics | None],
                    out_dir: Path | None = None, source: str = "results.json",
                    pairs: dict[str, list[rd.Pair]] | None = None) -> str:
    """The whole report.md text.  ``physics``: case name -> CasePhysics (or None); ``pairs``: case
    name -> :func:`report_data.pairwise` (computed here when not given)."""
    lines = front_matter(doc, source) + observed_order_lines(convergence, doc.get("runs") or [])
    for case, runs in rd.by_case(doc.get("runs") or []).items():
        lines += case_section(case, runs, convergence, physics.get(case), out_dir, (pairs or {}).get(case))
    return "\n".join(lines).rstrip() + "\n"
