"""Parallel, isolated runs: a crash or a hang costs one run only, and the numbers do not depend on
where the runs execute (in this process, in worker processes, on a dask cluster).

The crashing engine is real: ``tests/fake_engines/crashing_adapter.py`` segfaults or aborts in a
real worker process."""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import FAST_ENGINES
from fake_engines.crashing_adapter import REGISTRY_ENTRY
from freebody.adapters.base import ENGINES, is_available
from freebody.input.casefile import load_case
from freebody.cli import main
from freebody.run.executor import plan
from freebody.reference_impl.integrators import simulate as reference_simulate
from freebody.results.document import SAVED_SAMPLES, load_trajectory
from freebody.reference_impl.rotations import geodesic_angle
from freebody.run import SCHEME_CANDIDATES, expand
from freebody.run.sharedcache import SHAREABLE_REFERENCES
from freebody.run.suite import run_specs

# Keys of a run that measure time, not physics: the only ones allowed to differ between executors.
TIMING_KEYS = ("wall_time_s", "compile_time_s")
# The engines compared serial vs parallel: every registered engine but the slow ones (mjx spends
# ~10 s per run compiling); a missing one is a skipped run on both sides.
ENGINES_COMPARED = FAST_ENGINES
TIMEOUT_S = 3.0  # per-run limit of the hang test: far below crashing_adapter.SLEEP_S, above a small run judged
# in a freshly started worker on a loaded machine (1 s was missed under pytest -n 2: maps loaded, judged)
HANG_TEST_BUDGET_S = 30.0  # the hang test must finish well before the sleeping run would


@pytest.fixture
def crasher(monkeypatch):
    monkeypatch.setitem(ENGINES, "crasher", REGISTRY_ENTRY)
    return "crasher"


def _specs(cases, engines, integrators=None, dt=0.01, duration=0.1):
    return expand([load_case(c) for c in cases], engines, integrators, [dt], duration)


def _comparable(doc: dict) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in TIMING_KEYS} for r in doc["runs"]]


def _by_integrator(doc: dict, engine: str) -> dict[str, dict]:
    return {r["integrator"]: r for r in doc["runs"] if r["engine"] == engine}


def test_a_segfault_or_abort_in_one_engine_fails_that_run_only(crasher, tmp_path):
    specs = _specs(["dzhanibekov"], ["reference", crasher],
                   ["reference:rk4", "crasher:segfault", "crasher:abort", "crasher:semi-implicit-explicit-gyro"])
    doc, _ = run_specs(specs, tmp_path, ["reference", crasher], progress=False, jobs=2)
    runs = _by_integrator(doc, crasher)
    assert runs["segfault"]["status"] == "failed" and "SIGSEGV" in runs["segfault"]["message"]
    assert runs["abort"]["status"] == "failed" and "SIGABRT" in runs["abort"]["message"]
    assert runs["semi-implicit-explicit-gyro"]["status"] == "ok"
    assert _by_integrator(doc, "reference")["rk4"]["status"] == "ok"
    assert [r["integrator"] for r in doc["runs"]] == [s.integrator for s in specs]  # spec order
    assert json.loads((tmp_path / "results.json").read_text())["incomplete"] is False


def test_a_run_past_the_timeout_is_killed_and_the_others_finish(crasher, tmp_path):
    specs = _specs(["dzhanibekov"], [crasher, "reference"], ["crasher:sleep", "reference:rk4",
                                                             "crasher:semi-implicit-explicit-gyro"])
    t0 = time.perf_counter()
    doc, _ = run_specs(specs, tmp_path, [crasher, "reference"], progress=False, jobs=1, timeout=TIMEOUT_S)
    assert time.perf_counter() - t0 < HANG_TEST_BUDGET_S
    slept = _by_integrator(doc, crasher)["sleep"]
    assert slept["status"] == "failed" and f"timed out after {TIMEOUT_S:g} s" in slept["message"]
    assert slept["wall_time_s"] >= TIMEOUT_S
    for run in (_by_integrator(doc, crasher)["semi-implicit-explicit-gyro"], _by_integrator(doc, "reference")["rk4"]):
        assert run["status"] == "ok", (run["engine"], run["integrator"], run["message"])


