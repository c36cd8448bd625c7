"""Nothing lost, nothing inconsistent in ``--out`` (issue 14, items 1-8b): unique trajectory file
names, one writer per output folder (a lock that dies with its process), an atomic publish (kills
at each point of it through the ``FREEBODY_FAULT`` hook), freebody deleting only what it wrote,
interrupts (SIGINT, SIGTERM, SIGHUP) that never destroy a complete result, baselines never
written over special files, engine output capped in length, duplicate runs merged or refused.

Real ``freebody`` processes where it matters: concurrent writers, kills, signals.  The slow run
of those tests is the ``sleep`` integrator of the crashing test engine (``fake_engines``), which
never finishes on its own, so "no run finished yet" is certain, whatever the machine's speed.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from freebody.cli import main
from freebody.errors import InputError
from freebody.input.casefile import load_case
from freebody.results.document import load_trajectory, trajectory_filename, write_trajectory
from freebody.results.io import is_temporary
from freebody.results.outdir import FAULT_ENV, FAULT_POINTS, LOCK, OWNED, PREVIOUS, output_lock
from freebody.run import expand
from freebody.run.suite import run_specs

from case_text import case_text  # noqa: E402

TESTS = Path(__file__).resolve().parent
pytestmark = pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")

# quick runs: quiz is 2 steps per run, in the freebody process (no worker to start)
QUICK = ["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--no-report", "--quiet", "--no-isolation"]
# a freebody process with the crashing test engine registered (its ``sleep`` runs never finish)
WITH_CRASHER = f"""
import sys
sys.path.insert(0, {str(TESTS)!r})
from fake_engines.crashing_adapter import REGISTRY_ENTRY
from freebody.adapters.base import ENGINES
ENGINES["crasher"] = REGISTRY_ENTRY
from freebody.cli import main
sys.exit(main(sys.argv[1:]))
"""
# reference rk4 finishes at once; crasher sleep runs until the signal
SLOW = ["run", "quiz", "--engine", "reference", "--engine", "crasher", "--integrator", "reference:rk4",
        "--integrator", "crasher:sleep", "--dt", "0.05", "--no-report"]
SLEEP_ONLY = ["run", "quiz", "--engine", "crasher", "--integrator", "crasher:sleep", "--dt", "0.05", "--no-report"]
START_BUDGET_S = 60.0  # for a freebody process to start and finish its first run
EXIT_BUDGET_S = 30.0  # to stop after a signal
WORKER_EXIT_BUDGET_S = 10.0



# --- helpers ------------------------------------------------------------------------------------

def _freebody(*args: str, env: dict | None = None, timeout: float = START_BUDGET_S) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "freebody", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


def _start_with_crasher(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", WITH_CRASHER, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_sigint_as_at_a_terminal)


def _sigint_as_at_a_terminal() -> None:
    """SIGINT at its default in the child: a shell's background job (``cmd &``, e.g. a CI script run
    that way) inherits SIGINT ignored, and Python then installs no KeyboardInterrupt handler."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _consistent(out: Path) -> dict:
    """results.json, after checking that every trajectory file it names exists and loads."""
    doc = json.loads((out / "results.json").read_text())
    for r in doc["runs"]:
        if r.get("trajectory"):
            load_trajectory(out / r["trajectory"])
    return doc


def _temporaries(out: Path) -> list[Path]:
    return [p for p in out.rglob("*") if is_temporary(p.name)]


def _folders(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "trajectories").iterdir() if p.is_dir())


def _wait_for(predicate, proc: subprocess.Popen, what: str) -> None:
    t0 = time.monotonic()
    while not predicate():
        assert proc.poll() is None, f"freebody exited ({proc.returncode}) before {what}: {proc.stderr.read()}"
        assert time.monotonic() - t0 < START_BUDGET_S, f"no {what} after {START_BUDGET_S} s"
        time.sleep(0.05)


def _wait_for_finished_run(proc: subprocess.Popen) -> None:
    """Read stderr up to the first progress line (one per finished run when stderr is no terminal)."""
    t0 = time.monotonic()
    while True:
        line = proc.stderr.readline()
        assert line, f"freebody exited early ({proc.wait()})"
        if line.startswith("["):
            return
        assert time.monotonic() - t0 < START_BUDGET_S


