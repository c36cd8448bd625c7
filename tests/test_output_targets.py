"""One rule for every file freebody writes (issue 28, item 1), and duplicate runs refused by
compare (item 10).

The rule (:func:`freebody.results.io.output_obstacle`): a regular file or a new path.  A folder, a
FIFO, a device, a socket, or a symbolic link (whatever it points to) is exit 2 with one line
naming the option and the path, checked before the work starts and again at write time, and the
special file is left as it was.  Every command's output option is walked with each kind; special
files are made in the test's folder only (a character device only when ``os.mknod`` is allowed:
running as root), never the system's /dev nodes.
"""
from __future__ import annotations

import json
import os
import shutil
import socket
import stat
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.errors import InputError
from freebody.results.io import write_json_atomic, write_text_atomic

QUICK = ["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--no-report", "--quiet",
         "--no-isolation"]
SWEEP = ["sweep", "--count", "1", "--engine", "reference", "--integrator", "rk4", "--dt", "0.01",
         "--duration", "0.02", "--quiet", "--jobs", "1"]
INERTIA = ["inertia", "box", "--size", "1", "2", "3", "--density", "1", "--compare", "--resolution", "4"]
BENCH = ["bench", "--quick", "--no-suite", "--rss-steps", "0", "--repeats", "1", "--quiet"]
TARGET_TEXT = "the user's own file\n"


# --- special files, in tmp_path only ------------------------------------------------------------

def _fifo(p: Path) -> None:
    os.mkfifo(p)


def _folder(p: Path) -> None:
    p.mkdir()


def _socket(p: Path) -> None:
    """A UNIX socket bound at ``p`` (bound by its relative name: an AF_UNIX path has at most 107
    characters, and tmp_path can be longer)."""
    here = os.getcwd()
    s = socket.socket(socket.AF_UNIX)
    try:
        os.chdir(p.parent)
        s.bind(p.name)
    finally:
        os.chdir(here)
        s.close()


