"""Shared fixtures: engines as parameters, from the registry (``freebody.adapters.base``), a missing
engine as a visible skip with its install hint as the reason, the expensive engines marked slow.

A test that takes an argument ``engine`` runs on every registered engine, one taking
``physics_engine`` on every engine but the reference maps.  Modules that parametrise on engines
themselves build their parameters with :func:`engine_param` (``from conftest import ...``).
"""
from __future__ import annotations

import pytest

from freebody.adapters.base import REFERENCE_ENGINE, engine_names, install_hint, is_available
from freebody.reference_impl.problem import Load

# Engines whose every run is expensive: mjx JIT-compiles each integrator and precision (tens of
# seconds on 2 cores), newton each solver (Warp, 5-40 s on a cold kernel cache), brax each pipeline
# and precision (JAX, 1-6 s a program, a few programs per pipeline).  Their parameters
# carry the ``slow`` mark (``pytest -m "not slow"`` leaves them out), and tests that run many
# cases or bodies per engine leave them out (FAST_ENGINES).
SLOW_ENGINES = frozenset({"mjx", "newton", "brax"})


def engine_marks(engine: str) -> list:
    """The marks of a test parameter for this engine: skipped with its install hint when it is not
    installed; ``slow`` when it is one of SLOW_ENGINES."""
    marks = [pytest.mark.skipif(not is_available(engine),
                                reason=f"{engine} not installed ({install_hint(engine)})")]
    if engine in SLOW_ENGINES:
        marks.append(pytest.mark.slow)
    return marks


def engine_param(engine: str, *values, id: str | None = None):
    """``pytest.param(engine, *values)`` with the engine's marks (see :func:`engine_marks`)."""
    return pytest.param(engine, *values, marks=engine_marks(engine), id=id or engine)


ALL_ENGINES = [engine_param(name) for name in engine_names()]
PHYSICS_ENGINES = [p for p in ALL_ENGINES if p.values[0] != REFERENCE_ENGINE]
# Every registered engine but the slow ones (names; installed or not: a missing one is a skipped run)
FAST_ENGINES = [name for name in engine_names() if name not in SLOW_ENGINES]


def pytest_generate_tests(metafunc):
    if "engine" in metafunc.fixturenames:
        metafunc.parametrize("engine", ALL_ENGINES)
    elif "physics_engine" in metafunc.fixturenames:
        metafunc.parametrize("physics_engine", PHYSICS_ENGINES)


@pytest.fixture(scope="session", autouse=True)
def compiled_reference_maps():
    """Compile the reference maps and the engine-equivalent maps once per session, before any test
    times a subprocess: numba caches the machine code on disk (about 5 s cold for each set, 17 s on
    a loaded 2-core machine), so later processes load it in ~0.2 s and no test's time budget
    includes a first compilation."""
    from freebody.reference_impl.engine_maps import ENGINE_MAPS
    from freebody.reference_impl.integrators import INTEGRATORS, simulate
    from freebody.input import load_case

    problem = load_case("offset_push")  # loads of every kind: every kernel variant compiles
    for name in (*INTEGRATORS, *ENGINE_MAPS):
        simulate(problem, name, 0.01, 3)


# One load of each kind, for the adapters' load tests (pybullet, sapien): a force at a body point,
# at a world point and at the COM, a world couple and a body couple.
LOAD_KINDS = {
    "force at a body point": Load(force=(1.0, 2.0, -3.0), body_point=(0.3, -0.1, 0.2)),
    "force at a world point": Load(force=(1.0, 2.0, -3.0), point=(0.0, 0.5, 0.0)),
    "force at the COM": Load(force=(1.0, 2.0, -3.0)),
    "world torque": Load(torque=(0.5, -1.0, 2.0)),
    "body torque": Load(body_torque=(0.5, -1.0, 2.0)),
}
