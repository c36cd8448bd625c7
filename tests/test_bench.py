"""``freebody bench`` (freebody/tools/bench/): the check logic on synthetic figures (every target
of issue 29 passes, misses, or is n/a with its reason), the child-process timer (exit code, CPU,
peak RSS of the child and not of the caller), the truth yardstick (the same motion as freebody's
truth), schema 3 documents still readable, the command line, and one ``--quick`` run end to end
(slow).

No timing assertions on the machine's speed (that is what the PASS/MISS of the benchmark is for);
every assertion here can fail on a wrong benchmark.
"""
from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import math
import sys

import numpy as np
import pytest

from freebody.adapters.base import is_available
from freebody.cli import main
from freebody.reference_impl.integrators import INTEGRATORS
from freebody.tools import bench
from freebody.tools.bench import config as C

# The yardstick DOP853 (numba rhs) and freebody's truth integrate the same equations with the same
# tolerances (rtol = atol = 1e-12) and sample times: on body_torque_spinup (2 s at 1 ms) they agree
# to round-off of the rhs arithmetic (measured 8e-16 in q, 0 in x); 1e-10 leaves room for a
# reordered sum in either rhs and still fails on a wrong sign, frame or inertia.
TRUTH_YARDSTICK_AGREEMENT = 1e-10

requires_mujoco = pytest.mark.skipif(not is_available("mujoco"), reason="mujoco not installed")


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


# --- targets and their evaluation --------------------------------------------------------------------

@pytest.mark.parametrize("value, op, limit, expected", [
    (1.0, "<=", 2.0, True), (2.0, "<=", 2.0, True), (2.5, "<=", 2.0, False),
    (12.0, ">=", 10.0, True), (10.0, ">=", 10.0, True), (9.9, ">=", 10.0, False),
    (None, "<=", 2.0, None), (1.0, ">=", None, None), (math.nan, "<=", 2.0, None),
    (math.inf, ">=", 1.0, None),
])
def test_meets(value, op, limit, expected):
    assert bench.meets(value, op, limit) is expected


def test_meets_rejects_an_unknown_comparison():
    with pytest.raises(ValueError):
        bench.meets(1.0, "<", 2.0)


def _doc(**over) -> dict:
    """A synthetic full (non-quick) schema 4 document whose every target passes."""
    doc = {
        "schema_version": 4, "quick": False, "cold": False, "repeats": 5, "cores": 2,
        "created": "2026-01-01T00:00:00+00:00", "engines": {"mujoco": "4.0.0"}, "skipped": {},
        "overhead_one_run_cpu_s": 1.0, "overhead_n_runs": 111, "overhead_n_runs_cpu_s": 1.33,
        "overhead_marginal_run_cpu_s": 0.003,
        "suite_nomjx_wall_s": 100.0, "suite_nomjx_stepping_s": 30.0, "suite_nomjx_runs": 900,
        "suite_with_mjx": True, "suite_warm_wall_s": 200.0,
        "suite_warm_stepping_s": {"mjx": 20.0, "mujoco": 12.0, "reference": 9.0},
        "suite_cold_wall_s": 210.0, "suite_report_wall_s": 15.0, "suite_runs": 1551,
        "suite_trajectories_bytes": 40e6, "suite_report_html_bytes": 3e6,
        "suite_report_md_bytes": 150e3,
        "compile_cpu_s": 6.0, "compile_cold_cpu_s": 9.0, "compile_warm_cpu_s": 3.0,
        "truth_cpu_s": 0.006, "truth_yardstick_cpu_s": 0.003, "truth_case": "body_torque_spinup",
        "truth_steps": 2000,
        "maps_step_s": {name: 2e-7 for name in INTEGRATORS},
        "maps_steps": 1000, "maps_call_s": {name: 2e-4 for name in INTEGRATORS},
        "maps_floor_call_s": {name: 1.5e-4 for name in INTEGRATORS},
        "maps_mj_step_s": 2.5e-6, "maps_rollout_step_s": 1.8e-6,
        "sweep_bodies": 200, "sweep_body_steps_per_s": 5000.0, "sweep_rollout_body_steps_per_s": 40000.0,
        "sweep_jobs_gain": 1.8, "sweep_jobs1_wall_s": 8.0, "sweep_jobs2_wall_s": 4.4,
        "rss_steps": 10**7, "rss_bytes": 300e6, "rss_short_bytes": 200e6, "rss_short_steps": 10,
        "engine_step_s": {"mujoco": {"bare_step_s": 2e-6, "freebody_step_s": 2.2e-6, "overhead_ratio": 1.1}},
    }
    doc.update(over)
    return doc


