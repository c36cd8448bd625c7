"""The Brax adapter against real Brax (skipped without the ``brax`` extra): Brax's defaults and
facts the adapter relies on, the settings it forces (read back), each trap check failing once the
adapter stops handling its trap, loads on every pipeline, and scheme identification of every
pipeline's float64 runs as its engine-equivalent map (``explicit-gyro-regularised-exp``,
``semi-implicit-no-gyro``, ``semi-implicit-no-gyro-projected``).

Arrays follow freebody's canonical convention (reference_impl/conventions.py).  Every test that
steps compiles a JAX program the first time (seconds; JAX's persistent cache makes later processes
load it); the tests share the few programs (pipeline x precision x loaded) within the process.
Tests that compile programs of their own, or run many cases, are marked ``slow``.  The adapter's
conformance (t = 0 read-back, pushes, chunking, settings, blow-up) is in
``test_adapter_conformance.py``, parametrised over the registry.
"""
from __future__ import annotations

import contextlib
import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("brax", reason="brax not installed (pip install 'freebody[brax]')")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import freebody.adapters.brax_adapter as BA  # noqa: E402
from freebody.adapters import jax_runtime  # noqa: E402
from freebody.adapters.base import default_engine_names, load_adapter, registry  # noqa: E402
from freebody.adapters.brax_adapter import PIPELINES, BraxAdapter  # noqa: E402
from freebody.input import load_case  # noqa: E402
from freebody.reference_impl.integrators import simulate  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402
from freebody.reference_impl.rotations import geodesic_angle, matrix_from_quat, quat_from_rotvec  # noqa: E402
from freebody.run import RunSpec, execute  # noqa: E402
from freebody.run.selfcheck import run_trap_checks  # noqa: E402

# The engine-equivalent map of each pipeline (reference_impl/engine_maps.py).
MAPS = {"generalized": "explicit-gyro-regularised-exp", "spring": "semi-implicit-no-gyro",
        "positional": "semi-implicit-no-gyro-projected"}
assert BA.PIPELINE_MAPS == MAPS

# --- tolerances ---------------------------------------------------------------------------------
# A float64 run against its map, 100 steps of a loaded tumbling body at dt 0.01 (no flip): the
# same float64 map, other operation order; measured <= 6e-14 rad (positional, whose velocities
# are differences of positions) and <= 3e-15 elsewhere.  A wrong scheme is >= 1e-9 away (the
# 1e-8 regularisation of generalized: 3e-11 over 10 s; the missing gyroscopic term: O(0.1)).
MAP_FLOAT64_RAD = 1e-12
# A float32 run against the float64 map, same 100 steps: float32 round-off growth, measured
# <= 2e-6 rad; float64 round-off would be < 1e-13.
MAP_FLOAT32_MAX_RAD = 1e-4
MAP_FLOAT32_MIN_RAD = 1e-9
# The positional projection shortens a spin about a principal axis by 1 / sqrt(1 + h^2 |w|^2 / 4)
# a step: predicted and measured agree to the round-off of position differences, eps / (h |w|) a
# step (measured 3e-13 relative after 100 steps of 5 rad/s at dt 0.01).
PROJECTION_RTOL = 1e-10


def _tumbling_problem(loads=(), steps: int = 100) -> Problem:
    """A rotated, moving body with a full inertia tensor, gravity, tumbling (no flip in 1 s)."""
    Q = matrix_from_quat(quat_from_rotvec(np.array([0.3, 0.2, -0.5])))
    return Problem("brax-test", "", Body(1.7, Q.T @ np.diag([0.9, 1.6, 2.1]) @ Q),
                   InitialState([1.5, -2.0, 0.75], quat_from_rotvec(np.array([0.4, -0.7, 0.25])),
                                [0.3, -0.4, 1.2], [0.7, -1.1, 2.3]),
                   [0.0, 0.0, -9.81], tuple(loads), duration_steps=steps)


LOADS = (Load(force=[0.5, -1.0, 2.0], body_point=[0.1, 0.2, -0.3], start=0.0, end=0.35),
         Load(force=[1.0, 0.3, -0.2], point=[2.0, -1.5, 0.9], start=0.1, end=0.5),
         Load(torque=[0.05, 0.0, -0.1], body_torque=[0.1, -0.2, 0.3], start=0.05, steps=30))


def _run(problem: Problem, dt: float, steps: int, pipeline: str, precision: str = "float64"):
    adapter = BraxAdapter(problem, dt, pipeline, precision)
    try:
        return adapter.simulate(steps), adapter
    finally:
        adapter.close()


