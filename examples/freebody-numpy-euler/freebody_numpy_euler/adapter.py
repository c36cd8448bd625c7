"""The freebody adapter of the tiny engine in :mod:`.engine` (the worked example of
docs/adapters.md).

What it converts: the engine's scalar-last quaternion (x, y, z, w) to freebody's (w, x, y, z);
freebody's velocities (v, w world) to the engine's momenta (p = M v, L = R I_b R^T w) and back.
What it overrides and records: the engine's dt, gravity and angular damping.  Loads: the
segment's world wrench about the COM, at the state at the start of each step.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from freebody.adapters.base import SteppedAdapter
from freebody.adapters.loads import Segment
from freebody.reference_impl.conventions import quat_wxyz_from_xyzw, quat_xyzw_from_wxyz

from . import __version__
from .engine import SCHEMES, FreeBody, rotation_matrix


class NumpyEulerAdapter(SteppedAdapter):
    name: ClassVar[str] = "numpy-euler"
    import_name: ClassVar[str] = "freebody_numpy_euler"  # the "engine" is this package
    integrators: ClassVar[tuple[str, ...]] = SCHEMES     # ("symplectic", "explicit"): default first
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(x, y, z, w) scalar last, Hamilton, body -> world; reordered",
        "angular velocity frame": "world, derived from L: w = R I_b^-1 R^T L",
        "state": "momenta p (world) and L (world, about the COM); set from v and w",
        "inertia input": "full 3x3 tensor, body frame",
        "external loads": "(force at the COM, torque) world, for the next step only",
        "damping": "angular 0.05 1/s by default; set to 0",
    }

    @classmethod
    def engine_version(cls) -> str:
        return __version__

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        # explicit Euler's quaternion update is not exact for a steady spin: it would fail the
        # high_spin self-check by design, so `freebody conventions` checks the symplectic scheme
        return ("symplectic",)

    def build(self) -> None:
        pb, init = self.problem, self.problem.initial
        defaults = FreeBody(pb.body.mass, pb.body.I_body)  # the engine's own defaults, recorded
        eng = FreeBody(pb.body.mass, pb.body.I_body, scheme=self.integrator, dt=self.dt,
                       gravity=pb.gravity, angular_damping=0.0)
        self.record_setting("dt", defaults.dt, eng.dt)
        self.record_setting("gravity", defaults.gravity, eng.gravity)
        self.record_setting("angular_damping", defaults.angular_damping, eng.angular_damping)

        eng.x = np.array(init.position, dtype=float)
        eng.q = quat_xyzw_from_wxyz(init.quaternion_wxyz)
        R = rotation_matrix(eng.q)
        eng.p = pb.body.mass * np.asarray(init.linear_velocity, dtype=float)
        eng.L = R @ pb.body.I_body @ R.T @ init.angular_velocity
        self.engine = eng

    # --- SteppedAdapter: advance() loops over these ----------------------------------------------
    def apply_loads(self, segment: Segment) -> None:
        if segment.active:  # the engine clears its force and torque after every step
            eng = self.engine
            wrench = segment.wrench(eng.x, rotation_matrix(eng.q))  # (6,) N, N m, world, COM
            eng.apply_force_torque(wrench[:3], wrench[3:])

    def step(self) -> None:
        self.engine.step()

    def read_state(self):
        eng = self.engine
        return (eng.x.copy(), quat_wxyz_from_xyzw(eng.q), eng.p / eng.mass,
                eng.angular_velocity())

    def instability(self) -> str | None:
        warning, self.engine.warning = self.engine.warning, None
        return warning

    # --- optional: the engine's own loop, for `freebody bench` -----------------------------------
    def bare_loop(self, steps: int):
        eng = self.engine

        def loop():
            states = [(eng.x, eng.q, eng.p, eng.L)]
            for _ in range(steps):
                eng.step()
                states.append((eng.x, eng.q, eng.p, eng.L))
            return states
        return loop
