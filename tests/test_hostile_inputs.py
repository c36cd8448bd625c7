"""Hostile inputs of issue 14 (items 12-16): each is refused with exit 2 and one line on stderr that
names the file or option, the field and the reason, and no traceback; output places that cannot be
written are found before any work starts; a full disk mid-run ends the invocation with one line and
the previous results intact; a broken or full standard output is one line and never exit 0;
user-provided text is escaped wherever it is printed.

In-process tests call ``freebody.cli.main`` (an unexpected exception would fail them with its
traceback); the tests that need a real process (a closed or broken stdout, a file size limit, a
folder the process may not write) run ``python -m freebody``.
"""
from __future__ import annotations

import ctypes
import errno
import io
import json
import os
import resource
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.errors import printable
from freebody.report.summary import summary_table
from freebody.run.progress import ProgressDisplay

from case_text import INERTIA, MASS_AND_INERTIA, case_text  # noqa: E402

GOOD = case_text(description="A valid case that the hostile ones are mutations of.")
ESC = "\x1b"


def _exit_code(argv) -> int:
    """main()'s return code, or argparse's exit code for the errors it reports itself."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


def _assert_one_line(code: int, err: str, words, expected_code: int = 2) -> str:
    """exit code 2 (or ``expected_code``), exactly one line on stderr starting with
    "freebody: error: ", containing every word, no traceback and no raw escape character."""
    assert code == expected_code, err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("freebody: error: "), err
    assert ESC not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def _python_freebody(*args) -> list[str]:
    return [sys.executable, "-m", "freebody", *args]


# --- 12 and 16: hostile case files --------------------------------------------------------------

def _tetrahedron_obj(scale: float) -> str:
    verts = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    faces = [(1, 3, 2), (1, 2, 4), (1, 4, 3), (2, 3, 4)]
    return ("".join(f"v {x * scale!r} {y * scale!r} {z * scale!r}\n" for x, y, z in verts)
            + "".join(f"f {a} {b} {c}\n" for a, b, c in faces))


# (id, (line of GOOD to replace or "" to append, replacement), words the one line must contain,
#  words it must not contain)
HOSTILE_CASES = [
    # 12: LinAlgError before: finite numbers whose squares overflow
    ("inertia_1e308", (INERTIA, "inertia = [[1e308, 0.0, 0.0], [0.0, 1e308, 0.0], [0.0, 0.0, 1e308]]"),
     ["body.inertia[0][0]", "at most 1e+150", "1e+308"], []),
    ("shape_size_1e200", (MASS_AND_INERTIA, 'shape = "box"\nsize = [1e200, 1e200, 1e200]\nmass = 1.0'),
     ["body.size[0]", "at most 1e+150"], []),
    ("shape_size_1e100_inertia_overflows", (MASS_AND_INERTIA, 'shape = "box"\nsize = [1e100, 1e100, 1e100]\nmass = 1.0'),
     ["body.size", "principal moments", "too large"], []),
    ("shape_density_volume_overflows", (MASS_AND_INERTIA, 'shape = "sphere"\nsize = [1e100]\ndensity = 1.0'),
     ["body.size", "volume", "too large or too small"], []),
    ("shape_density_mass_overflows", (MASS_AND_INERTIA, 'shape = "sphere"\nsize = [1e40]\ndensity = 1e100'),
     ["body.density", "mass", "1e+150"], []),
    ("shape_tiny_size", (MASS_AND_INERTIA, 'shape = "cone"\nsize = [1e-200, 1.0]\nmass = 1.0'),
     ["body.size[0]", "at least 1e-150"], []),
    ("inertia_tiny", (INERTIA, "inertia = [[1e-200, 0.0, 0.0], [0.0, 1e-200, 0.0], [0.0, 0.0, 1e-200]]"),
     ["body.inertia", "principal moments", "too small"], []),
    # 12: TypeError before
    ("shape_is_a_list", (MASS_AND_INERTIA, 'shape = ["box"]\nsize = [1.0, 1.0, 1.0]\nmass = 1.0'),
     ["body.shape", "must be a shape name", "['box']"], []),
    ("shape_is_a_table", (MASS_AND_INERTIA, 'shape = {kind = "box"}\nsize = [1.0, 1.0, 1.0]\nmass = 1.0'),
     ["body.shape", "must be a shape name"], []),
    # 12: OverflowError before: integers of 300 and 400 digits
    ("mass_300_digit_integer", ("mass = 1.0", "mass = " + "9" * 300),
     ["body.mass", "at most 1e+150", "a 300-digit integer"], []),
    ("mass_400_digit_integer", ("mass = 1.0", "mass = " + "9" * 400),
     ["body.mass", "at most 1e+150", "a 400-digit integer"], []),
    ("duration_steps_300_digits", ("duration = 0.05", "duration_steps = " + "9" * 300),
     ["duration_steps", "at most 1000000000", "a 300-digit integer"], []),
    ("load_steps_300_digits", ("", "[[loads]]\ntorque = [0.0, 0.0, 1.0]\nsteps = " + "9" * 300),
     ["loads[0].steps", "at most 1000000000"], []),
    ("integer_5000_digits", ("mass = 1.0", "mass = " + "9" * 5000), ["invalid TOML", "digits"], []),
    # 12: dt = 1e-320, duration 1e308 with dt 1e-10, dt = 1e-300: the number of steps
    ("dt_1e-320", ("dt = [0.01]", "dt = [1e-320]"),
     ["duration", "dt = 1e-320 s", "more than 1.8e308 steps", "MAX_STEPS_PER_RUN"], []),
    ("duration_1e308_dt_1e-10", ("duration = 0.05\ndt = [0.01]", "duration = 1e308\ndt = [1e-10]"),
     ["duration", "at most 1e+150", "1e+308"], []),
    ("duration_1e100_dt_1e-10", ("duration = 0.05\ndt = [0.01]", "duration = 1e100\ndt = [1e-10]"),
     ["duration", "1e+110 steps", "at most 1e+09 steps"], []),
    ("dt_1e-300", ("dt = [0.01]", "dt = [1e-300]"), ["duration", "5e+298 steps", "at most 1e+09 steps"], []),
    ("dt_1e-200_with_duration_steps", ("duration = 0.05\ndt = [0.01]", "duration_steps = 5\ndt = [1e-200]"),
     ["dt", "at least 1e-150"], []),
    # 12: a name longer than the limit (file names, tables)
    ("name_250_characters", ('name = "good"', 'name = "' + "n" * 250 + '"'),
     ["name", "250 characters", "at most 100"], []),
    # 16: quaternions whose norm over- or underflows
    ("quaternion_1e308", ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [1e308, 1e308, 0.0, 0.0]"),
     ["initial.orientation[0]", "at most 1e+150"], ["normalised"]),
    ("quaternion_denormal", ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [1e-320, 0.0, 0.0, 0.0]"),
     ["initial.orientation", "too small to normalise", "denormal"], ["zero quaternion"]),
    # 16: control characters and terminal escapes in a case name
    ("name_with_ansi_escape", ('name = "good"', 'name = "bad\\u001b[31mred\\u0007"'),
     ["name", "printable", "\\x1b[31m", "\\x07"], []),
    ("name_with_bidi_override", ('name = "good"', 'name = "evil\\u202etxt"'), ["name", "\\u202e"], []),
]


def _write_case(tmp_path: Path, case_id: str, change, name: str | None = None) -> Path:
    old, new = change
    text = GOOD.replace(old, new, 1) if old else GOOD + new + "\n"
    assert text != GOOD
    p = tmp_path / (name or f"{case_id}.toml")
    p.write_text(text)
    return p


@pytest.mark.parametrize("case_id,change,words,absent", HOSTILE_CASES, ids=[c[0] for c in HOSTILE_CASES])
def test_hostile_case_file_is_one_line_exit_2(tmp_path, capsys, case_id, change, words, absent):
    p = _write_case(tmp_path, case_id, change)
    code = main(["run", str(p), "--engine", "reference", "--out", str(tmp_path / "out"), "--quiet"])
    line = _assert_one_line(code, capsys.readouterr().err, [str(p), *words])
    for w in absent:
        assert w not in line, line
    assert not (tmp_path / "out" / "results.json").exists()


@pytest.mark.parametrize("scale, words", [
    (1e300, ["body.mesh", "line 2", "1e+300", "at most 1e+60"]),  # numpy warnings and "collinear" before
    (1e50, ["body.mesh", "inertia", "principal moments", "too large"]),
    (1e-40, ["body.mesh", "inertia", "principal moments", "too small"]),
    (1e-70, ["body.mesh", "volume"]),
], ids=["1e300", "1e50", "1e-40", "1e-70"])
def test_mesh_with_unrepresentable_coordinates(tmp_path, capsys, scale, words):
    (tmp_path / "tet.obj").write_text(_tetrahedron_obj(scale))
    p = _write_case(tmp_path, "mesh", (MASS_AND_INERTIA, 'mesh = "tet.obj"\ndensity = 1.0'))
    code = main(["run", str(p), "--engine", "reference", "--out", str(tmp_path / "out"), "--quiet"])
    line = _assert_one_line(code, capsys.readouterr().err, [str(p), *words])
    assert "collinear" not in line and "zero area" not in line
    code = main(["inertia", str(tmp_path / "tet.obj"), "--density", "1"])
    _assert_one_line(code, capsys.readouterr().err, [str(tmp_path / "tet.obj")])


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _socket(path: Path) -> Path:
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))
    s.close()
    return path


def _char_device(path: Path) -> Path:
    """A character device node of our own, in the test's folder (never /dev/null itself)."""
    try:
        os.mknod(path, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    except (PermissionError, OSError) as e:
        pytest.skip(f"cannot create a device node here: {e}")
    return path


@pytest.mark.parametrize("make, words", [
    (lambda p: (p.mkdir(), p)[1], ["not a regular file", "folder"]),
    (_fifo, ["not a regular file", "FIFO"]),
    (_socket, ["not a regular file", "socket"]),
    (_char_device, ["not a regular file", "character device"]),
], ids=["folder", "fifo", "socket", "char-device"])
def test_case_file_that_is_not_a_regular_file_says_what_it_is(tmp_path, make, words):
    """A real process with a time limit: a FIFO that is opened would block forever."""
    target = make(tmp_path / "case.toml")
    r = subprocess.run(_python_freebody("run", str(target), "--engine", "reference", "--out",
                                        str(tmp_path / "o"), "--quiet"),
                       capture_output=True, text=True, timeout=120)
    line = _assert_one_line(r.returncode, r.stderr, [str(target), *words])
    assert "not found" not in line


def test_case_path_with_escapes_is_printed_escaped(tmp_path, capsys):
    p = tmp_path / f"bad{ESC}[2J.toml"
    p.write_text("name = = 1\n")
    code = main(["run", str(p), "--engine", "reference", "--out", str(tmp_path / "o"), "--quiet"])
    _assert_one_line(code, capsys.readouterr().err, ["bad\\x1b[2J.toml", "invalid TOML"])


# --- 13: hostile command-line values ------------------------------------------------------------

HOSTILE_ARGS = [
    (["run", "dzhanibekov", "--duration", "1e308"], ["--duration", "at most 1e+150"]),
    (["run", "dzhanibekov", "--duration", "1e100"], ["--duration", "dzhanibekov", "steps", "MAX_STEPS_PER_RUN"]),
    (["run", "dzhanibekov", "--dt", "1e-320"], ["--dt", "dzhanibekov", "more than 1.8e308 steps"]),
    (["run", "dzhanibekov", "--dt", "1e-12"], ["--dt", "1e+13 steps", "at most 1e+09"]),
    (["run", "dzhanibekov", "--save-every", "1e20"], ["--save-every", "not an integer"]),
    (["run", "dzhanibekov", "--save-every", "1" + "0" * 20], ["--save-every", ">= 1 and <= 1000000000"]),
    (["run", "dzhanibekov", "--save-every", "9" * 5000], ["--save-every", "5000 digits"]),
    (["run", "dzhanibekov", "--timeout", "1e300"], ["--timeout", "at most"]),
    (["inertia", "box", "--size", "1", "1", "1", "--density", "1", "--method", "particles", "--seed=-1"],
     ["--seed", ">= 0"]),
    (["inertia", "sphere", "--size", "1e200", "--density", "1e300"], ["--size", "at most 1e+150"]),
    (["inertia", "sphere", "--size", "1", "--density", "1e300"], ["--density", "at most 1e+150"]),
    (["inertia", "sphere", "--size", "1e100", "--density", "1"], ["--size", "volume", "4.18879e+300"]),
    (["inertia", "sphere", "--size", "1e40", "--density", "1e100"], ["--density", "mass"]),
    (["inertia", "cone", "--size", "1e-200", "1", "--density", "1"], ["--size", ">= 1e-150"]),
    (["inertia", "cone", "--size", "1e-100", "1", "--density", "1"], ["--size", "volume"]),
    (["inertia", "box", "--size", "1e-40", "1e-40", "1e-40", "--mass", "1e-100"],
     ["--size", "principal moments", "too small"]),
    (["sweep", "--count", "1", "--duration", "1e100"], ["--duration", "steps", "MAX_STEPS_PER_RUN"]),
    (["sweep", "--count", "1", "--dt", "1e-320", "--duration", "1e-320"], ["--dt", "at least 1e-150"]),
    (["sweep", "--count", "1", "--max-spin", "1e300"], ["--max-spin", "1e+150"]),
    (["compare", "a.json", "b.json", "--rtol", "1e400"], ["--rtol"]),
    (["run", "x" * 5000], ["path too long"]),
]


@pytest.mark.parametrize("argv,words", HOSTILE_ARGS, ids=[" ".join(a[0])[:60] for a in HOSTILE_ARGS])
def test_hostile_arguments_are_one_line_exit_2(tmp_path, capsys, argv, words):
    extra = ["--out", str(tmp_path / "o"), "--quiet"] if argv[0] in ("run", "sweep") else []
    if argv[0] == "run" and argv[1] == "dzhanibekov":
        extra += ["--engine", "reference"]
    code = _exit_code(argv + extra)
    _assert_one_line(code, capsys.readouterr().err, words)
    assert not (tmp_path / "o" / "results.json").exists()


# --- 14: output places, standard output, a full disk ---------------------------------------------

def _unwritable_folder(path: Path) -> Path:
    path.mkdir()
    path.chmod(0o555)
    return path


def _without_dac_override():
    """preexec_fn: as root, drop the capabilities that let root write into any folder (from the
    bounding set, so that they are not regained at exec); otherwise nothing."""
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        if libc.prctl(24, cap, 0, 0, 0) != 0:  # PR_CAPBSET_DROP
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def _run_unprivileged(args, **kw) -> subprocess.CompletedProcess:
    try:
        return subprocess.run(_python_freebody(*args), capture_output=True, text=True, timeout=300,
                              preexec_fn=_without_dac_override, **kw)
    except subprocess.SubprocessError as e:
        if "preexec_fn" in str(e):
            pytest.skip(f"cannot drop root's file-permission override here: {e}")
        raise


SWEEP = ["sweep", "--count", "1", "--engine", "reference", "--integrator", "rk4", "--duration", "0.02"]


@pytest.mark.parametrize("where, words", [
    ("file", ["--out", "exists and is not a folder"]),
    ("under-file", ["--out", "a part of its path is a file"]),
    ("empty", ["--out", "empty"]),
], ids=lambda x: x if isinstance(x, str) else "")
def test_sweep_out_that_cannot_be_a_folder_fails_before_the_runs(tmp_path, capsys, where, words):
    (tmp_path / "f").write_text("a user's file\n")
    out = {"file": str(tmp_path / "f"), "under-file": str(tmp_path / "f" / "sub"), "empty": ""}[where]
    code = main([*SWEEP, "--out", out])  # progress on: a run that started would show in stderr
    captured = capsys.readouterr()
    _assert_one_line(code, captured.err, words)
    assert captured.out == ""
    assert (tmp_path / "f").read_text() == "a user's file\n"


def test_sweep_out_unwritable_fails_before_the_runs(tmp_path):
    ro = _unwritable_folder(tmp_path / "ro")
    r = _run_unprivileged([*SWEEP, "--out", str(ro / "sweep")])
    _assert_one_line(r.returncode, r.stderr, ["--out", str(ro / "sweep"), "Permission denied"])
    assert r.stdout == ""
    r = _run_unprivileged([*SWEEP, "--out", str(ro)])
    _assert_one_line(r.returncode, r.stderr, ["--out", "cannot write there", "Permission denied"])


@pytest.mark.parametrize("where", ["file", "under-file"])
def test_inertia_compare_out_that_cannot_be_a_folder_fails_before_the_work(tmp_path, capsys, where):
    (tmp_path / "f").write_text("x\n")
    out = str(tmp_path / "f") if where == "file" else str(tmp_path / "f" / "sub")
    code = main(["inertia", "box", "--size", "1", "2", "3", "--density", "1", "--compare",
                 "--resolution", "4", "--out", out])
    captured = capsys.readouterr()
    _assert_one_line(code, captured.err, ["--out", out])
    assert captured.out == ""  # the exact report is printed after the comparison: nothing ran


def test_inertia_compare_out_unwritable(tmp_path):
    ro = _unwritable_folder(tmp_path / "ro")
    r = _run_unprivileged(["inertia", "box", "--size", "1", "2", "3", "--density", "1", "--compare",
                           "--resolution", "4", "--out", str(ro)])
    _assert_one_line(r.returncode, r.stderr, ["--out", "cannot write there"])
    assert r.stdout == ""


def _results_doc(**run_changes) -> dict:
    run = {"case": "c", "engine": "reference", "integrator": "rk4", "precision": "float64", "dt": 0.01,
           "steps": 5, "status": "ok", "message": "", "truth": "closed-form", "wall_time_s": 0.1,
           "engine_version": "1", "metrics": {"orientation_error_max_rad": 1e-6}}
    run.update(run_changes)
    return {"schema_version": 1, "engines": {"reference": "1"}, "incomplete": False, "runs": [run]}


def _write_results(path: Path, doc: dict | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc or _results_doc()))
    return path


