"""The per-map-run set-up a sweep's identification pays 135 times a body (27 candidate maps x the
run and its four perturbed starts), made cheaper without changing a bit; and the sweep's start-up:
what its parent imports before the workers start, and what the workers wait for."""
import dataclasses
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from freebody.adapters import base
from freebody.envs.facts import FACTS_DIR_VARIABLE
from freebody.reference_impl.compiled import mat, vec
from freebody.reference_impl.problem import Body
from freebody.reference_impl.rotations import matrix_from_quat


def test_one_quaternion_matrix_is_the_batched_one_bit_for_bit():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(500, 4)) * rng.uniform(0.5, 2.0, size=(500, 1))  # not unit: normalised there
    one_by_one = np.array([matrix_from_quat(row) for row in q])
    assert one_by_one.shape == (500, 3, 3)
    assert np.array_equal(one_by_one.view(np.uint64), matrix_from_quat(q).view(np.uint64))


def test_body_inverse_once_and_a_fresh_copy_each_call():
    body = Body(2.0, np.array([[1.0, 0.1, 0.0], [0.1, 2.0, 0.2], [0.0, 0.2, 3.0]]))
    first = body.I_body_inv
    assert np.array_equal(first, np.linalg.inv(body.I_body))
    first[0, 0] = 99.0  # a caller writing to it changes nothing of the body's
    assert np.array_equal(body.I_body_inv, np.linalg.inv(body.I_body))
    other = dataclasses.replace(body, I_body=2.0 * np.eye(3))  # a perturbed start: its own inverse
    assert np.array_equal(other.I_body_inv, 0.5 * np.eye(3))


def test_vec_and_mat_give_python_floats():
    a = np.arange(9.0).reshape(3, 3) / 7.0
    assert mat(a) == tuple(tuple(float(v) for v in row) for row in a)
    assert vec(np.float32([0.1, 2.0, 3.0])) == tuple(float(v) for v in np.float32([0.1, 2.0, 3.0]))
    assert all(type(v) is float for v in vec(a[0]))


# --- start-up: what the parent imports, what the workers wait for ---------------------------------

_BATCH_CLASSES = """
import json, sys
from freebody.envs.facts import engine_facts
from freebody.tools.sweep import _batch_classes
assert engine_facts("mujoco") is not None  # from the cache file the first process wrote
print(json.dumps([sorted(_batch_classes(["mujoco"], progress=True)), "mujoco" in sys.modules]))
"""


@pytest.mark.skipif(not base.is_available("mujoco"), reason="mujoco not installed")
def test_the_parent_of_a_mujoco_sweep_does_not_import_mujoco(tmp_path):
    """With MuJoCo's facts cached, the sweep's parent learns that MuJoCo steps no batch from them
    and leaves its import to the workers (``supports_batch`` in the facts; the parent imported
    MuJoCo, ~0.2 s CPU, before the workers started)."""
    env = {**os.environ, FACTS_DIR_VARIABLE: str(tmp_path)}
    for _ in range(2):  # the first process asks the adapter and writes the facts; the second reads them
        r = subprocess.run([sys.executable, "-c", _BATCH_CLASSES], capture_output=True, text=True,
                           timeout=300, env=env)
        assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1]) == [[], False]


_LOAD_CACHED = """
import sys
sys.path.insert(0, sys.argv[1])
from freebody.reference_impl.compiled_lock import serialize_if_asked
serialize_if_asked()  # the lock named by the environment, as compiled.py's import installs it
import tinymap
tinymap.twice(1.5)
s = tinymap.twice.stats
print(sum(s.cache_misses.values()), sum(s.cache_hits.values()))
"""


def test_a_function_in_the_disk_cache_is_loaded_without_the_compile_lock(tmp_path):
    """A worker of a pool loads a compiled map that numba's disk cache holds without waiting for the
    pool's compile lock (held here by another process for the whole load): two workers starting
    together load their maps side by side, not one after the other.  A miss still waits for the
    lock (test_fixed_costs: two processes compile a function once)."""
    import fcntl

    from freebody.reference_impl.compiled_lock import COMPILE_LOCK_ENV

    (tmp_path / "tinymap.py").write_text("from numba import njit\n\n@njit(cache=True)\n"
                                         "def twice(x):\n    return 2.0 * x\n")
    lock = tmp_path / "compile.lock"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), COMPILE_LOCK_ENV: str(lock)}
    child = [sys.executable, "-c", _LOAD_CACHED, str(tmp_path)]
    first = subprocess.run(child, capture_output=True, text=True, timeout=300, env=env)
    assert first.returncode == 0 and first.stdout.split() == ["1", "0"], first.stderr  # compiled, cached
    with open(lock, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)  # another worker compiling something else
        try:
            second = subprocess.run(child, capture_output=True, text=True, timeout=60, env=env)
        except subprocess.TimeoutExpired:
            pytest.fail("a cached function's load waited for the compile lock")
    assert second.returncode == 0 and second.stdout.split() == ["0", "1"], second.stderr  # loaded