def test_serial_and_parallel_results_are_identical(tmp_path):
    # a torque-free case (closed-form truth) and a loaded one (numerical truth), two time steps
    specs = expand([load_case("dzhanibekov"), load_case("offset_push")], ENGINES_COMPARED, None,
                   [0.01, 0.02], 0.2)
    docs = {}
    for jobs in (1, 2):  # 1: in this process (--no-isolation); 2: two worker processes
        docs[jobs], _ = run_specs(specs, tmp_path / str(jobs), ENGINES_COMPARED, progress=False,
                                  jobs=jobs, save_every=3, isolate=jobs != 1)
    assert _comparable(docs[1]) == _comparable(docs[2])
    assert docs[1]["engines"] == docs[2]["engines"]
    saved = [r["trajectory"] for r in docs[1]["runs"] if r["trajectory"]]
    assert len(saved) > len(specs) // 2
    for rel in saved:
        (a, ta), (b, tb) = (load_trajectory(tmp_path / str(j) / rel) for j in (1, 2))
        for f in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
            np.testing.assert_array_equal(getattr(ta, f), getattr(tb, f))


def test_save_every_thins_the_file_but_not_the_metrics(tmp_path):
    specs = _specs(["dzhanibekov"], ["reference"], ["rk4"], dt=0.01, duration=1.0)
    docs = {k: run_specs(specs, tmp_path / str(k), ["reference"], progress=False, save_every=k)[0]
            for k in (1, 7)}
    assert docs[1]["runs"][0]["metrics"] == docs[7]["runs"][0]["metrics"]
    full, _ = load_trajectory(tmp_path / "1" / docs[1]["runs"][0]["trajectory"])
    thin, truth = load_trajectory(tmp_path / "7" / docs[7]["runs"][0]["trajectory"])
    with np.load(tmp_path / "7" / docs[7]["runs"][0]["trajectory"]) as z:
        index = z["sample_index"]
    # samples 0, 7, ..., 98, the last (100), and those of the maximum errors
    assert len(full) == 101 and len(thin) == len(truth) == len(index) < 101
    assert set(range(0, 101, 7)) | {100} <= set(index.tolist())
    np.testing.assert_array_equal(thin.quaternion_wxyz, full.quaternion_wxyz[index])
    np.testing.assert_array_equal(thin.t, full.t[index])
    # the file shows the orientation error the metrics report, at its sample
    ori = geodesic_angle(truth.quaternion_wxyz, thin.quaternion_wxyz)
    assert np.max(ori) == docs[7]["runs"][0]["metrics"]["orientation_error_max_rad"]


def test_auto_save_keeps_about_saved_samples_and_every_maximum(tmp_path):
    """The default (--save-every auto) bounds a long run's file; metrics still use every step."""
    specs = _specs(["dzhanibekov"], ["reference"], ["euler-quat"], dt=0.001, duration=5.0)
    docs = {k: run_specs(specs, tmp_path / str(k), ["reference"], progress=False, save_every=k)[0]
            for k in (1, None)}
    assert docs[1]["runs"][0]["metrics"] == docs[None]["runs"][0]["metrics"]
    thin, truth = load_trajectory(tmp_path / "None" / docs[None]["runs"][0]["trajectory"])
    full, _ = load_trajectory(tmp_path / "1" / docs[1]["runs"][0]["trajectory"])
    assert len(full) == 5001 and SAVED_SAMPLES // 2 < len(thin) <= SAVED_SAMPLES + 12  # + the maxima
    m = docs[None]["runs"][0]["metrics"]
    assert np.max(geodesic_angle(truth.quaternion_wxyz, thin.quaternion_wxyz)) == m["orientation_error_max_rad"]
    assert thin.t[-1] == full.t[-1]


