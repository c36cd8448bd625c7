"""Adapter conformance on every registered engine: one subclass of the shipped suite
(:class:`freebody.testing.AdapterConformance`, its docstring lists the checks) per engine of the
registry (``engine_names()``: the built-ins and any entry-point engine installed), generated here,
so a new engine runs through it without being named.

Each class carries its engine's marks (``conftest.engine_marks``): skipped with the install hint
when the engine is not installed, ``slow`` for SLOW_ENGINES.  Select one engine with ``-k``
(``pytest tests/test_adapter_conformance.py -k mujoco``).
"""
from __future__ import annotations

import re

from conftest import engine_marks
from freebody.adapters.base import engine_names
from freebody.testing import AdapterConformance


def class_name(engine: str) -> str:
    """``Test`` + the engine's name in CamelCase: ``numpy-euler`` -> ``TestNumpyEuler``."""
    return "Test" + "".join(part[:1].upper() + part[1:] for part in re.split(r"[^0-9A-Za-z]+", engine))


def conformance_class(engine: str) -> type[AdapterConformance]:
    return type(class_name(engine), (AdapterConformance,),
                {"engine": engine, "pytestmark": engine_marks(engine), "__module__": __name__,
                 "__doc__": f"The conformance suite on {engine}."})


for _engine in engine_names():
    globals()[class_name(_engine)] = conformance_class(_engine)
del _engine
