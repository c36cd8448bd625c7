"""The floors (reference_impl/floors.py: flat loops, the bench's yardsticks) are their maps' arithmetic:
each floor's trajectory equals ``integrators.simulate``'s bit for bit on torque-free problems."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.input.casefile import load_case
from freebody.reference_impl.floors import FLOORS, run_floor
from freebody.reference_impl.integrators import simulate
from freebody.reference_impl.problem import Body, InitialState, Load, Problem
from freebody.reference_impl.rotations import matrix_from_quat, quat_from_rotvec

FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


def torque_free(seed: int) -> Problem:
    """A random full inertia, state and gravity (or none), no loads."""
    rng = np.random.default_rng(seed)
    moments = rng.uniform(0.2, 3.0, 3)
    moments[2] = min(moments[2], moments[0] + moments[1])
    P = matrix_from_quat(quat_from_rotvec(rng.normal(size=3)))
    q = rng.normal(size=4)
    return Problem(f"free{seed}", "", Body(rng.uniform(0.3, 5.0), P @ np.diag(moments) @ P.T),
                   InitialState(10.0 * rng.normal(size=3), q / np.linalg.norm(q), rng.normal(size=3),
                                2.0 * rng.normal(size=3)),
                   gravity=[0.0, 0.0, -9.81] if seed % 2 else [0.0, 0.0, 0.0], duration_steps=300, dts=(0.01,))


PROBLEMS = [(torque_free(s), dt) for s, dt in zip(range(6), (1e-3, 5e-3, 1e-2, 1e-3, 5e-3, 1e-2))]
PROBLEMS.append((load_case("dzhanibekov"), 1e-3))  # w0 on a principal plane: signed zeros in w_b x I w_b


@pytest.mark.parametrize("integrator", FLOORS)
def test_floor_is_its_map_bit_for_bit(integrator):
    for pb, dt in PROBLEMS:
        a, b = simulate(pb, integrator, dt, 300), run_floor(pb, integrator, dt, 300)
        for field in FIELDS:
            x, y = getattr(a, field), getattr(b, field)
            assert x.tobytes() == y.tobytes(), (pb.name, field)


def test_a_floor_refuses_loads_and_unknown_maps():
    pb, dt = PROBLEMS[0]
    loaded = Problem("loaded", "", pb.body, pb.initial, gravity=[0.0, 0.0, 0.0], loads=(Load(torque=[1.0, 0.0, 0.0]),), dts=(dt,))
    with pytest.raises(ValueError):
        run_floor(loaded, FLOORS[0], dt, 10)
    with pytest.raises(KeyError):
        run_floor(pb, "euler-quat", dt, 10)
