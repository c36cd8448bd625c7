"""An engine whose quaternions are not unit, for the quaternion-norm check
(tests/test_quaternion_norm.py): the reference map ``semi-implicit-explicit-gyro``, its
orientation handed out as SCALE x q (|q| = SCALE, the same rotation).  Every number freebody
derives from a rotation (orientation error, energy, momentum) uses q / |q| and is the map's; only
the quaternion's norm tells the two apart.

Registered by the tests in :data:`freebody.adapters.base.ENGINES` as ``scaledq``:
``EngineEntry("numpy", "fake_engines.scaled_quaternion_adapter", "ScaledQuaternionAdapter")``.
"""
from __future__ import annotations

from typing import ClassVar

from freebody.adapters.base import EngineEntry
from freebody.adapters.reference import ReferenceAdapter
from freebody.reference_impl.conventions import Trajectory

SCALE = 3.0  # |q| of every quaternion this engine hands out: |1 - |q|| = 2

REGISTRY_ENTRY = EngineEntry("numpy", "fake_engines.scaled_quaternion_adapter", "ScaledQuaternionAdapter")


class ScaledQuaternionAdapter(ReferenceAdapter):
    name: ClassVar[str] = "scaledq"
    integrators: ClassVar[tuple[str, ...]] = ("semi-implicit-explicit-gyro",)

    @classmethod
    def engine_version(cls) -> str:
        return "0-scaled-quaternion"

    def advance(self, steps: int) -> Trajectory:
        tr = super().advance(steps)  # may be the reference's cached arrays: scaled into a copy
        return Trajectory(tr.t, tr.position, SCALE * tr.quaternion_wxyz, tr.linear_velocity,
                          tr.angular_velocity, tr.orthonormality_error)
