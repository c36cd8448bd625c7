"""Test helpers for projects that test with freebody: regression gates, and the adapter
conformance suite a third-party engine runs from its own tests.

    from freebody.testing import assert_no_regression          # any test runner

    from freebody.testing import AdapterConformance            # pytest
    class TestMyEngine(AdapterConformance):
        engine = "myengine"

- :func:`assert_no_regression` (:mod:`freebody.results.testing`): fail when a run regressed
  against a baseline;
- :class:`AdapterConformance` (:mod:`.conformance`): the checks of the adapter contract, run on
  every integrator and precision the engine offers (docs/adapters.md, "The conformance suite");
- :func:`make_adapter` (a pytest fixture: ``make_adapter(engine, problem, dt, integrator,
  precision=None)`` builds adapters and closes them after the test), :func:`general_problem`,
  :func:`full_inertia` and :func:`assert_same_rotation` (:mod:`.helpers`), for an engine's own
  tests.

Only what needs pytest imports it, on first use: ``assert_no_regression`` and the helpers work
without it.
"""
from __future__ import annotations

from ..results.testing import assert_no_regression
from .helpers import I_FULL, assert_same_rotation, full_inertia, general_problem

__all__ = ["AdapterConformance", "I_FULL", "assert_no_regression", "assert_same_rotation",
           "full_inertia", "general_problem", "make_adapter"]

_NEEDS_PYTEST = ("AdapterConformance", "make_adapter")


def __getattr__(name: str):
    if name in _NEEDS_PYTEST:
        from . import conformance
        return getattr(conformance, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
