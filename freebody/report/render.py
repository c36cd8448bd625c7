"""Reports of a run directory: report.md (tables) and report.html (tables and embedded plots).

``freebody run`` calls :func:`finish_run` (adds the fitted orders and the cases' mass properties
to results.json, then writes the reports); ``freebody report DIR`` calls :func:`write_reports`,
which re-renders both from results.json and the trajectory files without running anything.
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

from . import data as rd
from ..run.convergence import fit_orders
from ..results.io import write_json_atomic, write_text_atomic


def augment(doc: dict, problems: dict | None = None, defaults: dict[str, list[str]] | None = None) -> dict:
    """The results document with ``"convergence"`` (see :mod:`freebody.run.convergence`) and ``"cases"``
    (name -> description, truth, mass kg, inertia kg m^2 (3x3, COM, body frame), gravity m/s^2
    (world), ...: what a report needs to recompute L and E without the case file; the case file's
    ``dts`` and ``duration``, ``ran``: [{dt, steps, duration_s}] of the runs that ran, and
    ``defaults``: the optional keys the case file left out, from ``defaults`` (case name -> keys,
    :func:`freebody.input.casefile.defaulted_keys`), when given)."""
    from ..reference_impl.truth import truth_kind

    out = dict(doc)
    out["convergence"] = fit_orders(doc.get("runs") or [])
    cases = dict(doc.get("cases") or {})
    for name, pb in (problems or {}).items():
        cases[name] = rd.case_record(pb, truth_kind(pb))
        if defaults is not None and name in defaults:
            cases[name]["defaults"] = list(defaults[name])
    ran: dict[str, dict] = {}
    for r in doc.get("runs") or []:  # what ran, whatever the case file's dts and duration say
        if r.get("case") in cases and isinstance(r.get("steps"), int):
            ran.setdefault(r["case"], {})[repr(float(r["dt"]))] = r["steps"]
    for name, by_dt in ran.items():
        cases[name] = {**cases[name], "ran": [{"dt": float(d), "steps": n, "duration_s": float(d) * n}
                                              for d, n in sorted(by_dt.items(), key=lambda kv: float(kv[0]))]}
    if cases:
        out["cases"] = cases
    return out


def convergence_of(doc: dict) -> list[dict]:
    """results.json's ``"convergence"`` list, or the fit of its runs when it has none."""
    conv = doc.get("convergence")
    return conv if isinstance(conv, list) else fit_orders(doc.get("runs") or [])


def compare_with(baseline, doc: dict, current: str = "this run"):
    """The comparison of the results ``doc`` with a baseline (a baseline file, a results.json, a
    run directory or a results dict), as ``freebody compare BASELINE RESULTS`` makes it with the
    default tolerances; InputError when the baseline is unusable.  ``current``: where ``doc``
    is stored (its run directory), named in the verdict's commands; "this run" when nowhere yet."""
    from ..results.compare import compare, load_side

    source = "baseline" if isinstance(baseline, dict) else str(baseline)
    return compare(load_side(baseline, "baseline"), doc, sources=(source, current))


def write_reports(out_dir: Path, doc: dict | None = None, problems: dict | None = None,
                  html: bool = True, baseline=None, progress: bool = False) -> list[Path]:
    """Write ``out_dir/report.md`` and (unless ``html`` is False) ``out_dir/report.html``, with
    ``out_dir/report-tables.html`` (rd.TABLES_PAGE) when its per-case tables are too long for it.

    doc : the results document (default: ``out_dir/results.json``).
    problems : case name -> Problem, for cases that results.json does not describe.
    baseline : a baseline (file, results.json, run directory or dict) to compare the results with:
        the reports then show the verdict of ``freebody compare`` (a finding and a section).
    progress : show the figures done / total on standard error (:class:`freebody.run.progress.
        ProgressDisplay`: on a terminal one line rewritten; in a log, when worker processes draw
        the figures, a line at the first and the last figure and at most every LOG_INTERVAL_S).
    Returns the paths written.  A run whose trajectory is not a regular file inside ``out_dir``
    (:func:`freebody.results.document.usable_trajectories`) is drawn without it, with a warning.

    When the figures are drawn by worker processes (more than plots.SERIAL_FIGURES of them), the
    workers are started first, as soon as the results are read, and draw while this process
    writes report.md and report.html, whose figures are put in last (:class:`_Figures`).
    """
    from ..results.document import load_results

    out_dir = Path(out_dir)
    doc = load_results(out_dir if doc is None else doc)  # the newest shape (a document in memory too)
    figures = _Figures(doc.get("runs") or [], progress) if html else None  # workers start importing
    try:
        return _write_reports(out_dir, doc, problems, figures, baseline)
    finally:
        if figures is not None:
            figures.stop()


