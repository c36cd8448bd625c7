"""The MuJoCo adapter against the reference maps, on the real engine (skipped if not installed).

Arrays follow freebody's canonical convention (reference_impl/conventions.py): quaternions
(w, x, y, z) body -> world, COM position/velocity in world (m, m/s), angular velocity in world
(rad/s), inertia (3, 3) about the COM in the body frame (kg m^2).
"""
from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="mujoco not installed (pip install 'freebody[engines]')")

from freebody.adapters.base import EngineDiverged  # noqa: E402
from freebody.adapters import mujoco_adapter  # noqa: E402
from freebody.adapters.mujoco_adapter import MujocoAdapter  # noqa: E402
from freebody.reference_impl.conventions import angular_momentum  # noqa: E402
from freebody.reference_impl.integrators import simulate  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402
from freebody.reference_impl.rotations import (geodesic_angle, matrix_from_quat,  # noqa: E402
                                               quat_from_rotvec, quat_multiply, quat_normalize)
from freebody.testing import assert_same_rotation  # noqa: E402

# t = 0 read-back: only the body -> world conversion of w (one 3x3 product each way) rounds.
READBACK_TOL = 1e-12
# Euler vs semi-implicit-explicit-gyro, Dzhanibekov case, dt 0.01, 10 s (1000 steps, through the
# flip, which amplifies round-off): measured 3e-10 rad (mujoco 4.0.0); 30x margin.
SAME_MAP_ANGLE_TOL = 1e-8
# angular velocity, same runs: measured 4.5e-10 rad/s at |w| ~ 5 rad/s.
SAME_MAP_OMEGA_TOL = 1e-8
# Same map, short run (dt 0.01, <= 40 steps, no flip): round-off only, measured 3e-15.
SHORT_RUN_TOL = 1e-11
# MuJoCo RK4 vs reference rk4 (both 4th order, different variables), Dzhanibekov case, dt 0.005,
# 2 s: they differ by their truncation errors, measured 6e-9 rad (ref 5.9e-9, MuJoCo 6e-10 from
# a fine solution).
RK4_TOL = 5e-8
# 150 rad/s about a principal axis, dt 1e-3, 200 steps: the exact map rotates by 150 t; round-off
# of 200 quaternion products, measured ~1e-13 rad.
SPIN_ANGLE_TOL = 1e-10

DZHANIBEKOV_I = np.diag([1.0, 2.0, 3.0])
DZHANIBEKOV_W0 = np.array([0.01, 5.0, 0.0])


def _problem(I, w, q=(1.0, 0.0, 0.0, 0.0), x=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0),
             gravity=(0.0, 0.0, 0.0), loads=(), mass=1.0, duration=1.0) -> Problem:
    return Problem("test", "", Body(mass, I), InitialState(x, quat_normalize(q), v, w),
                   gravity, tuple(loads), duration=duration)


def _rotated_inertia(seed: int) -> np.ndarray:
    """A non-diagonal, non-flat SPD inertia (principal moments 2, 3, 4) in a random body frame."""
    rng = np.random.default_rng(seed)
    R = matrix_from_quat(quat_normalize(rng.normal(size=4)))
    return R @ np.diag([2.0, 3.0, 4.0]) @ R.T


def _general_problem(loads=(), gravity=(0.0, 0.0, -9.81)) -> Problem:
    """Non-identity orientation, offset position, non-zero v and w, non-diagonal inertia."""
    return _problem(_rotated_inertia(11), w=[0.7, -1.3, 2.1], q=[0.8, 0.3, -0.4, 0.35],
                    x=[1.5, -2.0, 0.7], v=[0.3, -0.2, 1.1], gravity=gravity, loads=loads, mass=2.5)


def _dzhanibekov(rotated_body_frame: bool) -> Problem:
    """I = diag(1, 2, 3), w0 = (0.01, 5, 0) (world); optionally the same physics in a rotated body
    frame (full non-diagonal tensor, rotated initial orientation)."""
    if not rotated_body_frame:
        return _problem(DZHANIBEKOV_I, DZHANIBEKOV_W0, duration=10.0)
    Rb = matrix_from_quat(quat_normalize([0.9, -0.2, 0.3, 0.25]))  # body' -> body
    q_bb = quat_normalize([0.9, -0.2, 0.3, 0.25])
    return _problem(Rb.T @ DZHANIBEKOV_I @ Rb, DZHANIBEKOV_W0, q=q_bb, duration=10.0)


