"""Results files are data, not paths to follow (issue 28, items 3 and 4).

Item 3: a run's ``trajectory`` is read only when it names a regular file inside the results folder
(no absolute path, no "..", no symbolic link out of the folder, no FIFO or device), of at most the
size its run's steps allow; any other is the run's missing trajectory with one warning line naming
the run and the reason, never a hang (``freebody report`` runs in a real process with a timeout).
Item 4: every document read by ``report``, ``compare`` and ``baseline`` is validated by the one
validator (:func:`freebody.results.document.check_results`): a wrong type anywhere readers index is
exit 2 with one line naming the field.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from freebody.cli import main
from freebody.errors import InputError
from freebody.report import data as rd
from freebody.results.document import open_npz, open_run_trajectory, trajectory_max_bytes, trajectory_path

# A report of the one-run fixture takes ~3 s in a fresh process on the loaded 2-core machine; a
# process still running after this is taken to hang (before the fix, a FIFO blocked it forever).
REPORT_TIMEOUT_S = 60
# The in-process checks of a hostile document (compare, baseline) end in well under this.
FAST_S = 10


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A results folder of one reference run of the two-step quiz case, with its trajectory file."""
    out = tmp_path_factory.mktemp("as_data") / "run"
    assert main(["run", "quiz", "--engine", "reference", "--integrator", "euler-quat", "--dt", "0.1",
                 "--out", str(out), "--quiet", "--no-report"]) == 0
    return out


def _copy(run_dir: Path, tmp_path: Path, name: str = "run") -> tuple[Path, dict]:
    out = tmp_path / name
    shutil.copytree(run_dir, out, symlinks=True)
    return out, json.loads((out / "results.json").read_text())


def _save(out: Path, doc: dict) -> Path:
    (out / "results.json").write_text(json.dumps(doc))
    return out


def _report(out: Path) -> subprocess.CompletedProcess:
    """``freebody report OUT`` in a real process; a hang fails the test (TimeoutExpired)."""
    return subprocess.run([sys.executable, "-m", "freebody", "report", str(out)], capture_output=True,
                          text=True, timeout=REPORT_TIMEOUT_S, cwd=out.parent)


def _absolute(out: Path, doc: dict, tmp_path: Path) -> str:
    return "/etc/passwd"


def _dotdot(out: Path, doc: dict, tmp_path: Path) -> str:
    return "../" * 12 + "etc/passwd"


def _fifo_outside(out: Path, doc: dict, tmp_path: Path) -> str:
    os.mkfifo(tmp_path / "fifo")  # nobody writes it: opening it to read blocks forever
    return str(tmp_path / "fifo")


def _fifo_inside(out: Path, doc: dict, tmp_path: Path) -> str:
    rel = doc["runs"][0]["trajectory"]
    (out / rel).unlink()
    os.mkfifo(out / rel)
    return rel


def _link_to_fifo_outside(out: Path, doc: dict, tmp_path: Path) -> str:
    os.mkfifo(tmp_path / "fifo")
    rel = doc["runs"][0]["trajectory"]
    (out / rel).unlink()
    (out / rel).symlink_to(tmp_path / "fifo")
    return rel


def _link_to_another_folder(out: Path, doc: dict, tmp_path: Path) -> str:
    """The trajectory a symbolic link to the same file in another results folder."""
    other, _ = _copy(out, tmp_path, "other")
    rel = doc["runs"][0]["trajectory"]
    (out / rel).unlink()
    (out / rel).symlink_to(other / rel)
    return rel


def _sparse_huge(out: Path, doc: dict, tmp_path: Path) -> str:
    """A /dev/zero-like file: 1 TiB of zeros, sparse (no disk used)."""
    rel = doc["runs"][0]["trajectory"]
    os.truncate(out / rel, 2 ** 40)
    return rel


HOSTILE_PATHS = [
    (_absolute, "an absolute path"),
    (_dotdot, "leads out of its results folder"),
    (_fifo_outside, "an absolute path"),
    (_fifo_inside, "FIFO"),
    (_link_to_fifo_outside, "symbolic link out of its results folder"),
    (_link_to_another_folder, "symbolic link out of its results folder"),
    (_sparse_huge, "too large"),
]


