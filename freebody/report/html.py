"""report.html: one self-contained page (inline CSS and a few lines of script, plots embedded as
base64 PNG data URIs) that opens offline in any browser.  Same tables as report.md, plus the
figures.

The page opens on the verdict: the findings (each linking to the run, its plots and its engine's
conventions), the comparison with a baseline when one was given, and per case the engine runs
grouped by the reference map they reproduce.  Tables fit a laptop screen: text cells wrap, numbers
do not, and a table still wider than the page scrolls inside its own box.
"""
from __future__ import annotations

import base64
from html import escape
from pathlib import Path

from . import data as rd
from . import findings as fd
from . import markdown as md
from ..envs.versions import VERSIONS_NOTE, side_by_side, version_table
from .version_findings import VERSIONS_ANCHOR
from ..run.records import Status

CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 1.5em auto; max-width: 1400px;
       padding: 0 1em; color: #222; line-height: 1.4; }
h1 { margin-bottom: 0.2em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
h3 { margin-top: 1.4em; }
table { border-collapse: collapse; font-size: 12px; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 2px 6px; text-align: left; vertical-align: top;
         white-space: normal; overflow-wrap: break-word; }
th { background: #f3f3f3; }
td.num { font-family: ui-monospace, monospace; text-align: right; white-space: nowrap; overflow-wrap: normal; }
td.label { white-space: nowrap; }
td.ok { color: #1a7f37; } td.diverged { background: #333; color: #fff; } td.failed { background: #b2182b; color: #fff; }
td.skipped { background: #e5e5e5; color: #555; }
.meta { color: #555; font-size: 13px; } .note { color: #555; font-size: 13px; max-width: 75em; }
.warn { background: #fff3cd; border: 1px solid #e0c36b; padding: 0.5em 1em; }
img { max-width: 100%; height: auto; display: block; margin: 0.5em 0; border: 1px solid #eee; }
figure { margin: 0; }
nav a { margin-right: 0.8em; display: inline-block; } details summary { cursor: pointer; color: #0550ae; }
.scroll { overflow-x: auto; max-width: 100%; }
ul.findings { padding-left: 1.2em; } ul.findings li { margin: 0.25em 0; }
.sev { display: inline-block; min-width: 4.5em; text-align: center; border-radius: 3px; padding: 0 4px;
       font-size: 12px; font-weight: 600; }
.sev-error { background: #b2182b; color: #fff; } .sev-warning { background: #E69F00; color: #000; }
.sev-info { background: #d9ecf7; color: #000; } .sev-baseline { background: #555; color: #fff; }
.links a { margin-left: 0.4em; font-size: 12px; }
details.case { margin: 0.3em 0; } details.case > summary { font-weight: 600; }
:target { outline: 2px solid #0072B2; }
"""
# Opens the folded sections (<details>) holding the target of a link, so #anchors always land.
SCRIPT = """
function freebodyOpen() {
  var id = decodeURIComponent(location.hash.slice(1)); if (!id) return;
  var el = document.getElementById(id); if (!el) return;
  for (var p = el; p; p = p.parentElement) { if (p.tagName === 'DETAILS') p.open = true; }
  el.scrollIntoView();
}
window.addEventListener('hashchange', freebodyOpen);
window.addEventListener('DOMContentLoaded', freebodyOpen);
"""
NUMERIC = {"dt (s)", "orientation max (rad)", "orientation final (rad)", "L max (rel)", "E max (rel)",
           "position max (m)", "wall s / sim s", "runs", "max difference (rad)", "order p",
           "orientation (rad)", "L (rel)", "E (rel)", md.ORTHONORMALITY_COLUMN, "fit rms (decades)",
           rd.ORDER_FIT_COLUMN, "max distance (rad)", "orientation error max (rad)", "dt"}
LABEL_COLUMNS = {"engine run", "run A", "run B", "run"}
FOLD_ROWS = 16  # longer tables are folded in a <details> element


class Html(str):
    """A table cell that is markup already (links), not text to escape."""


def _cell(c) -> str:
    return str(c) if isinstance(c, Html) else escape(str(c))


def img(png: bytes | None, alt: str, anchor: str | None = None) -> str:
    ident = f' id="{escape(anchor)}"' if anchor else ""
    if png is None:
        return f'<p class="note"{ident}>({escape(alt)}: nothing to plot)</p>'
    data = base64.b64encode(png).decode("ascii")
    return f'<figure{ident}><img alt="{escape(alt)}" src="data:image/png;base64,{data}"></figure>'


def table(header, rows, status_col: int | None = None, fold: str | None = None, wrap: bool = False,
          row_ids: list[str | None] | None = None) -> str:
    """A table in a box that scrolls sideways if the table is wider than the page.  Numbers do not
    wrap; text does.  ``row_ids``: an id per row (link targets), or None."""
    head = "".join(f"<th>{escape(str(h))}</th>" for h in header)
    body = []
    for k, row in enumerate(rows):
        cells = []
        for i, c in enumerate(row):
            cls = []
            if header[i] in NUMERIC or str(header[i]).startswith("dt = "):
                cls.append("num")
            if header[i] in LABEL_COLUMNS:
                cls.append("label")
            if i == status_col or str(c) in (Status.DIVERGED, Status.FAILED, Status.SKIPPED):
                cls.append(str(c))
            attr = f' class="{" ".join(cls)}"' if cls else ""
            cells.append(f"<td{attr}>{_cell(c)}</td>")
        ident = row_ids[k] if row_ids else None
        body.append(f'<tr{f" id={chr(34)}{escape(ident)}{chr(34)}" if ident else ""}>' + "".join(cells) + "</tr>")
    html = (f'<div class="scroll"><table{" class=wrap" if wrap else ""}><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(body)}</tbody></table></div>')
    if fold and len(rows) > FOLD_ROWS:
        html = f"<details><summary>{escape(fold)} ({len(rows)} rows)</summary>{html}</details>"
    return html


def anchor(case: str) -> str:
    return rd.case_anchor(case)


def render_html(doc: dict, convergence: list[dict], physics: dict, figures: dict, notes: dict,
                out_dir: Path | None = None, source: str = "results.json",
                pairs: dict[str, list] | None = None, found: list[fd.Finding] | None = None,
                comparison=None, tables: str | None = None) -> str:
    """The whole report.html.  ``figures``: 'heatmap', 'convergence', 'speed' and (case, dt) -> PNG
    bytes or None; ``notes``: case -> lines about runs that could not be drawn; ``found``: the
    findings (computed here without trajectories when None); ``comparison``: a comparison with a
    baseline (:func:`freebody.report.render.compare_with`), or None; ``tables``: None (the per-case
    Runs and engine-vs-engine tables in the page), or the page holding them
    (:data:`freebody.report.data.TABLES_PAGE`, :func:`render_tables_html`), pointed to instead."""
    return render_html_later(doc, convergence, physics, out_dir, source, pairs, found, comparison,
                             tables)(figures, notes)


def render_html_later(doc: dict, convergence: list[dict], physics: dict, out_dir: Path | None = None,
                      source: str = "results.json", pairs: dict[str, list] | None = None,
                      found: list[fd.Finding] | None = None, comparison=None, tables: str | None = None):
    """report.html written before its figures are drawn: returns ``fill(figures, notes)``, which
    gives :func:`render_html` of these arguments (the same text), putting the figures and notes in
    the places kept for them.  ``freebody report`` writes the page while worker processes draw."""
    runs = doc.get("runs") or []
    cases = rd.by_case(runs)
    if found is None:
        found = fd.find(runs, convergence=convergence, cases=doc.get("cases"))
    later = _Later()
    p = _head_html(doc, runs, cases, source, comparison)
    p += _findings_html(found, runs, comparison, tables)
    if comparison is not None:
        p += _compare_html(comparison)
    p += _verdict_html(runs, found, tables)
    p += _overview_html(doc, runs, later.figure, convergence)
    for case, case_runs in cases.items():
        case_pairs = (pairs or {}).get(case)
        p += _case_html(case, case_runs, physics.get(case), convergence, case_pairs, later.figure,
                        later.notes(case), out_dir, tables)
    p.append("</body></html>\n")
    return later.filler("\n".join(p))


class _Later:
    """Places kept in a page for what is not known yet (figures, and the notes about runs that
    could not be drawn): a mark unique to the page and a number, replaced by :meth:`filler`'s
    function in one pass."""

    def __init__(self):
        import uuid

        self.mark = f"\x00{uuid.uuid4().hex}:"  # no page text holds it
        self.parts: list = []  # (figures, notes) -> text

    def _slot(self, make) -> str:
        self.parts.append(make)
        return f"{self.mark}{len(self.parts) - 1}\x00"

    def figure(self, key, alt: str, ident: str | None = None) -> str:
        """The place of figure ``key`` (its :func:`img`)."""
        return self._slot(lambda figures, notes: img(figures.get(key), alt, ident))

    def notes(self, case: str) -> str:
        """The place of a case's notes: each a paragraph on a line of its own, after the text
        it follows."""
        return self._slot(lambda figures, notes: "".join(f'\n<p class="note">{escape(line)}</p>'
                                                        for line in notes.get(case, [])))

    def filler(self, page: str):
        import re

        pattern = re.compile(re.escape(self.mark) + r"(\d+)\x00")
        return lambda figures, notes: pattern.sub(lambda m: self.parts[int(m.group(1))](figures, notes), page)


def _head_html(doc: dict, runs: list[dict], cases: dict, source: str, comparison=None) -> list[str]:
    """The page's head, title, provenance line, incomplete warning and navigation (every section
    with an id, the comparison with a baseline and the engine versions when the page has them)."""
    counts = rd.status_counts(runs)
    p = [_page_head("freebody report"), "<h1>freebody report</h1>"]
    p.append(f'<p class="meta">results <code>{escape(source)}</code> (schema {escape(str(doc.get("schema_version")))}), '
             f'freebody {escape(str(doc.get("freebody_version", "?")))}, created {escape(str(doc.get("created", "?")))}'
             f'<br>platform: {escape(str(doc.get("platform", "?")))}<br>runs: {len(runs)} ('
             + ", ".join(f"{n} {s}" for s, n in counts.items()) + ")</p>")
    if doc.get("incomplete"):
        p.append('<p class="warn"><b>Incomplete:</b> the run was interrupted; only the finished runs are shown.</p>')
    p.append('<nav><b>Sections:</b> <a href="#findings">Findings</a> '
             + ('<a href="#compare">Compare with baseline</a> ' if comparison is not None else '')
             + '<a href="#verdict">Verdict per case</a> '
             + (f'<a href="#{VERSIONS_ANCHOR}">Engine versions</a> ' if side_by_side(doc) else '')
             + '<a href="#errors">Errors</a> <a href="#convergence">Convergence</a> <a href="#speed">Speed</a> '
             '<a href="#settings">Settings</a> <a href="#conventions">Conventions</a><br><b>Cases:</b> '
             + " ".join(f'<a href="#{anchor(c)}">{escape(c)}</a>' for c in cases) + "</nav>")
    return p


def _page_head(title: str) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{escape(title)}</title><style>{CSS}</style><script>{SCRIPT}</script></head><body>")


def _links(links: list[tuple[str, str]], tables: str | None = None) -> str:
    return ('<span class="links">' + "".join(f'<a href="{escape(rd.anchor_href(a, tables))}">{escape(t)}</a>'
                                             for t, a in links) + "</span>") if links else ""


def _findings_html(found: list[fd.Finding], runs: list[dict], comparison, tables: str | None = None) -> list[str]:
    p = ['<h2 id="findings">Findings</h2>']
    p.append(f'<p class="note">{escape(fd.counts_text(found))}. {escape(fd.FINDINGS_NOTE)}</p>')
    items = []
    if comparison is not None:
        items.append('<li><span class="sev sev-baseline">baseline</span> compare verdict: '
                     f'{escape(md.verdict_line(comparison))} {_links([("comparison", "compare")])}</li>')
    keyed = md.runs_by_key(runs)
    for line in fd.summarize(found):
        lead, parts = md.finding_line_parts(line, keyed)
        f0 = line.items[0]
        head = (f'<span class="sev sev-{escape(line.severity)}">{escape(line.severity)}</span> '
                f'{escape(f0.title)}: <b>{escape(line.label)}</b>')
        if len(parts) == 1:
            text, links = parts[0]
            items.append(f"<li>{head} {escape(text)} {_links(links, tables)}</li>")
        else:
            sub = "".join(f"<li>{escape(text)} {_links(links, tables)}</li>" for text, links in parts)
            items.append(f"<li>{head} on {len(parts)} runs (from {escape(f0.source)}): "
                         f"<details><summary>the runs</summary><ul>{sub}</ul></details></li>")
    if items:
        p.append('<ul class="findings">' + "".join(items) + "</ul>")
    if not found:
        p.append(f"<p>{escape(fd.NO_FINDINGS)}</p>")
    return p


def _compare_html(comparison) -> list[str]:
    p = ['<h2 id="compare">Compare with baseline</h2>',
         f"<p><code>{escape(comparison.sources[0])}</code> against this run: "
         f"<b>{escape(md.verdict_line(comparison))}</b></p>"]
    changed = [(e, b, c) for e, b, c in comparison.versions if b != c]
    if changed:
        p.append(table(("", "baseline", "this run"), changed))
    if comparison.groups:
        p.append("<ul>" + "".join(f"<li>{escape(g['text'])}</li>" for g in comparison.groups) + "</ul>")
    rows = md.compare_rows(comparison)
    if rows:
        p.append(table(md.COMPARE_COLUMNS, rows[:md.COMPARE_ROWS], fold="the changes"))
        if len(rows) > md.COMPARE_ROWS:
            from ..results.verdict import compare_command

            p.append(f'<p class="note">{len(rows) - md.COMPARE_ROWS} more changes: '
                     f'<code>{escape(compare_command(comparison, "--all"))}</code>.</p>')
    return p


def _run_link(run: dict, text: str, tables: str | None = None) -> str:
    return f'<a href="{escape(rd.anchor_href(rd.run_anchor(run), tables))}">{escape(text)}</a>'


def _runs_text(n: int) -> str:
    return f"{n} engine run{'' if n == 1 else 's'}"


def _verdict_html(runs: list[dict], found: list[fd.Finding], tables: str | None = None) -> list[str]:
    """Per case, the scheme groups (folded; open where the case has a finding) and the
    differences between groups, attributed to the schemes."""
    p = ['<h2 id="verdict">Verdict per case</h2>']
    cases = rd.by_case(runs)
    flagged = {f.case for f in found if f.severity in ("error", "warning")}
    body = []
    for case, case_runs in cases.items():
        groups = fd.scheme_groups(case_runs)
        if not groups:
            continue
        rows = []
        for g in groups:
            name = Html(f'<span title="{escape(g.tie_text)}">{escape(g.name)}</span>')
            for dt in g.dts():
                members = Html("; ".join(f"{_run_link(m.run, m.label, tables)} {escape(fd.member_text(m))}"
                                         for m in g.at(dt)))
                rows.append((name, f"{dt:g}", members, fd.group_error(g, dt)))
        html = table(md.VERDICT_COLUMNS, rows)
        columns, between = fd.between_table(groups)
        if between:
            html += table(columns, between)
        summary = (f"{escape(case)}: {len(groups)} group{'s' if len(groups) > 1 else ''} ("
                   + "; ".join(f"{escape(g.name)}: {_runs_text(len({m.label for m in g.members}))}" for g in groups)
                   + ")" + (" · finding" if case in flagged else ""))
        body.append(f'<details class="case"{" open" if case in flagged else ""}><summary>{summary}</summary>'
                    f'{html}<p class="note"><a href="#{anchor(case)}">the case\'s runs and plots</a></p></details>')
    if not body:
        p.append('<p class="note">No engine run was judged against the reference maps (only the reference '
                 "engine ran, or no engine run was ok).</p>")
        return p
    p.append(f'<p class="note">{escape(fd.VERDICT_NOTE)} {escape(fd.BETWEEN_NOTE)} Cases with a finding are '
             "open; click a case to open the others.</p>")
    return p + body


def _overview_html(doc: dict, runs: list[dict], figure, convergence: list[dict] | None = None) -> list[str]:
    """The sections over all cases: engines, heat maps, convergence, speed, forced settings,
    reproduced reference maps, ported engines, conventions.  ``figure(key, alt)``: a figure's
    markup (:meth:`_Later.figure`)."""
    p = []
    p.append("<h2>Engines</h2>" + table(("engine", "version", "runs"), rd.engine_versions(doc)))
    versions = side_by_side(doc)
    if versions:
        p.append(f'<h2 id="{VERSIONS_ANCHOR}">Engine versions side by side</h2>'
                 f'<p class="note">{escape(VERSIONS_NOTE)}</p>' + table(*version_table(versions)))
    p.append('<h2 id="errors">Orientation error per case, engine run and time step</h2>'
             '<p class="note">One panel per time step (a maximum over time steps would show the coarsest '
             "only), one colour scale for all: the orientation error max (rad, log scale) of each run. "
             "Dark: the run diverged; red: failed; grey: skipped; white: not run at that time step. "
             "The column labels are repeated above the first panel and below the last.</p>")
    p.append(figure("heatmap", "heat map"))
    p.append('<h2 id="convergence">Convergence</h2>'
             '<p class="note">Error against time step (log-log) for the cases run at 3 or more time steps '
             "(else at 2); dotted: the least-squares fit; the legend gives "
             "the observed order p for the orientation and the energy error (sat.: the errors saturate, "
             "at order pi or at the truth's accuracy floor, so no order is meaningful). Colour: the engine "
             "(colour-blind safe, black: the reference engine); line style and marker: its integrator.</p>")
    p.append(figure("convergence", "convergence"))
    columns, rows = rd.observed_orders(convergence or [], runs, doc.get("cases"))
    if rows:
        p.append("<h3>Observed order of convergence per engine run</h3>"
                 f'<p class="note">{escape(md.ORDER_NOTE)}</p>' + table(columns, rows))
    p.append('<h2 id="speed">Speed and accuracy</h2>'
             '<p class="note">Orientation error against wall-clock time per simulated second, one point per '
             "time step (lower left is better); the legend at the right of the first row.</p>")
    p.append(figure("speed", "speed-accuracy"))
    forced = rd.settings_forced(runs)
    note = rd.settings_note(runs)
    p.append('<h2 id="settings">Settings the adapters forced</h2>' + (
        table(("engine", "setting", "engine default", "set to"), forced) if forced
        else '<p class="note">No adapter changed an engine default.</p>')
        + (f'<p class="note">{escape(note)}</p>' if note else ""))
    repro = rd.reproduction_summary(runs)
    p.append("<h2>Reference map each engine run reproduces</h2>" + (
        table(rd.REPRODUCTION_COLUMNS, [(*row[:4], rd.num(row[4], ".1e")) for row in repro]) if repro
        else '<p class="note">No engine run was compared with the reference maps.</p>'))
    ports = rd.port_comparison(runs)
    if ports:
        p.append("<h2>Ported engines against their originals (e.g. MJX vs C MuJoCo)</h2>"
                 + table(rd.PORT_COLUMNS, ports))
    conventions = rd.engine_conventions(doc)
    if conventions:
        p.append('<h2 id="conventions">Engine conventions and traps</h2>'
                 f'<p class="note">{escape(rd.CONVENTIONS_NOTE)}</p>')
        by_engine: dict[str, list] = {}
        for engine, key, text in conventions:
            by_engine.setdefault(engine, []).append((key, text))
        for engine, rows in by_engine.items():
            p.append(f'<details id="{escape(rd.conventions_anchor(engine))}"><summary>{escape(engine)} '
                     f"({len(rows)} conventions)</summary>"
                     + table(("convention", "what the adapter does"), rows, wrap=True) + "</details>")
    return p


def _case_html(case: str, case_runs: list[dict], ph, convergence: list[dict], case_pairs: list | None,
               figure, case_notes: str, out_dir: Path | None, tables: str | None = None) -> list[str]:
    """One case's section: description, runs (a row id per run), what was not ok, observed
    orders, engine-vs-engine differences at the end (``case_pairs``, computed here when None) and
    the per-dt figures (an id per figure), ``figure(key, alt, id)`` their markup, with the notes
    about runs that could not be drawn after them (``case_notes``: markup, each note starting a
    line).  ``ph``: the case's rd.CasePhysics, or None; ``tables``: the page holding the case's
    Runs and engine-vs-engine tables (pointed to), or None (here)."""
    p = []
    p.append(f'<h2 id="{anchor(case)}">Case <code>{escape(case)}</code></h2>')
    if ph is not None:
        first, *rest = [line for line in ph.lines() if line]
        p.append(f"<p>{escape(first)}</p>" + "".join(f'<p class="note">{escape(line)}</p>' for line in rest))
    there = f'<a href="{escape(tables or "")}#{escape(rd.tables_anchor(case))}">{escape(tables or "")}</a>'
    p.append("<h3>Runs</h3>" + (runs_table_html(case_runs) if tables is None else
                                f'<p class="note">{len(case_runs)} runs: the table is in {there} (apart: '
                                "with it, this page would exceed its size budget), each run's metrics in "
                                f"results.json (<code>runs[]</code>, case <code>{escape(case)}</code>).</p>"))
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
    if case_pairs and tables is not None:
        p.append(f'<p class="note">{len(case_pairs)} pairs of runs of different engines at the same time '
                 f"step: their final-state differences are tabled in {there}.</p>")
    else:
        p += pairs_html(case_pairs, ph)
    p.append("<h3>Errors and angular velocity against time</h3>"
             '<p class="note">Colour: the engine (black: the reference engine); line style and marker: its '
             "integrator; the legend at the right.</p>")
    for dt in rd.dts(case_runs):
        p.append(figure((case, dt), f"{case} dt={dt:g}", rd.figure_anchor(case, dt)))
    p[-1] += case_notes
    return p


def runs_table_html(case_runs: list[dict]) -> str:
    """A case's Runs table, each row's id its run's anchor (:func:`freebody.report.data.run_anchor`)."""
    order = {lab: i for i, lab in enumerate(rd.labels(case_runs))}
    ordered = sorted(case_runs, key=lambda r: (order[rd.label(r)], -float(r["dt"])))
    return table(*md.run_table(case_runs), status_col=2, row_ids=[rd.run_anchor(r) for r in ordered])


def pairs_html(case_pairs: list, ph) -> list[str]:
    """A case's engine-vs-engine differences at the end (folded when long), or why there are none."""
    if not case_pairs:
        return ['<p class="note">No two engines both finished a run of this case at the same time step.</p>']
    p = [f'<p class="note">{escape(md.PAIRS_NOTE)}</p>']
    if ph is None:
        p.append('<p class="note">L and E need the case\'s mass and inertia, not in this results.json '
                 "(pass <code>--case PATH</code> to <code>freebody report</code>).</p>")
    return p + [table(md.PAIR_COLUMNS, md.pair_rows(case_pairs), fold="engine-vs-engine differences")]


def tables_apart(runs: list[dict], pairs: dict[str, list], physics: dict) -> bool:
    """Whether the per-case Runs and engine-vs-engine tables go to their own page
    (:data:`freebody.report.data.TABLES_PAGE`): their markup exceeds TABLES_INLINE_MAX_BYTES."""
    size = 0
    for case, case_runs in rd.by_case(runs).items():
        size += len(runs_table_html(case_runs)) + sum(map(len, pairs_html(pairs.get(case), physics.get(case))))
        if size > rd.TABLES_INLINE_MAX_BYTES:
            return True
    return False


def render_tables_html(doc: dict, physics: dict, pairs: dict[str, list], source: str = "results.json") -> str:
    """:data:`freebody.report.data.TABLES_PAGE`: every case's Runs table (the rows report.html's
    links lead to) and engine-vs-engine differences, one section per case (``#tables-CASE``)."""
    runs = doc.get("runs") or []
    cases = rd.by_case(runs)
    p = [_page_head("freebody report: tables"), "<h1>freebody report: the per-case tables</h1>",
         f'<p class="meta">results <code>{escape(source)}</code>, created {escape(str(doc.get("created", "?")))}: '
         'the tables of <a href="report.html">report.html</a> (its findings, verdict, overview and '
         "figures) that would make it exceed its size budget.</p>",
         "<nav><b>Cases:</b> " + " ".join(f'<a href="#{rd.tables_anchor(c)}">{escape(c)}</a>' for c in cases)
         + "</nav>"]
    for case, case_runs in cases.items():
        p.append(f'<h2 id="{rd.tables_anchor(case)}">Case <code>{escape(case)}</code> '
                 f'<a class="links" href="report.html#{anchor(case)}">(its section in report.html)</a></h2>')
        p.append("<h3>Runs</h3>" + runs_table_html(case_runs))
        p.append("<h3>Engines at the end</h3>")
        p += pairs_html(pairs.get(case), physics.get(case))
    p.append("</body></html>\n")
    return "\n".join(p)