def _max_angle(a, b) -> float:
    return float(np.max(geodesic_angle(a.quaternion_wxyz, b.quaternion_wxyz)))


def test_readback_at_t0_equals_initial_state():
    pb = _general_problem()
    s0 = MujocoAdapter(pb, 0.01, "Euler").simulate(1).state(0)
    x, q, v, w = s0.position, s0.quaternion_wxyz, s0.linear_velocity, s0.angular_velocity
    init = pb.initial
    assert np.max(np.abs(x - init.position)) <= READBACK_TOL
    assert np.max(np.abs(q - init.quaternion_wxyz)) <= READBACK_TOL
    assert np.max(np.abs(v - init.linear_velocity)) <= READBACK_TOL
    assert np.max(np.abs(w - init.angular_velocity)) <= READBACK_TOL
    tr = MujocoAdapter(pb, 0.01, "Euler").simulate(1)
    assert np.max(np.abs(tr.angular_velocity[0] - init.angular_velocity)) <= READBACK_TOL


def test_body_frame_is_not_aligned_to_principal_axes():
    """qpos is the case's body frame: the compiler kept the rotated principal frame in body_iquat."""
    a = MujocoAdapter(_general_problem(), 0.01, "Euler")
    m = a.model
    assert np.array_equal(m.body_quat[1], [1.0, 0.0, 0.0, 0.0])
    assert np.array_equal(m.body_pos[1], np.zeros(3))
    assert geodesic_angle(m.body_iquat[1], [1.0, 0.0, 0.0, 0.0]) > 0.1
    I_back = (matrix_from_quat(m.body_iquat[1]) @ np.diag(m.body_inertia[1])
              @ matrix_from_quat(m.body_iquat[1]).T)
    assert np.max(np.abs(I_back - a.problem.body.I_body)) <= 1e-12


@pytest.mark.parametrize("rotated", [False, True], ids=["diag", "full-tensor"])
def test_euler_is_semi_implicit_explicit_gyro(rotated):
    pb = _dzhanibekov(rotated)
    steps = pb.steps(0.01)
    tr = MujocoAdapter(pb, 0.01, "Euler").simulate(steps)
    ref = simulate(pb, "semi-implicit-explicit-gyro", 0.01, steps)
    assert _max_angle(tr, ref) <= SAME_MAP_ANGLE_TOL
    assert np.max(np.abs(tr.angular_velocity - ref.angular_velocity)) <= SAME_MAP_OMEGA_TOL
    # the case does flip, and the other map is far away (the comparison can fail)
    other = simulate(pb, "semi-implicit-implicit-gyro", 0.01, steps)
    assert _max_angle(tr, other) > 0.1


@pytest.mark.parametrize("integrator", ["implicit", "implicitfast", "discrete"])
def test_implicit_family_is_semi_implicit_implicit_gyro(integrator):
    if integrator not in MujocoAdapter.offered_integrators():
        pytest.skip(f"mujoco {mujoco.__version__} has no {integrator} integrator")
    pb = _dzhanibekov(False)
    steps = pb.steps(0.01)
    tr = MujocoAdapter(pb, 0.01, integrator).simulate(steps)
    ref = simulate(pb, "semi-implicit-implicit-gyro", 0.01, steps)
    assert _max_angle(tr, ref) <= SAME_MAP_ANGLE_TOL
    assert np.max(np.abs(tr.angular_velocity - ref.angular_velocity)) <= SAME_MAP_OMEGA_TOL


def test_rk4_is_fourth_order_close_to_reference_rk4():
    pb = _dzhanibekov(False)
    steps = pb.steps(0.005, duration=2.0)
    tr = MujocoAdapter(pb, 0.005, "RK4").simulate(steps)
    ref = simulate(pb, "rk4", 0.005, steps)
    assert _max_angle(tr, ref) <= RK4_TOL
    # not the first-order map
    euler = simulate(pb, "semi-implicit-explicit-gyro", 0.005, steps)
    assert _max_angle(tr, euler) > 100 * RK4_TOL