def _max_angle(a, b) -> float:
    return float(np.max(geodesic_angle(a.quaternion_wxyz, b.quaternion_wxyz)))


# --- registry and Brax's own facts ----------------------------------------------------------------

def test_registered_opt_in_with_its_capabilities():
    assert load_adapter("brax") is BraxAdapter
    assert registry()["brax"].import_name == "brax"
    assert "brax" not in default_engine_names()  # opt-in: seconds of JAX compilation per program
    assert BraxAdapter.offered_integrators() == ("generalized", "positional", "spring")
    assert BraxAdapter.precisions == ("float32", "float64")
    assert BraxAdapter.selfcheck_integrators() == ("generalized",)
    assert BraxAdapter.compare_with is None  # no engine runs Brax's pipelines under these names
    for fact in ("gyroscopic term", "angular velocity frame", "external loads", "velocity projection"):
        assert fact in BraxAdapter.conventions
    assert "NONE" in BraxAdapter.conventions["gyroscopic term"]


def test_brax_defaults_are_as_documented():
    """What the module docstring says of Brax 0.14: no velocity damping by default, the
    approximate mass-matrix inverse, and a model without a geom refused."""
    with BA.x64_scope(True):
        defaults = BA._brax_defaults()
        assert defaults["ang_damping"] == 0.0 and defaults["vel_damping"] == 0.0
        assert defaults["timestep"] == 0.002 and defaults["gravity"] == [0.0, 0.0, -9.81]
        assert defaults["geom contype"] == 1 and defaults["geom conaffinity"] == 1
        sys_ = BA._load_system(BA._mjcf(_tumbling_problem(), 0.01))
        assert sys_.matrix_inv_iterations == 10
        no_geom = BA._mjcf(_tumbling_problem(), 0.01).replace(
            f'<geom name="anchor" type="sphere" size="{BA.format_floats(BA.GEOM_RADIUS)}" contype="0" conaffinity="0"/>', "")
        with pytest.raises(IndexError):
            BA.mjcf.validate_model(BA._load_system(no_geom).mj_model)


@pytest.mark.slow
def test_maximal_coordinate_pipelines_ignore_a_free_joints_generalized_forces():
    """Why the adapter hooks the joint force of positional and spring: their free joint drops
    actuator forces (joints._free), which generalized applies."""
    pb = _tumbling_problem()
    with BA.x64_scope(True):
        sys_ = BA._load_system(BA._mjcf(pb, 0.01))
        sys_ = sys_.replace(actuator=BA._dof_actuators(np.float64), nu=6, mj_model=None)
        q = jnp.asarray(np.concatenate([pb.initial.position, pb.initial.quaternion_wxyz]))
        qd = jnp.zeros(6)
        for pipeline, module in PIPELINES.items():
            state = jax.jit(module.init)(sys_, q, qd)
            step = jax.jit(module.step)
            pushed, free = step(sys_, state, jnp.ones(6)), step(sys_, state, jnp.zeros(6))
            moved = float(np.max(np.abs(np.asarray(pushed.qd) - np.asarray(free.qd))))
            assert (moved > 1e-3) == (pipeline == "generalized"), (pipeline, moved)


# --- settings -----------------------------------------------------------------------------------------

@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_settings_read_back_and_recorded(precision):
    pb = _tumbling_problem(LOADS)
    a = BraxAdapter(pb, 0.01, "generalized", precision)
    try:
        s = a.settings
        assert s["timestep"] == {"default": 0.002, "set": float(np.float32(0.01)) if precision == "float32" else 0.01}
        assert s["gravity"]["set"] == [0.0, 0.0, float(np.float32(-9.81)) if precision == "float32" else -9.81]
        assert s["ang_damping"] == {"default": 0.0, "set": BA.ANG_DAMPING}
        assert s["vel_damping"] == {"default": 0.0, "set": BA.VEL_DAMPING}
        assert s["geom contype"] == {"default": 1, "set": 0}
        assert s["jax_enable_x64"]["set"] == (precision == "float64")
        assert s["actuators"] == {"default": 0, "set": 6}  # loaded generalized: the per-dof actuators
        json.dumps(s, allow_nan=False)
    finally:
        a.close()
    unloaded = BraxAdapter(_tumbling_problem(), 0.01, "spring", precision)
    assert "actuators" not in unloaded.settings
    unloaded.close()