def _children(pid: int) -> list[int]:
    return [int(c) for task in Path(f"/proc/{pid}/task").iterdir() for c in (task / "children").read_text().split()]


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _one_line_error(err: str, *words: str) -> None:
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)


@pytest.fixture(scope="module")
def complete(tmp_path_factory):
    """An output folder holding a complete result, run once (tests work on copies)."""
    out = tmp_path_factory.mktemp("complete") / "out"
    assert main(QUICK + ["--dt", "0.01", "--out", str(out)]) == 0
    return out


@pytest.fixture
def previous(complete, tmp_path):
    """A copy of ``complete``: (folder, results.json bytes, {path: file bytes})."""
    out = tmp_path / "out"
    shutil.copytree(complete, out, symlinks=True)
    before = (out / "results.json").read_bytes()
    files = {r["trajectory"]: (out / r["trajectory"]).read_bytes() for r in json.loads(before)["runs"]}
    assert files
    return out, before, files


def _unchanged(out: Path, before: bytes, files: dict, name: str = "results.json") -> None:
    assert (out / name).read_bytes() == before
    for rel, data in files.items():
        assert (out / rel).read_bytes() == data, rel


# --- 1. trajectory file names -------------------------------------------------------------------

RUN = {"case": "x", "engine": "reference", "integrator": "rk4", "precision": "float64", "dt": 0.01, "steps": 100}


@pytest.mark.parametrize("a, b", [
    ({"case": "x y"}, {"case": "x_y"}),
    ({"case": "a/b"}, {"case": "a_b"}),
    ({"dt": 0.01}, {"dt": 0.0100000001}),
    ({"integrator": "Euler"}, {"integrator": "euler"}),
    ({"precision": "float32"}, {"precision": "float64"}),
    ({"steps": 100}, {"steps": 101}),
], ids=["space-vs-underscore", "slash-vs-underscore", "dt-beyond-6-digits", "case-of-integrator",
        "precision", "steps"])
def test_runs_that_differ_get_different_file_names(a, b):
    assert trajectory_filename({**RUN, **a}) != trajectory_filename({**RUN, **b})
    assert trajectory_filename({**RUN, **a}) == trajectory_filename(dict({**RUN, **a}))  # deterministic


@pytest.mark.parametrize("case", ["x" * 300, "é" * 200 + "/../" + "\x1b[31m", ".hidden", "a" * 220])
def test_trajectory_file_names_are_short_portable_and_visible(case):
    name = trajectory_filename({**RUN, "case": case})
    assert len(name.encode()) <= 160  # far below NAME_MAX (255) with a temporary file's affixes
    assert all(c.isascii() and (c.isalnum() or c in "._-") for c in name), name
    assert not name.startswith(".") and name.endswith(".npz") and not is_temporary(name)


def test_runs_that_used_to_collide_each_keep_their_own_file(tmp_path):
    # cases "x y" and "x_y" (another spin), dt 0.01 and 0.0100000001, a 220-character name
    base = load_case("dzhanibekov")
    problems = [dataclasses.replace(base, name="x y"),
                dataclasses.replace(base, name="x_y", initial=dataclasses.replace(
                    base.initial, angular_velocity=np.array([0.5, 5.0, 0.0]))),
                dataclasses.replace(base, name="n" * 220)]
    specs = expand(problems, ["reference"], ["rk4"], [0.01, 0.0100000001], 0.05)
    doc, _ = run_specs(specs, tmp_path, ["reference"], progress=False, jobs=1)
    paths = [r["trajectory"] for r in doc["runs"]]
    assert len(paths) == 6 and len(set(paths)) == 6
    for r in doc["runs"]:  # each file holds its own run
        tr, _ = load_trajectory(tmp_path / r["trajectory"])
        np.testing.assert_array_equal(tr.angular_velocity[-1], r["final_state"]["angular_velocity"])
        assert tr.t[1] == pytest.approx(r["dt"], rel=1e-15)


# --- 2. one writer per output folder --------------------------------------------------------------