def test_flat_body_with_off_diagonal_inertia_builds():
    """diag(1, 2, 3) (A + B = C) in random body frames: MuJoCo's own A + B >= C check rejects about
    a third of them by round-off; the adapter must still build them, with the right dynamics."""
    rng = np.random.default_rng(5)
    for _ in range(12):
        R = matrix_from_quat(quat_normalize(rng.normal(size=4)))
        pb = _problem(R @ DZHANIBEKOV_I @ R.T, rng.normal(size=3), q=rng.normal(size=4))
        tr = MujocoAdapter(pb, 0.01, "Euler").simulate(20)
        ref = simulate(pb, "semi-implicit-explicit-gyro", 0.01, 20)
        assert _max_angle(tr, ref) <= SHORT_RUN_TOL
        assert np.max(np.abs(tr.angular_velocity - ref.angular_velocity)) <= SHORT_RUN_TOL


def _step_by_step(pb: Problem, dt: float, integrator: str, steps: int):
    """(adapter, trajectory or EngineDiverged) of the plainest path through advance(): no
    mujoco.rollout, the warning counters read after every step (the yardstick of the fast paths)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mujoco_adapter, "_ROLLOUT_MIN_STEPS", 10 ** 9)
        mp.setattr(mujoco_adapter, "_CHECK_EVERY", 1)
        a = MujocoAdapter(pb, dt, integrator)
        try:
            return a, a.simulate(steps)
        except EngineDiverged as e:
            return a, e


def _push_loads():
    return (Load(force=np.array([3.0, -1.0, 2.0]), body_point=np.array([0.4, -0.2, 0.3]), steps=1),)


def test_body_point_push_torque_and_clear():
    """A one-step push at a body point on a rotated moving body: torque (R r_b) x f, then no load."""
    dt, steps = 0.01, 40
    pb = _general_problem(loads=_push_loads())
    a = MujocoAdapter(pb, dt, "Euler")
    tr = a.simulate(steps)
    ref = simulate(pb, "semi-implicit-explicit-gyro", dt, steps)
    assert _max_angle(tr, ref) <= SHORT_RUN_TOL
    for field in ("position", "linear_velocity", "angular_velocity"):
        assert np.max(np.abs(getattr(tr, field) - getattr(ref, field))) <= SHORT_RUN_TOL, field
    # the angular momentum change of the pushed step matches the reference map's
    I = pb.body.I_body
    dL = np.diff(angular_momentum(I, tr.quaternion_wxyz[:2], tr.angular_velocity[:2]), axis=0)[0]
    dL_ref = np.diff(angular_momentum(I, ref.quaternion_wxyz[:2], ref.angular_velocity[:2]), axis=0)[0]
    assert np.max(np.abs(dL - dL_ref)) <= SHORT_RUN_TOL
    # ... and differs from an unrotated arm r_b x f by more than round-off (the test can fail)
    ld = pb.loads[0]
    tau_right = np.cross(pb.R0 @ ld.body_point, ld.force)
    tau_wrong = np.cross(ld.body_point, ld.force)
    assert np.linalg.norm(dt * (tau_right - tau_wrong)) > 1e3 * SHORT_RUN_TOL
    # xfrc_applied is zero after the run (and the later steps follow the unloaded map, above)
    assert not np.any(a.data.xfrc_applied)


def test_step_by_step_path_clears_xfrc_and_matches_fast_path():
    """The plainest path (a step at a time, counters read every step) gives the fast path's
    result, with world-point, body-point, world- and body-torque loads switching on and off, and
    leaves xfrc_applied cleared."""
    loads = _push_loads() + (
        Load(force=np.array([0.0, 2.0, -1.0]), point=np.array([0.5, 0.5, 0.5]), start=0.05, steps=3),
        Load(torque=np.array([0.2, 0.0, -0.1]), start=0.02, end=0.12),
        Load(body_torque=np.array([0.0, 0.3, 0.1]), start=0.1),
    )
    dt, steps = 0.01, 20
    pb = _general_problem(loads=loads)
    a = MujocoAdapter(pb, dt, "Euler")
    fast = a.simulate(steps)
    assert not np.any(a.data.xfrc_applied)
    b, slow = _step_by_step(pb, dt, "Euler", steps)
    assert not np.any(b.data.xfrc_applied)
    for field in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        assert np.array_equal(getattr(fast, field), getattr(slow, field)), field
    ref = simulate(pb, "semi-implicit-explicit-gyro", dt, steps)
    assert _max_angle(fast, ref) <= SHORT_RUN_TOL
    assert np.max(np.abs(fast.angular_velocity - ref.angular_velocity)) <= SHORT_RUN_TOL
    assert np.max(np.abs(fast.position - ref.position)) <= SHORT_RUN_TOL


def test_fast_spin_is_not_clamped():
    """150 rad/s about a body axis at dt = 1e-3: orientation follows the exact rotation angle."""
    q0 = quat_normalize([0.6, -0.3, 0.5, 0.4])
    axis_body = np.array([1.0, 0.0, 0.0])
    w_world = 150.0 * matrix_from_quat(q0) @ axis_body
    pb = _problem(DZHANIBEKOV_I, w_world, q=q0, duration=0.2)
    dt, steps = 1e-3, 200
    tr = MujocoAdapter(pb, dt, "Euler").simulate(steps)
    t = tr.t
    exact = quat_multiply(q0, quat_from_rotvec(np.outer(150.0 * t, axis_body)))
    assert_same_rotation(tr.quaternion_wxyz, exact, SPIN_ANGLE_TOL)
    assert np.max(np.abs(np.linalg.norm(tr.angular_velocity, axis=1) - 150.0)) <= 1e-9


def test_blow_up_raises_engine_diverged(tmp_path, monkeypatch):
    """I = diag(1,2,3), w0 = (0.1, 50, 0), dt 0.01, Euler: MuJoCo's BADQACC warning ends the run
    (otherwise MuJoCo would reset the body to rest and carry on)."""
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to ./MUJOCO_LOG.TXT
    pb = _problem(DZHANIBEKOV_I, [0.1, 50.0, 0.0], duration=30.0)
    with pytest.raises(EngineDiverged) as info:
        MujocoAdapter(pb, 0.01, "Euler").simulate(3000)
    e = info.value
    assert "BADQACC" in e.reason
    assert e.t < 30.0
    assert len(e.trajectory) == round(e.t / 0.01) + 1
    assert np.max(np.abs(e.trajectory.angular_velocity[-1])) > 1e6  # not reset to rest
    # the step-by-step path sees the same warning at the same step
    _, e2 = _step_by_step(pb, 0.01, "Euler", 3000)
    assert isinstance(e2, EngineDiverged) and e2.t == e.t


def test_recorded_settings():
    pb = _general_problem(gravity=(0.5, -1.0, -3.0))
    a = MujocoAdapter(pb, 0.004, "implicit")
    s = a.settings
    assert s["timestep"] == {"default": 0.002, "set": 0.004}
    assert s["gravity"] == {"default": [0.0, 0.0, -9.81], "set": [0.5, -1.0, -3.0]}
    assert s["integrator"] == {"default": "Euler", "set": "implicit"}
    assert a.model.opt.timestep == 0.004
    assert a.model.opt.integrator == int(mujoco.mjtIntegrator.mjINT_IMPLICIT)
    if hasattr(mujoco.mjtDisableBit, "mjDSBL_AUTORESET"):
        assert s["autoreset"] == {"default": True, "set": False}
    assert "compiler.alignfree" not in s or s["compiler.alignfree"]["set"] is False


def test_integrators_and_conventions():
    offered = MujocoAdapter.offered_integrators()
    assert offered[0] == "Euler"
    assert set(offered) <= {"Euler", "RK4", "implicit", "implicitfast", "discrete"}
    assert {"RK4", "implicit", "implicitfast"} <= set(offered)
    for key in ("quaternion order", "angular velocity frame", "inertia input", "velocity clamp",
                "damping", "sleeping", "freebody sets"):
        assert MujocoAdapter.conventions[key]
    with pytest.raises(ValueError):
        MujocoAdapter(_general_problem(), 0.01, "rk4")


# --- advance()'s fast paths (mujoco.rollout, the chunked Python loop) against a step at a time ----

def _assert_same_trajectory(a, b):
    """Bit-for-bit equality (NaN == NaN) of two trajectories, t included."""
    for field in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field


# --- loads at every RK4 stage -------------------------------------------------------------------

# MuJoCo RK4 against its map with the loads at every stage (rkmk4-body in 4.x, rk4-body-exp in
# 3.x), 100 steps of dt 0.01 on a rotated moving body: round-off only, measured 3e-15 rad; the map
# with the loads held over the step is 1e-4 rad or more away on each load kind below.
RK4_PER_STAGE_TOL = 1e-11
RK4_PER_STEP_APART = 1e-6
# Observed order of MuJoCo 4 RK4 under a body couple (convergence_body_torque's body and state, 1 s,
# dt 0.02 -> 0.01 -> 0.005, numerical truth): measured 3.99 (before the loads reached every stage:
# 1.01).  MuJoCo 3.x orientation: 2.00.
RK4_LOADED_ORDER_SLACK = 0.3

STATE_DEPENDENT_LOADS = {
    "body couple": (Load(body_torque=np.array([0.2, -0.1, 0.5])),),
    "body-point force": (Load(force=np.array([0.0, 3.0, -1.0]), body_point=np.array([0.3, 0.2, -0.1])),),
    "world-point force": (Load(force=np.array([1.0, 0.0, 2.0]), point=np.array([0.5, 0.5, 0.5])),),
    "all, switching": (Load(body_torque=np.array([0.2, -0.1, 0.5]), start=0.2, end=0.6),
                       Load(force=np.array([0.0, 3.0, -1.0]), body_point=np.array([0.3, 0.2, -0.1]),
                            start=0.3),
                       Load(force=np.array([1.0, 0.0, 2.0]), point=np.array([0.5, 0.5, 0.5]), steps=40),
                       Load(torque=np.array([0.0, 0.1, 0.0]))),
}


def _rk4_map() -> str:
    return "rkmk4-body" if int(mujoco.__version__.split(".")[0]) >= 4 else "rk4-body-exp"


@pytest.mark.parametrize("kind", STATE_DEPENDENT_LOADS)
def test_rk4_evaluates_the_loads_at_every_stage(kind):
    """Every load reaches every RK4 stage as the case defines it: the run is the map with the loads
    at each stage's state, not the map with the step's start's world wrench held."""
    pb = _general_problem(loads=STATE_DEPENDENT_LOADS[kind])
    dt, steps = 0.01, 100
    a = MujocoAdapter(pb, dt, "RK4")
    tr = a.simulate(steps)
    per_stage = simulate(pb, _rk4_map(), dt, steps, load_sampling="per-stage")
    per_step = simulate(pb, _rk4_map(), dt, steps, load_sampling="per-step")
    assert _max_angle(tr, per_stage) <= RK4_PER_STAGE_TOL
    assert np.max(np.abs(tr.angular_velocity - per_stage.angular_velocity)) <= RK4_PER_STAGE_TOL * 10
    assert np.max(np.abs(tr.position - per_stage.position)) <= RK4_PER_STAGE_TOL * 10
    assert _max_angle(tr, per_step) > RK4_PER_STEP_APART
    assert MujocoAdapter.run_load_sampling(pb) == "per-stage"
    assert not np.any(a.data.xfrc_applied) and not np.any(a.data.qfrc_applied)


