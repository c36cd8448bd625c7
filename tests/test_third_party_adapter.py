"""A third-party engine, installed as its own package, works with every harness command.

The worked example ``examples/freebody-numpy-euler`` (docs/adapters.md) registers the engine
``numpy-euler`` through the ``freebody.adapters`` entry point.  It is installed into a TEMPORARY
environment, never the test environment: a venv made in tmp_path that sees the test
environment's packages (freebody, numpy) through a ``.pth`` file, so nothing is downloaded.  The
harness commands, and the adapter conformance suite on this engine (freebody's registry-driven
module, and the example's own ``tests/test_conformance.py`` run with plain pytest from the
example's folder, passing, and failing on a deliberately broken copy), then run with that venv's
python.
"""
from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from freebody.adapters.base import engine_names

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "freebody-numpy-euler"
ENGINE = "numpy-euler"
TIMEOUT_S = 300

pytestmark = pytest.mark.slow


def _setuptools_version() -> tuple[int, ...] | None:
    if importlib.util.find_spec("setuptools") is None:
        return None
    from importlib.metadata import version
    return tuple(int(p) for p in version("setuptools").split(".")[:2] if p.isdigit())


def _run(cmd: list, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)


def _check(proc: subprocess.CompletedProcess, what: str) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, (f"{what}: exit {proc.returncode}\n--- stdout\n{proc.stdout[-4000:]}"
                                  f"\n--- stderr\n{proc.stderr[-4000:]}")
    return proc


def _make_venv(root: Path) -> tuple[Path, Path]:
    """A venv without pip whose site-packages also holds the test environment's (freebody, numpy,
    the engines): (its python, its site-packages)."""
    _check(_run([sys.executable, "-m", "venv", "--without-pip", root]), "python -m venv")
    python = root / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    site = Path(_check(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]),
                       "venv site-packages").stdout.strip())
    # site.addsitedir (not a bare path line) so the parent's own .pth files (the editable install
    # of freebody) are processed too
    parents = dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    (site / "_freebody_test_parent.pth").write_text(
        "".join(f"import site; site.addsitedir({p!r})\n" for p in parents))
    return python, site


def _install_example(site: Path, work: Path) -> None:
    """Install a copy of the example into ``site``, offline, with the example's own build backend
    (setuptools reading its pyproject.toml, entry point included)."""
    src = work / "freebody-numpy-euler"
    shutil.copytree(EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    version = _setuptools_version()
    if version is None or version < (61,):
        pytest.skip("building the example offline needs setuptools >= 61 in the test environment")
    # setuptools < 70.1 builds wheels only with the `wheel` package installed
    can_build_wheel = version >= (70, 1) or importlib.util.find_spec("wheel") is not None
    if can_build_wheel and importlib.util.find_spec("pip") is not None:
        _check(_run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
                     "--no-build-isolation", "--target", site, src]), "pip install the example")
        return
    # no wheel builder: what `setup.py develop` did: the metadata (egg-info, with the entry
    # point) written by setuptools next to the source, and the source put on the venv's path
    _check(_run([sys.executable, "-c", "from setuptools import setup; setup()", "-q", "egg_info"],
                cwd=src), "setuptools egg_info of the example")
    (site / "freebody_numpy_euler.pth").write_text(f"{src}\n")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, Path]:
    """(the temporary venv's python, the copy of the example installed into it)."""
    work = tmp_path_factory.mktemp("third_party")
    python, site = _make_venv(work / "venv")
    _install_example(site, work)
    return python, work / "freebody-numpy-euler"


@pytest.fixture(scope="module")
def venv_python(installed) -> Path:
    return installed[0]


@pytest.fixture(scope="module")
def example_copy(installed) -> Path:
    return installed[1]


def _freebody(python: Path, *args) -> subprocess.CompletedProcess:
    return _run([python, "-m", "freebody", *args])


def test_the_test_environment_does_not_see_the_example():
    assert ENGINE not in engine_names()


def test_the_temporary_environment_registers_the_engine(venv_python):
    out = _check(_run([venv_python, "-c",
                       "from freebody.adapters.base import engine_names, install_hint, load_adapter\n"
                       f"print(engine_names()); print(install_hint({ENGINE!r}))\n"
                       f"print(load_adapter({ENGINE!r}).__name__)"]), "registry").stdout
    names, hint, cls = out.strip().splitlines()
    assert ENGINE in names and "'reference'" in names
    assert hint == "pip install freebody-numpy-euler"  # from the entry point's distribution
    assert cls == "NumpyEulerAdapter"


