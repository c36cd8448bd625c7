"""The bench document: every part's figures measured in one run (:func:`run_bench`), its schema
(:data:`SCHEMA_VERSION`), reading a saved one of any readable schema (:func:`load_bench`,
migrating once on load) and its text (:func:`format_text`)."""
from __future__ import annotations

import os
import platform
from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np

from ...results.document import document_header
from ...errors import InputError
from ...results.io import read_json
from . import maps, overhead, rss, suite, sweep, truth
from .checks import checks
from .config import CASE, DT, BenchConfig
from .core import log

# 2: the checks of issue 15 (a-e).  3: part 2 (batched reference integrators) removed.
# 4: issue 29: the checks of its targets (keys "run", "suite", "compile", "truth", "maps", "sweep",
#    "report", "output", "rss", "engine"); the default suite instead of the pinned one; CPU times;
#    maps against mujoco.rollout and their floors; no long run (b) and no pinned suite (c, d).
SCHEMA_VERSION = 4
READABLE_SCHEMAS = (3, 4)

PART_FUNCTIONS: dict[str, Callable[[BenchConfig, bool], dict]] = {
    "overhead": overhead.overhead, "compile": overhead.cold_compile, "maps": maps.reference_maps,
    "truth": truth.truth, "sweep": sweep.sweep, "suite": suite.suite, "rss": rss.peak_rss,
    "engines": maps.engines,
}


def _guarded(part: str, fn: Callable[[], dict], progress: bool) -> dict:
    """One part's figures, or {part_note: why} when it fails (the others still run)."""
    try:
        return fn()
    except Exception as e:
        log(f"{part}: failed: {type(e).__name__}: {e}", progress)
        return {f"{part}_note": f"failed: {type(e).__name__}: {e}"}


def _header(config: BenchConfig) -> dict:
    from ...adapters.base import engine_names, is_available, load_adapter

    versions: dict[str, str | None] = {}
    for engine in engine_names():
        try:
            versions[engine] = load_adapter(engine).engine_version() if is_available(engine) else None
        except Exception:  # a broken engine: its part says why
            versions[engine] = None
    return document_header(
        SCHEMA_VERSION, versions,
        platform=platform.platform(),  # the detailed OS string: timings depend on it
        python=platform.python_version(), numpy=np.__version__, cores=os.cpu_count(),
        load_average=list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        quick=config.quick, cold=config.cold, repeats=config.repeats, parts=list(config.parts),
        case=CASE, dt=DT)


def run_bench(config: BenchConfig, progress: bool = False) -> dict:
    """Every part of ``config.parts`` measured, in :data:`~.config.PARTS` order, as one JSON-ready
    document (schema :data:`SCHEMA_VERSION`) with its checks under ``"checks"``; a part not
    measured has ``<part>_note`` saying so."""
    doc = _header(config)
    for part, fn in PART_FUNCTIONS.items():
        if part in config.parts:
            log(f"part {part}", progress)
            doc.update(_guarded(part, lambda: fn(config, progress), progress))
        else:
            doc[f"{part}_note"] = ("not measured (--quick: give --cold to measure it)"
                                   if part == "compile" and config.quick else "not measured (not among the parts run)")
    doc["load_average_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    doc["checks"] = [asdict(c) | {"status": c.status} for c in checks(doc)]
    return doc


# --- reading a saved document -------------------------------------------------------------------

_RENAMED_IN_4 = {"reference_map_steps": "maps_steps", "reference_map_step_s": "maps_step_s",
                 "reference_map_call_s": "maps_call_s", "reference_map_first_call_s": "maps_first_call_s",
                 "reference_map_mujoco_step_s": "maps_mj_step_s",
                 "short_run_rss_bytes": "rss_short_bytes", "short_run_steps": "rss_short_steps"}


def update_to_4(doc: dict) -> dict:
    """Schema 3 -> 4: the figures that kept their meaning under their new names; the stored checks
    (a-e, 1: issue 15's targets) kept as they were judged; ``migrated_from`` 3."""
    out = {_RENAMED_IN_4.get(k, k): v for k, v in doc.items()}
    out.update(schema_version=4, migrated_from=3)
    return out


def load_bench(path: str | Path) -> dict:
    """A saved bench document (``bench --out``) of a readable schema, migrated to the current one
    (one step per version, as ``results.document`` migrates results).  InputError naming the
    schema for any other, or when the file cannot be read or parsed."""
    doc = read_json(Path(path), str(path))
    version = doc.get("schema_version") if isinstance(doc, dict) else None
    if version not in READABLE_SCHEMAS:
        raise InputError(f"{path}: bench schema {version!r} is not readable (readable: "
                         f"{', '.join(map(str, READABLE_SCHEMAS))}); run freebody bench again")
    for v in range(version + 1, SCHEMA_VERSION + 1):
        doc = globals()[f"update_to_{v}"](doc)
    return doc
