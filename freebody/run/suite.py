"""Execute a list of runs (in this process, in worker processes or on a dask cluster), show
progress, write results.json and the trajectory files (through :mod:`freebody.results.outdir`: one
writer per output folder, one atomic publish); keep the finished runs on Ctrl-C, SIGTERM, SIGHUP."""
from __future__ import annotations

import contextlib
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from ..envs.facts import convention_rows, engine_facts  # convention_rows: also read from here
from ..errors import InputError
from ..results.document import results_document, trajectory_filename, write_trajectory
from ..results.outdir import OutputFolder, out_folder, output_lock
from . import interrupts
from .progress import ProgressDisplay
from .records import RunOutput, RunSpec

EXECUTORS = ("local", "dask")

if TYPE_CHECKING:  # the pool's module is imported where a pool is made
    from .executor import LocalPool


def engine_versions(engines: list[str]) -> dict[str, str | None]:
    """Installed engine versions (None for an engine that is not installed or fails to import);
    an isolated engine's (:mod:`freebody.envs.engines`) as its environment reports it, another's
    from its cached facts (:mod:`freebody.envs.facts`: no engine import once cached)."""
    from ..envs import engines as engine_envs

    out = {}
    for e in engines:
        if engine_envs.isolated(e):
            out[e] = engine_envs.describe(e).get("version")
            continue
        facts = engine_facts(e)  # missing or broken: None, and its runs say which
        out[e] = facts["version"] if facts is not None else None
    return out


def engine_conventions(engines: list[str]) -> dict[str, list[list[str]]]:
    """engine -> :func:`convention_rows` for each engine whose adapter loads in this environment
    (an isolated engine's, or a missing one's, are left to the report: it says why it has none)."""
    from ..envs import engines as engine_envs

    out = {}
    for e in engines:
        if not engine_envs.isolated(e):
            facts = engine_facts(e)
            if facts is not None:  # missing or broken: engine_versions records None
                out[e] = facts["conventions"]
    return out


def default_jobs() -> int:
    """The default number of worker processes: the number of cores."""
    return os.cpu_count() or 1


def run_specs(specs: list[RunSpec], out_dir: Path | None, engines: list[str],
              progress: bool = True, save_every: int | None = None,
              on_result: Callable[[RunOutput], None] | None = None, *, jobs: int = 1,
              timeout: float | None = None, executor: str = "local", scheduler: str | None = None,
              keep_arrays: bool = False, isolate: bool = True,
              simulated: dict[int, tuple] | None = None, pool=None) -> tuple[dict, list[RunOutput]]:
    """Execute every spec, write results.json and the trajectory files to ``out_dir`` (if not None).

    jobs : worker processes (executor "local"); each run is isolated in a worker process whatever
        ``jobs`` is (``jobs=1``: one worker), so a crash or ``sys.exit`` in an engine fails its run only.
    isolate : False: every run in this process, one after another (``--no-isolation``, for
        debugging: an engine's segfault then ends this process); needs ``jobs=1``, no ``timeout``.
    timeout : per-run time limit, s; a run past it is killed and ``failed`` (needs a worker process).
    executor, scheduler : "local", or "dask" with the address of a dask.distributed scheduler.
    save_every : keep every ``save_every``-th sample in the trajectory files, and the samples of
        each maximum error and of a divergence (None: at most SAVED_SAMPLES evenly spaced, see
        :func:`freebody.results.document.auto_every`; 1: every sample); metrics use every step.
    keep_arrays : give each RunOutput its trajectory, truth and series (else only ``result``).
    simulated : spec index -> (Simulated, the engine it ports or None) for runs already stepped
        (``freebody sweep``'s batches): only judged, with the truths and reference maps of their group.
        None (the default): with the local executor and no ``timeout``, the runs of engines that
        step runs together bit for bit as alone (MJX) are stepped so in this process
        (:mod:`freebody.run.batching`): first, or with ``jobs`` > 1 in a thread beside ``jobs`` - 1
        workers, then judged in the workers: the same results, less time.
    pool : None, or a started :class:`~freebody.run.executor.LocalPool` of ``jobs`` workers to run
        the runs in (``freebody sweep`` starts it before drawing its bodies); the caller closes it.

    Returns (the results.json document, the RunOutputs in spec order); ``on_result`` is called
    with each RunOutput as it finishes.  The numbers do not depend on ``jobs`` or ``executor``.
    ``out_dir`` is locked for the call (another process writing it: InputError); the trajectory
    files go to a folder of this call, ``trajectories/<n>/``, and results.json is published once
    (see :mod:`freebody.results.outdir`).  Specs must be unique (:attr:`RunSpec.key`).
    On KeyboardInterrupt (Ctrl-C) or SIGTERM / SIGHUP (:class:`~freebody.run.interrupts.Interrupted`)
    the workers are stopped, the finished runs are written with ``"incomplete": true`` (none
    finished: results.json is left as it was; a complete previous one is kept as
    results.previous.json) and the interrupt is re-raised.
    """
    from .executor import plan

    check_options(jobs, timeout, save_every, executor, scheduler, isolate, engines)
    _check_unique(specs)
    out_path = out_folder(out_dir) if out_dir is not None else None
    bar = ProgressDisplay(len(specs), enabled=progress)
    local = executor == "local"
    with contextlib.ExitStack() as stack:
        stack.enter_context(interrupts.signals_interrupt())
        if out_path is not None:
            stack.enter_context(output_lock(out_path))  # before any work: a second writer refuses at once
        versions = engine_versions(engines)
        folder = OutputFolder(out_path) if out_path is not None else None
        finished = _Finished(folder, versions, bar, on_result, engine_conventions(engines))
        try:
            stepping = None
            if simulated is None and local and timeout is None:  # a time limit needs a run alone
                from . import batching

                if isolate and jobs > 1:  # stepped here in one of the slots, beside the workers
                    stepping = batching.Background(specs, note=bar.note)
                    stack.callback(stepping.close)
                else:
                    simulated = batching.step_together(specs, note=bar.note, on_steps=bar.steps)
            tasks = plan(specs, simulated=simulated,
                         save_dir=str(folder.trajectory_dir) if folder is not None and local else None,
                         save_every=save_every, ship_saved=folder is not None and not local,
                         keep_arrays=keep_arrays)
            if stepping is not None:
                stepping.gate(tasks)  # each stepped run's task waits for its Simulated
            _execute_tasks(tasks, finished.add, executor=executor, jobs=jobs, timeout=timeout,
                           scheduler=scheduler, engines=engines, isolate=isolate,
                           on_steps=lambda i, done, total: bar.steps(done, total, _label(specs[i])),
                           slot_taken=None if stepping is None else stepping.running, pool=pool)
        except KeyboardInterrupt as e:
            with _interrupts_deferred():
                finished.interrupted(e)
            raise
        with _interrupts_deferred():
            doc = finished.write(incomplete=False)
    return doc, [finished.outputs[i] for i in sorted(finished.outputs)]


