"""The judgement stored with each run (results.json ``judgement``, schema 5): the facts that
report/findings.py derived after the fact until schema 4 (blow-up, rotation cap, the map a run
reproduces or comes closest to and its distance, level and ratio, saturation, the formal order and
the maps an expected order comes from) are computed once when a run is recorded, equal what the
old rules derived, and an old schema-4 document migrates to the same facts and the same findings."""
from __future__ import annotations

import copy
import json

import pytest

from freebody import tolerances as tol
from freebody.adapters.base import REFERENCE_ENGINE, is_available
from freebody.cli import main
from freebody.numbers import finite_or_none
from freebody.reference_impl.engine_maps import ENGINE_MAPS
from freebody.reference_impl.integrators import INTEGRATORS
from freebody.report import findings as fd
from freebody.results import identification
from freebody.results import judgement as jd
from freebody.results.document import SCHEMA_VERSION, load_results


# --- the rules report/findings.py applied to a run after the fact (as at commit 81f150a) -------------

def _old_order(name):
    entry = INTEGRATORS.get(name) or ENGINE_MAPS.get(name)
    return entry.order if entry is not None else None


def _old_match(run):
    m = run.get("matches_reference")
    return m if isinstance(m, dict) and run.get("engine") != REFERENCE_ENGINE else None


def _old_level(m, name):
    level = finite_or_none((m.get("levels_rad") or {}).get(name))
    if level is None and m.get("closest") == name:
        level = finite_or_none(m.get("threshold_rad"))
    return None if level is None else max(level, tol.SCHEME_ROUNDOFF_FLOOR_RAD)


def _old_distance(m, name):
    d = finite_or_none((m.get("candidates") or {}).get(name))
    if d is None and m.get("closest") == name:
        d = finite_or_none(m.get("max_orientation_diff_rad"))
    return d


def _old_ratio(m, name):
    r = finite_or_none((m.get("ratios") or {}).get(name))
    if r is None:
        d, level = _old_distance(m, name), _old_level(m, name)
        r = d / level if d is not None and level else None
    return r


def old_facts(run: dict) -> dict:
    """What findings derived of one run (scheme_key, scheme_set, map_*, saturated, run_order, the
    per-run part of expected_order, blew_up, capped), in the shape of ``judgement``."""
    m = _old_match(run)
    ok = run.get("status") == "ok"
    schemes = list(identification.reproduced(m)) if m is not None else []
    key = None
    if m is not None and ok:
        if schemes:
            key = (schemes[0], True)
        elif isinstance(m.get("closest"), str):
            key = (m["closest"], False)
    saturated = key is not None and not key[1] and (
        _old_distance(m, key[0]) is None or _old_distance(m, key[0]) > tol.CONVERGENCE_ORIENTATION_SATURATED_RAD)
    if run.get("engine") == REFERENCE_ENGINE:
        order = _old_order(str(run.get("integrator")))
    else:
        orders = [o for o in map(_old_order, schemes or ((key[0],) if key else ())) if o is not None]
        order = min(orders) if orders else None
    g = run.get("state_growth") if isinstance(run.get("state_growth"), dict) else {}
    return {"scheme": key[0] if key else None, "reproduced": key[1] if key else None, "schemes": schemes,
            "scheme_distance_rad": _old_distance(m, key[0]) if key else None,
            "scheme_level_rad": _old_level(m, key[0]) if key else None,
            "scheme_ratio": _old_ratio(m, key[0]) if key else None, "saturated": saturated, "order": order,
            "order_maps": [] if key is None or saturated else [[n, _old_order(n)] for n in (schemes or [key[0]])],
            "blew_up": ok and finite_or_none(g.get("blow_up_t_s")) is not None,
            "capped": ok and finite_or_none(g.get("rotation_cap_t_s")) is not None
            and finite_or_none(g.get("step_rotation_cap_rad")) is not None,
            # schema 6 (tests/test_quaternion_norm.py): none of these runs' engines hands out a non-unit q
            "non_unit_quaternion": False}


# --- runs -------------------------------------------------------------------------------------------

