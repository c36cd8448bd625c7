"""Convention self-checks on every engine (a missing engine is a visible skip): t = 0 read-back,
pushes at world and body points, L kept as well as the engine's scheme keeps it, a 150 rad/s spin
not clamped (checked on the orientation)."""
from __future__ import annotations

import pytest

from freebody.adapters.base import load_adapter
from freebody.run.selfcheck import CHECKS, run_check, run_trap_checks


@pytest.mark.parametrize("check", CHECKS)
def test_selfcheck_passes_for_every_integrator(engine, check):
    # what ``freebody conventions`` checks: every offered integrator unless the adapter narrows
    # it to the schemes the checks' bounds are made for (the reference: the engines' semi-implicit
    # maps; Drake: its error-controlled explicit integrators at 1e-10, see selfcheck_integrators)
    integrators = load_adapter(engine).selfcheck_integrators()
    assert integrators
    results = [run_check(check, engine, i) for i in integrators]
    bad = [f"{r.integrator}: {r.detail}" for r in results if not r.passed]
    assert not bad, "; ".join(bad)


def test_checks_can_fail_on_an_integrator_that_breaks_them():
    """euler-matrix drifts L and R: the L and high-spin checks must say so."""
    assert not run_check("torque_free_L", "reference", "euler-matrix").passed
    assert not run_check("high_spin", "reference", "euler-quat").passed


def test_every_trap_check_of_the_engine_passes(engine):
    """The adapter's own trap checks (Adapter.trap_checks): each trap it handles, live."""
    results = run_trap_checks(engine)
    bad = [f"{r.check}: {r.detail}" for r in results if not r.passed]
    assert not bad, "; ".join(bad)
