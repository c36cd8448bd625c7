"""``freebody bench``: its pieces (the pinned suite, the targets and their evaluation, the child
process timer) and a ``--quick`` run end to end.

No timing assertions on the machine's speed (that is what the PASS/MISS of the benchmark is for);
every assertion here can fail on a wrong benchmark.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import sys

import numpy as np
import pytest

from freebody.adapters.base import engine_names, is_available
from freebody.cli import main
from freebody.reference_impl.integrators import INTEGRATORS
from freebody.tools import bench
from freebody.tools.bench import (ENGINE_EQUIVALENT_MAPS, PINNED_SUITE_CASES,
                                  PINNED_SUITE_INTEGRATORS, PINNED_SUITE_RUNS, QUICK_SUITE_CASES,
                                  SCHEMA_VERSION)

PINNED_ENGINES = list(PINNED_SUITE_INTEGRATORS)
requires_pinned_engines = pytest.mark.skipif(
    not all(is_available(e) for e in PINNED_ENGINES),
    reason=f"the pinned suite needs every one of {', '.join(PINNED_ENGINES)} installed")


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


# --- the pinned suite -----------------------------------------------------------------------------

def test_pinned_suite_has_525_distinct_runs():
    runs = bench.pinned_suite_runs()
    assert len(runs) == PINNED_SUITE_RUNS == 525
    assert len(set(r[:5] for r in runs)) == len(runs)  # (case, engine, integrator, precision, dt)
    assert "mjx" not in PINNED_SUITE_INTEGRATORS
    assert len(bench.pinned_suite_runs(QUICK_SUITE_CASES)) == 60


@requires_pinned_engines
def test_pinned_suite_is_in_todays_default_suite_without_mjx():
    """Every pinned run is one that `freebody run` (no case, no option) runs today on the engines
    but mjx, with the same steps, and the default runs of the pinned (case, engine, integrator)
    are exactly the pinned list.  When pinned (2026-11-27) the pinned list was the whole default
    suite without mjx (525 runs); cases, engines or integrators added since are not pinned.  Fails
    when a pinned case changes its time steps or length, or an engine drops a pinned integrator."""
    from freebody.input.casefile import bundled_case_paths

    args = list(bundled_case_paths())
    for e in engine_names():
        if e != "mjx":
            args += ["--engine", e]
    default = bench.expanded_runs(args)
    pinned = bench.pinned_suite_runs()
    assert len(default) >= PINNED_SUITE_RUNS
    assert [r for r in default if r[0] in PINNED_SUITE_CASES
            and r[2] in PINNED_SUITE_INTEGRATORS.get(r[1], ())] == pinned


@requires_pinned_engines
def test_the_pinned_command_expands_to_the_pinned_list():
    assert bench.pinned_suite_differences() == []
    assert bench.pinned_suite_differences(QUICK_SUITE_CASES) == []
    args = bench.pinned_suite_args()
    assert args[:len(PINNED_SUITE_CASES)] == list(PINNED_SUITE_CASES)
    assert "--precision" in args and "reference:rk4" in args and "mujoco:Euler" in args


def test_a_changed_pin_is_reported(monkeypatch):
    """A pinned case whose time steps are not the case's any more, an unknown case: named."""
    changed = dict(PINNED_SUITE_CASES, quiz=((0.1, 2), (0.05, 2)))
    monkeypatch.setattr(bench, "PINNED_SUITE_CASES", changed)
    diffs = bench.pinned_suite_differences(["quiz"])
    assert diffs and "quiz" in diffs[0]
    monkeypatch.setattr(bench, "PINNED_SUITE_CASES", {"no_such_case": ((0.01, 1),)})
    diffs = bench.pinned_suite_differences()
    assert len(diffs) == 1 and "no longer expands" in diffs[0]


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


def test_long_run_limit_is_three_times_bare_plus_one_second():
    assert bench.long_run_limit(0.1) == pytest.approx(1.3)
    assert bench.long_run_limit(0.0) == 1.0


