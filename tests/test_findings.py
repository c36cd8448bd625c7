"""Findings and the verdict page, from hand-made runs: each kind of finding is raised by the
results field it names (and only then), with its size and, from the saved trajectories, the time
of its first sample; runs are grouped by the map they reproduce and the differences between groups
attributed to the schemes; the overview tables show one answer per engine run and only the
settings that changed; the reports open on the verdict."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from freebody import tolerances as tol
from freebody.cli import main
from freebody.reference_impl.rotations import quat_from_rotvec
from freebody.report import data as rd
from freebody.report import findings as fd
from freebody.report.render import write_reports
from freebody.results.judgement import with_judgement

LEVEL = 1e-12  # the round-off level the hand-made identifications report (rad)
MAPS = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro", "rk4", "implicit-gyro-split-torque")


def q_about_z(angle: float) -> list[float]:
    return quat_from_rotvec(np.array([0.0, 0.0, angle])).tolist()


def match(reproduces: str | None, closest: str | None = None, distance: float = 1e-14,
          tie: tuple[str, ...] = ()) -> dict:
    """A matches_reference dict: ``reproduces`` to round-off (``distance``), or none with
    ``closest`` at ``distance``; every other map 1 rad away."""
    best = reproduces or closest
    candidates = {m: 1.0 for m in MAPS}
    candidates[best] = distance
    for m in tie:
        candidates[m] = distance
    verdict = ("indistinguishable" if tie else "reproduces") if reproduces else "closest"
    return {"verdict": verdict, "integrator": reproduces, "closest": best, "max_orientation_diff_rad": distance,
            "threshold_rad": LEVEL, "indistinguishable": ([reproduces, *tie] if reproduces else []),
            "candidates": candidates, "levels_rad": {m: LEVEL for m in MAPS},
            "ratios": {m: v / LEVEL for m, v in candidates.items()}, "rule": "(test)", "undecidable": []}


def run(engine: str, integrator: str, case: str = "c", dt: float = 0.01, error: float = 1e-3,
        reproduces: str | None = "semi-implicit-explicit-gyro", status: str = "ok", angle: float = 0.5,
        **extra) -> dict:
    """An engine run (ok by default): orientation error max ``error``, final orientation ``angle``
    about z, reproducing ``reproduces``; with its ``judgement`` as the run layer stores it (a test
    that changes a field afterwards judges the run again: :func:`with_judgement`)."""
    r = {"case": case, "engine": engine, "integrator": integrator, "precision": "float64", "dt": dt,
         "steps": 100, "status": status, "message": "", "engine_version": "1.0",
         "metrics": {"orientation_error_max_rad": error}, "trajectory": None, "diverged_at_s": None,
         "final_state": {"quaternion_wxyz": q_about_z(angle), "angular_velocity": [0.0, 0.0, 1.0],
                         "linear_velocity": [0.0, 0.0, 0.0], "position": [0.0, 0.0, 0.0], "t": 1.0},
         "matches_reference": None if engine == "reference" else match(reproduces), "vs_engine": None,
         "load_sampling": None}
    r.update(extra)
    return with_judgement(r)


def kinds(found) -> list[tuple[str, str, str]]:
    return [(f.kind, f.label, f.case) for f in found]


# --- each finding ------------------------------------------------------------------------------------

def test_a_run_that_reproduces_no_map_is_a_finding_with_its_closest_map():
    runs = [run("a", "x"), run("b", "y", matches_reference=match(None, closest="rk4", distance=2.7e-3))]
    found = fd.find(runs)
    assert kinds(found) == [("no-map", "b/y", "c")]
    f = found[0]
    assert f.severity == "warning" and f.source == "matches_reference"
    assert f.size_rad == 2.7e-3 and "closest rk4 at 2.7e-03 rad" in f.text and "2.7e+09 x" in f.text


def test_runs_of_one_map_that_disagree_beyond_round_off_are_an_error_with_the_time_it_began():
    a = run("a", "x", angle=0.5)
    b = run("b", "y", angle=0.5 + 1e-6)  # both reproduce the map to 1e-14, yet end 1e-6 apart
    same = run("c", "z", angle=0.5 + 1e-13)  # within the two levels: agrees
    t = np.linspace(0.0, 1.0, 11)
    qs = {id(a): np.array([q_about_z(0.5 * s) for s in t]),
          id(b): np.array([q_about_z(0.5 * s + (1e-6 if s >= 0.6 else 0.0)) for s in t]),
          id(same): np.array([q_about_z(0.5 * s) for s in t])}
    found = fd.find([a, b, same], trajectory=lambda r: (t, qs[id(r)], qs[id(a)]))
    assert {(f.kind, f.label, f.other) for f in found} == {("same-map-disagreement", "a/x", "b/y"),
                                                             ("same-map-disagreement", "b/y", "c/z")}
    f = [f for f in found if f.other == "b/y"][0]
    assert f.severity == "error" and f.size_rad == pytest.approx(1e-6, rel=1e-6)
    assert f.t_s == pytest.approx(0.6) and "both reproduce semi-implicit-explicit-gyro" in f.text


def test_an_error_far_above_the_other_engines_is_an_outlier_naming_its_map():
    runs = [run("a", "x", error=1e-13), run("b", "y", error=1.2e-13), run("c", "z", error=0.9e-13),
            run("p", "capped", error=3.1, reproduces="implicit-gyro-split-torque"),
            run("reference", "euler-quat", error=3.0)]  # a reference map is never an outlier
    t = np.linspace(0.0, 1.0, 101)
    truth = np.array([q_about_z(150 * s) for s in t])
    capped = np.array([q_about_z(min(150 * s, 0.78 * round(s / 0.01))) for s in t])
    found = fd.find(runs, trajectory=lambda r: (t, capped, truth) if r["engine"] == "p" else None)
    assert kinds(found) == [("outlier", "p/capped", "c")]
    f = found[0]
    assert f.size_rad == 3.1 and f.source == "orientation_error_max_rad"
    assert "implicit-gyro-split-torque" in f.text and "capped world exp map" in f.text  # the map's summary
    assert f.t_s == pytest.approx(0.01)  # the cap bites at the first step


def test_a_first_order_run_is_not_an_outlier_against_a_fourth_order_one():
    runs = [run("a", "Euler", error=1e-3), run("b", "RK4", error=1e-11, reproduces="rk4")]
    assert fd.outlier_findings(runs) == []
    runs.append(run("c", "Euler", error=1e-3))
    assert fd.outlier_findings(runs) == []  # first-order maps among themselves


def test_errors_below_the_truths_accuracy_are_no_outlier():
    runs = [run("a", "x", error=1e-15), run("b", "y", error=1e-15), run("c", "z", error=5e-11)]
    assert fd.outlier_findings(runs) == []  # 5e4 x the median, but below 100 x 1e-9 rad


def test_a_run_that_reproduces_another_map_on_one_case_is_a_scheme_switch():
    runs = [run("a", "x", case=c) for c in ("c1", "c2", "c3")]
    runs.append(run("a", "x", case="c4", reproduces="implicit-gyro-split-torque"))
    found = fd.find(runs)
    assert kinds(found) == [("scheme-switch", "a/x", "c4")]
    assert "3 of its 4 runs reproduce semi-implicit-explicit-gyro" in found[0].text
    # a tie that holds the usual map is no switch
    runs[-1] = with_judgement({**runs[-1], "matches_reference": match("implicit-gyro-split-torque",
                                                                      tie=("semi-implicit-explicit-gyro",))})
    assert fd.find(runs) == []


def test_status_findings_failed_diverged_unsupported_and_missing_engines():
    runs = [run("a", "x", status="failed", message="RuntimeError: boom", matches_reference=None),
            run("a", "x", dt=0.001, status="diverged", message="diverged at t = 0.25 s: state is not finite",
                diverged_at_s=0.25, metrics={"orientation_error_max_before_divergence_rad": 0.1},
                matches_reference=None),
            run("reference", "euler-matrix", status="diverged", diverged_at_s=2.0, message="diverged at t = 2 s: R"),
            run("b", "y", status="skipped", engine_version="9.0", message="b 9.0 is not supported: ...",
                matches_reference=None),
            *[run("m", "*", case=c, status="skipped", engine_version=None, message="m not installed: pip install m",
                  matches_reference=None) for c in ("c1", "c2")]]
    found = fd.find(runs)
    by = {f.kind: f for f in found}
    assert [f.severity for f in found] == sorted((f.severity for f in found), key=fd.SEVERITIES.index)
    assert by["failed"].severity == "error" and "RuntimeError: boom" in by["failed"].text
    d = by["diverged"]
    assert d.t_s == 0.25 and d.size_rad == 0.1 and "state is not finite" in d.text and d.severity == "warning"
    assert by["reference-diverged"].severity == "info"
    assert by["unsupported-version"].severity == "warning"
    assert [f.text for f in found if f.kind == "not-installed"] == ["2 runs skipped: m not installed: pip install m"]


def test_a_ported_engine_farther_from_its_original_than_round_off():
    near = run("mjx", "RK4", vs_engine={"engine": "mujoco", "integrator": "RK4", "max_orientation_diff_rad": 1e-14,
                                        "final_orientation_diff_rad": 1e-14})
    far = run("mjx", "Euler", vs_engine={"engine": "mujoco", "integrator": "Euler", "max_orientation_diff_rad": 1e-6,
                                         "final_orientation_diff_rad": 5e-7})
    gone = run("mjx", "implicit", vs_engine={"engine": "mujoco", "integrator": "implicit",
                                             "message": "mujoco offers no implicit"})
    found = fd.vs_engine_findings([near, far, gone])
    assert [(f.kind, f.label) for f in found] == [("vs-engine", "mjx/Euler"), ("vs-engine-unavailable", "mjx/implicit")]
    assert found[0].size_rad == 1e-6 and found[0].other == "mujoco/Euler"


def test_findings_of_one_kind_and_run_share_a_line_when_many():
    runs = [run("reference", "euler-matrix", case=f"c{i}", status="diverged", diverged_at_s=1.0,
                message="diverged at t = 1 s: R") for i in range(5)]
    runs.append(run("reference", "rk4", status="diverged", diverged_at_s=1.0, message="x"))
    lines = fd.summarize(fd.find(runs))
    assert [(ln.label, len(ln.items)) for ln in lines] == [("reference/euler-matrix", 5), ("reference/rk4", 1)]


# --- the verdict page's groups ----------------------------------------------------------------------

def test_runs_are_grouped_by_the_map_they_reproduce_and_groups_differ_by_scheme():
    runs = [run("a", "Euler", angle=0.5), run("b", "semi", angle=0.5),
            run("a", "implicit", reproduces="semi-implicit-implicit-gyro", angle=0.7,
                matches_reference=match("semi-implicit-implicit-gyro", tie=("implicit-gyro-split-torque",))),
            run("p", "maximal", reproduces="implicit-gyro-split-torque", angle=0.7),
            run("z", "odd", angle=1.5, matches_reference=match(None, closest="rk4", distance=1e-3)),
            run("reference", "rk4")]  # the maps themselves: in no group
    groups = fd.scheme_groups(runs)
    assert [(g.name, [m.label for m in g.members]) for g in groups] == [
        ("semi-implicit-explicit-gyro", ["a/Euler", "b/semi"]),
        ("semi-implicit-implicit-gyro = implicit-gyro-split-torque", ["a/implicit"]),
        ("implicit-gyro-split-torque", ["p/maximal"]),
        ("none (closest rk4)", ["z/odd"])]
    m = groups[0].members[0]
    assert m.distance_rad == 1e-14 and m.level_rad == LEVEL and m.ratio == pytest.approx(0.01)
    text = {(p.a.name, p.b.name): p for p in fd.between_groups(groups)}
    p = text[("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro = implicit-gyro-split-torque")]
    assert p.angle_rad == pytest.approx(0.2) and p.attribution == (
        "differs by scheme (semi-implicit-explicit-gyro vs semi-implicit-implicit-gyro = implicit-gyro-split-torque)")
    # ties that share a map: the groups agree to round-off on this case
    assert text[("semi-implicit-implicit-gyro = implicit-gyro-split-torque", "implicit-gyro-split-torque")].agree
    columns, rows = fd.between_table(groups)
    assert columns[0] == "between groups" and len(rows) == 6


def test_pair_relation_same_map_or_scheme():
    a, b = run("a", "x"), run("b", "y")
    c = run("c", "z", reproduces="rk4")
    assert fd.pair_relation(a, b) == "same map (semi-implicit-explicit-gyro)"
    assert fd.pair_relation(a, c) == "differs by scheme (semi-implicit-explicit-gyro vs rk4)"
    assert fd.pair_relation(run("reference", "rk4"), c) == "same map (rk4)"
    assert fd.pair_relation(a, run("d", "w", status="failed")) == ""


# --- overview tables ------------------------------------------------------------------------------------

def test_settings_table_lists_only_real_changes():
    runs = [run("e", "x", engine_settings={"timestep": {"default": 0.002, "set": 0.01},
                                           "alignfree": {"default": False, "set": False},
                                           "gravity": {"default": [0.0, 0.0, -9.81], "set": [0.0, 0.0, 0.0]}}),
            run("e", "x", dt=0.001, engine_settings={"timestep": {"default": 0.002, "set": 0.001},
                                                     "alignfree": {"default": False, "set": False}})]
    assert [row[1] for row in rd.settings_forced(runs)] == ["gravity", "timestep"]
    assert rd.settings_forced(runs)[1][3] == "0.01, 0.001"
    assert rd.settings_unchanged(runs) == 1 and "1 more" in rd.settings_note(runs)


def test_reproduction_summary_gives_one_answer_per_engine_run_and_names_the_cases_elsewhere():
    runs = [run("a", "RK4", case=c, reproduces="rk4") for c in ("c1", "c2", "c3")]
    runs.append(run("a", "RK4", case="c4", matches_reference=match(None, closest="rk4", distance=1e-3)))
    runs.append(run("reference", "rk4"))
    rows = rd.reproduction_summary(runs)
    assert rows == [("a/RK4", "rk4", "3 of 4", "c4 0.01: none (closest rk4)", 1e-3)]


def test_error_cells_are_per_time_step():
    runs = [run("a", "x", dt=0.01, error=1.0), run("a", "x", dt=0.001, error=1e-3),
            run("a", "x", case="d", dt=0.001, status="diverged", error=None)]
    cells = rd.error_cells(runs)
    assert list(cells) == [0.01, 0.001]
    assert cells[0.01] == {("c", "a/x"): ("ok", 1.0)}
    assert cells[0.001] == {("c", "a/x"): ("ok", 1e-3), ("d", "a/x"): ("diverged", None)}


# --- the reports open on the verdict --------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("findings_run")
    assert main(["run", "dzhanibekov", "--engine", "reference", "--integrator", "euler-quat",
                 "--integrator", "rk4", "--duration", "0.2", "--dt", "0.01", "--out", str(out),
                 "--quiet", "--no-report"]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_reports_open_on_findings_and_show_the_compare_verdict(small_run):
    out, doc = small_run
    base = copy.deepcopy(doc)
    base["runs"][0]["metrics"]["orientation_error_max_rad"] *= 0.5  # this run got worse
    md_path, html_path = write_reports(out, doc, baseline=base)
    md, html = md_path.read_text(), html_path.read_text()
    sections = [ln for ln in md.splitlines() if ln.startswith("## ")]
    assert sections[:3] == ["## Findings", "## Compare with baseline", "## Verdict per case"]
    assert "**baseline** · compare verdict · REGRESSION" in md
    assert html.index('id="findings"') < html.index('id="compare"') < html.index('id="verdict"') \
        < html.index("<h2>Engines</h2>")
    for r in doc["runs"]:  # every run has its anchor, every figure too
        assert f'id="{rd.run_anchor(r)}"' in html and f'id="{rd.figure_anchor(r["case"], r["dt"])}"' in html


def test_outlier_floor_is_the_truths_accuracy():
    assert fd.OUTLIER_FLOOR_RAD["float64"] == tol.CONVERGENCE_ORIENTATION_FLOOR_RAD


# --- blow-ups, the rotation cap per step, saturated orientations (issue 26, items 5 and 8) ----------

def thin_disk(duration: float = 3.5):
    """A thin disk (r = 0.5 m, 2 cm thick, 2 kg) spun at 20 rad/s about the vertical with its axis
    tilted 30 degrees, under gravity: torque-free about its COM, so the truth spins steadily, while
    an explicit gyroscopic term at dt = 0.01 blows up (|w| beyond 20x the truth's from t = 2.5 s)."""
    from freebody.reference_impl.problem import Body, InitialState, Problem

    m, r, h = 2.0, 0.5, 0.02
    it = m * (3 * r * r + h * h) / 12
    return Problem(name="thin_disk", description=thin_disk.__doc__, body=Body(m, np.diag([it, it, m * r * r / 2])),
                   initial=InitialState(np.zeros(3), quat_from_rotvec(np.array([np.pi / 6, 0.0, 0.0])),
                                        np.zeros(3), np.array([0.0, 0.0, 20.0])),
                   gravity=np.array([0.0, 0.0, -9.81]), duration=duration, dts=(0.01,))


# the engines whose default integrator has an explicit gyroscopic term, and one implicit (bounded)
EXPLICIT_GYRO = (("mujoco", "Euler"), ("pybullet", "multibody"), ("dart", "semi-implicit-euler"))
IMPLICIT_GYRO = (("mujoco", "implicitfast"), ("pybullet", "maximal"))


@pytest.fixture(scope="module")
def disk_runs():
    from freebody.adapters.base import is_available
    from freebody.api import run_case

    missing = sorted({e for e, _ in EXPLICIT_GYRO + IMPLICIT_GYRO if not is_available(e)})
    if missing:
        pytest.skip(f"not installed: {', '.join(missing)}")
    pb = thin_disk()
    return [run_case(pb, engine=e, integrator=i, dt=0.01).result.to_json() for e, i in EXPLICIT_GYRO + IMPLICIT_GYRO]


def test_the_thin_disk_blow_up_is_a_finding_for_the_explicit_gyro_engines(disk_runs):
    from freebody.report.summary import terminal_summary

    found = fd.find(disk_runs)
    blown = {f.label for f in found if f.kind == "blow-up"}
    assert blown == {f"{e}/{i}" for e, i in EXPLICIT_GYRO}
    for r in disk_runs:
        g = r["state_growth"]
        if (r["engine"], r["integrator"]) in EXPLICIT_GYRO:
            assert r["status"] == "ok" and g["omega_ratio"] > tol.BLOW_UP_OMEGA_FACTOR
            assert 2.0 < g["blow_up_t_s"] < 3.0  # |w| passes 20x the truth's at 2.5 s
        else:  # the implicit gyroscopic term keeps |w| and the energy bounded
            assert g["blow_up_t_s"] is None and g["omega_ratio"] < 1.01 and g["kinetic_energy_ratio"] < 1.01
    for f in found:  # "closest ... at 3.1 rad" is never said of a saturated run
        assert "closest" not in f.text, f.text
    text = " ".join(f.text for f in found if f.kind == "blow-up")
    assert "|w| " in text and "rad/s" in text and "kinetic energy x" in text
    import re

    from freebody.report.markdown import front_matter
    from freebody.report.summary import summary_table

    pages = "\n".join(front_matter({"runs": disk_runs}, "test")) + summary_table(disk_runs)
    assert not re.findall(r"closest [a-z0-9]+-[a-z0-9-]+", pages)  # nor on the verdict page and tables
    cells = terminal_summary(disk_runs).splitlines()
    row = next(ln for ln in cells if ln.startswith("thin_disk"))
    assert row.count("b") == 3, row  # one blow-up marker per engine column
    assert any(ln.startswith("b: blow-up") for ln in cells)


def test_pybullet_multibody_on_high_spin_names_the_pi_4_cap():
    """high_spin_dt_10ms turns 1.5 rad a step: beyond Bullet's pi/4 cap from the first step; the
    finding names the cap, not the map the capped run happens to reproduce."""
    from freebody.adapters.base import is_available
    from freebody.api import run_case

    if not is_available("pybullet"):
        pytest.skip("pybullet not installed")
    r = run_case("high_spin_dt_10ms", engine="pybullet", integrator="multibody", duration=0.2).result.to_json()
    g = r["state_growth"]
    assert g["step_rotation_cap_rad"] == pytest.approx(np.pi / 4)
    assert g["rotation_per_step_max_rad"] == pytest.approx(1.5) and g["rotation_cap_t_s"] == 0.0
    found = fd.find([r])
    cap = [f for f in found if f.kind == "rotation-cap"]
    assert len(cap) == 1 and "the pi/4 rotation cap per step" in cap[0].text
    # an outlier of the same run says the cause is the cap (and not the reproduced map's summary)
    peer = with_judgement({**copy.deepcopy(r), "engine": "other", "metrics": {"orientation_error_max_rad": 1e-6},
                           "state_growth": None})
    out = [f for f in fd.find([r, peer]) if f.label == "pybullet/multibody"]
    assert [f.kind for f in out] == ["outlier"] and "cause: the pi/4 rotation cap per step" in out[0].text
    # a run of an engine that declares no cap gets no cap finding, whatever its |w| dt
    other = with_judgement({**copy.deepcopy(r), "state_growth": {**g, "step_rotation_cap_rad": None,
                                                                 "rotation_cap_t_s": None}})
    assert not [f for f in fd.find([other]) if f.kind == "rotation-cap"]


def test_growth_is_the_same_judged_whole_or_in_chunks():
    from freebody.reference_impl.integrators import simulate
    from freebody.reference_impl.truth import truth_trajectory
    from freebody.run.metrics import GrowthStats, truth_scales

    pb = thin_disk(3.0)
    tr = simulate(pb, "semi-implicit-explicit-gyro", 0.01, 300)
    scales = truth_scales(pb, truth_trajectory(pb, 0.01, 300))
    whole, chunked = GrowthStats(0.01, np.pi / 4), GrowthStats(0.01, np.pi / 4)
    whole.update(pb, tr, 0, scales)
    for k0 in range(0, 301, 70):
        chunked.update(pb, tr.take(np.arange(k0, min(k0 + 70, 301))), k0, scales)
    assert whole.result(scales) == chunked.result(scales)
    assert whole.result(scales)["blow_up_t_s"] is not None


def test_a_saturated_run_is_said_lost_not_closest():
    lost = run("e", "x", reproduces=None, error=3.1, matches_reference=match(None, closest="rk4", distance=3.1))
    near = run("f", "y", reproduces=None, matches_reference=match(None, closest="rk4", distance=1e-6))
    by = {f.label: f for f in fd.find([lost, near]) if f.kind == "no-map"}
    assert "closest" not in by["e/x"].text and "orientation is lost" in by["e/x"].text
    assert "closest rk4" in by["f/y"].text
    from freebody.report.summary import summary_table

    table = summary_table([lost, near])
    assert "orientation lost" in table and "none (closest rk4)" in table


def test_results_without_state_growth_raise_no_growth_finding():
    r = run("e", "x")
    assert "state_growth" not in r
    assert not [f for f in fd.find([r]) if f.kind in ("blow-up", "rotation-cap")]


# --- expected orders (issue 26, item 9) ------------------------------------------------------------

def _fit(engine: str, integrator: str, case: str, order: float) -> dict:
    from freebody.run.metrics import ORIENTATION_ERROR_MAX

    return {"case": case, "engine": engine, "integrator": integrator, "precision": "float64",
            "metric": ORIENTATION_ERROR_MAX, "order": order, "dts": [0.005, 0.01, 0.02],
            "fitted_dts": [0.005, 0.01, 0.02], "fit_rms_decades": 0.01, "saturated": False}


def test_expected_order_comes_from_engine_maps_and_is_limited_by_per_step_sampling():
    rs = [run("mujoco", "RK4", case="c", dt=d, reproduces="rkmk4-body") for d in (0.02, 0.01, 0.005)]
    assert fd.expected_order(rs).text == "4 (rkmk4-body)"
    per_step = [{**r, "load_sampling": "per-step"} for r in rs]
    exp = fd.expected_order(per_step, state_dependent=True)
    assert exp.order == 1 and exp.scheme_order == 4 and "limited by per-step load sampling" in exp.text
    assert fd.expected_order(per_step, state_dependent=False).order == 4  # world couples: the same experiment
    cases = {"c": {"state_dependent_loads": True}}
    # observed 1.01 against 4: a finding; against the limited 1: none
    found = fd.find(rs, convergence=[_fit("mujoco", "RK4", "c", 1.01)], cases=cases)
    assert [f.kind for f in found] == ["order"] and "expected 4 (rkmk4-body)" in found[0].text
    assert not fd.find(per_step, convergence=[_fit("mujoco", "RK4", "c", 1.01)], cases=cases)
    assert not fd.find(rs, convergence=[_fit("mujoco", "RK4", "c", 4.02)], cases=cases)
    columns, rows = rd.observed_orders([_fit("mujoco", "RK4", "c", 1.01)], per_step, cases)
    assert "limited by per-step load sampling" in rows[0][columns.index(rd.ORDER_EXPECTED_COLUMN)]


def test_every_engine_run_of_a_convergence_case_has_its_expected_order():
    """Real runs at three dts: each engine run's expected order is shown (engine maps included)."""
    from freebody.adapters.base import is_available
    from freebody.api import run_case
    from freebody.run.convergence import fit_orders

    if not is_available("mujoco"):
        pytest.skip("mujoco not installed")
    runs = [o.result.to_json() for i in ("RK4", "Euler")
            for o in run_case("convergence_tumbling", engine="mujoco", integrator=i, duration=0.5)]
    assert len({r["dt"] for r in runs}) >= 3
    columns, rows = rd.observed_orders(fit_orders(runs), runs)
    expected = {row[0]: row[columns.index(rd.ORDER_EXPECTED_COLUMN)] for row in rows}
    assert expected["mujoco/RK4"].startswith("4 (") and expected["mujoco/Euler"].startswith("1 (")