def test_run(venv_python, tmp_path):
    out = tmp_path / "run"
    proc = _check(_freebody(venv_python, "run", "quiz", "offset_push", "--engine", ENGINE, "--dt", "0.01",
                            "--duration", "0.3", "--jobs", "2", "--quiet", "--out", out), "freebody run")
    assert ENGINE in proc.stdout
    doc = json.loads((out / "results.json").read_text())
    assert doc["engines"] == {ENGINE: "0.1.0"}
    runs = doc["runs"]
    assert {(r["case"], r["integrator"]) for r in runs} == {
        (c, i) for c in ("quiz", "offset_push") for i in ("symplectic", "explicit")}
    for r in runs:
        assert r["engine"] == ENGINE and r["status"] == "ok", r
        assert r["engine_settings"]["angular_damping"] == {"default": 0.05, "set": 0.0}
        assert r["metrics"]["orientation_error_max_rad"] < 0.05
    assert ENGINE in (out / "report.md").read_text()
    assert ENGINE in (out / "report.html").read_text()


def test_conventions(venv_python):
    proc = _check(_freebody(venv_python, "conventions", "--engine", ENGINE), "freebody conventions")
    assert f"== {ENGINE} 0.1.0" in proc.stdout
    assert "(x, y, z, w) scalar last" in proc.stdout
    assert "PASS" in proc.stdout and "FAIL" not in proc.stdout


def test_sweep(venv_python, tmp_path):
    out = tmp_path / "sweep"
    _check(_freebody(venv_python, "sweep", "--seed", "1", "--count", "2", "--engine", ENGINE, "--dt", "0.01",
                     "--duration", "0.1", "--quiet", "--out", out), "freebody sweep")
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["engines"] == {ENGINE: "0.1.0"}
    assert len(doc["runs"]) == 4 and all(r["status"] == "ok" for r in doc["runs"])


def test_bench(venv_python, tmp_path):
    out = tmp_path / "bench.json"
    _check(_freebody(venv_python, "bench", "--quick", "--no-suite", "--repeats", "1", "--quiet",
                     "--out", out), "freebody bench")
    doc = json.loads(out.read_text())
    assert doc["engines"][ENGINE] == "0.1.0"
    assert ENGINE not in doc["skipped"], doc["skipped"]
    assert doc["engine_step_s"][ENGINE]["overhead_ratio"] > 0


def test_conformance_suite(venv_python):
    """The registry-driven suite of freebody's own tests covers an entry-point engine too."""
    suite = REPO / "tests" / "test_adapter_conformance.py"
    # exit 5 (nothing collected) would mean the suite does not generate a class for entry-point
    # engines; -k on the class name (TestNumpyEuler) selects its engine-level checks too
    _check(_run([venv_python, "-m", "pytest", suite, "-q", "-k", "NumpyEuler", "-p", "no:cacheprovider"],
                cwd=REPO), "the conformance suite on the third-party engine")


# The example's own suite (tests/test_conformance.py): 2 integrators x 11 checks of an offer + 2
# engine-level checks.  Fewer collected would mean a check lost its parametrisation.
EXAMPLE_CHECKS = 24
# How the broken copy is broken: its adapter hands out the engine's scalar-last quaternion as it is
# (no reordering), a convention error the read-back and push checks catch on both integrators.
BREAKAGE = ("return (eng.x.copy(), quat_wxyz_from_xyzw(eng.q),", "return (eng.x.copy(), eng.q.copy(),")


def _pytest_in(python: Path, folder: Path) -> subprocess.CompletedProcess:
    """``python -m pytest`` run in ``folder``, as the package's developer would (no freebody
    checkout, no conftest: the folder's own tests/ only)."""
    return _run([python, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts="], cwd=folder)


def _counts(stdout: str) -> dict[str, int]:
    """{"passed": n, "failed": n, ...} from pytest's summary line."""
    return {word: int(n) for n, word in re.findall(r"(\d+) (passed|failed|skipped|error)", stdout)}


def test_the_example_runs_the_shipped_suite_from_its_own_folder(venv_python, example_copy):
    proc = _check(_pytest_in(venv_python, example_copy), "pytest in the example's folder")
    counts = _counts(proc.stdout)
    assert counts.get("passed", 0) + counts.get("skipped", 0) == EXAMPLE_CHECKS, proc.stdout[-2000:]
    assert counts.get("passed", 0) > 0 and "failed" not in counts, proc.stdout[-2000:]


def test_the_shipped_suite_fails_a_broken_adapter(venv_python, example_copy, tmp_path):
    """The same folder with a convention error in the adapter (imported from the folder, which
    comes first on sys.path): the suite fails, so the pass above means something."""
    broken = tmp_path / "broken"
    shutil.copytree(example_copy, broken, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    adapter = broken / "freebody_numpy_euler" / "adapter.py"
    text = adapter.read_text()
    assert BREAKAGE[0] in text, "the example's read_state changed: update BREAKAGE"
    adapter.write_text(text.replace(*BREAKAGE))
    proc = _pytest_in(venv_python, broken)
    assert proc.returncode == 1, (proc.returncode, proc.stdout[-2000:], proc.stderr[-2000:])
    counts = _counts(proc.stdout)
    assert counts.get("failed", 0) >= 2, proc.stdout[-2000:]
    assert "test_state_read_back_at_t0_is_the_initial_state" in proc.stdout
