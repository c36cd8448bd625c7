"""The DART adapter against real dartpy: conventions at t = 0, the reference map it should
reproduce (``semi-implicit-explicit-gyro``), loads and their frames, no velocity clamp, no
sleeping, and a blow-up that raises EngineDiverged without DART's stderr noise reaching the
terminal."""
from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("dartpy", reason="dartpy not installed (pip install 'freebody[engines]')")

from freebody.adapters.base import EngineDiverged, load_adapter  # noqa: E402
from freebody.adapters.dart_adapter import _WORLD, DartAdapter  # noqa: E402
from freebody.reference_impl.conventions import (angular_momentum,  # noqa: E402
                                                  angular_velocity_body_from_world)
from freebody.reference_impl.integrators import simulate as reference_simulate  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402
from freebody.reference_impl.rotations import (matrix_from_quat,  # noqa: E402
                                                quat_from_rotvec, quat_multiply, quat_normalize)
from freebody.testing import assert_same_rotation  # noqa: E402

INTEGRATOR = "semi-implicit-euler"
REFERENCE_MAP = "semi-implicit-explicit-gyro"

# t = 0 read-back: float64 pose/velocity written and read through DART's transforms (round-off).
READBACK_TOL = 1e-12
# Torque-free intermediate-axis tumble, 10 s at dt = 0.01: DART's log-map coordinates and the
# reference's quaternion differ by round-off (~1e-15 at 1 s), which the Dzhanibekov instability
# amplifies; measured 3.4e-9 rad (orientation) and 5e-9 rad/s at 10 s (dartpy 6.20).
DZHANIBEKOV_ANGLE_TOL = 1e-7  # rad
DZHANIBEKOV_OMEGA_TOL = 1e-7  # rad/s
# Short, non-chaotic runs (gravity, loads, frame conversions): round-off only;
# measured <= 1e-13 over 200 steps at dt = 0.01.
ROUNDOFF_TOL = 1e-11
# 150 rad/s about a principal axis, 200 steps at dt = 1e-3: the map is exact for a principal-axis
# spin, so only round-off remains (measured 7e-15 rad, 5e-13 rad/s).
SPIN_ANGLE_TOL = 1e-10  # rad
SPIN_OMEGA_TOL = 1e-9  # rad/s

# A generic state: non-identity orientation, offset position, non-zero v and w, full inertia.
I_FULL = np.array([[2.0, 0.3, -0.2], [0.3, 3.0, 0.1], [-0.2, 0.1, 4.0]])  # kg m^2
Q0 = quat_normalize(np.array([0.8, 0.3, -0.4, 0.2]))
X0, V0, W0 = np.array([1.0, -2.0, 3.0]), np.array([0.5, -0.2, 0.3]), np.array([0.3, -1.1, 2.0])
# diag(1, 2, 3) seen in a body frame rotated 40 deg about (1, 1, 1) (cases/dzhanibekov_rotated).
I_ROTATED = np.array([[1.373538252809395, 0.11576545177795344, -0.6264617471906059],
                      [0.11576545177795348, 2.115765451777954, 0.510696295412652],
                      [-0.6264617471906058, 0.510696295412652, 2.510696295412652]])
Q_ROTATED = np.array([0.9396926207859083, 0.19746542181734925, 0.19746542181734925,
                      0.19746542181734925])


def problem(I=I_FULL, q=Q0, x=X0, v=V0, w=W0, gravity=(0.0, 0.0, -9.81), loads=(), mass=2.5,
            duration=1.0) -> Problem:
    return Problem("test", "", Body(mass, np.asarray(I, float)),
                   InitialState(np.asarray(x, float), np.asarray(q, float), np.asarray(v, float),
                                np.asarray(w, float)),
                   np.asarray(gravity, float), loads=tuple(loads), duration=duration)


def run(pb: Problem, dt: float, steps: int | None = None):
    steps = pb.steps(dt) if steps is None else steps
    adapter = DartAdapter(pb, dt, INTEGRATOR)
    return adapter, adapter.simulate(steps), reference_simulate(pb, REFERENCE_MAP, dt, steps)


def test_registry_loads_the_adapter():
    assert load_adapter("dart") is DartAdapter
    assert DartAdapter.integrators == (INTEGRATOR,)
    assert DartAdapter.engine_version().startswith(("6.", "7."))


