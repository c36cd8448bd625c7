"""Execute a list of runs (in this process, in worker processes or on a dask cluster), show
progress, write results.json and the trajectory files; keep the finished runs on Ctrl-C."""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import Callable

from ..adapters.base import load_adapter
from ..errors import InputError
from ..results.document import results_document, save_trajectory, trajectory_filename
from ..results.io import is_temporary, write_json_atomic
from .progress import ProgressDisplay
from .records import RunOutput, RunSpec

EXECUTORS = ("local", "dask")


def engine_versions(engines: list[str]) -> dict[str, str | None]:
    """Installed engine versions (None for an engine that is not installed or fails to import)."""
    out = {}
    for e in engines:
        try:
            out[e] = load_adapter(e).engine_version()
        except Exception:  # missing (EngineMissing) or broken: its runs say which
            out[e] = None
    return out


def default_jobs() -> int:
    """The default number of worker processes: the number of cores."""
    return os.cpu_count() or 1


def run_specs(specs: list[RunSpec], out_dir: Path | None, engines: list[str],
              progress: bool = True, save_every: int = 1,
              on_result: Callable[[RunOutput], None] | None = None, *, jobs: int = 1,
              timeout: float | None = None, executor: str = "local", scheduler: str | None = None,
              keep_arrays: bool = False) -> tuple[dict, list[RunOutput]]:
    """Execute every spec, write results.json and the trajectory files to ``out_dir`` (if not None).

    jobs : worker processes (executor "local"); 1 with no ``timeout``: in this process, serially.
    timeout : per-run time limit, s; a run past it is killed and ``failed`` (needs a worker
        process, so ``jobs=1`` with a timeout runs in one worker process).
    executor, scheduler : "local", or "dask" with the address of a dask.distributed scheduler.
    save_every : keep every ``save_every``-th sample in the trajectory files (metrics use all).
    keep_arrays : give each RunOutput its trajectory, truth and series (else only ``result``).

    Returns (the results.json document, the RunOutputs in spec order); ``on_result`` is called
    with each RunOutput as it finishes.  The numbers do not depend on ``jobs`` or ``executor``.
    On KeyboardInterrupt the workers are stopped, the finished runs are written with
    ``"incomplete": true`` and the interrupt is re-raised.
    """
    from .executor import plan

    _check_options(jobs, timeout, save_every, executor, scheduler)
    out_path = Path(out_dir) if out_dir is not None else None
    bar = ProgressDisplay(len(specs), enabled=progress)
    finished = _Finished(out_path, engine_versions(engines), bar, on_result)
    local = executor == "local"
    if finished.staging is not None:
        shutil.rmtree(finished.staging, ignore_errors=True)  # left by a run killed with SIGKILL
    tasks = plan(specs, save_dir=str(finished.staging) if finished.staging is not None and local else None,
                 save_every=save_every, ship_saved=out_path is not None and not local,
                 keep_arrays=keep_arrays)
    try:
        _execute_tasks(tasks, finished.add, executor=executor, jobs=jobs, timeout=timeout,
                       scheduler=scheduler, engines=engines)
    except KeyboardInterrupt:
        with _interrupts_deferred():
            finished.interrupted()
        raise
    with _interrupts_deferred():
        doc = finished.write(incomplete=False)
    return doc, [finished.outputs[i] for i in sorted(finished.outputs)]


