"""Property-based tests: generated malformed and extreme cases thrown at the loader and at `run`.
Nothing may crash with an unhandled exception: a case is either valid or an InputError with one
line naming the key; a valid case runs to a status."""
from __future__ import annotations

import copy
import math
import tomllib

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

from freebody.input.casefile import parse_case
from freebody.cli import main
from freebody.errors import InputError
from freebody.run import STATUSES, RunSpec, execute

VALID = tomllib.loads("""
name = "fuzz"
description = "base case for fuzzing"
duration = 0.05
dt = [0.01]
[body]
mass = 1.0
inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]
[initial]
position = [0.0, 0.0, 0.0]
orientation = [1.0, 0.0, 0.0, 0.0]
linear_velocity = [0.0, 0.0, 0.0]
angular_velocity = [0.01, 5.0, 0.0]
[world]
gravity = [0.0, 0.0, 0.0]
[[loads]]
force = [1.0, 0.0, 0.0]
body_point = [0.0, 0.1, 0.0]
steps = 2
""")

PATHS = [("name",), ("description",), ("duration",), ("dt",), ("body", "mass"), ("body", "inertia"),
         ("initial", "position"), ("initial", "orientation"), ("initial", "linear_velocity"),
         ("initial", "angular_velocity"), ("world", "gravity"), ("loads",), ("body",), ("initial",)]

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
extreme = st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300, 1e-9, 1e9, float("nan"), float("inf")])
scalars = st.one_of(floats, extreme, st.integers(-10**6, 10**6), st.booleans(), st.text(max_size=5))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=12)


@st.composite
def mutated_cases(draw):
    case = copy.deepcopy(VALID)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        target = case
        for key in path[:-1]:
            target = target.setdefault(key, {}) if isinstance(target, dict) else {}
        if not isinstance(target, dict):
            continue
        action = draw(st.sampled_from(["set", "delete", "extra"]))
        if action == "set":
            target[path[-1]] = draw(values)
        elif action == "delete":
            target.pop(path[-1], None)
        else:
            target[draw(st.text(min_size=1, max_size=6))] = draw(values)
    return case


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_cases())
def test_loader_accepts_or_names_the_problem(case):
    try:
        pb = parse_case(case, "fuzz.toml")
    except InputError as e:
        msg = str(e)
        assert msg.startswith("fuzz.toml: ") and "\n" not in msg
        return
    assert pb.body.mass > 0 and np.all(np.isfinite(pb.body.I_body))
    assert math.isclose(float(np.linalg.norm(pb.initial.quaternion_wxyz)), 1.0, rel_tol=1e-12)


@st.composite
def extreme_valid_cases(draw):
    """Physically valid but extreme bodies: tiny/huge masses, near-planar or needle inertia, fast spins."""
    case = copy.deepcopy(VALID)
    a = draw(st.floats(1e-6, 1e6))
    b = a * draw(st.floats(1e-3, 1e3))
    c = draw(st.floats(abs(a - b), a + b))
    case["body"]["mass"] = draw(st.floats(1e-6, 1e6))
    case["body"]["inertia"] = [[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, 0.0, max(c, 1e-300)]]
    # moderate magnitudes: the numerical truth (DOP853 at 1e-12) costs steps in proportion to |w| t
    vec = st.lists(st.floats(-1e2, 1e2), min_size=3, max_size=3)
    case["initial"]["angular_velocity"] = draw(vec)
    case["initial"]["linear_velocity"] = draw(vec)
    case["initial"]["position"] = draw(vec)
    case["initial"]["orientation"] = draw(st.lists(st.floats(-1, 1), min_size=4, max_size=4))
    case["world"]["gravity"] = draw(vec)
    case["dt"] = [draw(st.floats(1e-5, 0.1))]
    case["duration"] = case["dt"][0] * draw(st.integers(1, 20))
    case["loads"][0]["force"] = draw(vec)
    return case


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(mutated_cases(), extreme_valid_cases()),
       st.sampled_from(["rk4", "euler-matrix", "semi-implicit-implicit-gyro"]))
def test_valid_generated_cases_run_to_a_status(case, integrator):
    try:
        pb = parse_case(case, "fuzz.toml")
    except InputError:
        return
    dt = pb.dts[0] if pb.dts else 0.01  # a case may leave dt and its duration to --dt and --duration
    no_duration = pb.duration is None and pb.duration_steps is None
    steps = min(pb.steps(dt, 5 * dt if no_duration else None), 20)
    out = execute(RunSpec(pb, "reference", integrator, dt, steps))
    assert out.result.status in STATUSES
    for v in out.result.metrics.values():
        assert v is None or math.isfinite(v)


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_arbitrary_bytes_as_a_case_file_exit_2(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("fz") / "case.toml"
    p.write_bytes(data)
    code = main(["run", str(p), "--engine", "reference", "--out", str(p.parent / "o"), "--quiet"])
    assert code == 2
