"""Execute runs: in this process, or in isolated worker processes, with a time limit per run.

Each run is :func:`freebody.run.execute.execute` of one :class:`~freebody.run.records.RunSpec`; the
executors differ only in where it happens, never in the numbers.

- :func:`run_serial`: in this process, one after another (``--no-isolation``: no isolation).
- :class:`LocalPool`: ``jobs`` long-lived worker processes (``python -m freebody.run.worker``,
  spawned, never forked: forking a process that has imported JAX or an engine is unsafe), each in
  its own process group.  A worker runs one run at a time; a run that crashes its worker (even a
  segfault or ``abort()``) is ``failed`` with the signal, a run past the time limit is killed and
  ``failed``; the worker is replaced and the other runs go on.  Workers are reused across runs.
- :func:`freebody.run.dask_executor.run_dask`: the same tasks on a dask.distributed cluster.

Sharing truths.  :func:`plan` groups the runs by (case, dt, steps), whose truth and reference maps
they share (see :mod:`freebody.run.sharedcache`): a group's first run computes the truth before its
engine starts, and the reference engine's runs of the identification maps produce those maps; the
other runs of the group wait for what they need (other groups' runs fill the time), then read it
from a directory shared by the workers.  Groups start largest first.

Time limit.  A run's limit counts from the moment its truth is ready and its engine starts (or from
when it was sent to its worker, while the truth is being computed).
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Callable

from .judge import scheme_candidates

from .records import RunSpec
from .sharedcache import group_prefix
from .worker import RunTask, Runner, failed_payload

# Cost of a step of the reference engine relative to an engine's step (the reference integrators
# loop in Python): only orders the groups, largest first; the numbers never depend on it.
REFERENCE_STEP_WEIGHT = 20
WORKER_START_ATTEMPTS = 3  # consecutive failures to start a worker before giving up
KILL_WAIT_S = 5.0  # how long to wait for a killed worker to be reaped
SLOT_POLL_S = 0.1  # LocalPool: how often to look for released runs while this process works in a slot

OnDone = Callable[[int, dict], None]  # (index of the run in the caller's specs, payload)


@dataclass
class Task:
    """A run in the plan.

    group : (problem key, dt, steps), the runs sharing a truth.
    truth_of : index of the run whose worker computes the group's truth: this run starts once that
        truth exists (None: this run computes it).
    deps : indices of runs that must finish first (reference runs whose trajectories this run's
        scheme identification reuses).
    ready : None, or whether the run may start yet (a run being stepped in this process meanwhile:
        :class:`freebody.run.batching.Background`, which may replace ``run`` when it says yes).
    """

    run: RunTask
    group: tuple
    deps: frozenset = field(default_factory=frozenset)
    truth_of: int | None = None
    ready: Callable[[], bool] | None = None

    @property
    def index(self) -> int:
        return self.run.index

    def can_start(self, finished: set[int], has_truth: set[int]) -> bool:
        """Whether its dependencies have finished and its group's truth exists."""
        return (self.deps <= finished and (self.truth_of is None or self.truth_of in has_truth)
                and (self.ready is None or self.ready()))


def _needed_references(spec: RunSpec) -> tuple[str, ...]:
    """Reference maps that scheme identification compares this run with (as runner.identify)."""
    if spec.is_reference:
        return ()
    return scheme_candidates(spec.integrator, spec.steps)