def _doc(**over) -> dict:
    """A synthetic full (non-quick) bench document whose every target passes."""
    doc = {
        "quick": False, "repeats": 7, "case": "dzhanibekov", "dt": 0.001, "cores": 2,
        "created": "2026-01-01T00:00:00+00:00", "engines": {"mujoco": "4.0.0"}, "skipped": {},
        "engine_steps": 20000,
        "engine_step_s": {"mujoco": {"bare_step_s": 2e-6, "freebody_step_s": 2.2e-6,
                                     "overhead_ratio": 1.1}},
        "reference_map_steps": 1000, "reference_map_mujoco_step_s": 2e-6,
        "reference_map_step_s": {name: 1.2e-7 for name in INTEGRATORS},
        "reference_map_call_s": {name: 1.2e-4 for name in INTEGRATORS},
        "long_run_steps": 50000, "short_run_steps": 10, "long_run_command": "freebody run ...",
        "long_run_s": 2.0, "short_run_s": 1.8, "long_run_extra_s": 0.2, "long_run_bare_s": 0.1,
        "long_run_limit_s": 1.3, "short_run_rss_bytes": 200e6, "long_run_rss_bytes": 200e6,
        "rss_steps": 10**7, "rss_bytes": 300e6, "rss_run_s": 20.0,
        "suite_pinned": True, "suite_pinned_differences": [], "suite_runs": 525, "suite_jobs": 2,
        "suite_serial_s": 60.0, "suite_parallel_s": 40.0, "suite_speedup": 1.5,
        "suite_trajectories_bytes": 30e6, "suite_report_html_bytes": 3e6,
        "suite_results_json_bytes": 1e6, "suite_note": "...",
    }
    doc.update(over)
    return doc


def _status(doc) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for c in bench.checks(doc):
        out.setdefault(c.key, []).append(c.status)
    return out


def test_checks_of_a_passing_document():
    assert _status(_doc()) == {"a": ["PASS", "PASS"], "b": ["PASS"], "c": ["PASS"],
                               "d": ["PASS", "PASS"], "e": ["PASS"], "1": ["PASS"]}


def test_checks_miss_each_target():
    doc = _doc(reference_map_step_s={name: 3e-7 for name in INTEGRATORS},  # 6.7x < 10x
               long_run_extra_s=1.5,                                        # > 3 x 0.1 + 1 s
               suite_parallel_s=50.0, suite_trajectories_bytes=60e6, suite_report_html_bytes=5e6,
               rss_bytes=1.2e9)
    doc["engine_step_s"]["mujoco"]["overhead_ratio"] = 1.4
    st = _status(doc)
    assert st == {"a": ["MISS", "MISS"], "b": ["MISS"], "c": ["MISS"], "d": ["MISS", "MISS"],
                  "e": ["MISS"], "1": ["MISS"]}
    e = next(c for c in bench.checks(doc) if c.key == "e")
    assert e.value == pytest.approx(1200.0) and "100 B a step more" in e.detail  # (1.2e9 - 2e8) / 1e7


def test_peak_rss_of_a_shorter_run_misses_over_the_limit_and_is_not_judged_under_it():
    """A longer run needs at least as much memory, but need not need more: a run shorter than the
    target's misses over 1 GB and is not judged (no extrapolation) under it."""
    e = next(c for c in bench.checks(_doc(rss_steps=10**5, rss_bytes=2e9)) if c.key == "e")
    assert e.status == "MISS" and e.value == pytest.approx(2000.0)
    e = next(c for c in bench.checks(_doc(rss_steps=10**6, rss_bytes=9e8)) if c.key == "e")
    assert e.status == "n/a" and e.value == pytest.approx(900.0) and "10000000" in e.note


def test_quick_or_changed_suite_is_not_judged():
    for doc in (_doc(quick=True, suite_pinned=False, suite_runs=60),
                _doc(suite_pinned_differences=["1 pinned runs not in today's list: ..."])):
        st = _status(doc)
        assert st["c"] == ["n/a"] and st["d"] == ["n/a", "n/a"]
        assert st["a"] == ["PASS", "PASS"] and st["b"] == ["PASS"]


def test_missing_figures_are_not_applicable_with_the_reason():
    doc = _doc()
    for key in ("reference_map_mujoco_step_s", "long_run_s", "rss_bytes"):
        doc.pop(key)
    doc.update(reference_map_mujoco_note="mujoco unavailable: EngineMissing", long_run_note="mujoco not installed",
               rss_note="mujoco not installed", suite_parallel_s=None, suite_serial_s=None,
               suite_note="suite not measured (--no-suite)")
    rows = bench.checks(doc)
    assert all(c.status == "n/a" for c in rows if c.key in "abcde"), [(c.key, c.status) for c in rows]
    assert "mujoco unavailable" in rows[0].note
    assert "--no-suite" in next(c for c in rows if c.key == "c").note
    text = bench.format_text(doc)  # renders without the missing figures
    assert "n/a" in text and "mujoco not installed" in text


def test_text_table_lists_every_check_with_its_status():
    doc = _doc(long_run_extra_s=1.5)
    doc["checks"] = [dict(vars(c), status=c.status) for c in bench.checks(doc)]
    text = bench.format_text(doc)
    table = text.split("\n\n")[1].splitlines()
    assert len(table) == 2 + len(doc["checks"])
    b_row = next(line for line in table if line.lstrip().startswith("b "))
    assert "MISS" in b_row and "1.50 s" in b_row and "<= 1.3 s" in b_row
    assert "1 MISS" in text


# --- child processes --------------------------------------------------------------------------------