@pytest.mark.parametrize("make, reason", HOSTILE_PATHS, ids=[m.__name__.strip("_") for m, _ in HOSTILE_PATHS])
def test_report_treats_a_hostile_trajectory_path_as_missing(run_dir, tmp_path, make, reason):
    out, doc = _copy(run_dir, tmp_path)
    doc["runs"][0]["trajectory"] = make(out, doc, tmp_path)
    _save(out, doc)
    start = time.monotonic()
    r = _report(out)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("freebody: warning: runs[0] (quiz reference/euler-quat dt=0.1)"), lines
    assert "treated as missing" in lines[0] and reason in lines[0], lines
    assert time.monotonic() - start < REPORT_TIMEOUT_S
    html = (out / "report.html").read_text()
    assert "root:" not in html  # nothing of /etc/passwd


def test_report_of_a_char_device_trajectory(run_dir, tmp_path):
    """A character device (that of /dev/zero, made in tmp_path) as the trajectory file."""
    out, doc = _copy(run_dir, tmp_path)
    rel = doc["runs"][0]["trajectory"]
    (out / rel).unlink()
    try:
        os.mknod(out / rel, 0o600 | 0o020000, os.makedev(1, 5))
    except (PermissionError, AttributeError, OSError) as e:
        pytest.skip(f"cannot make a character device in tmp_path ({e}); needs root")
    r = _report(out)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "a character device" in lines[0], r.stderr


@pytest.mark.parametrize("make, reason", HOSTILE_PATHS[:3] + HOSTILE_PATHS[5:],
                         ids=[m.__name__.strip("_") for m, _ in HOSTILE_PATHS[:3] + HOSTILE_PATHS[5:]])
