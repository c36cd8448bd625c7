"""Migrations on load (issue 27, item 4): every results document read is brought to the newest
shape, one ``_update_to_N`` per schema step (freebody.results.document), so readers index the keys
it guarantees.  The golden baselines in tests/golden/migrations were written by the freebody of
each schema (see its README): each loads, migrates (a few keys checked exactly), renders a report
and compares with the schema-4 one with the verdict the freebody of 81f150a (before the migrations)
gave, stored beside them."""
from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.results import document
from freebody.results.document import (READABLE_SCHEMA_VERSIONS, REQUIRED_RUN_KEYS, RUN_DEFAULTS, SCHEMA_VERSION,
                                       load_results, migrate)
from freebody.results.identification import VERDICTS
from freebody.run.records import RunResult

GOLDEN = Path(__file__).parent / "golden" / "migrations"
OLD_SCHEMAS = (1, 2, 3, 4)


def golden(v: int) -> Path:
    return GOLDEN / f"baseline_schema{v}.json"


def raw(v: int) -> dict:
    return json.loads(golden(v).read_text())


def find(doc: dict, case: str, engine: str, integrator: str, dt: float = 0.01) -> dict:
    (run,) = [r for r in doc["runs"] if (r["case"], r["engine"], r["integrator"], r["dt"]) == (case, engine, integrator, dt)]
    return run


def test_the_golden_files_are_of_the_schema_they_stand_for():
    for v in OLD_SCHEMAS:
        assert raw(v)["schema_version"] == v


def test_one_step_per_schema_version_and_every_version_readable():
    assert sorted(document._MIGRATIONS) == list(range(2, SCHEMA_VERSION + 1))
    assert READABLE_SCHEMA_VERSIONS == tuple(range(1, SCHEMA_VERSION + 1))


def test_every_run_key_has_its_default():
    """The keys the migration guarantees on every run are RunResult's (a new field needs a default
    here, or old documents' runs would lack it)."""
    fields = {f.name for f in dataclasses.fields(RunResult)}
    assert set(RUN_DEFAULTS) | set(REQUIRED_RUN_KEYS) == fields
    assert not set(RUN_DEFAULTS) & set(REQUIRED_RUN_KEYS)


@pytest.mark.parametrize("v", OLD_SCHEMAS)
def test_each_schema_migrates_to_the_newest_shape(v):
    before = raw(v)
    frozen = json.dumps(before, sort_keys=True)
    doc = load_results(golden(v))
    assert json.dumps(before, sort_keys=True) == frozen  # migrate works on copies
    assert doc["schema_version"] == v  # what was written
    assert len(doc["runs"]) == len(before["runs"]) == 20
    for r in doc["runs"]:
        assert set(RUN_DEFAULTS) <= set(r)
        m = r["matches_reference"]
        if r["engine"] == "reference":
            assert m is None
            continue
        assert m["verdict"] in VERDICTS and isinstance(m["indistinguishable"], list)
        assert isinstance(m["undecidable"], list) and isinstance(m["ratios"], dict) and isinstance(m["levels_rad"], dict)
    for c in doc["cases"].values():
        assert {"defaults", "ran", "state_dependent_loads"} <= set(c)
    again = migrate(doc)
    assert {k: again[k] for k in ("runs", "cases")} == {k: doc[k] for k in ("runs", "cases")}  # idempotent


def test_schema_1_unknowns_are_explicit():
    doc = load_results(golden(1))
    euler = find(doc, "dzhanibekov", "mujoco", "Euler")
    assert euler["experiment"] is None and euler["load_sampling"] is None and euler["state_growth"] is None
    m = euler["matches_reference"]
    assert m["verdict"] == "reproduces" and m["integrator"] == "semi-implicit-explicit-gyro"
    assert m["indistinguishable"] == ["semi-implicit-explicit-gyro"]  # a named map is its own tie
    assert m["undecidable"] == [] and m["levels_rad"] == {} and m["ratios"] == {}
    assert "rule" not in m  # optional: schema 1 recorded none
    assert find(doc, "dzhanibekov", "mujoco", "RK4")["matches_reference"]["verdict"] == "reproduces"
    # the reference map's old name, brought up to date on load
    assert "symplectic-euler" in {r["integrator"] for r in raw(1)["runs"]}
    assert find(doc, "dzhanibekov", "reference", "lie-euler")["status"] == "ok"
    case = doc["cases"]["dzhanibekov"]
    assert case["ran"] is None and case["defaults"] is None and case["state_dependent_loads"] is None