def test_run_child_reports_exit_code_and_wall_time():
    child = bench.run_child([sys.executable, "-c", "import sys, time; time.sleep(0.2); sys.exit(3)"])
    assert child.returncode == 3
    assert 0.2 <= child.wall_s < 30


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


# --- the command line ---------------------------------------------------------------------------------

@pytest.mark.parametrize("option", [["--repeats", "0"], ["--rss-steps", "-1"], ["--suite-repeats", "0"]])
def test_bad_numbers_are_one_line_input_errors(capsys, option):
    with pytest.raises(SystemExit) as e:
        main(["bench", "--quick", *option])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and option[0] in err


def test_quick_and_full_configurations():
    quick, full = bench.BenchConfig.make(quick=True), bench.BenchConfig.make(quick=False)
    assert quick.suite_cases == QUICK_SUITE_CASES and full.suite_cases == tuple(PINNED_SUITE_CASES)
    assert (quick.rss_steps, full.rss_steps) == (bench.QUICK_RSS_STEPS, bench.DEFAULT_RSS_STEPS)
    assert (quick.suite_repeats, full.suite_repeats) == (1, 3) and full.repeats == 7
    assert bench.BenchConfig.make(quick=False, rss_steps=0, repeats=2, suite_repeats=1) == \
        bench.BenchConfig(**{**vars(full), "rss_steps": 0, "repeats": 2, "suite_repeats": 1})


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """(stdout, the --out file's document) of one ``freebody bench --quick --json`` run."""
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["bench", "--quick", "--json", "--quiet", "--repeats", "1", "--out", str(out)])
    assert code == 0
    return buf.getvalue(), json.loads(out.read_text())


@pytest.mark.slow
def test_quick_bench_reports_every_figure(quick_run):
    doc = quick_run[1]
    assert doc["schema_version"] == SCHEMA_VERSION == 3
    assert doc["quick"] is True
    # the checks: a (2), b, c, d (2), e, one per measured engine; none failed to measure
    keys = [c["key"] for c in doc["checks"]]
    assert keys[:7] == ["a", "a", "b", "c", "d", "d", "e"]
    assert keys.count("1") == len(doc["overhead_ratio"]) and len(keys) == 7 + keys.count("1")
    for c in doc["checks"]:
        assert c["status"] in ("PASS", "MISS", "n/a")
        assert c["status"] == {True: "PASS", False: "MISS", None: "n/a"}[c["passed"]]
    if is_available("mujoco"):
        for c in doc["checks"]:
            if c["key"] in "ab":
                assert _positive(c["value"]) or c["key"] == "b", c  # b may be negative: noise
                assert c["status"] != "n/a", c
    # the quick suite is not the pinned one: measured, not judged
    assert [c["status"] for c in doc["checks"] if c["key"] in "cd"] == ["n/a"] * 3
    assert doc["suite_runs"] == 60 and doc["suite_pinned_differences"] == []
    for key in ("suite_serial_s", "suite_parallel_s", "suite_trajectories_bytes",
                "suite_report_html_bytes"):
        assert _positive(doc[key]), key
    # a: every reference map, b: the long run, e: the RSS run
    assert set(doc["reference_map_step_s"]) == set(INTEGRATORS)
    assert all(_positive(s) for s in doc["reference_map_step_s"].values())
    if is_available("mujoco"):
        assert doc["long_run_steps"] == 50000 and doc["short_run_steps"] == 10
        for key in ("long_run_s", "short_run_s", "long_run_bare_s", "rss_bytes", "short_run_rss_bytes"):
            assert _positive(doc[key]), key
        assert doc["rss_steps"] == bench.QUICK_RSS_STEPS
    # the figures of schema 1 are still there
    assert set(doc["engines"]) == set(engine_names())
    for engine in engine_names():
        assert (engine in doc["overhead_ratio"]) != (engine in doc["skipped"])
        if engine in doc["overhead_ratio"]:
            for key in ("bare_step_s", "freebody_step_s"):
                assert _positive(doc["engine_step_s"][engine][key])
    if "mujoco" in doc["overhead_ratio"]:
        for name in ENGINE_EQUIVALENT_MAPS:
            assert _positive(doc["reference_map_speedup_vs_mujoco"][name])
    # schema 3: the batched part of schema 2 is gone
    assert not {"reference_body_step_s", "mujoco_body_step_s", "batch_steps"} & set(doc)


@pytest.mark.slow
def test_bench_json_prints_one_object_and_the_text_summary_renders_it(quick_run):
    stdout, doc = quick_run
    assert json.loads(stdout) == doc
    text = bench.format_text(doc)
    for part in ("reference maps, one body", "suite wall time", "peak RSS", "engine loop overhead"):
        assert part in text
    assert "batched" not in text
    assert text.count("PASS") + text.count("MISS") + text.count("n/a") >= len(doc["checks"])
