"""An engine that really crashes, for the isolation tests: its integrator names say how.

- ``semi-implicit-explicit-gyro``: behaves (the reference map), so a healthy run of this engine
  can sit beside its crashing ones;
- ``segfault``: dereferences a null pointer in step() (SIGSEGV);
- ``abort``: calls ``os.abort()`` in step() (SIGABRT);
- ``sleep``: sleeps far longer than any test's time limit in step().

Registered by the tests in :data:`freebody.adapters.base.ENGINES` as ``crasher``:
``("numpy", "fake_engines.crashing_adapter", "CrashingAdapter")``.
"""
from __future__ import annotations

import ctypes
import os
import time
from typing import ClassVar

from freebody.adapters.base import Adapter
from freebody.adapters.reference import ReferenceAdapter

SLEEP_S = 600.0  # "forever" for a test with a time limit of a second or two

REGISTRY_ENTRY = ("numpy", "fake_engines.crashing_adapter", "CrashingAdapter")


class CrashingAdapter(ReferenceAdapter):
    name: ClassVar[str] = "crasher"
    integrators: ClassVar[tuple[str, ...]] = ("semi-implicit-explicit-gyro", "segfault", "abort", "sleep")

    @classmethod
    def engine_version(cls) -> str:
        return "0-crashing"

    def simulate(self, steps: int):
        if self.integrator in ("segfault", "abort", "sleep"):
            return Adapter.simulate(self, steps)  # the step loop, which crashes in step()
        return super().simulate(steps)

    def read_state(self):
        if self.integrator in ("segfault", "abort", "sleep"):  # never gets past the first step
            s = self.problem.initial
            return s.position.copy(), s.quaternion_wxyz.copy(), s.linear_velocity.copy(), s.angular_velocity.copy()
        return super().read_state()

    def step(self) -> None:
        if self.integrator == "segfault":
            ctypes.string_at(0)  # reads address 0: SIGSEGV
        elif self.integrator == "abort":
            os.abort()
        elif self.integrator == "sleep":
            time.sleep(SLEEP_S)
        super().step()
