"""Golden-text tests: report.md and the compare table of a tiny reference-only run, against
tests/golden/.  Regenerate after an intended change with

    FREEBODY_UPDATE_GOLDEN=1 python -m pytest tests/test_report_golden.py

and review the diff of tests/golden/ before committing it (see tests/golden/README.md).
"""
from __future__ import annotations

import copy
import json
import os
import re
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.results.compare import compare, default_tolerances
from freebody.report.render import convergence_of
from freebody.report import data as rd
from freebody.report.markdown import render_markdown

GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("FREEBODY_UPDATE_GOLDEN") == "1"
# The tiny case: the lecture quiz and the Dzhanibekov spin, 0.2 s at three time steps, on two
# first-order reference integrators (errors 1e-8..1e-1: far above round-off and the truth's floor).
RUN_ARGS = ["run", "quiz", "dzhanibekov", "--engine", "reference", "--integrator", "euler-quat",
            "--integrator", "semi-implicit-explicit-gyro", "--duration", "0.2",
            "--dt", "0.02", "--dt", "0.01", "--dt", "0.005", "--quiet", "--no-report"]
# Values below this are round-off (e.g. |L| error of a torque-free integrator that conserves L):
# their digits differ between CPUs and BLAS builds, so both sides show them as "~0".
ROUND_OFF = 1e-13
_NUMBER = re.compile(r"-?\d\.\d{3}e[+-]\d{2}")


def pinned(doc: dict) -> dict:
    """The results document with its machine- and time-dependent fields fixed."""
    doc = copy.deepcopy(doc)
    doc.update(created="(pinned)", platform="(pinned)", freebody_version="(pinned)")
    doc["engines"] = {e: "(pinned)" for e in doc.get("engines", {})}
    for r in doc["runs"]:
        r["wall_time_s"] = 0.001 * r["steps"] * r["dt"]  # 1 ms per simulated second
        r["engine_version"] = "(pinned)"
    return doc


def normalise(text: str) -> str:
    return _NUMBER.sub(lambda m: "~0" if abs(float(m.group())) < ROUND_OFF else m.group(), text)


def check_golden(name: str, text: str) -> None:
    path = GOLDEN / name
    if UPDATE:
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        return
    assert path.is_file(), f"{path} missing: run with FREEBODY_UPDATE_GOLDEN=1 to create it"
    expected = path.read_text()
    assert normalise(text) == normalise(expected), (
        f"{name} differs from {path}; if the change is intended, regenerate with "
        f"FREEBODY_UPDATE_GOLDEN=1 and review the diff")


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("golden_run")
    assert main([*RUN_ARGS, "--out", str(out)]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_report_markdown_matches_golden(tiny_run):
    out, doc = tiny_run
    doc = pinned(doc)
    physics = {c: rd.case_physics(doc, c) for c in rd.by_case(doc["runs"])}
    check_golden("report.md", render_markdown(doc, convergence_of(doc), physics, out))


def test_compare_table_matches_golden(tiny_run):
    _, doc = tiny_run
    base = pinned(doc)
    cur = copy.deepcopy(base)
    cur["engines"]["reference"] = "(pinned, upgraded)"
    cur["runs"][0]["metrics"]["orientation_error_max_rad"] *= 2.0  # worse beyond 1 %
    cur["runs"][1]["metrics"]["energy_error_max_rel"] *= 0.5  # better
    cur["runs"][2]["status"] = "diverged"
    del cur["runs"][3]
    result = compare(base, cur, default_tolerances(), sources=("baseline.json", "current"))
    assert result.exit_code == 1
    check_golden("compare.txt", result.table() + "\n")
