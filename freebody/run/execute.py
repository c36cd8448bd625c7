"""Executing one run: load the engine's adapter, build, step (the engine's output captured), and
hand what it produced to :func:`~freebody.run.judge.judge_run` (a long run: chunk by chunk to a
:class:`~freebody.run.judge.RunJudge`).  Judging, the records and their judgement are
:mod:`freebody.run.judge`'s; this module only steps engines.  Never raises for an engine's failure:
that is the run's status, including an engine that raises SystemExit (calls ``sys.exit``) or
another BaseException; only KeyboardInterrupt goes through (Ctrl-C still interrupts)."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..adapters.base import EngineDiverged, EngineMissing, load_adapter, unsupported_version
from ..adapters.capture import capture_output
from .. import tolerances as tol
from ..reference_impl.truth import truth_chunks
from ..results.document import auto_every
from .judge import (Identification, RunJudge, TruthCache, VsEngine, describe_error, judge_run, no_samples, recorded,
                    run_identity, stepped_engine_pieces, stepped_map_pieces, whole_truth_scales)
from .progress import report_steps
from .records import RunOutput, RunResult, RunSpec, Simulated, Status


def execute(spec: RunSpec, cache: TruthCache | None = None, identify_scheme: bool = True,
            save_every: int | None = None) -> RunOutput:
    """Run one spec; never raises for an engine's failure (that is the run's status), even a
    ``sys.exit()`` inside the engine; KeyboardInterrupt is re-raised.

    What the engine prints on the C level is captured into the result's ``engine_output``.

    A run of more than :data:`~freebody.tolerances.CHUNKED_JUDGING_MIN_STEPS` steps is stepped and
    judged chunk by chunk (:func:`_execute_chunked`; memory bounded by the chunk): its RunOutput
    holds only the samples its trajectory file keeps at stride ``save_every`` (None: automatic,
    :func:`~freebody.results.document.auto_every`), their indices in ``saved_index``.
    """
    with capture_output() as captured:  # importing an engine may print (pybullet's banner)
        cls = _adapter_class(spec.engine)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        capture = cls.output_capture() if isinstance(cls, type) else capture_output()
        with capture as during:
            if chunk_steps(spec.steps) is not None and not isinstance(cls, BaseException):
                out = _execute_chunked(spec, cls, identify_scheme, save_every)
            else:
                out = _execute(spec, cls, cache, identify_scheme)
    captured.lines.extend(during.lines)
    captured.total += during.total
    if captured.total:
        r = out.result
        message = r.message
        if r.status in (Status.FAILED, Status.DIVERGED):
            message = f"{message} [engine printed: {captured.lines[0][:200]}]"
        out = replace(out, result=replace(r, engine_output=captured.summary(), message=message))
    return out


def _adapter_class(engine: str):
    """The engine's adapter class, or the exception that loading it raised (recorded by
    _execute as a skipped or failed run)."""
    try:
        return load_adapter(engine)
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # SystemExit from an engine's import included
        return e


def _execute(spec: RunSpec, cls, cache: TruthCache | None, identify_scheme: bool) -> RunOutput:
    cache = cache or TruthCache()
    pb = spec.problem
    base = run_identity(spec)
    t0 = time.perf_counter()
    if isinstance(cls, EngineMissing):
        return no_samples(base, Status.SKIPPED, str(cls), 0.0)
    if isinstance(cls, BaseException):  # a broken install is a failure, never a skip
        return no_samples(base, Status.FAILED, f"importing the {spec.engine} adapter failed: {describe_error(cls)}",
                              time.perf_counter() - t0)
    version = settings = adapter = None
    try:
        version = cls.engine_version()
        if why := unsupported_version(cls, version):
            return no_samples(base, Status.SKIPPED, why, 0.0, version)
        adapter = cls(pb, spec.dt, spec.integrator, spec.precision)
        settings = adapter.settings
        try:
            trajectory = _simulate(adapter, spec.steps)
        finally:
            adapter.close()
        sim = Simulated(trajectory, None, "", version, settings, time.perf_counter() - t0,
                        adapter.compile_time_s)
    except EngineDiverged as e:
        sim = Simulated(e.trajectory, e.t, e.reason, version, settings, time.perf_counter() - t0,
                        adapter.compile_time_s if adapter is not None else None)
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # an engine calling sys.exit() fails its run, not freebody
        return no_samples(base, Status.FAILED, describe_error(e), time.perf_counter() - t0, version, settings)
    return judge_run(spec, sim, cache, identify_scheme, compare_with=cls.compare_with)


def _simulate(adapter, steps: int):
    """``adapter.simulate(steps)``; a run of more than PROGRESS_PIECE_MIN_STEPS steps in pieces of
    PROGRESS_PIECE_STEPS, its steps done reported to the progress display after each (the samples
    are the one-shot run's bit for bit: the chunks contract, checked by the conformance suite)."""
    if steps <= tol.PROGRESS_PIECE_MIN_STEPS:
        return adapter.simulate(steps)
    return adapter.simulate(steps, tol.PROGRESS_PIECE_STEPS, on_piece=lambda done: report_steps(done, steps))


def chunk_steps(steps: int, min_steps: int | None = None, chunk: int | None = None) -> int | None:
    """The chunk size (steps) a run of ``steps`` steps is judged in, or None: judged whole (see
    tolerances.CHUNKED_JUDGING_MIN_STEPS; ``min_steps`` and ``chunk`` default to those constants)."""
    min_steps = tol.CHUNKED_JUDGING_MIN_STEPS if min_steps is None else min_steps
    return (tol.JUDGE_CHUNK_STEPS if chunk is None else chunk) if steps > min_steps else None


def _execute_chunked(spec: RunSpec, cls, identify_scheme: bool, save_every: int | None,
                     chunk: int | None = None) -> RunOutput:
    """:func:`_execute` and :func:`~freebody.run.judge.judge_run` of a long run, chunk by chunk: a
    first pass over the truth for its maxima over the run (:class:`~freebody.run.metrics.Scales`),
    then the engine stepped with ``Adapter.chunks`` and each chunk judged (:class:`RunJudge`)
    against the truth's chunk (:func:`~freebody.reference_impl.truth.truth_chunks`), the reference
    maps and their runs from one-ulp starts stepped alongside (identification) as the other
    engine's run (a ported engine's comparison).  Nothing of the whole run is kept but the samples
    its trajectory file saves.  The same result as the whole run's to round-off: the numerical
    truth restarts at the chunk joins (see truth_chunks); a run the engine stops early keeps the
    samples of the stride of its actual length (a second pass when the automatic stride differs)."""
    every = save_every if save_every is not None else auto_every(spec.steps + 1)
    out, n = _run_chunked(spec, cls, identify_scheme, every, chunk)
    if save_every is None and n is not None and auto_every(n) != every:  # stopped early by the engine
        out, _ = _run_chunked(spec, cls, identify_scheme, auto_every(n), chunk)
    return out


def _run_chunked(spec: RunSpec, cls, identify_scheme: bool, every: int, chunk: int | None):
    """(RunOutput, samples judged) of one chunked pass (see :func:`_execute_chunked`)."""
    pb, dt, steps = spec.problem, spec.dt, spec.steps
    chunk = chunk or chunk_steps(steps) or tol.JUDGE_CHUNK_STEPS
    base = run_identity(spec)
    t0 = time.perf_counter()
    if isinstance(cls, EngineMissing):
        return no_samples(base, Status.SKIPPED, str(cls), 0.0), None
    version = settings = adapter = None
    try:
        version = cls.engine_version()
        if why := unsupported_version(cls, version):
            return no_samples(base, Status.SKIPPED, why, 0.0, version), None
        adapter = cls(pb, dt, spec.integrator, spec.precision)
        settings = adapter.settings
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # an engine calling sys.exit() fails its run, not freebody
        return no_samples(base, Status.FAILED, describe_error(e), time.perf_counter() - t0, version, settings), None
    stepping = time.perf_counter() - t0
    base = run_identity(spec, settings)
    try:
        scales = whole_truth_scales(spec, chunk)
    except Exception as e:
        adapter.close()
        return no_samples(base, Status.FAILED, f"truth oracle failed: {describe_error(e)}", stepping, version,
                              settings), None
    scheme = identify_scheme and not spec.is_reference
    judge = RunJudge(spec, scales, Identification(spec, stepped_map_pieces(spec, chunk)) if scheme else None,
                     VsEngine(spec, cls.compare_with, stepped_engine_pieces(spec, chunk))
                     if scheme and cls.compare_with else None, every=every)
    truth = truth_chunks(pb, dt, steps, chunk)
    pieces = adapter.chunks(steps, chunk)
    reason, diverged_at = "", None
    try:
        while True:
            t1 = time.perf_counter()
            try:
                piece = next(pieces)
            except StopIteration:
                break
            finally:
                stepping += time.perf_counter() - t1
            judge.feed(piece, next(truth))
            del piece  # not held while the next one is stepped
            report_steps(min(steps, max(0, judge.n - 1)), steps)  # to the progress display (throttled)
    except EngineDiverged as e:
        reason, diverged_at = e.reason, e.t
        if e.trajectory is not None and len(e.trajectory):
            judge.feed(e.trajectory, next(truth), diverged_at)
        elif judge.n:  # no samples of its own: the divergence after the last one
            judge.engine_stopped(e.t)
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # an engine calling sys.exit() fails its run, not freebody
        return no_samples(base, Status.FAILED, describe_error(e), time.perf_counter() - t0, version,
                              adapter.settings), None
    finally:
        adapter.close()
    settings = adapter.settings
    compile_time = adapter.compile_time_s
    if judge.n == 0:
        status = Status.OK if diverged_at is None else Status.DIVERGED
        return no_samples(base, status, reason, stepping, version, settings, diverged_at), None
    fields = judge.outcome(reason)
    result = recorded(RunResult(**run_identity(spec, settings), **fields, wall_time_s=stepping,
                                engine_version=version, engine_settings=settings or {}, compile_time_s=compile_time))
    tr, tr_truth, series, idx = judge.saved()
    return RunOutput(result, tr, tr_truth, series, saved_index=idx), judge.n
