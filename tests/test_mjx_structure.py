"""MJX compiles each model structure once per machine: every free body shares one model structure
per (integrator, precision) without changing a bit of its trajectory, and compilations are kept
in a persistent on-disk cache shared by processes (skipped without the ``jax`` extra).

Arrays follow freebody's canonical convention (reference_impl/conventions.py).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("jax", reason="jax not installed (pip install 'freebody[jax]')")
pytest.importorskip("mujoco.mjx", reason="mujoco-mjx not installed (pip install 'freebody[jax]')")

import jax  # noqa: E402

from freebody.adapters import jax_runtime, mjx_adapter  # noqa: E402
from freebody.adapters.base import ENGINES  # noqa: E402
from freebody.adapters.mjx_adapter import MjxAdapter  # noqa: E402
from freebody.input.casefile import bundled_case_paths, load_case  # noqa: E402
from freebody.reference_impl.problem import Body, InitialState, Load, Problem  # noqa: E402

DT = 0.01
STEPS = 60
# A body whose body frame is its principal frame with Ixx > Iyy > Izz: MuJoCo's "simple body"
# (diagonal mass-matrix sparsity); and a body with a non-diagonal inertia (full sparsity).
PRINCIPAL_INERTIA = np.diag([4.0, 3.0, 2.0])  # kg m^2
ROTATED_INERTIA = np.array([[2.0, 0.3, -0.1], [0.3, 3.0, 0.2], [-0.1, 0.2, 4.0]])  # kg m^2
LOADS = (Load(force=[0.5, -1.0, 2.0], body_point=[0.1, 0.2, -0.3], start=0.0, end=0.3),
         Load(force=[1.0, 0.3, -0.2], point=[2.0, -1.5, 0.9], start=0.1, end=0.4),
         Load(torque=[0.05, 0.0, -0.1], body_torque=[0.1, -0.2, 0.3], start=0.05, steps=20))


def _problem(inertia: np.ndarray) -> Problem:
    return Problem("structure-test", "", Body(1.3, inertia),
                   InitialState([1.0, -2.0, 3.0], [0.9, 0.3, -0.1, 0.2], [0.3, 0.0, -0.2], [0.7, -1.3, 2.1]),
                   [0.0, 0.0, -9.81], loads=LOADS, duration=STEPS * DT)


def _structure(problem: Problem, integrator: str, precision: str):
    with jax_runtime.x64_scope(precision == "float64"):
        mx, _, _, mask = mjx_adapter._build(problem, DT, integrator, precision, False)
    return jax.tree_util.tree_structure(mx), mask


def test_mjx_make_m_is_the_checked_one():
    """The normalisation relies on a copy of MJX's make_m: a new MJX whose make_m differs turns it
    off (correct, but one compilation per structure again) and must be re-checked."""
    assert mjx_adapter.NORMALISE, (
        "mujoco.mjx._src.support.make_m is not the source _make_m_masked copies: compare the two, "
        "update _make_m_masked and _MAKE_M_SHA256, and re-run this file's bit-for-bit tests")


@pytest.mark.parametrize("integrator,precision", [("Euler", "float64"), ("RK4", "float32")])
def test_every_bundled_case_has_one_structure(integrator, precision):
    """Principal-frame bodies (MuJoCo's "simple" bodies, e.g. far_from_origin) and the others
    share one model structure after normalisation; their masks still tell them apart."""
    structures, masks = set(), set()
    for name in bundled_case_paths():
        treedef, mask = _structure(load_case(name), integrator, precision)
        structures.add(treedef)
        masks.add(np.asarray(mask).tobytes())
    assert len(structures) == 1
    assert len(masks) == 2  # diagonal (simple body) and lower-triangular (the others)


@pytest.mark.parametrize("integrator,precision", [("Euler", "float64"), ("RK4", "float32")])
@pytest.mark.parametrize("inertia", [PRINCIPAL_INERTIA, ROTATED_INERTIA], ids=["principal", "rotated"])
def test_normalised_model_steps_bit_for_bit(integrator, precision, inertia, monkeypatch):
    """The normalised model with the body's mass-matrix mask as an argument gives the trajectory
    of MJX's own model, bit for bit (RK4 builds the mass matrix four times per step)."""
    pb = _problem(inertia)
    _, mask = _structure(pb, integrator, precision)
    full = np.tril(np.ones((6, 6), bool))
    assert np.array_equal(mask, np.eye(6, dtype=bool) if inertia is PRINCIPAL_INERTIA else full)
    normalised = MjxAdapter(pb, DT, integrator, precision).simulate(STEPS)
    assert np.all(np.isfinite(normalised.quaternion_wxyz))
    monkeypatch.setattr(mjx_adapter, "NORMALISE", False)
    own = MjxAdapter(pb, DT, integrator, precision)
    assert own._mask is None
    own = own.simulate(STEPS)
    for field in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity"):
        assert np.array_equal(getattr(normalised, field), getattr(own, field)), field


def test_batch_mixes_principal_and_rotated_bodies():
    """One vmapped batch takes both kinds of body (before normalisation: ValueError)."""
    problems = [_problem(PRINCIPAL_INERTIA), _problem(ROTATED_INERTIA)]
    batch = MjxAdapter.simulate_batch(problems, DT, 20, "Euler", "float64")
    for pb, tr in zip(problems, batch.trajectories):
        single = MjxAdapter(pb, DT, "Euler", "float64").simulate(20)
        assert np.max(np.abs(tr.quaternion_wxyz - single.quaternion_wxyz)) <= 1e-12


def test_default_cache_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert mjx_adapter.default_cache_dir() == os.path.join(str(tmp_path), "freebody", "jax")
    for unusable in ("", "relative/dir"):
        monkeypatch.setenv("XDG_CACHE_HOME", unusable)
        assert mjx_adapter.default_cache_dir() == os.path.join(
            os.path.expanduser("~"), ".cache", "freebody", "jax")


def test_worker_processes_are_not_given_a_private_cache():
    """The executor gives an engine's cache_env a per-invocation folder; mjx declares none, so
    its workers use the persistent folder like a serial run."""
    assert ENGINES["mjx"].cache_env is None


_CHILD = textwrap.dedent("""
    import json, os, numpy as np
    from freebody.adapters import mjx_adapter
    from freebody.adapters.mjx_adapter import MjxAdapter
    from freebody.reference_impl.problem import Body, InitialState, Problem
    pb = Problem("p", "", Body(1.0, np.diag([1.0, 2.0, 3.0])),
                 InitialState([0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [0.01, 5.0, 0.0]), [0, 0, 0], duration=0.03)
    a = MjxAdapter(pb, 0.01, "Euler", "float64")
    tr = a.simulate(3)
    print(json.dumps({"dir": mjx_adapter.CACHE_DIR, "stats": mjx_adapter.COMPILE_STATS,
                      "compile_time_s": a.compile_time_s, "q": tr.quaternion_wxyz.tolist()}))
""")


def _child(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD], env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_compilation_is_kept_on_disk_across_processes(tmp_path):
    """A first process compiles into $XDG_CACHE_HOME/freebody/jax; a second one loads it (no
    compilation) and computes the same numbers."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    first = _child(env)
    folder = os.path.join(str(tmp_path), "freebody", "jax")
    assert first["dir"] == folder and os.path.isdir(folder)
    assert first["stats"]["compiled"] == 1 and first["stats"]["from_disk"] == 0
    assert any(name.endswith("-cache") for name in os.listdir(folder))
    second = _child(env)
    assert second["stats"]["compiled"] == 0 and second["stats"]["from_disk"] == 1
    assert second["q"] == first["q"]
    # JAX_COMPILATION_CACHE_DIR overrides the folder
    env["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path / "elsewhere")
    third = _child(env)
    assert third["dir"] == str(tmp_path / "elsewhere") and third["stats"]["compiled"] == 1
