"""Runs of one engine stepped together before they are judged (``freebody run``'s MJX runs).

An engine whose adapter class steps many runs in one program, each run bit for bit as it steps
alone, says so with ``steps_runs_together = True`` and implements the contract's
``step_runs(adapters, steps, on_steps) -> trajectories`` and ``runs_scope(precision)`` (MJX: its
LANES-wide vmapped program, see :mod:`freebody.adapters.mjx_adapter`).  :func:`step_together` builds those runs' adapters in this
process, steps the runs of each (engine, integrator, precision) together, across cases, time steps
and lengths, and returns what each produced as the :class:`~freebody.run.records.Simulated` that
:func:`~freebody.run.execute.execute` would have made of it; :func:`freebody.run.suite.run_specs`
then has them judged in the workers like any run (its ``simulated=`` argument).  Because the
numbers are the one-by-one run's, batching never changes a result; what it changes is the
time: a run's ``wall_time_s`` is its adapter's set-up plus its share of the program's calls and
of the compilation.

Left to be stepped one by one (same numbers, in a worker): runs of an engine that is missing,
fails to load, is not supported in its installed version or runs in an isolated environment; a
run whose adapter cannot be built (it records its own failure there); runs past
:data:`MAX_BATCHED_SAMPLES` (the batched trajectories wait in memory for their judging); and every
run when a per-run time limit is set (``--timeout``: a limit needs the run in a worker of its own)
or the executor is dask.  A run that blows up is that run's divergence (decided when it is judged);
the others in its lanes go on.

Beside the pool.  With worker processes (``--jobs N``, N > 1) :class:`Background` steps them in
a thread of this process instead, in one of the N slots (the pool starts N - 1 workers meanwhile,
``executor.LocalPool(slot_taken=)``), and each stepped run's task waits at a gate
(``executor.Task.ready``) until its group is stepped: the other runs are judged meanwhile, so no
core waits for MJX; the numbers are the same.  With one worker (``--jobs 1``) or none
(``--no-isolation``) the runs are stepped first, as :func:`step_together`.
"""
from __future__ import annotations

import functools
import threading
import time
from dataclasses import replace
from typing import Callable

from .records import RunSpec, Simulated

# At most this many samples of batched runs are held at once (a sample of a Trajectory is 15
# float64, 120 B: 1.5 M samples ~180 MB; the default suite's MJX runs are 1.2 M); later runs go
# one by one.
MAX_BATCHED_SAMPLES = 1_500_000
CLOSE_WAIT_S = 30.0  # Background.close: how long to wait for a program call (or a compilation) to end


def step_together(specs: list[RunSpec], note: Callable[[str], None] | None = None,
                  on_steps: Callable[[int, int, str], None] | None = None,
                  ) -> dict[int, tuple[Simulated, str | None]]:
    """Step the runs of engines with ``steps_runs_together`` among ``specs`` together; spec index ->
    (its Simulated, the engine it ports or None).  ``note``: told one line per group stepped
    (engine/integrator/precision, runs, seconds); ``on_steps(done, total, label)``: a group's
    steps so far (the progress display's line while it steps)."""
    out: dict[int, tuple[Simulated, str | None]] = {}
    for cls, key, chosen in _selection(specs):
        out.update(_step_chosen(cls, key, [(i, specs[i]) for i in chosen], note, on_steps))
    return out


def _selection(specs: list[RunSpec]) -> list[tuple[type, tuple, list[int]]]:
    """[(adapter class, (engine, integrator, precision), spec indices)]: the groups to step
    together, within :data:`MAX_BATCHED_SAMPLES` (in spec order; the runs past it go one by one)."""
    out = []
    budget = MAX_BATCHED_SAMPLES
    classes: dict[str, type | None] = {}
    for key, members in _groups(specs).items():
        engine = key[0]
        if engine not in classes:
            classes[engine] = _lane_class(engine)
        if classes[engine] is None:
            continue
        chosen = []
        for i in members:
            if specs[i].steps + 1 <= budget:
                budget -= specs[i].steps + 1
                chosen.append(i)
        if chosen:
            out.append((classes[engine], key, chosen))
    return out


def _step_chosen(cls, key: tuple, members: list[tuple[int, RunSpec]], note=None, on_steps=None) -> dict:
    """One group of :func:`_selection` stepped together (:func:`_step_group` in the class's
    ``runs_scope``); ``note`` and ``on_steps`` as for :func:`step_together`."""
    engine, integrator, precision = key
    label = f"{len(members)} {engine}/{integrator}/{precision} runs stepped together"
    shown = None if on_steps is None else (lambda done, total: on_steps(done, total, label))
    t0 = time.perf_counter()
    with cls.runs_scope(precision):
        done = _step_group(cls, cls.step_runs, members, shown)
    if note is not None and done:
        note(f"{engine}/{integrator}/{precision}: {len(done)} runs stepped together "
             f"({time.perf_counter() - t0:.1f} s)")
    return done


class _Stopped(Exception):
    """Raised between two calls of a group's program when :meth:`Background.close` asks."""


