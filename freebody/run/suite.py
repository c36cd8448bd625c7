"""Execute a list of runs (in this process, in worker processes or on a dask cluster), show
progress, write results.json and the trajectory files; keep the finished runs on Ctrl-C."""
from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, TextIO

from ..adapters.base import load_adapter
from ..errors import InputError
from ..results.document import results_document, save_trajectory, trajectory_filename, write_json_atomic
from .records import RunOutput, RunSpec

EXECUTORS = ("local", "dask")


class Progress:
    """A one-line progress display on a terminal, one line per run otherwise (e.g. in CI logs)."""

    def __init__(self, total: int, stream: TextIO | None = None, enabled: bool = True):
        self.total = total
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = self.enabled and self.stream.isatty()
        self.done = 0
        self.t0 = time.perf_counter()

    def update(self, out: RunOutput) -> None:
        self.done += 1
        if not self.enabled:
            return
        r = out.result
        label = f"{r.case} {r.engine}/{r.integrator} dt={r.dt:g}"
        elapsed = time.perf_counter() - self.t0
        line = f"[{self.done}/{self.total}] {elapsed:6.1f}s {r.status:8s} {label}"
        if self.tty:
            self.stream.write("\r\033[K" + line[:150])
            if self.done == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def interrupted(self, where: Path | None) -> None:
        """Say what an interrupt kept."""
        if not self.enabled:
            return
        if self.tty:
            self.stream.write("\n")
        kept = f"; kept in {where} (marked incomplete)" if where is not None else ""
        self.stream.write(f"interrupted: {self.done} of {self.total} runs finished{kept}\n")
        self.stream.flush()


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
    from .executor import LocalPool, plan, run_serial

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

    out_path = Path(out_dir) if out_dir is not None else None
    bar = Progress(len(specs), enabled=progress)
    versions = engine_versions(engines)
    runs: dict[int, dict] = {}
    outputs: dict[int, RunOutput] = {}

    # Trajectory files are written to a staging folder and published with results.json, so a kill
    # at any moment leaves the previous results.json with the trajectory files it names.
    staging = out_path / STAGING if out_path is not None else None

    def on_done(index: int, payload: dict) -> None:
        result = payload["result"]
        if "saved" in payload and staging is not None:
            rel = trajectory_filename(result.to_json())
            tr, truth = payload["saved"]
            save_trajectory(staging, rel, tr, truth, every=1)  # thinned by the worker already
            result = replace(result, trajectory=rel)
        out = RunOutput(result, *(payload.get("arrays") or (None, None, None)))
        runs[index] = result.to_json()
        outputs[index] = out
        bar.update(out)
        if on_result:
            on_result(out)

    def write(incomplete: bool) -> dict:
        doc = results_document([runs[i] for i in sorted(runs)], versions, incomplete=incomplete)
        if out_path is not None:
            _publish_trajectories(out_path)
            write_json_atomic(out_path / "results.json", doc)
        return doc

    local = executor == "local"
    if staging is not None:
        shutil.rmtree(staging, ignore_errors=True)  # left by a run killed with SIGKILL
    tasks = plan(specs, save_dir=str(staging) if staging is not None and local else None,
                 save_every=save_every, ship_saved=out_path is not None and not local,
                 keep_arrays=keep_arrays)
    try:
        if local and jobs == 1 and timeout is None:
            run_serial(tasks, on_done)
        elif local:
            pool = LocalPool(min(jobs, max(1, len(tasks))), timeout=timeout, engines=engines)
            try:
                pool.run(tasks, on_done)
            finally:
                with _interrupts_deferred():  # a second Ctrl-C must not leave workers behind
                    pool.close(kill=sys.exc_info()[0] is not None)
        else:
            from .dask_executor import run_dask

            run_dask(tasks, scheduler, timeout, engines, on_done)
    except KeyboardInterrupt:
        with _interrupts_deferred():
            _remove_partial_trajectories(staging)
            write(incomplete=True)
            bar.interrupted(out_path / "results.json" if out_path is not None else None)
        raise
    with _interrupts_deferred():
        doc = write(incomplete=False)
    return doc, [outputs[i] for i in sorted(outputs)]


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


_TEMPORARY_NPZ = re.compile(r"tmp[a-z0-9_]{8}\.npz")  # tempfile.mkstemp(suffix=".npz") in save_trajectory


def _remove_partial_trajectories(staging: Path | None) -> None:
    """Remove the temporary files of trajectories being written by a killed worker."""
    if staging is None or not (staging / "trajectories").is_dir():
        return
    for p in (staging / "trajectories").iterdir():
        if _TEMPORARY_NPZ.fullmatch(p.name) and "__dt" not in p.name:
            with contextlib.suppress(OSError):
                p.unlink()
