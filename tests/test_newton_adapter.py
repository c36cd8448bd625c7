"""The Newton adapter against real Newton (on Warp's CPU device): Newton's defaults and traps, the
settings the adapter forces (read back), each trap check failing once the adapter stops handling
its trap, the state read from ``body_q``, and each solver following its engine-equivalent map to
float32 round-off (far closer to it than to any other map).

Every run is float32 (Newton has no other precision).  Warp compiles each solver's kernels on first
use (5 to 40 s per solver on a cold kernel cache, milliseconds from the cache on disk after that),
so every test that steps Newton is marked slow; the fast ones check conversions and documented
defaults without stepping.  The adapter's conformance (t = 0 read-back, pushes, chunking,
settings) is in ``test_adapter_conformance.py``, parametrised over the registry.
"""
from __future__ import annotations

import inspect
import json
import subprocess
import sys

import numpy as np
import pytest

newton = pytest.importorskip("newton", reason="newton not installed (pip install 'freebody[newton]')")

import warp as wp  # noqa: E402

import freebody.adapters.newton_adapter as NA  # noqa: E402
from freebody.adapters.base import load_adapter  # noqa: E402
from freebody.adapters.loads import LoadSchedule  # noqa: E402
from freebody.adapters.newton_adapter import NewtonAdapter  # noqa: E402
from freebody.input import load_case  # noqa: E402
from freebody.reference_impl.conventions import (angular_velocity_body_from_world,  # noqa: E402
                                                 angular_velocity_world_from_body, quat_xyzw_from_wxyz)
from freebody.reference_impl.integrators import simulate  # noqa: E402
from freebody.reference_impl.problem import Load, Problem  # noqa: E402
from freebody.reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec  # noqa: E402
from freebody.run.selfcheck import run_trap_checks  # noqa: E402
from freebody.testing import I_FULL, assert_same_rotation, general_problem, make_adapter  # noqa: E402

# The solvers freebody runs by default (kamino is opt-in: ~35 ms a step) and each one's map.
SOLVERS = ("semi-implicit", "featherstone", "xpbd", "steel", "vbd")
MAPS = {"semi-implicit": "quat-rate-semi-implicit", "featherstone": "quat-rate-semi-implicit",
        "xpbd": "quat-rate-semi-implicit", "steel": "quat-rate-cayley-gyro",
        "vbd": "quat-rate-pose-velocity", "kamino": "explicit-gyro-rescaled-torque-last"}

# --- tolerances (float32 runs) ------------------------------------------------------------------
# Values set through Newton come back as their float32 rounding: relative 6e-8.
READBACK_RTOL = 1e-6
# A solver's run against its own float64 map, as a fraction of the distance to the nearest other
# map (largest orientation difference, MAP_CASES at dt 0.01, 200 steps): measured 0.001-0.072
# (vbd on world_torque); a wrong map is 1 (or more) by definition.
OWN_VS_OTHER_MAP = 0.1
# ... and in absolute terms (rad): float32 round-off growth over 200 steps, measured 3e-7
# (featherstone, world_torque) to 1.3e-4 (vbd, offset_push: its finite-difference velocities).
OWN_MAP_RAD = 5e-4
# test_float32_spin_bias_documented: per-step factor - 1 of |w| of a steady spin (measured: semi-implicit
# 1.8e-7, 1.9e-7; xpbd 2.1e-7, 2.4e-7; steel 1.5e-7, 1.9e-7; featherstone 7e-11, 0; vbd -1.07e-4,
# its map's -(h |w|)^2 / 12 = -1.3e-4 at the start, less as |w| shrinks).
SPIN_BIAS_PER_STEP = {"semi-implicit": (5e-8, 5e-7), "xpbd": (5e-8, 5e-7), "steel": (5e-8, 5e-7),
                      "featherstone": (-1e-9, 1e-9), "vbd": (-1.5e-4, -0.8e-4)}
# Featherstone's angular_damping is stored and ignored (Newton 1.8): 0.05 keeps the energy of a
# torque-free spin to float32 round-off (measured 1e-5; honoured it would take 0.09 in 2 s).
IGNORED_DAMPING_RTOL = 1e-4
# A second adapter of a solver in one process finds the kernels loaded: its "compile" is the
# solver's construction and first step beyond a regular one (measured < 0.05 s; cold: 5-40 s).
WARM_COMPILE_S = 1.0

