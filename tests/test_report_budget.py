"""The report within its budget (issue 29 item 7): report.md of a large document stays under
MD_BUDGET_BYTES with pointers to report.html's per-case tables; long tables are unpadded; the
figures' progress (done / total) is shown; the text-caching Agg canvas draws the same pixels."""
from __future__ import annotations

import copy
import io
import json
from pathlib import Path

import numpy as np
import pytest

from freebody.cli import main
from freebody.report import data as rd
from freebody.report import markdown as md
from freebody.report import plots
from freebody.report.render import convergence_of, write_reports
from freebody.results.document import load_results

# engines x integrators x cases of the synthetic document: 1,200 runs (the default suite: 1,551)
FAKE_ENGINES, FAKE_CASES = 6, 25


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("budget_run")
    assert main(["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--integrator", "euler-quat",
                 "--integrator", "semi-implicit-explicit-gyro", "--integrator", "lie-euler",
                 "--duration", "0.05", "--dt", "0.01", "--dt", "0.005", "--out", str(out), "--quiet",
                 "--no-report"]) == 0
    return json.loads((out / "results.json").read_text())["runs"]


def _large_doc(tiny_runs: list[dict]) -> dict:
    """The tiny run's runs copied to FAKE_CASES cases and FAKE_ENGINES engine names (their
    trajectories dropped: the tables only)."""
    runs = []
    for c in range(FAKE_CASES):
        for e in range(FAKE_ENGINES):
            for r in tiny_runs:
                r = copy.deepcopy(r)
                r.update(case=f"case_{c:02d}", engine=r["engine"] if e == 0 else f"engine{e}", trajectory=None)
                runs.append(r)
    return load_results({"runs": runs, "schema_version": 6})


def _md(doc: dict) -> str:
    conv = convergence_of(doc)
    return md.render_markdown(doc, conv, {c: None for c in rd.by_case(doc["runs"])})


def test_report_md_of_a_large_document_stays_in_its_budget(tiny_runs):
    doc = _large_doc(tiny_runs)
    text = _md(doc)
    pairs = sum(len(md.md_table(md.PAIR_COLUMNS, md.pair_rows(rd.pairwise(rs, None, None))))
                for rs in rd.by_case(doc["runs"]).values())
    assert pairs > md.MD_BUDGET_BYTES  # the whole report would not fit
    assert len(text.encode("utf-8")) <= md.MD_BUDGET_BYTES
    for case in rd.by_case(doc["runs"]):  # each case keeps its section, with pointers
        assert f"## Case `{case}`" in text
        assert f"report.html#{rd.case_anchor(case)}" in text
    assert text.count(f"{len(tiny_runs) * FAKE_ENGINES} runs: the table is in [report.html]") == FAKE_CASES
    for title in ("## Findings", "## Engines", "## Orientation error max (rad) per case",
                  "## Reference map each engine run reproduces", "### Observed order (error ~ dt^p)"):
        assert title in text  # the front tables stay


def test_a_small_report_md_keeps_its_per_case_tables(tiny_runs):
    doc = load_results({"runs": copy.deepcopy(tiny_runs), "schema_version": 6})
    text = _md(doc)
    assert "### Runs\n\n| engine run" in text and "the table is in [report.html]" not in text


def test_a_long_table_is_unpadded_and_a_short_one_aligned():
    header = ("a", "long header")
    short = md.md_table(header, [("x", "1")])
    assert short.splitlines()[2] == "| x | 1           |"
    rows = [(f"row{i}", "v" * 40) for i in range(200)]
    long = md.md_table(header, rows)
    assert long.splitlines()[2] == "| row0 | " + "v" * 40 + " |" and long.splitlines()[1] == "|---|---|"
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in long.splitlines()[2:]]
    assert cells == [list(r) for r in rows]  # every cell, unchanged


def test_figures_report_their_progress(tiny_runs, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(plots, "SERIAL_FIGURES", 1)  # drawn by workers, as a long report's are
    (tmp_path / "results.json").write_text(json.dumps({"runs": [dict(r, trajectory=None) for r in tiny_runs],
                                                       "schema_version": 6}))
    write_reports(tmp_path, progress=True)
    lines = [line for line in capsys.readouterr().err.splitlines() if "figures]" in line]
    total = plots.figure_count(tiny_runs)
    assert total == 3 + 2  # heat map, convergence, speed; quiz at two dts
    assert lines[0].startswith(f"[1/{total} figures]") and lines[-1].startswith(f"[{total}/{total} figures]")
    monkeypatch.setattr(plots, "SERIAL_FIGURES", 8)
    write_reports(tmp_path, progress=True)  # a few figures drawn here: seconds, no lines in a log
    assert "figures]" not in capsys.readouterr().err


def test_the_text_caching_canvas_draws_the_same_pixels():
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    def draw(canvas_of):
        fig = plots._figure(3, 2)
        ax = fig.add_subplot(1, 1, 1)
        ax.plot([1, 2, 3], [1e-3, 1e-9, 1e-12])
        plots._log_axes(ax, y=True)
        ax.set_title("orientation error (rad)", fontsize=9)
        ax.set_xlabel("t (s)")
        fig.text(0.1, 0.1, "x = 1.5e-03 (engine/RK4)", fontsize=7, rotation=30)
        for k in range(12):  # the same glyphs at other positions within a pixel, and whole pixels away
            fig.text(0.5 + k * 0.37 / (3 * plots.DPI), 0.2 + k * 0.07, "1e-05 t (s)", fontsize=7)
            fig.text(0.5 + (k + 0.25) * 7 / (3 * plots.DPI), 0.25 + k * 0.07, "1e-05 t (s)", fontsize=7)
        canvas = canvas_of(fig)
        canvas.draw()
        return np.asarray(canvas.buffer_rgba()).copy()

    plain = draw(FigureCanvasAgg)
    for _ in range(2):  # the second draws from the cache
        assert np.array_equal(draw(plots.agg_canvas), plain)
