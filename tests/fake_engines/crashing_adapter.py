"""An engine that really crashes, for the isolation tests: its integrator names say how.

- ``semi-implicit-explicit-gyro``: behaves (the reference map), so a healthy run of this engine
  can sit beside its crashing ones;
- ``segfault``: dereferences a null pointer in advance() (SIGSEGV);
- ``abort``: calls ``os.abort()`` in advance() (SIGABRT);
- ``sleep``: sleeps far longer than any test's time limit in advance();
- ``exit``: calls ``sys.exit(EXIT_CODE)`` in advance() (SystemExit, not an Exception);
- ``interrupt``: raises KeyboardInterrupt in advance() (as a Ctrl-C during the step would).

Registered by the tests in :data:`freebody.adapters.base.ENGINES` as ``crasher``:
``EngineEntry("numpy", "fake_engines.crashing_adapter", "CrashingAdapter")``.
"""
from __future__ import annotations

import ctypes
import os
import sys
import time
from typing import ClassVar

from freebody.adapters.base import EngineEntry
from freebody.adapters.reference import ReferenceAdapter

SLEEP_S = 600.0  # "forever" for a test with a time limit of a second or two
EXIT_CODE = 4  # what the ``exit`` integrator passes to sys.exit
CRASHES = ("segfault", "abort", "sleep", "exit", "interrupt")

REGISTRY_ENTRY = EngineEntry("numpy", "fake_engines.crashing_adapter", "CrashingAdapter")


class CrashingAdapter(ReferenceAdapter):
    name: ClassVar[str] = "crasher"
    integrators: ClassVar[tuple[str, ...]] = ("semi-implicit-explicit-gyro",) + CRASHES

    @classmethod
    def engine_version(cls) -> str:
        return "0-crashing"

    def prepare(self, steps: int) -> None:
        if self.integrator not in CRASHES:
            super().prepare(steps)

    def advance(self, steps: int):
        if self.integrator == "segfault":
            ctypes.string_at(0)  # reads address 0: SIGSEGV
        elif self.integrator == "abort":
            os.abort()
        elif self.integrator == "sleep":
            time.sleep(SLEEP_S)
        elif self.integrator == "exit":
            sys.exit(EXIT_CODE)
        elif self.integrator == "interrupt":
            raise KeyboardInterrupt
        return super().advance(steps)