def _status(doc) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for c in bench.checks(doc):
        out.setdefault(c.key, []).append(c.status)
    return out


ALL_PASS = {"run": ["PASS"] * 2, "suite": ["PASS"] * 2, "compile": ["PASS"], "truth": ["PASS"],
            "maps": ["PASS"] * 8, "sweep": ["PASS"] * 2, "report": ["PASS"], "output": ["PASS"] * 3,
            "rss": ["PASS"], "engine": ["PASS"]}


def test_one_check_per_target_of_issue_29_and_a_passing_document():
    assert _status(_doc()) == ALL_PASS


def test_checks_miss_each_target():
    doc = _doc(overhead_marginal_run_cpu_s=0.02, overhead_one_run_cpu_s=2.5,
               suite_nomjx_wall_s=150.0,                                   # 5x > 4x
               suite_warm_stepping_s={"mjx": 30.0, "mujoco": 12.0},        # 2.5x > 2x
               compile_cpu_s=26.0, truth_cpu_s=0.024,                      # 8x > 3x
               maps_step_s={name: 6e-7 for name in INTEGRATORS},           # 4.2x mj_step
               maps_call_s={name: 6e-4 for name in INTEGRATORS},           # 4x floor
               sweep_body_steps_per_s=250.0, sweep_jobs_gain=1.1,
               suite_report_wall_s=40.0, suite_trajectories_bytes=56e6, suite_report_html_bytes=4.1e6,
               suite_report_md_bytes=1.17e6, rss_bytes=1.2e9)
    doc["engine_step_s"]["mujoco"]["overhead_ratio"] = 1.4
    st = _status(doc)
    assert st == {k: ["MISS"] * len(v) for k, v in ALL_PASS.items()}
    rows = bench.checks(doc)
    run = rows[0]
    assert run.value == pytest.approx(20.0) and run.unit == "ms"
    rss = next(c for c in rows if c.key == "rss")
    assert rss.value == pytest.approx(1200.0) and "100 B a step more" in rss.detail  # (1.2e9 - 2e8) / 1e7


def test_the_ratios_are_the_ones_the_targets_name():
    rows = {(c.key, c.label): c for c in bench.checks(_doc())}
    by = lambda key, word: next(c for (k, label), c in rows.items() if k == key and word in label)  # noqa: E731
    assert by("suite", "w/o MJX").value == pytest.approx(100 / 30)
    assert by("suite", "MJX stepping").value == pytest.approx(20 / 12)
    assert by("truth", "truth").value == pytest.approx(2.0)
    assert by("sweep", "rollout").value == pytest.approx(5000 / 40000)
    assert by("report", "report").value == pytest.approx(15 / 210)
    assert by("output", "report.md").value == pytest.approx(150.0) and by("output", "report.md").unit == "KB"
    assert by("maps", "semi-implicit-explicit-gyro / its flat").value == pytest.approx(2 / 1.5)
    assert by("maps", "semi-implicit-explicit-gyro: mj_step").value == pytest.approx(12.5)


def test_quick_figures_are_shown_not_judged():
    st = _status(_doc(quick=True, sweep_bodies=10, suite_with_mjx=False))
    for key in ("sweep", "report", "output"):
        assert set(st[key]) == {"n/a"}, key
    assert st["suite"] == ["n/a", "n/a"]
    assert st["run"] == ["PASS", "PASS"] and st["truth"] == ["PASS"] and st["rss"] == ["PASS"]
    rows = bench.checks(_doc(quick=True, suite_with_mjx=False))
    suite = [c for c in rows if c.key == "suite"]
    assert suite[0].value is not None and "--quick" in suite[0].note  # measured, shown
    assert suite[1].value is None  # no MJX in the quick suite


def test_peak_rss_of_a_shorter_run_misses_over_the_limit_and_is_not_judged_under_it():
    """A longer run needs at least as much memory, but need not need more: a run shorter than the
    target's misses over 1 GB and is not judged (no extrapolation) under it."""
    e = next(c for c in bench.checks(_doc(rss_steps=10**5, rss_bytes=2e9)) if c.key == "rss")
    assert e.status == "MISS" and e.value == pytest.approx(2000.0)
    e = next(c for c in bench.checks(_doc(rss_steps=10**6, rss_bytes=9e8)) if c.key == "rss")
    assert e.status == "n/a" and e.value == pytest.approx(900.0) and "10000000" in e.note