@pytest.mark.skipif(not base.is_available("mujoco"), reason="mujoco not installed")
def test_a_mujoco_body_is_built_with_one_model_compilation(monkeypatch):
    """A sweep body's MuJoCo world costs one XML compilation: the empty model of the recorded
    defaults is compiled once per process, and the full inertia is not compiled first on its own
    (inertial_element's check) when MuJoCo takes it (three compilations a body before, ~1.5 ms)."""
    import mujoco

    from freebody.adapters.mjcf import fullinertia_element, inertial_element
    from freebody.adapters.mujoco_adapter import MujocoAdapter
    from freebody.tools.sweep import SweepSettings, random_bodies

    bodies = random_bodies(SweepSettings(seed=0, count=3, duration=0.1, dts=(0.01,)))
    MujocoAdapter(bodies[0].problem, 0.01, "Euler").close()
    compiled = []
    original = mujoco.MjModel.from_xml_string
    monkeypatch.setattr(mujoco.MjModel, "from_xml_string", lambda xml, *a: compiled.append(xml) or original(xml, *a))
    for b in bodies[1:]:
        MujocoAdapter(b.problem, 0.01, "Euler").close()
    assert len(compiled) == len(bodies[1:])  # one model a body
    monkeypatch.undo()
    for b, xml in zip(bodies[1:], compiled):  # the element inertial_element gives, compiled once
        assert inertial_element(b.problem.body.mass, b.problem.body.I_body) in xml
        assert fullinertia_element(b.problem.body.mass, b.problem.body.I_body) in xml


def test_the_sweep_starts_its_workers_before_it_draws_its_bodies(monkeypatch):
    """``freebody sweep`` starts its pool first (tools.sweep.start_pool), so the workers' imports
    overlap the drawing of the bodies; the pool is the one its runs go to, and it is closed after
    (the code before spawned the workers in run_specs, after the bodies: 0 at the draw)."""
    from freebody.run import executor
    from freebody.tools import sweep as sw

    spawned, at_draw, pools = [], [], []
    real_init, real_draw, real_run = executor.Worker.__init__, sw.random_bodies, executor.LocalPool.run

    def init(self, *a, **k):
        spawned.append(self)
        real_init(self, *a, **k)

    def draw(settings):
        at_draw.append(len(spawned))
        return real_draw(settings)

    def run(self, *a, **k):
        pools.append((self, len(self.workers)))
        return real_run(self, *a, **k)

    monkeypatch.setattr(executor.Worker, "__init__", init)
    monkeypatch.setattr(sw, "random_bodies", draw)
    monkeypatch.setattr(executor.LocalPool, "run", run)
    out = sw.sweep(sw.SweepSettings(seed=3, count=1, duration=0.02, dts=(0.01,)), ["reference"],
                   ["semi-implicit-explicit-gyro"], None, progress=False, jobs=2)
    assert at_draw == [1]  # one run: one worker (min(jobs, runs)), started before the draw
    assert len(pools) == 1 and pools[0][1] == 1 and len(spawned) == 1  # that worker ran the run
    assert pools[0][0].workers == [] and spawned[0].proc.poll() is not None  # closed, exited
    assert [r["status"] for r in out.document["runs"]] == ["ok"]


class _IdleWorker:
    def __init__(self, log, name):
        self.log, self.name, self.task, self.ready = log, name, None, True

    def ask_exit(self):
        self.log.append(("exit", self.name))

    def stop(self, asked=False):
        self.log.append(("wait", self.name, asked))

    def kill(self):
        self.log.append(("kill", self.name))


def test_closing_a_pool_tells_every_idle_worker_to_exit_before_waiting_for_one():
    """Idle workers exit side by side: each is told first, then each is waited for (the code
    before told and waited for one after the other); a busy one is killed."""
    from freebody.run.executor import LocalPool

    log: list = []
    pool = LocalPool(3, share_truths=False)
    busy = _IdleWorker(log, "c")
    busy.task = object()
    pool.workers = [_IdleWorker(log, "a"), _IdleWorker(log, "b"), busy]
    pool.close()
    assert log == [("exit", "a"), ("exit", "b"), ("wait", "a", True), ("wait", "b", True), ("kill", "c")]
    assert pool.workers == []
