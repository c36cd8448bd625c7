"""Fixed costs (issue 29 item 1): plug-ins are discovered once per process, and the command line
knows every command without importing what the commands run.  Behaviour only: the CPU figures
are ``freebody bench``'s."""
from __future__ import annotations

import json
import subprocess
import sys
from enum import IntEnum, StrEnum

import numpy as np
import pytest

from freebody.adapters import base
from freebody.results.io import json_safe, json_text


class _EntryPoint:
    name = "countedplug"
    value = "countedplug_adapter:PlugAdapter"


@pytest.fixture
def counted_scan(monkeypatch):
    """``importlib.metadata.entry_points`` replaced by one that counts its calls (a fresh scan)."""
    calls = []

    def entry_points(group):
        calls.append(group)
        return [_EntryPoint()] if group == base.ENTRY_POINT_GROUP else []

    monkeypatch.setattr(base.importlib.metadata, "entry_points", entry_points)
    yield calls
    base.reset_registry()


def test_entry_points_are_scanned_once_per_process(counted_scan):
    for _ in range(3):
        assert "countedplug" in base.registry()
        assert "countedplug" in base.engine_names() and "countedplug" in base.default_engine_names()
        assert base.base_engine("CountedPlug") == "countedplug"
        assert base.install_hint("countedplug") == "install the package of countedplug_adapter"
    assert counted_scan == [base.ENTRY_POINT_GROUP]


def test_reset_and_a_new_import_path_scan_again(counted_scan, tmp_path, monkeypatch):
    base.registry()
    base.reset_registry()
    base.registry()
    assert len(counted_scan) == 2
    monkeypatch.syspath_prepend(str(tmp_path))  # a plug-in's folder joins the import path
    base.registry()
    base.registry()
    assert len(counted_scan) == 3


def test_the_registry_is_a_fresh_dict_each_call(counted_scan):
    """A caller that edits what registry() returns does not edit the cache (nor ENGINES)."""
    base.registry().pop("countedplug")
    base.registry()["mujoco"] = None
    assert "countedplug" in base.registry() and base.registry()["mujoco"] is base.ENGINES["mujoco"]


def test_built_in_entries_are_read_at_each_call(counted_scan, monkeypatch):
    """A test's registry entry (monkeypatch.setitem(ENGINES, ...)) is seen without a reset."""
    base.registry()
    monkeypatch.setitem(base.ENGINES, "extra", base.ENGINES["reference"])
    assert "extra" in base.registry() and len(counted_scan) == 1


# what no command's parser needs: the modules that run, judge, write or render (numpy is allowed:
# `freebody inertia --help` lists reference_impl.massprops.SIZE_DOC, and every run needs numpy)
RUN_TIME_MODULES = ("scipy", "numba", "mujoco", "matplotlib", "freebody.run", "freebody.results",
                    "freebody.report", "freebody.input", "freebody.reference_impl.problem",
                    "freebody.adapters.base")