def test_rk4_is_fourth_order_under_a_body_couple():
    from freebody.input import load_case
    from freebody.reference_impl.truth import truth_trajectory
    pb = load_case("convergence_body_torque")
    errors = []
    for dt in (0.02, 0.01, 0.005):
        steps = pb.steps(dt)
        tr = MujocoAdapter(pb, dt, "RK4").simulate(steps)
        errors.append(_max_angle(tr, truth_trajectory(pb, dt, steps)))
    order = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    expected = 4 if _rk4_map() == "rkmk4-body" else 2
    assert np.all(np.abs(order - expected) <= RK4_LOADED_ORDER_SLACK), (errors, order)


class _Sentinel:
    """A control callback of someone else's: counts its calls."""

    def __init__(self):
        self.calls = 0

    def __call__(self, m, d):
        self.calls += 1


def test_stage_callback_is_removed_and_leaves_other_data_to_the_previous_one(monkeypatch):
    """mjcb_control is process-global: the adapter installs its callback only while a point force
    acts under RK4, passes another data to the callback it replaced, and restores that one after
    the run, after an exception too."""
    pb = _general_problem(loads=STATE_DEPENDENT_LOADS["all, switching"])
    other_model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='0.1'/>"
                                                 "</body></worldbody></mujoco>")
    other = mujoco.MjData(other_model)
    a = MujocoAdapter(pb, 0.01, "RK4")
    b = MujocoAdapter(pb, 0.01, "RK4")
    sentinel = _Sentinel()  # installed after the models are compiled (the compiler calls it too)
    mujoco.set_mjcb_control(sentinel)
    try:
        a.simulate(100)
        assert sentinel.calls == 0  # the adapter's data went to the adapter's callback
        assert mujoco.get_mjcb_control() is sentinel
        mujoco.mj_step(other_model, other)
        assert sentinel.calls == 1
        # an exception inside the callback's stretch: the callback is still restored
        installed = []

        def failing_loop(self, *args):
            installed.append(mujoco.get_mjcb_control())
            raise RuntimeError("engine failed")

        monkeypatch.setattr(MujocoAdapter, "_loop", failing_loop)
        with pytest.raises(RuntimeError):
            b.simulate(3000)
        assert installed and installed[0] not in (None, sentinel)
        assert mujoco.get_mjcb_control() is sentinel
    finally:
        mujoco.set_mjcb_control(None)
    assert mujoco.get_mjcb_control() is None