def plan(specs: list[RunSpec], simulated: dict | None = None, **run_options) -> list[Task]:
    """Tasks of every spec, ordered: groups (problem, dt, steps) by estimated cost, largest first;
    in a group the run that computes the truth (its first reference run, else its first run), then
    the reference runs that produce identification maps, then the rest, in spec order.  ``run_options`` go to every :class:`~freebody.run.worker.RunTask`;
    ``simulated`` (spec index -> (Simulated, compare_with)) to the runs stepped already (judged only)."""
    keys: dict[int, str] = {}
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(specs):
        pkey = keys.setdefault(id(s.problem), f"p{len(keys)}")
        groups.setdefault((pkey, float(s.dt), int(s.steps)), []).append(i)

    def cost(members):
        return sum(specs[i].steps * (REFERENCE_STEP_WEIGHT if specs[i].is_reference else 1)
                   for i in members)

    tasks: list[Task] = []
    for group, members in sorted(groups.items(), key=lambda kv: -cost(kv[1])):
        producers = {specs[i].integrator: i for i in members
                     if specs[i].is_reference and specs[i].precision == "float64"}
        # the truth's producer needs nothing from the group: a reference run if there is one
        first = min(producers.values(), default=members[0])
        ordered = [first] + [i for i in members if i in producers.values() and i != first] + \
                  [i for i in members if i not in producers.values() and i != first]
        for i in ordered:
            deps = frozenset(producers[n] for n in _needed_references(specs[i]) if n in producers)
            tasks.append(Task(RunTask(i, group[0], specs[i], share=len(members) > 1,
                                      simulated=(simulated or {}).get(i), **run_options),
                              group, deps, None if i == first else first))
    return tasks


def run_serial(tasks: list[Task], on_done: OnDone,
               on_steps: Callable[[int, int, int], None] | None = None) -> None:
    """Execute the tasks in this process, in spec order within the plan's grouping;
    ``on_steps(index, done, total)`` as a long run reports its steps (run/progress.py)."""
    from .progress import set_step_reporter

    first_seen: dict[tuple, int] = {}
    for t in tasks:
        first_seen[t.group] = min(first_seen.get(t.group, t.index), t.index)
    runner = Runner()
    try:
        for t in sorted(tasks, key=lambda t: (first_seen[t.group], t.index)):
            if on_steps is not None:
                set_step_reporter(lambda done, total, i=t.index: on_steps(i, done, total))
            on_done(t.index, runner.run(t.run))
    finally:
        set_step_reporter(None)


# --- worker processes ------------------------------------------------------------------------

def describe_exit(returncode: int | None) -> str:
    """'died with signal SIGSEGV' / 'exited with code 1' for a worker's exit status."""
    if returncode is None:
        return "stopped responding"
    if returncode < 0:
        try:
            return f"died with signal {signal.Signals(-returncode).name}"
        except ValueError:
            return f"died with signal {-returncode}"
    return f"exited with code {returncode}"


