"""The CLI end to end on the reference engine, results.json's schema, and bad input (exit 2, one line)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from freebody.results.document import SCHEMA_VERSION
from freebody.adapters.base import REFERENCE_ENGINE, registry
from freebody.cli import main
from freebody.reference_impl.integrators import INTEGRATORS

from case_text import GOOD  # noqa: E402  (tests/ is on sys.path, as for conftest)


# (id, replacement of a line of GOOD or text appended, words the message must contain)
BAD_CASES = [
    ("malformed_toml", ("mass = 1.0", "mass = = 1.0"), ["invalid TOML"]),
    ("typo_key", ("mass = 1.0", "mas = 1.0"), ["body.mas", "unknown key", "did you mean 'mass'"]),
    ("typo_top_key", ("duration = 0.05", "duraton = 0.05"), ["duraton", "unknown key"]),
    ("missing_mass", ("mass = 1.0", ""), ["body.mass", "missing"]),
    ("missing_name", ('name = "good"', ""), ["name", "missing"]),
    ("missing_dt", ("dt = [0.01]", ""), ["dt", "missing"]),
    ("non_symmetric", ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                       "inertia = [[1.0, 0.5, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]"), ["body.inertia", "symmetric"]),
    ("not_positive_definite", ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                               "inertia = [[1.0, 0.0, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, 3.0]]"), ["positive definite"]),
    ("triangle_inequality", ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                             "inertia = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 3.0]]"), ["triangle inequality"]),
    ("inertia_not_3x3", ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                         "inertia = [1.0, 2.0, 3.0]"), ["body.inertia", "3x3"]),
    ("mass_zero", ("mass = 1.0", "mass = 0.0"), ["body.mass", "> 0"]),
    ("mass_negative", ("mass = 1.0", "mass = -1.0"), ["body.mass", "> 0"]),
    ("mass_nan", ("mass = 1.0", "mass = nan"), ["body.mass", "finite"]),
    ("mass_string", ("mass = 1.0", 'mass = "heavy"'), ["body.mass", "number"]),
    ("mass_and_density", ("mass = 1.0\ninertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                          'shape = "box"\nsize = [1.0, 2.0, 3.0]\nmass = 1.0\ndensity = 1000.0'), ["mass", "density"]),
    ("unknown_shape", ("mass = 1.0\ninertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                       'shape = "torus"\nsize = [1.0]\nmass = 1.0'), ["body.shape", "torus"]),
    ("shape_bad_size", ("mass = 1.0\ninertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                        'shape = "box"\nsize = [1.0, 2.0]\nmass = 1.0'), ["body.size", "3 numbers"]),
    ("inf_velocity", ("linear_velocity = [0.0, 0.0, 0.0]", "linear_velocity = [inf, 0.0, 0.0]"), ["initial.linear_velocity[0]", "finite"]),
    ("nan_in_inertia", ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]",
                        "inertia = [[nan, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]"), ["body.inertia[0][0]", "finite"]),
    ("zero_quaternion", ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [0.0, 0.0, 0.0, 0.0]"), ["initial.orientation", "zero quaternion"]),
    ("quaternion_length", ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [1.0, 0.0, 0.0]"), ["initial.orientation", "4 numbers"]),
    ("dt_zero", ("dt = [0.01]", "dt = [0.0]"), ["dt", "> 0"]),
    ("dt_negative", ("dt = [0.01]", "dt = [-0.01]"), ["dt", "> 0"]),
    ("dt_empty", ("dt = [0.01]", "dt = []"), ["dt", "at least one"]),
    ("duration_shorter_than_dt", ("duration = 0.05", "duration = 0.001"), ["duration", "shorter than dt"]),
    ("duration_and_steps", ("duration = 0.05", "duration = 0.05\nduration_steps = 3"), ["duration", "exactly one"]),
    ("duration_steps_float", ("duration = 0.05", "duration_steps = 2.5"), ["duration_steps", "integer"]),
    ("gravity_length", ("gravity = [0.0, 0.0, 0.0]", "gravity = [0.0, -9.81]"), ["world.gravity", "3 numbers"]),
    ("world_typo", ("gravity = [0.0, 0.0, 0.0]", "gravty = [0.0, 0.0, 0.0]"), ["world.gravty", "unknown key"]),
    ("load_point_and_body_point", ("", "[[loads]]\nforce = [1.0, 0.0, 0.0]\npoint = [0.0, 0.0, 0.0]\nbody_point = [1.0, 0.0, 0.0]"), ["loads[0].point", "at most one"]),
    ("load_steps_and_end", ("", "[[loads]]\nforce = [1.0, 0.0, 0.0]\nsteps = 1\nend = 1.0"), ["loads[0].steps", "at most one"]),
    ("load_empty", ("", "[[loads]]\nstart = 0.0"), ["loads[0]", "force, torque or body_torque"]),
    ("load_end_before_start", ("", "[[loads]]\ntorque = [1.0, 0.0, 0.0]\nstart = 1.0\nend = 0.5"), ["loads[0].end", "after start"]),
    ("load_typo", ("", "[[loads]]\nforse = [1.0, 0.0, 0.0]"), ["loads[0].forse", "unknown key"]),
    ("load_negative_start", ("", "[[loads]]\ntorque = [1.0, 0.0, 0.0]\nstart = -1.0"), ["loads[0].start", ">= 0"]),
    ("name_empty", ('name = "good"', 'name = ""'), ["name", "non-empty"]),
]


def _write_bad(tmp_path: Path, case_id: str, change) -> Path:
    old, new = change
    text = GOOD.replace(old, new, 1) if old else GOOD + new + "\n"
    assert text != GOOD
    p = tmp_path / f"{case_id}.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("case_id,change,words", BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_bad_case_file_is_one_line_exit_2(tmp_path, capsys, case_id, change, words):
    p = _write_bad(tmp_path, case_id, change)
    code = main(["run", str(p), "--engine", "reference", "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert err.startswith("freebody: error: ") and str(p) in err
    for w in words:
        assert w in err, (w, err)
    assert not (tmp_path / "out" / "results.json").exists()


BAD_ARGS = [
    (["run", "no_such_case"], ["no_such_case", "unknown case"]),
    (["run", "dzhanibekov", "--engine", "nosuchengine"], ["unknown engine", "nosuchengine"]),
    (["run", "dzhanibekov", "--engine", "reference", "--integrator", "leapfrog"], ["reference offers none", "'leapfrog'", "rk4"]),
    (["run", "dzhanibekov", "--engine", "reference", "--integrator", "reference:leapfrog"], ["no integrator 'leapfrog'"]),
    (["run", "dzhanibekov", "--dt", "0"], ["--dt", "> 0"]),
    (["run", "dzhanibekov", "--dt", "-1e-3"], ["--dt"]),
    (["run", "dzhanibekov", "--dt", "nan"], ["--dt"]),
    (["run", "dzhanibekov", "--duration", "abc"], ["--duration"]),
    (["run", "dzhanibekov", "--dt", "0.1", "--duration", "0.01"], ["--duration", "shorter than dt"]),
    (["run", "missing/file.toml"], ["case file not found"]),
    (["frobnicate"], ["invalid choice"]),
]


def _exit_code(argv) -> int:
    """main()'s return code, or argparse's exit code for errors it reports itself."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


