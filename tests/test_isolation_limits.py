"""Issue 14, items 9-11: crashes, memory and hangs.

- 9: runs are isolated in a worker process whatever ``--jobs`` is (one worker for ``--jobs 1``): a
  real segfault or ``sys.exit(4)`` in an engine (``tests/fake_engines/crashing_adapter.py``) fails
  that run only; ``--no-isolation`` runs in this process, where ``sys.exit`` in an engine is still
  a failed run and KeyboardInterrupt still interrupts (so does the Python API ``run_case``).
- 10: every input file (case file, mesh, results document or baseline, ``--tolerances``) must be a
  regular file within a size limit: a FIFO is refused at once (tested in a real process with a
  time limit, so a regression fails instead of hanging), as are folders, sockets and files above
  the limit (sparse files: no disk space used).  No test touches /dev or other system files.
- 11: memory is estimated before the work starts; what cannot fit (the memory available mocked
  small) is refused with exit 2, the estimate and the memory available; ``--force-large`` lets it
  start; a long estimated time is a warning.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import freebody
from fake_engines.crashing_adapter import EXIT_CODE, REGISTRY_ENTRY
from freebody import tolerances as tol
from freebody.adapters.base import ENGINES
from freebody.cli import main
from freebody.errors import InputError
from freebody.input.casefile import load_case
from freebody.input.meshfile import read_mesh
from freebody.reference_impl import approx
from freebody.reference_impl.mesh import MeshError
from freebody.results import io as results_io
from freebody.results.io import FileRefused, read_regular_file
from freebody.run import budget

from case_text import MASS_AND_INERTIA, case_text  # noqa: E402

TESTS = Path(__file__).resolve().parent
SUBPROCESS_TIMEOUT_S = 120  # a FIFO read that blocks (the regression) fails the test at this point
MIB = 2 ** 20
SMALL_MEMORY = 64 * MIB  # the mocked memory available of the budget tests

INERTIA_BODY = MASS_AND_INERTIA


@pytest.fixture
def crasher(monkeypatch):
    monkeypatch.setitem(ENGINES, "crasher", REGISTRY_ENTRY)
    return "crasher"


def _exit_code(argv) -> int:
    try:
        return main(argv)
    except SystemExit as e:  # argparse reports its own errors
        return e.code


def _one_line_exit_2(code: int, err: str, *words: str) -> str:
    err = err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    return err


def _freebody_process(args, tmp_path: Path, crasher: bool = False) -> subprocess.CompletedProcess:
    """``freebody ARGS`` in a new Python process (with the crashing engine registered if asked),
    killed after SUBPROCESS_TIMEOUT_S."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); "
            + ("from fake_engines.crashing_adapter import REGISTRY_ENTRY; "
               "from freebody.adapters.base import ENGINES; ENGINES['crasher'] = REGISTRY_ENTRY; "
               if crasher else "")
            + "from freebody.cli import main; sys.exit(main(sys.argv[2:]))")
    return subprocess.run([sys.executable, "-c", code, str(TESTS), *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT_S)


# --- 9: isolation -------------------------------------------------------------------------------

CRASH_RUNS = ["--integrator", "reference:rk4", "--integrator", "crasher:segfault",
              "--integrator", "crasher:exit", "--integrator", "crasher:semi-implicit-explicit-gyro"]


def test_jobs_1_survives_a_segfault_and_sys_exit_in_an_engine(tmp_path):
    """A real process with --jobs 1: the segfault and the sys.exit(4) fail their runs; freebody
    itself finishes (exit 1: a run failed) and writes every run."""
    out = tmp_path / "out"
    done = _freebody_process(["run", "dzhanibekov", "--engine", "reference", "--engine", "crasher",
                              *CRASH_RUNS, "--dt", "0.01", "--duration", "0.05", "--jobs", "1",
                              "--out", str(out), "--quiet", "--no-report"], tmp_path, crasher=True)
    assert done.returncode == 1, done.stderr
    runs = {r["integrator"]: r for r in json.loads((out / "results.json").read_text())["runs"]}
    assert len(runs) == 4
    assert runs["segfault"]["status"] == "failed" and "SIGSEGV" in runs["segfault"]["message"]
    assert runs["exit"]["status"] == "failed" and f"SystemExit: {EXIT_CODE}" in runs["exit"]["message"]
    assert runs["rk4"]["status"] == "ok" and runs["semi-implicit-explicit-gyro"]["status"] == "ok"


def test_run_specs_with_one_job_uses_a_worker_process(crasher, tmp_path):
    from freebody.run import expand
    from freebody.run.suite import run_specs

    specs = expand([load_case("dzhanibekov")], [crasher], ["crasher:segfault"], [0.01], 0.05)
    doc, _ = run_specs(specs, tmp_path, [crasher], progress=False, jobs=1)  # would kill pytest in-process
    assert doc["runs"][0]["status"] == "failed" and "SIGSEGV" in doc["runs"][0]["message"]


def test_no_isolation_records_sys_exit_in_an_engine_as_a_failed_run(crasher, tmp_path, capsys):
    code = _exit_code(["run", "dzhanibekov", "--engine", "reference", "--engine", crasher,
                       "--integrator", "reference:rk4", "--integrator", "crasher:exit", "--dt", "0.01",
                       "--duration", "0.05", "--no-isolation", "--out", str(tmp_path), "--quiet", "--no-report"])
    assert code == 1, capsys.readouterr().err
    runs = {r["integrator"]: r for r in json.loads((tmp_path / "results.json").read_text())["runs"]}
    assert runs["exit"]["status"] == "failed" and f"SystemExit: {EXIT_CODE}" in runs["exit"]["message"]
    assert runs["rk4"]["status"] == "ok"


def test_run_case_records_sys_exit_and_keyboard_interrupt_still_interrupts(crasher):
    out = freebody.run_case("dzhanibekov", engine=crasher, integrator="exit", dt=0.01, duration=0.05)
    assert out.result.status == "failed" and f"SystemExit: {EXIT_CODE}" in out.result.message
    with pytest.raises(KeyboardInterrupt):
        freebody.run_case("dzhanibekov", engine=crasher, integrator="interrupt", dt=0.01, duration=0.05)


@pytest.mark.parametrize("argv, words", [
    (["--jobs", "2"], ["--no-isolation", "--jobs 2"]),
    (["--timeout", "5"], ["--no-isolation", "--timeout"]),
    (["--executor", "dask", "--scheduler", "tcp://127.0.0.1:9"], ["--no-isolation", "--executor dask"]),
])
def test_no_isolation_with_an_option_that_needs_workers_is_one_line_exit_2(tmp_path, capsys, argv, words):
    code = _exit_code(["run", "quiz", "--engine", "reference", "--no-isolation", *argv,
                       "--out", str(tmp_path / "out"), "--quiet"])
    _one_line_exit_2(code, capsys.readouterr().err, *words)
    assert not (tmp_path / "out").exists()


# --- 10: regular files within a size limit ------------------------------------------------------

def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _write_case(tmp_path: Path, body: str = INERTIA_BODY) -> Path:
    p = tmp_path / "case.toml"
    p.write_text(case_text(name="tiny", description="A small case for the isolation and limits tests.",
                           horizon="duration = 0.02", body=body))
    return p


def _results(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"schema_version": 1, "runs": [], "engines": {}}))
    return path


