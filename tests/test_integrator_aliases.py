"""Honest names (issue 17, item 3): the reference integrator once called ``symplectic-euler`` is
``lie-euler`` (momenta first, then x and q with the new velocities; torque-free the Lie-Euler step,
not symplectic for the rotation).  The old name stays an alias: it simulates the same map bit for
bit, ``freebody run --integrator symplectic-euler`` runs (and records) ``lie-euler``, and results and
baselines written under the old name compare with today's runs without a missing run or a scheme
change (results/document.upgrade_names, applied on load)."""
from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from freebody.adapters.reference import ReferenceAdapter
from freebody.cli import main
from freebody.input import load_case
from freebody.reference_impl.integrators import (INTEGRATOR_ALIASES, INTEGRATORS, canonical_integrator,
                                                 simulate)
from freebody.results.compare import compare, load_side
from freebody.results.document import upgrade_names
from freebody.run.judge import TruthCache, identify
from freebody.run.records import RunSpec

OLD, NEW = "symplectic-euler", "lie-euler"
FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")
# the dts of the runs below (a convergence fit needs three), few steps
DTS = ("0.02", "0.01", "0.005")
DURATION = "0.1"


def test_the_alias_names_the_current_integrator():
    assert INTEGRATOR_ALIASES == {OLD: NEW}
    assert NEW in INTEGRATORS and OLD not in INTEGRATORS  # offered under its current name only
    assert canonical_integrator(OLD) == NEW and canonical_integrator("rk4") == "rk4"
    assert OLD not in ReferenceAdapter.offered_integrators()


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "numpy"])
def test_the_alias_simulates_bit_identically(compiled):
    pb = load_case("offset_push")  # loads and gravity: the kick of the momenta matters
    dt, n = 0.01, 50
    old, new = simulate(pb, OLD, dt, n, compiled=compiled), simulate(pb, NEW, dt, n, compiled=compiled)
    for f in FIELDS:
        assert np.array_equal(getattr(old, f), getattr(new, f)), f
    assert not np.array_equal(new.quaternion_wxyz, simulate(pb, "euler-quat", dt, n).quaternion_wxyz)


def test_the_alias_runs_in_the_reference_adapter():
    pb, dt, n = load_case("dzhanibekov"), 0.01, 40
    expected = simulate(pb, NEW, dt, n)
    adapter = ReferenceAdapter(pb, dt, OLD)
    assert adapter.integrator == NEW
    assert np.array_equal(adapter.simulate(n).quaternion_wxyz, expected.quaternion_wxyz)


# --- the command line ---------------------------------------------------------------------------

def _run(out: Path, *integrators: str) -> Path:
    args = ["run", "dzhanibekov", "--engine", "reference", "--duration", DURATION, "--out", str(out),
            "--quiet", "--no-report"]
    for i in integrators:
        args += ["--integrator", i]
    for d in DTS:
        args += ["--dt", d]
    assert main(args) == 0
    return out


def test_cli_accepts_the_old_name_and_records_the_current_one(tmp_path, capsys):
    out = _run(tmp_path / "old", OLD, f"reference:{OLD.upper()}")
    err = capsys.readouterr().err
    assert "Traceback" not in err
    notes = [line for line in err.splitlines() if "deprecated" in line]
    assert notes and all(line.startswith("freebody: warning:") and NEW in line for line in notes), err
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert [(r["integrator"], r["status"]) for r in runs] == [(NEW, "ok")] * len(DTS)
    assert all(NEW in r["trajectory"] and (out / r["trajectory"]).is_file() for r in runs)


# --- old results and baselines ------------------------------------------------------------------

def _renamed(obj, old_of: dict[str, str]):
    """A JSON value with every string (keys too) in ``old_of`` replaced: today's document as a release
    before the rename wrote it."""
    if isinstance(obj, str):
        return old_of.get(obj, obj)
    if isinstance(obj, list):
        return [_renamed(x, old_of) for x in obj]
    if isinstance(obj, dict):
        return {old_of.get(k, k): _renamed(v, old_of) for k, v in obj.items()}
    return obj


