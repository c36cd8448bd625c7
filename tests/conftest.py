"""Shared fixtures: engines as parameters, a missing engine as a visible skip with its reason."""
from __future__ import annotations

import importlib.util

import pytest

from freebody.adapters.base import ENGINES, install_hint


def _requires(engine: str):
    import_name = ENGINES[engine][0]
    missing = importlib.util.find_spec(import_name) is None
    return pytest.mark.skipif(missing, reason=f"{engine} not installed ({install_hint(engine)})")


ALL_ENGINES = [pytest.param(name, marks=_requires(name), id=name) for name in ENGINES]
PHYSICS_ENGINES = [p for p in ALL_ENGINES if p.values[0] != "reference"]


def pytest_generate_tests(metafunc):
    if "engine" in metafunc.fixturenames:
        metafunc.parametrize("engine", ALL_ENGINES)
    elif "physics_engine" in metafunc.fixturenames:
        metafunc.parametrize("physics_engine", PHYSICS_ENGINES)