def _fifo_argv(kind: str, tmp_path: Path) -> list[str]:
    """A command whose input is a FIFO (nobody ever writes to it)."""
    if kind == "mesh":
        _fifo(tmp_path / "part.obj")
        return ["run", str(_write_case(tmp_path, 'mesh = "part.obj"\ndensity = 1000.0')), "--engine",
                "reference", "--out", str(tmp_path / "out"), "--quiet"]
    if kind == "inertia":
        return ["inertia", str(_fifo(tmp_path / "part.stl")), "--density", "1"]
    if kind == "compare":
        return ["compare", str(_fifo(tmp_path / "baseline.json")), str(_results(tmp_path / "cur.json"))]
    if kind == "compare-current":
        return ["compare", str(_results(tmp_path / "base.json")), str(_fifo(tmp_path / "current.json"))]
    if kind == "tolerances":
        return ["compare", str(_results(tmp_path / "base.json")), str(_results(tmp_path / "cur.json")),
                "--tolerances", str(_fifo(tmp_path / "tol.toml"))]
    if kind in ("report", "compare-folder"):
        (tmp_path / "run").mkdir()
        _fifo(tmp_path / "run" / "results.json")
        return (["report", str(tmp_path / "run")] if kind == "report" else
                ["compare", str(_results(tmp_path / "base.json")), str(tmp_path / "run")])
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["mesh", "inertia", "compare", "compare-current", "compare-folder",
                                  "tolerances", "report"])
def test_a_fifo_as_input_is_refused_at_once(tmp_path, kind):
    done = _freebody_process(_fifo_argv(kind, tmp_path), tmp_path)
    err = _one_line_exit_2(done.returncode, done.stderr)
    if kind not in ("inertia", "report", "compare-folder"):  # these look for a regular file first
        assert "not a regular file (a FIFO" in err


def _socket(path: Path) -> Path:
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))
    s.close()  # the socket file stays
    return path