def test_joint_coordinates_convert_to_dart_frames():
    """advance() converts the raw FreeJoint coordinates ([log R; x], [w; v] in the frame probed
    by _coordinate_frames) into what DART's frame-explicit getters say, at t = 0 (the state set
    in build) and after a step; the full inertia tensor went in undiagonalised."""
    pb = problem()
    adapter = DartAdapter(pb, 0.01, INTEGRATOR)
    body = adapter.body
    dart_t0 = (body.getWorldTransform(), body.getCOMLinearVelocity(_WORLD, _WORLD),
               body.getAngularVelocity(_WORLD, _WORLD))
    tr = adapter.simulate(1)
    dart_t1 = (body.getWorldTransform(), body.getCOMLinearVelocity(_WORLD, _WORLD),
               body.getAngularVelocity(_WORLD, _WORLD))
    for i, (T, v, w) in enumerate((dart_t0, dart_t1)):
        assert np.abs(tr.position[i] - T.translation()).max() < READBACK_TOL
        assert np.abs(matrix_from_quat(tr.quaternion_wxyz[i]) - T.rotation()).max() < READBACK_TOL
        assert np.abs(tr.linear_velocity[i] - v).max() < READBACK_TOL
        assert np.abs(tr.angular_velocity[i] - w).max() < READBACK_TOL
    assert np.abs(tr.position[0] - X0).max() < READBACK_TOL
    assert_same_rotation(tr.quaternion_wxyz[0], Q0, READBACK_TOL)
    assert np.abs(tr.linear_velocity[0] - V0).max() < READBACK_TOL
    assert np.abs(tr.angular_velocity[0] - W0).max() < READBACK_TOL
    assert np.abs(adapter.body.getInertia().getMoment() - I_FULL).max() < READBACK_TOL


def test_settings_recorded_and_in_effect():
    pb = problem(gravity=(0.5, -1.0, -3.0))
    adapter = DartAdapter(pb, 0.004, INTEGRATOR)
    s = adapter.settings
    assert s["time_step"] == {"default": 1e-3, "set": 0.004}
    assert s["gravity"] == {"default": [0.0, 0.0, -9.81], "set": [0.5, -1.0, -3.0]}
    assert s["deactivation_enabled"] == {"default": True, "set": False}
    assert adapter.world.getTimeStep() == 0.004
    assert adapter.world.getDeactivationOptions().mEnabled is False
    np.testing.assert_array_equal(adapter.world.getGravity(), [0.5, -1.0, -3.0])


@pytest.mark.parametrize("I, q", [(np.diag([1.0, 2.0, 3.0]), (1.0, 0.0, 0.0, 0.0)),
                                  (I_ROTATED, Q_ROTATED)], ids=["diagonal", "rotated"])
def test_dzhanibekov_reproduces_reference_map(I, q):
    pb = problem(I=I, q=q, x=(0, 0, 0), v=(0, 0, 0), w=(0.01, 5.0, 0.0), gravity=(0, 0, 0),
                 mass=1.0, duration=10.0)
    _, tr, ref = run(pb, 0.01)
    assert_same_rotation(tr.quaternion_wxyz, ref.quaternion_wxyz, DZHANIBEKOV_ANGLE_TOL)
    assert np.abs(tr.angular_velocity - ref.angular_velocity).max() < DZHANIBEKOV_OMEGA_TOL
    # and the body really flipped (principal-frame w_y changed sign): not a steady spin
    R0 = matrix_from_quat(np.asarray(q, float))  # body -> principal axes (= world at t = 0)
    w_body = angular_velocity_body_from_world(tr.quaternion_wxyz, tr.angular_velocity)
    w_principal = w_body @ R0.T
    assert w_principal[:, 1].min() < -4.0


def test_gravity_reproduces_reference_map():
    pb = problem(duration=2.0)
    _, tr, ref = run(pb, 0.01)
    assert np.abs(tr.position - ref.position).max() < ROUNDOFF_TOL
    assert np.abs(tr.linear_velocity - ref.linear_velocity).max() < ROUNDOFF_TOL
    assert_same_rotation(tr.quaternion_wxyz, ref.quaternion_wxyz, ROUNDOFF_TOL)
    assert np.abs(tr.angular_velocity - ref.angular_velocity).max() < ROUNDOFF_TOL
    # the semi-implicit COM: x_n = x0 + v0 t + g h^2 n (n + 1) / 2
    n, h = len(tr) - 1, 0.01
    expect = X0 + V0 * n * h + np.array([0, 0, -9.81]) * h * h * n * (n + 1) / 2
    assert np.abs(tr.position[-1] - expect).max() < ROUNDOFF_TOL