# The body: freebody.testing's general problem (I_FULL, diag(1, 2, 3) in rotated principal
# axes, 2 kg, rotated, offset, moving); adapters from its make_adapter fixture.


# --- fast: registry, capabilities, Newton's documented defaults, conversions ----------------------

def test_registered_and_capabilities():
    assert load_adapter("newton") is NewtonAdapter
    offered = NewtonAdapter.offered_integrators()
    assert offered[:6] == (*SOLVERS[:3], "steel", "vbd", "kamino")
    mujoco = tuple(i for i in offered if i.startswith("mujoco-"))
    assert bool(mujoco) == NA._mujoco_available()
    assert NewtonAdapter.opt_in_integrators == ("kamino",)
    assert NewtonAdapter.precisions == ("float32",)
    assert NewtonAdapter.supported_versions == ">=1.8"
    assert NewtonAdapter.engine_version().startswith(newton.__version__)
    assert f"warp {wp.__version__}" in NewtonAdapter.engine_version()
    assert NewtonAdapter.selfcheck_integrators() == ("kamino",)
    for key in ("quaternion order", "angular velocity frame", "state read", "external loads", "damping",
                "gravity", "precision", "integrator", "compilation", "contacts"):
        assert key in NewtonAdapter.conventions
    assert len(NewtonAdapter.trap_checks()) == 6


def test_newton_defaults_are_as_documented():
    """What the adapter changes or relies on, without stepping (Newton 1.8.0)."""
    def default(cls, arg):
        return inspect.signature(cls.__init__).parameters[arg].default

    assert default(newton.solvers.SolverSemiImplicit, "angular_damping") == 0.05
    assert default(newton.solvers.SolverFeatherstone, "angular_damping") == 0.05
    assert default(newton.solvers.SolverXPBD, "angular_damping") == 0.0
    assert default(newton.solvers.SolverFeatherstone, "update_mass_matrix_interval") == 1
    assert newton.solvers.SolverKamino.Config().angular_velocity_damping == 0.0
    assert newton.solvers.SolverKamino.Config().integrator == "euler"
    builder = newton.ModelBuilder()
    assert str(builder.up_axis).endswith("Z")
    np.testing.assert_array_equal(np.asarray(builder.gravity), np.float32([0.0, 0.0, -9.81]))
    from newton._src.solvers.steel import solver_steel
    assert solver_steel._DEFAULT_ANGULAR_DAMPING == 0.05
    # Featherstone stores angular_damping and never reads it (the reason it has no trap check)
    source = inspect.getsource(newton.solvers.SolverFeatherstone)
    assert source.count("angular_damping") == 4  # the parameter, its doc line and its storage
    # Warp's log messages are off (the banner, a line per module load)
    assert wp.config.log_level >= wp.LOG_WARNING


