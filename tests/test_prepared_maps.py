"""Map runs from a prepared start (reference_impl/prepared_maps.py) are integrators.simulate's runs:
every reference integrator and engine map, from a case's own start and from its perturbed starts,
under both load samplings, gives the same arrays bit for bit, and calls the compiled drivers with
the argument types simulate() uses (no new compiled signature)."""
from __future__ import annotations

import numba
import numpy as np
import pytest

from freebody.input import load_case
from freebody.reference_impl import compiled, compiled_engine_maps, prepared_maps
from freebody.reference_impl.integrators import simulate
from freebody.run.judge import SCHEME_CANDIDATES, perturbed_starts

# torque-free, a body couple, a force switching on and off, a force at a body point, gravity
CASES = ("dzhanibekov", "body_torque_spinup", "offset_push", "convergence_body_point_force", "projectile")
DT, STEPS = 0.01, 23
FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity", "orthonormality_error")
MAPS = (*SCHEME_CANDIDATES, "symplectic-euler")  # an old name runs the map it stands for


def _starts(pb):
    """The case's own start and two of its perturbed starts (a float64 and a float32 ulp)."""
    return (pb, perturbed_starts(pb, "float64")[1], perturbed_starts(pb, "float32")[2])


def _same(a, b) -> bool:
    return (a is None) == (b is None) and (a is None or (a.dtype == b.dtype and a.shape == b.shape
                                                         and a.tobytes() == b.tobytes()))


@pytest.mark.parametrize("case", CASES)
def test_every_map_from_a_prepared_start_is_simulate_bit_for_bit(case):
    pb = load_case(case)
    loads = None
    for start in _starts(pb):
        prepared = prepared_maps.map_start(start, DT, loads)
        loads = prepared.loads  # the perturbed starts share the case's loads, as identification's do
        for name in MAPS:
            for sampling in ("per-stage", "per-step"):
                want = simulate(start, name, DT, STEPS, load_sampling=sampling)
                got = prepared_maps.run_map(prepared, name, STEPS, sampling)
                assert all(_same(getattr(want, f), getattr(got, f)) for f in FIELDS), (name, sampling)
                q = prepared_maps.map_orientations(prepared, name, STEPS, sampling)
                assert _same(want.quaternion_wxyz, q), (name, sampling)


def _signatures() -> dict:
    return {f"{m.__name__}.{k}": len(v.signatures) for m in (compiled, compiled_engine_maps)
            for k, v in vars(m).items() if isinstance(v, numba.core.registry.CPUDispatcher)}


def test_a_prepared_run_compiles_no_new_signature():
    """The prepared runs pass the compiled drivers what simulate() passes (tuples of floats, a float
    dt, an int step count, C-contiguous rows): every dispatcher keeps the signatures simulate() used."""
    pb = load_case("offset_push")
    for name in SCHEME_CANDIDATES:
        for sampling in ("per-stage", "per-step"):
            simulate(pb, name, DT, STEPS, load_sampling=sampling)
    before = _signatures()
    prepared = prepared_maps.map_start(pb, np.float64(DT))
    for name in SCHEME_CANDIDATES:
        for sampling in ("per-stage", "per-step"):
            prepared_maps.map_orientations(prepared, name, np.int64(STEPS), sampling)
            prepared_maps.run_map(prepared, name, STEPS, sampling)
    assert _signatures() == before


def test_an_unknown_map_is_a_key_error():
    with pytest.raises(KeyError):
        prepared_maps.run_map(prepared_maps.map_start(load_case("dzhanibekov"), DT), "no-such-map", 3)