@pytest.mark.parametrize("where", ["body_point", "point"])
def test_push_at_offset_point_gives_its_torque(where):
    """One step of a force at a point off the COM of a rotated, moving body."""
    f, h = np.array([3.0, -1.0, 2.0]), 0.01
    body_r = np.array([0.2, -0.3, 0.15])  # body frame, from the COM
    world_point = X0 + matrix_from_quat(Q0) @ body_r  # the same material point at t = 0
    load = (Load(force=f, body_point=body_r, steps=1) if where == "body_point"
            else Load(force=f, point=world_point, steps=1))
    pb = problem(loads=[load], gravity=(0, 0, 0))
    _, tr, ref = run(pb, h, steps=1)
    L = angular_momentum(I_FULL, tr.quaternion_wxyz, tr.angular_velocity)
    L_ref = angular_momentum(I_FULL, ref.quaternion_wxyz, ref.angular_velocity)
    np.testing.assert_allclose(L[1] - L[0], L_ref[1] - L_ref[0], rtol=0, atol=ROUNDOFF_TOL)
    # the angular impulse of the load, in the start-of-step frame, is h (r - x) x f: compare the
    # body-frame w+ with the torque-free step's (the map is linear in tau for w_b+)
    free = reference_simulate(problem(gravity=(0, 0, 0)), REFERENCE_MAP, h, 1)
    wb = angular_velocity_body_from_world(tr.quaternion_wxyz[1], tr.angular_velocity[1])
    wb_free = angular_velocity_body_from_world(free.quaternion_wxyz[1], free.angular_velocity[1])
    impulse = matrix_from_quat(Q0) @ I_FULL @ (wb - wb_free)
    tau = np.cross(world_point - X0, f)
    np.testing.assert_allclose(impulse, h * tau, rtol=0, atol=ROUNDOFF_TOL)
    np.testing.assert_allclose(tr.linear_velocity[1] - V0, h * f / 2.5, rtol=0, atol=ROUNDOFF_TOL)


def test_all_load_kinds_match_reference():
    loads = [Load(force=np.array([1.0, 2.0, -3.0]), point=np.array([1.5, -1.8, 3.4]), steps=30),
             Load(force=np.array([-2.0, 0.5, 1.0]), body_point=np.array([0.2, 0.1, -0.3]),
                  start=0.1, end=0.25),
             Load(torque=np.array([0.3, -0.2, 0.5]), start=0.05, steps=10),
             Load(body_torque=np.array([-0.4, 0.1, 0.2]), start=0.2),
             Load(force=np.array([0.0, 1.0, 0.0]), start=0.3, steps=5)]
    pb = problem(loads=loads, duration=0.5)
    _, tr, ref = run(pb, 0.01)
    assert_same_rotation(tr.quaternion_wxyz, ref.quaternion_wxyz, ROUNDOFF_TOL)
    assert np.abs(tr.angular_velocity - ref.angular_velocity).max() < ROUNDOFF_TOL
    assert np.abs(tr.position - ref.position).max() < ROUNDOFF_TOL
    assert np.abs(tr.linear_velocity - ref.linear_velocity).max() < ROUNDOFF_TOL


def test_external_forces_clear_after_each_step():
    """DART clears external forces after every World.step (the adapter re-applies them before
    each step): after the loaded step none is left, and the motion afterwards is force-free."""
    load = Load(force=np.array([4.0, 0.0, 1.0]), body_point=np.array([0.0, 0.3, 0.0]),
                torque=np.array([0.0, 0.5, 0.0]), steps=1)
    pb = problem(loads=[load], gravity=(0, 0, 0))
    adapter = DartAdapter(pb, 0.01, INTEGRATOR)
    tr = adapter.simulate(1)
    np.testing.assert_allclose(tr.linear_velocity[1] - V0, 0.01 * load.force / 2.5, rtol=0,
                               atol=ROUNDOFF_TOL)  # the load acted
    np.testing.assert_array_equal(adapter.body.getExternalForceGlobal(), np.zeros(6))
    adapter2, tr, ref = run(pb, 0.01, steps=20)
    assert np.abs(tr.linear_velocity[1:] - tr.linear_velocity[1]).max() < ROUNDOFF_TOL
    assert np.abs(tr.angular_velocity - ref.angular_velocity).max() < ROUNDOFF_TOL


def test_fast_spin_is_not_clamped():
    q0 = quat_normalize(np.array([0.9, 0.1, -0.3, 0.2]))
    w = matrix_from_quat(q0) @ np.array([0.0, 0.0, 150.0])  # about body z, a principal axis
    pb = problem(I=np.diag([1.0, 2.0, 3.0]), q=q0, w=w, v=(0, 0, 0), gravity=(0, 0, 0), mass=1.0)
    _, tr, _ = run(pb, 1e-3, steps=200)
    exact = quat_multiply(quat_from_rotvec(np.outer(tr.t, w)), q0)  # 30 rad turned at t = 0.2 s
    assert_same_rotation(tr.quaternion_wxyz, exact, SPIN_ANGLE_TOL)
    assert np.abs(tr.angular_velocity - w).max() < SPIN_OMEGA_TOL


