"""The MJX adapter against C MuJoCo and through the harness, on the real engines (skipped without
the ``jax`` extra).

Arrays follow freebody's canonical convention (reference_impl/conventions.py): quaternions
(w, x, y, z) body -> world, COM position/velocity in world (m, m/s), angular velocity in world
(rad/s), inertia (3, 3) about the COM in the body frame (kg m^2).

Compiling ``mjx.step`` takes seconds per (integrator, precision): the tests share the Euler
compilations (float64 and float32, CHUNK_STEPS steps per call) and keep horizons short.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax", reason="jax not installed (pip install 'freebody[jax]')")
pytest.importorskip("mujoco.mjx", reason="mujoco-mjx not installed (pip install 'freebody[jax]')")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from freebody.adapters import jax_runtime, mjx_adapter  # noqa: E402
from freebody.adapters.mjx_adapter import CHUNK_STEPS, MjxAdapter  # noqa: E402
from freebody.adapters.mujoco_adapter import MujocoAdapter  # noqa: E402
from freebody.errors import InputError  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402
from freebody.reference_impl.rotations import (geodesic_angle, matrix_from_quat,  # noqa: E402
                                               quat_normalize)
from freebody.run import execute, expand  # noqa: E402

# float64 MJX Euler vs C MuJoCo Euler, the loaded case below, dt 0.01, 60 steps: the same map in
# the same precision, different operation order; measured 3e-15 rad / 2e-16 m / 7e-15 rad/s.
SAME_MAP_ANGLE_TOL = 1e-12
SAME_MAP_POS_TOL = 1e-12
SAME_MAP_OMEGA_TOL = 1e-11
# float32 vs float64 MJX Euler, same case and horizon: float32 round-off (eps 6e-8) over 60 steps,
# measured ~1e-6; float64 round-off would be ~1e-15.  Bounds separate the two precisions.
FLOAT32_DIFF_MIN = 1e-9
FLOAT32_DIFF_MAX = 1e-4
STEPS = 60
DT = 0.01


def _rotated_inertia(seed: int) -> np.ndarray:
    """A non-diagonal SPD inertia (principal moments 2, 3, 4) in a random body frame."""
    rng = np.random.default_rng(seed)
    R = matrix_from_quat(quat_normalize(rng.normal(size=4)))
    return R @ np.diag([2.0, 3.0, 4.0]) @ R.T


def _loaded_problem(seed: int = 11, mass: float = 2.5, w=(0.7, -1.3, 2.1)) -> Problem:
    """Non-diagonal inertia, offset rotated pose, moving, gravity, and every kind of load: a
    body-point force, two world-point forces (overlapping), a world and a body-frame couple."""
    loads = (Load(force=[0.5, -1.0, 2.0], body_point=[0.1, 0.2, -0.3], start=0.0, end=0.35),
             Load(force=[1.0, 0.3, -0.2], point=[2.0, -1.5, 0.9], start=0.1, end=0.5),
             Load(force=[0.0, 0.4, 0.1], point=[1.0, -1.0, 0.2], start=0.2, end=0.4),
             Load(torque=[0.05, 0.0, -0.1], body_torque=[0.1, -0.2, 0.3], start=0.05, steps=30))
    return Problem("mjx-test", "", Body(mass, _rotated_inertia(seed)),
                   InitialState([1.5, -2.0, 0.7], quat_normalize([0.8, 0.3, -0.4, 0.35]),
                                [0.3, -0.2, 1.1], w),
                   [0.0, 0.0, -9.81], loads, duration=STEPS * DT)


def _max_diffs(a, b):
    return (float(np.max(geodesic_angle(a.quaternion_wxyz, b.quaternion_wxyz))),
            float(np.max(np.abs(a.position - b.position))),
            float(np.max(np.abs(a.angular_velocity - b.angular_velocity))))


def test_float64_euler_equals_c_mujoco_euler():
    pb = _loaded_problem()
    mjx_tr = MjxAdapter(pb, DT, "Euler", "float64").simulate(STEPS)
    c_tr = MujocoAdapter(pb, DT, "Euler").simulate(STEPS)
    angle, pos, omega = _max_diffs(mjx_tr, c_tr)
    assert angle <= SAME_MAP_ANGLE_TOL and pos <= SAME_MAP_POS_TOL and omega <= SAME_MAP_OMEGA_TOL, \
        (angle, pos, omega)
    # the loads and gravity did act (a load-free run is far away)
    free = MujocoAdapter(Problem("free", "", pb.body, pb.initial, [0, 0, 0], duration=1.0), DT,
                         "Euler").simulate(STEPS)
    assert float(np.max(geodesic_angle(free.quaternion_wxyz, c_tr.quaternion_wxyz))) > 1e-3


# float64 MJX RK4 vs its map rk4-body-exp, 50 steps of dt 0.01: round-off, measured 4e-15 rad; the
# map's other load sampling is 1e-4 rad or more away on these cases.
RK4_MAP_TOL = 1e-11
RK4_OTHER_SAMPLING_APART = 1e-6


def test_rk4_load_sampling_is_what_it_declares():
    """Body couples reach every MJX RK4 stage (qfrc_applied) in a case without point forces
    (per-stage); with a force at a point the whole wrench is held over the step (per-step)."""
    from freebody.reference_impl.integrators import simulate

    pb = _loaded_problem()
    couple = Problem("mjx-couple", "", pb.body, pb.initial, pb.gravity,
                     (Load(body_torque=[0.3, -0.2, 0.5]), Load(torque=[0.05, 0.0, -0.1], steps=20)),
                     duration=0.5)
    for problem, sampling in ((couple, "per-stage"), (pb, "per-step")):
        assert MjxAdapter.run_load_sampling(problem) == sampling
        run = MjxAdapter(problem, DT, "RK4", "float64").simulate(50)
        same = simulate(problem, "rk4-body-exp", DT, 50, load_sampling=sampling)
        other = simulate(problem, "rk4-body-exp", DT, 50,
                         load_sampling="per-step" if sampling == "per-stage" else "per-stage")
        assert _max_diffs(run, same)[0] <= RK4_MAP_TOL, sampling
        assert _max_diffs(run, other)[0] > RK4_OTHER_SAMPLING_APART, sampling


def test_a_run_continues_from_where_it_stopped():
    pb = _loaded_problem()
    a = MjxAdapter(pb, DT, "Euler", "float64")
    first, second = a.simulate(25), a.simulate(STEPS - 25)
    whole = MujocoAdapter(pb, DT, "Euler").simulate(STEPS)
    assert np.allclose(second.t, whole.t[25:], rtol=0, atol=1e-12)
    assert max(_max_diffs(first, _head(whole, 26))) <= SAME_MAP_OMEGA_TOL
    assert float(np.max(geodesic_angle(second.quaternion_wxyz, whole.quaternion_wxyz[25:]))) \
        <= SAME_MAP_ANGLE_TOL


def _head(tr, n):
    from freebody.reference_impl.conventions import Trajectory
    return Trajectory(tr.t[:n], tr.position[:n], tr.quaternion_wxyz[:n], tr.linear_velocity[:n],
                      tr.angular_velocity[:n])


@pytest.mark.parametrize("chunk_steps", [1, 7])
def test_a_run_in_pieces_equals_the_run_in_one_piece(chunk_steps):
    """advance(n) with n below CHUNK_STEPS runs a padded compiled chunk; the Data carried on is that
    of the last real step, so pieces of any size (also across a CHUNK_STEPS boundary) give the
    one-piece run bit for bit, and the same final Data."""
    pb = _loaded_problem()
    n = CHUNK_STEPS + 10 if chunk_steps == 7 else 40
    one = MjxAdapter(pb, DT, "Euler", "float64")
    whole = one.simulate(n)
    a = MjxAdapter(pb, DT, "Euler", "float64")
    pieces = a.simulate(n, chunk_steps=chunk_steps)
    assert a.k == one.k == n
    for f in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        assert np.array_equal(getattr(pieces, f), getattr(whole, f)), f
    for f in ("time", "qpos", "qvel", "qacc", "qacc_warmstart"):
        assert np.array_equal(np.asarray(getattr(a._d, f)), np.asarray(getattr(one._d, f))), f


def test_float32_run_is_float32_and_reported_so():
    pb = _loaded_problem()
    x64_before = jax.config.jax_enable_x64
    specs = expand([pb], ["mjx"], ["Euler"], [DT], None, ["float32"])
    assert [(s.engine, s.integrator, s.precision) for s in specs] == [("mjx", "Euler", "float32")]
    out = execute(specs[0])
    r = out.result
    assert r.status == "ok", r.message
    assert r.precision == "float32" and r.to_json()["precision"] == "float32"
    assert r.engine_settings["jax_enable_x64"]["set"] is False
    assert isinstance(r.compile_time_s, float) and 0.0 <= r.compile_time_s <= r.wall_time_s
    # it really computed in float32: far from float64 beyond float64 round-off, close to it
    f64 = MjxAdapter(pb, DT, "Euler", "float64").simulate(STEPS)
    angle, pos, omega = _max_diffs(out.trajectory, f64)
    assert FLOAT32_DIFF_MIN < max(angle, pos, omega) < FLOAT32_DIFF_MAX, (angle, pos, omega)
    a = MjxAdapter(pb, DT, "Euler", "float32")
    a.simulate(3)
    assert a._d.qpos.dtype == jnp.float32
    # the process-wide flag was left alone
    assert jax.config.jax_enable_x64 == x64_before == r.engine_settings["jax_enable_x64"]["default"]


def test_float32_guard_rejects_a_float64_computation():
    """The compile-time check that a float32 run has no f64 operation can fail."""
    pb = _loaded_problem()
    a = MjxAdapter(pb, DT, "Euler", "float64")
    with jax_runtime.x64_scope(True):
        rows = jnp.zeros((2, jax_runtime.LOAD_ROW))
        with pytest.raises(RuntimeError, match="float64"):
            jax_runtime.compiled("guard-probe", jax.jit(mjx_adapter._chunk), "float32",
                                 (a._m, a._d, rows, jnp.int32(2)))


def test_switching_precision_scopes_does_not_reuse_stale_traces():
    """JAX 0.10 reuses a trace of jnp.tril on a numpy constant across x64 modes (MJX RK4 does
    this) and then fails to lower; the adapter's scope clears the caches on a mode change."""
    A = np.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]])

    def f(x):
        return x * jnp.tril(A).sum(axis=0)

    got = []
    for on in (True, False, True):
        with jax_runtime.x64_scope(on):
            x = jnp.ones(3)
            got.append(jax.jit(f).lower(x).compile()(x).dtype)
    assert got == [jnp.float64, jnp.float32, jnp.float64]


