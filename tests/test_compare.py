"""Baselines and `freebody compare`: exit 0 on identical runs, 1 on a regression (metric worse,
run newly diverged/failed, run missing), 2 on unusable input; tolerances; the pytest helper."""
from __future__ import annotations

import copy
import ctypes.util
import json
import os
import shlex
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.results.compare import compare, default_tolerances, load_side, resolve_tolerances
from freebody.results.document import SCHEMA_VERSION
from freebody.testing import assert_no_regression
from freebody.tolerances import COMPARE_DEFAULT_RTOL as DEFAULT_RTOL
from freebody.tolerances import COMPARE_ORIENTATION_ATOL_RAD as ORIENTATION_ATOL_RAD

WORSE = 1.5  # a metric 50 % worse: far beyond the default 1 %
NOISE = 1.0 + 1e-6  # a change far inside every default tolerance (round-off on another machine)
METRIC = "orientation_error_max_rad"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("compare_run")
    assert main(["run", "dzhanibekov", "--engine", "reference", "--integrator", "euler-quat",
                 "--integrator", "rk4", "--duration", "0.1", "--dt", "0.02", "--dt", "0.01",
                 "--out", str(out), "--quiet", "--no-report"]) == 0
    return out


@pytest.fixture()
def baseline(run_dir, tmp_path) -> Path:
    path = tmp_path / "baselines" / "reference.json"
    assert main(["baseline", str(run_dir), "--to", str(path)]) == 0
    return path


def _current(run_dir: Path, tmp_path: Path, change) -> Path:
    doc = json.loads((run_dir / "results.json").read_text())
    change(doc)
    path = tmp_path / "current.json"
    path.write_text(json.dumps(doc))
    return path


def test_baseline_has_no_trajectories_and_keeps_versions(run_dir, baseline):
    doc = json.loads(baseline.read_text())
    src = json.loads((run_dir / "results.json").read_text())
    assert doc["schema_version"] == src["schema_version"] and doc["engines"] == src["engines"]
    assert all("trajectory" not in r for r in doc["runs"]) and len(doc["runs"]) == len(src["runs"])
    assert doc["runs"][0]["metrics"] == src["runs"][0]["metrics"]


def test_baseline_refuses_to_overwrite_without_force(run_dir, baseline, capsys):
    baseline.write_text("precious")
    assert main(["baseline", str(run_dir), "--to", str(baseline)]) == 2
    assert "--force" in capsys.readouterr().err and baseline.read_text() == "precious"
    assert main(["baseline", str(run_dir), "--to", str(baseline), "--force"]) == 0
    assert json.loads(baseline.read_text())["schema_version"] == SCHEMA_VERSION
    assert not [p for p in baseline.parent.iterdir() if p.name.startswith(".")]  # no temporary left


def test_identical_runs_exit_0(run_dir, baseline, capsys):
    assert main(["compare", str(baseline), str(run_dir)]) == 0
    out = capsys.readouterr().out
    assert "OK:" in out and "no change beyond the tolerances" in out


def test_noise_within_tolerance_exits_0(run_dir, baseline, tmp_path):
    def jitter(doc):
        for r in doc["runs"]:
            r["metrics"] = {k: (v * NOISE if isinstance(v, float) else v) for k, v in r["metrics"].items()}
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, jitter))]) == 0


def test_worse_metric_exits_1_and_names_it(run_dir, baseline, tmp_path, capsys):
    def worse(doc):
        doc["runs"][0]["metrics"][METRIC] *= WORSE
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, worse))]) == 1
    line = [ln for ln in capsys.readouterr().out.splitlines() if "REGRESSED" in ln]
    assert len(line) == 1 and METRIC in line[0] and "euler-quat" in line[0]


@pytest.mark.parametrize("status", ["diverged", "failed", "skipped"])
def test_run_newly_not_ok_exits_1(run_dir, baseline, tmp_path, status):
    def broke(doc):
        doc["runs"][1]["status"] = status
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, broke))]) == 1


def test_missing_run_exits_1_new_run_exits_0(run_dir, baseline, tmp_path, capsys):
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, lambda d: d["runs"].pop()))]) == 1
    assert "MISSING" in capsys.readouterr().out

    def extra(doc):
        doc["runs"].append({**copy.deepcopy(doc["runs"][0]), "integrator": "new-scheme"})
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, extra))]) == 0
    assert " new" in capsys.readouterr().out


