"""What ``freebody run`` prints: a compact summary that fits a screen (:func:`terminal_summary`: a
matrix of cases x engines, the runs that are not ok grouped, the status counts), where to look next
(:func:`where_to_look`), and with ``--table`` the full per-run table (:func:`summary_table`)."""
from __future__ import annotations

import re
import shlex
import sys
from pathlib import Path

from ..errors import printable
from ..run.progress import terminal_width
from .. import tolerances as tol
from ..numbers import finite_or_none
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_MAX,
                           POSITION_ERROR_MAX)
from ..run.records import STATUSES, Status
from ..results import identification


def fmt(x, spec: str = ".3e") -> str:
    """A number in a fixed format, '-' for None (undefined or not applicable)."""
    return "-" if x is None else format(x, spec)


def run_label(run: dict) -> str:
    """engine/integrator, with the precision when it is not float64."""
    label = f"{run['engine']}/{run['integrator']}"
    if run.get("precision", "float64") != "float64":
        label += f"/{run['precision']}"
    return label


def reproduced_text(match: dict, precision: str | None = "float64") -> str:
    """What a ``matches_reference`` dict says the run reproduces: 'tie: a = b = c' when two or more
    maps are indistinguishable on the case ('float32 cannot tell these apart: a, b' in float32),
    else the map's name ('' when none reproduces it: closest or undecidable)."""
    return identification.tie_text(identification.reproduced(match), precision)


