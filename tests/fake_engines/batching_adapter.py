"""A small numpy engine that steps bodies as a batch (``supports_batch``), for the tests of the
harness's batching path (``freebody.tools.sweep``) and of the conformance checks.

Registered by the tests in :data:`freebody.adapters.base.ENGINES` as ``batcher``
(:data:`REGISTRY_ENTRY`); never by freebody itself.

The map (one step of h, for B bodies at once): semi-implicit Euler with an explicit gyroscopic
term in the body frame and a first-order quaternion update, renormalised::

    v+ = v + h (f / M + g);  x+ = x + h v+
    w_b = R^T w;  w_b+ = w_b + h I^-1 (R^T tau - w_b x I w_b)
    q+ = normalise(q + h/2 q (0, w_b+));  w+ = R(q+) w_b+

with the wrench (f, tau about the COM, world) of the step's load segment at the state at the start
of the step.  Only elementwise operations (+, -, *, /, sqrt: correctly rounded in IEEE 754) touch
the state, so a body's numbers do not depend on the batch it is stepped in: ``simulate_batch``
equals ``simulate`` of each body alone, bit for bit.  Every ``simulate_batch`` call is recorded
in :attr:`BatchingAdapter.batch_calls`.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from freebody.adapters.base import BatchRun, EngineEntry, SteppedAdapter, UnsupportedOption
from freebody.adapters.loads import LoadSchedule, Segment
from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.problem import Problem

REGISTRY_ENTRY = EngineEntry("numpy", "fake_engines.batching_adapter", "BatchingAdapter",
                             "part of freebody's test suite (tests/fake_engines)")

INTEGRATOR = "semi-implicit-quat"


# --- the map, elementwise over a leading batch axis ---------------------------------------------

def _mv(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v for (B, 3, 3) A and (B, 3) v, as explicit sums of products."""
    return A[:, :, 0] * v[:, None, 0] + A[:, :, 1] * v[:, None, 1] + A[:, :, 2] * v[:, None, 2]


def _mtv(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A^T v for (B, 3, 3) A and (B, 3) v."""
    return A[:, 0, :] * v[:, None, 0] + A[:, 1, :] * v[:, None, 1] + A[:, 2, :] * v[:, None, 2]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for (B, 3) arrays."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=-1)


def _matrix(q: np.ndarray) -> np.ndarray:
    """R(q) (B, 3, 3) body -> world for unit (B, 4) quaternions (w, x, y, z)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


class _State:
    """B bodies: their constants and state arrays (leading axis B)."""

    def __init__(self, problems: list[Problem], dt: float):
        self.h = float(dt)
        self.M = np.array([pb.body.mass for pb in problems])[:, None]             # (B, 1) kg
        self.I = np.stack([np.array(pb.body.I_body) for pb in problems])          # (B, 3, 3)
        self.I_inv = np.stack([pb.body.I_body_inv for pb in problems])            # (B, 3, 3)
        self.g = np.stack([np.array(pb.gravity) for pb in problems])              # (B, 3)
        self.x = np.stack([np.array(pb.initial.position) for pb in problems])     # (B, 3) m
        self.q = np.stack([np.array(pb.initial.quaternion_wxyz) for pb in problems])  # (B, 4)
        self.v = np.stack([np.array(pb.initial.linear_velocity) for pb in problems])  # (B, 3)
        self.w = np.stack([np.array(pb.initial.angular_velocity) for pb in problems])  # (B, 3) world
        self.f = np.zeros_like(self.x)    # (B, 3) N world, the next step's force
        self.tau = np.zeros_like(self.x)  # (B, 3) N m world, the next step's torque about the COM

    def set_loads(self, i: int, seg: Segment) -> None:
        """Body i's wrench for the next step, at its current state."""
        if not seg.active:
            self.f[i] = 0.0
            self.tau[i] = 0.0
            return
        wrench = seg.wrench(self.x[i], _matrix(self.q[i:i + 1])[0])
        self.f[i], self.tau[i] = wrench[0:3], wrench[3:6]

    def step(self) -> None:
        h = self.h
        R = _matrix(self.q)
        self.v = self.v + h * (self.f / self.M + self.g)
        self.x = self.x + h * self.v
        wb = _mtv(R, self.w)
        gyro = _cross(wb, _mv(self.I, wb))
        wb = wb + h * _mv(self.I_inv, _mtv(R, self.tau) - gyro)
        qw, qx, qy, qz = self.q[:, 0], self.q[:, 1], self.q[:, 2], self.q[:, 3]
        ax, ay, az = wb[:, 0], wb[:, 1], wb[:, 2]
        dq = np.stack([-qx * ax - qy * ay - qz * az,       # q (0, w_b): Hamilton product
                       qw * ax + qy * az - qz * ay,
                       qw * ay - qx * az + qz * ax,
                       qw * az + qx * ay - qy * ax], axis=-1)
        q = self.q + (0.5 * h) * dq
        n = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2] + q[:, 3] * q[:, 3])
        self.q = q / n[:, None]
        self.w = _mv(_matrix(self.q), wb)
        self.f[:] = 0.0
        self.tau[:] = 0.0