@pytest.mark.parametrize("argv,words", BAD_ARGS, ids=[" ".join(a[0][1:]) or a[0][0] for a in BAD_ARGS])
def test_bad_arguments_are_one_line_exit_2(tmp_path, capsys, argv, words):
    extra = ["--out", str(tmp_path / "o"), "--quiet"] if argv[0] == "run" else []
    code = _exit_code(argv + extra)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)


def test_non_unit_quaternion_is_normalised_with_a_warning(tmp_path, capsys):
    p = tmp_path / "c.toml"
    p.write_text(GOOD.replace("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [2.0, 0.0, 0.0, 0.0]"))
    code = main(["run", str(p), "--engine", "reference", "--integrator", "rk4", "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 0
    assert "normalised" in capsys.readouterr().err
    run = json.loads((tmp_path / "o" / "results.json").read_text())["runs"][0]
    assert abs(sum(x * x for x in run["final_state"]["quaternion_wxyz"]) - 1) < 1e-12


RUN_KEYS = {"case", "engine", "integrator", "precision", "dt", "steps", "status", "message", "truth",
            "metrics", "final_state", "trajectory", "wall_time_s"}
METRIC_KEYS = {"orientation_error_max_rad", "orientation_error_final_rad", "angular_momentum_error_max_rel",
               "energy_error_max_rel", "position_error_max_m", "rotation_orthonormality_error_max"}


def test_run_writes_results_json_and_trajectories(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", "quiz", "projectile", "--engine", "reference", "--dt", "0.01",
                 "--out", str(out), "--quiet"])
    printed = capsys.readouterr().out
    assert code == 0
    text = (out / "results.json").read_text()
    doc = json.loads(text)
    assert doc["schema_version"] == SCHEMA_VERSION == 7
    assert {"freebody_version", "created", "platform", "engines", "runs"} <= set(doc)
    assert list(doc) == sorted(doc)  # sorted keys
    assert len(doc["runs"]) == 2 * len(INTEGRATORS)  # two cases, every reference integrator
    for run in doc["runs"]:
        assert RUN_KEYS <= set(run)
        if run["integrator"] == "euler-matrix" and run["case"] == "projectile":  # R stops being a rotation
            assert run["status"] == "diverged" and "R is no rotation" in run["message"]
        else:
            assert run["status"] == "ok", run["message"]
        assert METRIC_KEYS <= set(run["metrics"])
        assert (out / run["trajectory"]).is_file()
    quiz = [r for r in doc["runs"] if r["case"] == "quiz"]
    assert all(r["truth"] == "numerical" and r["steps"] == 2 for r in quiz)
    assert all(r["truth"] == "closed-form" for r in doc["runs"] if r["case"] == "projectile")
    assert "euler-matrix" in printed and "ok" in printed


def test_diverged_run_is_a_status_with_nulls_not_nan(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", "dzhanibekov", "--engine", "reference", "--integrator", "euler-matrix", "--dt", "0.01",
                 "--out", str(out), "--quiet"])
    assert code == 0  # diverged is a result, not a failure
    text = (out / "results.json").read_text()
    run = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-finite number {c} in results.json"))["runs"][0]
    assert run["status"] == "diverged" and run["diverged_at_s"] > 1.0
    assert run["metrics"]["orientation_error_max_rad"] is None