def _check_unique(specs: list[RunSpec]) -> None:
    """InputError if two specs are the same run (two runs would share a trajectory file and a
    results.json identity; :func:`freebody.run.matrix.expand` never makes such a list)."""
    seen = set()
    for s in specs:
        if s.key in seen:
            raise InputError(f"case {s.problem.name!r}: the run {s.engine}/{s.integrator}/{s.precision} "
                             f"at dt = {s.dt!r} s is listed twice; each run must be listed once")
        seen.add(s.key)


def check_options(jobs, timeout, save_every, executor: str, scheduler: str | None,
                   isolate: bool = True, engines=()) -> None:
    """InputError naming the command-line option of the first unusable argument of run_specs."""
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise InputError(f"--jobs: must be an integer >= 1, got {jobs!r}")
    if timeout is not None and not (isinstance(timeout, (int, float)) and timeout > 0 and timeout < float("inf")):
        raise InputError(f"--timeout: must be a finite number of seconds > 0, got {timeout!r}")
    if save_every is not None and (not isinstance(save_every, int) or isinstance(save_every, bool)
                                   or save_every < 1):
        raise InputError(f"--save-every: must be 'auto' or an integer >= 1, got {save_every!r}")
    if executor not in EXECUTORS:
        raise InputError(f"--executor: must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if executor == "dask" and engines:
        from ..envs.engines import isolated

        for e in engines:
            if isolated(e):
                raise InputError(f"--executor dask: {e} runs in an isolated environment of its own, "
                                 f"which dask workers do not have (use the local executor)")
    if executor == "dask" and not scheduler:
        raise InputError("--scheduler: missing; --executor dask needs the address of a dask "
                         "scheduler (e.g. tcp://127.0.0.1:8786)")
    if executor != "dask" and scheduler:
        raise InputError("--scheduler: only used with --executor dask")
    if not isolate:
        if engines:
            from ..envs.engines import isolated

            for e in engines:
                if isolated(e):
                    raise InputError(f"--no-isolation: {e} runs in an isolated environment of its own, "
                                     f"in worker processes (drop --no-isolation)")
        for bad, option in ((jobs != 1, f"--jobs {jobs}"), (timeout is not None, "--timeout"),
                            (executor != "local", f"--executor {executor}")):
            if bad:
                raise InputError(f"--no-isolation: runs one run after another in this process; "
                                 f"{option} needs worker processes (drop one of the two)")


class _Finished:
    """The finished runs of one run_specs call, by spec index: each one's trajectory file saved,
    the progress shown, ``on_result`` called; written as results.json on demand.

    Trajectory files are written to this call's own folder (``folder``, an OutputFolder) and
    published with results.json, so a kill at any moment leaves a results.json with the trajectory
    files it names.
    """

    def __init__(self, folder: OutputFolder | None, versions: dict[str, str | None], bar: ProgressDisplay,
                 on_result: Callable[[RunOutput], None] | None, conventions: dict[str, list] | None = None):
        self.folder, self.versions, self.bar, self.on_result = folder, versions, bar, on_result
        self.conventions = conventions  # results.json ``conventions`` (engine_conventions)
        self.runs: dict[int, dict] = {}
        self.outputs: dict[int, RunOutput] = {}

    def add(self, index: int, payload: dict) -> None:
        """A task's payload: its ``result``, and its trajectory and truth (``saved``) when a worker
        elsewhere shipped them (else it saved them itself, its ``trajectory`` the file name in the
        folder) and its arrays when asked for.  A worker's full disk (``environment_error``, see
        :mod:`.worker`) is raised as the OSError it was: the invocation ends, results.json untouched."""
        if payload.get("environment_error"):
            raise OSError(*payload["environment_error"])
        result = payload["result"]
        if self.folder is not None:
            if "saved" in payload:
                name = trajectory_filename(result.to_json())
                write_trajectory(self.folder.trajectory_dir / name, *payload["saved"])  # selected already
                result = replace(result, trajectory=name)
            if result.trajectory:  # relative to the output folder, as results.json stores it
                result = replace(result, trajectory=self.folder.relative(result.trajectory))
        out = RunOutput(result, *(payload.get("arrays") or (None, None, None)))
        self.runs[index] = result.to_json()
        self.outputs[index] = out
        self.bar.update(f"{result.status:8s} {result.case} {result.engine}/{result.integrator} dt={result.dt:g}")
        if self.on_result:
            self.on_result(out)

    def write(self, incomplete: bool) -> dict:
        """The results document of the runs so far; with an output folder, published as results.json."""
        doc = results_document([self.runs[i] for i in sorted(self.runs)], self.versions, incomplete=incomplete,
                               conventions=self.conventions)
        if self.folder is not None:
            self.folder.publish(doc)
        return doc

    def interrupted(self, exc: BaseException) -> None:
        """Write what an interrupt kept (marked incomplete) and say so; with no run finished, leave
        the output folder's results.json as it was."""
        what = f"{interrupts.describe(exc)}: {self.bar.done} of {self.bar.total} runs finished"
        if self.folder is None:
            self.bar.note(what)
            return
        results = self.folder.path / "results.json"
        if not self.runs:
            self.folder.abandon()
            self.bar.note(f"{what}; nothing written" + (f" ({results} is as it was)" if results.exists() else ""))
            return
        self.write(incomplete=True)
        kept = (f"; the previous complete results are kept in {self.folder.path / 'results.previous.json'}"
                if self.folder.kept is not None else "")
        self.bar.note(f"{what}; kept in {results} (marked incomplete){kept}")


def _label(spec: RunSpec) -> str:
    return f"{spec.problem.name} {spec.engine}/{spec.integrator} dt={spec.dt:g}"


def _execute_tasks(tasks: list, on_done: Callable[[int, dict], None], *, executor: str, jobs: int,
                   timeout: float | None, scheduler: str | None, engines: list[str],
                   isolate: bool = True, on_steps: Callable[[int, int, int], None] | None = None,
                   slot_taken: Callable[[], bool] | None = None, pool=None) -> None:
    """Execute the planned tasks, calling ``on_done(index, payload)`` as each finishes: in local
    worker processes (``jobs`` of them, one for ``jobs=1``), on a dask cluster, or in this process
    (``isolate=False``).  ``on_steps(index, done, total)``: a long run's steps so far (local
    workers and this process; not dask's workers).  ``slot_taken``: the local pool's (this process
    steps runs in one of the ``jobs`` slots while it says True)."""
    from .executor import run_serial

    if executor == "dask":
        from .dask_executor import run_dask

        run_dask(tasks, scheduler, timeout, engines, on_done)
    elif pool is not None:  # the caller's, started early; the caller closes it
        pool.run(tasks, on_done, on_steps)
    elif not isolate:
        run_serial(tasks, on_done, on_steps)
    else:
        pool = local_pool(jobs, len(tasks), engines, timeout, slot_taken)
        try:
            pool.run(tasks, on_done, on_steps)
        finally:
            with _interrupts_deferred():  # a second Ctrl-C must not leave workers behind
                pool.close(kill=sys.exc_info()[0] is not None)


def local_pool(jobs: int, runs: int, engines: list[str], timeout: float | None = None,
               slot_taken: Callable[[], bool] | None = None) -> LocalPool:
    """The pool of worker processes that runs ``runs`` runs of ``engines``: ``min(jobs, runs)``
    workers (at least one), each engine in its own interpreter where it has one
    (:func:`freebody.envs.engines.interpreters`), ``timeout`` s a run (None: no limit)."""
    from ..envs.engines import interpreters
    from .executor import LocalPool

    return LocalPool(min(jobs, max(1, runs)), timeout=timeout, engines=engines,
                     interpreters=interpreters(engines), slot_taken=slot_taken)


def _interrupts_deferred():
    """Hold off Ctrl-C, SIGTERM and SIGHUP while results are being written; raise it afterwards."""
    return interrupts.deferred()