class Background:
    """:func:`step_together`'s work in a thread of this process, beside the worker pool (``freebody
    run --jobs N``, N > 1: the thread takes one of the N slots, see :meth:`running`), so the
    other runs are judged while these step.  The groups are chosen at once (as
    :func:`step_together` chooses them) and stepped in order; :meth:`gate` holds each planned task
    of a chosen run until its group is stepped, then hands the worker its Simulated (a run whose
    adapter could not be built, or whose group failed, goes one by one: the same numbers).  The
    numbers are the same as :func:`step_together`'s (the same program, the same runs); ``note``
    is called on the caller's thread only (from the gates), never from the stepping thread."""

    def __init__(self, specs: list[RunSpec], note: Callable[[str], None] | None = None):
        self.specs, self.note = specs, note
        self.selection = _selection(specs)
        self.waiting = {i for _, _, chosen in self.selection for i in chosen}
        self.results: dict[int, tuple[Simulated, str | None]] = {}
        self.stepped: set[int] = set()  # chosen runs whose group is done (stepped or not)
        self.notes: list[str] = []  # written by the thread, shown by the caller's thread
        self.stop = False
        self.thread = threading.Thread(target=self._run, name="freebody-step-together", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for cls, key, chosen in self.selection:
                if self.stop:
                    break
                done = _step_chosen(cls, key, [(i, self.specs[i]) for i in chosen],
                                    self.notes.append, self._check_stop)
                self.results.update(done)  # before the runs count as stepped
                self.stepped.update(chosen)
        except Exception as e:  # noqa: BLE001  the runs left go one by one, and record any failure
            self.notes.append(f"stepping runs together stopped ({type(e).__name__}: {e}); the "
                              "runs left are run one by one")
        finally:
            self.stepped.update(self.waiting)

    def _check_stop(self, done: int, total: int, label: str) -> None:
        if self.stop:
            raise _Stopped()

    def running(self) -> bool:
        """Whether the thread still steps (it takes a slot of the pool meanwhile)."""
        return self.thread.is_alive()

    def gate(self, tasks: list) -> None:
        """Hold each task of a chosen run (``executor.Task.ready``) until its group is stepped."""
        for t in tasks:
            if t.index in self.waiting:
                t.ready = functools.partial(self._ready, t)

    def _ready(self, task) -> bool:
        """Whether ``task``'s run is stepped; once it is, the task carries its Simulated (none:
        the run goes one by one) and its gate is lifted."""
        self._show_notes()
        if task.index not in self.stepped:
            return False
        simulated = self.results.get(task.index)
        if simulated is not None:
            task.run = replace(task.run, simulated=simulated)
        task.ready = None
        return True

    def _show_notes(self) -> None:
        while self.notes:
            text = self.notes.pop(0)
            if self.note is not None:
                self.note(text)

    def close(self) -> None:
        """Stop stepping (at the next call of the program) and wait for the thread; show its notes."""
        self.stop = True
        self.thread.join(CLOSE_WAIT_S)
        self._show_notes()


def _groups(specs: list[RunSpec]) -> dict[tuple, list[int]]:
    """(engine, integrator, precision) -> indices of the specs that may be stepped together."""
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(specs):
        if s.integrator != "*":
            groups.setdefault((s.engine, s.integrator, s.precision), []).append(i)
    return groups


def _lane_class(engine: str):
    """The engine's adapter class, or None: not stepping runs together (``steps_runs_together``),
    missing, isolated, failing to load, or not supported in its installed version (its runs then
    go one by one, and a failure is recorded by the run)."""
    from ..adapters.base import is_available, load_adapter, unsupported_version
    from ..adapters.capture import capture_output
    from ..envs.engines import isolated
    from ..envs.facts import engine_facts

    try:
        if isolated(engine) or not is_available(engine):
            return None
        facts = engine_facts(engine)  # cached: an engine that does not step runs together is not imported
        if facts is None or not facts["steps_runs_together"]:
            return None
        with capture_output():
            cls = load_adapter(engine)
        if not cls.steps_runs_together:
            return None
        return None if unsupported_version(cls, cls.engine_version()) else cls
    except Exception:
        return None


def _step_group(cls, step_runs, members: list[tuple[int, RunSpec]], on_steps=None) -> dict[int, tuple]:
    """Build each member's adapter (one that fails is left out: it fails again, recorded, when
    run alone), step them together, and wrap each run's samples as execute() does."""
    version = cls.engine_version()
    built, setup = [], {}
    for i, spec in members:
        t0 = time.perf_counter()
        try:
            adapter = cls(spec.problem, spec.dt, spec.integrator, spec.precision)
        except Exception:
            continue
        built.append((i, spec, adapter))
        setup[i] = time.perf_counter() - t0
    if not built:
        return {}
    try:
        trajectories = step_runs([a for _, _, a in built], [s.steps for _, s, _ in built], on_steps)
    except Exception:  # the runs go one by one instead, and record their own failure
        return {}
    finally:
        for _, _, a in built:
            a.close()
    out = {}
    for (i, spec, a), tr in zip(built, trajectories):
        wall = setup[i] + a.step_time_s + a.compile_time_s
        out[i] = (Simulated(tr, None, "", version, a.settings, wall, a.compile_time_s),
                  cls.compare_with)
    return out
