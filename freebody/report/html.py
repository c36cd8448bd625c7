"""report.html: one self-contained page (inline CSS, plots embedded as base64 PNG data URIs) that
opens offline in any browser.  Same tables as report.md, plus the figures."""
from __future__ import annotations

import base64
from html import escape
from pathlib import Path

from . import data as rd
from . import markdown as md
from ..results.versions import VERSIONS_NOTE, side_by_side, version_table
from ..run.records import Status

CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 1.5em auto; max-width: 1400px;
       padding: 0 1em; color: #222; line-height: 1.4; }
h1 { margin-bottom: 0.2em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
h3 { margin-top: 1.4em; }
table { border-collapse: collapse; font-size: 12px; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 2px 6px; text-align: left; white-space: nowrap; }
th { background: #f3f3f3; } td.num { font-family: ui-monospace, monospace; text-align: right; }
td.ok { color: #1a7f37; } td.diverged { background: #333; color: #fff; } td.failed { background: #b2182b; color: #fff; }
td.skipped { background: #e5e5e5; color: #555; }
.meta { color: #555; font-size: 13px; } .note { color: #555; font-size: 13px; }
.warn { background: #fff3cd; border: 1px solid #e0c36b; padding: 0.5em 1em; }
img { max-width: 100%; height: auto; display: block; margin: 0.5em 0; border: 1px solid #eee; }
nav a { margin-right: 0.8em; display: inline-block; } details summary { cursor: pointer; color: #0550ae; }
.scroll { overflow-x: auto; } table.wrap td { white-space: normal; max-width: 60em; }
"""
NUMERIC = {"dt (s)", "orientation max (rad)", "orientation final (rad)", "L max (rel)", "E max (rel)",
           "position max (m)", "wall s / sim s", "runs", "max difference (rad)", "order p",
           "orientation (rad)", "L (rel)", "E (rel)", md.ORTHONORMALITY_COLUMN, "fit rms (decades)",
           rd.ORDER_FIT_COLUMN}
FOLD_ROWS = 16  # longer tables are folded in a <details> element


def img(png: bytes | None, alt: str) -> str:
    if png is None:
        return f'<p class="note">({escape(alt)}: nothing to plot)</p>'
    data = base64.b64encode(png).decode("ascii")
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{data}">'


def table(header, rows, status_col: int | None = None, fold: str | None = None, wrap: bool = False) -> str:
    head = "".join(f"<th>{escape(str(h))}</th>" for h in header)
    body = []
    for row in rows:
        cells = []
        for i, c in enumerate(row):
            cls = []
            if header[i] in NUMERIC:
                cls.append("num")
            if i == status_col or str(c) in (Status.DIVERGED, Status.FAILED, Status.SKIPPED):
                cls.append(str(c))
            attr = f' class="{" ".join(cls)}"' if cls else ""
            cells.append(f"<td{attr}>{escape(str(c))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    html = f'<div class="scroll"><table{" class=wrap" if wrap else ""}><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table></div>'
    if fold and len(rows) > FOLD_ROWS:
        html = f"<details><summary>{escape(fold)} ({len(rows)} rows)</summary>{html}</details>"
    return html


def anchor(case: str) -> str:
    return "case-" + "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in case)


def render_html(doc: dict, convergence: list[dict], physics: dict, figures: dict, notes: dict,
                out_dir: Path | None = None, source: str = "results.json",
                pairs: dict[str, list] | None = None) -> str:
    """The whole report.html.  ``figures``: 'heatmap', 'convergence', 'speed' and (case, dt) -> PNG
    bytes or None; ``notes``: case -> lines about runs that could not be drawn."""
    runs = doc.get("runs") or []
    cases = rd.by_case(runs)
    p = _head_html(doc, runs, cases, source)
    p += _overview_html(doc, runs, figures, convergence)
    for case, case_runs in cases.items():
        case_pairs = (pairs or {}).get(case)
        p += _case_html(case, case_runs, physics.get(case), convergence, case_pairs, figures,
                        notes.get(case, []), out_dir)
    p.append("</body></html>\n")
    return "\n".join(p)


def _head_html(doc: dict, runs: list[dict], cases: dict, source: str) -> list[str]:
    """The page's head, title, provenance line, incomplete warning and case navigation."""
    counts = rd.status_counts(runs)
    p = []
    p.append("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
             "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
             f"<title>freebody report</title><style>{CSS}</style></head><body>")
    p.append("<h1>freebody report</h1>")
    p.append(f'<p class="meta">results <code>{escape(source)}</code> (schema {escape(str(doc.get("schema_version")))}), '
             f'freebody {escape(str(doc.get("freebody_version", "?")))}, created {escape(str(doc.get("created", "?")))}'
             f'<br>platform: {escape(str(doc.get("platform", "?")))}<br>runs: {len(runs)} ('
             + ", ".join(f"{n} {s}" for s, n in counts.items()) + ")</p>")
    if doc.get("incomplete"):
        p.append('<p class="warn"><b>Incomplete:</b> the run was interrupted; only the finished runs are shown.</p>')
    p.append("<nav><b>Cases:</b> " + " ".join(f'<a href="#{anchor(c)}">{escape(c)}</a>' for c in cases) + "</nav>")
    return p


def _overview_html(doc: dict, runs: list[dict], figures: dict, convergence: list[dict] | None = None) -> list[str]:
    """The sections over all cases: engines, heat map, convergence, speed, forced settings,
    reproduced reference maps, ported engines."""
    p = []
    p.append("<h2>Engines</h2>" + table(("engine", "version", "runs"), rd.engine_versions(doc)))
    versions = side_by_side(doc)
    if versions:
        p.append("<h2>Engine versions side by side</h2>"
                 f'<p class="note">{escape(VERSIONS_NOTE)}</p>' + table(*version_table(versions)))
    p.append("<h2>Worst orientation error per case and engine run</h2>"
             '<p class="note">Colour: the largest orientation error (rad, log scale) over time and over the '
             "time steps of the cell's ok runs. Dark: a run diverged; red: a run failed; grey: skipped.</p>")
    p.append(img(figures.get("heatmap"), "heat map"))
    p.append("<h2>Convergence</h2>"
             '<p class="note">Error against time step (log-log) for the cases run at 3 or more time steps '
             "(else at 2); dotted: the least-squares fit; the legend gives "
             "the observed order p for the orientation and the energy error (sat.: the errors saturate, "
             "at order pi or at the truth's accuracy floor, so no order is meaningful).</p>")
    p.append(img(figures.get("convergence"), "convergence"))
    columns, rows = rd.observed_orders(convergence or [], runs)
    if rows:
        p.append("<h3>Observed order of convergence per engine run</h3>"
                 f'<p class="note">{escape(md.ORDER_NOTE)}</p>' + table(columns, rows))
    p.append("<h2>Speed and accuracy</h2>"
             '<p class="note">Orientation error against wall-clock time per simulated second, one point per '
             "time step (lower left is better).</p>")
    p.append(img(figures.get("speed"), "speed-accuracy"))
    forced = rd.settings_forced(runs)
    p.append("<h2>Settings the adapters forced</h2>" + (
        table(("engine", "setting", "engine default", "set to"), forced) if forced
        else '<p class="note">No adapter changed an engine default.</p>'))
    repro = rd.reproduction_summary(runs)
    p.append("<h2>Reference map each engine run reproduces</h2>" + (
        table(("engine run", "reproduces", "runs", "max difference (rad)"),
              [(a, b, n, rd.num(max_diff, ".1e")) for a, b, n, max_diff in repro]) if repro
        else '<p class="note">No engine run was compared with the reference maps.</p>'))
    ports = rd.port_comparison(runs)
    if ports:
        p.append("<h2>Ported engines against their originals (e.g. MJX vs C MuJoCo)</h2>"
                 + table(rd.PORT_COLUMNS, ports))
    conventions = rd.engine_conventions(doc)
    if conventions:
        p.append("<h2>Engine conventions and traps</h2>"
                 f'<p class="note">{escape(rd.CONVENTIONS_NOTE)}</p>'
                 + table(("engine", "convention", "what the adapter does"), conventions,
                         fold="the conventions of each engine", wrap=True))
    return p


def _case_html(case: str, case_runs: list[dict], ph, convergence: list[dict], case_pairs: list | None,
               figures: dict, case_notes: list[str], out_dir: Path | None) -> list[str]:
    """One case's section: description, runs, what was not ok, observed orders, engine-vs-engine
    differences at the end (``case_pairs``, computed here when None) and the per-dt figures.
    ``ph``: the case's rd.CasePhysics, or None."""
    p = []
    p.append(f'<h2 id="{anchor(case)}">Case <code>{escape(case)}</code></h2>')
    if ph is not None:
        p.append(f"<p>{escape(ph.description)}</p><p class=\"note\">Truth: {escape(ph.truth or '?')}.</p>")
    p.append("<h3>Runs</h3>" + table(*md.run_table(case_runs), status_col=2))
    bad = [r for r in case_runs if r.get("status") != Status.OK]
    if bad:
        items = dict.fromkeys(f"{rd.label(r)} dt = {float(r['dt']):g} s: {r.get('status')}: "
                              f"{(r.get('message') or '').strip() or '(no message)'}" for r in bad)
        p.append("<p>Not ok:</p><ul>" + "".join(f"<li>{escape(x)}</li>" for x in items) + "</ul>")
    mine = [e for e in convergence if e.get("case") == case]
    p.append("<h3>Observed order (error ~ dt<sup>p</sup>)</h3>" + (
        table(md.CONVERGENCE_COLUMNS, md.convergence_rows(mine)) if mine
        else '<p class="note">No engine run of this case ran at 3 or more time steps: no order fitted.</p>'))
    if case_pairs is None:
        case_pairs = rd.pairwise(case_runs, ph, out_dir)
    p.append("<h3>Engines at the end</h3>")
    if case_pairs:
        p.append('<p class="note">Final states of runs of different engines: orientation angle, '
                 "|L<sub>a</sub> - L<sub>b</sub>| / mean |L|, |E<sub>a</sub> - E<sub>b</sub>| / mean KE; "
                 "largest angle first.</p>")
        if ph is None:
            p.append('<p class="note">L and E need the case\'s mass and inertia, not in this results.json '
                     "(pass <code>--case PATH</code> to <code>freebody report</code>).</p>")
        p.append(table(("dt (s)", "run A", "run B", "orientation (rad)", "L (rel)", "E (rel)"),
                       [(f"{q.dt:g}", q.a, q.b, rd.num(q.angle_rad), rd.num(q.dL_rel), rd.num(q.dE_rel))
                        for q in case_pairs], fold="engine-vs-engine differences"))
    else:
        p.append('<p class="note">No two engines both finished a run of this case at the same time step.</p>')
    p.append("<h3>Errors and angular velocity against time</h3>")
    for dt in rd.dts(case_runs):
        p.append(img(figures.get((case, dt)), f"{case} dt={dt:g}"))
    for line in case_notes:
        p.append(f'<p class="note">{escape(line)}</p>')
    return p