def test_missing_figures_are_not_applicable_with_the_reason():
    """A part not measured (or failed) leaves its figures out: its checks are n/a and say why."""
    doc = {k: v for k, v in _doc().items() if not k.startswith(("overhead_", "suite_", "truth_", "maps_floor"))}
    doc["maps_floor_call_s"] = {"semi-implicit-explicit-gyro": 1.5e-4}  # a floor of one map only
    doc.update(overhead_note="mujoco not installed", suite_note="not measured (--part)",
               truth_note="failed: RuntimeError: boom")
    rows = bench.checks(doc)
    for c in rows:
        if c.key in ("run", "suite", "truth", "report", "output") or ("flat loop" in c.label and "explicit" not in c.label):
            assert c.status == "n/a" and c.value is None and c.note, c
    assert "mujoco not installed" in rows[0].note
    assert any("boom" in c.note for c in rows if c.key == "truth")
    flat = [c for c in rows if "flat loop" in c.label]
    assert flat[0].status == "PASS" and "no floor of rk4" in flat[2].note
    text = bench.format_text(doc)  # renders without the missing figures
    assert "n/a" in text and "no floor of rk4" in text
    none = bench.checks(dict(doc, maps_floor_call_s={}, maps_floor_note="no flat-loop floors yet"))
    assert all(c.status == "n/a" and "no flat-loop floors" in c.note for c in none if "flat loop" in c.label)


def test_text_table_lists_every_check_with_its_status():
    doc = _doc(truth_cpu_s=0.024)
    doc["checks"] = [dict(vars(c), status=c.status) for c in bench.checks(doc)]
    text = bench.format_text(doc)
    table = text.split("\n\n")[1].splitlines()
    assert len(table) == 2 + len(doc["checks"])
    row = next(line for line in table if line.lstrip().startswith("truth "))
    assert "MISS" in row and "8.00x" in row and "<= 3x" in row
    assert f"{len(doc['checks']) - 1} PASS, 1 MISS, 0 n/a" in text


# --- schema 3 documents --------------------------------------------------------------------------------

SCHEMA_3 = {
    "schema_version": 3, "freebody_version": "0.2.0", "created": "2026-11-27T21:02:00+00:00",
    "quick": False, "repeats": 7, "case": "dzhanibekov", "dt": 0.001, "cores": 2,
    "load_average": [4.1, 3.0, 2.0], "engines": {"mujoco": "4.0.0"},
    "reference_map_steps": 200000, "reference_map_step_s": {"semi-implicit-explicit-gyro": 1.79e-7},
    "reference_map_call_s": {"semi-implicit-explicit-gyro": 0.036}, "reference_map_mujoco_step_s": 2.85e-6,
    "short_run_steps": 10, "short_run_rss_bytes": 217e6, "rss_steps": 10**6, "rss_bytes": 1.109e9,
    "engine_steps": 20000, "skipped": {},
    "engine_step_s": {"mujoco": {"bare_step_s": 2e-6, "freebody_step_s": 1.6e-6, "overhead_ratio": 0.81}},
    "checks": [{"key": "a", "label": "semi-implicit-explicit-gyro: mj_step / map step", "value": 15.9,
                "op": ">=", "limit": 10.0, "unit": "x", "passed": True, "status": "PASS",
                "detail": "179 ns vs 2.85 us a step", "note": ""},
               {"key": "e", "label": "peak RSS of a 1000000-step MuJoCo run", "value": 1109.0, "op": "<=",
                "limit": 1000.0, "unit": "MB", "passed": False, "status": "MISS", "detail": "", "note": ""}],
}


def test_a_schema_3_document_is_read_with_its_checks_kept(tmp_path):
    path = tmp_path / "bench3.json"
    path.write_text(json.dumps(SCHEMA_3))
    doc = bench.load_bench(path)
    assert doc["schema_version"] == bench.SCHEMA_VERSION == 4 and doc["migrated_from"] == 3
    assert doc["maps_step_s"] == SCHEMA_3["reference_map_step_s"]
    assert doc["maps_mj_step_s"] == 2.85e-6 and doc["rss_short_bytes"] == 217e6
    assert doc["checks"] == SCHEMA_3["checks"]  # judged as they were, by issue 15's targets
    text = bench.format_text(doc)
    assert "schema 3 document" in text and "1 PASS, 1 MISS, 0 n/a" in text


