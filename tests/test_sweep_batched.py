"""`freebody sweep --engine mjx` steps the bodies as one vmapped batch; each run's result must be
the result of the same run alone."""
from __future__ import annotations

import math

import pytest

pytest.importorskip("jax", reason="mjx not installed (pip install 'freebody[jax]')")
pytest.importorskip("mujoco.mjx", reason="mujoco-mjx not installed (pip install 'freebody[jax]')")

from freebody.run import execute, expand  # noqa: E402
from freebody.tools.sweep import SweepSettings, random_bodies, run_bodies  # noqa: E402

BATCH_VS_SINGLE_REL = 1e-9  # the same compiled float64 step, vmapped: round-off only over 0.5 s


def test_batched_mjx_sweep_runs_equal_single_runs(capsys):
    bodies = random_bodies(SweepSettings(seed=11, count=3, duration=0.5))
    runs = run_bodies(bodies, ["mjx"], ["Euler"], progress=True, precisions=["float64"])
    assert "3 bodies in one batch" in capsys.readouterr().err
    assert len(runs) == 3
    for body, run in zip(bodies, runs):
        spec = expand([body.problem], ["mjx"], ["Euler"], None, None, precisions=["float64"])[0]
        alone = execute(spec).result
        assert run["status"] == alone.status == "ok"
        for key, value in alone.metrics.items():
            got = run["metrics"][key]
            if value is None:
                assert got is None, key
            else:
                assert math.isclose(got, value, rel_tol=BATCH_VS_SINGLE_REL, abs_tol=1e-15), (key, got, value)
        assert run["vs_engine"]["engine"] == "mujoco"
        assert run["matches_reference"]["integrator"] == alone.matches_reference["integrator"]
