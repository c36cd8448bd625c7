"""freebody sweep: valid random bodies, determinism by seed, worst cases that reproduce their runs."""
from __future__ import annotations

import tomllib
import warnings

import numpy as np
import pytest

from conftest import FAST_ENGINES, engine_param
from freebody.input.casefile import bundled_case_paths, load_case, parse_case
from freebody.cli import main
from freebody.run import RunSpec, TruthCache, execute
from freebody.tools.sweep import SweepSettings, dump_case, load_sweep, random_bodies, sweep

# Every registered engine but the slow ones (mjx: its JIT compile takes about a minute per body shape).
SWEEP_ENGINES = [engine_param(e) for e in FAST_ENGINES]
SMALL = SweepSettings(seed=7, count=3, duration=0.1, dts=(0.01,))
TRIANGLE_RTOL = 1e-12  # the principal moments of I_body, recomputed by eigvalsh, to round-off
UNIT_QUATERNION_ATOL = 1e-15  # |q| - 1 of a quaternion normalised once


def _without_wall_times(doc: dict) -> dict:
    doc = dict(doc)
    doc.pop("wall_time_s")
    doc.pop("created")  # to the second: two sweeps may straddle one
    doc["runs"] = [{k: v for k, v in r.items() if k != "wall_time_s"} for r in doc["runs"]]
    return doc


def test_bodies_are_physically_valid():
    settings = SweepSettings(seed=3, count=60, max_spin=7.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no quaternion needed normalising with a warning
        bodies = random_bodies(settings)
    assert len({b.problem.name for b in bodies}) == 60
    gravity = set()
    for b in bodies:
        pb = b.problem
        I = pb.body.I_body
        assert np.array_equal(I, I.T)
        m = np.linalg.eigvalsh(I)
        assert m[0] > 0
        assert m[0] + m[1] >= m[2] * (1 - TRIANGLE_RTOL)
        assert abs(np.linalg.norm(pb.initial.quaternion_wxyz) - 1) < UNIT_QUATERNION_ATOL
        assert np.linalg.norm(pb.initial.angular_velocity) <= settings.max_spin
        assert pb.torque_free and pb.duration == settings.duration and pb.dts == settings.dts
        gravity.add(bool(np.any(pb.gravity)))
        # not all diagonal: the principal frame is random
    assert gravity == {True, False}  # "mixed": both kinds occur
    assert sum(abs(b.problem.body.I_body[0, 1]) > 0 for b in bodies) > 50


def test_same_seed_same_bodies_and_prefix_property():
    a = random_bodies(SweepSettings(seed=11, count=5))
    b = random_bodies(SweepSettings(seed=11, count=8))
    c = random_bodies(SweepSettings(seed=12, count=5))
    assert [x.toml for x in a] == [x.toml for x in b[:5]]
    assert [x.toml for x in a] != [x.toml for x in c]
    off = random_bodies(SweepSettings(seed=11, count=5, gravity="off"))
    assert all(not np.any(x.problem.gravity) for x in off)
    assert [x.problem.body.mass for x in off] == [x.problem.body.mass for x in a]


@pytest.mark.parametrize("sweep_engine", SWEEP_ENGINES)
def test_same_seed_gives_identical_sweep_json(sweep_engine, tmp_path):
    engine = sweep_engine
    engines = ["reference"] if engine == "reference" else ["reference", engine]
    first = sweep(SMALL, engines, out_dir=tmp_path / "a", progress=False)
    second = sweep(SMALL, engines, out_dir=tmp_path / "b", progress=False)
    a, b = load_sweep(tmp_path / "a"), load_sweep(tmp_path / "b")
    assert _without_wall_times(a) == _without_wall_times(b)
    assert a["seed"] == 7 and a["count"] == 3 and a["schema_version"] == 2 and a["incomplete"] is False
    assert {r["engine"] for r in a["runs"]} == set(engines)
    assert all(r["status"] == "ok" for r in a["runs"]), [r["message"] for r in a["runs"]]
    assert first.report.splitlines()[2:] != [] and second.document["summary"]


@pytest.mark.parametrize("sweep_engine", SWEEP_ENGINES)
def test_worst_case_file_reproduces_its_run(sweep_engine, tmp_path):
    engine = sweep_engine
    out = sweep(SMALL, [engine], out_dir=tmp_path, progress=False)
    doc = out.document
    worst = [w for w in doc["worst_cases"] if w["reason"] == "orientation_error_max_rad"]
    assert worst
    for w in worst:
        pb = load_case(tmp_path / w["file"])
        assert pb.name == w["case"]
        spec = RunSpec(pb, w["engine"], w["integrator"], w["dt"], pb.steps(w["dt"]), w["precision"])
        again = execute(spec, TruthCache()).result
        original = next(r for r in doc["runs"] if (r["case"], r["engine"], r["integrator"], r["dt"])
                        == (w["case"], w["engine"], w["integrator"], w["dt"]))
        assert again.metrics == original["metrics"]
        assert again.metrics["orientation_error_max_rad"] == w["value"]


@pytest.mark.parametrize("name", list(bundled_case_paths()))
def test_dump_case_round_trips_every_bundled_case(name):
    pb = load_case(name)
    back = parse_case(tomllib.loads(dump_case(pb)), "<dump>")
    assert (back.name, back.description, back.duration, back.duration_steps, back.dts) == \
           (pb.name, pb.description, pb.duration, pb.duration_steps, pb.dts)
    assert back.body.mass == pb.body.mass and np.array_equal(back.body.I_body, pb.body.I_body)
    for f in ("position", "linear_velocity", "angular_velocity"):
        assert np.array_equal(getattr(back.initial, f), getattr(pb.initial, f))
    # renormalising a unit quaternion may move it by one rounding error
    np.testing.assert_allclose(back.initial.quaternion_wxyz, pb.initial.quaternion_wxyz, rtol=0, atol=1e-15)
    assert len(back.loads) == len(pb.loads)
    for x, y in zip(back.loads, pb.loads):
        for f in ("force", "torque", "body_torque", "point", "body_point", "start", "steps", "end"):
            assert np.array_equal(getattr(x, f), getattr(y, f)) if getattr(y, f) is not None \
                else getattr(x, f) is None


def test_dump_case_escapes_strings():
    pb = load_case("quiz")
    import dataclasses

    odd = dataclasses.replace(pb, description='a "quoted" \\ back\tslash\nnew line \x7f and é')
    assert parse_case(tomllib.loads(dump_case(odd))).description == odd.description


def test_cli_sweep_writes_report_and_files(tmp_path, capsys):
    out = tmp_path / "sw"
    assert main(["sweep", "--seed", "1", "--count", "2", "--engine", "reference", "--integrator", "euler-quat",
                 "--integrator", "rk4", "--duration", "0.05", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "orientation error max (rad)" in text and "reference/rk4 dt=0.01" in text
    assert (out / "sweep.json").is_file() and (out / "sweep.txt").is_file()
    assert list((out / "worst").glob("sweep_s1_*.toml"))


@pytest.mark.parametrize("argv, needle", [
    (["--count", "0"], "--count"),
    (["--duration", "0.001"], "--duration"),
    (["--max-spin", "nan"], "--max-spin"),
    (["--engine", "nosuch"], "--engine"),
    (["--jobs", "0"], "--jobs"),
    (["--jobs", "two"], "--jobs"),
])
def test_cli_sweep_bad_input_is_one_line(argv, needle, tmp_path, capsys):
    try:
        code = main(["sweep", "--out", str(tmp_path), *argv])
    except SystemExit as e:  # argparse reports its own errors
        code = e.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]