def test_a_second_writer_is_refused_and_a_killed_writer_leaves_no_lock(tmp_path):
    out = tmp_path / "out"
    first = _start_with_crasher(*SLEEP_ONLY, "--out", str(out), "--jobs", "1")
    try:
        _wait_for(lambda: (out / "trajectories" / "1").is_dir(), first, "its trajectory folder")
        second = _freebody(*QUICK, "--dt", "0.01", "--out", str(out))
        assert second.returncode == 2
        _one_line_error(second.stderr, str(out), "another freebody process", f"pid {first.pid}")
        assert not (out / "results.json").exists()  # the refused process wrote nothing
        first.kill()  # SIGKILL: no chance to release anything
        first.wait(EXIT_BUDGET_S)
    finally:
        first.kill()
    third = _freebody(*QUICK, "--dt", "0.01", "--out", str(out))  # at once: the kernel dropped the lock
    assert third.returncode == 0, third.stderr
    assert len(_consistent(out)["runs"]) == 1
    assert _folders(out) == ["2"]  # the killed writer's folder is gone


def test_the_lock_is_reentrant_in_one_process_and_report_respects_it(previous):
    out, before, files = previous
    with output_lock(out):
        with output_lock(out):  # run_specs inside freebody run: the same process
            pass
        code = subprocess.run([sys.executable, "-m", "freebody", "report", str(out)],
                              capture_output=True, text=True, timeout=START_BUDGET_S)
    assert code.returncode == 2
    _one_line_error(code.stderr, "another freebody process", f"pid {os.getpid()}")
    assert (out / LOCK).is_file()
    assert main(["report", str(out), "--markdown-only"]) == 0  # released


# --- 3. the publish is one atomic step --------------------------------------------------------------

@pytest.mark.parametrize("point", FAULT_POINTS)
def test_a_kill_at_each_point_of_the_publish_leaves_results_consistent_with_their_files(previous, point):
    out, before, files = previous
    killed = _freebody(*QUICK, "--dt", "0.02", "--out", str(out), env={FAULT_ENV: point})
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    doc = _consistent(out)
    if point == "after-publish":
        assert [r["dt"] for r in doc["runs"]] == [0.02]  # the new results, with their files
    else:
        _unchanged(out, before, files)  # the previous results, with theirs
    strays = _temporaries(out)
    assert bool(strays) == (point == "before-publish"), strays  # the complete, unrenamed results.json
    # the next run cleans up: no temporary file, no folder of the killed run, only its own files
    assert main(QUICK + ["--dt", "0.03", "--out", str(out)]) == 0
    doc = _consistent(out)
    assert [r["dt"] for r in doc["runs"]] == [0.03]
    assert _temporaries(out) == []
    assert _folders(out) == ["3"]
    assert json.loads((out / OWNED).read_text())["owned"] == ["trajectories/3"]


def test_report_and_compare_read_the_flat_layout_of_earlier_releases(previous, capsys):
    out, _, _ = previous
    doc = json.loads((out / "results.json").read_text())
    for r in doc["runs"]:  # as written before per-invocation folders: trajectories/<file>.npz, format 1
        flat = "trajectories/" + Path(r["trajectory"]).name
        with np.load(out / r["trajectory"]) as z:
            index = z["sample_index"]
        write_trajectory(out / flat, *load_trajectory(out / r["trajectory"]), index, trajectory_format=1)
        r["trajectory"] = flat
    shutil.rmtree(out / "trajectories" / "1")
    (out / OWNED).unlink()
    (out / "results.json").write_text(json.dumps(doc))
    (out / "trajectories" / "mine.npz").write_bytes(b"a user's file")
    assert main(["report", str(out)]) == 0
    assert "unreadable" not in (out / "report.md").read_text() + (out / "report.html").read_text()
    assert main(["compare", str(out), str(out)]) == 0
    capsys.readouterr()
    # a new run over it removes the flat files its results.json named, and nothing else
    assert main(QUICK + ["--dt", "0.02", "--out", str(out)]) == 0
    _consistent(out)
    assert sorted(p.name for p in (out / "trajectories").iterdir()) == ["1", "mine.npz"]