def test_compare_and_baseline_do_not_follow_trajectory_paths(run_dir, tmp_path, capsys, make, reason):
    """They read no trajectory: the document is valid, compared and stored as it is."""
    out, doc = _copy(run_dir, tmp_path)
    doc["runs"][0]["trajectory"] = make(out, doc, tmp_path)
    _save(out, doc)
    start = time.monotonic()
    assert main(["compare", str(out), str(run_dir)]) == 0
    assert main(["baseline", str(out), "--to", str(tmp_path / "base.json")]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and time.monotonic() - start < FAST_S
    assert "trajectory" not in json.loads((tmp_path / "base.json").read_text())["runs"][0]


def test_a_trajectory_inside_the_folder_through_a_link_is_read(run_dir, tmp_path):
    """A symbolic link that stays inside the folder is followed: the file is the folder's."""
    out, doc = _copy(run_dir, tmp_path)
    rel = doc["runs"][0]["trajectory"]
    (out / "kept.npz").write_bytes((out / rel).read_bytes())
    (out / rel).unlink()
    (out / rel).symlink_to(out / "kept.npz")
    assert trajectory_path(out, rel) == (out / "kept.npz").resolve()
    with open_run_trajectory(out, doc["runs"][0]) as z:
        assert len(z["t"]) == 3  # 2 steps


def test_readers_refuse_what_the_check_refuses(run_dir, tmp_path):
    """The trajectory readers of the report (findings, final states, figures) open through the same
    checks, so a file swapped after the warnings' check is not followed either."""
    out, doc = _copy(run_dir, tmp_path)
    run = {**doc["runs"][0], "final_state": None}
    os.mkfifo(tmp_path / "fifo")
    (out / run["trajectory"]).unlink()
    (out / run["trajectory"]).symlink_to(tmp_path / "fifo")
    assert rd.trajectory_reader(out)(run) is None
    assert rd._final(run, out) is None
    with pytest.raises(InputError, match="symbolic link"):
        rd.SeriesReader(None).read(out / run["trajectory"], run)


def test_uncompressed_size_is_bounded(tmp_path):
    """A small npz that inflates beyond what its run's steps allow (a zip bomb) is not read."""
    path = tmp_path / "bomb.npz"
    np.savez_compressed(path, t=np.zeros(2_000_000))  # 16 MB of zeros in ~16 KB
    run = {"steps": 2}
    assert path.stat().st_size < trajectory_max_bytes(run) < 16_000_000
    with pytest.raises(InputError, match="uncompressed"):
        with open_npz(path, trajectory_max_bytes(run)):
            pass


# --- item 4: one validator for report, compare and baseline -----------------------------------

def _set(path: str, value):
    """A change of the document: set the part at ``path`` (keys and list indices, dot-separated)."""
    def change(doc: dict) -> dict:
        *parents, last = [int(p) if p.isdigit() else p for p in path.split(".")]
        node = doc
        for p in parents:
            node = node[p]
        node[last] = value
        return doc
    return change


def _match(**fields):
    base = {"verdict": "reproduces", "integrator": "euler-quat", "closest": "euler-quat",
            "indistinguishable": ["euler-quat"], "levels_rad": {}, "ratios": {}}
    return _set("runs.0.matches_reference", {**base, **fields})


WRONG_TYPES = [
    ("cases_list", _set("cases", [1, 2]), "cases: must be an object or null, got an array"),
    ("case_string", _set("cases.quiz", "x"), "cases.quiz: must be an object, got a string"),
    ("case_mass_string", _set("cases.quiz.mass", "1 kg"), "cases.quiz.mass: must be"),
    ("case_ran_entry", _set("cases.quiz.ran", ["x"]), "cases.quiz.ran[0]: must be an object"),
    ("case_dts_string", _set("cases.quiz.dts", ["0.1"]), "cases.quiz.dts[0]: must be a number"),
    ("convergence_object", _set("convergence", {"a": 1}), "convergence: must be an array or null"),
    ("convergence_entry", _set("convergence", [{"case": "quiz"}]), "convergence[0].engine: missing"),
    ("baseline_list", _set("baseline", []), "baseline: must be an object or null"),
    ("created_number", _set("created", 5), "created: must be a string or null, got an integer"),
    ("match_names", _match(indistinguishable=[1]), "runs[0].matches_reference.indistinguishable[0]"),
    ("match_level", _match(levels_rad={"rk4": "tiny"}), "runs[0].matches_reference.levels_rad.rk4"),
    ("match_verdict", _match(verdict=["reproduces"]), "runs[0].matches_reference.verdict"),
    ("judgement_flag", _set("runs.0.judgement.blew_up", "yes"), "runs[0].judgement.blew_up: must be true or false"),
    ("final_state_q", _set("runs.0.final_state.quaternion_wxyz", "q"), "runs[0].final_state.quaternion_wxyz"),
    ("state_growth", _set("runs.0.state_growth.omega_ratio", "big"), "runs[0].state_growth.omega_ratio"),
    ("experiment_steps", _set("runs.0.experiment.steps", "2"), "runs[0].experiment.steps"),
]


@pytest.mark.parametrize("case_id, change, words", WRONG_TYPES, ids=[c[0] for c in WRONG_TYPES])
def test_wrong_types_are_one_line_exit_2_for_report_compare_and_baseline(run_dir, tmp_path, capsys,
                                                                         case_id, change, words):
    out, doc = _copy(run_dir, tmp_path)
    _save(out, change(doc))
    where = str(out / "results.json")
    for argv in (["report", str(out), "--markdown-only"], ["compare", str(out), str(run_dir)],
                 ["compare", str(run_dir), str(out)], ["baseline", str(out), "--to", str(tmp_path / "b.json")]):
        start = time.monotonic()
        code = main(argv)
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("freebody: error: "), (argv, err)
        assert where in lines[0] and words in lines[0], (argv, lines[0])
        assert "Traceback" not in err and time.monotonic() - start < FAST_S
    assert not (tmp_path / "b.json").exists()


def test_report_of_wrong_types_in_a_real_process(run_dir, tmp_path):
    """The issue's case: ``"cases": [1, 2]`` was an AttributeError traceback, exit 1."""
    out, doc = _copy(run_dir, tmp_path)
    _save(out, _set("cases", [1, 2])(doc))
    r = _report(out)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.strip() == (f"freebody: error: {out / 'results.json'}: cases: must be an object or null, "
                                f"got an array: [1, 2]")


def test_the_fixture_itself_is_valid(run_dir, tmp_path, capsys):
    """The validator rejects nothing freebody writes: the untouched folder reports, compares, stores."""
    assert main(["report", str(run_dir), "--markdown-only"]) == 0
    assert main(["compare", str(run_dir), str(run_dir)]) == 0
    assert main(["baseline", str(run_dir), "--to", str(tmp_path / "b.json")]) == 0
    assert main(["compare", str(tmp_path / "b.json"), str(run_dir)]) == 0
    assert "error" not in capsys.readouterr().err
