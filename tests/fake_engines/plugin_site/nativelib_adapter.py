"""A third-party freebody adapter (entry point ``nativelib`` of the distribution
``freebody-nativelib`` beside it) whose engine loads a shared library at import: the module
imports its engine at the top, as the built-in adapters do, so a missing library makes loading
the adapter raise ``OSError`` (see ``nativelib/__init__.py``).

Put this folder on ``PYTHONPATH`` (or ``sys.path``) and freebody's registry finds the engine
through the entry point (``importlib.metadata`` reads the ``.dist-info`` folder).  When the engine
loads, the adapter runs the reference maps under its own name (it subclasses the reference adapter).
"""
from __future__ import annotations

from typing import ClassVar

import nativelib  # noqa: F401  (OSError when its shared library is missing)

from freebody.adapters.reference import ReferenceAdapter


class NativeLibAdapter(ReferenceAdapter):
    name: ClassVar[str] = "nativelib"
    import_name: ClassVar[str] = "nativelib_adapter"
    integrators: ClassVar[tuple[str, ...]] = ("semi-implicit-explicit-gyro", "rk4")

    @classmethod
    def engine_version(cls) -> str:
        return "4.0.0"