class Worker:
    """One worker process and its two pipes.

    python : the interpreter it runs (None: this one; else an isolated engine environment's, which
        holds its own copy of freebody: its ``init`` carries no ``sys_path``)."""

    def __init__(self, options: dict, python: str | None = None):
        r_task, w_task = os.pipe()
        r_res, w_res = os.pipe()
        self.python = python
        environ = os.environ
        if python is not None:  # nothing of this environment on its sys.path: -P, no PYTHONPATH
            from ..envs.build import clean_environ

            options, environ = {**options, "sys_path": None}, clean_environ()
        try:
            self.proc = subprocess.Popen(
                [python or sys.executable, *(["-P"] if python else []), "-m", "freebody.run.worker",
                 str(r_task), str(w_res)],
                pass_fds=(r_task, w_res), stdin=subprocess.DEVNULL, stdout=2,  # stray prints: to stderr
                process_group=0, env={**environ, **options.get("env", {})})
        finally:
            os.close(r_task)
            os.close(w_res)
        self.to_worker = Connection(w_task, readable=False)
        self.from_worker = Connection(r_res, writable=False)
        self.ready = False
        self.task: Task | None = None
        self.started_at = 0.0
        self.group: tuple | None = None
        self.kind: tuple | None = None  # (engine, precision) of its last run
        try:
            self.to_worker.send(("init", options))
        except OSError:  # died at once: seen as EOF on from_worker
            pass

    def send(self, task: Task) -> None:
        self.to_worker.send(("run", task.run))
        self.task, self.group, self.started_at = task, task.group, time.monotonic()
        self.kind = (task.run.spec.engine, task.run.spec.precision)

    def kill(self) -> int | None:
        """Kill the worker (and anything it started) and reap it; its exit status."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        return self.reap()

    def reap(self) -> int | None:
        for c in (self.to_worker, self.from_worker):
            try:
                c.close()
            except OSError:
                pass
        try:
            return self.proc.wait(KILL_WAIT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()

    def ask_exit(self) -> None:
        """Tell an idle worker to exit, without waiting (:meth:`stop` waits)."""
        try:
            self.to_worker.send(("exit",))
        except OSError:
            pass

    def stop(self, asked: bool = False) -> None:
        """Ask an idle worker to exit (unless ``asked`` already); kill it if it does not."""
        if not asked:
            self.ask_exit()
        try:
            self.proc.wait(KILL_WAIT_S)
        except subprocess.TimeoutExpired:
            pass
        self.kill()


class LocalPool:
    """Up to ``jobs`` worker processes, reused across runs and across calls of :meth:`run`.

    timeout : per-run time limit, s, or None; a run past it is killed and ``failed``.
    engines : engines whose adapters the workers import when they start (as the parent has).
    share_truths : share truths and reference maps between workers through a temporary directory
        (not for one worker of this interpreter: it keeps a group's in memory, and the store's files
        cost more to write, a millisecond each, than most of the runs they would serve).
    registry : the adapter registry the workers use (default: this process's,
        :data:`freebody.adapters.base.ENGINES`, so an engine registered at run time works there too).
    slot_taken : None, or whether this process itself works in one of the ``jobs`` slots now
        (:class:`freebody.run.batching.Background` stepping runs): meanwhile one worker fewer is
        started, and the pool looks every ``SLOT_POLL_S`` for the runs that work releases.
    interpreters : engine -> the Python interpreter of its isolated environment
        (:mod:`freebody.envs.engines`): its runs go only to workers running that interpreter; the others to
        workers of this one.  With several interpreters the ``jobs`` workers are shared: an idle
        worker of an interpreter with no run ready is stopped when another has runs ready and no worker.
    """

    def __init__(self, jobs: int, timeout: float | None = None, engines=(), share_truths: bool = True,
                 registry: dict | None = None, interpreters: dict[str, str] | None = None,
                 slot_taken: Callable[[], bool] | None = None):
        from ..adapters import base

        self.interpreters = dict(interpreters or {})
        self.jobs = max(1, int(jobs))
        self.slot_taken = slot_taken  # while it says True, this process works in one of the slots
        self.timeout = timeout
        self.workers: list[Worker] = []
        # one worker (of this interpreter; with other interpreters workers are swapped) runs a
        # group's runs one after another: nothing to share
        share_truths = share_truths and (self.jobs > 1 or bool(self.interpreters))
        self.store = tempfile.mkdtemp(prefix="freebody-truths-") if share_truths else None
        self.options = {"sys_path": list(sys.path), "engines": dict(base.ENGINES if registry is None else registry),
                        "preimport": [e for e in engines if e not in self.interpreters], "store": self.store,
                        "env": {}, "plugin_import_timeout": timeout,
                        # plug-ins probed here: no worker probes them again (see worker._plugin_options)
                        "plugin_probes": base.plugin_probes(), "parent_python": sys.executable}
        if self.store is not None:  # workers compile each numba function once between them
            from ..reference_impl.compiled_lock import COMPILE_LOCK_ENV

            self.options["env"][COMPILE_LOCK_ENV] = os.path.join(self.store, "numba-compile.lock")
        for entry in self.options["engines"].values():
            var = entry.cache_env
            if self.store is not None and var and var not in os.environ:
                # workers share a JIT engine's compiled programs (mjx compiles for seconds per
                # integrator and precision); the cache goes with the store at close()
                self.options["env"][var] = os.path.join(self.store, f"cache-{var.lower()}")
        self._start_failures = 0
        self.on_steps: Callable[[int, int, int], None] | None = None  # set by run()

    # -- the event loop --
    def run(self, tasks: list[Task], on_done: OnDone,
            on_steps: Callable[[int, int, int], None] | None = None) -> None:
        """Execute the tasks; ``on_done(index, payload)`` as each finishes (in completion order),
        ``on_steps(index, steps done, total)`` as a long run reports its steps (run/progress.py)."""
        self.on_steps = on_steps
        pending = list(tasks)
        finished: set[int] = set()
        truth_ready: set[int] = set()  # runs whose truth is computed (reported "started")
        left_in_group: dict[tuple, int] = {}
        for t in tasks:
            left_in_group[t.group] = left_in_group.get(t.group, 0) + 1

        def done(task: Task, payload: dict) -> None:
            finished.add(task.index)
            left_in_group[task.group] -= 1
            if left_in_group[task.group] == 0:
                self._forget_group(task.group)
            on_done(task.index, payload)

        while pending or any(w.task for w in self.workers):
            self._staff(pending, finished, truth_ready)
            if not self.workers:  # no worker could be started: fail what is left, loudly
                for t in pending:
                    done(t, failed_payload(t.run.spec, "could not start a worker process "
                                                       "(see the messages above)", 0.0))
                return
            self._dispatch(pending, finished, truth_ready)
            self._receive(truth_ready, done)
            if self.timeout is not None:
                self._kill_overdue(done)

    def _dispatch(self, pending: list[Task], finished: set[int], truth_ready: set[int]) -> None:
        """Send each idle worker a task it can start now (see _pick), taken off ``pending``."""
        for w in self.workers:
            if w.ready and w.task is None and pending:
                t = self._pick(w, [t for t in pending if self._python(t) == w.python],
                               finished | truth_ready, finished)
                if t is None:
                    continue
                pending.remove(t)
                try:
                    w.send(t)
                except OSError:  # died while idle: run the task elsewhere
                    pending.insert(0, t)
                    w.task = None

    def _receive(self, truth_ready: set[int], done) -> None:
        """Wait for the workers' messages (until the earliest time limit of a busy worker, if
        any) and handle them: "ready", "started" (the truth is ready: the time limit counts from
        here), "done"; a closed pipe is a lost worker."""
        busy = [w for w in self.workers if w.task]
        wait_s = None
        if self.timeout is not None and busy:
            now = time.monotonic()
            wait_s = max(0.0, min(w.started_at + self.timeout for w in busy) - now)
        if self.slot_taken is not None and self.slot_taken():  # runs may be released meanwhile
            wait_s = SLOT_POLL_S if wait_s is None else min(wait_s, SLOT_POLL_S)
        for conn in wait([w.from_worker for w in self.workers], wait_s):
            w = next(w for w in self.workers if w.from_worker is conn)
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                self._lost(w, done)
                continue
            if msg[0] == "ready":
                w.ready = True
                self._start_failures = 0
            elif msg[0] == "started":  # the time limit counts from here
                truth_ready.add(msg[1])
                w.started_at = time.monotonic()
            elif msg[0] == "done":
                task, w.task = w.task, None
                done(task, msg[2])
            elif msg[0] == "steps" and self.on_steps is not None:  # a long run's (index, done, total)
                self.on_steps(*msg[1:])

    def _kill_overdue(self, done) -> None:
        """Kill every worker whose run is past the time limit; the run is ``failed``."""
        now = time.monotonic()
        for w in list(self.workers):
            if w.task is not None and now - w.started_at >= self.timeout:
                task, wall = w.task, now - w.started_at
                w.kill()
                self.workers.remove(w)
                done(task, failed_payload(task.run.spec, f"timed out after {self.timeout:g} s "
                                                         f"(its worker process was killed)", wall))

    def _pick(self, w: Worker, pending: list[Task], has_truth: set[int], finished: set[int]) -> Task | None:
        """The first ready task of the worker's current group with the engine and precision of its
        last run (warm caches: JIT engines compile per precision), else of its current group (the
        truth in memory), else the first ready task."""
        found: dict[int, Task] = {}
        for t in pending:
            if t.can_start(finished, has_truth):
                if t.group == w.group:
                    if (t.run.spec.engine, t.run.spec.precision) == w.kind:
                        return t
                    found.setdefault(1, t)
                else:
                    found.setdefault(2, t)
        return found.get(1) or found.get(2)

    def _python(self, task: Task) -> str | None:
        """The interpreter of the worker a task needs (None: this one)."""
        return self.interpreters.get(task.run.spec.engine)

    def _staff(self, pending: list[Task], finished: set[int], truth_ready: set[int]) -> None:
        """Start workers up to min(jobs, runs pending or running), each for the interpreter whose
        runs have the fewest workers per run left; with every slot taken, stop an idle worker whose
        interpreter has no run ready when another interpreter has runs ready and no worker."""
        left: dict[str | None, int] = {}
        ready: set[str | None] = set()
        has_truth = finished | truth_ready if self.interpreters else set()
        for t in pending:
            py = self._python(t)
            left[py] = left.get(py, 0) + 1
            if self.interpreters and t.can_start(finished, has_truth):
                ready.add(py)
        for w in self.workers:
            if w.task is not None:
                left[w.python] = left.get(w.python, 0) + 1
        jobs = self.jobs - 1 if self.jobs > 1 and self.slot_taken is not None and self.slot_taken() else self.jobs
        if len(self.workers) >= jobs and not any(w.task is None and not w.ready for w in self.workers):
            staffed = {w.python for w in self.workers}
            starved = [py for py in ready if py not in staffed]
            idle = [w for w in self.workers if w.ready and w.task is None and w.python not in ready]
            for _ in starved[:len(idle)]:
                w = idle.pop()
                self.workers.remove(w)
                w.stop()
        while len(self.workers) < min(jobs, sum(left.values())):
            if self._start_failures >= WORKER_START_ATTEMPTS:
                return
            count: dict[str | None, int] = {}
            for w in self.workers:
                count[w.python] = count.get(w.python, 0) + 1
            want = [py for py in left if left[py] > count.get(py, 0)]
            if not want:
                return
            # ready interpreters first, then the one with the fewest workers per run left
            python = min(want, key=lambda py: (py not in ready, count.get(py, 0) / left[py]))
            try:
                self.workers.append(Worker(self.options, python))
            except OSError as e:
                self._start_failures += 1
                sys.stderr.write(f"freebody: warning: cannot start a worker process: {e}\n")

    def _lost(self, w: Worker, done) -> None:
        """A worker's pipe closed: it died (crash) or failed to start."""
        code = w.reap()
        self.workers.remove(w)
        if w.task is not None:
            wall = time.monotonic() - w.started_at
            why = ("killed from outside, e.g. by the kernel when out of memory"
                   if code == -signal.SIGKILL else "a crash in the engine or its adapter")
            done(w.task, failed_payload(w.task.run.spec,
                                        f"the worker process running this run {describe_exit(code)} ({why})",
                                        wall))
        elif not w.ready:
            self._start_failures += 1
            sys.stderr.write(f"freebody: warning: a worker process {describe_exit(code)} while starting\n")

    def _forget_group(self, group: tuple) -> None:
        if self.store is None:
            return
        prefix = group_prefix(*group)
        for p in Path(self.store).glob(prefix + "*"):
            try:
                p.unlink()
            except OSError:
                pass

    def start(self, count: int) -> None:
        """Start up to ``count`` workers (of this interpreter) now, before the runs are known, so
        that their start-up (imports) overlaps the caller's work until :meth:`run` (``freebody
        sweep`` starts them before drawing its bodies).  :meth:`run` uses them as its own."""
        while len(self.workers) < min(self.jobs, count) and self._start_failures < WORKER_START_ATTEMPTS:
            try:
                self.workers.append(Worker(self.options))
            except OSError as e:
                self._start_failures += 1
                sys.stderr.write(f"freebody: warning: cannot start a worker process: {e}\n")

    def close(self, kill: bool = False) -> None:
        """Stop every worker (kill them if ``kill`` or if busy) and remove the shared directory.
        Idle workers are all told to exit first, then waited for: they exit side by side."""
        workers, self.workers = self.workers, []
        idle = [w for w in workers if not (kill or w.task is not None or not w.ready)]
        for w in idle:
            w.ask_exit()
        for w in workers:
            if w in idle:
                w.stop(asked=True)
            else:
                w.kill()
        if self.store is not None:
            shutil.rmtree(self.store, ignore_errors=True)

    def __enter__(self) -> "LocalPool":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(kill=exc_type is not None)