def test_precision_selection_in_the_matrix():
    pb = _loaded_problem()
    both = expand([pb], ["mujoco", "mjx"], ["Euler"], [DT], None)
    assert sorted((s.engine, s.precision) for s in both) == [
        ("mjx", "float32"), ("mjx", "float64"), ("mujoco", "float64")]
    only32 = expand([pb], ["mujoco", "mjx"], ["Euler"], [DT], None, ["float32"])
    assert [(s.engine, s.precision) for s in only32] == [("mjx", "float32")]
    with pytest.raises(InputError, match="float32"):
        expand([pb], ["mujoco"], None, [DT], None, ["float32"])
    with pytest.raises(InputError, match="unknown precision"):
        expand([pb], ["mjx"], None, [DT], None, ["float16"])


def test_integrators_offered_and_refused():
    assert MjxAdapter.offered_integrators() == ("Euler", "RK4", "implicitfast")
    pb = _loaded_problem()
    for bad in ("implicit", "discrete"):
        with pytest.raises(ValueError, match="no integrator"):
            MjxAdapter(pb, DT, bad, "float64")
    with pytest.raises(ValueError, match="precision"):
        MjxAdapter(pb, DT, "Euler", "float16")


def test_blow_up_is_reported_diverged():
    """MJX has no instability warning: the harness sees the state leave its bounds."""
    pb = Problem("blowup", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState([0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0.1, 50.0, 0.0]), [0, 0, 0],
                 duration=5.0)
    spec = expand([pb], ["mjx"], ["Euler"], [DT], None, ["float64"])[0]
    r = execute(spec).result
    assert r.status == "diverged", (r.status, r.message)
    assert r.diverged_at_s is not None and r.diverged_at_s < 5.0


def test_simulate_batch_equals_single_runs_bit_for_bit():
    """The same lanes program alone and batched (LANES): the same numbers, not just to round-off."""
    n = 30
    problems = [_loaded_problem(seed=11), _loaded_problem(seed=12, mass=1.2, w=(3.0, 0.2, -1.0)),
                Problem("plain", "", Body(0.7, np.diag([1.0, 2.0, 3.0])),
                        InitialState([0, 0, 0], [1, 0, 0, 0], [1.0, 0, 0], [0.01, 5.0, 0.0]),
                        [0.0, 0.0, -1.0], duration=1.0)]
    assert MjxAdapter.supports_batch
    batch = MjxAdapter.simulate_batch(problems, DT, n, "Euler", "float64")
    assert len(batch.trajectories) == 3 and batch.diverged_at_s == [None, None, None]
    assert batch.compile_time_s >= 0.0 and batch.step_time_s > 0.0
    for pb, tr in zip(problems, batch.trajectories):
        single = MjxAdapter(pb, DT, "Euler", "float64").simulate(n)
        assert len(tr) == n + 1
        for field in ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
            assert np.array_equal(getattr(tr, field), getattr(single, field)), field