def test_body_at_rest_does_not_fall_asleep():
    """At rest for 2 s (4x DART's default time-until-sleep), then one push: it must move.
    (dartpy 6.20 deactivates only bodies in contact islands, so a lone free body would not
    sleep even with the default; the adapter switches deactivation off regardless.)"""
    h, f = 0.01, np.array([0.0, 2.0, 0.0])
    pb = problem(q=(1, 0, 0, 0), x=(0, 0, 0), v=(0, 0, 0), w=(0, 0, 0), gravity=(0, 0, 0),
                 loads=[Load(force=f, body_point=np.array([0.1, 0.0, 0.0]), start=2.0, steps=1)],
                 mass=1.0, duration=2.5)
    adapter, tr, ref = run(pb, h)
    assert adapter.world.getDeactivationOptions().mEnabled is False
    k = 200
    assert np.abs(tr.position[k]).max() == 0.0 and np.abs(tr.linear_velocity[k]).max() == 0.0
    np.testing.assert_allclose(tr.linear_velocity[-1], h * f, rtol=0, atol=ROUNDOFF_TOL)
    assert tr.position[-1, 1] > 0.9 * 50 * h * h * f[1]
    assert np.abs(tr.angular_velocity[-1] - ref.angular_velocity[-1]).max() < ROUNDOFF_TOL


BLOWUP = dict(I=np.diag([1.0, 2.0, 3.0]), q=(1, 0, 0, 0), x=(0, 0, 0), v=(0, 0, 0),
              w=(0.1, 50.0, 0.0), gravity=(0, 0, 0), mass=1.0, duration=10.0)


def test_blow_up_raises_and_keeps_the_terminal_quiet(capfd):
    pb = problem(**BLOWUP)
    adapter = DartAdapter(pb, 0.01, INTEGRATOR)
    with pytest.raises(EngineDiverged) as info:
        adapter.simulate(pb.steps(0.01))
    err = info.value
    out, stderr = capfd.readouterr()
    assert stderr == "" and out == "", "DART's warnings reached the terminal"
    assert "non-finite" in err.reason.lower()
    assert err.reason.count("|") <= 2  # a few captured lines at most
    tr = err.trajectory
    n = len(tr)
    assert 100 < n < 1000 and err.t == pytest.approx((n - 1) * 0.01)
    assert np.isfinite(tr.quaternion_wxyz[:-1]).all()  # finite up to the bad sample
    assert not np.isfinite(tr.quaternion_wxyz[-1]).all()  # which is not passed off as identity
    # fd 2 is restored afterwards
    os.write(2, b"still here\n")
    assert capfd.readouterr().err == "still here\n"


def test_advancing_past_the_blow_up_raises_again_quietly(capfd):
    """After EngineDiverged the adapter stands at the bad sample (self.k); advancing on from there
    (DART keeps printing its warnings) raises again at the next step, times counted from k."""
    pb = problem(**BLOWUP)
    adapter = DartAdapter(pb, 0.01, INTEGRATOR)
    with pytest.raises(EngineDiverged) as info:
        adapter.simulate(pb.steps(0.01))
    k = adapter.k
    assert k == len(info.value.trajectory) - 1
    with pytest.raises(EngineDiverged) as again:
        adapter.advance(3)
    assert "non-finite" in again.value.reason.lower()
    assert again.value.t == pytest.approx((k + 1) * 0.01) and adapter.k == k + 1
    np.testing.assert_array_equal(again.value.trajectory.t, np.array([k, k + 1]) * 0.01)
    assert capfd.readouterr().err == ""


def test_bare_loop_steps_the_adapters_world():
    """bare_loop (freebody bench): World.step and the raw joint coordinates on the adapter's
    world, the coordinates advance() records for a load-free body."""
    pb = problem()
    P, V = DartAdapter(pb, 0.01, INTEGRATOR).bare_loop(5)()
    adapter = DartAdapter(pb, 0.01, INTEGRATOR)
    tr = adapter.simulate(5)
    assert P.shape == V.shape == (6, 6)
    np.testing.assert_array_equal(P[:, 3:], tr.position)
    if adapter._frames == "world":  # DART 6.20: velocity coordinates are [w; v] world
        np.testing.assert_array_equal(V[:, :3], tr.angular_velocity)
        np.testing.assert_array_equal(V[:, 3:], tr.linear_velocity)
