"""A long run is stepped and judged in chunks (freebody/run/execute._execute_chunked, RunJudge):
its result must be the whole-run judgement's, to round-off.  Each case runs both ways, the chunked
path forced by a small threshold and chunk (the constants of freebody/tolerances.py)."""
from __future__ import annotations

import numpy as np
import pytest

from freebody import tolerances as tol
from freebody.adapters.base import EngineDiverged, is_available
from freebody.adapters.reference import ReferenceAdapter, map_orientations
from freebody.input.casefile import load_case
from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.integrators import INTEGRATORS, simulate
from freebody.reference_impl.truth import truth_chunks, truth_trajectory
from freebody.results.document import load_trajectory, samples_to_save
from freebody.run import budget
from freebody.run.execute import _execute_chunked, execute
from freebody.run.judge import TruthCache, judge_run
from freebody.run.metrics import METRIC_NAMES, series
from freebody.run.records import RunSpec, Simulated, Status
from freebody.run.worker import RunTask, Runner

FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")
CHUNK = 700  # steps: every run below spans several chunks, the last one partial

needs_mujoco = pytest.mark.skipif(not is_available("mujoco"), reason="mujoco not installed")


def _chunked(monkeypatch, spec, save_every=None):
    monkeypatch.setattr(tol, "CHUNKED_JUDGING_MIN_STEPS", 10)
    monkeypatch.setattr(tol, "JUDGE_CHUNK_STEPS", CHUNK)
    out = execute(spec, TruthCache(), save_every=save_every)
    monkeypatch.undo()
    assert out.saved_index is not None  # it did go the chunked way
    return out


def _both(monkeypatch, case, engine, integrator, dt, steps):
    spec = RunSpec(load_case(case), engine, integrator, dt, steps)
    whole = execute(spec, TruthCache())
    assert whole.saved_index is None
    return whole, _chunked(monkeypatch, spec)


def _same_metrics(a: dict, b: dict, rtol: float = 1e-9, atol: float = 0.0) -> None:
    assert set(a) == set(b)
    for k in a:
        if a[k] is None or b[k] is None:
            assert a[k] is None and b[k] is None, k
        else:
            assert b[k] == pytest.approx(a[k], rel=rtol, abs=atol), k


def _same_result(whole, chunked, rtol: float = 1e-9, saved: bool = True) -> None:
    a, b = whole.result, chunked.result
    assert (b.status, b.diverged_at_s, b.steps) == (a.status, a.diverged_at_s, a.steps)
    assert b.message == a.message
    _same_metrics(a.metrics, b.metrics, rtol)
    if a.final_state is None:
        assert b.final_state is None
    else:
        for k, v in a.final_state.items():
            np.testing.assert_allclose(b.final_state[k], v, rtol=1e-12, atol=1e-15)
    ma, mb = a.matches_reference, b.matches_reference
    assert (ma is None) == (mb is None)
    if ma is not None:
        assert set(ma) == set(mb)
        for k in ("verdict", "integrator", "closest", "indistinguishable", "undecidable", "rule"):
            assert mb[k] == ma[k], k
        for k in ("candidates", "levels_rad", "ratios"):
            _same_metrics(ma[k], mb[k], rtol)
        for k in ("max_orientation_diff_rad", "threshold_rad"):
            assert mb[k] == pytest.approx(ma[k], rel=rtol)
    if saved:
        sa = samples_to_save(whole.trajectory, whole.truth, None, whole.series, a.diverged_at_s)
        sb = samples_to_save(chunked.trajectory, chunked.truth, None, chunked.series, b.diverged_at_s,
                             chunked.saved_index)
        np.testing.assert_array_equal(sb[2], sa[2])
        for i in (0, 1):
            for f in FIELDS:
                np.testing.assert_allclose(getattr(sb[i], f), getattr(sa[i], f), rtol=1e-9, atol=1e-9)
        if sa[0].orthonormality_error is not None:
            np.testing.assert_array_equal(sb[0].orthonormality_error, sa[0].orthonormality_error)


