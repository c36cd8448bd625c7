"""The quaternion's norm is checked by the harness for every engine (issue 28, item 9): each judged
run records max_k |1 - |q_k|| of the quaternions as its engine handed them out (metric
``quaternion_norm_error_max``, before anything normalises them); beyond round-off
(tolerances.QUATERNION_NORM_ROUNDOFF, per precision) the run stays ok and gets the finding "engine
returns non-unit quaternions" (``judgement["non_unit_quaternion"]``).  The engine that hands out
3 q (tests/fake_engines/scaled_quaternion_adapter.py) was ok with no note before."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fake_engines.scaled_quaternion_adapter import REGISTRY_ENTRY, SCALE
from freebody import tolerances as tol
from freebody.adapters.base import ENGINES, is_available
from freebody.cli import main
from freebody.report import findings as fd
from freebody.results.document import SCHEMA_VERSION, load_results
from freebody.results.judgement import JUDGEMENT, run_judgement
from freebody.run.metrics import DIAGNOSTIC_METRICS, METRIC_KEYS, QUATERNION_NORM_ERROR_MAX

FINDING_TITLE = "engine returns non-unit quaternions"
# |1 - |3 q|| = 2 up to the round-off of the map's own |q| (1e-16) times 3
SCALED_NORM_ERROR_ATOL = 1e-12
# Real engines measured here: float64 engines that normalise q every step, over a 0.2 s run
REAL_ENGINES = [e for e in ("reference", "mujoco", "pybullet", "dart", "drake") if is_available(e)]


@pytest.fixture(scope="module")
def scaled_run(tmp_path_factory):
    """One folder: dzhanibekov, 0.2 s at dt = 0.01, the 3 q engine beside the reference map it
    scales and the real engines installed here (their default integrators)."""
    out = tmp_path_factory.mktemp("quatnorm")
    mp = pytest.MonkeyPatch()
    mp.setitem(ENGINES, "scaledq", REGISTRY_ENTRY)
    try:
        args = ["run", "dzhanibekov", "--engine", "scaledq", *(a for e in REAL_ENGINES for a in ("--engine", e)),
                "--integrator", "reference:semi-implicit-explicit-gyro", "--dt", "0.01", "--duration", "0.2",
                "--no-isolation", "--out", str(out), "--quiet"]
        assert main(args) == 0
    finally:
        mp.undo()
    return out, json.loads((out / "results.json").read_text())


def _runs(doc, engine):
    return [r for r in doc["runs"] if r["engine"] == engine]


def test_an_engine_returning_norm_3_quaternions_is_ok_with_the_metric_and_a_finding(scaled_run):
    out, doc = scaled_run
    (run,) = _runs(doc, "scaledq")
    assert run["status"] == "ok"
    assert abs(run["metrics"][QUATERNION_NORM_ERROR_MAX] - (SCALE - 1.0)) < SCALED_NORM_ERROR_ATOL
    assert run[JUDGEMENT]["non_unit_quaternion"] is True
    report = (out / "report.md").read_text()
    lines = [ln for ln in report.splitlines() if FINDING_TITLE in ln]
    assert lines and any("scaledq" in ln for ln in lines), report[:3000]
    (f,) = [f for f in fd.find(load_results(out / "results.json")["runs"]) if f.kind == "non-unit-quaternion"]
    assert f.engine == "scaledq" and "2.0e+00" in f.text and f.source == QUATERNION_NORM_ERROR_MAX


def test_the_scaled_engine_is_judged_as_the_map_it_scales(scaled_run):
    """The harness judges the rotation q / |q|: every other metric is the reference map's."""
    _, doc = scaled_run
    (scaled,) = _runs(doc, "scaledq")
    (ref,) = [r for r in _runs(doc, "reference") if r["integrator"] == "semi-implicit-explicit-gyro"]
    for key in METRIC_KEYS:
        if key == QUATERNION_NORM_ERROR_MAX:
            continue
        a, b = scaled["metrics"][key], ref["metrics"][key]
        assert (a is None and b is None) or a == pytest.approx(b, rel=1e-9, abs=1e-15), key
    assert "semi-implicit-explicit-gyro" in scaled[JUDGEMENT]["schemes"]  # reproduced (a tie on 0.2 s)