def test_better_metric_and_fixed_run_exit_0(run_dir, baseline, tmp_path, capsys):
    base = json.loads(baseline.read_text())
    base["runs"][1]["status"] = "diverged"
    baseline.write_text(json.dumps(base))

    def better(doc):
        doc["runs"][0]["metrics"][METRIC] /= WORSE
    assert main(["compare", str(baseline), str(_current(run_dir, tmp_path, better))]) == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.endswith("improved")]
    assert len(rows) == 2 and any(" status " in r for r in rows) and any(METRIC in r for r in rows)


def test_engine_versions_side_by_side(run_dir, baseline, tmp_path, capsys):
    def upgrade(doc):
        doc["engines"]["reference"] = "9.9.9"
    main(["compare", str(baseline), str(_current(run_dir, tmp_path, upgrade))])
    row = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("reference ")]
    assert "9.9.9" in row[0] and "<- changed" in row[0]


def test_every_metric_has_a_default_tolerance():
    from freebody.run.metrics import DIAGNOSTIC_METRICS, METRIC_NAMES

    assert set(default_tolerances()) == set(METRIC_NAMES) - set(DIAGNOSTIC_METRICS)


def test_tolerances_from_file_and_command_line(run_dir, baseline, tmp_path):
    def worse(doc):
        doc["runs"][0]["metrics"][METRIC] *= WORSE
    cur = str(_current(run_dir, tmp_path, worse))
    assert main(["compare", str(baseline), cur, "--rtol", "1.0"]) == 0
    toml = tmp_path / "tol.toml"
    toml.write_text(f"rtol = 0.0\n[metrics.{METRIC}]\nrtol = 1.0\n")
    assert main(["compare", str(baseline), cur, "--tolerances", str(toml)]) == 0
    # the file's per-metric table beats the command line; the command line beats the defaults
    tols = resolve_tolerances(toml, rtol=0.5, atol=0.0)
    assert tols[METRIC].rtol == 1.0 and tols["energy_error_max_rel"].rtol == 0.5
    assert resolve_tolerances()[METRIC].rtol == DEFAULT_RTOL
    assert resolve_tolerances()[METRIC].atol == ORIENTATION_ATOL_RAD


def test_pytest_helper(run_dir, baseline, tmp_path):
    assert assert_no_regression(baseline, run_dir).exit_code == 0

    def worse(doc):
        doc["runs"][0]["metrics"][METRIC] *= WORSE
    with pytest.raises(AssertionError, match="REGRESSED"):
        assert_no_regression(baseline, _current(run_dir, tmp_path, worse))
    with pytest.raises(AssertionError):
        assert_no_regression(json.loads(baseline.read_text()), {**load_side(run_dir, "current"), "runs": []})


BAD_INPUT = [
    ("schema", lambda d: '{"schema_version": 0, "runs": []}', ["schema_version", "to migrate", "freebody baseline"]),
    ("not_json", lambda d: "{runs: ", ["not valid JSON", "line 1"]),
    ("no_schema", lambda d: '{"runs": []}', ["schema_version", "missing"]),
    ("run_without_dt", lambda d: '{"schema_version": 1, "runs": [{"case": "c", "engine": "e", "integrator": "i", '
                                 '"status": "ok"}]}', ["runs[0].dt", "missing"]),
]