def summary_table(runs: list[dict]) -> str:
    """One row a run: status, the maximum errors, the reference map it reproduces; then the messages
    of the runs that are not ok and the status counts (``freebody run --table``)."""
    header = ("case", "engine/integrator", "dt", "status", "orient max", "L max rel", "E max rel",
              "pos max m", "reproduces")
    rows = []
    for r in runs:
        m = r.get("metrics") or {}
        match = r.get("matches_reference")
        if match:
            d = finite_or_none(match.get("max_orientation_diff_rad"))
            shown = reproduced_text(match, r.get("precision"))
            if not shown and (d is None or d > tol.CONVERGENCE_ORIENTATION_SATURATED_RAD):
                repro = f"none (orientation lost: every map >= {fmt(d, '.1e')})"  # no closest map means anything
            elif not shown and identification.verdict(match) == identification.UNDECIDABLE:
                repro = f"undecidable here (closest {match.get('closest')}) {fmt(d, '.1e')}"
            else:
                closest = match.get("closest")
                repro = f"{shown or f'none (closest {closest})'} {fmt(d, '.1e')}"
        else:
            repro = ""
        vs = r.get("vs_engine")
        if vs:
            diff = vs.get("max_orientation_diff_rad")
            repro += f"; vs {vs['engine']}/{vs['integrator']} " + (fmt(diff, ".1e") if diff is not None
                                                                    else vs.get("message", "-"))
        status = r["status"]
        rows.append((printable(r["case"]), printable(run_label(r)), f"{r['dt']:g}", status,
                     fmt(m.get(ORIENTATION_ERROR_MAX)), fmt(m.get(ANGULAR_MOMENTUM_ERROR_MAX_REL)),
                     fmt(m.get(ENERGY_ERROR_MAX_REL)), fmt(m.get(POSITION_ERROR_MAX)), repro))
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(f"{h:<{w}}" for h, w in zip(header, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    for row in rows:
        lines.append("  ".join(f"{c:<{w}}" for c, w in zip(row, widths)).rstrip())
    notes = [printable(f"  {r['case']} {run_label(r)} dt={r['dt']:g}: {r['status']}: {r['message']}")
             for r in runs if r["status"] != Status.OK and r.get("message")]
    if notes:
        lines.append("")
        lines.append("not ok:")
        lines.extend(dict.fromkeys(notes))
    lines.append("")
    lines.append(status_counts_line(runs))
    return "\n".join(lines)


# --- the compact summary printed by ``freebody run`` -----------------------------------------------

SUMMARY_WIDTH = 80  # columns of the compact summary when standard output is no terminal
NAME_WIDTH_MAX = 28  # case-name column, characters: longer names are cut ...
NAME_WIDTH_MIN = 16  # ... and down to this many when the engines need the room
HEADER_LINES_MAX = 3  # lines of column labels when they do not fit on one, each holding every n-th
NOT_OK_LINES_MAX = 10  # lines of the grouped list of runs that are not ok, "and N more" included
MATRIX_TITLE = "worst orientation error, rad (over each engine's integrators and time steps)"
STATUS_ORDER = (Status.FAILED, Status.DIVERGED, Status.SKIPPED)  # worst first
MARKERS = {Status.FAILED: "F", Status.DIVERGED: "d", Status.SKIPPED: "s"}  # a cell with some runs not ok
NONE_OK = {Status.FAILED: "FAIL", Status.DIVERGED: "div", Status.SKIPPED: "skip"}  # a cell with no run ok
MARKER_TEXT = {Status.FAILED: "a run failed", Status.DIVERGED: "a run diverged", Status.SKIPPED: "a run skipped"}
# Markers of ok runs whose state says more than their orientation error (the run's stored
# judgement, results.json runs[].judgement, judged from state_growth): a blow-up (its orientation
# error is the blow-up's, not a phase error) and a rotation per step beyond the engine's cap;
# after the status marker.
GROWTH_MARKERS = {"blew_up": "b", "capped": "c"}
GROWTH_MARKER_TEXT = {
    "b": f"blow-up (|w| > {tol.BLOW_UP_OMEGA_FACTOR:g}x or KE > {tol.BLOW_UP_ENERGY_FACTOR:g}x the truth's)",
    "c": "|w| dt beyond the engine's rotation cap a step",
}
_DIVERGED_AT = re.compile(r"^diverged at t = \S+ s: ?")  # the time of judge.outcome's messages


def column_label(run: dict) -> str:
    """The matrix column of a run: its engine, with the precision when it is not float64."""
    label = str(run["engine"])
    if run.get("precision", "float64") != "float64":
        label += f"/{run['precision']}"
    return printable(label)


def _number(x: float, style: str) -> str:
    """``x`` in scientific notation: "full" 1.8e-02, "short" 1.8e-2, "tiny" 2e-2 (0 as 0)."""
    if x == 0:
        return "0"
    text = format(x, ".0e" if style == "tiny" else ".1e")
    if style == "full":
        return text
    mantissa, exponent = text.split("e")
    return f"{mantissa}e{int(exponent)}"


def _cell(runs: list[dict], style: str) -> tuple[str, str]:
    """(value, marker) of a matrix cell: the worst orientation error of its ok runs and the marker of
    its worst other status ('' when all are ok); with no ok run, the word of its worst status."""
    if not runs:
        return "-", ""
    statuses = {r["status"] for r in runs}
    worst_other = next((s for s in STATUS_ORDER if s in statuses), None)
    if Status.OK not in statuses:
        return NONE_OK.get(worst_other, "?"), ""
    errors = [x for r in runs if r["status"] == Status.OK
              for x in [(r.get("metrics") or {}).get(ORIENTATION_ERROR_MAX)] if x is not None]
    value = _number(max(errors), style) if errors else "-"
    return value, MARKERS.get(worst_other, "") + "".join(
        m for key, m in GROWTH_MARKERS.items() if any(_grew(r, key) for r in runs))


def _grew(run: dict, key: str) -> bool:
    """Whether the run's judgement says ``key`` (it blew up, reached the rotation cap: only ever
    true of an ok run; results/judgement.run_judgement decides it once)."""
    return bool(run["judgement"][key])


def _clip(text: str, width: int, mark: str = "...") -> str:
    return text if len(text) <= width else text[:max(0, width - len(mark))] + mark


def _widths(cells: dict, cases: list[str], columns: list[str], sep: int,
            label_wide: bool) -> list[tuple[int, int]]:
    """(value width, marker width) of each column: no room for a marker in a column without one;
    ``label_wide``: each value as wide as its column's label and two spaces (less the separator), so
    the labels fit on one line."""
    out = []
    for col in columns:
        vw = max(len(cells[c, col][0]) for c in cases)
        out.append((max(vw, len(col) + 2 - sep) if label_wide else vw, max(len(cells[c, col][1]) for c in cases)))
    return out


def _header_lines(name_w: int, sep: int, widths: list[tuple[int, int]], labels: list[str]) -> list[str]:
    """The column labels, right-aligned over the values: on one line when they fit, else on two or
    three lines, each holding every second (third) label, which may then reach over its
    neighbours; a label that does not fit even so is cut with ``~``."""
    ends, pos = [], name_w
    for vw, mw in widths:
        ends.append(pos + sep + vw)
        pos += sep + vw + mw

    def place(n_lines: int, cut: bool) -> list[str] | None:
        rows = [list("case".ljust(pos))] + [list(" " * pos) for _ in range(n_lines - 1)]
        free = [len("case") + 1] * n_lines
        for i, (label, end) in enumerate(zip(labels, ends)):
            k = i % n_lines
            if end - len(label) < free[k]:
                if not cut:
                    return None
                label = _clip(label, max(0, end - free[k]), "~")
            rows[k][end - len(label):end] = label
            free[k] = end + 1
        return ["".join(r).rstrip() for r in rows]

    for n in range(1, HEADER_LINES_MAX + 1):
        lines = place(n, cut=False)
        if lines:
            return lines
    return place(HEADER_LINES_MAX, cut=True)


def _matrix_block(cases: list[str], names: dict[str, str], columns: list[str], cells: dict,
                  name_w: int, sep: int, widths: list[tuple[int, int]]) -> list[str]:
    lines = _header_lines(name_w, sep, widths, columns)
    for c in cases:
        row = _clip(names[c], name_w, "~").ljust(name_w)
        for col, (vw, mw) in zip(columns, widths):
            value, marker = cells[c, col]
            row += " " * sep + value.rjust(vw) + marker.ljust(mw)
        lines.append(row.rstrip())
    return lines


def _wrapped(items: list[str], width: int, joiner: str = "; ") -> list[str]:
    """``items`` joined with ``joiner`` into lines of at most ``width`` columns (an item longer than
    a line is cut)."""
    lines: list[str] = []
    for item in items:
        item = _clip(item, width)
        if lines and len(lines[-1]) + len(joiner) + len(item) <= width:
            lines[-1] += joiner + item
        else:
            lines.append(item)
    return lines


def summary_matrix(runs: list[dict], width: int = SUMMARY_WIDTH) -> list[str]:
    """Cases (rows) x engines (columns, see :func:`column_label`): the worst orientation error of
    the engine's ok runs of the case (rad, over its integrators and time steps) and a marker when
    some of them are not ok (:data:`MARKERS`), or the word of the worst status when none is ok.

    An engine whose every run was skipped (e.g. not installed) gets no column (the runs that are
    not ok are listed after the matrix).  The numbers are shown with as many digits as fit in
    ``width`` columns with the case names whole, else with the names cut; when even one digit
    does not fit, the engines are split into blocks, one under the other.
    Returns the lines: a title, the header, one line a case, a legend when a marker is used.
    """
    by: dict[tuple[str, str], list[dict]] = {}
    for r in runs:
        by.setdefault((r["case"], column_label(r)), []).append(r)
    cases = list(dict.fromkeys(r["case"] for r in runs))
    names = {c: printable(c) for c in cases}
    every_col = list(dict.fromkeys(column_label(r) for r in runs))
    hidden = [col for col in every_col
              if all(r["status"] == Status.SKIPPED for c in cases for r in by.get((c, col), []))]
    columns = [col for col in every_col if col not in hidden]
    if not columns:
        return [f"no engine ran: every run was skipped ({', '.join(hidden)})"] if hidden else []
    longest = max(min(max(len(n) for n in names.values()), NAME_WIDTH_MAX), len("case"))
    lines: list[str] = []
    for name_w in dict.fromkeys((longest, min(longest, max(NAME_WIDTH_MIN, len("case"))))):
        for style, sep in (("full", 2), ("short", 1), ("tiny", 1)):
            cells = {(c, col): _cell(by.get((c, col), []), style) for c in cases for col in columns}
            for label_wide in (True, False):  # the labels on one line if there is room for them
                widths = _widths(cells, cases, columns, sep, label_wide)
                if name_w + sum(sep + vw + mw for vw, mw in widths) <= width:
                    lines = _matrix_block(cases, names, columns, cells, name_w, sep, widths)
                    break
            if lines:
                break
        if lines:
            break
    else:  # not even one digit of every engine fits: blocks of engines, one under the other
        block: list[str] = []
        for col in columns:
            widths = _widths(cells, cases, block + [col], sep, False)
            if block and name_w + sum(sep + vw + mw for vw, mw in widths) > width:
                lines += _matrix_block(cases, names, block, cells, name_w, sep, widths[:-1]) + [""]
                block = []
            block.append(col)
        lines += _matrix_block(cases, names, block, cells, name_w, sep, _widths(cells, cases, block, sep, False))
    used = {c for (value, m) in cells.values() for c in m}
    legend = [f"{m}: {MARKER_TEXT[s]}" for s, m in MARKERS.items() if m in used]
    legend += [f"{m}: {text}" for m, text in GROWTH_MARKER_TEXT.items() if m in used]
    if any(value in NONE_OK.values() for value, _ in cells.values()):
        legend.append("FAIL/div/skip: no run ok")
    if hidden:
        legend.append(f"no column: {', '.join(hidden)} (every run skipped)")
    return [_clip(MATRIX_TITLE, width)] + lines + _wrapped(legend, width)


def _reason(run: dict) -> str:
    """What went wrong in a run, without what differs between runs that went wrong the same way
    (a divergence's time)."""
    message = str(run.get("message") or "")
    if run["status"] == Status.DIVERGED:
        message = _DIVERGED_AT.sub("", message)
    return printable(message.strip()) or "(no message)"


def not_ok_lines(runs: list[dict], width: int = SUMMARY_WIDTH, max_lines: int = NOT_OK_LINES_MAX) -> list[str]:
    """The runs that are not ok, grouped by status, engine (and precision) and reason: a line a
    group, ``label: N status in <case | K cases>[, at t = a to b s]: reason`` (the reason, or the
    time and the reason, on a line of its own when they do not fit on one); failed first, then
    diverged, then skipped, larger groups first; at most ``max_lines`` lines, the rest counted in
    an "and N more" line."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        if r["status"] != Status.OK:
            key = (r["status"], r["engine"], r.get("precision", "float64"), _reason(r))
            groups.setdefault(key, []).append(r)
    if not groups:
        return []
    rank = {s: i for i, s in enumerate(STATUS_ORDER)}
    order = sorted(groups, key=lambda k: (rank.get(k[0], len(rank)), -len(groups[k])))
    total = sum(len(g) for g in groups.values())
    lines = [f"not ok: {total} run{'s' if total != 1 else ''} (each one: report.md, or freebody run --table)"]
    for i, key in enumerate(order):
        status, engine, precision, reason = key
        rs = groups[key]
        integrators = [x for x in dict.fromkeys(str(r["integrator"]) for r in rs) if x != "*"]
        label = column_label(rs[0])
        if len(integrators) == 1:
            label += f"/{printable(integrators[0])}"
        elif 1 < len(integrators) <= 3:
            label += "/{" + ",".join(printable(x) for x in integrators) + "}"
        elif integrators:
            label += f" ({len(integrators)} integrators)"
        cases = list(dict.fromkeys(r["case"] for r in rs))
        where = printable(cases[0]) if len(cases) == 1 else f"{len(cases)} cases"
        head = f"  {label}: {len(rs)} {status} in {where}"
        times = [r["diverged_at_s"] for r in rs if isinstance(r.get("diverged_at_s"), (int, float))]
        when = ""
        if times:
            lo, hi = min(times), max(times)
            when = f"at t = {lo:.3g} s" if lo == hi else f"at t = {lo:.3g} to {hi:.3g} s"
        if len(one := f"{head}{', ' + when if when else ''}: {reason}") <= width:
            text = [one]
        elif len(f"{head}, {when}") <= width or not when:  # the reason on a line of its own
            text = [_clip(f"{head}{', ' + when if when else ''}", width), _clip(f"    {reason}", width)]
        else:  # and the time with it
            text = [_clip(head, width), _clip(f"    {when}: {reason}", width)]
        left = len(order) - i - 1
        if len(lines) - 1 + len(text) + (1 if left else 0) > max_lines:
            rest = order[i:]
            n_runs = sum(len(groups[k]) for k in rest)
            lines.append(f"  and {len(rest)} more group{'s' if len(rest) != 1 else ''} ({n_runs} runs)")
            break
        lines += text
    return lines


def status_counts_line(runs: list[dict]) -> str:
    """``761 ok, 13 diverged, 0 failed, 0 skipped (774 runs)``."""
    counts = {s: sum(r["status"] == s for r in runs) for s in STATUSES}
    return ", ".join(f"{n} {s}" for s, n in counts.items()) + f" ({len(runs)} runs)"


def summary_width(stream=None) -> int:
    """Columns for the summary: the terminal's when ``stream`` (default: standard output) is one,
    else SUMMARY_WIDTH (a log or a pipe: the same text whatever the terminal of whoever reads it)."""
    stream = stream if stream is not None else sys.stdout
    try:
        tty = stream.isatty()
    except (AttributeError, OSError, ValueError):
        tty = False
    return terminal_width(stream, SUMMARY_WIDTH) if tty else SUMMARY_WIDTH


def terminal_summary(runs: list[dict], width: int = SUMMARY_WIDTH) -> str:
    """What ``freebody run`` prints when its runs are done: the matrix of :func:`summary_matrix`,
    the grouped runs that are not ok (:func:`not_ok_lines`) and the status counts; at most
    ``width`` columns, and for the default suite short enough for an 80 x 50 terminal (the
    per-run table is :func:`summary_table`, ``freebody run --table``, and report.md)."""
    lines = summary_matrix(runs, width)
    bad = not_ok_lines(runs, width)
    if bad:
        lines += ([""] if lines else []) + bad
    lines += ([""] if lines else []) + [status_counts_line(runs)]
    return "\n".join(lines)


def where_to_look(out_dir, reports: list) -> str:
    """The last lines of ``freebody run``: what to open first, where the tables and the data are
    (``reports``: the report files written; none: how to write them)."""
    out_dir = Path(out_dir)
    pages = [Path(p) for p in reports if Path(p).suffix == ".html"]
    # the report itself, not the page its long tables moved to (report-tables.html)
    html = next((p for p in pages if p.name == "report.html"), pages[0] if pages else None)
    md = next((Path(p) for p in reports if Path(p).suffix == ".md"), None)
    lines = []
    if html is not None:
        lines.append(f"open {printable(html)} (start with the findings at the top)")
    if md is not None:
        lines.append(f"tables: {printable(md)}")
    if html is None and md is None:
        lines.append(f"reports: not written; freebody report {printable(shlex.quote(str(out_dir)))} writes them")
    lines.append(f"data: {printable(out_dir / 'results.json')}")
    return "\n".join(lines)
