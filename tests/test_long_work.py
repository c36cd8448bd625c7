"""Long work says so before it starts (issue 28 item 11): a case whose run list is absurdly long is
refused at once, with the count; a long single run shows its steps as it goes."""
from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import pytest

from freebody import tolerances as tol
from freebody.run import RunSpec, execute, progress
from freebody.run.progress import LOG_INTERVAL_S, ProgressDisplay

from freebody.cli import main
from freebody.input.casefile import MAX_TIME_STEPS_PER_CASE, load_case

REPO = Path(__file__).resolve().parents[1]
LONG_RUN_BUDGET_S = 120.0  # a 210,000-step reference run, ~5 s of CPU, on a loaded shared machine


def _case_with_dts(tmp_path: Path, n: int) -> Path:
    """dzhanibekov with ``n`` time steps (all 0.01 s) and 0.1 s of simulated time."""
    lines = [line for line in (REPO / "cases" / "dzhanibekov.toml").read_text().splitlines()
             if not line.startswith(("dt ", "dt=", "duration ", "duration="))]
    path = tmp_path / "many_dts.toml"
    path.write_text(f"dt = [{', '.join(['0.01'] * n)}]\nduration = 0.1\n" + "\n".join(lines) + "\n")
    return path


def test_a_case_listing_too_many_time_steps_is_refused_before_any_run(tmp_path, capsys):
    path = _case_with_dts(tmp_path, MAX_TIME_STEPS_PER_CASE + 1)
    out = tmp_path / "out"
    code = main(["run", str(path), "--engine", "reference", "--integrator", "rk4", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"freebody: error: {path}: dt: lists {MAX_TIME_STEPS_PER_CASE + 1} time steps"), err
    assert f"at most {MAX_TIME_STEPS_PER_CASE}" in lines[0]
    assert not (out / "results.json").exists()


def test_a_case_at_the_limit_loads(tmp_path):
    pb = load_case(_case_with_dts(tmp_path, MAX_TIME_STEPS_PER_CASE))
    assert len(pb.dts) == MAX_TIME_STEPS_PER_CASE


# --- the steps of a long single run --------------------------------------------------------------

class _Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_long_run_reports_its_steps_chunk_by_chunk(monkeypatch):
    """execute() of a run judged in chunks sends (steps done, total) after each chunk."""
    monkeypatch.setattr(tol, "CHUNKED_JUDGING_MIN_STEPS", 2_000)  # a small run takes the long-run path
    monkeypatch.setattr(tol, "JUDGE_CHUNK_STEPS", 1_000)
    monkeypatch.setattr(progress, "STEP_REPORT_INTERVAL_S", 0.0)  # every chunk, not once a second
    reports = []
    progress.set_step_reporter(lambda done, total: reports.append((done, total)))
    try:
        out = execute(RunSpec(load_case("dzhanibekov"), "reference", "rk4", 0.01, 3_000))
    finally:
        progress.set_step_reporter(None)
    assert out.result.status == "ok", out.result.message
    assert reports == [(1_000, 3_000), (2_000, 3_000), (3_000, 3_000)]


def test_steps_show_on_a_terminal_and_every_10_s_in_a_log():
    clock = _Clock()
    log = io.StringIO()
    bar = ProgressDisplay(2, stream=log, clock=clock)
    bar.steps(100, 1000, "long reference/rk4 dt=0.01")
    clock.t = LOG_INTERVAL_S / 2
    bar.steps(200, 1000, "long reference/rk4 dt=0.01")  # too soon for a log
    clock.t = LOG_INTERVAL_S * 1.5
    bar.steps(900, 1000, "long reference/rk4 dt=0.01")
    lines = log.getvalue().splitlines()
    assert len(lines) == 2, lines
    assert lines[0].startswith("[0/2 runs]") and lines[0].endswith("step 100/1000 (10%) of long reference/rk4 dt=0.01")
    assert "step 900/1000 (90%) of long" in lines[1]
    term = _Terminal()
    bar = ProgressDisplay(2, stream=term, clock=clock)
    bar.steps(500, 1000, "long reference/rk4 dt=0.01")
    assert term.getvalue().startswith("\r\033[K[0/2 runs]") and "step 500/1000 (50%)" in term.getvalue()
    assert "\n" not in term.getvalue()  # rewritten in place


@pytest.mark.slow
def test_a_long_run_shows_its_steps_from_the_worker(tmp_path):
    """A real run of 210,000 steps (judged in chunks of 100,000) in a worker process: its steps
    reach the parent's display before the run ends (stderr is a log: the first report is a line)."""
    proc = subprocess.run([sys.executable, "-m", "freebody", "run", str(REPO / "cases" / "dzhanibekov.toml"),
                           "--engine", "reference", "--integrator", "rk4", "--dt", "1e-4", "--duration", "21",
                           "--no-report", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=LONG_RUN_BUDGET_S, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"^\[0/1 runs\].* step 1\d{5}/210000 \(\d+%\) of dzhanibekov reference/rk4 dt=0\.0001$",
                     proc.stderr, re.M), proc.stderr


def test_a_long_run_judged_whole_reports_its_steps_piece_by_piece(monkeypatch):
    """A run below the chunked-judging length but above PROGRESS_PIECE_MIN_STEPS is stepped in
    pieces that report their steps, and its result is the one-shot run's, number for number."""
    spec = RunSpec(load_case("dzhanibekov"), "mujoco", "RK4", 0.01, 2_500)
    pytest.importorskip("mujoco", reason="mujoco not installed: pip install -e '.[engines]'")
    whole = execute(spec).result  # 2,500 <= PROGRESS_PIECE_MIN_STEPS: one piece
    monkeypatch.setattr(tol, "PROGRESS_PIECE_MIN_STEPS", 2_000)
    monkeypatch.setattr(tol, "PROGRESS_PIECE_STEPS", 1_000)
    monkeypatch.setattr(progress, "STEP_REPORT_INTERVAL_S", 0.0)
    reports = []
    progress.set_step_reporter(lambda done, total: reports.append((done, total)))
    try:
        pieces = execute(spec).result
    finally:
        progress.set_step_reporter(None)
    assert reports == [(1_000, 2_500), (2_000, 2_500), (2_500, 2_500)]
    assert pieces.status == "ok", pieces.message
    for field in ("metrics", "final_state", "matches_reference", "state_growth"):
        assert getattr(pieces, field) == getattr(whole, field), field


def test_no_isolation_shows_a_long_runs_steps(monkeypatch, capsys):
    """--no-isolation (every run in the freebody process) shows the steps of a long run too."""
    monkeypatch.setattr(tol, "PROGRESS_PIECE_MIN_STEPS", 2_000)
    monkeypatch.setattr(tol, "PROGRESS_PIECE_STEPS", 1_000)
    monkeypatch.setattr(progress, "STEP_REPORT_INTERVAL_S", 0.0)
    code = main(["run", "dzhanibekov", "--engine", "reference", "--integrator", "rk4", "--dt", "0.001",
                 "--duration", "3", "--no-report", "--no-isolation"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert re.search(r"^\[0/1 runs\].* step 1000/3000 \(33%\) of dzhanibekov reference/rk4 dt=0\.001$", err, re.M), err
