"""Executing one run: load the engine's adapter, build, step (the engine's output captured), and
hand what it produced to :func:`~freebody.run.judge.finish`.  Never raises for an engine's failure:
that is the run's status, including an engine that raises SystemExit (calls ``sys.exit``) or
another BaseException; only KeyboardInterrupt goes through (Ctrl-C still interrupts)."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..adapters.base import EngineDiverged, EngineMissing, load_adapter
from ..adapters.capture import capture_output
from .judge import TruthCache, finish
from .records import RunOutput, RunSpec, Simulated, Status, _describe, _identity, _no_trajectory


def execute(spec: RunSpec, cache: TruthCache | None = None, identify_scheme: bool = True) -> RunOutput:
    """Run one spec; never raises for an engine's failure (that is the run's status), even a
    ``sys.exit()`` inside the engine; KeyboardInterrupt is re-raised.

    What the engine prints on the C level is captured into the result's ``engine_output``.
    """
    with capture_output() as captured:  # importing an engine may print (pybullet's banner)
        cls = _adapter_class(spec.engine)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        capture = cls.output_capture() if isinstance(cls, type) else capture_output()
        with capture as during:
            out = _execute(spec, cls, cache, identify_scheme)
    captured.lines.extend(during.lines)
    captured.total += during.total
    if captured.total:
        r = out.result
        message = r.message
        if r.status in (Status.FAILED, Status.DIVERGED):
            message = f"{message} [engine printed: {captured.lines[0][:200]}]"
        out = RunOutput(replace(r, engine_output=captured.summary(), message=message),
                        out.trajectory, out.truth, out.series)
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
    base = _identity(spec)
    t0 = time.perf_counter()
    if isinstance(cls, EngineMissing):
        return _no_trajectory(base, Status.SKIPPED, str(cls), 0.0)
    if isinstance(cls, BaseException):  # a broken install is a failure, never a skip
        return _no_trajectory(base, Status.FAILED, f"importing the {spec.engine} adapter failed: {_describe(cls)}",
                              time.perf_counter() - t0)
    version = settings = adapter = None
    try:
        version = cls.engine_version()
        adapter = cls(pb, spec.dt, spec.integrator, spec.precision)
        settings = adapter.settings
        try:
            trajectory = adapter.simulate(spec.steps)
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
        return _no_trajectory(base, Status.FAILED, _describe(e), time.perf_counter() - t0, version, settings)
    return finish(spec, sim, cache, identify_scheme, compare_with=cls.compare_with)