@pytest.mark.parametrize("real_engine", REAL_ENGINES)
def test_a_real_engine_has_the_metric_at_round_off_and_no_finding(scaled_run, real_engine):
    _, doc = scaled_run
    engine = real_engine
    runs = [r for r in _runs(doc, engine) if r["status"] == "ok"]
    assert runs
    for r in runs:
        x = r["metrics"][QUATERNION_NORM_ERROR_MAX]
        assert x is not None and 0.0 <= x <= tol.QUATERNION_NORM_ROUNDOFF[r["precision"]], (r["integrator"], x)
        assert r[JUDGEMENT]["non_unit_quaternion"] is False
    found = fd.find(load_results(doc)["runs"])
    assert not [f for f in found if f.kind == "non-unit-quaternion" and f.engine == engine]


def test_chunked_judging_gives_the_same_metric(scaled_run):
    """A long run is judged chunk by chunk (RunMetrics fed piece by piece): the same maximum."""
    from freebody.input.casefile import load_case
    from freebody.reference_impl.integrators import simulate
    from freebody.reference_impl.conventions import Trajectory
    from freebody.reference_impl.truth import truth_trajectory
    from freebody.run.metrics import RunMetrics, truth_scales

    pb = load_case("dzhanibekov")
    tr = simulate(pb, "rk4", 0.01, 40)
    rng = np.random.default_rng(28)
    q = tr.quaternion_wxyz * (1.0 + rng.uniform(-1e-3, 1e-3, size=(len(tr), 1)))
    tr = Trajectory(tr.t, tr.position, q, tr.linear_velocity, tr.angular_velocity)
    truth = truth_trajectory(pb, 0.01, 40)
    scales = truth_scales(pb, truth)
    whole = RunMetrics(pb, scales, 0.01)
    whole.feed(tr, truth, 0)
    pieces = RunMetrics(pb, scales, 0.01)
    for a, b in ((0, 7), (7, 30), (30, 41)):
        pieces.feed(tr.tail(a).head(b - a), truth.tail(a).head(b - a), a)
    expected = float(np.max(np.abs(1.0 - np.linalg.norm(q, axis=1))))
    assert whole.result(None)[0][QUATERNION_NORM_ERROR_MAX] == pieces.result(None)[0][QUATERNION_NORM_ERROR_MAX] == expected


def test_a_schema_5_document_reads_the_metric_as_unknown_and_no_finding(scaled_run):
    _, doc = scaled_run
    assert doc["schema_version"] == SCHEMA_VERSION == 7
    old = copy.deepcopy(doc)
    old["schema_version"] = 5
    for r in old["runs"]:
        r["metrics"].pop(QUATERNION_NORM_ERROR_MAX, None)
        del r[JUDGEMENT]["non_unit_quaternion"]
    migrated = load_results(old)
    for r in migrated["runs"]:
        assert QUATERNION_NORM_ERROR_MAX in r["metrics"] and r["metrics"][QUATERNION_NORM_ERROR_MAX] is None
        assert r[JUDGEMENT]["non_unit_quaternion"] is False
    assert not [f for f in fd.find(migrated["runs"]) if f.kind == "non-unit-quaternion"]
    assert old["runs"][0]["metrics"].get(QUATERNION_NORM_ERROR_MAX, "absent") == "absent"  # input not modified


def test_the_bound_is_per_precision():
    run = {"engine": "e", "integrator": "x", "status": "ok", "precision": "float32", "matches_reference": None,
           "state_growth": None, "metrics": {QUATERNION_NORM_ERROR_MAX: 3e-7}}  # SAPIEN's float32 round-off
    assert run_judgement(run)["non_unit_quaternion"] is False
    assert run_judgement({**run, "precision": "float64"})["non_unit_quaternion"] is True
    assert run_judgement({**run, "status": "diverged"})["non_unit_quaternion"] is False  # its finding: diverged
    assert QUATERNION_NORM_ERROR_MAX in DIAGNOSTIC_METRICS  # recorded and judged, not gated by compare