def test_baseline_to_under_a_file(tmp_path, capsys):
    res = _write_results(tmp_path / "run" / "results.json")
    (tmp_path / "f").write_text("x\n")
    code = main(["baseline", str(res.parent), "--to", str(tmp_path / "f" / "base.json")])
    _assert_one_line(code, capsys.readouterr().err, ["--to", str(tmp_path / "f"), "exists and is not a folder"])


def test_baseline_to_an_unwritable_folder(tmp_path):
    res = _write_results(tmp_path / "run" / "results.json")
    ro = _unwritable_folder(tmp_path / "ro")
    r = _run_unprivileged(["baseline", str(res.parent), "--to", str(ro / "base.json")])
    _assert_one_line(r.returncode, r.stderr, ["--to", "cannot write there", "Permission denied"])
    assert not (ro / "base.json").exists()


@pytest.mark.parametrize("argv, code_if_written", [
    (["list"], 0),
    (["compare", "BASE", "CUR"], 1),  # a regression: never exit 0 because the output was lost
])
def test_broken_stdout_pipe_is_one_line_and_not_exit_0(tmp_path, argv, code_if_written):
    base = _write_results(tmp_path / "base.json")
    cur = _write_results(tmp_path / "cur.json", _results_doc(metrics={"orientation_error_max_rad": 1.0}))
    argv = [str(base) if a == "BASE" else str(cur) if a == "CUR" else a for a in argv]
    p = subprocess.Popen(_python_freebody(*argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before freebody writes
    err = p.stderr.read().decode()
    code = p.wait(timeout=120)
    _assert_one_line(code, err, ["standard output", "pipe was closed"])
    # the same command with its output read: the expected code
    r = subprocess.run(_python_freebody(*argv), capture_output=True, text=True, timeout=120)
    assert r.returncode == code_if_written, r.stderr


def test_closed_stdout_is_one_line(tmp_path):
    r = subprocess.run(_python_freebody("list"), stderr=subprocess.PIPE, text=True, timeout=120,
                       preexec_fn=lambda: os.close(1))
    _assert_one_line(r.returncode, r.stderr, ["standard output is closed"])


class _FullDevice(io.TextIOBase):
    """A standard output on a full device (as /dev/full): every write fails with ENOSPC."""

    def write(self, text):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def flush(self):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_full_stdout_is_one_line_exit_2(monkeypatch, capsys):
    monkeypatch.setattr(sys, "stdout", _FullDevice())
    code = main(["list"])
    _assert_one_line(code, capsys.readouterr().err, ["standard output", "No space left on device"])


def _limited_file_size(limit: int):
    def pre():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return pre


@pytest.mark.parametrize("mode", [["--jobs", "1"], ["--no-isolation"]], ids=["worker", "in-process"])
def test_full_disk_mid_run_is_one_line_and_keeps_the_previous_results(tmp_path, capsys, mode):
    """RLIMIT_FSIZE makes every write past 4 KiB fail (EFBIG), as a full disk does (ENOSPC): the
    trajectory file (~13 KB) cannot be written.  One line naming the file, exit 2, and the previous
    results.json and the trajectory files it names untouched."""
    out = tmp_path / "out"
    args = ["run", "dzhanibekov", "--engine", "reference", "--integrator", "rk4", "--dt", "0.01",
            "--duration", "1", "--quiet", "--no-report", "--out", str(out)]
    assert main(args) == 0
    capsys.readouterr()
    before = (out / "results.json").read_bytes()
    named = [out / r["trajectory"] for r in json.loads(before)["runs"]]
    assert named and all(p.is_file() for p in named)
    r = subprocess.run(_python_freebody(*args, *mode), capture_output=True, text=True,
                       timeout=300, preexec_fn=_limited_file_size(4096))
    _assert_one_line(r.returncode, r.stderr, ["trajectories", ".npz", "File too large"])
    assert (out / "results.json").read_bytes() == before
    assert all(p.is_file() for p in named)


# --- 15: compare on hostile results files and tolerances --------------------------------------

def _bytes(doc) -> bytes:
    return json.dumps(doc).encode()


HOSTILE_RESULTS = [
    ("latin1", json.dumps(_results_doc(case="caf\u00e9"), ensure_ascii=False).encode("latin-1"), ["not UTF-8"]),
    ("utf16", json.dumps(_results_doc()).encode("utf-16"), ["not UTF-8"]),
    ("nested", b"[" * 200_000 + b"]" * 200_000, ["nested too deeply"]),
    ("case_list", _bytes(_results_doc(case=["c"])), ["runs[0].case", "must be a string", "an array"]),
    ("case_dict", _bytes(_results_doc(case={"c": 1})), ["runs[0].case", "must be a string", "an object"]),
    ("precision_list", _bytes(_results_doc(precision=["float64"])), ["runs[0].precision", "a string or null"]),
    ("precision_dict", _bytes(_results_doc(precision={})), ["runs[0].precision"]),
    ("metrics_list", _bytes(_results_doc(metrics=[1.0])), ["runs[0].metrics", "an object or null"]),
    ("metrics_string", _bytes(_results_doc(metrics="bad")), ["runs[0].metrics"]),
    ("metric_value_list", _bytes(_results_doc(metrics={"orientation_error_max_rad": [1]})),
     ["runs[0].metrics.orientation_error_max_rad", "a number or null"]),
    ("engines_list", _bytes({**_results_doc(), "engines": ["reference"]}), ["engines", "must be an object"]),
    ("engines_string", _bytes({**_results_doc(), "engines": "reference"}), ["engines", "must be an object"]),
    ("engine_version_dict", _bytes({**_results_doc(), "engines": {"reference": {"v": 1}}}),
     ["engines.reference", "version string or null"]),
    ("engine_list", _bytes(_results_doc(engine=["reference"])), ["runs[0].engine"]),
    ("status_unknown", _bytes(_results_doc(status="fine")), ["runs[0].status", "unknown status"]),
    ("status_list", _bytes(_results_doc(status=["ok"])), ["runs[0].status"]),
    ("dt_400_digits", b'{"schema_version": 1, "runs": [{"case": "c", "engine": "e", "integrator": "i", '
                      b'"status": "ok", "dt": ' + b"9" * 400 + b"}]}", ["runs[0].dt", "not a positive number"]),
    ("metric_400_digits", _bytes(_results_doc()).replace(b"1e-06", b"9" * 400), None),  # huge: just compared
    ("incomplete_string", _bytes({**_results_doc(), "incomplete": "no"}), ["incomplete", "true or false"]),
]


@pytest.mark.parametrize("case_id,data,words", HOSTILE_RESULTS, ids=[c[0] for c in HOSTILE_RESULTS])
def test_compare_on_hostile_results(tmp_path, capsys, case_id, data, words):
    bad = tmp_path / "bad.json"
    bad.write_bytes(data)
    good = _write_results(tmp_path / "good.json")
    for argv in (["compare", str(bad), str(good)], ["compare", str(good), str(bad)]):
        code = main(argv)
        captured = capsys.readouterr()
        if words is None:  # a valid (if odd) document: compared without a traceback
            assert code in (0, 1) and "Traceback" not in captured.err
            continue
        _assert_one_line(code, captured.err, [str(bad), *words])


@pytest.mark.parametrize("data, words", [
    (bytes(range(256)) * 4, ["--tolerances", "not UTF-8"]),
    ("rtol = 0.1\n".encode("utf-16"), ["--tolerances", "not UTF-8"]),
    (b"rtol = 0.1\x00\x01\x02\n", ["--tolerances", "invalid TOML"]),
    (b"rtol = " + b"9" * 5000 + b"\n", ["--tolerances", "invalid TOML", "digits"]),
    (b"rtol = " + b"9" * 400 + b"\n", ["--tolerances", "rtol", "finite number"]),
    (b"metrics = [1, 2]\n", ["--tolerances", "metrics", "must be a table"]),
], ids=["binary", "utf16", "nul-bytes", "5000-digits", "400-digits", "metrics-list"])
def test_compare_with_a_hostile_tolerances_file(tmp_path, capsys, data, words):
    tols = tmp_path / "tol.toml"
    tols.write_bytes(data)
    good = _write_results(tmp_path / "good.json")
    code = main(["compare", str(good), str(good), "--tolerances", str(tols)])
    _assert_one_line(code, capsys.readouterr().err, words)


# --- 16: user-provided text is escaped wherever it is printed --------------------------------

def test_compare_table_escapes_case_names(tmp_path, capsys):
    name = f"x{ESC}]0;owned{chr(7)}{ESC}[2J"
    base = _write_results(tmp_path / "b.json", _results_doc(case=name))
    cur = _write_results(tmp_path / "c.json", _results_doc(case=name, metrics={"orientation_error_max_rad": 1.0}))
    assert main(["compare", str(base), str(cur)]) == 1
    out = capsys.readouterr().out
    assert ESC not in out and "\x07" not in out
    assert printable(name) in out


def test_progress_display_escapes_text():
    stream = io.StringIO()
    bar = ProgressDisplay(2, stream=stream)
    bar.update(f"ok case{ESC}[31mred{chr(7)}")
    bar.note(f"note{ESC}[2J")
    text = stream.getvalue()
    assert ESC not in text and "\x07" not in text
    assert "case\\x1b[31mred\\x07" in text and "note\\x1b[2J" in text


def test_summary_table_escapes_names_and_messages():
    run = {"case": f"c{ESC}[31m", "engine": "reference", "integrator": "rk4", "dt": 0.01, "status": "failed",
           "message": f"engine said {ESC}[2J\nsecond line", "metrics": {}}
    text = summary_table([run])
    assert ESC not in text
    assert "c\\x1b[31m" in text and "engine said \\x1b[2J\\nsecond line" in text


def test_warnings_escape_user_text(tmp_path, capsys):
    p = _write_case(tmp_path, "q", ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [2.0, 0.0, 0.0, 0.0]"),
                    name=f"q{ESC}[31m.toml")
    main(["run", str(p), "--engine", "reference", "--integrator", "rk4", "--out", str(tmp_path / "o"),
          "--quiet", "--no-report", "--jobs", "1"])
    err = capsys.readouterr().err
    assert "normalised" in err and ESC not in err and "q\\x1b[31m.toml" in err