def test_the_parser_imports_nothing_a_command_runs():
    code = ("import sys; from freebody.cli import build_parser; build_parser(); "
            f"print(sorted(m for m in {RUN_TIME_MODULES!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_every_command_is_in_the_parser_with_its_own_help():
    from freebody.cli import _commands, build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == [name.replace("_", "-") for name in _commands()]
    for name, p in sub.choices.items():
        assert p.format_help().startswith(f"usage: freebody {name}"), name


class _Label(StrEnum):
    OK = "ok"


class _Level(IntEnum):
    TWO = 2


def test_json_text_is_json_dumps_of_json_safe_byte_for_byte():
    """results.json's writer (one walk) writes exactly what json.dumps(json_safe(...), sort_keys,
    indent 1) writes, for every kind of value a document holds, numpy's and non-finite ones too."""
    rng = np.random.default_rng(29)
    doc = {"runs": [{"metrics": dict(zip("abc", rng.normal(size=3))), "ok": True, "n": 3, "none": None,
                     "status": _Label.OK, "level": _Level.TWO, "t": rng.normal(size=(2, 3)),
                     "x": np.float32(0.1), "k": np.int64(-7), "b": np.bool_(False), "s": np.str_("é\n\"")}],
           "odd": [float("nan"), float("inf"), -0.0, 5e-324, 1e300, 10**30, (), [], {}, (1.5, "a"),
                   {2: "int key", "z": [[{}]]}, np.array([np.nan, 1.0]), np.float64(-np.inf)],
           _Label.OK: "enum key", 3: "int key"}
    assert json_text(doc) == json.dumps(json_safe(doc), sort_keys=True, indent=1, allow_nan=False)
    for bad in ({"p": object()}, [{1, 2}]):
        with pytest.raises(TypeError, match="is not JSON serializable"):
            json_text(bad)


@pytest.mark.parametrize("jobs, interpreters, shared", [(1, None, False), (2, None, True),
                                                          (1, {"reference==0": sys.executable}, True)])
def test_one_worker_of_one_interpreter_has_no_shared_store(jobs, interpreters, shared):
    """One worker runs a group's runs one after another (its memory holds the group): writing every
    map to a shared folder would only cost; several workers, or workers swapped between
    interpreters, share through it."""
    from freebody.run.executor import LocalPool

    with LocalPool(jobs, interpreters=interpreters) as pool:
        assert (pool.store is not None) == shared


def test_a_worker_imports_only_what_its_run_needs():
    """A worker running a closed-form case on the reference engine imports no other engine, no
    plotting and no ODE solver (scipy.integrate is the numerical truth's only)."""
    code = ("import sys\n"
            "from freebody.input.casefile import load_case\n"
            "from freebody.run.records import RunSpec\n"
            "from freebody.run.worker import RunTask, Runner\n"
            "r = Runner().run(RunTask(0, 'p0', RunSpec(load_case('dzhanibekov'), 'reference', 'rk4', 0.01, 3)))\n"
            "assert r['result'].status == 'ok', r['result'].message\n"
            "print(sorted(m for m in ('scipy.integrate', 'matplotlib', 'mujoco', 'jax', 'pybullet', 'dartpy',\n"
            "                         'pydrake', 'sapien', 'freebody.report.plots') if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().splitlines()[-1] == "[]"


@pytest.mark.parametrize("jobs, locked", [(1, False), (2, True)])
def test_workers_of_a_shared_pool_are_told_to_compile_once(jobs, locked):
    """Two workers or more get the file of the compile lock (in the pool's store); one gets none."""
    from freebody.reference_impl.compiled_lock import COMPILE_LOCK_ENV
    from freebody.run.executor import LocalPool

    with LocalPool(jobs) as pool:
        got = pool.options["env"].get(COMPILE_LOCK_ENV)
        assert (got is not None) == locked
        if locked:
            assert got.startswith(pool.store)


_COMPILE_ONCE = """
import sys, time
sys.path.insert(0, sys.argv[1])
from freebody.reference_impl import compiled  # installs the lock named by the environment
from numba.core.dispatcher import Dispatcher
assert Dispatcher.compile.lock_path == sys.argv[2]
import tinymap
tinymap.twice(1.5)
s = tinymap.twice.stats
print(sum(s.cache_misses.values()), sum(s.cache_hits.values()))
"""


def test_two_processes_compile_a_function_once(tmp_path):
    """Two processes started together with the lock and one empty numba cache: one compiles the
    function, the other waits and loads it from the cache (1 miss and 1 hit between them; without
    the lock both miss)."""
    import os

    from freebody.reference_impl.compiled_lock import COMPILE_LOCK_ENV

    (tmp_path / "tinymap.py").write_text("from numba import njit\n\n@njit(cache=True)\n"
                                         "def twice(x):\n    return 2.0 * x\n")
    lock = str(tmp_path / "compile.lock")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), COMPILE_LOCK_ENV: lock}
    procs = [subprocess.Popen([sys.executable, "-c", _COMPILE_ONCE, str(tmp_path), lock], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1] for o in outs]
    misses_hits = sorted(tuple(map(int, o[0].split())) for o in outs)
    assert misses_hits == [(0, 1), (1, 0)]


def test_timed_commands_cache_bytecode_as_users_have_it(monkeypatch):
    """The bench times a command with its modules' bytecode cached (as an installation has it),
    even when this environment says not to write bytecode (PYTHONDONTWRITEBYTECODE)."""
    from freebody.tools.bench.core import run_child

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    child = run_child([sys.executable, "-c", "import sys; sys.exit(3 if sys.dont_write_bytecode else 0)"],
                      {"FB_X": "1"})
    assert child.returncode == 0