def _constant_wrench_loads():
    """Loads with world-fixed wrenches only (COM forces, world couples), switching on and off."""
    return (Load(force=np.array([0.5, -1.0, 2.0]), start=0.1, end=0.9),
            Load(torque=np.array([0.3, -0.2, 0.1]), start=0.4),
            Load(force=np.array([0.0, 0.2, 0.0]), torque=np.array([0.0, 0.0, -0.5]), steps=1))


@pytest.mark.parametrize("integrator", MujocoAdapter.offered_integrators())
@pytest.mark.parametrize("loaded", [False, True, "body couple"], ids=["load-free", "constant-wrench", "body-couple"])
def test_rollout_path_equals_base_loop(integrator, loaded, monkeypatch):
    """Stretches without point forces (none, world-fixed wrenches, body couples in qfrc_applied) run
    through mujoco.rollout: the same trajectory, bit for bit, as the base loop and as the Python
    loop over mj_step."""
    loads = _constant_wrench_loads() if loaded else ()
    if loaded == "body couple":
        loads += (Load(body_torque=np.array([0.0, 0.3, 0.1]), start=0.3, end=1.0),)
    pb = _general_problem(loads=loads)
    dt, steps = 0.005, 260  # stretches of 20 to 140 steps: some rolled out, some looped
    a = MujocoAdapter(pb, dt, integrator)
    fast = a.simulate(steps)
    assert a._roller is not None  # the rollout path was taken
    assert not np.any(a.data.xfrc_applied) and not np.any(a.data.qfrc_applied)
    _, slow = _step_by_step(pb, dt, integrator, steps)
    _assert_same_trajectory(fast, slow)
    monkeypatch.setattr(mujoco_adapter, "_ROLLOUT_MIN_STEPS", 10 ** 9)
    b = MujocoAdapter(pb, dt, integrator)
    _assert_same_trajectory(b.simulate(steps), slow)
    assert b._roller is None
    # not vacuous: the loads do change the motion
    if loaded:
        free = MujocoAdapter(_general_problem(), dt, integrator).simulate(steps)
        assert np.max(np.abs(free.angular_velocity - fast.angular_velocity)) > 1e-3