@needs_mujoco
def test_torque_free_engine_run_identified_chunked_as_whole(monkeypatch):
    """Closed-form truth: the chunks' truth is the whole truth's numbers, so everything agrees to
    a few ulps; MuJoCo Euler is identified as the engines' explicit map either way."""
    whole, chunked = _both(monkeypatch, "dzhanibekov", "mujoco", "Euler", 0.001, 3000)
    assert whole.result.status == Status.OK
    assert whole.result.matches_reference["integrator"] == "semi-implicit-explicit-gyro"
    _same_result(whole, chunked)


@needs_mujoco
def test_a_tie_chunked_as_whole(monkeypatch):
    """A sphere's spin: several maps tie (the pairwise checks run chunk by chunk)."""
    whole, chunked = _both(monkeypatch, "spinning_sphere", "mujoco", "Euler", 0.001, 2500)
    assert len(whole.result.matches_reference["indistinguishable"]) > 1
    _same_result(whole, chunked)


@needs_mujoco
def test_loaded_case_numerical_truth_chunked_as_whole(monkeypatch):
    """Numerical truth (a spin-up: the truth's maxima grow, each chunk scales by the whole run's):
    restarted at the chunk joins, it moves by its tolerance (~1e-11 here, ~1e-13 of |L|), far below
    the engine's errors (1e-4 of |L|): the metrics agree to 1e-6 (1e-9 with the closed form)."""
    whole, chunked = _both(monkeypatch, "body_torque_spinup", "mujoco", "Euler", 0.001, 3000)
    assert whole.result.truth == "numerical" and whole.result.status == Status.OK
    _same_result(whole, chunked, rtol=1e-6)


@pytest.mark.parametrize("case, dt, steps", [("high_spin_dt_10ms", 0.01, 2000), ("dzhanibekov", 0.01, 3000)])
def test_diverging_run_chunked_as_whole(monkeypatch, case, dt, steps):
    """Reference euler-matrix blows up (after one step / at 2.15 s, inside a chunk): the same
    divergence, the metrics before it, R's orthonormality and the saved samples around it."""
    whole, chunked = _both(monkeypatch, case, "reference", "euler-matrix", dt, steps)
    assert whole.result.status == Status.DIVERGED
    _same_result(whole, chunked)


class _BlowsUp(ReferenceAdapter):
    """The reference map, reporting an instability of its own at step BLOW_UP (as MuJoCo's warning)."""
    BLOW_UP = 1234

    def advance(self, steps):
        k0 = self.k
        out = super().advance(steps)
        if k0 + steps >= self.BLOW_UP:
            raise EngineDiverged(self.BLOW_UP * self.dt, "the engine's warning", out.head(self.BLOW_UP - k0 + 1))
        return out


def test_engine_reported_divergence_chunked_as_whole(monkeypatch):
    """An engine stopping early: the samples up to its blow-up judged alike, and the saved samples
    at the stride of the actual length (a second pass)."""
    spec = RunSpec(load_case("dzhanibekov"), "reference", "semi-implicit-explicit-gyro", 0.001, 3000)
    try:
        _BlowsUp(spec.problem, spec.dt, spec.integrator).simulate(spec.steps)
    except EngineDiverged as e:
        sim = Simulated(e.trajectory, e.t, e.reason, "v", {}, 0.0)
    whole = judge_run(spec, sim, TruthCache())
    monkeypatch.setattr(tol, "CHUNKED_JUDGING_MIN_STEPS", 10)
    chunked = _execute_chunked(spec, _BlowsUp, True, None, chunk=CHUNK)
    assert whole.result.status == Status.DIVERGED and len(whole.trajectory) == _BlowsUp.BLOW_UP + 1
    _same_result(whole, chunked)