@pytest.mark.parametrize("make, words", [
    (lambda p: p.mkdir(), ["not a regular file (a folder)"]),
    (_socket, ["not a regular file (a socket)"]),
    (lambda p: os.truncate(p.touch() or p, tol.MESH_FILE_MAX_BYTES + 1), ["too large", "128 MiB"]),
], ids=["folder", "socket", "too-large"])
def test_a_case_files_mesh_must_be_a_regular_file_within_the_limit(tmp_path, capsys, make, words):
    make(tmp_path / "part.stl")
    case = _write_case(tmp_path, 'mesh = "part.stl"\ndensity = 1000.0')
    code = _exit_code(["run", str(case), "--engine", "reference", "--out", str(tmp_path / "out"), "--quiet"])
    _one_line_exit_2(code, capsys.readouterr().err, "body.mesh", *words)


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)  # a hole: no disk space
    return path


@pytest.mark.parametrize("argv, limit_name", [
    (lambda p: ["run", str(_sparse(p / "big.toml", tol.CASE_FILE_MAX_BYTES + 1)), "--engine", "reference",
                "--out", str(p / "out")], "CASE_FILE_MAX_BYTES"),
    (lambda p: ["inertia", str(_sparse(p / "big.stl", tol.MESH_FILE_MAX_BYTES + 1)), "--density", "1"],
     "MESH_FILE_MAX_BYTES"),
    (lambda p: ["compare", str(_sparse(p / "big.json", tol.RESULTS_FILE_MAX_BYTES + 1)),
                str(_results(p / "cur.json"))], "RESULTS_FILE_MAX_BYTES"),
    (lambda p: ["compare", str(_results(p / "base.json")), str(_results(p / "cur.json")), "--tolerances",
                str(_sparse(p / "big.toml", tol.TOLERANCES_FILE_MAX_BYTES + 1))], "TOLERANCES_FILE_MAX_BYTES"),
], ids=["case", "mesh", "results", "tolerances"])
def test_an_input_file_above_its_limit_is_refused(tmp_path, capsys, argv, limit_name):
    code = _exit_code(argv(tmp_path))
    limit = getattr(tol, limit_name)
    _one_line_exit_2(code, capsys.readouterr().err, "too large", f"{limit / MIB:.4g} MiB")


def test_read_regular_file_reads_a_regular_file_up_to_the_limit(tmp_path):
    p = tmp_path / "f.txt"
    p.write_bytes(b"0123456789")
    assert read_regular_file(p, 10, "f") == b"0123456789"
    with pytest.raises(FileRefused, match=r"^f: too large"):
        read_regular_file(p, 9, "f")
    with pytest.raises(FileRefused, match=r"^g: no such file$"):
        read_regular_file(tmp_path / "missing", 10, "g")


def test_a_file_growing_past_the_limit_while_read_is_refused(tmp_path, monkeypatch):
    """A file whose size says 0 (as /proc files do) is read only up to the limit."""
    p = tmp_path / "f.txt"
    p.write_bytes(b"x" * 100)
    real_fstat = os.fstat

    class _Zero:
        def __init__(self, st):
            self.st_mode, self.st_size = st.st_mode, 0

    monkeypatch.setattr(results_io.os, "fstat", lambda fd: _Zero(real_fstat(fd)))
    assert read_regular_file(p, 100, "f") == b"x" * 100
    with pytest.raises(FileRefused, match="too large"):
        read_regular_file(p, 99, "f")


def test_mesh_and_case_readers_use_the_limits(tmp_path, monkeypatch):
    from freebody.input import meshfile

    case = _write_case(tmp_path)
    monkeypatch.setattr(tol, "CASE_FILE_MAX_BYTES", case.stat().st_size - 1)
    with pytest.raises(InputError, match="too large"):
        load_case(case)
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\n")
    monkeypatch.setattr(meshfile, "MESH_FILE_MAX_BYTES", 4)
    with pytest.raises(MeshError, match="too large"):
        read_mesh(mesh)


# --- 11: memory and time estimates --------------------------------------------------------------

@pytest.fixture
def small_memory(monkeypatch):
    monkeypatch.setattr(budget, "available_memory", lambda: SMALL_MEMORY)
    return SMALL_MEMORY


# A case listing thousands of time steps is refused by the case's dt limit before any estimate
# (input/casefile.MAX_TIME_STEPS_PER_CASE, tests/test_long_work.py).
TOO_LARGE = [
    pytest.param(lambda p: ["run", "dzhanibekov", "--engine", "reference", "--integrator", "rk4", "--dt", "1e-5",
                            "--duration", "10", "--out", str(p / "out")], id="run-1e6-steps"),
    pytest.param(lambda p: ["sweep", "--count", "1000000000", "--engine", "reference", "--out", str(p / "out")],
                 id="sweep-count-1e9"),
    pytest.param(lambda p: ["inertia", "box", "--size", "1", "1", "1", "--density", "1", "--method", "voxels",
                            "--resolution", "1024"], id="inertia-voxels-1024"),
    pytest.param(lambda p: ["inertia", "sphere", "--size", "1", "--density", "1", "--compare", "--resolution",
                            "1024", "--out", str(p / "out")], id="inertia-compare-1024"),
]