@pytest.mark.parametrize("split", [0, 1, 20, 150])
def test_simulate_continues_from_current_step(split):
    """simulate(n1) then simulate(n2) = simulate(n1 + n2): times, loads and states continue."""
    loads = _push_loads() + _constant_wrench_loads() + (
        Load(body_torque=np.array([0.0, 0.3, 0.1]), start=0.5, end=0.6),)
    pb = _general_problem(loads=loads)
    dt, steps = 0.005, 200
    whole = MujocoAdapter(pb, dt, "Euler").simulate(steps)
    a = MujocoAdapter(pb, dt, "Euler")
    first, second = a.simulate(split), a.simulate(steps - split)
    assert a.k == steps
    assert len(first) == split + 1 and len(second) == steps - split + 1
    assert second.t[0] == whole.t[split]
    for field in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        joined = np.concatenate([getattr(first, field), getattr(second, field)[1:]])
        assert np.array_equal(joined, getattr(whole, field)), field


def _blow_up_problem(loads=()):
    return _problem(DZHANIBEKOV_I, [0.1, 50.0, 0.0], loads=loads, duration=30.0)


@pytest.mark.parametrize("check_every", [64, 7, 1])
def test_chunked_loop_reports_divergence_at_the_step(check_every, tmp_path, monkeypatch):
    """State-dependent loads run in the Python loop, which reads the warning counters once per
    chunk: the divergence is still reported at the step that raised BADQACC (found by replaying
    the chunk), with the base loop's time, trajectory, counters and message."""
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warnings to ./MUJOCO_LOG.TXT
    monkeypatch.setattr(mujoco_adapter, "_CHECK_EVERY", check_every)
    # a force at a body point (its torque depends on the pose) keeps the run in the Python loop
    pb = _blow_up_problem(loads=(Load(force=np.array([0.0, 1e-9, 0.0]), body_point=np.array([0.1, 0.0, 0.0])),))
    a = MujocoAdapter(pb, 0.01, "Euler")
    with pytest.raises(EngineDiverged) as fast:
        a.simulate(3000)
    b, slow = _step_by_step(pb, 0.01, "Euler", 3000)
    assert isinstance(slow, EngineDiverged)
    assert fast.value.t == slow.t and fast.value.reason == slow.reason
    assert "BADQACC" in fast.value.reason
    assert round(fast.value.t / 0.01) % 64 != 0  # the bad step lies inside a chunk of 64
    _assert_same_trajectory(fast.value.trajectory, slow.trajectory)
    assert a.k == b.k == round(slow.t / 0.01)
    assert [w.number for w in a._all_warnings] == [w.number for w in b._all_warnings]
    assert np.array_equal(a.data.qvel, b.data.qvel) and a.data.time == b.data.time