def _write_reports(out_dir: Path, doc: dict, problems: dict | None, figures: _Figures | None, baseline) -> list[Path]:
    """write_reports once the results are read and the figure workers (``figures``) started."""
    from .markdown import render_markdown

    from ..results.document import usable_trajectories

    doc, refused = usable_trajectories(doc, out_dir)  # only regular files inside out_dir are read
    for line in refused:
        warnings.warn(line, stacklevel=3)
    conv = convergence_of(doc)
    runs = doc.get("runs") or []
    physics = {c: rd.case_physics(doc, c, problems) for c in rd.by_case(runs)}
    if figures is not None and figures.parallel:
        figures.start(runs, conv, physics, out_dir)  # the workers draw while the reports are written
    pairs, found, comparison = _tables_data(doc, runs, conv, physics, out_dir, baseline)
    tables = _tables_page(out_dir, runs, pairs, physics) if figures is not None else None
    md_path = out_dir / "report.md"
    write_text_atomic(md_path, render_markdown(doc, conv, physics, out_dir, pairs=pairs, found=found,
                                               comparison=comparison, tables=tables))
    written = [md_path]
    if figures is not None:
        from .html import render_html_later, render_tables_html

        if tables is not None:
            write_text_atomic(out_dir / tables, render_tables_html(doc, physics, pairs))
            written.append(out_dir / tables)
        fill = render_html_later(doc, conv, physics, out_dir, pairs=pairs, found=found, comparison=comparison,
                                 tables=tables)
        html_path = out_dir / "report.html"
        write_text_atomic(html_path, fill(*figures.result(runs, conv, physics, out_dir)))
        written.append(html_path)
    return written


def _tables_data(doc: dict, runs: list[dict], conv: list[dict], physics: dict, out_dir: Path, baseline):
    """(the engine-vs-engine pairs per case, the findings, the comparison with ``baseline`` or
    None): what report.md and report.html both show, computed once."""
    from . import findings as fd

    pairs = {c: rd.pairwise(rs, physics[c], out_dir) for c, rs in rd.by_case(runs).items()}
    found = fd.find(runs, rd.trajectory_reader(out_dir), conv, doc.get("cases"))
    comparison = compare_with(baseline, doc, str(out_dir)) if baseline is not None else None
    return pairs, found, comparison


def _tables_page(out_dir: Path, runs: list[dict], pairs: dict, physics: dict) -> str | None:
    """rd.TABLES_PAGE when report.html's per-case tables go there (:func:`freebody.report.html.
    tables_apart`), else None, with a stale copy of that page from an earlier report removed."""
    from .html import tables_apart

    if tables_apart(runs, pairs, physics):
        return rd.TABLES_PAGE
    stale = out_dir / rd.TABLES_PAGE
    if stale.is_file() and not stale.is_symlink():
        stale.unlink()
    return None


class _FiguresStopped(Exception):
    """The report failed or was interrupted while its figures were drawn: the workers stop."""


class _Figures:
    """The figures of report.html (:func:`freebody.report.plots.render_figures`) of ``runs``: when
    worker processes draw them (``parallel``), the workers are started here and fed by a thread
    of this process (``start``, then ``result``); else drawn here when ``result`` is called; with a
    progress display of the figures done / total.  ``stop`` ends what is left."""

    def __init__(self, runs: list[dict], progress: bool):
        import threading

        from . import plots
        from ..run.progress import ProgressDisplay

        total = plots.figure_count(runs)
        self.parallel = plots.drawn_apart(runs)  # as render_figures decides
        self.workers = plots.start_workers(plots.usable_cpus()) if self.parallel else None
        # shown on a terminal, and in a log when the figures take long (worker processes draw them):
        # a report of a few figures takes seconds, and its log stays the warnings alone
        shown = progress and (self.parallel or bool(getattr(sys.stderr, "isatty", lambda: False)()))
        self.display = ProgressDisplay(total, unit="figures", enabled=shown, every=total)
        self.stopping = threading.Event()
        self.thread = None
        self.outcome = None  # (figures, notes), or the exception raised drawing them

    def _done(self, name: str) -> None:
        if self.stopping.is_set():
            raise _FiguresStopped  # render_figures ends its workers
        self.display.update(name)

    def _draw(self, runs: list[dict], conv: list[dict], physics: dict, out_dir: Path) -> None:
        from . import plots

        workers, self.workers = self.workers, None  # render_figures ends them
        try:
            self.outcome = plots.render_figures(runs, conv, physics, out_dir, on_figure=self._done,
                                                jobs=None if workers is None else len(workers), workers=workers)
        except BaseException as e:  # handed to result()
            self.outcome = e

    def start(self, runs: list[dict], conv: list[dict], physics: dict, out_dir: Path) -> None:
        import threading

        self.thread = threading.Thread(target=self._draw, args=(runs, conv, physics, out_dir),
                                       name="report-figures", daemon=True)
        self.thread.start()

    def result(self, runs: list[dict], conv: list[dict], physics: dict, out_dir: Path) -> tuple[dict, dict]:
        """(figures, notes) of these runs: those the thread drew (``start``), or drawn now."""
        if self.thread is None:
            self._draw(runs, conv, physics, out_dir)
        else:
            self.thread.join()
        if isinstance(self.outcome, BaseException):
            raise self.outcome
        return self.outcome

    def stop(self) -> None:
        """After the report (written, or failed): a thread still drawing stops at its next figure;
        workers never handed their figures are ended."""
        from . import plots

        self.stopping.set()
        if self.thread is not None:
            self.thread.join()
        if self.workers:
            plots.stop_workers(self.workers, wait=False)
            self.workers = None


def finish_run(out_dir: Path, doc: dict, problems: dict, report: bool = True,
               baseline=None, defaults: dict[str, list[str]] | None = None,
               progress: bool = False) -> tuple[dict, list[Path]]:
    """After ``freebody run``: re-write results.json (atomically) with the fitted orders and the
    cases, then write the reports (compared with ``baseline`` when given; ``progress``: the
    figures done / total on standard error).  Returns (the document, the report paths written)."""
    doc = augment(doc, problems, defaults)
    write_json_atomic(Path(out_dir) / "results.json", doc)
    paths = write_reports(out_dir, doc, problems, baseline=baseline, progress=progress) if report else []
    return doc, paths

