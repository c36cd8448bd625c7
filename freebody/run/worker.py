"""A worker process: executes runs sent by :mod:`freebody.run.executor`, one at a time, until told to stop.

Started as ``python -m freebody.run.worker READ_FD WRITE_FD`` in its own process group (so a Ctrl-C
at the terminal reaches only the parent, which stops the workers itself).  It talks to the parent
over two pipes with :class:`multiprocessing.connection.Connection` (pickled messages), never over
stdin/stdout, which the engines may write to.

Messages, parent -> worker:

- ``("init", options)`` once: ``options`` holds ``sys_path`` (list or None), ``engines`` (the
  parent's adapter registry, :data:`freebody.adapters.base.ENGINES`, or None), ``preimport``
  (engine names whose adapters to import up front, as the parent has) and ``store`` (a directory
  where truths are shared between workers, or None);
- ``("run", task)`` for each run: ``task`` is a :class:`RunTask`;
- ``("exit",)``.

Messages, worker -> parent: ``("ready", pid)`` after init; for each run ``("started", index)`` once
its truth is ready and its engine starts, then ``("done", index, payload)`` (see :func:`pack_payload`).

Every run goes through :func:`freebody.run.execute.execute`, exactly as a serial run does.

A file that cannot be written for lack of room (a full disk, a quota, a file size limit, a
read-only file system: :data:`DISK_ERRNOS`) is no run's failure: the payload carries
``environment_error`` ((errno, strerror, filename)) and the parent ends the invocation with it,
leaving the previous results.json as it was.
"""
from __future__ import annotations

import errno
import os
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

from .execute import chunk_steps, execute
from .judge import judge_run as judge

from .records import RunOutput, RunSpec
from .sharedcache import GroupTruthCache
from ..results.document import samples_to_save, trajectory_filename, write_trajectory

# errno values of a write that failed for lack of room or a read-only file system: the environment's
# error, which ends the invocation, not a run's
DISK_ERRNOS = frozenset(e for e in (errno.ENOSPC, errno.EFBIG, getattr(errno, "EDQUOT", None), errno.EROFS)
                        if e is not None)


def environment_error(e: BaseException) -> tuple | None:
    """(errno, strerror, filename) of an OSError in :data:`DISK_ERRNOS`, else None."""
    if isinstance(e, OSError) and e.errno in DISK_ERRNOS:
        return (e.errno, e.strerror, e.filename)
    return None


@dataclass(frozen=True)
class RunTask:
    """One run as sent to a worker.

    index : position of the run in the caller's list of specs (results are ordered by it).
    problem_key : a name of ``spec.problem`` that is stable across processes (e.g. ``"p3"``).
    spec : the run.
    save_dir : directory where the worker writes the trajectory file itself, or None.
    save_every : the stride of the saved samples (None: automatic), see
        :func:`freebody.results.document.samples_to_save` (metrics use every step).
    ship_saved : return the thinned arrays to save (when the caller writes the file itself).
    keep_arrays : return the full trajectory, truth and error series.
    share : write the group's truths to the shared store (pointless for a group of one run).
    simulated : (Simulated, compare_with) of a run stepped elsewhere (a batch: ``freebody sweep``),
        only to be judged here, against the group's truth and reference maps; None: execute it.
    """

    index: int
    problem_key: str
    spec: RunSpec
    save_dir: str | None = None
    save_every: int | None = None
    ship_saved: bool = False
    keep_arrays: bool = False
    share: bool = True
    simulated: tuple | None = None


def samples_for_saving(out: RunOutput, every: int | None):
    """(trajectory, truth, sample indices) of a finished run as its trajectory file keeps them."""
    return samples_to_save(out.trajectory, out.truth, every, out.series, out.result.diverged_at_s,
                           out.saved_index)


def pack_payload(out: RunOutput, task: RunTask) -> dict:
    """The payload of a finished run: ``result`` (RunResult, its ``trajectory`` the file written,
    if any), ``saved`` ((trajectory, truth) thinned, if ``ship_saved``) and ``arrays``
    ((trajectory, truth, series), if ``keep_arrays``)."""
    result = out.result
    payload: dict = {}
    if out.trajectory is not None:
        if task.save_dir is not None:
            rel = trajectory_filename(result.to_json())
            try:
                write_trajectory(Path(task.save_dir) / rel, *samples_for_saving(out, task.save_every))
            except OSError as e:  # say which file (a write error has no file name)
                if e.filename is None:
                    e.filename = str(Path(task.save_dir) / rel)
                raise
            result = replace(result, trajectory=rel)
        elif task.ship_saved:
            payload["saved"] = samples_for_saving(out, task.save_every)
    if task.keep_arrays:
        payload["arrays"] = (out.trajectory, out.truth, out.series, out.saved_index)
    payload["result"] = result
    return payload


def failed_payload(spec: RunSpec, message: str, wall_time_s: float) -> dict:
    """The payload of a run that ended without a result of its own (crash, time limit)."""
    from .judge import no_samples, run_identity
    from .records import Status

    return {"result": no_samples(run_identity(spec), Status.FAILED, message, wall_time_s).result}


