"""The harness against the adapter contract, with a fake engine that declares batching
(``tests/fake_engines/batching_adapter.py``, registered as ``batcher``): ``freebody sweep`` steps
the bodies of such an engine as one batch per (integrator, precision, dt, steps), through the
adapter class's ``simulate_batch``, and the results are those of each body run alone.  The fake
engine itself passes the shipped conformance suite (a subclass of
:class:`freebody.testing.AdapterConformance`: every check, a new one included)."""
from __future__ import annotations

from pathlib import Path

import pytest

from fake_engines.batching_adapter import INTEGRATOR, REGISTRY_ENTRY, BatchingAdapter
from freebody.adapters import base
from freebody.testing import AdapterConformance
from freebody.testing.conformance import assert_identical
from freebody.run import execute, expand
from freebody.tools.sweep import SweepSettings, _batched_outputs, random_bodies, run_bodies, sweep

BODIES = SweepSettings(seed=5, count=4, duration=0.2, dts=(0.01,))
# Keys of a run that measure time, not physics: the only ones a batched run may change.
TIMING_KEYS = ("wall_time_s", "compile_time_s")
# Keys run_bodies() leaves out of its runs.
DROPPED_KEYS = ("engine_settings", "trajectory")


@pytest.fixture
def batcher(monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    monkeypatch.setitem(base.ENGINES, "batcher", REGISTRY_ENTRY)
    BatchingAdapter.batch_calls.clear()
    yield "batcher"
    BatchingAdapter.batch_calls.clear()


def test_the_fake_engine_is_registered_and_declares_batching(batcher):
    assert batcher in base.engine_names() and base.is_available(batcher)
    assert base.load_adapter(batcher) is BatchingAdapter
    assert BatchingAdapter.supports_batch


def test_sweep_batches_a_batching_engine_once_per_group(batcher):
    bodies = random_bodies(BODIES)
    specs = expand([b.problem for b in bodies], [batcher], None, None, None)
    assert len(specs) == len(bodies) and len({s.steps for s in specs}) == 1
    outputs = _batched_outputs(specs, progress=False)
    assert [c["bodies"] for c in BatchingAdapter.batch_calls] == [len(bodies)], \
        BatchingAdapter.batch_calls
    call = BatchingAdapter.batch_calls[0]
    assert (call["dt"], call["steps"], call["integrator"], call["precision"]) == \
        (specs[0].dt, specs[0].steps, INTEGRATOR, "float64")
    assert set(outputs) == {id(s) for s in specs}, "some runs were not batched"
    for spec in specs:
        sim, compare_with = outputs[id(spec)]
        alone = BatchingAdapter(spec.problem, spec.dt, spec.integrator, spec.precision)
        assert_identical(sim.trajectory, alone.simulate(spec.steps),
                                     f"{spec.problem.name}: batched vs alone")
        assert sim.diverged_at is None and compare_with is None
        assert sim.settings == alone.settings


def test_run_bodies_results_equal_each_body_run_alone(batcher):
    bodies = random_bodies(BODIES)
    runs = run_bodies(bodies, [batcher], progress=False)
    assert len(BatchingAdapter.batch_calls) == 1
    BatchingAdapter.batch_calls.clear()
    specs = expand([b.problem for b in bodies], [batcher], None, None, None)
    assert len(runs) == len(specs)
    def physics(run: dict) -> dict:
        return {k: v for k, v in run.items() if k not in TIMING_KEYS + DROPPED_KEYS}

    for spec, got in zip(specs, runs):
        assert got["status"] == "ok", got["message"]
        assert physics(got) == physics(execute(spec).result.to_json())
    assert BatchingAdapter.batch_calls == []  # execute() runs one body at a time


def test_a_sweep_with_batching_and_non_batching_engines(batcher, tmp_path):
    """Only the batching engine's runs are batched; the other engine's run one by one."""
    outcome = sweep(BODIES, ["reference", batcher], integrators=["semi-implicit-explicit-gyro",
                                                                f"{batcher}:{INTEGRATOR}"],
                    out_dir=tmp_path, progress=False)
    assert len(BatchingAdapter.batch_calls) == 1
    runs = outcome.document["runs"]
    assert {r["engine"] for r in runs} == {"reference", batcher}
    assert all(r["status"] == "ok" for r in runs), [r["message"] for r in runs]


class TestTheFakeEngineConformance(AdapterConformance):
    """The shipped conformance suite on the fake engine, whose adapter class is given directly
    (its module is importable from tests/ only) and registered while each check runs."""

    engine = "batcher"

    @classmethod
    def adapter_class(cls):
        return BatchingAdapter

    @pytest.fixture(autouse=True)
    def _registered(self, batcher):
        """The checks that go through the harness (``execute``, ``registry()``) look it up."""


# --- the harness knows engines only through the contract ---------------------------------------

def _harness_modules():
    import pathlib

    import freebody

    root = pathlib.Path(freebody.__file__).parent
    return sorted(p for p in root.rglob("*.py"))


def test_no_harness_module_imports_an_engine_or_dispatches_on_its_name():
    """freebody/ (the harness) imports no engine package and never compares a value with an
    engine's name: what differs between engines is declared by their adapters (capabilities) or
    their registry entries.  Fails on ``if engine == "mjx"``, ``spec.engine in ("mujoco",)``,
    ``import pybullet``."""
    import ast

    from freebody.adapters.base import ENGINES, REFERENCE_ENGINE

    names = set(ENGINES) | {REFERENCE_ENGINE}
    packages = {entry.import_name for name, entry in ENGINES.items() if name != REFERENCE_ENGINE}
    packages |= {"mujoco", "pybullet", "dartpy", "jax"}
    found = []
    for path in _harness_modules():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
                for m in mods:
                    if m.split(".")[0] in packages and not (isinstance(node, ast.ImportFrom) and node.level):
                        found.append(f"{path.name}:{node.lineno} imports {m}")
            if isinstance(node, ast.Compare):
                for sub in ast.walk(node):
                    if isinstance(sub, ast.Constant) and sub.value in names:
                        found.append(f"{path.name}:{node.lineno} compares with {sub.value!r}")
    assert not found, "engine-specific code in the harness:\n" + "\n".join(found)


def _adapter_member_names() -> set[str]:
    """Every public name the contract declares (``Adapter``, ``SteppedAdapter``, ``EngineEntry``)
    and every public class-level name a built-in adapter class defines (read from its source)."""
    import ast
    import importlib.util
    import pathlib

    from freebody.adapters.base import ENGINES, Adapter, EngineEntry, SteppedAdapter

    names = {n for c in (Adapter, SteppedAdapter) for n in (*vars(c), *vars(c).get("__annotations__", {}))}
    names |= set(EngineEntry._fields) | {"distribution"}
    for entry in ENGINES.values():
        tree = ast.parse(pathlib.Path(importlib.util.find_spec(entry.module).origin).read_text())
        for cls in (n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == entry.cls):
            for node in cls.body:
                if isinstance(node, (ast.FunctionDef, ast.AnnAssign, ast.Assign)):
                    targets = (node.targets if isinstance(node, ast.Assign) else
                               [node.target] if isinstance(node, ast.AnnAssign) else [node])
                    names |= {getattr(t, "id", getattr(t, "name", "")) for t in targets}
    return {n for n in names if n and not n.startswith("_")}


def test_the_harness_reads_adapters_only_through_the_declared_contract():
    """No ``getattr(cls, "member", default)`` or ``hasattr(cls, "member")`` on an adapter class,
    an adapter or a registry entry in the harness (freebody/ and the registry in
    adapters/base.py): every member it reads is declared on ``Adapter`` or ``EngineEntry`` with
    its default (docs/adapters.md "Members"), so it reads ``cls.member``.  Fails on
    ``getattr(load_adapter(e), "integrator_aliases", None)``."""
    import ast
    import pathlib

    import freebody.adapters
    from freebody.adapters import base

    members = _adapter_member_names()
    adapters_dir = pathlib.Path(freebody.adapters.__file__).parent
    paths = [p for p in _harness_modules() if adapters_dir not in p.parents] + [pathlib.Path(base.__file__)]
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                    and isinstance(node.args[1], ast.Constant) and node.args[1].value in members):
                found.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    assert not found, "the harness reads adapter members around the contract:\n" + "\n".join(found)
