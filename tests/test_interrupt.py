"""Ctrl-C and kills on a real ``python -m freebody run``: nothing lost, nothing half-written, no
worker left behind."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from freebody.run import STATUSES

# Three runs of 200 steps (dt = 5 s): two reference runs that finish at once (the planner runs a
# group's reference runs first), and one of the crashing test engine's ``sleep`` integrator, which sleeps far longer than any budget here, so they
# are still running when the signal arrives whatever the speed of the machine or of the reference
# maps (compiled, they no longer take seconds).
TESTS = Path(__file__).parent
WITH_CRASHER = f"""
import sys
sys.path.insert(0, {str(TESTS)!r})
from fake_engines.crashing_adapter import REGISTRY_ENTRY
from freebody.adapters.base import ENGINES
ENGINES["crasher"] = REGISTRY_ENTRY
from freebody.cli import main
sys.exit(main(sys.argv[1:]))
"""
FAST = ["run", "dzhanibekov", "--engine", "reference", "--integrator", "reference:euler-quat",
        "--integrator", "reference:rk4", "--duration", "1000", "--no-report", "--dt", "5"]
RUN = FAST + ["--engine", "crasher", "--integrator", "crasher:sleep"]
STARTUP_BUDGET_S = 60.0  # time allowed for the first run to finish (imports, worker start-up)
EXIT_BUDGET_S = 30.0  # time allowed to stop after the signal
WORKER_EXIT_BUDGET_S = 10.0  # orphaned workers notice their parent is gone within ~0.5 s

pytestmark = pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")


def _start(out: Path, jobs: int, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", WITH_CRASHER, *RUN, "--out", str(out), "--jobs", str(jobs), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_sigint_as_at_a_terminal)


def _sigint_as_at_a_terminal() -> None:
    """SIGINT at its default in the child: a shell's background job (``cmd &``, e.g. a CI script run
    that way) inherits SIGINT ignored, and Python then installs no KeyboardInterrupt handler."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _wait_for_finished_runs(proc: subprocess.Popen, n: int) -> list[str]:
    """Progress lines (one per finished run when stderr is not a terminal) until n runs finished."""
    lines, t0 = [], time.monotonic()
    while len(lines) < n:
        line = proc.stderr.readline()
        assert line, f"freebody exited early ({proc.wait()}): {lines}"
        if line.startswith("["):
            lines.append(line)
        assert time.monotonic() - t0 < STARTUP_BUDGET_S, lines
    return lines


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _wait_gone(pids: list[int], budget_s: float) -> list[int]:
    t0 = time.monotonic()
    while any(_alive(p) for p in pids) and time.monotonic() - t0 < budget_s:
        time.sleep(0.1)
    return [p for p in pids if _alive(p)]


@pytest.mark.parametrize("jobs", [1, 2], ids=["serial", "parallel"])
def test_ctrl_c_keeps_the_finished_runs_marked_incomplete_exit_130(tmp_path, jobs):
    proc = _start(tmp_path, jobs)
    try:
        finished = _wait_for_finished_runs(proc, 1)
        workers = _children(proc.pid)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=EXIT_BUDGET_S)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["incomplete"] is True
    assert 1 <= len(finished) <= len(doc["runs"]) < 3
    assert all(r["status"] in STATUSES for r in doc["runs"])
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]
    assert _wait_gone(workers, EXIT_BUDGET_S) == [], "worker processes left running"


def test_a_killed_run_leaves_the_previous_results_and_no_worker(tmp_path):
    done = subprocess.run([sys.executable, "-m", "freebody", *FAST, "--out", str(tmp_path), "--jobs", "1", "--quiet"],
                          capture_output=True, text=True, timeout=STARTUP_BUDGET_S)
    assert done.returncode == 0, done.stderr
    before = (tmp_path / "results.json").read_bytes()
    files = {r["trajectory"]: (tmp_path / r["trajectory"]).read_bytes() for r in json.loads(before)["runs"]}
    assert files
    proc = _start(tmp_path, 2, "--save-every", "7")  # same file names, other contents
    try:
        _wait_for_finished_runs(proc, 1)
        workers = _children(proc.pid)
        assert workers
        proc.kill()  # SIGKILL: no chance to clean up
        proc.wait(EXIT_BUDGET_S)
    finally:
        proc.kill()
    assert (tmp_path / "results.json").read_bytes() == before
    assert json.loads(before)["incomplete"] is False
    for rel, data in files.items():  # the trajectory files it names are still its own
        assert (tmp_path / rel).read_bytes() == data, rel
    assert _wait_gone(workers, WORKER_EXIT_BUDGET_S) == [], "orphaned workers kept running"
