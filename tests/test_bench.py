"""``freebody bench --quick --json``: a smoke run; the JSON figures exist and are positive numbers.

No timing assertions: the figures depend on the machine and its load.
"""
from __future__ import annotations

import contextlib
import io
import json
import math

import pytest

from freebody.adapters.base import engine_names
from freebody.tools.bench import BATCH_SIZES, ENGINE_EQUIVALENT_MAPS, SCHEMA_VERSION
from freebody.cli import main
from freebody.reference_impl.batched import BATCHED_INTEGRATORS


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """(stdout, the --out file's document) of one ``freebody bench --quick --json`` run."""
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["bench", "--quick", "--json", "--quiet", "--repeats", "1", "--out", str(out)])
    assert code == 0
    return buf.getvalue(), json.loads(out.read_text())


@pytest.fixture(scope="module")
def quick_doc(quick_run):
    return quick_run[1]


def test_quick_bench_reports_every_figure_as_a_positive_number(quick_doc):
    doc = quick_doc
    assert doc["schema_version"] == SCHEMA_VERSION
    assert set(doc["engines"]) == set(engine_names())
    for engine in engine_names():
        # an installed engine is measured; a missing one is listed as skipped, never silently absent
        assert (engine in doc["overhead_ratio"]) != (engine in doc["skipped"])
        if engine in doc["overhead_ratio"]:
            assert _positive(doc["overhead_ratio"][engine])
            assert doc["engines"][engine]
            for key in ("bare_step_s", "freebody_step_s"):
                assert _positive(doc["engine_step_s"][engine][key])
    assert set(doc["reference_body_step_s"]) == set(BATCHED_INTEGRATORS)
    for name, row in doc["reference_body_step_s"].items():
        assert set(row) == {str(B) for B in BATCH_SIZES}
        assert all(_positive(s) for s in row.values()), name
    if "mujoco" in doc["overhead_ratio"]:
        assert _positive(doc["mujoco_body_step_s"])
        for name in ENGINE_EQUIVALENT_MAPS:
            assert _positive(doc["reference_speedup_vs_mujoco"][name][str(1000)])
    assert _positive(doc["suite_serial_s"])
    assert doc["suite_parallel_s"] is None or _positive(doc["suite_parallel_s"])
    assert doc["suite_note"]


def test_bench_json_prints_one_object_and_the_text_summary_renders_it(quick_run):
    from freebody.tools.bench import format_text

    stdout, doc = quick_run
    assert json.loads(stdout) == doc
    text = format_text(doc)
    assert "engine loop overhead" in text and "batched reference" in text and "suite" in text


def test_bad_repeats_is_one_line_input_error(capsys):
    assert main(["bench", "--quick", "--repeats", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--repeats" in err
