"""The registry: a missing engine is a visible skip with an install hint, a broken one a failure,
never a pass; unknown engines are bad input; third-party adapters come through entry points."""
from __future__ import annotations

import pytest

from freebody.adapters import base
from freebody.input.casefile import load_case
from freebody.run import RunSpec, execute, expand


@pytest.fixture
def fake_registry(monkeypatch):
    reg = dict(base.ENGINES)
    reg["absent"] = base.EngineEntry("freebody_test_engine_that_is_not_installed",
                                     "fake_engines.missing_engine_adapter", "X",
                                     "pip install freebody-absent-engine")
    reg["broken"] = base.EngineEntry("numpy", "fake_engines.broken_engine_adapter", "X")
    monkeypatch.setattr(base, "ENGINES", reg)
    monkeypatch.syspath_prepend(str(__import__("pathlib").Path(__file__).parent))
    return reg


def test_missing_engine_is_skipped_with_install_hint(fake_registry):
    pb = load_case("quiz")
    specs = expand([pb], ["absent"], None, [0.1], None)
    assert [s.integrator for s in specs] == ["*"]
    r = execute(specs[0]).result
    assert r.status == "skipped"
    assert "pip install freebody-absent-engine" in r.message and "absent" in r.message


def test_broken_engine_is_failed_not_skipped(fake_registry):
    pb = load_case("quiz")
    r = execute(RunSpec(pb, "broken", "*", 0.1, 2)).result
    assert r.status == "failed"
    assert "this_symbol_does_not_exist" in r.message


def test_unknown_engine_name_is_bad_input():
    from freebody.errors import InputError
    from freebody.run import select_engines

    with pytest.raises(InputError, match="unknown engine 'nope'"):
        select_engines(["nope"])
    assert select_engines(["MuJoCo"]) == ["mujoco"]


def test_entry_point_adapters_join_the_registry(monkeypatch):
    class EP:
        name = "thirdparty"
        value = "thirdparty_pkg.adapter:ThirdPartyAdapter"

    monkeypatch.setattr(base.importlib.metadata, "entry_points", lambda group: [EP()] if group == base.ENTRY_POINT_GROUP else [])
    reg = base.registry()
    assert reg["thirdparty"][:3] == ("thirdparty_pkg", "thirdparty_pkg.adapter", "ThirdPartyAdapter")
    assert list(reg)[: len(base.ENGINES)] == list(base.ENGINES)