def _check_options(jobs, timeout, save_every, executor: str, scheduler: str | None) -> None:
    """InputError naming the command-line option of the first unusable argument of run_specs."""
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise InputError(f"--jobs: must be an integer >= 1, got {jobs!r}")
    if timeout is not None and not (isinstance(timeout, (int, float)) and timeout > 0 and timeout < float("inf")):
        raise InputError(f"--timeout: must be a finite number of seconds > 0, got {timeout!r}")
    if not isinstance(save_every, int) or isinstance(save_every, bool) or save_every < 1:
        raise InputError(f"--save-every: must be an integer >= 1, got {save_every!r}")
    if executor not in EXECUTORS:
        raise InputError(f"--executor: must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    if executor == "dask" and not scheduler:
        raise InputError("--scheduler: missing; --executor dask needs the address of a dask "
                         "scheduler (e.g. tcp://127.0.0.1:8786)")
    if executor != "dask" and scheduler:
        raise InputError("--scheduler: only used with --executor dask")


class _Finished:
    """The finished runs of one run_specs call, by spec index: each one's trajectory file saved,
    the progress shown, ``on_result`` called; written as results.json on demand.

    Trajectory files are written to a staging folder and published with results.json, so a kill
    at any moment leaves the previous results.json with the trajectory files it names.
    """

    def __init__(self, out_path: Path | None, versions: dict[str, str | None], bar: ProgressDisplay,
                 on_result: Callable[[RunOutput], None] | None):
        self.out_path, self.versions, self.bar, self.on_result = out_path, versions, bar, on_result
        self.staging = out_path / STAGING if out_path is not None else None
        self.runs: dict[int, dict] = {}
        self.outputs: dict[int, RunOutput] = {}

    def add(self, index: int, payload: dict) -> None:
        """A task's payload: its ``result``, and its trajectory and truth (``saved``) when a worker
        elsewhere shipped them (else it saved them itself) and its arrays when asked for."""
        result = payload["result"]
        if "saved" in payload and self.staging is not None:
            rel = trajectory_filename(result.to_json())
            tr, truth = payload["saved"]
            save_trajectory(self.staging, rel, tr, truth, every=1)  # thinned by the worker already
            result = replace(result, trajectory=rel)
        out = RunOutput(result, *(payload.get("arrays") or (None, None, None)))
        self.runs[index] = result.to_json()
        self.outputs[index] = out
        self.bar.update(f"{result.status:8s} {result.case} {result.engine}/{result.integrator} dt={result.dt:g}")
        if self.on_result:
            self.on_result(out)

    def write(self, incomplete: bool) -> dict:
        """The results document of the runs so far; with an output folder, its trajectory files
        published and results.json written."""
        doc = results_document([self.runs[i] for i in sorted(self.runs)], self.versions, incomplete=incomplete)
        if self.out_path is not None:
            _publish_trajectories(self.out_path)
            write_json_atomic(self.out_path / "results.json", doc)
        return doc

    def interrupted(self) -> None:
        """Write what an interrupt kept (marked incomplete) and say so."""
        _remove_partial_trajectories(self.staging)
        self.write(incomplete=True)
        kept = f"; kept in {self.out_path / 'results.json'} (marked incomplete)" if self.out_path is not None else ""
        self.bar.note(f"interrupted: {self.bar.done} of {self.bar.total} runs finished{kept}")


def _execute_tasks(tasks: list, on_done: Callable[[int, dict], None], *, executor: str, jobs: int,
                   timeout: float | None, scheduler: str | None, engines: list[str]) -> None:
    """Execute the planned tasks, calling ``on_done(index, payload)`` as each finishes: in this
    process (one job, no timeout), in local worker processes, or on a dask cluster."""
    from .executor import LocalPool, run_serial

    if executor == "dask":
        from .dask_executor import run_dask

        run_dask(tasks, scheduler, timeout, engines, on_done)
    elif jobs == 1 and timeout is None:
        run_serial(tasks, on_done)
    else:
        pool = LocalPool(min(jobs, max(1, len(tasks))), timeout=timeout, engines=engines)
        try:
            pool.run(tasks, on_done)
        finally:
            with _interrupts_deferred():  # a second Ctrl-C must not leave workers behind
                pool.close(kill=sys.exc_info()[0] is not None)


@contextlib.contextmanager
def _interrupts_deferred():
    """Hold off Ctrl-C while results are being written; raise it afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


STAGING = ".staging"  # inside the output folder: trajectory files of the run in progress


def _publish_trajectories(out_path: Path) -> None:
    """Replace ``trajectories/`` by the staged files of this run (the previous run's files go with
    its results.json, which is replaced right after).  Between the two renames and the write of
    results.json a kill can leave the old results.json beside the new files: a window of a few
    system calls, against the whole run otherwise."""
    staged = out_path / STAGING / "trajectories"
    final, old = out_path / "trajectories", out_path / ".trajectories.old"
    if staged.is_dir():
        shutil.rmtree(old, ignore_errors=True)
        if final.exists():
            final.rename(old)
        staged.rename(final)
        shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(out_path / STAGING, ignore_errors=True)


def _remove_partial_trajectories(staging: Path | None) -> None:
    """Remove the temporary files of trajectories being written by a killed worker."""
    if staging is None or not (staging / "trajectories").is_dir():
        return
    for p in (staging / "trajectories").iterdir():
        if is_temporary(p.name):
            with contextlib.suppress(OSError):
                p.unlink()
