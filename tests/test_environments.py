"""freebody.envs (requirements, cache, build, describe) and ``freebody envs``: where environments
live, their keys, requirement checking, listing and clearing, the copy of freebody's source and its
digest, reuse of a complete environment.  The tests marked ``slow`` need the package index (pip): a
requirement that cannot be installed, and a real ``mujoco==3.1.6`` environment built, reused,
described, listed and cleared."""
from __future__ import annotations

import json
import errno
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import freebody
from freebody.envs import build, cache, describe, requirements
from freebody.cli import main
from freebody.errors import InputError


@pytest.fixture
def root(tmp_path, monkeypatch) -> Path:
    """An empty FREEBODY_ENV_DIR."""
    folder = tmp_path / "envs"
    monkeypatch.setenv(cache.ENV_DIR_VARIABLE, str(folder))
    return folder


def fake_environment(root: Path, requirement: str, key: str | None = None, complete: bool = True,
                     format1: bool = False, **marker) -> Path:
    """A folder that looks like an environment freebody built: pyvenv.cfg, bin/python (this
    interpreter) and, when complete, a marker as freebody writes it (``format1``: as freebody wrote
    it before marker format 2, its key then that of the marker's fields)."""
    folder = root / (key or cache.environment_key(requirement))
    (folder / "bin").mkdir(parents=True)
    (folder / "pyvenv.cfg").write_text("home = /usr/bin\n")
    os.symlink(sys.executable, folder / "bin" / "python")
    if complete:
        data = {"requirement": requirement, "created": "2026-01-02T03:04:05+00:00",
                "last_used": "2026-01-02T03:04:05+00:00", "freebody_version": freebody.__version__,
                "python": "3.11.7", "installed": {"mujoco": "3.1.6", "numpy": "2.0.0"},
                "source_digest": "0" * 64, "pins": True, "core": build.core_versions(),
                "machine": platform.machine(), **marker}
        if format1:
            data = {**data, "key": folder.name}
        else:
            data = cache.sealed(data, folder.name, [p.name for p in folder.iterdir()])
        (folder / cache.MARKER).write_text(json.dumps(data))
    return folder


# --- where, and under which name -------------------------------------------------------------------

