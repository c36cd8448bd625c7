"""The Python API: the same work as ``freebody run``, returning arrays instead of files."""
from __future__ import annotations

from .input.casefile import load_case
from .reference_impl.problem import Problem
from .run import RunOutput, expand, select_engines


def run_case(case: str | Problem, engine: str = "reference", integrator: str | None = None,
             dt: float | None = None, duration: float | None = None,
             precision: str | None = "float64") -> RunOutput | list[RunOutput]:
    """Run a case on one engine.

    case : a bundled case name, a path to a TOML case file, or a Problem.
    integrator : one of the engine's integrators (case-insensitive); None: every one.
    dt : one time step, s; None: the case's default time steps.
    precision : "float64" or "float32" (an engine must offer it: ``Adapter.precisions``);
        None: every precision the engine offers.
    Returns a :class:`RunOutput` (``.result``, ``.trajectory``, ``.truth``, ``.series``) when the
    selection is a single run, else a list of them.
    """
    from .run import TruthCache, execute
    from .run.worker import import_quietly

    problem = case if isinstance(case, Problem) else load_case(case)
    engines = select_engines([engine])
    specs = expand([problem], engines, [integrator] if integrator else None,
                   [dt] if dt is not None else None, duration,
                   [precision] if precision is not None else None)
    import_quietly(engines)  # an adapter's import banner is no run's output (as in freebody run)
    cache = TruthCache()
    outs = [execute(s, cache) for s in specs]
    return outs[0] if len(outs) == 1 else outs
