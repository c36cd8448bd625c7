"""Engines named with a version (``--engine mujoco==3.1.6``): names, supported ranges, where their
runs execute, and the side-by-side readings of one results file (compare --against, versions).

The isolated environments themselves are built in tests/test_environments.py; the end-to-end run
of an old MuJoCo in a real environment is the slow test at the end of this file."""
from __future__ import annotations

import copy
import importlib.metadata
import json
import math
import os
import re
import shlex
import sys
from pathlib import Path

import pytest

from freebody.adapters.base import (UnknownEngine, base_engine, engine_requirement, resolve_engine,
                                    split_engine_name, unsupported_version, version_in)
from freebody.adapters.reference import ReferenceAdapter
from freebody.cli import main
from freebody.envs import engines as engine_envs
from freebody.envs.versions import side_by_side, split_sides, version_groups
from freebody.errors import InputError
from freebody.input.casefile import load_case
from freebody.run import executor
from freebody.run.matrix import expand, select_integrators
from freebody.run.suite import run_specs

OLD_MUJOCO = "3.1.6"  # the release before implicitfast's and RK4's changes (docs/environments.md)


def _installed(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


# --- names ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, parts", [
    ("mujoco==3.1.6", ("mujoco", "==3.1.6")), ("mujoco", ("mujoco", "")),
    (" MuJoCo >= 3.1 , < 3.2 ", ("MuJoCo", ">=3.1,<3.2")), ("dartpy~=6.19.0", ("dartpy", "~=6.19.0")),
])
def test_an_engine_name_splits_into_the_engine_and_a_normalised_specifier(name, parts):
    assert split_engine_name(name) == parts


@pytest.mark.parametrize("bad", ["mujoco==", "mujoco=3.1", "mujoco==3.1,", "mujoco 3.1", "==3.1", "mujoco==3 1"])
def test_a_malformed_versioned_name_is_an_unknown_engine(bad):
    with pytest.raises(UnknownEngine):
        resolve_engine(bad)


def test_a_versioned_name_resolves_to_the_registered_spelling_and_its_distribution():
    assert resolve_engine("MuJoCo == 3.1.6") == "mujoco==3.1.6"
    assert base_engine("dartpy==6.19.0") == "dart"  # the pip distribution names the engine too
    assert resolve_engine("dartpy==6.19.0") == "dart==6.19.0"
    assert engine_requirement("dart==6.19.0") == "dartpy==6.19.0"
    assert engine_requirement("mjx==3.17.0") == "mujoco-mjx==3.17.0"
    assert engine_requirement("mujoco") is None
    with pytest.raises(UnknownEngine, match="no versions"):
        engine_requirement("reference==0.1")