def _char_device(p: Path) -> None:
    """A character device node of our own (1, 3: what /dev/null is), in the test's folder."""
    if os.geteuid() != 0:
        pytest.skip("a character device node can be made by root only (os.mknod)")
    try:
        os.mknod(p, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    except OSError as e:
        pytest.skip(f"cannot create a device node here: {e}")


def _link_to_file(p: Path) -> None:
    target = p.parent / f"{p.name}.target"
    target.write_text(TARGET_TEXT)
    p.symlink_to(target.name)


def _link_to_fifo(p: Path) -> None:
    os.mkfifo(p.parent / f"{p.name}.target")
    p.symlink_to(f"{p.name}.target")


def _dangling_link(p: Path) -> None:
    p.symlink_to(f"{p.name}.nowhere")


FILE_KINDS = {"fifo": _fifo, "folder": _folder, "socket": _socket, "char-device": _char_device,
              "symlink-to-file": _link_to_file, "symlink-to-fifo": _link_to_fifo,
              "dangling-symlink": _dangling_link}
# what a folder option (DIR) must refuse: anything but a folder (a link to a folder is a folder)
FOLDER_KINDS = {k: FILE_KINDS[k] for k in ("fifo", "socket", "char-device", "symlink-to-fifo")}


def _state(p: Path):
    """What is at ``p``, for before/after: its lstat mode and, for a link, its target's mode and text."""
    st = os.lstat(p)
    if not stat.S_ISLNK(st.st_mode):
        return (st.st_mode, st.st_rdev)
    target = p.parent / os.readlink(p)
    if not os.path.lexists(target):
        return (st.st_mode, os.readlink(p), None)
    tst = os.lstat(target)
    text = target.read_text() if stat.S_ISREG(tst.st_mode) else None
    return (st.st_mode, os.readlink(p), tst.st_mode, text)


def _refused(capsys, argv: list[str], target: Path, *words: str, shown: Path | None = None) -> str:
    """Run ``argv``: exit 2, one line naming ``shown`` (default ``target``) and ``words``, no
    traceback, and ``target`` as it was."""
    before = _state(target)
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, (code, err)
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for w in (str(shown or target), *words):
        assert w in err, (w, err)
    assert _state(target) == before, "the special file was changed"
    return err


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """A run folder with a complete results.json (tests copy it)."""
    out = tmp_path_factory.mktemp("results") / "out"
    assert main(QUICK + ["--out", str(out)]) == 0
    return out


# --- every file option --------------------------------------------------------------------------

FILE_OPTIONS = {
    "compare --junit": lambda base, x: ["compare", str(base), str(base), "--junit", x],
    "baseline --to": lambda base, x: ["baseline", str(base), "--to", x],
    "baseline --to --force": lambda base, x: ["baseline", str(base), "--to", x, "--force"],
    "bench --out": lambda base, x: BENCH + ["--out", x],
    "new-case --out": lambda base, x: ["new-case", "--out", x],
}


@pytest.mark.parametrize("kind", FILE_KINDS)
@pytest.mark.parametrize("command", FILE_OPTIONS)
def test_a_file_option_refuses_what_is_no_regular_file(results, tmp_path, capsys, command, kind):
    target = tmp_path / "out.file"
    FILE_KINDS[kind](target)
    option = command.split()[1]
    _refused(capsys, FILE_OPTIONS[command](results, str(target)), target, option, "not a regular file")


# --- the files freebody writes in an output folder ----------------------------------------------

def _copy(results: Path, tmp_path: Path) -> Path:
    out = tmp_path / "out"
    shutil.copytree(results, out, symlinks=True)
    return out


FOLDER_FILES = {
    "run results.json": (lambda out: QUICK + ["--dt", "0.01", "--out", str(out)], "results.json"),
    "run .freebody.lock": (lambda out: QUICK + ["--dt", "0.01", "--out", str(out)], ".freebody.lock"),
    "run report.md": (lambda out: QUICK[:-3] + ["--quiet", "--no-isolation", "--out", str(out)],
                      "report.md"),
    "report report.md": (lambda out: ["report", str(out), "--markdown-only"], "report.md"),
    "report report.html": (lambda out: ["report", str(out)], "report.html"),
    "sweep sweep.json": (lambda out: SWEEP + ["--out", str(out)], "sweep.json"),
    "sweep sweep.txt": (lambda out: SWEEP + ["--out", str(out)], "sweep.txt"),
    "inertia --compare": (lambda out: INERTIA + ["--out", str(out)], "inertia_box.json"),
    "inertia --compare png": (lambda out: INERTIA + ["--out", str(out)], "inertia_box.png"),
}


@pytest.mark.parametrize("kind", ["fifo", "socket", "char-device", "symlink-to-file", "folder"])
@pytest.mark.parametrize("command", FOLDER_FILES)
def test_a_file_freebody_writes_in_its_folder_is_checked_before_the_work(results, tmp_path, capsys,
                                                                         command, kind):
    out = _copy(results, tmp_path)
    argv, name = FOLDER_FILES[command]
    if kind == "folder" and name == "results.json":
        pytest.skip("covered by test_output_safety (a results.json that is a folder)")
    target = out / name
    if target.exists():
        target.unlink()
    FILE_KINDS[kind](target)
    _refused(capsys, argv(out), target, name, "not a regular file", shown=out)


def test_the_lock_file_is_never_written_through_a_link(results, tmp_path, capsys):
    """Before: ``.freebody.lock`` -> a user's file had that file truncated to freebody's pid."""
    out = _copy(results, tmp_path)
    lock = out / ".freebody.lock"
    lock.unlink(missing_ok=True)
    _link_to_file(lock)
    _refused(capsys, QUICK + ["--dt", "0.01", "--out", str(out)], lock, ".freebody.lock", shown=out)
    assert (out / ".freebody.lock.target").read_text() == TARGET_TEXT


# --- every folder option ------------------------------------------------------------------------

FOLDER_OPTIONS = {
    "run --out": lambda x: QUICK + ["--out", x],
    "sweep --out": lambda x: SWEEP + ["--out", x],
    "inertia --compare --out": lambda x: INERTIA + ["--out", x],
    "demo --out": lambda x: ["demo", "quiz", "--quiet", "--engine", "reference", "--out", x],
    "report DIR": lambda x: ["report", x, "--markdown-only"],
}


@pytest.mark.parametrize("kind", FOLDER_KINDS)
@pytest.mark.parametrize("command", FOLDER_OPTIONS)
def test_a_folder_option_refuses_what_is_no_folder(tmp_path, capsys, command, kind):
    target = tmp_path / "outdir"
    FOLDER_KINDS[kind](target)
    _refused(capsys, FOLDER_OPTIONS[command](str(target)), target)


# --- at write time: the path may have changed since the check -----------------------------------

@pytest.mark.parametrize("kind", ["fifo", "symlink-to-file", "folder"])
def test_a_path_changed_after_the_check_is_not_replaced(tmp_path, kind):
    path = tmp_path / "doc.json"
    path.write_text("{}\n")

    def swap():  # between the command's check and the rename
        path.unlink()
        FILE_KINDS[kind](path)

    with pytest.raises(InputError, match="--out doc.json: is .*not a regular file"):
        write_json_atomic(path, {"a": 1}, before_replace=swap, what="--out doc.json")
    after = os.lstat(path).st_mode
    assert {"fifo": stat.S_ISFIFO, "folder": stat.S_ISDIR, "symlink-to-file": stat.S_ISLNK}[kind](after)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary left


def test_write_refuses_a_symlink_and_accepts_a_regular_file_or_a_new_path(tmp_path):
    link = tmp_path / "link.txt"
    _link_to_file(link)
    with pytest.raises(InputError, match="symbolic link"):
        write_text_atomic(link, "x")
    assert (tmp_path / "link.txt.target").read_text() == TARGET_TEXT and link.is_symlink()
    write_text_atomic(tmp_path / "new.txt", "new\n")
    write_text_atomic(tmp_path / "new.txt", "replaced\n")
    assert (tmp_path / "new.txt").read_text() == "replaced\n"


def test_a_regular_file_or_a_new_path_is_written(results, tmp_path, capsys):
    junit = tmp_path / "sub" / "junit.xml"
    assert main(["compare", str(results), str(results), "--junit", str(junit)]) == 0
    assert junit.read_text().startswith("<?xml")
    assert main(["compare", str(results), str(results), "--junit", str(junit)]) == 0  # replaced
    capsys.readouterr()


# --- item 10: a document with two runs of one identity ------------------------------------------

def test_compare_refuses_a_document_with_a_duplicate_run(results, tmp_path, capsys):
    doc = json.loads((results / "results.json").read_text())
    doc["runs"].append(dict(doc["runs"][0], metrics={**doc["runs"][0]["metrics"]}))
    dup = tmp_path / "dup.json"
    dup.write_text(json.dumps(doc))
    run = doc["runs"][0]
    n = len(doc["runs"]) - 1
    for argv, role in ((["compare", str(results), str(dup)], "current"),
                       (["compare", str(dup), str(results)], "baseline")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        for w in (role, str(dup), f"runs[0] and runs[{n}]", run["case"], run["engine"], run["integrator"]):
            assert w in err, (w, err)
    assert main(["compare", str(results), str(results)]) == 0  # each run once: fine
    capsys.readouterr()


def test_run_baseline_with_a_duplicate_run_is_refused_before_the_runs(results, tmp_path, capsys):
    doc = json.loads((results / "results.json").read_text())
    doc["runs"].append(doc["runs"][0])
    dup = tmp_path / "dup.json"
    dup.write_text(json.dumps(doc))
    out = tmp_path / "never"
    assert main(QUICK + ["--baseline", str(dup), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    n = len(doc["runs"]) - 1
    assert "--baseline" in err and f"runs[0] and runs[{n}]" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()
