"""report.html in its budget (issue 29 item 7): a long report's per-case Runs and engine-vs-engine
tables go to report-tables.html (every row kept, each run's link leads there), a short one keeps
them; the conventions come from results.json (schema 7) without importing the engines."""
from __future__ import annotations

import copy
import json
import re
import subprocess
import sys

import pytest

from freebody.cli import main
from freebody.report import data as rd
from freebody.report import html as rh
from freebody.report.render import write_reports
from freebody.results.document import load_results

ENGINES, CASES = 6, 25  # of the synthetic document: 1,200 runs (the default suite: 1,551)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tables_run")
    assert main(["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--integrator", "euler-quat",
                 "--integrator", "semi-implicit-explicit-gyro", "--integrator", "lie-euler",
                 "--duration", "0.05", "--dt", "0.01", "--dt", "0.005", "--out", str(out), "--quiet",
                 "--no-report"]) == 0
    return json.loads((out / "results.json").read_text())


def _large(tiny: dict) -> dict:
    runs = []
    for c in range(CASES):
        for e in range(ENGINES):
            for r in tiny["runs"]:
                r = copy.deepcopy(r)
                r.update(case=f"case_{c:02d}", engine=r["engine"] if e == 0 else f"engine{e}", trajectory=None)
                runs.append(r)
    return {**tiny, "runs": runs, "engines": {**tiny["engines"], **{f"engine{e}": "1" for e in range(1, ENGINES)}}}


def _ids(text: str) -> set[str]:
    return set(re.findall(r' id="([^"]+)"', text))


def test_a_long_reports_tables_are_apart_with_every_row_and_link(tiny, tmp_path, monkeypatch):
    monkeypatch.setattr("freebody.report.plots.SERIAL_FIGURES", 10**6)  # drawn here: no workers
    doc = _large(tiny)
    (tmp_path / "results.json").write_text(json.dumps(doc))
    paths = write_reports(tmp_path, html=True)
    assert tmp_path / rd.TABLES_PAGE in paths
    page, tables = (tmp_path / "report.html").read_text(), (tmp_path / rd.TABLES_PAGE).read_text()
    runs = load_results(doc)["runs"]
    anchors = {rd.run_anchor(r) for r in runs}
    assert anchors <= _ids(tables) and not anchors & _ids(page)  # every run's row, on the tables page
    assert tables.count("<h3>Engines at the end</h3>") == CASES
    for href in re.findall(r'href="([^"]*#run-[^"]+)"', page):  # a run's link leads to its row there
        assert href.startswith(rd.TABLES_PAGE + "#") and href.split("#")[1] in anchors
    for case in rd.by_case(runs):
        assert f'href="{rd.TABLES_PAGE}#{rd.tables_anchor(case)}"' in page
        assert f'href="report.html#{rd.case_anchor(case)}"' in tables
    md = (tmp_path / "report.md").read_text()
    assert f"]({rd.TABLES_PAGE}#{rd.tables_anchor('case_00')})" in md and "(report.html#run-" not in md
    # one row per run in the tables page, and the pairs there are the pairs of the data
    assert tables.count('<tr id="run-') == len(runs)
    pairs = sum(len(rd.pairwise(rs, None, None)) for rs in rd.by_case(runs).values())
    assert tables.count("<tr>") - tables.count("<thead><tr>") == pairs


def test_a_short_report_keeps_its_tables_and_drops_a_stale_tables_page(tiny, tmp_path, monkeypatch):
    monkeypatch.setattr("freebody.report.plots.SERIAL_FIGURES", 10**6)
    doc = {**tiny, "runs": [dict(r, trajectory=None) for r in tiny["runs"]]}
    (tmp_path / "results.json").write_text(json.dumps(doc))
    (tmp_path / rd.TABLES_PAGE).write_text("an earlier report's")
    paths = write_reports(tmp_path)
    assert not (tmp_path / rd.TABLES_PAGE).exists() and len(paths) == 2
    page = (tmp_path / "report.html").read_text()
    assert {rd.run_anchor(r) for r in load_results(doc)["runs"]} <= _ids(page)
    assert rd.TABLES_PAGE not in page and not rh.tables_apart(load_results(doc)["runs"], {}, {})


def test_a_run_records_its_conventions_and_the_report_imports_no_engine(tiny, tmp_path):
    """results.json (schema 7) holds each engine's conventions as its adapter states them; a report
    of it reads them there (here: a fake engine's, which no adapter could give)."""
    from freebody.run.suite import convention_rows
    from freebody.adapters.base import load_adapter

    assert tiny["schema_version"] == 7
    assert tiny["conventions"]["reference"] == convention_rows(load_adapter("reference"))
    doc = {**tiny, "engines": {**tiny["engines"], "mjx": "3"},
           "conventions": {**tiny["conventions"], "mjx": [["frame", "as recorded"]]}}
    assert ("mjx", "frame", "as recorded") in rd.engine_conventions(doc)
    (tmp_path / "results.json").write_text(json.dumps(doc))
    code = ("import sys; from freebody.report import data as rd; from freebody.results.document import "
            f"load_results; rd.engine_conventions(load_results({str(tmp_path)!r})); "
            "print(sorted(m for m in ('jax', 'mujoco', 'pybullet') if m in sys.modules))")
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert got.stdout.strip() == "[]"


@pytest.mark.parametrize("quiet", [False, True])
def test_freebody_run_shows_the_reports_progress_unless_quiet(tmp_path, monkeypatch, quiet):
    import freebody.report.render as render

    seen = []
    real = render.finish_run

    def spy(*args, **kw):
        seen.append(kw.get("progress"))
        return real(*args, **kw)

    monkeypatch.setattr(render, "finish_run", spy)
    assert main(["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--duration", "0.02",
                 "--dt", "0.01", "--out", str(tmp_path / "out"), *(["--quiet"] if quiet else [])]) == 0
    assert seen == [not quiet]