def test_rows_convert_to_the_canonical_trajectory():
    """body_q rows [x, q (x, y, z, w)] and body_qd rows [v, w world] -> canonical float64 samples:
    the quaternion reordered, nothing else changed, t = (k0 + i) dt."""
    rng = np.random.default_rng(11)
    q = rng.normal(size=(5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    x, v, w = rng.normal(size=(3, 5, 3))
    P = np.concatenate([x, quat_xyzw_from_wxyz(q)], axis=1).astype(np.float32)
    T = np.concatenate([v, w], axis=1).astype(np.float32)
    tr = NA._trajectory(P, T, 0.01, 7)
    np.testing.assert_array_equal(tr.t, (7 + np.arange(5)) * 0.01)
    np.testing.assert_array_equal(tr.quaternion_wxyz, q.astype(np.float32).astype(float))
    np.testing.assert_array_equal(tr.position, x.astype(np.float32).astype(float))
    np.testing.assert_array_equal(tr.linear_velocity, v.astype(np.float32).astype(float))
    np.testing.assert_array_equal(tr.angular_velocity, w.astype(np.float32).astype(float))
    for a in (tr.position, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity):
        assert a.dtype == np.float64 and a.flags.c_contiguous


def test_body_f_rows_are_force_then_torque_about_the_com():
    """The body_f entry of a segment with every kind of load, at a body_q row: [force, torque about
    the COM], world, arms from the row's pose (as Segment.wrench at that state)."""
    loads = (Load(force=(1.0, 2.0, -3.0), body_point=(0.3, -0.1, 0.2)),
             Load(force=(0.5, 0.0, 1.0), point=(2.0, -1.0, 0.5)),
             Load(torque=(0.1, 0.2, 0.3), body_torque=(-0.4, 0.5, 0.6)))
    pb = general_problem(loads=loads)
    seg = LoadSchedule(pb, 0.01).at(0)
    x, q = np.array([0.2, -0.3, 1.5]), quat_from_rotvec([0.3, -0.9, 0.4])
    row = np.concatenate([x, quat_xyzw_from_wxyz(q)]).astype(np.float32)
    got = NA._wrench_at(seg, row)
    assert got.dtype == np.float32 and got.shape == (6,)
    want = seg.wrench(row[0:3].astype(float), matrix_from_quat(q.astype(np.float32).astype(float)))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)


# --- slow: trap checks -----------------------------------------------------------------------------

# check -> the adapter's handling undone: (attribute of the module, value)
UNHANDLED = {
    "semi-implicit angular damping (0.05) off": ("SEMI_IMPLICIT_ANGULAR_DAMPING", 0.05),
    "steel angular damping (0.05) off": ("STEEL_ANGULAR_DAMPING", 0.05),
    "state read from body_q (semi-implicit, xpbd, vbd leave joint_q)": ("READ_JOINT_Q", True),
    "angular velocity in the world frame": ("_w_to_engine", angular_velocity_body_from_world),
    "body_f = (force, torque about the COM), world": ("_wrench_row", lambda f, tau: np.concatenate([tau, f])),
    "gravity set (builder default -9.81 along Z)": ("SET_GRAVITY", False),
}


@pytest.mark.slow
def test_every_trap_check_passes():
    results = {r.check: r for r in run_trap_checks("newton")}
    assert set(results) == set(UNHANDLED)
    bad = [f"{r.check}: {r.detail}" for r in results.values() if not r.passed]
    assert not bad, "; ".join(bad)


@pytest.mark.slow
@pytest.mark.parametrize("check", list(UNHANDLED))
def test_trap_check_fails_when_the_adapter_stops_handling_it(check, monkeypatch):
    """Set the adapter's handling back to Newton's default (or the naive way): the trap's live
    check must fail on its measurement.  A body-frame w is undone on both ways (written and read)."""
    name, value = UNHANDLED[check]
    monkeypatch.setattr(NA, name, value)
    if name == "_w_to_engine":
        monkeypatch.setattr(NA, "_w_from_engine",
                            lambda q, w: np.array([angular_velocity_world_from_body(qi, wi) for qi, wi in zip(q, w)]))
    passed, measured, bound, detail = NewtonAdapter.trap_checks()[check]()
    assert not passed, f"{check} still passes with {name} = {value!r}: {detail}"
    assert measured > 10 * bound, detail


@pytest.mark.slow
def test_featherstone_ignores_its_angular_damping(monkeypatch):
    """KNOWN ENGINE PROPERTY (why Featherstone's damping has no trap check): Newton 1.8's
    SolverFeatherstone takes angular_damping = 0.05 and never applies it.  If this fails, Newton
    started honouring it: the adapter sets 0 already; add a live check like semi-implicit's."""
    monkeypatch.setattr(NA, "FEATHERSTONE_ANGULAR_DAMPING", 0.05)
    err = NA._spin_energy_change("featherstone")
    assert err <= IGNORED_DAMPING_RTOL, err


@pytest.mark.slow
@pytest.mark.parametrize("solver", SOLVERS)
def test_joint_q_is_left_behind_by_maximal_coordinate_solvers(solver, make_adapter):
    """KNOWN ENGINE PROPERTY: semi-implicit, xpbd and vbd integrate body_q/body_qd and never touch
    the FREE joint's joint_q/joint_qd; featherstone and steel integrate joint_q and compute body_q
    from it (equal).  The adapter reads body_q for all."""
    pb = general_problem()
    a = make_adapter("newton", pb, 0.01, solver)
    tr = a.simulate(20)
    state = a._views[0].state
    body_q, joint_q = state.body_q.numpy()[0], state.joint_q.numpy()
    np.testing.assert_array_equal(body_q[0:3], tr.position[-1])
    if solver in ("semi-implicit", "xpbd", "vbd"):
        np.testing.assert_allclose(joint_q[0:3], pb.initial.position, rtol=READBACK_RTOL)
        assert np.linalg.norm(joint_q[0:3] - body_q[0:3]) > 0.1
    else:
        np.testing.assert_array_equal(joint_q, body_q)


# --- slow: settings --------------------------------------------------------------------------------

EXPECTED_SETTINGS = {
    "semi-implicit": {"gravity", "angular_damping"},
    "featherstone": {"gravity", "angular_damping"},
    "xpbd": {"gravity", "angular_damping"},
    "steel": {"gravity", "steel:rigid_body_angular_damping"},
    "vbd": {"gravity"},
}


@pytest.mark.slow
@pytest.mark.parametrize("solver", SOLVERS)
def test_settings_are_recorded_and_read_back(solver, make_adapter):
    pb = general_problem(gravity=(0.5, -1.0, -3.0))
    a = make_adapter("newton", pb, 0.01, solver)
    assert set(a.settings) == EXPECTED_SETTINGS[solver]
    json.dumps(a.settings, allow_nan=False)
    np.testing.assert_allclose(a.settings["gravity"]["set"], [0.5, -1.0, -3.0], rtol=READBACK_RTOL)
    np.testing.assert_allclose(a.settings["gravity"]["default"], [0.0, 0.0, -9.81], rtol=READBACK_RTOL)
    for key in ("angular_damping", "steel:rigid_body_angular_damping"):
        if key in a.settings:
            assert a.settings[key]["set"] == 0.0
            assert a.settings[key]["default"] == pytest.approx(0.0 if solver == "xpbd" else 0.05)
    m = a._model
    np.testing.assert_allclose(m.body_inertia.numpy()[0], I_FULL, rtol=READBACK_RTOL, atol=READBACK_RTOL)
    assert m.shape_count == 0 and m.body_count == 1 and m.joint_count == 1


# --- slow: the maps -----------------------------------------------------------------------------------

def _nearest_other_map(pb: Problem, dt: float, n: int, own: str, tr_own: np.ndarray) -> float:
    """How far the nearest other engine map is from the solver's own float64 map (rad)."""
    others = set(MAPS.values()) | {"semi-implicit-explicit-gyro", "explicit-gyro-rescaled-momentum",
                                   "semi-implicit-implicit-gyro"}
    return min(float(np.max(geodesic_angle(simulate(pb, m, dt, n).quaternion_wxyz, tr_own)))
               for m in others - {own})


# (solver, case): the cases on which a solver's map and the nearest other one separate by more
# than the solver's float32 round-off (see test_float32_spin_bias_documented: semi-implicit and
# xpbd drift from their map on world_torque and body_torque_spinup, where the maps of kamino and
# semi-implicit-explicit-gyro are only 1.2e-5 rad away).
MAP_CASES = [(s, c) for s in SOLVERS for c in ("offset_push",)] + [
    (s, c) for s in ("featherstone", "steel", "vbd") for c in ("world_torque", "body_torque_spinup")]


@pytest.mark.slow
@pytest.mark.parametrize("solver, case", MAP_CASES)
def test_solver_follows_its_map(solver, case, make_adapter):
    """At dt 0.01 (200 steps) each solver's float32 run is within float32 round-off growth of its
    float64 engine-equivalent map, and a small fraction of the way to the nearest other map."""
    pb, dt = load_case(case), 0.01
    n = pb.steps(dt)
    own = simulate(pb, MAPS[solver], dt, n).quaternion_wxyz
    got = make_adapter("newton", pb, dt, solver).simulate(n).quaternion_wxyz
    d_own = float(np.max(geodesic_angle(got, own)))
    d_other = _nearest_other_map(pb, dt, n, MAPS[solver], own)
    print(f"{solver} {case}: own map {d_own:.2e} rad, nearest other map {d_other:.2e} rad")
    assert d_own <= OWN_MAP_RAD, d_own
    assert d_own <= OWN_VS_OTHER_MAP * d_other, (d_own, d_other)


@pytest.mark.slow
@pytest.mark.parametrize("solver", SOLVERS)
def test_float32_spin_bias_documented(solver, make_adapter):
    """KNOWN ENGINE PROPERTY: a steady spin about a principal axis of I = diag(1, 2, 3), 2000 steps
    at dt 0.01.  semi-implicit, xpbd (and steel, whose gyroscopic update also goes through the body
    frame) scale |w| by 1 + 1.5e-7 .. 2.4e-7 a step: the float32 quaternion, normalised, keeps a
    norm above 1 by ~2.5e-8, and quat_rotate_inv then quat_rotate scale w by its fourth power;
    featherstone keeps |w| (world frame throughout); vbd shortens it by its map's (h |w|)^2 / 12
    (1.07e-4).  If this fails, Newton changed: update SPIN_BIAS_PER_STEP and docs/adapters.md."""
    n = 2000
    pb = general_problem(I_body=np.diag([1.0, 2.0, 3.0]), q=(1.0, 0.0, 0.0, 0.0), w=(0.0, 0.0, 4.0),
                         gravity=(0, 0, 0), duration=20.0)
    w = np.linalg.norm(make_adapter("newton", pb, 0.01, solver).simulate(n).angular_velocity, axis=1)
    per_step = (w[-1] / w[0]) ** (1.0 / n) - 1.0
    lo, hi = SPIN_BIAS_PER_STEP[solver]
    assert lo <= per_step <= hi, per_step


@pytest.mark.slow
def test_kamino_follows_its_map(make_adapter):
    """Kamino (opt-in, ~35 ms a step): body_torque_spinup at dt 0.01, 50 steps, a torque acting: its map,
    not PhysX's (the torque impulse after the gyroscopic step, not before)."""
    pb, dt, n = load_case("body_torque_spinup"), 0.01, 50
    own = simulate(pb, MAPS["kamino"], dt, n).quaternion_wxyz
    physx = simulate(pb, "explicit-gyro-rescaled-momentum", dt, n).quaternion_wxyz
    got = make_adapter("newton", pb, dt, "kamino").simulate(n).quaternion_wxyz
    d_own, d_physx = (float(np.max(geodesic_angle(got, r))) for r in (own, physx))
    assert d_own <= OWN_MAP_RAD and d_own <= OWN_VS_OTHER_MAP * d_physx, (d_own, d_physx)


# --- slow: stepping, compile time, output --------------------------------------------------------------

@pytest.mark.slow
def test_loads_switch_off_and_body_f_is_cleared(make_adapter):
    """A body-point push for 3 steps, then nothing: the run follows the map over the switch (body_f
    rewritten with zeros: Newton never clears it), and the last sample is Newton's state."""
    pb = general_problem(loads=(Load(force=(3.0, -1.0, 2.0), body_point=(0.3, 0.1, -0.2), start=0.02,
                                     steps=3),), gravity=(0.0, 0.0, 0.0))
    a = make_adapter("newton", pb, 0.01, "semi-implicit")
    tr = a.simulate(30)
    ref = simulate(pb, MAPS["semi-implicit"], 0.01, 30)
    assert_same_rotation(tr.quaternion_wxyz, ref.quaternion_wxyz, OWN_MAP_RAD)
    np.testing.assert_allclose(tr.angular_velocity, ref.angular_velocity, atol=1e-5)
    for views in a._views:
        np.testing.assert_array_equal(views.state.body_f.numpy(), 0.0)


@pytest.mark.slow
def test_compile_time_is_reported_apart(make_adapter):
    """compile_time_s: the build and first step beyond a regular step; a second adapter of the same
    solver in the process finds the kernels loaded."""
    pb = general_problem()
    first = make_adapter("newton", pb, 0.01, "semi-implicit")
    first.simulate(5)
    second = make_adapter("newton", pb, 0.01, "semi-implicit")
    second.simulate(5)
    for a in (first, second):
        assert a.compile_time_s >= 0.0 and a.step_time_s > 0.0
    assert second.compile_time_s < WARM_COMPILE_S


@pytest.mark.slow
def test_import_and_run_print_nothing():
    """Importing the adapter and stepping a body print nothing: no Warp banner, no module-load lines,
    no CUDA-driver notice on a machine without a GPU."""
    code = ("from freebody.adapters.newton_adapter import NewtonAdapter\n"
            "from freebody.input import load_case\n"
            "a = NewtonAdapter(load_case('quiz'), 0.01, 'semi-implicit', 'float32'); a.simulate(2); a.close()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == "" and proc.stderr == "", (proc.stdout, proc.stderr)


@pytest.mark.slow
def test_freebody_conventions_passes_every_check():
    """``freebody conventions --engine newton``: the self-checks (kamino, see selfcheck_integrators)
    and every trap check pass."""
    conv = subprocess.run([sys.executable, "-m", "freebody", "conventions", "--engine", "newton"],
                          capture_output=True, text=True, timeout=1200)
    assert conv.returncode == 0, conv.stdout + conv.stderr
    assert "FAIL" not in conv.stdout and conv.stdout.count("PASS") == 5 + 6, conv.stdout