@pytest.mark.parametrize("path", ["rollout", "python loop"])
def test_divergence_time_equals_base_loop(path, tmp_path, monkeypatch):
    """Load-free blow-up through mujoco.rollout (which stops at the warning and repeats the last
    state) and through the Python loop: the base loop's divergence time and trajectory."""
    monkeypatch.chdir(tmp_path)
    if path == "python loop":
        monkeypatch.setattr(mujoco_adapter, "_ROLLOUT_MIN_STEPS", 10 ** 9)
    pb = _blow_up_problem()
    a = MujocoAdapter(pb, 0.01, "Euler")
    with pytest.raises(EngineDiverged) as fast:
        a.simulate(3000)
    assert (a._roller is not None) == (path == "rollout")
    b, slow = _step_by_step(pb, 0.01, "Euler", 3000)
    assert isinstance(slow, EngineDiverged)
    assert fast.value.t == slow.t and fast.value.reason == slow.reason
    _assert_same_trajectory(fast.value.trajectory, slow.trajectory)
    assert [w.number for w in a._all_warnings] == [w.number for w in b._all_warnings]


def test_rollout_stopped_by_an_unwatched_warning_carries_on(tmp_path, monkeypatch):
    """mujoco.rollout stops at a warning of ANY kind; one the adapter does not watch (here BADQACC,
    unwatched for the test) must not end the run: the Python loop finishes it as the base loop
    would (the state then turns non-finite, as MuJoCo leaves it with auto-reset off)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(mujoco_adapter, "_WATCHED_WARNINGS", ("mjWARN_INERTIA",))
    pb = _blow_up_problem()
    a = MujocoAdapter(pb, 0.01, "Euler")
    fast = a.simulate(300)
    assert a._roller is not None
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mujoco_adapter, "_ROLLOUT_MIN_STEPS", 10 ** 9)
        mp.setattr(mujoco_adapter, "_CHECK_EVERY", 1)
        b = MujocoAdapter(pb, 0.01, "Euler")
        slow = b.simulate(300)
    _assert_same_trajectory(fast, slow)
    assert np.isnan(fast.angular_velocity[-1]).all()  # stepped on past the blow-up
    assert a.data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)].number > 0
    assert [w.number for w in a._all_warnings] == [w.number for w in b._all_warnings]
