"""``freebody sweep`` on the executor of ``freebody run``: isolated worker processes (``--jobs``),
truths and reference maps shared per body as ``run`` shares them per case, numbers that do not
depend on the number of workers, and Ctrl-C as in ``run``."""
from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from conftest import FAST_ENGINES
from fake_engines.crashing_adapter import REGISTRY_ENTRY as CRASHER_ENTRY
from freebody.adapters import base
from freebody.cli import main
from freebody.run import expand, judge
from freebody.errors import InputError
from freebody.tools.sweep import SweepSettings, load_sweep, random_bodies, sweep
from test_interrupt import (EXIT_BUDGET_S, WITH_CRASHER, _children, _sigint_as_at_a_terminal,
                            _wait_for_finished_runs, _wait_gone)

SMALL = SweepSettings(seed=3, count=4, duration=0.2, dts=(0.01,))
# Keys of a run that measure time, not physics: the only ones the number of workers may change.
TIMING_KEYS = ("wall_time_s", "compile_time_s")


@pytest.fixture
def crasher(monkeypatch):
    monkeypatch.setitem(base.ENGINES, "crasher", CRASHER_ENTRY)
    return "crasher"


def _physics(doc: dict) -> dict:
    doc = {k: v for k, v in doc.items() if k not in ("wall_time_s", "created")}
    doc["runs"] = [{k: v for k, v in r.items() if k not in TIMING_KEYS} for r in doc["runs"]]
    return doc


def test_jobs_1_and_2_and_in_process_give_identical_sweeps(tmp_path, capsys):
    """sweep.json, sweep.txt (but for the wall time) and the worst-case files do not depend on
    --jobs; in spec order, as in this process (the workers finish runs in another order)."""
    common = ["sweep", "--seed", "3", "--count", "4", "--duration", "0.2", "--quiet"]
    for e in FAST_ENGINES:
        common += ["--engine", e]
    outs = {}
    for jobs in (1, 2):
        outs[jobs] = tmp_path / f"j{jobs}"
        assert main([*common, "--jobs", str(jobs), "--out", str(outs[jobs])]) in (0, 1)
    capsys.readouterr()
    docs = {j: json.loads((d / "sweep.json").read_text()) for j, d in outs.items()}
    assert docs[1]["runs"] and {r["engine"] for r in docs[1]["runs"]} == set(FAST_ENGINES)
    assert _physics(docs[1]) == _physics(docs[2])
    alone = sweep(SMALL, list(FAST_ENGINES), progress=False, isolate=False).document
    assert _physics(alone)["runs"] == _physics(docs[1])["runs"]
    assert _physics(alone)["summary"] == _physics(docs[1])["summary"]
    texts = {j: (d / "sweep.txt").read_text().splitlines() for j, d in outs.items()}
    assert texts[1][2:] == [line.replace(str(outs[2]), str(outs[1])) for line in texts[2][2:]]
    worst = {j: sorted(p.name for p in (d / "worst").iterdir()) for j, d in outs.items()}
    assert worst[1] == worst[2] and worst[1]
    for name in worst[1]:
        assert (outs[1] / "worst" / name).read_text() == (outs[2] / "worst" / name).read_text()


def test_a_segfault_in_one_engine_fails_its_runs_only(crasher):
    """Every run is isolated in a worker process: a crashing engine costs its runs, not the sweep."""
    out = sweep(SMALL, ["reference", crasher], ["reference:rk4", "crasher:segfault",
                                                "crasher:semi-implicit-explicit-gyro"],
                progress=False, jobs=2)
    runs = out.document["runs"]
    assert len(runs) == 3 * SMALL.count
    for r in runs:
        if r["integrator"] == "segfault":
            assert r["status"] == "failed" and "SIGSEGV" in r["message"], r
        else:
            assert r["status"] == "ok", r
    assert out.document["summary"]["crasher/segfault dt=0.01"]["status"]["failed"] == SMALL.count