# --- 4. freebody deletes only what it wrote ---------------------------------------------------------

def test_a_rerun_deletes_only_what_freebody_wrote(previous):
    out, _, files = previous
    users = {"trajectories/notes.txt": b"notes", "trajectories/mine.npz": b"npz",
             "trajectories/1/user.txt": b"inside freebody's folder",
             "trajectories/7/" + Path(next(iter(files))).name: b"a numbered folder of the user's",
             ".staging/keep.txt": b"staging of the user's", "trajectories.old/x.npz": b"x"}
    for rel, data in users.items():
        (out / rel).parent.mkdir(parents=True, exist_ok=True)
        (out / rel).write_bytes(data)
    assert main(QUICK + ["--dt", "0.02", "--out", str(out)]) == 0
    doc = _consistent(out)
    for rel, data in users.items():
        assert (out / rel).read_bytes() == data, rel
    for rel in files:  # the previous run's files are gone, its folder kept for the user's file
        assert not (out / rel).exists()
    assert [r["trajectory"].split("/")[1] for r in doc["runs"]] == ["8"]  # above the user's 7


def test_an_empty_out_is_bad_input(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(QUICK + ["--out", ""]) == 2
    _one_line_error(capsys.readouterr().err, "--out", "empty")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="--out"):
        run_specs([], "", ["reference"], progress=False)


@pytest.mark.parametrize("kind", ["fifo", "folder"])
def test_a_results_json_that_is_no_file_is_neither_read_nor_replaced(tmp_path, capsys, kind):
    out = tmp_path / "out"
    out.mkdir()
    (os.mkfifo if kind == "fifo" else os.mkdir)(out / "results.json")  # reading a FIFO would block
    assert main(QUICK + ["--dt", "0.01", "--out", str(out)]) == 2
    _one_line_error(capsys.readouterr().err, "results.json is not a regular file")
    assert (stat.S_ISFIFO if kind == "fifo" else stat.S_ISDIR)(os.stat(out / "results.json").st_mode)


# --- 5 and 8b. interrupts never destroy a complete result --------------------------------------------

@pytest.mark.slow
def test_an_interrupt_before_any_run_finished_leaves_the_previous_results_untouched(previous):
    out, before, files = previous
    proc = _start_with_crasher(*SLEEP_ONLY, "--out", str(out), "--jobs", "1")
    try:
        _wait_for(lambda: (out / "trajectories" / "2").is_dir(), proc, "its trajectory folder")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=EXIT_BUDGET_S)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "0 of 1 runs finished; nothing written" in err and "Traceback" not in err, err
    _unchanged(out, before, files)
    assert not (out / PREVIOUS).exists()
    assert _folders(out) == ["1"] and _temporaries(out) == []


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)],
                         ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_keeps_the_finished_runs_and_the_previous_complete_results(previous, signum, code):
    out, before, files = previous
    proc = _start_with_crasher(*SLOW, "--out", str(out), "--jobs", "2")
    try:
        _wait_for_finished_run(proc)
        workers = _children(proc.pid)
        assert workers
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=EXIT_BUDGET_S)
    finally:
        proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err, err
    doc = _consistent(out)
    assert doc["incomplete"] is True
    assert [(r["engine"], r["status"]) for r in doc["runs"]] == [("reference", "ok")]
    _unchanged(out, before, files, name=PREVIOUS)  # the complete results and their files, kept
    assert _temporaries(out) == []
    t0 = time.monotonic()
    while any(_alive(p) for p in workers) and time.monotonic() - t0 < WORKER_EXIT_BUDGET_S:
        time.sleep(0.1)
    assert not [p for p in workers if _alive(p)], "workers left running"
    # the next complete run replaces both, and their files go
    assert main(QUICK + ["--dt", "0.02", "--out", str(out)]) == 0
    assert not (out / PREVIOUS).exists() and _folders(out) == ["3"]


# --- 6. a baseline never replaces a device, FIFO or other special file ----------------------------