def test_saved_file_of_a_chunked_run_holds_each_maximum(monkeypatch, tmp_path):
    """The trajectory file of a run judged in chunks keeps the sample of every maximum its metrics
    report (recomputed from the file's run and truth samples)."""
    monkeypatch.setattr(tol, "CHUNKED_JUDGING_MIN_STEPS", 10)
    monkeypatch.setattr(tol, "JUDGE_CHUNK_STEPS", CHUNK)
    pb = load_case("dzhanibekov")
    spec = RunSpec(pb, "reference", "euler-quat", 0.001, 5000)
    payload = Runner().run(RunTask(0, "p0", spec, save_dir=str(tmp_path)))
    r = payload["result"]
    assert r.status == Status.OK and r.trajectory
    tr, truth = load_trajectory(tmp_path / r.trajectory)
    assert len(tr) < spec.steps + 1  # thinned
    with np.load(tmp_path / r.trajectory) as z:
        assert z["sample_index"][-1] == spec.steps
    whole_truth = truth_trajectory(pb, spec.dt, spec.steps)
    from freebody.run.metrics import truth_scales
    s = series(pb, tr, truth, truth_scales(pb, whole_truth))
    m = r.metrics
    assert np.max(s.orientation_error) == pytest.approx(m["orientation_error_max_rad"], rel=1e-12)
    assert np.max(s.angular_momentum_error) == pytest.approx(m["angular_momentum_error_max_rel"], rel=1e-12)
    assert np.max(s.energy_error) == pytest.approx(m["energy_error_max_rel"], rel=1e-12)
    assert np.max(s.position_error) == pytest.approx(m["position_error_max_m"], rel=1e-12, abs=1e-300)


@pytest.mark.parametrize("integrator", list(INTEGRATORS))
def test_reference_adapter_continues_bit_for_bit(integrator):
    """The reference adapter stepped chunk by chunk (its own state continued) gives
    integrators.simulate's trajectory bit for bit, loads switching inside the run included."""
    pb = load_case("offset_push")
    whole = simulate(pb, integrator, 0.001, 1500)
    pieces = Trajectory.concatenate(list(ReferenceAdapter(pb, 0.001, integrator).chunks(1500, 333)))
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(pieces, f), getattr(whole, f))
    if whole.orthonormality_error is not None:
        np.testing.assert_array_equal(pieces.orthonormality_error, whole.orthonormality_error)
    q = np.concatenate(list(map_orientations(pb, integrator, 0.001, 1500, 333)))
    np.testing.assert_array_equal(q, whole.quaternion_wxyz)


@pytest.mark.parametrize("case", ["dzhanibekov", "world_torque"])
def test_truth_chunks(case):
    """Closed form: the whole truth's numbers; numerical: within the truth's own accuracy."""
    pb = load_case(case)
    whole = truth_trajectory(pb, 0.001, 2000)
    pieces = Trajectory.concatenate(list(truth_chunks(pb, 0.001, 2000, 333)))
    assert len(pieces) == 2001
    np.testing.assert_array_equal(pieces.t, whole.t)
    for f in FIELDS[1:]:
        if pb.torque_free:
            np.testing.assert_array_equal(getattr(pieces, f), getattr(whole, f))
        else:
            np.testing.assert_allclose(getattr(pieces, f), getattr(whole, f), rtol=0, atol=1e-9)


def test_a_long_run_is_estimated_by_its_chunk():
    """The memory estimate of a 1e7-step run is that of one chunk (it is no longer refused)."""
    est = budget.run_estimate(1, 10**7, 10**7, 1)
    assert est.memory_bytes < 2 ** 30
    assert budget.held_samples(10**7) == tol.JUDGE_CHUNK_STEPS + 1
    assert budget.held_samples(tol.CHUNKED_JUDGING_MIN_STEPS) == tol.CHUNKED_JUDGING_MIN_STEPS + 1


def test_metric_keys_of_chunked_runs_are_known(monkeypatch):
    spec = RunSpec(load_case("projectile"), "reference", "rk4", 0.001, 1500)
    out = _chunked(monkeypatch, spec)
    assert set(out.result.metrics) <= set(METRIC_NAMES)