def test_show_prints_a_saved_document_and_refuses_an_unknown_schema(tmp_path, capsys):
    path = tmp_path / "bench3.json"
    path.write_text(json.dumps(SCHEMA_3))
    assert main(["bench", "--show", str(path)]) == 0
    assert "peak RSS of a 1000000-step MuJoCo run" in capsys.readouterr().out
    path.write_text(json.dumps(dict(SCHEMA_3, schema_version=2)))
    assert main(["bench", "--show", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bench schema 2" in err


def test_a_schema_4_document_is_judged_again_the_same(tmp_path):
    doc = _doc()
    doc["checks"] = [dict(vars(c), status=c.status) for c in bench.checks(doc)]
    path = tmp_path / "bench4.json"
    path.write_text(json.dumps(doc))
    back = bench.load_bench(path)
    assert "migrated_from" not in back
    assert [dict(vars(c), status=c.status) for c in bench.checks(back)] == doc["checks"]


# --- what is timed ------------------------------------------------------------------------------------

def test_run_child_reports_exit_code_wall_and_cpu_time():
    child = bench.run_child([sys.executable, "-c",
                             "import sys, time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass\n"
                             "time.sleep(0.2); sys.exit(3)"])
    assert child.returncode == 3
    assert 0.5 <= child.wall_s < 60
    assert child.cpu_s is None or 0.3 <= child.cpu_s < child.wall_s + 1


def test_run_child_passes_environment_variables():
    child = bench.run_child([sys.executable, "-c", "import os, sys; sys.exit(int(os.environ['FB_X']))"],
                            env={"FB_X": "7"})
    assert child.returncode == 7


@pytest.mark.skipif(sys.platform.startswith("win"), reason="no resource module")
def test_run_child_peak_rss_is_the_childs_not_the_callers():
    """A child allocating 150 MB reports at least that; a tiny one reports far less than this
    process holds (a child forked from the caller must not count the caller's pages)."""
    ballast = np.ones(40_000_000)  # 320 MB touched in this process
    try:
        tiny = bench.run_child([sys.executable, "-c", "pass"])
        big = bench.run_child([sys.executable, "-c", "b = b'x' * 150_000_000"])
    finally:
        del ballast
    assert tiny.maxrss_bytes is not None and tiny.maxrss_bytes < 100e6, tiny
    assert 150e6 <= big.maxrss_bytes < 320e6, big


def test_folder_bytes(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.npz").write_bytes(b"1" * 1000)
    (tmp_path / "y").write_bytes(b"2" * 24)
    assert bench.folder_bytes(tmp_path) == 1024
    assert bench.folder_bytes(tmp_path / "missing") == 0


def test_the_truth_yardstick_computes_freebodys_truth():
    """The numba-rhs DOP853 is a yardstick of the same computation: same motion, same samples."""
    from freebody.input.casefile import load_case
    from freebody.reference_impl.truth import NUMERICAL_ATOL, NUMERICAL_RTOL, truth_trajectory
    from freebody.tools.bench.truth import yardstick_truth

    problem = load_case(C.TRUTH_CASE)
    dt, steps = 0.01, 200
    ours = truth_trajectory(problem, dt, steps)
    Y, nfev = yardstick_truth(problem, dt, steps, NUMERICAL_RTOL, NUMERICAL_ATOL)
    q = Y[:, 6:10] / np.linalg.norm(Y[:, 6:10], axis=1)[:, None]
    q *= np.sign(np.sum(q * ours.quaternion_wxyz, axis=1))[:, None]
    assert Y.shape == (steps + 1, 13) and nfev > 0
    assert np.max(np.abs(q - ours.quaternion_wxyz)) < TRUTH_YARDSTICK_AGREEMENT
    assert np.max(np.abs(Y[:, 0:3] - ours.position)) < TRUTH_YARDSTICK_AGREEMENT
    # and it is not trivially equal: the couple spins the body up
    assert np.linalg.norm(ours.angular_velocity[-1]) > 2 * np.linalg.norm(ours.angular_velocity[0])


@requires_mujoco
def test_rollout_steps_the_models_it_is_given():
    """The maps' C yardstick (mujoco.rollout of the adapter's world) runs and times something."""
    from freebody.tools.bench.maps import rollout_step

    assert _positive(rollout_step(100)())


def test_the_removed_batched_module_stays_removed():
    assert importlib.util.find_spec("freebody.reference_impl.batched") is None


# --- the command line ---------------------------------------------------------------------------------

@pytest.mark.parametrize("option", [["--repeats", "0"], ["--rss-steps", "-1"], ["--part", "nope"]])
def test_bad_options_are_one_line_input_errors(capsys, option):
    with pytest.raises(SystemExit) as e:
        main(["bench", "--quick", *option])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") <= 2 and option[0] in err


def test_the_parser_knows_every_part():
    from freebody.cli.bench_cmd import PARTS
    assert PARTS == C.PARTS


def test_quick_and_full_configurations():
    quick, full = bench.BenchConfig.make(quick=True), bench.BenchConfig.make(quick=False)
    assert quick.suite_cases == C.QUICK_SUITE_CASES and full.suite_cases == ()
    assert (quick.rss_steps, full.rss_steps) == (C.QUICK_RSS_STEPS, C.TARGET_RSS_STEPS)
    assert "compile" not in quick.parts and full.parts == C.PARTS
    assert "compile" in bench.BenchConfig.make(quick=True, cold=True).parts
    assert bench.BenchConfig.make(quick=False, parts=("truth", "maps")).parts == ("maps", "truth")
    assert bench.BenchConfig.make(quick=False, rss_steps=0, repeats=2).rss_steps == 0


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """(stdout, the --out file's document) of one ``freebody bench --quick --json`` run."""
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["bench", "--quick", "--json", "--quiet", "--repeats", "1", "--rss-steps", "10000",
                     "--out", str(out)])
    assert code == 0
    return buf.getvalue(), json.loads(out.read_text())


@pytest.mark.slow
def test_quick_bench_reports_every_figure(quick_run):
    stdout, doc = quick_run
    assert json.loads(stdout) == doc
    assert doc["schema_version"] == 4 and doc["quick"] is True
    assert [c["key"] for c in doc["checks"]][:21] == (
        ["run"] * 2 + ["suite"] * 2 + ["compile", "truth"] + ["maps"] * 8 + ["sweep"] * 2
        + ["report"] + ["output"] * 3 + ["rss"])
    for c in doc["checks"]:
        assert c["status"] == {True: "PASS", False: "MISS", None: "n/a"}[c["passed"]]
    assert not [k for k in doc if k.endswith("_note") and "failed" in str(doc[k])], doc
    assert _positive(doc["truth_cpu_s"]) and _positive(doc["truth_yardstick_cpu_s"])
    assert set(doc["maps_step_s"]) == set(INTEGRATORS)
    if is_available("mujoco"):
        for key in ("overhead_one_run_cpu_s", "overhead_n_runs_cpu_s", "maps_mj_step_s",
                    "maps_rollout_step_s", "sweep_jobs1_wall_s", "sweep_rollout_wall_s", "rss_bytes",
                    "suite_cold_wall_s", "suite_warm_wall_s", "suite_report_wall_s",
                    "suite_nomjx_stepping_s", "suite_trajectories_bytes"):
            assert _positive(doc[key]), key
        assert doc["overhead_n_runs"] == len(C.QUICK_OVERHEAD_CASES) * 5 and doc["rss_steps"] == 10000
    text = bench.format_text(doc)
    assert text.count("PASS") + text.count("MISS") + text.count("n/a") >= len(doc["checks"])


@pytest.mark.parametrize("argv, parts", [
    (["--quick"], tuple(p for p in C.PARTS if p != "compile")),
    (["--quick", "--cold"], C.PARTS),
    (["--quick", "--no-suite"], tuple(p for p in C.PARTS if p not in ("compile", "suite"))),
    (["--no-suite"], tuple(p for p in C.PARTS if p != "suite")),
    (["--part", "truth", "--part", "maps"], ("maps", "truth")),
])
def test_options_select_the_parts(monkeypatch, capsys, argv, parts):
    seen = []

    def fake(config, progress=False):
        seen.append(config)
        return {"quick": config.quick, "repeats": config.repeats, "cores": 2, "created": "now"}
    monkeypatch.setattr(bench, "run_bench", fake)
    assert main(["bench", "--quiet", *argv]) == 0
    assert seen[0].parts == parts
    assert "0 PASS" in capsys.readouterr().out  # the text of the (empty) document