def test_every_body_shares_one_compilation():
    """The System's static structure is normalised: a body whose principal frame is its body frame
    (sorted diagonal inertia) and a full-tensor one step through the same compiled programs."""
    one = Problem("diag", "", Body(1.0, np.diag([3.0, 2.0, 1.0])),
                  InitialState([0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0.1, 1.0, 0.2]), [0, 0, 0], duration_steps=5)
    _run(one, 0.01, 5, "spring")
    _, second = _run(_tumbling_problem(), 0.02, 5, "spring")
    assert second.compile_time_s == 0.0


# --- the schemes ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("pipeline", list(PIPELINES))
def test_float64_runs_follow_their_map_with_loads(pipeline):
    """A loaded (every kind of load), tumbling, rotated body with a full inertia: each pipeline is
    its map to float64 round-off."""
    pb = _tumbling_problem(LOADS)
    tr, _ = _run(pb, 0.01, 100, pipeline)
    mapped = simulate(pb, MAPS[pipeline], 0.01, 100)
    assert _max_angle(tr, mapped) <= MAP_FLOAT64_RAD
    assert np.max(np.abs(tr.angular_velocity - mapped.angular_velocity)) <= MAP_FLOAT64_RAD * 10
    assert np.max(np.abs(tr.position - mapped.position)) <= MAP_FLOAT64_RAD * 10


@pytest.mark.parametrize("pipeline", list(PIPELINES))
def test_float32_runs_are_float32(pipeline):
    pb = _tumbling_problem(LOADS)
    tr, _ = _run(pb, 0.01, 100, pipeline, "float32")
    d = _max_angle(tr, simulate(pb, MAPS[pipeline], 0.01, 100))
    assert MAP_FLOAT32_MIN_RAD <= d <= MAP_FLOAT32_MAX_RAD, d
    assert np.all(tr.quaternion_wxyz == tr.quaternion_wxyz.astype(np.float32))  # float32 values, widened


def test_positional_projection_shortens_the_spin():
    """A spin about a principal axis (no gyroscopic change): positional's |w| shrinks by
    1 / sqrt(1 + h^2 |w|^2 / 4) a step (its energy loss), spring keeps it."""
    h, steps, rate = 0.01, 100, 5.0
    q0 = quat_from_rotvec(np.array([0.2, -0.4, 0.1]))
    pb = Problem("spin", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState(np.zeros(3), q0, np.zeros(3), rate * matrix_from_quat(q0)[:, 2]), [0, 0, 0],
                 duration_steps=steps)
    expected = rate * np.cumprod(np.r_[1.0, np.full(steps, 1.0)])
    for k in range(steps):
        expected[k + 1] = expected[k] / np.sqrt(1.0 + 0.25 * (h * expected[k]) ** 2)
    positional, _ = _run(pb, h, steps, "positional")
    spring, _ = _run(pb, h, steps, "spring")
    got = np.linalg.norm(positional.angular_velocity, axis=1)
    assert np.max(np.abs(got / expected - 1.0)) <= PROJECTION_RTOL
    assert got[-1] / rate < 0.975  # 100 steps of 5 rad/s at 0.01: 3% of |w|, 6% of the energy
    assert np.max(np.abs(np.linalg.norm(spring.angular_velocity, axis=1) / rate - 1.0)) <= PROJECTION_RTOL


@pytest.mark.slow
@pytest.mark.parametrize("pipeline", list(PIPELINES))
@pytest.mark.parametrize("case, dt", [("body_torque_spinup", 0.01), ("thin_rod", 0.01), ("dzhanibekov", 0.001)])
def test_identification_names_the_pipelines_map(pipeline, case, dt):
    """Through the harness, float64: each pipeline's run reproduces its map (the map named, or in
    the tie it is named with).  generalized on a steady case at dt 0.01 is told apart from
    semi-implicit-explicit-gyro by the 1e-8 of its exponential map."""
    pb = load_case(case)
    steps = pb.steps(dt, 2.0)
    r = execute(RunSpec(pb, "brax", pipeline, dt, steps, "float64")).result
    assert r.status == "ok", r.message
    m = r.matches_reference
    assert MAPS[pipeline] in m["indistinguishable"], m
    if pipeline == "generalized" and case == "thin_rod":
        assert m["integrator"] == MAPS[pipeline] and m["ratios"]["semi-implicit-explicit-gyro"] > 1.0, m


# --- loads refused where the hook was not checked -------------------------------------------------------

