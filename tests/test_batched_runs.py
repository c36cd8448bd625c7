"""MJX runs stepped together (freebody.run.batching, MjxAdapter.step_runs): each run's numbers
are those it gets stepped alone, bit for bit; a blow-up stays its own run's; what cannot be
batched goes one by one (skipped without the ``jax`` extra).

Arrays follow freebody's canonical convention (reference_impl/conventions.py): quaternions
(w, x, y, z) body -> world, COM position/velocity in world (m, m/s), angular velocity in world
(rad/s).  Only Euler is compiled here (the unbatched float64 program, shared with
tests/test_mjx_adapter.py, and the 2-lane float64 and float32 ones), with short horizons.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax", reason="jax not installed (pip install 'freebody[jax]')")
pytest.importorskip("mujoco.mjx", reason="mujoco-mjx not installed (pip install 'freebody[jax]')")

from freebody.adapters import mjx_adapter  # noqa: E402
from freebody.adapters.mjx_adapter import CHUNK_STEPS, MjxAdapter  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402
from freebody.run import batching, execute, expand  # noqa: E402
from freebody.run import suite  # noqa: E402

FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


def _problem(k: int, duration: float = 0.05, spin: float = 1.0) -> Problem:
    """Body k: its own mass, inertia (diagonal unsorted for odd k: another mass-matrix mask),
    start, gravity and a body couple for a while."""
    inertia = np.diag([1.0 + 0.1 * k, 2.0, 3.0 - 0.1 * k]) if k % 2 else np.diag([3.0, 2.0, 1.0 + 0.1 * k])
    loads = (Load(body_torque=[0.1 * k, -0.2, 0.05], start=0.0, end=duration / 2),)
    return Problem(f"b{k}", "", Body(1.0 + 0.2 * k, inertia),
                   InitialState([0.1 * k, 0, 0], [1, 0, 0, 0], [0, 0.1 * k, 0],
                                [0.3 * spin, spin * (1 + 0.1 * k), 0.02]),
                   [0.0, 0.0, -9.81 + 0.01 * k], loads, duration=duration)


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in FIELDS)


@pytest.mark.parametrize("precision, lanes", [("float64", 1), ("float64", 2), ("float32", 2)])
def test_runs_stepped_together_are_the_runs_alone_bit_for_bit(precision, lanes, monkeypatch):
    """More runs than lanes, of different dt and lengths (0 steps, under and over a chunk): a lane
    is refilled mid-way, and every run still has its one-by-one samples exactly (at the default
    width and at a vmapped one)."""
    monkeypatch.setattr(mjx_adapter, "LANES", lanes)
    dts = [0.01, 0.001, 0.005, 0.01, 0.002, 0.001, 0.01, 0.004, 0.001, 0.01]
    steps = [5, 0, CHUNK_STEPS + 3, 40, 7, 2, 12, 1, 30, CHUNK_STEPS]
    assert len(dts) > mjx_adapter.LANES
    problems = [_problem(k) for k in range(len(dts))]
    alone = [MjxAdapter(p, dt, "Euler", precision).simulate(n) for p, dt, n in zip(problems, dts, steps)]
    adapters = [MjxAdapter(p, dt, "Euler", precision) for p, dt in zip(problems, dts)]
    together = MjxAdapter.step_runs(adapters, steps)
    for k, (a, b) in enumerate(zip(alone, together)):
        assert len(b) == steps[k] + 1 and _same(a, b), k
    assert all(a.k == n for a, n in zip(adapters, steps))  # each state moved on as advance moves it
    more = MjxAdapter.step_runs(adapters[:2], [3, 3])  # and continues from there, as a run alone
    single = MjxAdapter(problems[0], dts[0], "Euler", precision)
    single.simulate(steps[0])
    assert _same(more[0], single.simulate(3))


def test_a_blow_up_is_its_own_runs(monkeypatch):
    """A body that turns non-finite in its lane leaves the others' samples as they are alone."""
    monkeypatch.setattr(mjx_adapter, "LANES", 2)
    # Euler at dt 0.01 spinning 50 rad/s about the middle axis: non-finite at t = 1.89 s
    wild = Problem("wild", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                   InitialState([0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0.1, 50.0, 0.0]),
                   [0, 0, 0], duration=5.0)
    problems = [_problem(1), wild, _problem(2)]
    batch = MjxAdapter.simulate_batch(problems, 0.01, 300, "Euler", "float64")
    assert batch.diverged_at_s[1] is not None and batch.diverged_at_s[0] is None is batch.diverged_at_s[2]
    for k in (0, 2):
        assert _same(batch.trajectories[k], MjxAdapter(problems[k], 0.01, "Euler", "float64").simulate(300))


def _spec_results(outputs):
    out = []
    for o in outputs:
        r = o.result.to_json()
        for key in ("wall_time_s", "compile_time_s", "trajectory"):
            r.pop(key, None)
        out.append(r)
    return out