def test_each_body_computes_its_truth_once_and_reuses_the_reference_runs(crasher, monkeypatch):
    """As in ``freebody run``: one truth per body and dt, and the reference engine's runs serve as
    the maps that identification compares the other engines' runs with: no map that the reference
    engine ran is integrated a second time, and no other map twice."""
    truths, maps = [], []

    def counted(real, calls, key):
        def wrapper(*args, **kwargs):
            calls.append(key(*args))
            return real(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(judge, "truth_trajectory",
                        counted(judge.truth_trajectory, truths, lambda pb, *_: pb.name))
    monkeypatch.setattr(judge, "run_map",  # a map's run from the case's own start (perturbed: map_orientations)
                        counted(judge.run_map, maps, lambda start, integrator, *_: (start.problem.name, integrator)))
    engines, integrators = ["reference", crasher], ["crasher:semi-implicit-explicit-gyro"]
    out = sweep(SMALL, engines, integrators, progress=False, isolate=False)
    runs = out.document["runs"]
    assert len(runs) == len(expand([b.problem for b in random_bodies(SMALL)], engines, integrators, None, None))
    assert all(r["status"] == "ok" for r in runs), [r["message"] for r in runs]
    identified = [r["matches_reference"]["closest"] for r in runs if r["engine"] == crasher]
    assert identified == ["semi-implicit-explicit-gyro"] * SMALL.count
    assert sorted(truths) == sorted(b["case"] for b in out.document["bodies"])
    ran = {(r["case"], r["integrator"]) for r in runs if r["engine"] == "reference"}
    assert ran and not ran & set(maps), sorted(ran & set(maps))
    assert maps and len(maps) == len(set(maps)), maps  # the engine maps were run, each once


def test_progress_counts_runs_on_stderr(tmp_path, capsys):
    assert main(["sweep", "--seed", "1", "--count", "2", "--engine", "reference", "--integrator", "rk4",
                 "--integrator", "euler-quat", "--duration", "0.05", "--jobs", "1", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err.splitlines()
    progress = [line for line in err if line.startswith("[")]
    assert progress and progress[-1].startswith("[4/4 runs]") and "4 ok" in progress[-1], err


INTERRUPTED_SWEEP = ["sweep", "--count", "2", "--engine", "reference", "--engine", "crasher", "--integrator",
                     "reference:euler-quat", "--integrator", "crasher:sleep", "--dt", "5", "--duration", "1000",
                     "--jobs", "2"]


def _sweep_files(out) -> dict:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


@pytest.mark.skipif(not hasattr(signal, "SIGTERM"), reason="needs signals")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_keeps_the_finished_bodies_and_the_previous_complete_sweep(tmp_path, signum, capsys):
    """Ctrl-C or SIGTERM with runs finished: the workers are stopped, exit 128 + the signal; the
    finished runs are written as a sweep marked incomplete in OUT/interrupted/, and the complete
    sweep already in OUT is left byte for byte.  A complete sweep then removes the interrupted one."""
    out = tmp_path / "out"
    assert main(["sweep", "--count", "1", "--engine", "reference", "--integrator", "euler-quat",
                 "--duration", "0.05", "--quiet", "--out", str(out)]) == 0
    before = _sweep_files(out)
    proc = subprocess.Popen([sys.executable, "-c", WITH_CRASHER, *INTERRUPTED_SWEEP, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_sigint_as_at_a_terminal)
    try:
        _wait_for_finished_runs(proc, 2)  # the two reference runs; the crasher's sleep for ever
        workers = _children(proc.pid)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=EXIT_BUDGET_S)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err, err
    assert f"2 of 4 runs finished; kept in {out / 'interrupted' / 'sweep.json'} (marked incomplete)" in err, err
    assert _sweep_files(out) == {**before, **{k: v for k, v in _sweep_files(out).items()
                                              if k.startswith("interrupted/")}}  # OUT's own files unchanged
    doc = load_sweep(out / "interrupted")
    assert doc["incomplete"] is True and doc["schema_version"] == 2
    assert [(r["case"], r["engine"], r["status"]) for r in doc["runs"]] == [
        ("sweep_s0_0000", "reference", "ok"), ("sweep_s0_0001", "reference", "ok")]
    assert [b["case"] for b in doc["bodies"]] == ["sweep_s0_0000", "sweep_s0_0001"]
    assert "INCOMPLETE" in (out / "interrupted" / "sweep.txt").read_text()
    assert workers and _wait_gone(workers, EXIT_BUDGET_S) == [], "worker processes left running"
    (out / "interrupted" / "mine.txt").write_text("a user's file")
    assert main(["sweep", "--count", "1", "--engine", "reference", "--integrator", "euler-quat",
                 "--duration", "0.05", "--quiet", "--out", str(out)]) == 0
    assert sorted(p.relative_to(out).as_posix() for p in (out / "interrupted").rglob("*")) == ["interrupted/mine.txt"]


def test_a_schema_1_sweep_reads_as_complete(tmp_path):
    out = tmp_path / "out"
    sweep(SweepSettings(seed=1, count=1, duration=0.05), ["reference"], ["euler-quat"], out, progress=False)
    doc = json.loads((out / "sweep.json").read_text())
    del doc["incomplete"]
    doc["schema_version"] = 1
    (out / "sweep.json").write_text(json.dumps(doc))
    assert load_sweep(out)["incomplete"] is False
    doc["schema_version"] = 3
    (out / "sweep.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="schema_version: expected 2"):
        load_sweep(out)