def test_a_worker_ends_without_teardown_but_flushes_its_streams():
    """exit_now skips the interpreter's teardown (os._exit) with the exit code given and what was
    printed still written."""
    code = ("import sys\nfrom freebody.run.worker import exit_now\n"
            "print('out', end=''); sys.stderr.write('err')\nexit_now(4)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert (r.returncode, r.stdout, r.stderr) == (4, "out", "err")


# --- engine facts: what the parent reads of an adapter, cached (freebody/envs/facts.py) ---------

ENGINE_MODULES = ("mujoco", "jax", "pydrake", "sapien", "pybullet", "dartpy", "warp", "brax")

_ONE_RUN = """
import io, json, sys, contextlib
sys.argv = ["freebody", "run", "dzhanibekov", "--engine", "mujoco", "--integrator", "Euler", "--dt",
            "0.001", "--duration", "0.01", "--no-report", "--quiet", "--jobs", "1", "--out", sys.argv[1]]
from freebody.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main()
print(json.dumps([code, sorted(m for m in sys.modules if m.split(".")[0] in ENGINE_MODULES
                                or m in ("importlib.metadata", "freebody.adapters.mujoco_adapter"))]))
"""


def _one_run(out, env) -> list:
    r = subprocess.run([sys.executable, "-c", f"ENGINE_MODULES = {ENGINE_MODULES!r}\n" + _ONE_RUN, str(out)],
                       capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not base.is_available("mujoco"), reason="mujoco not installed")
def test_a_one_mujoco_run_invocation_imports_no_engine_in_the_parent(tmp_path):
    """With its facts cached (the first invocation wrote them), ``freebody run`` of one MuJoCo run
    imports no engine in the parent process (nor importlib.metadata): only its worker imports
    MuJoCo.  The results are those of the invocation that asked the adapter."""
    import os

    from freebody.results.document import load_results

    env = {**os.environ, "FREEBODY_ENGINE_FACTS_DIR": str(tmp_path / "facts")}
    first = _one_run(tmp_path / "a", env)
    assert first[0] == 0 and "mujoco" in first[1]  # a cold cache: the adapter was asked
    assert len(list((tmp_path / "facts").glob("mujoco-*.json"))) == 1
    second = _one_run(tmp_path / "b", env)
    assert second == [0, []]
    a, b = (load_results(tmp_path / d / "results.json") for d in "ab")
    assert (a["engines"], a["conventions"]) == (b["engines"], b["conventions"])
    drop = ("wall_time_s", "trajectory", "compile_time_s")
    assert [{k: v for k, v in r.items() if k not in drop} for r in a["runs"]] == \
           [{k: v for k, v in r.items() if k not in drop} for r in b["runs"]]


_EXPAND = """
import json, sys
from freebody.input.casefile import load_case
from freebody.run.matrix import expand
from freebody.run.suite import engine_conventions, engine_versions
engines = json.loads(sys.argv[1])
specs = expand([load_case("dzhanibekov")], engines, None, None, 0.01)
print(json.dumps([[(s.engine, s.integrator, s.precision, s.dt) for s in specs], engine_versions(engines),
                  engine_conventions(engines),
                  sorted({m.split(".")[0] for m in sys.modules} & set(ENGINE_MODULES))]))
"""


@pytest.mark.slow  # imports every default engine here (JAX, Drake, SAPIEN): ~4 s quiet, 11 s loaded
def test_the_run_matrix_of_every_engine_is_expanded_from_cached_facts(tmp_path, monkeypatch):
    """Facts written to the cache (here by this process, which imports the adapters) are what a
    later process expands the matrix and records results.json's versions and conventions from,
    without importing any engine: no JAX, Drake or SAPIEN in a process that expands runs of them."""
    import os

    from freebody.envs import facts
    from freebody.run.matrix import expand
    from freebody.run.suite import engine_conventions, engine_versions
    from freebody.input.casefile import load_case

    monkeypatch.setenv(facts.FACTS_DIR_VARIABLE, str(tmp_path))
    monkeypatch.setattr(facts, "_memo", {})
    engines = base.default_engine_names()
    installed = [e for e in engines if base.is_available(e)]
    for e in installed:  # this process's adapters (imported: the live path), written as a miss writes them
        live = facts.engine_facts(e)
        assert live is not None, e
        facts._write(tmp_path / f"{e}-{facts.fingerprint(e, base.registry_entry(e))}.json", live)
    r = subprocess.run([sys.executable, "-c", f"ENGINE_MODULES = {ENGINE_MODULES!r}\n" + _EXPAND,
                        json.dumps(engines)], capture_output=True, text=True, timeout=300,
                       env={**os.environ, facts.FACTS_DIR_VARIABLE: str(tmp_path)})
    assert r.returncode == 0, r.stderr
    runs, versions, conventions, imported = json.loads(r.stdout.strip().splitlines()[-1])
    assert imported == []
    here = expand([load_case("dzhanibekov")], engines, None, None, 0.01)
    assert [tuple(x) for x in runs] == [(s.engine, s.integrator, s.precision, s.dt) for s in here]
    assert versions == engine_versions(engines)
    assert conventions == json.loads(json.dumps(engine_conventions(engines)))


def test_a_stale_or_unreadable_facts_file_is_a_miss(tmp_path, monkeypatch):
    """Only the file of the current fingerprint is read, and only in the current format; an engine
    whose adapter module is imported is asked directly (a test's monkeypatched class is seen)."""
    from freebody.adapters.reference import ReferenceAdapter
    from freebody.envs import facts

    monkeypatch.setenv(facts.FACTS_DIR_VARIABLE, str(tmp_path))
    entry = base.registry_entry("reference")
    key = facts.fingerprint("reference", entry)
    bogus = {**facts.facts_of(ReferenceAdapter), "integrators": ["from-the-file"]}
    (tmp_path / f"reference-{key}.json").write_text(json.dumps({"format": facts.FACTS_FORMAT, "facts": bogus}))
    assert facts._read(tmp_path / f"reference-{key}.json") == bogus
    (tmp_path / "bad.json").write_text(json.dumps({"format": facts.FACTS_FORMAT + 1, "facts": bogus}))
    assert facts._read(tmp_path / "bad.json") is None
    assert facts.engine_facts("reference")["integrators"] == list(ReferenceAdapter.offered_integrators())
    monkeypatch.setattr(ReferenceAdapter, "opt_in_integrators", ("rk4",))
    assert facts.engine_facts("reference")["opt_in"] == ["rk4"]


def test_one_identity_of_a_run_for_specs_results_and_compare():
    """RunSpec.key, RunResult.key and compare's run_key are the same tuple (one helper's order)."""
    from freebody.input.casefile import load_case
    from freebody.results.compare import run_key
    from freebody.run.judge import no_samples, run_identity
    from freebody.run.records import RunSpec, Status

    spec = RunSpec(load_case("dzhanibekov"), "reference", "rk4", 0.01, 3, "float64")
    result = no_samples(run_identity(spec), Status.SKIPPED, "not run", 0.0).result
    assert spec.key == result.key == run_key(result.to_json()) == ("dzhanibekov", "reference", "rk4", "float64", 0.01)


def test_the_file_lock_waits_for_another_process_and_says_so(tmp_path):
    """results.io.file_lock (the shared store's and the environments' lock): a second process waits
    while the first holds it, ``waiting`` told once."""
    from freebody.results.io import file_lock

    lock = tmp_path / "x.lock"
    hold = ("import sys, time\nfrom freebody.results.io import file_lock\n"
            "with file_lock(__import__('pathlib').Path(sys.argv[1])):\n"
            "    print('held', flush=True); time.sleep(1.0)\n"
            "    open(sys.argv[1] + '.done', 'w').close()  # still holding it\n")
    p = subprocess.Popen([sys.executable, "-c", hold, str(lock)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    told = []
    with file_lock(lock, waiting=lambda: told.append(1)):
        assert (tmp_path / "x.lock.done").exists()  # the holder was done before the block ran
    p.wait(timeout=60)
    assert told == [1]
    with file_lock(lock, waiting=lambda: told.append(2)):
        pass
    assert told == [1]


@pytest.mark.skipif(not base.is_available("mujoco"), reason="mujoco not installed")
@pytest.mark.parametrize("user_setting, expected", [(None, "disable"), ("glfw", "glfw")])
def test_a_worker_imports_mujoco_without_its_opengl_back_end(user_setting, expected):
    """A worker's MuJoCo is imported with MUJOCO_GL=disable (EngineEntry.worker_env: no glfw, which
    no run needs), unless the user's environment sets MUJOCO_GL: theirs is kept."""
    import os

    code = ("import os, sys\nfrom freebody.run.worker import preimport\npreimport(['mujoco'])\n"
            "print(os.environ.get('MUJOCO_GL'), 'mujoco' in sys.modules, 'glfw' in sys.modules)\n")
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    if user_setting is not None:
        env["MUJOCO_GL"] = user_setting
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    gl, imported, glfw = r.stdout.split()
    assert (gl, imported) == (expected, "True")
    if user_setting is None:
        assert glfw == "False"


@pytest.mark.skipif(not base.is_available("pybullet"), reason="pybullet not installed")
def test_an_engine_first_imported_by_its_run_keeps_its_banner_out_of_the_run(tmp_path):
    """With the facts cached nothing imports PyBullet before its first run (which prints a build
    banner when imported): the Python API and a serial runner import it quietly first, so the run's
    engine_output is what the engine printed while running, as in a worker."""
    import os

    code = ("import sys\nfrom freebody.api import run_case\n"
            "out = run_case('dzhanibekov', 'pybullet', 'multibody', dt=0.01, duration=0.02)\n"
            "print(repr(out.result.engine_output))\n")
    env = {**os.environ, "FREEBODY_ENGINE_FACTS_DIR": str(tmp_path)}
    outs = []
    for _ in range(2):  # the first asks the adapter (imported: its banner discarded), the second the cache
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
        assert r.returncode == 0, r.stderr
        outs.append(r.stdout.strip().splitlines()[-1])
    assert list(tmp_path.glob("pybullet-*.json")) and outs == ["[]", "[]"]
