"""Scheme identification shares its maps: the candidate maps of a (case, dt, steps, precision, load
sampling) and their round-off spreads are prepared once (run/judge.TruthCache.map_piece) and every
engine run of the group compares with the same arrays; the case's perturbed starts are built once,
not once per map; a worker that finds a group's maps in the shared store computes none; and a run
judged against the shared maps gets exactly the result it gets alone."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from freebody.input import load_case
from freebody.reference_impl import integrators, prepared_maps
from freebody.run import judge
from freebody.run.judge import (SCHEME_CANDIDATES, ULP_SIGN_PATTERNS, MapPiece, TruthCache, identify,
                                perturbed_starts, roundoff_spread, stepped_map_pieces)
from freebody.run.records import RunSpec
from freebody.run.sharedcache import GroupTruthCache

# short runs: the sharing is what is checked, not the physics (a loaded case: its loads switch)
CASE, DT, STEPS = "body_torque_spinup", 0.01, 20


@pytest.fixture
def counted(monkeypatch):
    """Counts of perturbed_start and map runs (integrators.simulate, and prepared_maps.run_map and
    map_orientations: what identification runs, from starts prepared once) from here on."""
    n = {"perturbed_start": 0, "simulate": 0}
    start, simulate, run_map = judge.perturbed_start, integrators.simulate, prepared_maps.run_map
    orientations = prepared_maps.map_orientations

    def counting_start(*a, **k):
        n["perturbed_start"] += 1
        return start(*a, **k)

    def counting(f):
        def counted_run(*a, **k):
            n["simulate"] += 1
            return f(*a, **k)
        return counted_run
    monkeypatch.setattr(judge, "perturbed_start", counting_start)
    monkeypatch.setattr(integrators, "simulate", counting(simulate))
    monkeypatch.setattr(judge, "run_map", counting(run_map))
    monkeypatch.setattr(judge, "map_orientations", counting(orientations))
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


def _per_map(pb, trajectory, spec, cache):
    """identify() with the run compared with one map after another (no stacked CandidateMaps)."""
    spec = dataclasses.replace(spec, problem=pb)
    ident = judge.Identification(spec, judge.cached_map_pieces(spec, cache))
    ident.update(trajectory.quaternion_wxyz)
    return ident.result()


def _runs(pb, dt, steps):
    """Engine-like runs of the case: several maps' own runs, one between two maps, one that blows up
    half way, one shorter than the group's maps."""
    runs = [integrators.simulate(pb, name, dt, steps)
            for name in ("semi-implicit-explicit-gyro", "rkmk4-body", "implicit-gyro-split-torque",
                         "quat-rate-euler", "symplectic-splitting")]
    a, b = runs[0].quaternion_wxyz, runs[3].quaternion_wxyz
    between = (a + b) / np.linalg.norm(a + b, axis=1, keepdims=True)
    blown = runs[1].quaternion_wxyz.copy()
    blown[steps // 2:] = np.inf
    return runs + [dataclasses.replace(runs[0], quaternion_wxyz=between),
                   dataclasses.replace(runs[1], quaternion_wxyz=blown), runs[2].head(steps // 3)]


# the sharing case; a fast spin at a coarse step (maps whose perturbed copies reach the level's cap:
# undecidable); a coarse flip (a map whose own run is not finite); a longer run (its 27 maps compared
# in blocks, BLOCK_SAMPLES)
GROUPS = [(CASE, DT, STEPS), ("high_spin_dt_10ms", 0.01, 60), ("dzhanibekov", 0.05, 100), ("dzhanibekov", 0.01, 900)]


@pytest.mark.parametrize("case, dt, steps", GROUPS)
@pytest.mark.parametrize("precision, block", [("float64", None), ("float32", None), ("float64", 16)])
def test_the_stacked_comparison_is_the_one_map_at_a_time_result(monkeypatch, case, dt, steps, precision, block):
    """A run compared with every map at once (CandidateMaps, the group's runs) gets exactly the dict
    it gets compared with one map after another: verdicts, every candidate's difference, level and
    ratio, the tie, the undecidable maps; also with blocks of one map (or one perturbed copy) each."""
    pb = load_case(case)
    spec = RunSpec(pb, "mujoco", "Euler", dt, steps, precision)
    runs = _runs(pb, dt, steps)
    want = [_per_map(pb, tr, spec, TruthCache()) for tr in runs]
    if block is not None:
        monkeypatch.setattr(judge, "BLOCK_SAMPLES", block)
    shared = TruthCache()
    got = [identify(pb, tr, spec, shared) for tr in runs]
    assert shared.candidate_maps(pb, dt, steps, precision, "per-stage", SCHEME_CANDIDATES) is not None
    assert got == want


def test_a_further_run_of_a_group_is_compared_in_one_pass(monkeypatch):
    """The group's first run compares the maps that reproduce it pair by pair (the tie); a further
    run with the same maps within reach is compared with every map in one pass and finds the pairs
    found already: one angle computation, whatever the number of maps."""
    pb = load_case(CASE)
    spec, tr = RunSpec(pb, "mujoco", "Euler", DT, STEPS), _run(pb)
    cache = TruthCache()
    first = identify(pb, tr, spec, cache)
    assert len(first["indistinguishable"]) > 1  # a tie: pairs of maps were compared
    calls = {"n": 0}
    angle = judge._angle_parts

    def counting_angle(*a):
        calls["n"] += 1
        return angle(*a)
    monkeypatch.setattr(judge, "_angle_parts", counting_angle)
    assert identify(pb, tr, dataclasses.replace(spec, integrator="implicit"), cache) == first
    assert calls["n"] == 1


def test_a_group_too_long_to_stack_is_compared_map_by_map(monkeypatch):
    """Past STACKED_SAMPLES_MAX candidates x samples the maps are not stacked (memory): the run is
    compared with one map after another, with the same result."""
    pb = load_case(CASE)
    spec, tr = RunSpec(pb, "mujoco", "Euler", DT, STEPS), _run(pb, "rk4")
    want = identify(pb, tr, spec, TruthCache())
    monkeypatch.setattr(judge, "STACKED_SAMPLES_MAX", len(SCHEME_CANDIDATES) * (STEPS + 1) - 1)
    cache = TruthCache()
    assert cache.candidate_maps(pb, DT, STEPS, "float64", "per-stage", SCHEME_CANDIDATES) is None
    assert identify(pb, tr, spec, cache) == want