@pytest.mark.parametrize("name,text,words", BAD_INPUT, ids=[b[0] for b in BAD_INPUT])
def test_unusable_baseline_is_one_line_exit_2(run_dir, tmp_path, capsys, name, text, words):
    bad = tmp_path / "bad.json"
    bad.write_text(text(None))
    assert main(["compare", str(bad), str(run_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and all(w in err[0] for w in words), err


BAD_TOLERANCES = [
    ("unknown_metric", "[metrics.orientaton_error_max_rad]\nrtol = 1.0\n", ["metrics.orientaton_error_max_rad", "did you mean"]),
    ("negative", "rtol = -1.0\n", ["rtol", ">= 0"]),
    ("string", 'atol = "small"\n', ["atol", "number"]),
    ("unknown_key", "rtl = 0.1\n", ["rtl", "did you mean 'rtol'"]),
    ("bad_toml", "rtol = = 1\n", ["invalid TOML"]),
    ("metric_not_table", "[metrics]\norientation_error_max_rad = 1.0\n", ["metrics.orientation_error_max_rad", "table"]),
]


@pytest.mark.parametrize("name,text,words", BAD_TOLERANCES, ids=[b[0] for b in BAD_TOLERANCES])
def test_bad_tolerance_file_is_one_line_exit_2(run_dir, baseline, tmp_path, capsys, name, text, words):
    toml = tmp_path / "tol.toml"
    toml.write_text(text)
    assert main(["compare", str(baseline), str(run_dir), "--tolerances", str(toml)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(toml) in err[0] and all(w in err[0] for w in words), err


def test_missing_inputs_exit_2(run_dir, baseline, tmp_path, capsys):
    assert main(["compare", str(tmp_path / "nope.json"), str(run_dir)]) == 2
    assert main(["compare", str(baseline), str(tmp_path)]) == 2  # a directory without results.json
    assert main(["compare", str(baseline), str(run_dir), "--tolerances", str(tmp_path / "no.toml")]) == 2
    with pytest.raises(SystemExit) as e:  # argparse's own one-line error
        main(["compare", str(baseline), str(run_dir), "--rtol", "nan"])
    assert e.value.code == 2
    assert main(["baseline", str(tmp_path / "nothing"), "--to", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(e.startswith("freebody: error:") for e in err), err


def test_compare_matches_on_precision_and_dt(run_dir):
    doc = load_side(run_dir, "current")
    f32 = copy.deepcopy(doc)
    for r in f32["runs"]:
        r["precision"] = "float32"
    result = compare(doc, f32)
    assert result.matched == 0 and result.exit_code == 1  # every float64 run is missing


# --- an engine installed but broken (a real import failure: tests/fake_engines/plugin_site) -------

PLUGIN_SITE = Path(__file__).parent / "fake_engines" / "plugin_site"
BROKEN = "nativelib"  # its package loads a shared library at import; OSError when it is missing
LOADER_ERROR = "libfreebody_nativelib_core.so.4.0.0: cannot open shared object file"


def _plugin_freebody(*args, healthy: bool) -> subprocess.CompletedProcess:
    """freebody in a child process that sees the plug-in engine through its entry point; its
    shared library is the C library (``healthy``) or missing (the install is broken)."""
    env = {k: v for k, v in os.environ.items() if k not in ("FREEBODY_TEST_NATIVELIB",)}
    env["PYTHONPATH"] = os.pathsep.join([str(PLUGIN_SITE)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if healthy:
        env["FREEBODY_TEST_NATIVELIB"] = ctypes.util.find_library("c") or "libc.so.6"
    return subprocess.run([sys.executable, "-m", "freebody", *map(str, args)], env=env, capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def broken_engine(tmp_path_factory) -> dict:
    """A baseline of the plug-in engine while it loads, and a run after its library went missing."""
    root = tmp_path_factory.mktemp("broken_engine")
    common = ("quiz", "--engine", BROKEN, "--dt", "0.02", "--dt", "0.01", "--duration", "0.1", "--jobs", "1",
              "--quiet")
    ok = _plugin_freebody("run", *common, "--no-report", "--out", root / "ok", healthy=True)
    assert ok.returncode == 0, ok.stderr
    stored = _plugin_freebody("baseline", root / "ok", "--to", root / "base.json", healthy=True)
    assert stored.returncode == 0, stored.stderr
    bad = _plugin_freebody("run", *common, "--out", root / "bad", healthy=False)
    return {"root": root, "base": root / "base.json", "bad": root / "bad", "run": bad}


def test_a_broken_engine_is_failed_with_its_import_error_not_missing(broken_engine):
    run = broken_engine["run"]
    assert run.returncode == 1, run.stderr  # a failed run: exit 1, no traceback
    assert "Traceback" not in run.stderr and "OSError" in run.stdout
    doc = json.loads((broken_engine["bad"] / "results.json").read_text())
    assert doc["runs"] and all(r["status"] == "failed" for r in doc["runs"])
    assert all("OSError" in r["message"] and LOADER_ERROR in r["message"] for r in doc["runs"])
    report = (broken_engine["bad"] / "report.md").read_text()  # the report renders, with the reason
    assert LOADER_ERROR in report and (broken_engine["bad"] / "report.html").is_file()


def test_compare_names_the_import_error_in_text_json_and_junit(broken_engine, tmp_path, capsys):
    base, bad = str(broken_engine["base"]), str(broken_engine["bad"])
    junit = tmp_path / "out.xml"
    assert main(["compare", base, bad, "--junit", str(junit)]) == 1
    out = capsys.readouterr().out
    versions = [ln for ln in out.splitlines() if ln.startswith(BROKEN + " ")]
    assert versions and "failed (" in versions[0] and "OSError" in versions[0] and "not installed" not in out
    assert "MISSING" in out and "FAILED (new)" in out and "2 runs failed in the current results" in out
    assert main(["compare", base, bad, "--json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["counts"]["failed_current"] == 2 and verdict["counts"]["missing"] == 4
    for c in verdict["changes"]:
        assert c["fails"] and LOADER_ERROR in c["note"], c  # the missing ones say why too
    tree = ET.parse(junit).getroot()
    cases = tree.findall(".//testcase")
    assert len(cases) == 6 and tree.get("failures") == "6"
    for case in cases:  # every failed or missing run is a <failure>, with the reason
        (failure,) = case.findall("failure")
        assert LOADER_ERROR in failure.get("message") and LOADER_ERROR in failure.text


def test_a_baseline_of_a_broken_engine_names_its_import_error(broken_engine, tmp_path):
    """`freebody baseline` of runs whose engine failed to import says 'failed (OSError ...)' for
    that engine, never 'not installed'."""
    stored = _plugin_freebody("baseline", broken_engine["bad"], "--to", tmp_path / "b.json",
                              "--allow-no-ok-runs", healthy=False)
    assert stored.returncode == 0, stored.stderr
    line = stored.stdout.strip().splitlines()[0]
    assert f"{BROKEN} failed (" in line and "OSError" in line and "not installed" not in line, line


def test_a_run_failed_on_both_sides_still_fails_the_gate(run_dir, baseline, tmp_path, capsys):
    def broke(doc):
        doc["runs"][1].update(status="failed", message="RuntimeError: the engine crashed")
    base = _current(run_dir, tmp_path / "b", broke) if (tmp_path / "b").mkdir() is None else None
    cur = _current(run_dir, tmp_path, broke)
    junit = tmp_path / "out.xml"
    assert main(["compare", str(base), str(cur), "--junit", str(junit)]) == 1
    out = capsys.readouterr().out
    assert "FAILED" in out and "RuntimeError: the engine crashed" in out
    failures = ET.parse(junit).getroot().findall(".//failure")
    assert len(failures) == 1 and "the engine crashed" in failures[0].get("message")


def test_run_with_a_baseline_prints_the_verdict_and_exits_as_compare(run_dir, baseline, tmp_path, capsys):
    args = ["run", "dzhanibekov", "--engine", "reference", "--integrator", "euler-quat", "--integrator", "rk4",
            "--dt", "0.02", "--dt", "0.01", "--quiet", "--no-report", "--jobs", "1"]
    assert main([*args, "--duration", "0.1", "--out", str(tmp_path / "same"), "--baseline", str(baseline)]) == 0
    out = capsys.readouterr().out
    assert f"compared with the baseline {baseline}: OK:" in out
    # another experiment under the same names: the gate fails, in the terminal and the exit code
    assert main([*args, "--duration", "0.05", "--out", str(tmp_path / "short"), "--baseline", str(baseline)]) == 1
    out = capsys.readouterr().out
    (line,) = [ln for ln in out.splitlines() if ln.startswith("compared with the baseline")]
    assert "REGRESSION:" in line and "4 not comparable" in line
    (command,) = [ln for ln in out.splitlines() if ln.startswith("(the changes: freebody compare ")]
    argv = shlex.split(command[len("(the changes: "):-1])[1:]
    assert main(argv) == 1 and "NOT COMPARABLE" in capsys.readouterr().out  # runnable as printed


def test_a_lost_orientation_names_no_closest_map_in_compare():
    """A run that reproduces no map and is beyond CONVERGENCE_ORIENTATION_SATURATED_RAD from the
    nearest is 'none (orientation lost)' in compare's scheme text, as in the report: every map is
    about as far, so naming the closest would mislead; a run near its closest map still names it."""
    from freebody import tolerances as tol
    from freebody.results.compare import scheme_text

    def run(d):
        return {"matches_reference": {"verdict": "closest", "integrator": None, "closest": "rk4",
                                      "max_orientation_diff_rad": d, "indistinguishable": []}}

    assert scheme_text((), run(3.1)) == "none (orientation lost)"
    assert scheme_text((), run(None)) == "none (orientation lost)"
    near = 0.5 * tol.CONVERGENCE_ORIENTATION_SATURATED_RAD
    assert scheme_text((), run(near)) == "none (closest rk4)"
