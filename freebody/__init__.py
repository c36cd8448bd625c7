"""freebody: cross-validate rigid-body physics engines on the free rigid body.

``import freebody`` imports no physics engine; adapters are loaded lazily when a run needs them.
"""
from __future__ import annotations

__version__ = "0.2.0"


def run_case(case, engine: str = "reference", integrator: str | None = None, dt: float | None = None,
             duration: float | None = None, precision: str = "float64"):
    """Run one case on one engine and return a :class:`freebody.run.records.RunOutput`
    (trajectory arrays, truth, metrics, status).  ``case`` is a bundled case name, a path to a
    TOML file, or a :class:`freebody.reference_impl.problem.Problem`."""
    from .api import run_case as _run_case

    return _run_case(case, engine=engine, integrator=integrator, dt=dt, duration=duration,
                     precision=precision)
