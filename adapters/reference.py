"""The reference integrators of ``reference_impl`` wrapped as an engine, so the harness treats
every engine alike.

Conventions: canonical throughout (no conversion).  Integrators: every name in
``reference_impl.integrators.INTEGRATORS``.  Always available (numpy only).
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
    install_hint: ClassVar[str] = "always installed"
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

    def build(self) -> None:
        self._trajectory: Trajectory | None = None

    def simulate(self, steps: int) -> Trajectory:
        return simulate(self.problem, self.integrator, self.dt, steps)

    # Step-by-step use replays a trajectory integrated on first use (the integrators are
    # whole-trajectory loops); loads are part of the problem, so apply_loads has nothing to do.
    def apply_loads(self, k: int) -> None:
        pass

    def step(self) -> None:
        self.k += 1

    def read_state(self):
        if self._trajectory is None or len(self._trajectory) <= self.k:
            steps = max(self.k, self.problem.steps(self.dt))
            self._trajectory = simulate(self.problem, self.integrator, self.dt, steps)
        tr = self._trajectory
        return (tr.position[self.k].copy(), tr.quaternion_wxyz[self.k].copy(),
                tr.linear_velocity[self.k].copy(), tr.angular_velocity[self.k].copy())