def _engine_run(reference_run: dict) -> dict:
    """An engine run (a made-up engine whose scheme is the reference lie-euler map) with the
    matches_reference that identification gives it today."""
    pb, dt = load_case("dzhanibekov"), float(reference_run["dt"])
    n = reference_run["steps"]
    m = identify(pb, simulate(pb, NEW, dt, n), RunSpec(pb, "numpy-euler", "symplectic", dt, n), TruthCache())
    assert m["integrator"] == NEW and m["indistinguishable"] == [NEW], m
    from freebody.results.judgement import with_judgement

    return with_judgement({**copy.deepcopy(reference_run), "engine": "numpy-euler", "integrator": "symplectic",
                           "engine_version": "1.0", "matches_reference": m})


@pytest.fixture(scope="module")
def documents(tmp_path_factory) -> tuple[dict, dict]:
    """(an old document, today's): reference runs of euler-quat and lie-euler at two dts, an engine
    run identified as lie-euler, convergence fits; the old one under the old name throughout."""
    out = _run(tmp_path_factory.mktemp("aliases") / "run", "euler-quat", NEW)
    current = json.loads((out / "results.json").read_text())
    current["runs"] += [_engine_run(r) for r in current["runs"] if r["integrator"] == NEW]
    assert any(c["integrator"] == NEW for c in current["convergence"])
    old = _renamed(current, {v: k for k, v in INTEGRATOR_ALIASES.items()})
    assert json.dumps(OLD) in json.dumps(old) and json.dumps(NEW) not in json.dumps(old)  # paths aside
    return old, current


def test_upgrade_names_brings_an_old_document_up_to_date(documents):
    old, current = documents
    frozen = json.dumps(old, sort_keys=True)
    up = upgrade_names(old)
    assert json.dumps(old, sort_keys=True) == frozen  # the argument is not modified
    assert up == current  # runs, matches_reference (names, ties, keyed values) and convergence
    assert upgrade_names(current) is current  # nothing to change: the document itself
    # only the reference engine's integrators are reference maps: an engine's own name is kept
    run = next(r for r in old["runs"] if r["engine"] == "reference" and r["integrator"] == OLD)
    other = {**old, "runs": [{**run, "engine": "numpy-euler"}]}
    assert upgrade_names(other)["runs"][0]["integrator"] == OLD


@pytest.mark.parametrize("schema_version", [1, 2])
def test_an_old_baseline_compares_with_current_results(documents, tmp_path, capsys, schema_version):
    old, current = documents
    old = {**old, "schema_version": schema_version}
    if schema_version == 1:  # schema-1 runs carry no experiment
        old["runs"] = [{k: v for k, v in r.items() if k != "experiment"} for r in old["runs"]]
    base, cur = tmp_path / "base.json", tmp_path / "current.json"
    base.write_text(json.dumps(old))
    cur.write_text(json.dumps(current))
    cmp = compare(load_side(base, "baseline"), load_side(cur, "current"))
    verdicts = {c.verdict for c in cmp.changes}
    assert not verdicts & {"missing", "new", "scheme changed", "not comparable"}, cmp.table()
    assert cmp.matched == len(current["runs"]) and not cmp.regressions
    assert compare(old, current).matched == len(current["runs"])  # documents not loaded from files too
    assert main(["compare", str(base), str(cur)]) == 0
    printed = capsys.readouterr().out
    assert "MISSING" not in printed and "SCHEME CHANGED" not in printed


def test_a_baseline_stored_from_old_results_has_the_current_names(documents, tmp_path):
    old, _ = documents
    src = tmp_path / "results.json"
    src.write_text(json.dumps(old))
    assert main(["baseline", str(src), "--to", str(tmp_path / "base.json")]) == 0
    text = (tmp_path / "base.json").read_text()
    assert NEW in text and OLD not in text


def test_report_of_an_old_run_directory(tmp_path):
    """A run directory written before the rename: results.json names the old integrator, the
    trajectory files keep their old names; the report is regenerated from both, under the new name
    (its figures drawn from the old files)."""
    out = _run(tmp_path / "run", NEW)
    doc = json.loads((out / "results.json").read_text())
    for r in doc["runs"]:
        path = out / r["trajectory"]
        old_path = path.with_name(path.name.replace(NEW, OLD))
        path.rename(old_path)
        r["trajectory"] = old_path.relative_to(out).as_posix()
    old = _renamed(doc, {NEW: OLD})
    (out / "results.json").write_text(json.dumps(old))
    assert main(["report", str(out)]) == 0
    report = (out / "report.md").read_text()
    assert f"reference/{NEW}" in report and OLD not in report
    html = (out / "report.html").read_text()
    assert f"reference/{NEW}" in html and "unreadable" not in html
