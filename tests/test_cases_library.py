"""The bundled case library: every case loads and runs, the list is long enough, and the truths of
the symmetric top and the far-from-origin case are what their descriptions claim."""
from __future__ import annotations

import numpy as np
import pytest

import freebody
from freebody.input.casefile import bundled_case_paths, load_case
from freebody.cli import main
from freebody.reference_impl.rotations import quat_from_rotvec, quat_multiply
from freebody.reference_impl.truth import truth_kind, truth_trajectory
from freebody.testing import assert_same_rotation

MIN_BUNDLED_CASES = 15  # the bar for the library
SMOKE_STEPS = 3  # a few steps of every case: it builds, runs and is measured
SYMMETRIC_TOP_RAD = 1e-11  # closed form vs the textbook formula: both exact, round-off over 500 steps
FAR_POSITION_M = 1e-9  # rk4 integrates ballistic x exactly; round-off at |x| ~ 2e4 m is ~4e-12 per step
FAR_HORIZON_S = 0.2

CASES = list(bundled_case_paths())


def test_list_shows_the_library(capsys):
    assert main(["list", "--names"]) == 0
    names = capsys.readouterr().out.split()
    assert len(names) >= MIN_BUNDLED_CASES
    assert names == CASES


@pytest.mark.parametrize("name", CASES)
def test_every_case_loads_with_a_description_naming_its_truth(name):
    pb = load_case(name)
    assert pb.name == name
    assert truth_kind(pb) in pb.description  # "closed-form truth" or "numerical truth"


@pytest.mark.parametrize("name", CASES)
def test_every_case_runs_a_few_steps_on_reference_rk4(name):
    pb = load_case(name)
    dt = pb.dts[0]
    out = freebody.run_case(name, engine="reference", integrator="rk4", dt=dt, duration=SMOKE_STEPS * dt)
    assert out.result.status == "ok", out.result.message
    assert out.result.steps == SMOKE_STEPS
    assert np.all(np.isfinite(out.trajectory.quaternion_wxyz))
    assert out.result.metrics["orientation_error_max_rad"] is not None


def test_symmetric_top_truth_is_the_textbook_closed_form():
    """R(t) = Exp(t L / I_t) R0 Exp(t w3 (1 - I_s / I_t) e3) for I = diag(I_t, I_t, I_s)."""
    pb = load_case("symmetric_top")
    assert truth_kind(pb) == "closed-form"
    I = np.diag(pb.body.I_body)
    I_t, I_s = I[0], I[2]
    assert I[1] == I_t and np.count_nonzero(pb.body.I_body - np.diag(I)) == 0
    dt, steps = pb.dts[0], pb.steps(pb.dts[0])
    truth = truth_trajectory(pb, dt, steps)
    R0 = pb.R0
    w_b0 = R0.T @ pb.initial.angular_velocity
    L = R0 @ (I * w_b0)
    nu = w_b0[2] * (1.0 - I_s / I_t)
    t = truth.t[:, None]
    q = quat_multiply(quat_multiply(quat_from_rotvec(t * L / I_t), pb.initial.quaternion_wxyz),
                      quat_from_rotvec(t * np.array([0.0, 0.0, nu])))
    assert_same_rotation(q, truth.quaternion_wxyz, SYMMETRIC_TOP_RAD)
    # the body's angular velocity turns about the symmetry axis at (I_s - I_t) / I_t w3 (the description)
    assert nu == pytest.approx(-(I_s - I_t) / I_t * w_b0[2])


def test_far_from_origin_keeps_the_com_exact_on_rk4():
    pb = load_case("far_from_origin")
    assert np.linalg.norm(pb.initial.position) > 1e4
    out = freebody.run_case(pb, engine="reference", integrator="rk4", dt=0.01, duration=FAR_HORIZON_S)
    assert out.result.status == "ok"
    assert out.result.metrics["position_error_max_m"] < FAR_POSITION_M


def test_long_cases_document_their_cost_and_sweeps():
    """The expensive defaults are deliberate: the long horizon runs one dt, the Gazebo cases one dt
    inside their 1e-4..1e-3 sweep and say how to run the rest."""
    assert load_case("long_horizon").dts == (0.001,) and load_case("long_horizon").duration == 100.0
    for name in ("gazebo_boxes_simple", "gazebo_boxes_complex"):
        pb = load_case(name)
        assert pb.duration == 10.0 and all(1e-4 <= d <= 1e-3 for d in pb.dts)
        text = bundled_case_paths()[name].read_text()
        assert "--dt 1e-4" in text