@pytest.mark.parametrize("argv", TOO_LARGE)
def test_what_cannot_fit_is_refused_before_it_starts(tmp_path, capsys, small_memory, argv):
    args = argv(tmp_path)
    code = _exit_code(args + (["--quiet"] if args[0] != "inertia" else []))
    _one_line_exit_2(code, capsys.readouterr().err, "needs about", "of memory", "64 MiB available",
                     "--force-large")
    assert not (tmp_path / "out").exists()


SMALL_WORK = [
    pytest.param(["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--dt", "0.01",
                  "--no-isolation", "--no-report", "--quiet"], id="run"),
    pytest.param(["sweep", "--count", "2", "--engine", "reference", "--integrator", "rk4", "--duration", "0.02",
                  "--quiet"], id="sweep"),
    pytest.param(["inertia", "box", "--size", "1", "1", "1", "--density", "1", "--method", "voxels",
                  "--resolution", "4"], id="inertia"),
]


@pytest.mark.parametrize("argv", SMALL_WORK)
def test_force_large_lets_what_does_not_fit_start(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.setattr(budget, "available_memory", lambda: 1)  # nothing fits
    out = [] if argv[0] == "inertia" else ["--out", str(tmp_path / "out")]
    _one_line_exit_2(_exit_code(argv + out), capsys.readouterr().err, "needs about", "--force-large")
    assert _exit_code(argv + out + ["--force-large"]) == 0, capsys.readouterr().err


def test_a_long_estimated_time_is_a_warning(tmp_path, capsys, monkeypatch):
    argv = ["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--dt", "0.01", "--no-isolation",
            "--no-report", "--quiet", "--out", str(tmp_path)]
    assert _exit_code(argv) == 0
    assert "will take about" not in capsys.readouterr().err
    monkeypatch.setattr(tol, "LONG_RUN_WARNING_S", 0.0)
    assert _exit_code(argv) == 0
    err = capsys.readouterr().err
    assert "freebody: warning: 1 run of up to 2 steps: will take about" in err


def test_the_default_suite_is_far_from_any_refusal():
    """The bundled cases on every engine: well under 1 GiB, under an hour."""
    from conftest import FAST_ENGINES
    from freebody.input.casefile import bundled_case_paths
    from freebody.run import expand

    specs = expand([load_case(n) for n in bundled_case_paths()], FAST_ENGINES, None, None, None)
    steps = [s.steps for s in specs]
    est = budget.run_estimate(len(steps), sum(steps), max(steps), 2)
    assert est.memory_bytes < 2 ** 30 and est.seconds < tol.LONG_RUN_WARNING_S


def test_available_memory_reads_meminfo_then_a_cgroup_limit(tmp_path, monkeypatch):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       16000000 kB\nMemFree:   100 kB\nMemAvailable:    8000000 kB\n")
    monkeypatch.setattr(budget, "MEMINFO", meminfo)
    monkeypatch.setattr(budget, "CGROUP", tmp_path / "no-cgroup")
    assert budget.available_memory() == 8000000 * 1024
    cgroup = tmp_path / "cgroup"
    cgroup.mkdir()
    (cgroup / "memory.max").write_text(f"{3 * 2 ** 30}\n")
    (cgroup / "memory.current").write_text(f"{2 ** 30}\n")
    monkeypatch.setattr(budget, "CGROUP", cgroup)
    assert budget.available_memory() == 2 * 2 ** 30
    (cgroup / "memory.max").write_text("max\n")
    assert budget.available_memory() == 8000000 * 1024
    monkeypatch.setattr(budget, "MEMINFO", tmp_path / "missing")
    monkeypatch.setattr(budget.os, "sysconf", lambda name: {"SC_AVPHYS_PAGES": 1000, "SC_PAGE_SIZE": 4096}[name])
    assert budget.available_memory() == 1000 * 4096


@pytest.mark.parametrize("shape, size", [("box", [1.0, 0.3, 0.01]), ("sphere", [0.2]), ("cylinder", [0.1, 2.0]),
                                         ("cone", [1.0, 0.5])])
@pytest.mark.parametrize("n", [1, 7, 64, 1024])
def test_grid_cells_are_those_of_the_approximations(shape, size, n):
    import numpy as np

    solid = approx.solid_from_shape(shape, np.array(size))
    _, counts, _ = approx._grid(solid, n)
    assert budget.grid_cells(solid.lo, solid.hi, n) == int(np.prod(counts))
