"""Scheme identification shares its maps: the candidate maps of a (case, dt, steps, precision, load
sampling) and their round-off spreads are prepared once (run/judge.TruthCache.map_piece) and every
engine run of the group compares with the same arrays; the case's perturbed starts are built once,
not once per map; a worker that finds a group's maps in the shared store computes none; and a run
judged against the shared maps gets exactly the result it gets alone."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.input import load_case
from freebody.reference_impl import integrators
from freebody.run import judge
from freebody.run.judge import (SCHEME_CANDIDATES, ULP_SIGN_PATTERNS, MapPiece, TruthCache, identify,
                                perturbed_starts, roundoff_spread, stepped_map_pieces)
from freebody.run.records import RunSpec
from freebody.run.sharedcache import GroupTruthCache

# short runs: the sharing is what is checked, not the physics (a loaded case: its loads switch)
CASE, DT, STEPS = "body_torque_spinup", 0.01, 20


@pytest.fixture
def counted(monkeypatch):
    """Counts of perturbed_start and map runs (integrators.simulate) from here on."""
    n = {"perturbed_start": 0, "simulate": 0}
    start, simulate = judge.perturbed_start, integrators.simulate

    def counting_start(*a, **k):
        n["perturbed_start"] += 1
        return start(*a, **k)

    def counting_simulate(*a, **k):
        n["simulate"] += 1
        return simulate(*a, **k)
    monkeypatch.setattr(judge, "perturbed_start", counting_start)
    monkeypatch.setattr(integrators, "simulate", counting_simulate)
    monkeypatch.setattr(judge, "reference_simulate", counting_simulate)
    return n


def _run(pb, integrator="semi-implicit-explicit-gyro"):
    return integrators.simulate(pb, integrator, DT, STEPS)


def test_a_group_prepares_each_map_once_whatever_its_runs(counted):
    """Three runs of one group (two engines, three integrators): the maps and their spreads are run
    once (27 maps, four perturbed copies each), the perturbed starts built once, and every run gets
    the same MapPiece objects."""
    pb = load_case(CASE)
    cache = TruthCache()
    runs = [RunSpec(pb, "mujoco", "Euler", DT, STEPS), RunSpec(pb, "mujoco", "implicit", DT, STEPS),
            RunSpec(pb, "pybullet", "maximal", DT, STEPS)]
    q = _run(pb)
    before = dict(counted)
    for spec in runs:
        identify(pb, q, spec, cache)
    n_maps = len(SCHEME_CANDIDATES)
    assert counted["perturbed_start"] - before["perturbed_start"] == len(ULP_SIGN_PATTERNS)
    # a multi-stage map may have two load-sampling variants on a loaded case: at most one more run each
    assert n_maps * (1 + len(ULP_SIGN_PATTERNS)) <= counted["simulate"] - before["simulate"]
    assert counted["simulate"] - before["simulate"] <= 2 * n_maps * (1 + len(ULP_SIGN_PATTERNS))
    pieces = [cache.map_piece(pb, name, DT, STEPS, "float64", "per-stage") for name in SCHEME_CANDIDATES]
    assert all(isinstance(p, MapPiece) for p in pieces)
    again = [cache.map_piece(pb, name, DT, STEPS, "float64", "per-stage") for name in SCHEME_CANDIDATES]
    assert all(a is b for a, b in zip(pieces, again))


def test_the_shared_maps_give_each_run_the_result_it_gets_alone():
    """A run judged after others of its group (the cache warm) gets exactly the dict it gets with a
    cache of its own: the shared arrays carry no state of the runs before it."""
    pb = load_case(CASE)
    shared = TruthCache()
    specs = [(RunSpec(pb, "mujoco", "Euler", DT, STEPS), _run(pb)),
             (RunSpec(pb, "mujoco", "RK4", DT, STEPS), _run(pb, "rkmk4-body")),
             (RunSpec(pb, "engine", "rk4", DT, STEPS, "float32"), _run(pb, "rk4"))]
    warm = [identify(pb, q, spec, shared) for spec, q in specs]
    alone = [identify(pb, q, spec, TruthCache()) for spec, q in specs]
    assert warm == alone
    assert "semi-implicit-explicit-gyro" in warm[0]["indistinguishable"]


def test_the_perturbed_starts_given_are_the_ones_built():
    """roundoff_spread from starts built once equals roundoff_spread building its own, bit for bit."""
    pb = load_case(CASE)
    q = _run(pb).quaternion_wxyz
    for precision in ("float64", "float32"):
        own = roundoff_spread(pb, "semi-implicit-explicit-gyro", DT, STEPS, precision, q)
        given = roundoff_spread(pb, "semi-implicit-explicit-gyro", DT, STEPS, precision, q,
                                starts=perturbed_starts(pb, precision))
        assert np.array_equal(own, given)


def test_a_chunked_run_builds_its_perturbed_starts_once(counted):
    """The maps of a run judged in chunks are stepped from four perturbed starts built once for the
    run, not once per map."""
    pb = load_case(CASE)
    pieces = stepped_map_pieces(RunSpec(pb, "mujoco", "Euler", DT, STEPS), 7)
    for name in SCHEME_CANDIDATES[:5]:
        next(pieces(name))
    assert counted["perturbed_start"] == len(ULP_SIGN_PATTERNS)


def test_a_worker_reading_the_store_computes_no_map(tmp_path, counted):
    """Two workers of one suite (two GroupTruthCaches on one store): the second finds every map and
    spread the first computed and runs none, with the same result."""
    pb = load_case(CASE)
    spec, q = RunSpec(pb, "mujoco", "Euler", DT, STEPS), _run(pb)
    first, second = GroupTruthCache(tmp_path), GroupTruthCache(tmp_path)
    for cache in (first, second):
        cache.enter(pb, "p0", DT, STEPS)
    a = identify(pb, q, spec, first)
    n = counted["simulate"]
    b = identify(pb, q, spec, second)
    assert counted["simulate"] == n
    assert a == b


def test_a_worker_waits_for_the_map_another_is_computing(tmp_path, counted):
    """While one worker holds a map's claim (computing it), another that needs the map waits for it
    and reads what the first wrote, instead of computing it a second time."""
    import threading

    from freebody.run import sharedcache

    pb = load_case(CASE)
    name = "rk4-body-exp"
    first, second = GroupTruthCache(tmp_path), GroupTruthCache(tmp_path)
    for cache in (first, second):
        cache.enter(pb, "p0", DT, STEPS)
    path = first._path(pb, DT, STEPS, name)
    got = {}
    with sharedcache._claimed(path):
        reader = threading.Thread(target=lambda: got.update(q=second.orientation(pb, name, DT, STEPS)))
        reader.start()
        reader.join(0.3)
        assert reader.is_alive() and not got  # waiting for the claim
        tr = integrators.simulate(pb, name, DT, STEPS)
        sharedcache._save(path, tr)
        n = counted["simulate"]
    reader.join(10)
    assert counted["simulate"] == n  # the waiting worker read the map, it did not run it
    assert np.array_equal(got["q"], tr.quaternion_wxyz)