def test_run_specs_steps_mjx_runs_together_with_the_one_by_one_results(monkeypatch):
    """run_specs (this process) steps the MJX runs through step_together once, and every result
    is the one execute() gives the run alone."""
    problems = [_problem(k, duration=0.03) for k in range(3)]
    specs = expand(problems, ["mjx"], ["Euler"], [0.01, 0.005], None, ["float64"])
    calls = []
    real = batching.step_together
    monkeypatch.setattr(batching, "step_together",
                        lambda s, **kw: calls.append(len(s)) or real(s, **kw))
    _, outputs = suite.run_specs(specs, None, ["mjx"], progress=False, isolate=False)
    assert calls == [len(specs)]
    alone = [execute(s) for s in specs]
    assert _spec_results(outputs) == _spec_results(alone)


def test_what_is_not_batched(monkeypatch):
    """The samples budget leaves later runs to go one by one; another engine's run is never
    batched; with --timeout nothing is."""
    problems = [_problem(k, duration=0.02) for k in range(3)]
    specs = expand(problems, ["mjx", "mujoco"], ["Euler"], [0.01], None, ["float64"])
    mjx = [i for i, s in enumerate(specs) if s.engine == "mjx"]
    monkeypatch.setattr(batching, "MAX_BATCHED_SAMPLES", 2 * (specs[mjx[0]].steps + 1))
    done = batching.step_together(specs)
    assert sorted(done) == mjx[:2]

    def refuse(*args, **kwargs):
        raise AssertionError("batched despite a time limit")

    monkeypatch.setattr(batching, "step_together", refuse)
    monkeypatch.setattr(suite, "_execute_tasks", lambda *a, **k: None)
    suite.run_specs(specs, None, ["mjx", "mujoco"], progress=False, timeout=30.0)


def test_background_steps_in_a_thread_what_step_together_steps():
    """batching.Background (freebody run --jobs N > 1) steps the same runs in a thread: each
    planned task of a chosen run waits at its gate until its group is stepped, then carries the
    Simulated step_together gives it, bit for bit; the other engines' tasks have no gate."""
    from freebody.run.executor import plan

    problems = [_problem(k, duration=0.03) for k in range(3)]
    specs = expand(problems, ["mjx", "mujoco"], ["Euler"], [0.01, 0.005], None, ["float64"])
    mjx = {i for i, s in enumerate(specs) if s.engine == "mjx"}
    notes = []
    stepping = batching.Background(specs, note=notes.append)
    tasks = plan(specs)
    stepping.gate(tasks)
    assert {t.index for t in tasks if t.ready is not None} == mjx
    stepping.thread.join(120)
    assert not stepping.running()
    everything = set(range(len(specs)))
    assert all(t.can_start(everything, everything) for t in tasks)  # gates lifted
    assert all(t.ready is None for t in tasks) and len(notes) == 1  # the note, on this thread
    together = batching.step_together(specs)
    assert sorted(together) == sorted(mjx)
    for t in tasks:
        if t.index in mjx:
            assert _same(t.run.simulated[0].trajectory, together[t.index][0].trajectory), t.index
        else:
            assert t.run.simulated is None


def test_the_pool_leaves_a_slot_to_the_stepping(monkeypatch):
    """While this process steps runs (slot_taken), a pool of N starts N - 1 workers; the N-th once
    the stepping ends."""
    from freebody.run import executor

    class FakeWorker:
        def __init__(self, options, python=None):
            self.python, self.task, self.ready = python, None, True

    monkeypatch.setattr(executor, "Worker", FakeWorker)
    stepping = [True]
    pool = executor.LocalPool(2, slot_taken=lambda: stepping[0])
    try:
        tasks = executor.plan(expand([_problem(k) for k in range(3)], ["mujoco"], ["Euler"], [0.01],
                                     None, ["float64"]))
        pool._staff(tasks, set(), set())
        assert len(pool.workers) == 1
        stepping[0] = False
        pool._staff(tasks, set(), set())
        assert len(pool.workers) == 2
    finally:
        pool.workers = []
        pool.close()


@pytest.mark.slow
def test_run_specs_with_workers_steps_mjx_beside_them_with_the_one_by_one_results():
    """jobs=2: the MJX runs are stepped in the parent's Background thread beside one worker,
    then judged by the workers; every result is the one execute() gives the run alone."""
    problems = [_problem(k, duration=0.03) for k in range(2)]
    specs = expand(problems, ["mjx", "mujoco"], ["Euler"], [0.01], None, ["float64"])
    _, outputs = suite.run_specs(specs, None, ["mjx", "mujoco"], progress=False, jobs=2)
    assert _spec_results(outputs) == _spec_results([execute(s) for s in specs])
