"""The reference integrators of ``reference_impl`` wrapped as an engine, so the harness treats
every engine alike.

Conventions: canonical throughout (no conversion).  Integrators: every name in
``reference_impl.integrators.INTEGRATORS``.  Always available (numpy and numba, both required
dependencies of freebody).  The integrators are whole-trajectory loops from the initial state,
compiled (``reference_impl.compiled``, through ``integrators.simulate``): :meth:`prepare` integrates
the run once and :meth:`advance` hands out its samples.
"""
from __future__ import annotations

from typing import ClassVar

from .. import __version__ as _freebody_version
from ..reference_impl.conventions import Trajectory
from ..reference_impl.integrators import INTEGRATORS, simulate
from .base import Adapter


class ReferenceAdapter(Adapter):
    name: ClassVar[str] = "reference"
    import_name: ClassVar[str] = "numpy"
    integrators: ClassVar[tuple[str, ...]] = tuple(INTEGRATORS)
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (canonical)",
        "angular velocity frame": "world",
        "inertia input": "full 3x3 tensor, body frame",
        "velocity clamp": "none",
        "damping": "none",
        "sleeping": "none",
    }

    @classmethod
    def engine_version(cls) -> str:
        return _freebody_version

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        # the self-checks' expectations are those of the engines' maps
        return tuple(i for i in cls.integrators if i.startswith("semi-implicit"))

    def build(self) -> None:
        self._trajectory: Trajectory | None = None

    def prepare(self, steps: int) -> None:
        self._integrate(self.k + steps)

    def _integrate(self, total: int) -> None:
        if self._trajectory is None or len(self._trajectory) <= total:
            self._trajectory = simulate(self.problem, self.integrator, self.dt, total)

    def advance(self, steps: int) -> Trajectory:
        k0 = self.k
        self._integrate(k0 + steps)
        tr = self._trajectory
        self.k = k0 + steps
        if k0 == 0 and len(tr) == steps + 1:
            return tr
        return tr.tail(k0).head(steps + 1)