ENGINES = [e for e in ("mujoco", "pybullet") if is_available(e)]


@pytest.fixture(scope="module")
def doc(tmp_path_factory):
    """A real results document: the high spin (PyBullet's rotation cap, orientations lost at 10 ms)
    and a convergence case (four dts: fitted orders), on the reference maps and the engines here."""
    out = tmp_path_factory.mktemp("judgement_run")
    args = ["run", "high_spin_dt_10ms", "convergence_body_torque", "--engine", "reference",
            *(a for e in ENGINES for a in ("--engine", e)), "--integrator", "rk4", "--integrator", "euler-quat",
            "--integrator", "Euler", "--integrator", "RK4", "--integrator", "multibody", "--integrator", "maximal",
            "--duration", "0.2", "--out", str(out), "--quiet", "--no-report"]
    assert main(args) == 0
    return json.loads((out / "results.json").read_text())


def hand_made() -> list[dict]:
    """Runs of every kind findings tells apart, as results.json stores them (without ``judgement``)."""
    def m(verdict, tie=(), closest=None, d=1e-14):
        names = ["semi-implicit-explicit-gyro", "rk4", "rkmk4-body"]
        return {"verdict": verdict, "integrator": tie[0] if tie else None, "closest": closest or (tie[0] if tie else None),
                "max_orientation_diff_rad": d, "threshold_rad": 1e-12, "indistinguishable": list(tie),
                "undecidable": [], "candidates": {n: (d if n in tie or n == closest else 1.0) for n in names},
                "levels_rad": {n: 1e-12 for n in names}, "ratios": {}}

    def run(engine="e", integrator="x", status="ok", match=None, growth=None):
        return {"case": "c", "engine": engine, "integrator": integrator, "precision": "float64", "dt": 0.01,
                "steps": 10, "status": status, "message": "", "metrics": {}, "final_state": None,
                "matches_reference": match, "state_growth": growth}

    grown = {"blow_up_t_s": 2.5, "omega_max_rad_s": 800.0, "rotation_cap_t_s": 0.0, "step_rotation_cap_rad": 0.785}
    return [run(match=m("reproduces", ("semi-implicit-explicit-gyro",))),
            run(match=m("indistinguishable", ("rkmk4-body", "rk4"))),
            run(match=m("closest", closest="rk4", d=1e-3)),
            run(match=m("closest", closest="rk4", d=3.1)),  # saturated: the orientation is lost
            run(match=m("undecidable", closest="rk4", d=1e-3)),
            run(match=m("reproduces", ("semi-implicit-explicit-gyro",)), growth=grown),  # blow-up and cap
            run(match=m("reproduces", ("rk4",)), growth={**grown, "step_rotation_cap_rad": None}),  # no cap declared
            run(status="diverged", growth=grown),  # not ok: no blow-up nor cap finding
            run(status="failed"), run(status="skipped"),
            run(engine=REFERENCE_ENGINE, integrator="rk4", growth=grown),  # a reference map's blow-up
            run(engine=REFERENCE_ENGINE, integrator="no-such-map")]


# --- tests ------------------------------------------------------------------------------------------

def test_every_run_stores_the_facts_findings_derived_after_the_fact(doc):
    assert doc["schema_version"] == SCHEMA_VERSION == 7
    for r in doc["runs"]:
        assert r[jd.JUDGEMENT] == old_facts(r), (r["engine"], r["integrator"], r["case"], r["dt"])
    facts = [r[jd.JUDGEMENT] for r in doc["runs"]]
    assert any(f["reproduced"] for f in facts) and any(f["order"] == 4 for f in facts)
    if "pybullet" in ENGINES:  # the pi/4 cap per step at 1.5 rad a step
        assert any(f["capped"] for f in facts)