def test_schema_2_and_3_keep_what_they_wrote():
    two, three = load_results(golden(2)), load_results(golden(3))
    for doc in (two, three):
        r = find(doc, "offset_push", "mujoco", "Euler")
        assert isinstance(r["experiment"], dict) and r["load_sampling"] is None
        assert r["matches_reference"]["verdict"] in ("reproduces", "indistinguishable")
        assert r["matches_reference"]["undecidable"] == []
        assert isinstance(doc["cases"]["offset_push"]["ran"], list)
        assert doc["cases"]["offset_push"]["state_dependent_loads"] is None
    assert two["cases"]["dzhanibekov"]["defaults"] is None  # written before schema 3: unknown
    assert three["cases"]["dzhanibekov"]["defaults"] == raw(3)["cases"]["dzhanibekov"]["defaults"]
    assert isinstance(three["cases"]["dzhanibekov"]["defaults"], list)


def test_schema_4_runs_are_read_as_written():
    """A schema-4 document needs no step before 5: its runs' keys come back unchanged (but for
    the metric schema 6 added, unknown: null)."""
    written = raw(4)
    doc = load_results(golden(4))
    for a, b in zip(written["runs"], doc["runs"]):
        new = {"quaternion_norm_error_max": None} if a["metrics"] else {}
        assert {k: b[k] for k in a} == {**a, "metrics": {**a["metrics"], **new}}
    assert doc["cases"] == written["cases"]
    assert find(doc, "offset_push", "mujoco", "Euler")["load_sampling"] in ("per-stage", "per-step")


def test_a_hand_made_document_gets_every_key():
    """A document with only the required keys of its runs (hand-made, trimmed) reads as one
    freebody wrote: absent keys are their defaults, a null precision is float64, an unknown
    verdict word is the one its other keys imply."""
    run = {"case": "c", "engine": "e", "integrator": "i", "dt": 0.01, "status": "ok", "precision": None,
           "metrics": None, "matches_reference": {"verdict": "maybe", "integrator": None, "closest": "rk4",
                                                  "ratios": None}}
    doc = load_results({"schema_version": SCHEMA_VERSION, "runs": [run]})
    (r,) = doc["runs"]
    assert r["precision"] == "float64" and r["metrics"] == {} and r["engine_settings"] == {}
    assert r["experiment"] is None and r["engine_output"] == [] and r["message"] == ""
    assert r["matches_reference"]["verdict"] == "closest" and r["matches_reference"]["ratios"] == {}
    assert doc["engines"] == {} and doc["incomplete"] is False
    assert run["precision"] is None and run["matches_reference"]["verdict"] == "maybe"  # not modified


@pytest.mark.parametrize("v", OLD_SCHEMAS)
def test_each_schema_compares_with_the_verdict_it_had(v, capsys):
    """``freebody compare`` of each golden baseline against the schema-4 one prints what the
    freebody before the migrations printed (tests/golden/migrations/compare_schemaN_vs_4.txt):
    schema 1 is matched on steps (content not checked) and its RK4 runs changed scheme (rk4 ->
    rkmk4-body, a map added after schema 1); schemas 2 and 3 compare equal."""
    expected = (GOLDEN / f"compare_schema{v}_vs_4.txt").read_text()
    code = main(["compare", str(golden(v)), str(golden(4))])
    out = capsys.readouterr().out
    out = out.replace(str(golden(v)), "{baseline}").replace(str(golden(4)), "{current}")
    assert out == expected
    assert code == (1 if "REGRESSION" in expected else 0)


@pytest.mark.parametrize("v", OLD_SCHEMAS)
def test_each_schema_renders_a_report(v, tmp_path):
    from freebody.report.render import write_reports

    out = tmp_path / f"schema{v}"
    out.mkdir()
    (out / "results.json").write_text(golden(v).read_text())
    assert main(["report", str(out)]) == 0
    md = (out / "report.md").read_text()
    assert "mujoco/Euler" in md and "semi-implicit-explicit-gyro" in md and "reference/lie-euler" in md
    assert ("| rk4 " in md) == (v == 1)  # what MuJoCo's RK4 reproduced: rk4 then, rkmk4-body since
    # a document in memory (not read from a file) is migrated by the report too
    (md_path,) = write_reports(tmp_path / "mem", copy.deepcopy(raw(v)), html=False)
    assert md_path.read_text() == md.replace(str(out), str(tmp_path / "mem"))


def test_schema_6_has_no_conventions_and_its_report_asks_the_adapters():
    """Schema 7 added ``conventions`` (what the run's adapters state): a schema-6 document has none
    and its report's conventions are the adapters' (imported), the same rows a schema-7 document
    records."""
    from freebody.report import data as rd
    from freebody.run.suite import engine_conventions

    before = raw(6)
    assert before["schema_version"] == 6 and "conventions" not in before
    doc = load_results(golden(6))
    assert "conventions" not in doc and len(doc["runs"]) == 20
    asked = rd.engine_conventions(doc)
    recorded = rd.engine_conventions({**doc, "conventions": engine_conventions(list(doc["engines"]))})
    assert asked == recorded and {e for e, _, _ in asked} == {"mujoco", "reference"}
    assert ("mujoco", "load sampling") in {(e, k) for e, k, _ in asked}