class BatchingAdapter(SteppedAdapter):
    name: ClassVar[str] = "batcher"
    import_name: ClassVar[str] = "numpy"
    integrators: ClassVar[tuple[str, ...]] = (INTEGRATOR,)
    precisions: ClassVar[tuple[str, ...]] = ("float64",)
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (canonical)",
        "angular velocity frame": "world",
        "batching": "simulate_batch steps B bodies at once, elementwise (bit-identical to single runs)",
    }
    # every simulate_batch call: {"bodies": B, "dt", "steps", "integrator", "precision"}
    batch_calls: ClassVar[list[dict]] = []

    @classmethod
    def engine_version(cls) -> str:
        return "0-batching"

    supports_batch: ClassVar[bool] = True

    # --- one body (B = 1) ---------------------------------------------------------------------
    def build(self) -> None:
        self._s = _State([self.problem], self.dt)
        self.record_setting("batch axis", None, "leading")

    def apply_loads(self, segment: Segment) -> None:
        self._s.set_loads(0, segment)

    def step(self) -> None:
        self._s.step()

    def read_state(self):
        s = self._s
        return s.x[0].copy(), s.q[0].copy(), s.v[0].copy(), s.w[0].copy()

    # --- many bodies ------------------------------------------------------------------------------
    @classmethod
    def simulate_batch(cls, problems: list[Problem], dt: float, steps: int, integrator: str,
                       precision: str = "float64") -> BatchRun:
        cls.batch_calls.append({"bodies": len(problems), "dt": dt, "steps": steps,
                                "integrator": integrator, "precision": precision})
        if integrator not in cls.offered_integrators():
            raise UnsupportedOption(f"{cls.name} has no integrator {integrator!r}")
        if precision not in cls.precisions:
            raise UnsupportedOption(f"{cls.name} offers no precision {precision!r}")
        if not problems:
            return BatchRun([], [], 0.0, 0.0, [])
        s = _State(problems, dt)
        schedules = [LoadSchedule(pb, float(dt)) for pb in problems]
        B = len(problems)
        out = [Trajectory.empty(steps + 1) for _ in range(B)]
        t = (0 + np.arange(steps + 1)) * float(dt)

        def record(k: int) -> None:
            for i, tr in enumerate(out):
                tr.position[k], tr.quaternion_wxyz[k] = s.x[i], s.q[i]
                tr.linear_velocity[k], tr.angular_velocity[k] = s.v[i], s.w[i]

        record(0)
        for k in range(steps):
            for i, sched in enumerate(schedules):
                s.set_loads(i, sched.at(k))
            s.step()
            record(k + 1)
        diverged = []
        for tr in out:
            tr.t[:] = t
            bad = ~(np.isfinite(tr.position).all(1) & np.isfinite(tr.quaternion_wxyz).all(1)
                    & np.isfinite(tr.linear_velocity).all(1) & np.isfinite(tr.angular_velocity).all(1))
            diverged.append(float(t[np.argmax(bad)]) if bad.any() else None)
        settings = [{"batch axis": {"default": None, "set": "leading"}} for _ in problems]
        return BatchRun(out, diverged, 0.0, 0.0, settings)