@pytest.mark.parametrize("kind", ["fifo", "symlink-to-fifo"])
@pytest.mark.parametrize("force", [True, False], ids=["force", "no-force"])
def test_baseline_refuses_special_files(previous, tmp_path, capsys, kind, force):
    out, _, _ = previous
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    to = fifo
    if kind == "symlink-to-fifo":
        to = tmp_path / "link.json"
        to.symlink_to(fifo)
    assert main(["baseline", str(out), "--to", str(to)] + (["--force"] if force else [])) == 2
    _one_line_error(capsys.readouterr().err, str(to), "FIFO", "not a regular file")
    assert stat.S_ISFIFO(os.stat(to).st_mode)  # still a FIFO
    assert main(["baseline", str(out), "--to", str(tmp_path / "b.json")]) == 0  # a file is fine


# --- 7. engine output capped in length ----------------------------------------------------------------

def test_a_huge_line_of_engine_output_is_cut(monkeypatch):
    from freebody.adapters.capture import MAX_LINE_CHARS, MAX_LINES
    from freebody.adapters.reference import ReferenceAdapter
    from freebody.run import execute

    advance = ReferenceAdapter.advance
    printed = []

    def noisy(self, steps):
        if not printed:
            os.write(1, b"x" * 5_000_000 + b"\n")  # one 5 MB line, then many short ones
            os.write(2, b"".join(b"line %d\n" % i for i in range(30)))
            printed.append(True)
        return advance(self, steps)

    monkeypatch.setattr(ReferenceAdapter, "advance", noisy)
    spec = expand([load_case("quiz")], ["reference"], ["rk4"], [0.01], None)[0]
    result = execute(spec).result
    out = result.engine_output
    assert out[0] == "x" * MAX_LINE_CHARS + f"... ({5_000_000 - MAX_LINE_CHARS} more characters)"
    assert len(out) == MAX_LINES + 1 and out[-1] == f"... {31 - MAX_LINES} more lines"
    assert len(json.dumps(result.to_json())) < 20_000


# --- 8. duplicate run identities --------------------------------------------------------------------

def _case_file(folder: Path, file: str, name: str = "spin", dt: str = "0.01", wx: float = 0.01) -> str:
    path = folder / file
    path.write_text(case_text(name=name, description="a spinning box", horizon="duration_steps = 3", dt=dt,
                              wx=wx))
    return str(path)


@pytest.mark.parametrize("cases, dts, runs", [
    (["quiz", "quiz"], [0.01], 1),
    (["quiz"], [0.01, 0.01, 0.0100000001], 2),
    (["same-a", "same-b"], None, 1),
    (["dt-twice"], None, 1),
], ids=["case-twice", "dt-twice-on-the-command-line", "two-files-same-content", "dt-twice-in-the-case"])
def test_exact_duplicates_are_merged_with_a_warning(tmp_path, cases, dts, runs):
    files = {"same-a": _case_file(tmp_path, "a.toml"), "same-b": _case_file(tmp_path, "b.toml"),
             "dt-twice": _case_file(tmp_path, "c.toml", dt="[0.01, 0.01]")}
    paths = [files.get(c, c) for c in cases]
    with pytest.warns(UserWarning, match="twice"):
        specs = expand([load_case(p) for p in paths], ["reference"], ["rk4"], dts, None, sources=paths)
    assert len(specs) == runs and len({s.key for s in specs}) == runs


def test_two_different_cases_with_one_name_are_refused(tmp_path, capsys):
    a = _case_file(tmp_path, "a.toml")
    b = _case_file(tmp_path, "b.toml", wx=0.02)
    with pytest.raises(InputError, match="two different cases have this name"):
        expand([load_case(a), load_case(b)], ["reference"], ["rk4"], None, None)
    assert main(["run", a, b, "--engine", "reference", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    _one_line_error(capsys.readouterr().err, "'spin'", a, b)
    assert not (tmp_path / "out").exists()


def test_distinct_cases_raise_no_warning_and_run_specs_refuses_a_duplicated_spec(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        specs = expand([load_case("quiz"), load_case("projectile")], ["reference"], ["rk4"], [0.01, 0.02], None)
    assert len(specs) == 4
    with pytest.raises(InputError, match="listed twice"):
        run_specs([specs[0], specs[0]], tmp_path, ["reference"], progress=False)
