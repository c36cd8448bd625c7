"""A ported engine (MJX) is compared run by run with its original (C MuJoCo): results.json
``vs_engine``, the summary and the report show how far apart they are."""
from __future__ import annotations

import pytest

pytest.importorskip("jax", reason="mjx not installed (pip install 'freebody[jax]')")
pytest.importorskip("mujoco.mjx", reason="mujoco-mjx not installed (pip install 'freebody[jax]')")

from freebody.input.casefile import load_case  # noqa: E402
from freebody.report.data import port_comparison  # noqa: E402
from freebody.run import execute, expand  # noqa: E402
from freebody.report.summary import summary_table  # noqa: E402

MJX_F64_VS_C_RAD = 1e-9  # same map in float64 over 0.5 s at dt = 0.01: round-off only
MJX_F32_VS_C_MIN_RAD = 1e-7  # float32 keeps ~7 digits: it must be visibly apart from float64


def test_mjx_runs_carry_their_distance_to_c_mujoco():
    pb = load_case("dzhanibekov")
    specs = expand([pb], ["mjx"], ["Euler"], [0.01], 0.5)
    runs = {s.precision: execute(s).result for s in specs}
    assert set(runs) == {"float32", "float64"}
    for precision, r in runs.items():
        assert r.status == "ok", r.message
        v = r.vs_engine
        assert v["engine"] == "mujoco" and v["integrator"] == "Euler"
    assert runs["float64"].vs_engine["max_orientation_diff_rad"] <= MJX_F64_VS_C_RAD
    assert runs["float32"].vs_engine["max_orientation_diff_rad"] >= MJX_F32_VS_C_MIN_RAD
    docs = [r.to_json() for r in runs.values()]
    assert "vs mujoco/Euler" in summary_table(docs)
    rows = port_comparison(docs)
    assert len(rows) == 2 and all(row[3] == "mujoco/Euler" for row in rows)


def test_engines_that_port_nothing_have_no_comparison():
    pb = load_case("quiz")
    r = execute(expand([pb], ["mujoco"], ["Euler"], [0.1], None)[0]).result
    assert r.status == "ok" and r.vs_engine is None