def test_hand_made_runs_of_every_kind_get_the_facts_of_the_old_rules():
    runs = hand_made()
    for r in runs:
        assert jd.run_judgement(r) == old_facts(r), r
    facts = [jd.run_judgement(r) for r in runs]
    assert [f["saturated"] for f in facts].count(True) == 1
    assert [f["blew_up"] for f in facts] == [False] * 5 + [True, True, False, False, False, True, False]
    assert [f["capped"] for f in facts] == [False] * 5 + [True] + [False] * 4 + [True, False]
    assert facts[1]["order_maps"] == [["rkmk4-body", 4], ["rk4", 4]] and facts[3]["order_maps"] == []


def test_a_schema_4_document_migrates_to_the_same_facts_and_the_same_findings(doc):
    old = copy.deepcopy(doc)
    old["schema_version"] = 4
    for r in old["runs"]:
        del r[jd.JUDGEMENT]
    migrated = load_results(old)
    assert [r[jd.JUDGEMENT] for r in migrated["runs"]] == [r[jd.JUDGEMENT] for r in doc["runs"]]

    def texts(d):
        return [(f.kind, f.label, f.case, f.dt, f.text) for f in fd.find(d["runs"], None, d.get("convergence"),
                                                                          d.get("cases"))]
    assert texts(migrated) == texts(doc)


def test_old_map_names_are_judged_by_their_current_names():
    """A schema-4 run that reproduced 'symplectic-euler' (now 'lie-euler'): its scheme and order
    are those of the current name, as findings saw them after the names were brought up to date."""
    run = hand_made()[0]
    run["matches_reference"] = {**run["matches_reference"], "integrator": "symplectic-euler",
                                "closest": "symplectic-euler", "indistinguishable": ["symplectic-euler"]}
    ref = {**hand_made()[-1], "integrator": "symplectic-euler"}
    doc = load_results({"schema_version": 4, "runs": [run, ref]})
    j, j_ref = (r[jd.JUDGEMENT] for r in doc["runs"])
    assert j["scheme"] == "lie-euler" and j["schemes"] == ["lie-euler"] and j["order"] == 1
    assert j_ref["order"] == 1 and doc["runs"][1]["integrator"] == "lie-euler"


def test_findings_present_the_stored_facts_and_judge_nothing_again(doc, monkeypatch):
    """fd.find never calls the judgement function: a stored fact is what the findings say (here a
    run made to claim a blow-up it did not have gets a blow-up finding), and a run without its
    judgement is an error, not judged on the fly."""
    expected = fd.find(doc["runs"], None, doc.get("convergence"), doc.get("cases"))

    def refuse(run):
        raise AssertionError("findings re-judged a run")
    monkeypatch.setattr(jd, "run_judgement", refuse)
    assert fd.find(doc["runs"], None, doc.get("convergence"), doc.get("cases")) == expected
    ok = next(r for r in doc["runs"] if r["status"] == "ok" and r["engine"] != REFERENCE_ENGINE)
    claimed = {**ok, "state_growth": {**ok["state_growth"], "blow_up_t_s": 0.1},
               jd.JUDGEMENT: {**ok[jd.JUDGEMENT], "blew_up": True}}
    assert [f.kind for f in fd.blow_up_findings([claimed])] == ["blow-up"]
    with pytest.raises(KeyError):
        fd.find([{k: v for k, v in ok.items() if k != jd.JUDGEMENT}])


def test_a_renamed_map_is_renamed_in_a_stored_judgement_too():
    """A schema-5 file judged under a map's old name reads with the current name in its judgement
    (the facts of the renamed map: its order, found under the current name)."""
    run = jd.with_judgement(hand_made()[0])
    old = {**run, "matches_reference": {**run["matches_reference"], "integrator": "symplectic-euler",
                                        "closest": "symplectic-euler", "indistinguishable": ["symplectic-euler"]}}
    old = {**old, jd.JUDGEMENT: {**run[jd.JUDGEMENT], "scheme": "symplectic-euler", "schemes": ["symplectic-euler"],
                                 "order": None, "order_maps": [["symplectic-euler", None]]}}
    j = load_results({"schema_version": SCHEMA_VERSION, "runs": [old]})["runs"][0][jd.JUDGEMENT]
    assert j["scheme"] == "lie-euler" and j["order"] == 1 and j["order_maps"] == [["lie-euler", 1]]