def test_env_root_follows_the_variables(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv(cache.ENV_DIR_VARIABLE, raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert cache.env_root() == tmp_path / "home" / ".cache" / "freebody" / "envs"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.env_root() == tmp_path / "xdg" / "freebody" / "envs"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/cache")  # ignored, as the XDG specification says
    assert cache.env_root() == tmp_path / "home" / ".cache" / "freebody" / "envs"
    monkeypatch.setenv(cache.ENV_DIR_VARIABLE, str(tmp_path / "mine"))
    assert cache.env_root() == tmp_path / "mine"
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(cache.ENV_DIR_VARIABLE, "rel")
    assert cache.env_root() == tmp_path / "rel" and cache.env_root().is_absolute()


def test_environment_key_is_stable_readable_and_distinct(monkeypatch):
    key = cache.environment_key("mujoco==3.1.6")
    assert key.startswith("mujoco-3.1.6-") and cache.KEY_RE.match(key)
    assert cache.environment_key("MuJoCo == 3.1.6") == key == cache.environment_key(" mujoco==3.1.6 ")
    assert cache.environment_key("mujoco>=3,<4") == cache.environment_key("mujoco<4 , >=3")
    others = {cache.environment_key(r) for r in ("mujoco==3.1.5", "mujoco>=3.1.6", "mujoco[usd]==3.1.6",
                                                 "mujoco-mjx==3.1.6", "mujoco")}
    assert len(others) == 5 and key not in others
    monkeypatch.setattr(freebody, "__version__", "99.0")
    assert cache.environment_key("mujoco==3.1.6") != key
    monkeypatch.undo()
    monkeypatch.setattr(cache.platform, "machine", lambda: "riscv64")
    assert cache.environment_key("mujoco==3.1.6") != key


VALID = {"mujoco==3.1.6": "mujoco==3.1.6", "MuJoCo == 3.1.6": "mujoco==3.1.6",
         "Mujoco_MJX>=3.1": "mujoco-mjx>=3.1", "dartpy": "dartpy", "mujoco[USD]==3.1.*": "mujoco[usd]==3.1.*",
         "mujoco>=3, <4": "mujoco<4,>=3"}
INVALID = ["", "  ", "--index-url=https://evil.example", "-e .", "mujoco==3.1.6 numpy", "mujoco===",
           "mujoco @ https://example.com/m.whl", 'mujoco==3.1.6; python_version > "3"', "mujoco==3.1.6\n",
           "./local/path", "mujoco==3.1.6\x1b[2J"]


@pytest.mark.parametrize("text", list(VALID))
@pytest.mark.parametrize("packaging", [True, False], ids=["packaging", "regex"])
def test_requirements_are_normalised(text, packaging, monkeypatch):
    if not packaging:
        monkeypatch.setitem(sys.modules, "packaging.requirements", None)  # import fails
    assert requirements.normalise_requirement(text) == VALID[text]


@pytest.mark.parametrize("text", INVALID)
@pytest.mark.parametrize("packaging", [True, False], ids=["packaging", "regex"])
def test_invalid_requirement_is_one_line_input_error(text, packaging, monkeypatch, root):
    if not packaging:
        monkeypatch.setitem(sys.modules, "packaging.requirements", None)
    for call in (requirements.normalise_requirement, cache.environment_key, build.ensure_environment,
                 lambda r: cache.clear_environments([r])):
        with pytest.raises(InputError) as e:
            call(text)
        message = str(e.value)
        assert "\n" not in message and "\x1b" not in message and "invalid engine requirement" in message
    assert not root.exists()  # nothing was created


UNSATISFIABLE = ["mujoco==3.1.6,<3.1.6", "mujoco==3.1.6,!=3.1.6", "mujoco==3.1.6,==3.1.7", "mujoco>=4,<3",
                 "mujoco>3,<=3", "mujoco~=3.1,<3.0", "mujoco==3.1.6, >3.1.6"]
SATISFIABLE = ["mujoco>=3,<=3", "mujoco==3.1.6,>=3.1", "mujoco==3.1.*,<4", "mujoco>=3,<4", "mujoco!=3.1.6",
               "mujoco==3.1.6,<3.1.6.post1"]


@pytest.mark.parametrize("packaging", [True, False], ids=["packaging", "regex"])
def test_unsatisfiable_specifier_is_refused_before_any_work(packaging, monkeypatch, root, capsys):
    if not packaging:
        for module in ("packaging.requirements", "packaging.specifiers", "packaging.version"):
            monkeypatch.setitem(sys.modules, module, None)
    for text in SATISFIABLE:
        requirements.normalise_requirement(text)
    monkeypatch.setattr(build, "_build", lambda *a: pytest.fail("built an unsatisfiable requirement"))
    for text in UNSATISFIABLE:
        with pytest.raises(InputError, match=r"^unsatisfiable engine requirement .*: no version of mujoco is "):
            build.ensure_environment(text)
        assert main(["envs", "create", text]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "unsatisfiable engine requirement" in err
    assert str(requirements.unsatisfiable("<3.1.6,==3.1.6")) == "==3.1.6 and <3.1.6"
    assert not root.exists()  # nothing was created


def test_unsatisfiable_engine_of_a_run_is_refused_before_any_work(tmp_path, root, capsys):
    out = tmp_path / "out"
    code = main(["run", "dzhanibekov", "--engine", "mujoco==3.1.6,<3.1.6", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "unsatisfiable engine requirement" in err, err
    assert not root.exists() and not out.exists()


# --- listing and clearing ----------------------------------------------------------------------------

def test_list_and_clear_a_fake_tree(root):
    a = fake_environment(root, "mujoco==3.1.6")
    old = fake_environment(root, "mujoco==3.1.6", key="mujoco-3.1.6-0123456789ab", freebody_version="0.1.0")
    b = fake_environment(root, "pybullet==3.2.5", installed={"pybullet": "3.2.5"})
    incomplete = fake_environment(root, "dartpy==0.2", complete=False)  # no marker: not freebody's
    leftover = root / f".tmp-{cache.environment_key('dartpy==0.2')}-abcd1234"
    leftover.mkdir()  # an interrupted build's folder, named in its record
    (root / "locks").mkdir()
    (root / "locks" / f"{cache.environment_key('dartpy==0.2')}.building").write_text(leftover.name)
    unrelated = root / "my-notes"  # not an environment: never touched
    unrelated.mkdir()
    (unrelated / "keep.txt").write_text("mine")
    (root / "logs").mkdir()
    (root / "logs" / f"{a.name}.log").write_text("log")

    listed = cache.list_environments()
    assert [(e["requirement"], e["path"]) for e in listed] == sorted(
        [("mujoco==3.1.6", str(a)), ("mujoco==3.1.6", str(old)), ("pybullet==3.2.5", str(b))])
    first = next(e for e in listed if e["path"] == str(a))
    assert set(first) >= {"requirement", "path", "size_bytes", "created", "last_used", "freebody_version",
                          "python", "installed", "source_digest", "pins"}
    assert first["installed"] == {"mujoco": "3.1.6", "numpy": "2.0.0"} and first["size_bytes"] > 0

    # by requirement: every environment of it (also an older freebody's), in any spelling
    assert sorted(cache.clear_environments(["MuJoCo == 3.1.6"])) == sorted([a, old])
    assert not a.exists() and not old.exists() and b.exists()
    assert not (root / "logs" / f"{a.name}.log").exists()
    assert cache.clear_environments(["mujoco==3.1.6"]) == []
    # a folder without freebody's marker is not freebody's, whatever its name
    assert cache.clear_environments(["dartpy==0.2"]) == [] and (incomplete / "pyvenv.cfg").is_file()
    # everything: the rest and the recorded leftovers of interrupted builds, nothing else
    assert sorted(cache.clear_environments()) == sorted([b, leftover])
    assert cache.list_environments() == [] and (unrelated / "keep.txt").read_text() == "mine"
    assert cache.clear_environments() == [] and (incomplete / "pyvenv.cfg").is_file()
    assert cache.foreign_entries() == [(incomplete, "named like an environment, without freebody's marker"),
                                       (unrelated, "not made by freebody")]


def test_list_and_clear_without_a_root(root):
    assert cache.list_environments() == [] and cache.clear_environments() == []
    assert cache.clear_environments(["mujoco==3.1.6"]) == [] and not root.exists()


def test_cli_envs(root, capsys):
    assert main(["envs", "path"]) == 0
    assert capsys.readouterr().out == f"{root}\n"
    assert main(["envs", "list"]) == 0
    assert capsys.readouterr().out == f"no environments in {root}\n"
    env = fake_environment(root, "mujoco==3.1.6")
    fake_environment(root, "scipy==1.11.4", installed={"scipy": "1.11.4"}, pins=False)
    assert main(["envs"]) == 0  # list is the default
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["requirement", "installed", "size", "MB", "last", "used", "path"]
    assert lines[1].split()[:2] == ["mujoco==3.1.6", "3.1.6"] and lines[1].endswith(str(env))
    assert "1.11.4 (core unpinned)" in lines[2]
    assert main(["envs", "clear", "mujoco==3.1.6", "dartpy==1"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"removed {env}", f"no environment for dartpy==1 in {root}"]
    assert main(["envs", "clear"]) == 0
    assert capsys.readouterr().out.startswith("removed ")
    assert main(["envs", "clear"]) == 0
    assert capsys.readouterr().out == f"no environments in {root}\n"


@pytest.mark.parametrize("argv, expected", [
    (["envs", "create"], "needs at least one REQUIREMENT"),
    (["envs", "create", "mujoco==3.1.6", "--index-url=x"], "unrecognized arguments"),
    (["envs", "create", "mujoco==3.1.6", "not a requirement"], "invalid engine requirement 'not a requirement'"),
    (["envs", "list", "mujoco==3.1.6"], "envs list takes no REQUIREMENT"),
    (["envs", "remove"], "invalid choice: 'remove'"),
])
def test_cli_envs_bad_input_is_one_line(argv, expected, root, capsys):
    code = None
    try:
        code = main(argv)
    except SystemExit as e:  # argparse's own errors
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and expected in err and err.count("\n") == 1
    assert not root.exists()


def test_clear_removes_only_what_freebody_built(root, capsys):
    """Issue 28, item 5: folders that look like environments but that freebody did not build are
    left with everything in them, and listed as not freebody's."""
    mine = fake_environment(root, "mujoco==3.1.6")
    (mine / "notes.txt").write_text("put there by hand")  # kept, with its folder
    venv = root / "myproj-0123456789ab"  # a key's name and a pyvenv.cfg: a user's own venv
    venv.mkdir()
    (venv / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (venv / "work.py").write_text("mine")
    copied = root / "backup"  # freebody's environment copied by hand: the marker is for another folder
    shutil.copytree(mine, copied, symlinks=True)
    forged = fake_environment(root, "pybullet==3.2.5")  # a marker edited by hand: its digest no longer holds
    marker = json.loads((forged / cache.MARKER).read_text())
    (forged / cache.MARKER).write_text(json.dumps({**marker, "entries": [*marker["entries"], "data"]}))
    stray = root / f".tmp-{cache.environment_key('dartpy==0.2')}-abcd1234"  # no build recorded it
    stray.mkdir()
    (stray / "x").write_text("mine")

    assert [e["path"] for e in cache.list_environments()] == [str(mine)]
    assert main(["envs", "clear"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"removed {mine}"
    foreign = sorted([mine, venv, copied, forged, stray])
    assert lines[1:] == [f"not freebody's, left alone: {p} ({why})" for p, why in cache.foreign_entries()]
    assert [p for p, _ in cache.foreign_entries()] == foreign
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    assert (venv / "work.py").read_text() == "mine" and (copied / cache.MARKER).is_file()
    assert (forged / "pyvenv.cfg").is_file() and (stray / "x").read_text() == "mine"
    assert cache.clear_environments(["pybullet==3.2.5"]) == [] and (forged / cache.MARKER).is_file()
    assert main(["envs", "list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"no environments in {root}" and len(out) == 1 + len(foreign)
    assert all(line.startswith("not freebody's, left alone: ") for line in out[1:])


def test_marker_of_the_previous_format(root, monkeypatch):
    """A marker freebody wrote before format 2 is accepted when it holds what freebody wrote (its
    key is the folder's name and the hash of its fields); its next use rewrites it in format 2; of
    it, clear removes the venv's entries only."""
    monkeypatch.setattr(build, "_build", lambda *a, **k: pytest.fail("rebuilt a usable environment"))
    old = fake_environment(root, "mujoco==3.1.6", format1=True, source_digest=build.source_digest())
    assert cache.owned_marker(old) is not None and [e["path"] for e in cache.list_environments()] == [str(old)]
    build.ensure_environment("mujoco==3.1.6")
    marker = json.loads((old / cache.MARKER).read_text())
    assert marker["marker_format"] == cache.MARKER_FORMAT
    assert marker["entries"] == sorted(["bin", "pyvenv.cfg", cache.MARKER])
    # a format-1 marker whose key is not the folder's, or not the hash of its fields: not freebody's
    renamed = fake_environment(root, "pybullet==3.2.5", format1=True, key="pybullet-3.2.5-0123456789ab")
    (renamed / cache.MARKER).write_text(json.dumps({**json.loads((renamed / cache.MARKER).read_text()),
                                                   "key": "pybullet-3.2.5-0123456789ab"}))
    other = root / "elsewhere"
    shutil.copytree(old, other, symlinks=True)
    (other / cache.MARKER).write_text(json.dumps({**marker, "marker_format": None}))
    assert cache.owned_marker(renamed) is None and cache.owned_marker(other) is None
    (old / "results.json").write_text("{}")  # not a venv's entry: kept
    assert cache.clear_environments() == [old]
    assert sorted(p.name for p in old.iterdir()) == ["results.json"]
    assert renamed.is_dir() and other.is_dir()


def test_folder_at_the_key_that_is_not_freebodys_is_never_replaced(root, monkeypatch):
    monkeypatch.setattr(build, "_build", lambda *a: pytest.fail("built over a folder that is not freebody's"))
    folder = root / cache.environment_key("mujoco==3.1.6")
    folder.mkdir(parents=True)
    (folder / "pyvenv.cfg").write_text("home = /usr/bin\n")
    (folder / "data.csv").write_text("mine")
    with pytest.raises(build.EnvironmentFailed) as e:
        build.ensure_environment("mujoco==3.1.6")
    assert str(e.value) == (f"cannot create the environment for mujoco==3.1.6 in {folder}: {folder} exists and "
                            f"holds what freebody did not build (data.csv, pyvenv.cfg); freebody removes nothing "
                            f"it did not make: move it away, then retry")
    assert sorted(p.name for p in folder.iterdir()) == ["data.csv", "pyvenv.cfg"]


def test_killed_build_leftover_is_removed_by_the_next_build(root, monkeypatch):
    fake = FakeInstaller([(0, "")])
    monkeypatch.setattr(build, "_run_logged", fake)
    monkeypatch.setattr(build, "find_uv", lambda: None)
    key = cache.environment_key("mujoco==3.1.6")
    leftover, unrecorded = root / f".tmp-{key}-killed00", root / f".tmp-{key}-mine0000"
    (leftover / "bin").mkdir(parents=True)
    unrecorded.mkdir()
    (root / "locks").mkdir()
    (root / "locks" / f"{key}.building").write_text(f"{leftover.name}\n")
    env = build.ensure_environment("mujoco==3.1.6")
    assert not leftover.exists() and unrecorded.is_dir() and env.path.is_dir()
    assert not (root / "locks" / f"{key}.building").exists()
    assert cache.owned_marker(env.path)["entries"] == sorted(p.name for p in env.path.iterdir())


# --- reuse, rebuild, re-copy ---------------------------------------------------------------------------

def test_complete_environment_is_reused_and_touched(root, monkeypatch):
    monkeypatch.setattr(build, "_build", lambda *a, **k: pytest.fail("rebuilt a complete environment"))
    folder = fake_environment(root, "mujoco==3.1.6", source_digest=build.source_digest())
    env = build.ensure_environment("MuJoCo==3.1.6")
    assert env == cache.EngineEnvironment("mujoco==3.1.6", folder, folder / "bin" / "python")
    marker = json.loads((folder / cache.MARKER).read_text())
    assert marker["last_used"] > "2026-01-02T03:04:05+00:00"


def test_changed_source_is_copied_again(root, monkeypatch):
    monkeypatch.setattr(build, "_build", lambda *a, **k: pytest.fail("rebuilt instead of copying"))
    folder = fake_environment(root, "mujoco==3.1.6", source_digest="stale")
    lines = []
    build.ensure_environment("mujoco==3.1.6", progress=lines.append)
    assert lines == ["copying freebody's changed source into the environment for mujoco==3.1.6"]
    site = cache.site_packages(folder)
    assert (site / "freebody" / "adapters" / "base.py").read_bytes() == \
        Path(build.source_files()["freebody/adapters/base.py"]).read_bytes()
    assert json.loads((folder / cache.MARKER).read_text())["source_digest"] == build.source_digest()


@pytest.mark.parametrize("damage", ["no marker", "other core versions", "interpreter gone", "other requirement"])
def test_incomplete_or_outdated_environment_is_rebuilt(damage, root, monkeypatch):
    built = []
    monkeypatch.setattr(build, "_build", lambda req, env, *a: built.append(env.requirement))
    requirement = "mujoco==3.1.6"
    if damage == "no marker":  # an empty folder (a clear killed before its last step)
        (root / cache.environment_key(requirement)).mkdir(parents=True)
    elif damage == "other core versions":
        fake_environment(root, requirement, core={"numpy": "1.0"})
    elif damage == "interpreter gone":
        folder = fake_environment(root, requirement)
        (folder / "bin" / "python").unlink()
    else:
        fake_environment(root, "mujoco==3.1.5", key=cache.environment_key(requirement))
    build.ensure_environment(requirement)
    assert built == [requirement]


class FakeInstaller:
    """Stands in for the venv, pip and uv commands of a build (:func:`build._run_logged`): records
    each command and answers with the given install results, in order."""

    def __init__(self, installs):
        self.installs = list(installs)
        self.commands = []

    def __call__(self, cmd, log, cwd=None):
        cmd = [str(c) for c in cmd]
        self.commands.append(cmd)
        if "venv" in cmd:
            folder = Path(cmd[-1])
            (folder / "bin").mkdir(parents=True)
            os.symlink(sys.executable, folder / "bin" / "python")
            return 0, ""
        if "install" in cmd:
            return self.installs.pop(0)
        if build._INSTALLED_SCRIPT in cmd:
            return 0, json.dumps([{"mujoco": "3.1.6", "numpy": "2.0.0"}, build.core_versions()])
        return 0, ""  # the import check


@pytest.mark.parametrize("uv", [None, "/opt/uv"], ids=["pip", "uv"])
def test_build_commands(uv, root, monkeypatch):
    fake = FakeInstaller([(0, "")])
    monkeypatch.setattr(build, "_run_logged", fake)
    monkeypatch.setattr(build, "find_uv", lambda: uv)
    lines = []
    env = build.ensure_environment("mujoco==3.1.6", progress=lines.append)
    venv, install, check, installed = fake.commands
    tmp = Path(venv[-1])
    assert tmp.parent == root and tmp.name.startswith(f".tmp-{env.path.name}-") and not tmp.exists()
    assert venv == ([uv, "venv", "--python", sys.executable, str(tmp)] if uv
                    else [sys.executable, "-m", "venv", str(tmp)])
    pins = [f"{n}=={v}" for n, v in build.core_versions().items()]
    assert install == ([uv, "pip", "install", "--python", str(tmp / "bin" / "python")] if uv else
                       [str(tmp / "bin" / "python"), "-m", "pip", "install", "--disable-pip-version-check",
                        "--no-input"]) + ["mujoco==3.1.6", *pins]
    assert check == [str(tmp / "bin" / "python"), "-P", "-c", build.IMPORT_CHECK]
    assert lines[:4] == [f"creating environment for mujoco==3.1.6 in {env.path} (first use; this takes a minute)",
                         "copying freebody", f"installing mujoco==3.1.6 {' '.join(pins)}", "checking"]
    assert lines[4].startswith("ready in ")
    marker = json.loads((env.path / cache.MARKER).read_text())
    assert marker["pins"] is True and marker["installer"] == ("uv" if uv else "pip")
    assert marker["installed"] == {"mujoco": "3.1.6", "numpy": "2.0.0"}
    assert marker["source_digest"] == build.source_digest() and marker["requirement"] == "mujoco==3.1.6"
    site = cache.site_packages(env.path)
    assert (site / "freebody" / "run" / "worker.py").is_file()
    assert (site / f"freebody-{freebody.__version__}.dist-info" / "METADATA").read_text().startswith(
        "Metadata-Version: 2.1\nName: freebody\n")
    assert [e["requirement"] for e in cache.list_environments()] == ["mujoco==3.1.6"]


def test_build_retries_without_pins_after_a_conflict(root, monkeypatch):
    fake = FakeInstaller([(1, PIP_CONFLICT), (0, "")])
    monkeypatch.setattr(build, "_run_logged", fake)
    monkeypatch.setattr(build, "find_uv", lambda: None)
    lines = []
    env = build.ensure_environment("mujoco==3.1.6", progress=lines.append)
    first, second = [c for c in fake.commands if "install" in c]
    assert second[second.index("mujoco==3.1.6"):] == ["mujoco==3.1.6", *build.core_requirements()]
    assert any("retrying without the pins" in ln for ln in lines)
    assert json.loads((env.path / cache.MARKER).read_text())["pins"] is False


def test_build_failure_is_one_line_and_leaves_nothing(root, monkeypatch):
    fake = FakeInstaller([(1, PIP_NOT_FOUND)])
    monkeypatch.setattr(build, "_run_logged", fake)
    monkeypatch.setattr(build, "find_uv", lambda: None)
    requirement = "freebody-no-such-engine==0.0.1"
    with pytest.raises(build.EnvironmentFailed) as e:
        build.ensure_environment(requirement)
    log = root / "logs" / f"{cache.environment_key(requirement)}.log"
    assert str(e.value) == (f"cannot create the environment for {requirement} in "
                            f"{root / cache.environment_key(requirement)}: no such version: No matching "
                            f"distribution found for {requirement} (install log: {log})")
    assert len([c for c in fake.commands if "install" in c]) == 1  # no retry: the engine does not exist
    assert sorted(p.name for p in root.iterdir()) == ["locks", "logs"]


# --- freebody's source -------------------------------------------------------------------------------

def test_source_files_cover_the_packages():
    files = build.source_files()
    for rel in ("freebody/__init__.py", "freebody/run/worker.py", "freebody/envs/build.py",
                "freebody/adapters/base.py", "freebody/reference_impl/__init__.py",
                "freebody/cases/dzhanibekov.toml", "freebody/cases/meshes/t_handle.obj"):
        assert rel in files, rel
    assert list(files) == sorted(files)
    assert not [r for r in files if "__pycache__" in r or r.endswith((".pyc", ".nbi", ".nbc"))]


def test_copied_source_is_importable(tmp_path):
    site = tmp_path / "site"
    digest = build.copy_source(site)
    assert digest == build.source_digest()
    assert not list(site.rglob("__pycache__")) and not list(site.rglob("*.nb[ic]"))
    script = ("import freebody, freebody.adapters.base, freebody.run.worker, freebody.envs.build\n"
              "from freebody.input.casefile import bundled_case_paths\n"
              "from freebody.input import load_case\n"
              "load_case('dzhanibekov')\n"
              "import json, sys\n"
              "print(json.dumps([m.__file__ for m in (freebody, freebody.adapters.base, freebody.run.worker)]"
              " + [str(bundled_case_paths()['dzhanibekov'])]))\n")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-P", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for path in json.loads(out.stdout.splitlines()[-1]):
        assert Path(path).is_relative_to(site), path


def test_digest_follows_the_source(tmp_path):
    files = build.source_files()
    assert build.source_digest(files) == build.source_digest(dict(reversed(list(files.items()))))
    edited = tmp_path / "base.py"
    edited.write_bytes(files["freebody/adapters/base.py"].read_bytes() + b"\n# edited\n")
    changed = {**files, "freebody/adapters/base.py": edited}
    assert build.source_digest(changed) != build.source_digest(files)
    renamed = {("freebody/adapters/renamed.py" if k == "freebody/adapters/base.py" else k): v
               for k, v in files.items()}
    assert build.source_digest(renamed) != build.source_digest(files)

    # copied again: the edited file replaced, a file gone from the source gone, caches kept
    site = tmp_path / "site"
    build.copy_source(site, files)
    cache = site / "freebody" / "adapters" / "__pycache__"
    cache.mkdir()
    (cache / "base.cpython-311.pyc").write_bytes(b"cached")
    fewer = {k: v for k, v in changed.items() if k != "freebody/adapters/loads.py"}
    assert build.copy_source(site, fewer) == build.source_digest(fewer)
    assert (site / "freebody" / "adapters" / "base.py").read_bytes().endswith(b"# edited\n")
    assert not (site / "freebody" / "adapters" / "loads.py").exists()
    assert (cache / "base.cpython-311.pyc").read_bytes() == b"cached"
    assert sorted(p.name for p in site.iterdir()) == ["freebody"]  # no temporary folders left


# --- messages ------------------------------------------------------------------------------------------

PIP_NOT_FOUND = """\
Collecting freebody-no-such-engine==0.0.1
ERROR: Could not find a version that satisfies the requirement freebody-no-such-engine==0.0.1 (from versions: none)
ERROR: No matching distribution found for freebody-no-such-engine==0.0.1
"""
PIP_CONFLICT = """\
ERROR: Cannot install numpy==2.4.6 and scipy==1.11.4 because these package versions have conflicting dependencies.

The conflict is caused by:
    The user requested numpy==2.4.6
    scipy 1.11.4 depends on numpy<1.28.0 and >=1.21.6

ERROR: ResolutionImpossible: for help visit https://pip.pypa.io/en/latest/topics/dependency-resolution/
"""
UV_NOT_FOUND = """\
  × No solution found when resolving dependencies:
  ╰─▶ Because there is no version of mujoco==9.9 and you require mujoco==9.9, we can conclude
      that your requirements are unsatisfiable.
"""


def test_key_error_lines():
    assert build.key_error(PIP_NOT_FOUND) == "No matching distribution found for freebody-no-such-engine==0.0.1"
    assert build.key_error(PIP_CONFLICT).startswith("Cannot install numpy==2.4.6 and scipy==1.11.4")
    assert build.key_error(UV_NOT_FOUND) == ("Because there is no version of mujoco==9.9 and you require "
                                            "mujoco==9.9, we can conclude that your requirements are "
                                            "unsatisfiable.")
    assert build.key_error("error: uv could not do it\n") == "error: uv could not do it"
    assert build.key_error("") == "no output"
    # retrying without the pins helps a conflict, not a distribution that does not exist
    assert build._not_found(build.key_error(PIP_NOT_FOUND), "freebody-no-such-engine")
    assert build._not_found(build.key_error(UV_NOT_FOUND), "mujoco")
    assert not build._not_found(build.key_error(PIP_CONFLICT), "scipy")
    assert not build._not_found("No matching distribution found for numpy==2.4.6", "mujoco")


def test_environment_failed_is_one_line(tmp_path):
    e = build.EnvironmentFailed("mujoco==9.9", "No matching distribution\nfound", tmp_path / "x.log")
    assert "\n" not in str(e) and str(e).startswith("cannot create the environment for mujoco==9.9: ")
    assert str(e).endswith(f"(install log: {tmp_path / 'x.log'})")


# --- build errors: the environment, the requirement, the cause, the log --------------------------------

class FullDisk(FakeInstaller):
    """A build on a full disk: the command ``step`` (``venv`` or ``install``) raises ENOSPC."""

    def __init__(self, step):
        super().__init__([])
        self.step = step

    def __call__(self, cmd, log, cwd=None):
        if self.step in [str(c) for c in cmd]:
            raise OSError(errno.ENOSPC, "No space left on device", str(cmd[-1]))
        return super().__call__(cmd, log, cwd)


@pytest.mark.parametrize("step", ["venv", "install"])
def test_full_disk_names_the_environment_requirement_cause_and_log(step, root, monkeypatch, capsys):
    """Issue 28, item 8: a full disk (ENOSPC raised in this process) is one line naming all four."""
    monkeypatch.setattr(build, "_run_logged", FullDisk(step))
    monkeypatch.setattr(build, "find_uv", lambda: None)
    assert main(["envs", "create", "mujoco==3.1.6"]) == 2
    err = capsys.readouterr().err.splitlines()
    folder = root / cache.environment_key("mujoco==3.1.6")
    log = root / "logs" / f"{folder.name}.log"
    assert err[-1].startswith(f"freebody: error: cannot create the environment for mujoco==3.1.6 in {folder}: "
                              f"the disk is full: No space left on device: ")
    assert err[-1].endswith(f" (install log: {log})") and log.is_file()
    assert sorted(p.name for p in root.iterdir()) == ["locks", "logs"]
    assert os.listdir(root / "locks") == [f"{folder.name}.lock"]  # no build record left


PIP_DISK_FULL = "ERROR: Could not install packages due to an OSError: [Errno 28] No space left on device\n"
PIP_NO_NETWORK = ("WARNING: Retrying (Retry(total=4, connect=None, read=None, redirect=None, status=None)) after "
                  "connection broken by 'NewConnectionError('<pip._vendor.urllib3.connection.HTTPSConnection "
                  "object at 0x7f>: Failed to establish a new connection: [Errno 101] Network is unreachable')'"
                  ": /simple/mujoco/\n" + PIP_NOT_FOUND.replace("freebody-no-such-engine", "mujoco"))


@pytest.mark.parametrize("output, cause", [(PIP_DISK_FULL, "the disk is full"),
                                           (PIP_NO_NETWORK, "no network (the package index cannot be reached)"),
                                           (PIP_NOT_FOUND.replace("freebody-no-such-engine", "mujoco"),
                                            "no such version")])
def test_pip_failure_names_its_cause(output, cause, root, monkeypatch):
    monkeypatch.setattr(build, "_run_logged", FakeInstaller([(1, output), (1, output)]))
    monkeypatch.setattr(build, "find_uv", lambda: None)
    with pytest.raises(build.EnvironmentFailed) as e:
        build.ensure_environment("mujoco==0.0.1")
    assert e.value.cause == cause
    assert str(e.value).startswith(f"cannot create the environment for mujoco==0.0.1 in "
                                   f"{root / cache.environment_key('mujoco==0.0.1')}: {cause}: ")


def test_cause_of():
    assert build.cause_of(code=errno.ENOSPC) == "the disk is full"
    assert build.cause_of(code=errno.EDQUOT) == "the disk quota is reached"
    assert build.cause_of(UV_NOT_FOUND, name="mujoco") == "no such version"
    assert build.cause_of(PIP_NOT_FOUND, name="mujoco") is None  # another distribution is missing
    assert build.cause_of(PIP_CONFLICT, name="scipy") is None and build.cause_of("") is None


# --- describing an engine ------------------------------------------------------------------------------

def test_describe_entry_point(capsys):
    assert describe.main(["describe", "reference"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(describe.DESCRIBE_PREFIX) and out.count("\n") == 1
    data = json.loads(out[len(describe.DESCRIBE_PREFIX):])
    assert data["available"] and data["version"] == freebody.__version__ and data["error"] is None
    assert "rk4" in data["integrators"] and data["precisions"] == ["float64"]
    assert describe.main(["describe"]) == 2


def test_describe_engine_in_a_subprocess(tmp_path):
    env = cache.EngineEnvironment("reference", tmp_path, Path(sys.executable))  # this interpreter
    data = describe.describe_engine(env, "reference")
    assert data["available"] and data["engine"] == "reference" and data["integrators"]
    unknown = describe.describe_engine(env, "no-such-engine")
    assert not unknown["available"] and "unknown engine 'no-such-engine'" in unknown["error"]
    broken = describe.describe_engine(cache.EngineEnvironment("x", tmp_path, tmp_path / "no-python"), "mujoco")
    assert not broken["available"] and "cannot run" in broken["error"]


# --- real environments (the package index) -------------------------------------------------------------

@pytest.mark.slow
def test_requirement_that_cannot_be_installed(root):
    requirement = "freebody-no-such-engine==0.0.1"
    with pytest.raises(build.EnvironmentFailed) as e:
        build.ensure_environment(requirement)
    message = str(e.value)
    log = root / "logs" / f"{cache.environment_key(requirement)}.log"
    assert "\n" not in message
    assert message == (f"cannot create the environment for {requirement} in "
                       f"{root / cache.environment_key(requirement)}: no such version: No matching distribution "
                       f"found for {requirement} (install log: {log})")
    assert log.is_file() and requirement in log.read_text()
    assert sorted(p.name for p in root.iterdir()) == ["locks", "logs"]  # nothing half-built left


@pytest.mark.slow
def test_real_environment_built_reused_described_cleared(root):
    lines = []
    t0 = time.perf_counter()
    env = build.ensure_environment("mujoco==3.1.6", progress=lines.append)
    first = time.perf_counter() - t0
    assert env.python.exists() and env.path.parent == root and (env.path / cache.MARKER).is_file()
    assert lines[0] == (f"creating environment for mujoco==3.1.6 in {env.path} (first use; this takes "
                        "a minute)")
    assert any(ln.startswith("installing mujoco==3.1.6 numpy==") for ln in lines)
    assert lines[-1].startswith("ready in ") and "checking" in lines

    t0 = time.perf_counter()
    again = build.ensure_environment("mujoco==3.1.6", progress=lines.append)
    second = time.perf_counter() - t0
    assert again == env and second < 1.0 and second < first / 10
    print(f"\nfirst build {first:.1f} s ({json.loads((env.path / cache.MARKER).read_text())['installer']}), "
          f"cached {second * 1000:.0f} ms")

    data = describe.describe_engine(env, "mujoco")
    assert data["available"] and data["version"] == "3.1.6" and data["error"] is None
    assert "RK4" in data["integrators"] and "Euler" in data["integrators"]
    versioned = describe.describe_engine(env, "mujoco==3.1.6")
    assert versioned["available"] and versioned["version"] == "3.1.6"
    listed = cache.list_environments()
    assert [(e["requirement"], e["installed"]["mujoco"]) for e in listed] == [("mujoco==3.1.6", "3.1.6")]
    assert listed[0]["pins"] is True and listed[0]["core_installed"] == build.core_versions()
    assert cache.clear_environments(["mujoco==3.1.6"]) == [env.path] and not env.path.exists()