def test_loads_on_an_unchecked_step_source_are_refused(monkeypatch):
    monkeypatch.setattr(BA, "_STEP_SHA256", {"positional": "0" * 64, "spring": "0" * 64})
    for pipeline in ("positional", "spring"):
        assert not BA.loads_supported(pipeline)
        with pytest.raises(NotImplementedError, match="external loads"):
            BraxAdapter(_tumbling_problem(LOADS), 0.01, pipeline, "float64")
        BraxAdapter(_tumbling_problem(), 0.01, pipeline, "float64").close()  # torque-free: runs
    assert BA.loads_supported("generalized")


# --- trap checks ---------------------------------------------------------------------------------------

@pytest.mark.slow
def test_every_trap_check_passes():
    results = {r.check: r for r in run_trap_checks("brax")}
    assert set(results) == set(UNHANDLED)
    bad = [f"{r.check}: {r.detail}" for r in results.values() if not r.passed]
    assert not bad, "; ".join(bad)


def _world_w_as_written(q, w):
    return np.asarray(w, dtype=float)


def _diagonal_only(mass, I_body):
    from freebody.adapters.mjcf import inertial_element
    return inertial_element(mass, np.diag(np.diag(I_body)))


@contextlib.contextmanager
def _no_float64():
    yield


# trap check -> (adapter attributes set back to the naive way, whether build() refuses first)
UNHANDLED = {
    "angular velocity: qd[3:6] is body frame": ({"angular_velocity_body_from_world": _world_w_as_written}, False),
    "no damping left on (ang/vel_damping, exp(d h) per step)": ({"ANG_DAMPING": -0.05, "VEL_DAMPING": -0.05}, False),
    "full inertia: body frame kept, principal frame in link.inertia": ({"inertial_element": _diagonal_only}, True),
    "external wrench reaches the free body (all pipelines)": ({"_with_external": lambda original: original}, True),
    "float64 runs are float64 (x64 scope), float32 runs float32": ({"x64_scope": lambda on: _no_float64()}, True),
    # labelled as the engines' usual scheme (a gyroscopic term), not as Brax's
    "positional/spring: no gyroscopic term (finding, identified)":
        ({"PIPELINE_MAPS": {**MAPS, "positional": "semi-implicit-explicit-gyro",
                            "spring": "semi-implicit-explicit-gyro"}}, False),
}


@pytest.mark.slow
@pytest.mark.parametrize("check", list(UNHANDLED))
def test_trap_check_fails_when_the_adapter_stops_handling_it(check, monkeypatch):
    """Set the adapter's handling back to the naive way (a fresh compilation cache, so no program
    compiled with the handling is reused): the trap's live check fails, or build()'s read-back
    (or the wrench hook's call count) refuses the run first."""
    attrs, refused = UNHANDLED[check]
    monkeypatch.setattr(jax_runtime, "_COMPILED", {})
    for name, value in attrs.items():
        monkeypatch.setattr(BA, name, value)
    if refused:
        with pytest.raises(RuntimeError):
            BraxAdapter.trap_checks()[check]()
        return
    passed, measured, bound, detail = BraxAdapter.trap_checks()[check]()
    assert not passed, f"{check} still passes with {attrs}: {detail}"


# --- the command line -----------------------------------------------------------------------------------

@pytest.mark.slow
def test_freebody_conventions_passes_every_check():
    """``freebody conventions --engine brax``: every self-check on generalized (float64) and every
    trap check passes."""
    conv = subprocess.run([sys.executable, "-m", "freebody", "conventions", "--engine", "brax"],
                          capture_output=True, text=True, timeout=1200)
    assert conv.returncode == 0, conv.stdout + conv.stderr
    assert "FAIL" not in conv.stdout and conv.stdout.count("PASS") == 5 + len(UNHANDLED), conv.stdout


@pytest.mark.slow
def test_freebody_run_output_is_clean(tmp_path):
    """``freebody run`` with Brax: every pipeline and precision ok, nothing printed by Brax (its
    "not maintained" warning is silenced)."""
    run = subprocess.run([sys.executable, "-m", "freebody", "run", "quiz", "--engine", "brax", "--dt", "0.01",
                          "--duration", "0.2", "--out", str(tmp_path / "out"), "--jobs", "1"],
                         capture_output=True, text=True, timeout=1200)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "maintained" not in run.stdout + run.stderr
    runs = json.loads((tmp_path / "out" / "results.json").read_text())["runs"]
    assert {(r["integrator"], r["precision"], r["status"]) for r in runs} == {
        (p, prec, "ok") for p in PIPELINES for prec in ("float32", "float64")}
    assert not any(r.get("engine_output") for r in runs)
