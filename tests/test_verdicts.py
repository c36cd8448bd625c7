"""Verdicts a CI gate can trust (issue 16, items 1-3): another experiment under the same name is
"not comparable" (exit 1), a changed scheme fails even when every error went down, --strict,
--engine/--case, --json and --junit, schema-1 baselines still read, a baseline of failed runs refused."""
from __future__ import annotations

import copy
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from freebody.adapters.base import is_available
from freebody.cli import main
from freebody.input.casefile import bundled_case_paths
from freebody.results.compare import compare, load_side
from freebody.results.verdict import VERDICT_KIND, VERDICT_SCHEMA_VERSION, verdict_json
from freebody.tolerances import COMPARE_ORDER_CHANGE, COMPARE_ORIENTATION_SATURATED_RAD

pytestmark = pytest.mark.skipif(not is_available("mujoco"),
                                reason="mujoco not installed (pip install 'freebody[engines]')")
RUN = ["--engine", "mujoco", "--engine", "reference", "--integrator", "Euler", "--integrator", "RK4",
       "--integrator", "euler-quat", "--dt", "0.01", "--dt", "0.005", "--quiet", "--no-report"]


def _run(out: Path, *args) -> Path:
    assert main(["run", *args, *RUN, "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("verdicts")
    edited = tmp / "dzhanibekov.toml"  # the bundled case with another inertia, same name
    text = bundled_case_paths()["dzhanibekov"].read_text()
    assert "[body]" in text
    edited.write_text(_heavier(text))
    return {"long": _run(tmp / "long", "dzhanibekov", "--duration", "0.4"),
            "short": _run(tmp / "short", "dzhanibekov", "--duration", "0.2"),
            "edited": _run(tmp / "edited", str(edited), "--duration", "0.4")}


def _heavier(text: str) -> str:
    """The case text with its mass doubled (the line ``mass = X`` of [body])."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.strip().startswith("mass") and "=" in line:
            value = float(line.split("=", 1)[1].split("#")[0])
            lines[i] = f"mass = {2 * value!r}"
            return "\n".join(lines) + "\n"
    raise AssertionError("no mass line in the case file")


@pytest.fixture()
def baseline(runs, tmp_path) -> Path:
    path = tmp_path / "base.json"
    assert main(["baseline", str(runs["long"]), "--to", str(path)]) == 0
    return path


def _edited(src: Path, tmp_path: Path, change, name="current.json") -> Path:
    doc = json.loads((src / "results.json" if src.is_dir() else src).read_text())
    change(doc)
    out = tmp_path / name
    out.write_text(json.dumps(doc))
    return out


def test_same_experiment_passes(runs, baseline, capsys):
    assert main(["compare", str(baseline), str(runs["long"])]) == 0
    assert "OK:" in capsys.readouterr().out


def test_shorter_experiment_is_not_comparable(runs, baseline, capsys):
    assert main(["compare", str(baseline), str(runs["short"])]) == 1
    out = capsys.readouterr().out
    assert "NOT COMPARABLE" in out and "steps 40 -> 20" in out and "improved" not in out.split("REGRESSION")[0]
    assert "freebody baseline" in out  # how to accept it


def test_edited_case_file_is_not_comparable(runs, baseline, capsys):
    assert main(["compare", str(baseline), str(runs["edited"]), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    bad = [c for c in doc["changes"] if c["verdict"] == "not comparable"]
    assert bad and all("body changed" in c["note"] for c in bad) and all(c["fails"] for c in bad)
    assert doc["counts"]["not_comparable"] == len(bad) == doc["counts"]["matched"]


def _mujoco_euler_runs(doc):
    return [r for r in doc["runs"] if r["engine"] == "mujoco" and r["integrator"] == "Euler"]


def test_scheme_change_fails_even_when_every_error_improved(runs, baseline, tmp_path, capsys):
    runs_doc = json.loads((runs["long"] / "results.json").read_text())
    m0 = _mujoco_euler_runs(runs_doc)[0]["matches_reference"]
    assert m0["integrator"], "mujoco Euler reproduces a reference map (engine-notes.md)"
    scheme = " = ".join(m0["indistinguishable"])  # a tie is printed as one

    def other_scheme_and_better(doc):
        for r in _mujoco_euler_runs(doc):
            m = r["matches_reference"]
            r["matches_reference"] = {**m, "integrator": "rk4", "indistinguishable": ["rk4"]}
            r["metrics"] = {k: (v / 10 if isinstance(v, float) else v) for k, v in r["metrics"].items()}
    cur = _edited(runs["long"], tmp_path, other_scheme_and_better)
    assert main(["compare", str(baseline), str(cur)]) == 1
    out = capsys.readouterr().out
    assert "SCHEME CHANGED" in out and f"mujoco/Euler 4" in out
    assert f"scheme {scheme} -> rk4" in out and "improved" in out


def test_a_tie_that_still_holds_the_map_is_no_scheme_change(runs, baseline, tmp_path):
    def tie(doc):
        for r in _mujoco_euler_runs(doc):
            m = r["matches_reference"]
            r["matches_reference"] = {**m, "indistinguishable": [m["integrator"], "rk4"]}
    assert main(["compare", str(baseline), str(_edited(runs["long"], tmp_path, tie))]) == 0


def test_an_undecidable_run_is_no_scheme_change(runs, baseline, tmp_path):
    """A run whose maps identify nothing on its case (verdict undecidable) has no scheme to compare."""
    def undecided(doc):
        for r in _mujoco_euler_runs(doc):
            m = r["matches_reference"]
            r["matches_reference"] = {**m, "verdict": "undecidable", "integrator": None, "indistinguishable": [],
                                      "undecidable": [m["integrator"]]}
    assert main(["compare", str(baseline), str(_edited(runs["long"], tmp_path, undecided))]) == 0


def test_closest_is_a_scheme_change_and_results_without_a_verdict_read(runs, baseline, tmp_path, capsys):
    """From 'reproduces' to 'closest' (no map reproduced) the scheme changed; results written before
    the verdict key (derived from integrator / tie / closest) compare as they did."""
    def closest(doc):
        for r in _mujoco_euler_runs(doc):
            m = r["matches_reference"]
            assert m["verdict"] in ("reproduces", "indistinguishable")
            r["matches_reference"] = {**m, "verdict": "closest", "integrator": None, "indistinguishable": []}
    assert main(["compare", str(baseline), str(_edited(runs["long"], tmp_path, closest))]) == 1
    assert "SCHEME CHANGED" in capsys.readouterr().out

    def old(doc):
        for r in doc["runs"]:
            for key in ("verdict", "undecidable"):
                (r.get("matches_reference") or {}).pop(key, None)
    assert main(["compare", str(baseline), str(_edited(runs["long"], tmp_path, old, "old.json"))]) == 0
    assert main(["compare", str(_edited(runs["long"], tmp_path, old, "old.json")), str(baseline)]) == 0


def test_strict_fails_on_improvements(runs, baseline, tmp_path):
    def better(doc):
        doc["runs"][0]["metrics"]["orientation_error_max_rad"] /= 2
    cur = _edited(runs["long"], tmp_path, better)
    assert main(["compare", str(baseline), str(cur)]) == 0
    assert main(["compare", str(baseline), str(cur), "--strict"]) == 1


def test_engine_and_case_filters(runs, baseline, tmp_path, capsys):
    def worse_mujoco(doc):
        for r in doc["runs"]:
            if r["engine"] == "mujoco":
                r["metrics"]["orientation_error_max_rad"] *= 2
    cur = _edited(runs["long"], tmp_path, worse_mujoco)
    assert main(["compare", str(baseline), str(cur)]) == 1
    assert main(["compare", str(baseline), str(cur), "--engine", "reference"]) == 0
    assert main(["compare", str(baseline), str(cur), "--engine", "mujoco", "--case", "dzhanibekov"]) == 1
    capsys.readouterr()
    assert main(["compare", str(baseline), str(cur), "--engine", "mujocoo"]) == 2
    err = capsys.readouterr().err
    assert "--engine mujocoo" in err and len(err.strip().splitlines()) == 1


def test_json_verdict_validates(runs, baseline, capsys):
    assert main(["compare", str(baseline), str(runs["short"]), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["kind"] == VERDICT_KIND and doc["schema_version"] == VERDICT_SCHEMA_VERSION
    assert doc["verdict"] == "regression" and doc["exit_code"] == 1
    assert {"baseline", "current", "versions", "counts", "groups", "changes"} <= set(doc)
    for c in doc["changes"]:
        assert {"case", "engine", "integrator", "precision", "dt", "what", "baseline", "current", "limit",
                "verdict", "fails", "note"} == set(c)
    assert any(v["name"] == "mujoco" for v in doc["versions"])


def test_junit_has_one_test_case_per_run(runs, baseline, tmp_path):
    junit = tmp_path / "verdict.xml"
    assert main(["compare", str(baseline), str(runs["short"]), "--junit", str(junit)]) == 1
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites"
    cases = root.findall("./testsuite/testcase")
    n_runs = len(json.loads(baseline.read_text())["runs"])
    assert len(cases) == n_runs == int(root.get("tests"))
    failing = [c for c in cases if c.find("failure") is not None]
    assert len(failing) == n_runs == int(root.get("failures"))  # every run is another experiment
    assert all(c.find("failure").get("type") == "not comparable" for c in failing)
    for suite in root.findall("testsuite"):
        assert int(suite.get("tests")) == len(suite.findall("testcase"))
    # a passing comparison: test cases without failures
    assert main(["compare", str(baseline), str(runs["long"]), "--junit", str(junit)]) == 0
    root = ET.parse(junit).getroot()
    assert root.get("failures") == "0" and len(root.findall("./testsuite/testcase")) == n_runs


def _schema_1(doc):
    doc["schema_version"] = 1
    for r in doc["runs"]:
        r.pop("experiment", None)


def test_schema_1_baseline_still_reads_and_says_content_unchecked(runs, baseline, tmp_path, capsys):
    old = _edited(baseline, tmp_path, _schema_1, "old.json")
    assert main(["compare", str(old), str(runs["long"])]) == 0
    out = capsys.readouterr().out
    assert "could not be checked" in out
    assert main(["compare", str(old), str(runs["short"])]) == 1  # steps still checked
    assert "steps 40 -> 20" in capsys.readouterr().out


def _schema_3(doc):
    """The document as freebody 0.2.0 before schema 4 wrote it: no verdict, load sampling, state
    growth or state_dependent_loads."""
    doc["schema_version"] = 3
    for r in doc["runs"]:
        for key in ("load_sampling", "state_growth"):
            r.pop(key, None)
        if isinstance(r.get("matches_reference"), dict):
            for key in ("verdict", "undecidable"):
                r["matches_reference"].pop(key, None)
    for c in doc.get("cases", {}).values():
        c.pop("state_dependent_loads", None)


def test_schema_3_baseline_is_migrated_on_load_and_still_gates(runs, baseline, tmp_path, capsys):
    """A stored schema-3 baseline keeps working after the upgrade: its runs get the verdict their
    keys imply (migrate), and comparing it with today's runs of the same experiment passes."""
    from freebody.results.document import SCHEMA_VERSION, load_results

    old = _edited(baseline, tmp_path, _schema_3, "old3.json")
    doc = load_results(old)
    assert doc["schema_version"] == 3 < SCHEMA_VERSION
    judged = [r for r in doc["runs"] if isinstance(r.get("matches_reference"), dict)]
    assert judged and all(r["matches_reference"]["verdict"] in ("reproduces", "indistinguishable", "closest",
                                                                  "undecidable") for r in judged)
    now = {(r["engine"], r["integrator"], r["dt"]): r["matches_reference"]["verdict"]
           for r in load_results(runs["long"] / "results.json")["runs"] if r.get("matches_reference")}
    assert {(r["engine"], r["integrator"], r["dt"]): r["matches_reference"]["verdict"] for r in judged} == now
    assert main(["compare", str(old), str(runs["long"])]) == 0
    assert "OK:" in capsys.readouterr().out


def test_baseline_of_failed_runs_refused_unless_asked(runs, tmp_path, capsys):
    def all_failed(doc):
        for r in doc["runs"]:
            r["status"], r["message"] = "failed", "AttributeError: 'World' has no attribute 'getDeactivationOptions'"
    bad = _edited(runs["long"], tmp_path, all_failed)
    to = tmp_path / "b.json"
    assert main(["baseline", str(bad), "--to", str(to)]) == 2
    err = capsys.readouterr().err
    assert "no run is ok or diverged" in err and "--allow-no-ok-runs" in err and not to.exists()
    assert main(["baseline", str(bad), "--to", str(to), "--allow-no-ok-runs"]) == 0
    assert "failed" in capsys.readouterr().err  # the warning

    def one_failed(doc):
        doc["runs"][0]["status"] = "failed"
    assert main(["baseline", str(_edited(runs["long"], tmp_path, one_failed, "one.json")), "--to",
                 str(tmp_path / "c.json")]) == 0
    assert "warning: 1 of" in capsys.readouterr().err


def test_saturated_orientation_errors_compare_equal(runs, baseline):
    base = load_side(baseline, "baseline")
    cur = copy.deepcopy(base)
    b0, c0 = base["runs"][0]["metrics"], cur["runs"][0]["metrics"]
    b0["orientation_error_max_rad"] = COMPARE_ORIENTATION_SATURATED_RAD * 2.7
    c0["orientation_error_max_rad"] = COMPARE_ORIENTATION_SATURATED_RAD * 3.1
    assert compare(base, cur).exit_code == 0
    c0["orientation_error_max_rad"] = COMPARE_ORIENTATION_SATURATED_RAD * 3.1
    b0["orientation_error_max_rad"] = COMPARE_ORIENTATION_SATURATED_RAD * 0.5  # now beyond
    assert compare(base, cur).exit_code == 1


def test_order_change_is_a_scheme_change(runs, baseline):
    base = load_side(baseline, "baseline")
    entry = {"case": "dzhanibekov", "engine": "mujoco", "integrator": "RK4", "precision": "float64",
             "metric": "orientation_error_max_rad", "order": 2.0}
    base["convergence"] = [entry]
    cur = copy.deepcopy(base)
    cur["convergence"][0]["order"] = 2.0 + COMPARE_ORDER_CHANGE / 2
    assert compare(base, cur).exit_code == 0
    cur["convergence"][0]["order"] = 4.0
    result = compare(base, cur)
    assert result.exit_code == 1
    doc = verdict_json(result)
    assert [c["verdict"] for c in doc["changes"] if c["fails"]] == ["order changed"]


def test_a_setting_one_engine_version_lacks_is_shown_not_a_new_experiment(runs, baseline, tmp_path, capsys):
    """MuJoCo 3.1 has no auto-reset switch: freebody sets it on 4.0 only.  That alone must not make
    an upgrade incomparable; a setting both sides have with another value must."""
    def lacks_autoreset(doc):
        for r in doc["runs"]:
            if r["engine"] == "mujoco":
                r["experiment"]["settings"].pop("autoreset")
    old = _edited(baseline, tmp_path, lacks_autoreset, "old.json")
    assert main(["compare", str(old), str(runs["long"])]) == 0
    assert "mujoco: setting autoreset only in current" in capsys.readouterr().out

    def other_timestep(doc):
        for r in doc["runs"]:
            if r["engine"] == "mujoco":
                r["experiment"]["settings"]["timestep"] *= 2
    assert main(["compare", str(_edited(baseline, tmp_path, other_timestep, "ts.json")), str(runs["long"])]) == 1
    assert "setting timestep" in capsys.readouterr().out