def test_list_shows_every_bundled_case(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in ("quiz", "dzhanibekov", "dzhanibekov_rotated", "stable_major_axis", "projectile"):
        assert name in out


def test_console_script_and_no_traceback_in_a_real_process(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("mass = 1.0", "mass = -3"))
    r = subprocess.run([sys.executable, "-m", "freebody", "run", str(bad), "--out", str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "body.mass" in r.stderr


def test_import_freebody_imports_no_engine():
    # every registered engine's package and adapter module (the reference maps are numpy's, which
    # freebody always imports; mujoco.mjx is the mjx engine's package beside its "jax" import name)
    watched = sorted({m for name, e in registry().items() if name != REFERENCE_ENGINE
                      for m in (e.import_name, e.module)} | {"mujoco.mjx"})
    code = ("import sys, freebody, freebody.run, freebody.cli, freebody.adapters.base; "
            "from freebody.cli import build_parser; build_parser(); "
            f"print(sorted(m for m in {watched!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_python_api_returns_arrays_and_metrics():
    import freebody

    out = freebody.run_case("dzhanibekov", engine="reference", integrator="RK4", dt=0.01, duration=1.0)
    assert out.result.integrator == "rk4" and out.result.status == "ok"
    assert out.trajectory.quaternion_wxyz.shape == (101, 4)
    assert out.result.metrics["orientation_error_max_rad"] < 1e-5


def test_same_inputs_give_the_same_numbers(tmp_path):
    docs = []
    for i in range(2):
        main(["run", "quiz", "projectile", "--engine", "reference", "--duration", "0.2", "--out", str(tmp_path / str(i)),
              "--quiet", "--no-report"])
        doc = json.loads((tmp_path / str(i) / "results.json").read_text())
        docs.append([{k: v for k, v in r.items() if k != "wall_time_s"} for r in doc["runs"]])
    assert docs[0] == docs[1]


def test_run_with_a_baseline_shows_the_compare_verdict_in_the_report(tmp_path, capsys):
    """--baseline: the report carries the compare verdict; an unusable baseline is exit 2 before any run."""
    args = ["run", "quiz", "--engine", "reference", "--integrator", "rk4", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "a"), "--no-report"]) == 0
    assert main([*args, "--out", str(tmp_path / "b"), "--baseline", str(tmp_path / "a")]) == 0
    report = (tmp_path / "b" / "report.md").read_text()
    assert "compare verdict" in report and "Compare with baseline" in report
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "c"), "--baseline", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--baseline" in err[0] and not (tmp_path / "c").exists()
    assert main(["report", str(tmp_path / "a"), "--baseline", str(tmp_path / "b")]) == 0
    assert "compare verdict" in (tmp_path / "a" / "report.md").read_text()