class Runner:
    """Executes tasks in this process with a truth cache shared per (case, dt) group.

    started : called with the task's index once its truth is ready and its engine starts.
    """

    def __init__(self, store: str | None = None, started: Callable[[int], None] | None = None):
        self.cache = GroupTruthCache(Path(store) if store else None)
        self.started = started
        self._problems: dict = {}
        self._imported: set[str] = set()  # engines whose adapter this runner imported quietly

    def run(self, task: RunTask) -> dict:
        # one Problem object per key, so the cache (keyed by object) hits across tasks
        problem = self._problems.setdefault(task.problem_key, task.spec.problem)
        spec = replace(task.spec, problem=problem) if problem is not task.spec.problem else task.spec
        self.cache.enter(problem, task.problem_key, spec.dt, spec.steps, share=task.share)
        if spec.engine not in self._imported:  # before its time limit counts, as a worker's start
            import_quietly([spec.engine])
            self._imported.add(spec.engine)
        self._prepare_truth(spec)
        if self.started is not None:
            self.started(task.index)
        if task.simulated is None:
            out = execute(spec, self.cache, save_every=task.save_every)
        else:  # stepped in a batch: judged as execute() judges a run it stepped
            import numpy as np

            sim, compare_with = task.simulated
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                out = judge(spec, sim, self.cache, compare_with=compare_with)
        self.cache.offer(spec, out)
        return pack_payload(out, task)

    def _prepare_truth(self, spec: RunSpec) -> None:
        """Compute (or load) the group's truth before the engine runs, so that the other runs of
        the group can start as soon as it exists.  A failure is left for execute() to record;
        what the oracle prints is discarded."""
        import numpy as np

        from ..adapters.capture import capture_output

        try:
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"), capture_output():
                if chunk_steps(spec.steps) is None:  # a long run computes its truth chunk by chunk
                    self.cache.get(spec.problem, spec.dt, spec.steps)
        except Exception:
            pass


def preimport(engines) -> None:
    """A worker's start: each engine's ``EngineEntry.worker_env`` set where the environment does
    not set it (MuJoCo's import without an OpenGL back-end), then :func:`import_quietly`."""
    from ..adapters.base import UnknownEngine, registry_entry

    for name in engines:
        try:
            for var, value in registry_entry(name).worker_env:
                os.environ.setdefault(var, value)
        except UnknownEngine:  # the run records it
            pass
    import_quietly(engines)


def import_quietly(engines) -> None:
    """Import the adapters of the available engines among ``engines`` with their import banners
    discarded, so that a run's captured engine output does not depend on whether it was the first
    run of its engine in its process (the parent no longer imports them: freebody.envs.facts)."""
    from ..adapters.base import is_available, load_adapter
    from ..adapters.capture import capture_output

    for name in engines:
        try:
            if is_available(name):
                with capture_output():
                    load_adapter(name)
        except Exception:  # the run itself records the failure
            pass


def _plugin_options(options: dict) -> None:
    """The parent's plug-in import limit (``--timeout``) and its probes: the plug-ins it found
    broken, and, in a worker of the parent's interpreter, those it imported (another interpreter,
    an engine's environment, has other packages: it probes a sound one itself)."""
    from ..adapters import base

    if options.get("plugin_import_timeout") is not None:
        base.set_plugin_import_timeout(options["plugin_import_timeout"])
    probes = options.get("plugin_probes") or {}
    if options.get("parent_python") != sys.executable:
        probes = {module: why for module, why in probes.items() if why is not None}
    base.seed_plugin_probes(probes)


def _watch_parent(ppid: int) -> None:
    # a parent killed with SIGKILL cannot stop its workers: they stop themselves
    while True:
        time.sleep(0.5)
        if os.getppid() != ppid:
            os._exit(3)


def main(argv: list[str] | None = None) -> int:
    import signal
    from multiprocessing.connection import Connection

    from .progress import set_step_reporter

    argv = sys.argv[1:] if argv is None else argv
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    conn_in = Connection(int(argv[0]), writable=False)
    conn_out = Connection(int(argv[1]), readable=False)
    threading.Thread(target=_watch_parent, args=(os.getppid(),), daemon=True).start()
    try:
        _, options = conn_in.recv()
    except EOFError:
        return 0
    if options.get("sys_path"):
        sys.path[:] = options["sys_path"]
    if options.get("engines") is not None:
        from ..adapters import base

        base.ENGINES.clear()
        base.ENGINES.update(options["engines"])
    _plugin_options(options)
    preimport(options.get("preimport") or ())
    runner = Runner(options.get("store"), started=lambda index: conn_out.send(("started", index)))
    conn_out.send(("ready", os.getpid()))
    while True:
        try:
            msg = conn_in.recv()
        except EOFError:
            return 0
        if msg[0] == "exit":
            return 0
        task = msg[1]
        t0 = time.perf_counter()
        set_step_reporter(lambda done, total, i=task.index: conn_out.send(("steps", i, done, total)))
        try:
            payload = runner.run(task)
        except BaseException as e:  # a bug outside the engine (execute never raises for the engine's)
            payload = failed_payload(task.spec, f"the worker failed: {type(e).__name__}: {e}",
                                     time.perf_counter() - t0)
            if environment_error(e) is not None:  # a full disk: the parent ends the invocation
                payload["environment_error"] = environment_error(e)
        try:
            conn_out.send(("done", task.index, payload))
        except (BrokenPipeError, OSError):
            return 0


def exit_now(code: int) -> None:
    """End the worker without the interpreter's teardown: its finalizers and module clean-up
    (numba's ~0.2 s, scipy's, the engines') cost ~0.5 s CPU a worker and keep nothing: each run's
    files are written and closed by the run, numba's cache when a function is compiled, the pipes
    need no flush.  Only the standard streams are flushed."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":
    exit_now(main())
