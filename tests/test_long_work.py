"""Long work says so before it starts (issue 28 item 11): a case whose run list is absurdly long is
refused at once, with the count; a long single run shows its steps as it goes."""
from __future__ import annotations

from pathlib import Path

from freebody.cli import main
from freebody.input.casefile import MAX_TIME_STEPS_PER_CASE, load_case

REPO = Path(__file__).resolve().parents[1]


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