def test_reference_engine_runs_stand_in_for_the_identification_maps():
    """GroupTruthCache reuses a reference engine run as the map identify() compares with: valid only
    while the reference adapter returns exactly reference_impl's simulate."""
    from freebody.adapters.reference import ReferenceAdapter

    pb = load_case("offset_push")
    for name in SHAREABLE_REFERENCES:
        adapter = ReferenceAdapter(pb, 0.01, name)
        a, b = adapter.simulate(30), reference_simulate(pb, name, 0.01, 30)
        for f in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_plan_shares_truths_within_a_group_and_orders_groups_largest_first():
    specs = expand([load_case("dzhanibekov")], ["reference", "mujoco"], None, [0.01, 0.001], 0.1)
    tasks = plan(specs)
    assert sorted(t.index for t in tasks) == list(range(len(specs)))
    assert tasks[0].run.spec.dt == 0.001  # 10x the steps: first
    for group in {t.group for t in tasks}:
        members = [t for t in tasks if t.group == group]
        first = members[0]
        assert first.run.spec.engine == "reference" and not first.deps and first.truth_of is None
        assert all(t.truth_of == first.index for t in members[1:])
        producers = {t.run.spec.integrator: t.index for t in members if t.run.spec.engine == "reference"}
        for t in members:
            if t.run.spec.engine == "mujoco":
                assert {producers[n] for n in SHAREABLE_REFERENCES} <= t.deps


def test_plan_never_makes_the_truth_wait_for_its_own_group():
    # the engine listed before the reference engine: the truth still comes from a reference run
    specs = expand([load_case("dzhanibekov")], ["mujoco", "reference"], None, [0.01], 0.1)
    first = plan(specs)[0]
    assert first.run.spec.engine == "reference" and not first.deps and first.truth_of is None


@pytest.mark.parametrize("argv, words", [
    (["--jobs", "0"], ["--jobs", ">= 1"]),
    (["--save-every", "0"], ["--save-every", ">= 1"]),
    (["--timeout", "-1"], ["--timeout", "> 0"]),
    (["--executor", "spark"], ["--executor", "invalid choice"]),
    (["--executor", "dask"], ["--scheduler", "missing"]),
    (["--scheduler", "tcp://127.0.0.1:1"], ["--scheduler", "--executor dask"]),
])
def test_bad_parallel_options_are_one_line_exit_2(tmp_path, capsys, argv, words):
    try:
        code = main(["run", "quiz", "--engine", "reference", "--out", str(tmp_path), "--quiet", *argv])
    except SystemExit as e:  # argparse reports its own errors
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err


# --- dask ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def dask_scheduler():
    distributed = pytest.importorskip("distributed", reason="dask.distributed not installed "
                                                            "(pip install 'freebody[dask]')")
    # threads in this process, loopback only; the runs themselves go to freebody worker processes
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp",
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        yield cluster.scheduler_address


def test_dask_gives_the_local_results_and_isolates_a_crash(crasher, dask_scheduler, tmp_path):
    engines = ["reference", crasher]
    specs = (expand([load_case("dzhanibekov"), load_case("offset_push")], ["reference"], ["rk4", "euler-quat"],
                    [0.01], 0.2)
             + _specs(["dzhanibekov"], [crasher], ["crasher:segfault", "crasher:semi-implicit-explicit-gyro"],
                      duration=0.2))
    local, _ = run_specs(specs, tmp_path / "local", engines, progress=False, jobs=2)
    remote, _ = run_specs(specs, tmp_path / "dask", engines, progress=False, executor="dask",
                          scheduler=dask_scheduler, save_every=2)
    crashed = [r for r in remote["runs"] if r["integrator"] == "segfault"]
    assert len(crashed) == 1 and crashed[0]["status"] == "failed" and "SIGSEGV" in crashed[0]["message"]
    assert _comparable(local) == _comparable(remote)
    rel = remote["runs"][0]["trajectory"]
    (full, _), (thin, _) = (load_trajectory(tmp_path / d / rel) for d in ("local", "dask"))
    with np.load(tmp_path / "dask" / rel) as z:
        index = z["sample_index"]
    assert set(range(0, len(full), 2)) <= set(index.tolist())
    np.testing.assert_array_equal(thin.position, full.position[index])


def test_dask_unreachable_scheduler_is_bad_input(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed", reason="dask.distributed not installed (pip install 'freebody[dask]')")
    from freebody.run import dask_executor as dask_executor

    monkeypatch.setattr(dask_executor, "CONNECT_TIMEOUT_S", 1)  # nothing listens there: fail fast
    code = main(["run", "quiz", "--engine", "reference", "--out", str(tmp_path), "--quiet",
                 "--executor", "dask", "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 2 and "--scheduler" in err and "Traceback" not in err