def test_the_cli_rejects_a_bad_engine_version_in_one_line(capsys):
    assert main(["run", "dzhanibekov", "--engine", "mujoco=3.1.6", "--out", "/nonexistent/x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mujoco=3.1.6" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("version, spec, ok", [
    ("3.1.6", "==3.1.6", True), ("3.1.6", ">=3.2", False), ("6.20.0", ">=6.19", True),
    ("6.18.0", ">=6.19", False), ("6.19", "==6.19.0", True), ("3.17.0 (mujoco 4.0.0, jax 0.10.2)", ">=3.17", True),
    ("6.19.5", "~=6.19.0", True), ("6.20.0", "~=6.19.0", False), ("3.1.6", "==3.1.*", True),
    ("3.2.0", "!=3.2.*", False), ("4.0.0", ">=3.1,<4", False), ("4.0.0rc1", ">=4", True),
    ("unknown", ">=1", None),
])
def test_version_in(version, spec, ok):
    assert version_in(version, spec) is ok


# --- supported ranges -----------------------------------------------------------------------------

def test_a_version_outside_the_adapters_range_is_a_skipped_run_naming_the_range(monkeypatch, tmp_path):
    monkeypatch.setattr(ReferenceAdapter, "supported_versions", ">=99")
    reason = unsupported_version(ReferenceAdapter, ReferenceAdapter.engine_version())
    assert ">=99" in reason and "not supported" in reason
    specs = expand([load_case("dzhanibekov")], ["reference"], ["rk4"], [0.01], 0.1)
    doc, _ = run_specs(specs, tmp_path, ["reference"], progress=False, isolate=False)
    (run,) = doc["runs"]
    assert run["status"] == "skipped" and ">=99" in run["message"]
    monkeypatch.setattr(ReferenceAdapter, "supported_versions", ">=0.1")
    doc, _ = run_specs(specs, tmp_path / "b", ["reference"], progress=False, isolate=False)
    assert doc["runs"][0]["status"] == "ok"


def test_every_builtin_adapter_supports_its_installed_version():
    from freebody.adapters.base import is_available, load_adapter

    for name in ("mujoco", "pybullet", "dart"):
        if is_available(name):
            cls = load_adapter(name)
            assert cls.supported_versions, name
            assert unsupported_version(cls, cls.engine_version()) is None, name


# --- where runs execute ---------------------------------------------------------------------------

def test_a_versioned_engine_whose_version_is_installed_here_runs_here():
    have = _installed("mujoco")
    if have is None:
        pytest.skip("mujoco is not installed")
    assert engine_envs.requirement(f"mujoco=={have}") is None
    assert engine_envs.requirement("mujoco==0.0.1") == "mujoco==0.0.1"
    assert engine_envs.isolated("mujoco==0.0.1")


def test_an_integrator_for_an_engine_applies_to_each_of_its_versions():
    offered = ("Euler", "RK4", "implicit")
    assert select_integrators("mujoco==3.1.6", offered, ["mujoco:RK4"]) == ["RK4"]
    assert select_integrators("mujoco==3.1.6", offered, ["mujoco==3.1.6:implicit"]) == ["implicit"]
    # a selection for another version does not apply
    assert select_integrators("mujoco==3.1.6", offered, ["mujoco==4.0.0:implicit"]) == list(offered)


def test_no_isolation_and_dask_refuse_an_isolated_engine_before_building_anything(tmp_path, capsys):
    for extra in (["--no-isolation"], ["--executor", "dask", "--scheduler", "tcp://127.0.0.1:1"]):
        code = main(["run", "dzhanibekov", "--engine", "mujoco==0.0.1", "--out", str(tmp_path), *extra])
        err = capsys.readouterr().err
        assert code == 2 and "isolated environment" in err and "creating" not in err


def _second_interpreter() -> str:
    """Another path of this very interpreter (python3 beside python): a worker started with it is
    an 'isolated' worker to the pool, with this environment's packages."""
    here = Path(sys.executable)
    for name in ("python3", "python", f"python3.{sys.version_info.minor}"):
        other = here.with_name(name)
        if other.exists() and other.name != here.name:
            return str(other)
    pytest.skip("no second name of this interpreter")


@pytest.mark.parametrize("jobs", [1, 2])
def test_runs_go_to_the_workers_of_their_engines_interpreter(tmp_path, monkeypatch, jobs):
    other = _second_interpreter()
    started: list[str | None] = []

    class Recording(executor.Worker):
        def __init__(self, options, python=None):
            started.append(python)
            super().__init__(options, python)

        def send(self, task):  # a run reaches only a worker of its interpreter
            assert self.python == ({"reference==pinned": other}.get(task.run.spec.engine))
            super().send(task)

    monkeypatch.setattr(executor, "Worker", Recording)
    problems = [load_case("dzhanibekov"), load_case("body_torque_spinup")]
    specs = expand(problems, ["reference"], ["rk4", "euler-quat"], [0.01], 0.2)
    import dataclasses

    specs += [dataclasses.replace(s, engine="reference==pinned") for s in specs if s.integrator == "rk4"]
    tasks = executor.plan(specs)
    done: dict[int, dict] = {}
    with executor.LocalPool(jobs, interpreters={"reference==pinned": other}) as pool:
        pool.run(tasks, lambda i, p: done.setdefault(i, p))
    assert len(done) == len(specs) and set(started) == {None, other}
    assert len(started) <= jobs + 4  # workers are swapped, not started per run
    by_key = {(specs[i].problem.name, specs[i].engine, specs[i].integrator): p["result"] for i, p in done.items()}
    for case in ("dzhanibekov", "body_torque_spinup"):
        a, b = by_key[(case, "reference", "rk4")], by_key[(case, "reference==pinned", "rk4")]
        assert a.status == b.status == "ok" and a.metrics == b.metrics


# --- one results file, two versions ---------------------------------------------------------------

@pytest.fixture(scope="module")
def two_versions(tmp_path_factory) -> dict:
    """A results document whose reference runs appear under two engine names, the second with
    implicitfast-like changes: one run's scheme and one metric moved."""
    out = tmp_path_factory.mktemp("versions")
    specs = expand([load_case("dzhanibekov")], ["reference"], ["rk4", "semi-implicit-explicit-gyro"],
                   [0.01, 0.005], 1.0)
    doc, _ = run_specs(specs, out, ["reference"], progress=False, jobs=1)
    new = []
    for r in doc["runs"]:
        a, b = copy.deepcopy(r), copy.deepcopy(r)
        a["engine"], b["engine"] = "fake==1", "fake==2"
        a["matches_reference"] = {"integrator": r["integrator"], "closest": r["integrator"]}
        b["matches_reference"] = dict(a["matches_reference"])
        if r["integrator"] == "rk4" and r["dt"] == 0.01:
            b["matches_reference"] = {"integrator": "rkmk4", "closest": "rkmk4"}
            b["metrics"]["orientation_error_max_rad"] *= 10
        new += [a, b]
    from freebody.results.document import load_results  # hand-made runs: the newest shape, as on load

    doc = load_results({**doc, "runs": doc["runs"] + new, "engines": {**doc["engines"], "fake==1": "1", "fake==2": "2"}})
    (out / "two.json").write_text(json.dumps(doc))
    return {"doc": doc, "path": out / "two.json"}


def test_side_by_side_rows_show_each_versions_scheme_and_what_changed(two_versions):
    doc = two_versions["doc"]
    assert version_groups(doc) == {"fake": ["fake==1", "fake==2"]}
    rows = side_by_side(doc)
    assert len(rows) == 2 and all([c.engine for c in r.cells] == ["fake==1", "fake==2"] for r in rows)
    changed = {r.integrator: r for r in rows if r.changes}
    assert list(changed) == ["rk4"] and changed["rk4"].changes == ["scheme", "order"]
    old, new = changed["rk4"].cells
    assert old.scheme == "rk4" and new.scheme == "rk4 / rkmk4" and changed["rk4"].final_angle_rad == 0.0
    # two time steps: the slope of the error; the moved error at dt = 0.01 moves it by one decade
    assert changed["rk4"].order_kind == "slope" and new.order == pytest.approx(old.order + math.log(10) / math.log(2))


def test_compare_against_gives_the_verdicts_between_two_engines_of_one_file(two_versions, capsys):
    path = str(two_versions["path"])
    assert main(["compare", path, "--engine", "fake==1", "--against", "fake==2"]) == 1
    out = capsys.readouterr().out
    assert "scheme changed" in out.lower() and "rk4 → rkmk4" in out.replace("->", "→") or "rkmk4" in out
    assert main(["compare", path, "--engine", "fake==1", "--against", "fake==1"]) == 2
    assert main(["compare", path, "--engine", "fake==1", "--against", "fake==3"]) == 2
    assert main(["compare", path, "--against", "fake==2"]) == 2
    assert main(["compare", path, path, "--engine", "fake==1", "--against", "fake==2"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(errors) == 4 and all(line.startswith("freebody: error:") for line in errors)


def test_split_sides_renames_both_sides_to_one_engine(two_versions):
    base, cur = split_sides(two_versions["doc"], "fake==1", "fake==2")
    assert {r["engine"] for r in base["runs"]} == {r["engine"] for r in cur["runs"]} == {"fake"}
    assert base["engines"] == {"fake": "1"} and cur["engines"] == {"fake": "2"}
    with pytest.raises(InputError):
        split_sides(two_versions["doc"], "fake==1", "nope")


def _side(doc: dict, name: str, as_name: str | None = None) -> dict:
    """The runs of one engine name of a document, as a results document of their own (renamed)."""
    runs = [{**r, "engine": as_name or name} for r in doc["runs"] if r["engine"] == name]
    return {**doc, "runs": runs, "engines": {as_name or name: doc["engines"][name]}}


def test_version_changes_are_findings_linking_to_the_side_by_side_table(two_versions):
    from freebody.report import findings as fd
    from freebody.report.render import write_reports

    doc = copy.deepcopy(two_versions["doc"])
    for r in doc["runs"]:  # an engine default that freebody overrides, moved by the upgrade
        if r["engine"].startswith("fake=="):
            r["engine_settings"] = {"damping": {"default": 0.0 if r["engine"] == "fake==1" else 0.05, "set": 0.0}}
    found = [f for f in fd.find(doc["runs"]) if f.kind == "version-change"]
    runs = [f for f in found if f.case]
    assert [(f.case, f.label) for f in runs] == [("dzhanibekov", "fake/rk4")]
    text = runs[0].text
    assert text.startswith("from fake==1") and " to fake==2" in text
    assert "scheme rk4 -> rk4 / rkmk4; observed order" in text
    (default,) = [f for f in found if not f.case]
    assert "damping" in default.text and "0.05" in default.text and default.label == "fake"
    out = two_versions["path"].parent
    md_path, html_path = write_reports(out, doc)
    first_screen = md_path.read_text().split("## Verdict per case")[0]
    assert first_screen.count("changed between engine versions") == 2
    assert first_screen.count("(report.html#versions)") == 2 and "No finding" not in first_screen
    html = html_path.read_text()
    nav = html.split("<nav>", 1)[1].split("</nav>", 1)[0]
    assert '<a href="#versions">' in nav and '<h2 id="versions">Engine versions side by side' in html
    items = [li for li in html.split("<li>") if "changed between engine versions" in li]
    assert len(items) == 2 and all('href="#versions"' in li for li in items)


def test_compare_matches_an_engine_across_the_names_of_two_files(two_versions, tmp_path, capsys):
    """A baseline of ``fake==1`` and current results of the unversioned ``fake`` (version 2): the
    runs match across the names, and the scheme change is reported as within one file."""
    doc = two_versions["doc"]
    base, cur = tmp_path / "base.json", tmp_path / "cur.json"
    base.write_text(json.dumps(_side(doc, "fake==1")))
    cur.write_text(json.dumps(_side(doc, "fake==2", "fake")))
    assert main(["compare", str(base), str(cur)]) == 1
    out = capsys.readouterr().out
    assert "fake==1 (baseline) = fake (current)" in out and "SCHEME CHANGED" in out and "MISSING" not in out
    assert main(["compare", str(base), str(cur), "--json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    n = len(_side(doc, "fake==1")["runs"])
    assert verdict["counts"]["matched"] == n and verdict["counts"]["missing"] == verdict["counts"]["new"] == 0
    assert verdict["counts"]["scheme_changed"] == 1
    assert verdict["engines_matched_across_names"] == [{"engine": "fake", "baseline": "fake==1", "current": "fake"}]
    assert {"name": "fake", "baseline": "1", "current": "2"} in verdict["versions"]
    # the same verdicts as the two versions of one file compared with --against
    assert main(["compare", str(two_versions["path"]), "--engine", "fake==1", "--against", "fake==2", "--json"]) == 1
    against = json.loads(capsys.readouterr().out)
    keep = ("case", "integrator", "dt", "what", "verdict")
    assert ([{k: c[k] for k in keep} for c in verdict["changes"]]
            == [{k: c[k] for k in keep} for c in against["changes"]])


_COMMAND = re.compile(r"freebody (?:baseline|compare|run|report|envs) [^\n`<]*")


def _suggested(text: str) -> list[list[str]]:
    """The freebody commands a text suggests, split as a shell would (argv without 'freebody')."""
    return [shlex.split(m.group().rstrip(" .)"))[1:] for m in _COMMAND.finditer(text)]


def test_every_command_freebody_suggests_is_runnable_as_printed(two_versions, tmp_path, capsys):
    from freebody.cli import build_parser

    doc = two_versions["doc"]
    folder = tmp_path / "with space"  # printed paths are quoted for the shell
    folder.mkdir()
    base, cur = folder / "base.json", folder / "cur.json"
    base.write_text(json.dumps(_side(doc, "fake==1")))
    cur.write_text(json.dumps(_side(doc, "fake==2", "fake")))
    assert main(["compare", str(base), str(cur)]) == 1
    out = capsys.readouterr().out
    commands = _suggested(out)
    assert commands and commands[-1][:1] == ["baseline"], out  # how to accept the change
    assert main(["compare", str(two_versions["path"]), "--engine", "fake==1", "--against", "fake==2"]) == 1
    against = capsys.readouterr().out
    assert "[fake==1]" in against and all("[" not in " ".join(c) for c in _suggested(against))
    assert main(["compare", str(base), str(cur), "--json"]) == 1
    accept = json.loads(capsys.readouterr().out)["accept_command"]
    assert shlex.split(accept)[1:] == commands[-1]
    for argv in commands + _suggested(against):
        build_parser().parse_args(argv)  # argparse exits 2 on a command it cannot read
        assert main(argv) in (0, 1), argv  # not 2: the paths and options exist
    capsys.readouterr()
    assert main(["compare", str(base), str(cur)]) == 0  # the baseline accepted


# --- a real old MuJoCo in a real environment (slow: builds it with pip on first use) ---------------

BLOW_UP_CASE = """\
name = "blow_up"
duration = 30.0
dt = 0.01
body = { mass = 1.0, inertia = [[1, 0, 0], [0, 2, 0], [0, 0, 3]] }
initial = { angular_velocity = [0.1, 50.0, 0.0] }  # explicit Euler blows up within 30 s at dt 0.01
"""
# Time steps at which MuJoCo's RK4 is in its asymptotic range on dzhanibekov over 10 s on both
# versions (errors 5e-5 .. 2e-7 rad on 4.0, above the truth's 1e-9 floor): three, so orders are fitted.
ORDER_DTS = ("0.04", "0.02", "0.01")
ORDER_TOLERANCE = 0.3  # |fitted - nominal| of RK4's orientation order at ORDER_DTS (measured: 2.00, 3.9)


@pytest.fixture(scope="module")
def env_root(tmp_path_factory):
    """A FREEBODY_ENV_DIR of this module: the environment is built once for its tests
    (FREEBODY_TEST_ENV_DIR: a folder of environments built before, e.g. ~/.cache/freebody/envs,
    reused instead; the first test then finds its environment built)."""
    root = Path(os.environ["FREEBODY_TEST_ENV_DIR"]) if os.environ.get("FREEBODY_TEST_ENV_DIR") \
        else tmp_path_factory.mktemp("envs")
    old = os.environ.get("FREEBODY_ENV_DIR")
    os.environ["FREEBODY_ENV_DIR"] = str(root)
    for f in (engine_envs.environment, engine_envs.describe):
        f.cache_clear()
    yield root
    if old is None:
        os.environ.pop("FREEBODY_ENV_DIR", None)
    else:
        os.environ["FREEBODY_ENV_DIR"] = old
    for f in (engine_envs.environment, engine_envs.describe):
        f.cache_clear()


@pytest.mark.slow
def test_two_mujoco_versions_side_by_side_in_one_run(env_root, tmp_path, capsys):
    have = _installed("mujoco")
    if have is None or have == OLD_MUJOCO:
        pytest.skip(f"needs a MuJoCo other than {OLD_MUJOCO} installed here (have {have})")
    new = f"mujoco=={have}"
    old = f"mujoco=={OLD_MUJOCO}"
    code = main(["run", "dzhanibekov", "--engine", old, "--engine", new, "--integrator", "mujoco:implicitfast",
                 "--integrator", "mujoco:RK4", *(a for d in ORDER_DTS for a in ("--dt", d)),
                 "--out", str(tmp_path / "out"), "--quiet"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    if not os.environ.get("FREEBODY_TEST_ENV_DIR"):
        assert f"creating environment for {old}" in captured.err  # built on first use, progress shown
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert doc["engines"] == {old: OLD_MUJOCO, new: have}
    runs = {(r["engine"], r["integrator"], r["dt"]): r for r in doc["runs"]}
    assert all(r["status"] == "ok" for r in runs.values()) and len(runs) == 12
    # implicitfast: MuJoCo 3.1 drops the gyroscopic term's derivative (= Euler's map); 4.0 keeps it
    assert "semi-implicit-explicit-gyro" in runs[(old, "implicitfast", 0.01)]["matches_reference"]["indistinguishable"]
    assert "semi-implicit-implicit-gyro" in runs[(new, "implicitfast", 0.01)]["matches_reference"]["indistinguishable"]
    orders = {e["engine"]: e["order"] for e in doc["convergence"]
              if e["integrator"] == "RK4" and e["metric"] == "orientation_error_max_rad"}
    assert abs(orders[old] - 2) < ORDER_TOLERANCE and abs(orders[new] - 4) < ORDER_TOLERANCE, orders

    report = (tmp_path / "out" / "report.md").read_text()
    section = report.split("## Engine versions side by side", 1)[1].split("\n## ", 1)[0]
    assert "| dzhanibekov | mujoco/RK4" in section.replace("  ", "").replace(" |", "|").replace("| ", "|").replace("|", "| ").replace("  ", " ") or "mujoco/RK4" in section
    rk4 = [line for line in section.splitlines() if "mujoco/RK4" in line]
    assert rk4 and "scheme, order" in rk4[0]
    fast = [line for line in section.splitlines() if "mujoco/implicitfast" in line]
    assert fast and "scheme" in fast[0]

    code = main(["compare", str(tmp_path / "out"), "--engine", old, "--against", new])
    out = capsys.readouterr().out
    assert code == 1 and "SCHEME CHANGED" in out and "ORDER CHANGED" in out.upper()

    # cached use: no build, the same numbers
    code = main(["run", "dzhanibekov", "--engine", old, "--integrator", "mujoco:implicitfast", "--dt", "0.01",
                 "--out", str(tmp_path / "again"), "--quiet", "--no-report"])
    captured = capsys.readouterr()
    assert code == 0 and "creating environment" not in captured.err
    again = json.loads((tmp_path / "again" / "results.json").read_text())["runs"][0]
    assert again["metrics"] == runs[(old, "implicitfast", 0.01)]["metrics"]


@pytest.mark.slow
def test_an_old_mujoco_blow_up_is_diverged_not_silently_reset(env_root, tmp_path, capsys):
    """MuJoCo 3.1 has no switch for its auto-reset: a blow-up resets the body to rest.  It still
    counts the warning first, which the adapter watches: the run is diverged at the step."""
    case = tmp_path / "blow_up.toml"
    case.write_text(BLOW_UP_CASE)
    code = main(["run", str(case), "--engine", f"mujoco=={OLD_MUJOCO}", "--integrator", "mujoco:Euler",
                 "--out", str(tmp_path / "out"), "--quiet", "--no-report"])
    capsys.readouterr()
    assert code == 0
    (run,) = json.loads((tmp_path / "out" / "results.json").read_text())["runs"]
    assert run["status"] == "diverged" and "BADQACC" in run["message"].upper(), run["message"]
    assert "autoreset" not in run["engine_settings"]  # 3.1.6 lacks the switch: nothing was set


@pytest.mark.slow
def test_an_engine_registered_with_an_environment_always_runs_there(env_root, tmp_path, monkeypatch, capsys):
    """An engine whose package pins conflict with another's declares an environment in its
    registry entry: its runs go there without a version on the command line."""
    from freebody.adapters.base import ENGINES

    monkeypatch.setitem(ENGINES, "mujoco-old", ENGINES["mujoco"]._replace(environment=f"mujoco=={OLD_MUJOCO}"))
    code = main(["run", "dzhanibekov", "--engine", "mujoco-old", "--integrator", "mujoco-old:Euler", "--dt", "0.01",
                 "--duration", "1", "--out", str(tmp_path / "out"), "--quiet", "--no-report"])
    captured = capsys.readouterr()
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert code == 0, (captured.err, doc["runs"][0]["message"])
    assert doc["engines"] == {"mujoco-old": OLD_MUJOCO}
    assert [r["engine_version"] for r in doc["runs"]] == [OLD_MUJOCO]


@pytest.mark.slow
def test_an_upgrade_gates_against_a_baseline_of_the_pinned_version(env_root, tmp_path, capsys):
    """A baseline stored from ``--engine mujoco==3.1.6`` against a plain ``--engine mujoco`` run
    (the installed version): the runs match across the names and the verdict reports what a run
    of both versions side by side reports as findings: implicitfast's scheme, RK4's scheme and order."""
    have = _installed("mujoco")
    if have is None or have == OLD_MUJOCO:
        pytest.skip(f"needs a MuJoCo other than {OLD_MUJOCO} installed here (have {have})")
    old = f"mujoco=={OLD_MUJOCO}"
    common = ["convergence_tumbling", "--integrator", "mujoco:implicitfast", "--integrator", "mujoco:RK4",
              "--quiet", "--jobs", "1"]
    assert main(["run", *common, "--engine", old, "--no-report", "--out", str(tmp_path / "old")]) == 0
    assert main(["baseline", str(tmp_path / "old"), "--to", str(tmp_path / "base.json")]) == 0
    assert main(["run", *common, "--engine", "mujoco", "--no-report", "--out", str(tmp_path / "new")]) == 0
    capsys.readouterr()
    assert main(["compare", str(tmp_path / "base.json"), str(tmp_path / "new"), "--json"]) == 1
    verdict = json.loads(capsys.readouterr().out)
    assert verdict["engines_matched_across_names"] == [{"engine": "mujoco", "baseline": old, "current": "mujoco"}]
    assert verdict["counts"]["missing"] == verdict["counts"]["new"] == 0 and verdict["counts"]["matched"] == 8
    moved = {(c["integrator"], c["verdict"]) for c in verdict["changes"] if c["fails"]}
    assert {("implicitfast", "scheme changed"), ("RK4", "scheme changed"), ("RK4", "order changed")} <= moved
    (order,) = [c for c in verdict["changes"] if c["verdict"] == "order changed"]
    assert abs(order["baseline"] - 2) < ORDER_TOLERANCE and abs(order["current"] - 4) < ORDER_TOLERANCE

    # both versions in one run: the same changes are findings on the report's first screen
    assert main(["run", *common, "--engine", old, "--engine", "mujoco", "--out", str(tmp_path / "both")]) == 0
    first = (tmp_path / "both" / "report.md").read_text().split("## Verdict per case")[0]
    lines = [ln for ln in first.splitlines() if "changed between engine versions" in ln]
    rk4 = [ln for ln in lines if "mujoco/RK4" in ln]
    fast = [ln for ln in lines if "mujoco/implicitfast" in ln]
    assert rk4 and "scheme rk4-body-exp -> rkmk4-body" in rk4[0] and "observed order 2." in rk4[0]
    assert fast and "scheme semi-implicit-explicit-gyro" in fast[0] and "report.html#versions" in fast[0]
    assert "No finding" not in first
