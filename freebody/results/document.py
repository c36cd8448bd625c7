"""results.json (schema version 1) and the per-run trajectory files, written atomically.

results.json::

    {"schema_version": 1, "freebody_version", "created", "platform", "engines": {name: version},
     "incomplete": false, "runs": [RunResult.to_json(), ...], ...}

Written with sorted keys; non-finite numbers become null (the run's status says why).  Readers
ignore keys they do not know.  A trajectory file (npz) holds the run's arrays and its truth's:
``t (N,)``, ``position (N, 3)``, ``quaternion_wxyz (N, 4)``, ``linear_velocity (N, 3)``,
``angular_velocity (N, 3)`` [, ``orthonormality_error (N,)``], and the same with a ``truth_`` prefix.
"""
from __future__ import annotations

import math
import platform
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError
from ..reference_impl.conventions import Trajectory
from .io import read_json, write_npz_atomic

SCHEMA_VERSION = 1
_FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


def document_header(schema_version: int, engines: dict[str, str | None] | None = None, **fields) -> dict:
    """The fields every freebody JSON document (results, sweep, bench, inertia) opens with:
    ``schema_version`` (that of the document's kind), ``freebody_version``, ``created`` (UTC, to the
    second), ``platform`` (OS, machine, Python) and, if given, ``engines`` {name: version or None};
    then ``fields`` in their order (a field may replace one of these, e.g. bench's detailed platform)."""
    doc = {
        "schema_version": schema_version,
        "freebody_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "platform": f"{platform.system()} {platform.machine()} Python {platform.python_version()}",
    }
    if engines is not None:
        doc["engines"] = engines
    doc.update(fields)
    return doc


def results_document(runs: list[dict], engines: dict[str, str | None], incomplete: bool = False,
                     extra: dict | None = None) -> dict:
    doc = document_header(SCHEMA_VERSION, engines, incomplete=incomplete, runs=runs)
    doc.update(extra or {})
    return doc


def trajectory_filename(run: dict) -> str:
    name = f"{run['case']}__{run['engine']}__{run['integrator']}__{run.get('precision', 'float64')}__dt{run['dt']:g}"
    return "trajectories/" + "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in name) + ".npz"


def thinned_for_saving(tr: Trajectory, truth: Trajectory | None,
                       every: int = 1) -> tuple[Trajectory, Trajectory | None]:
    """(run, truth) as a trajectory file stores them: the truth cut to the run's samples (a
    diverged run stops early) without orthonormality, both thinned to every ``every``-th sample."""
    if truth is not None:
        truth = truth.head(len(tr)).without_orthonormality()
    if every > 1:
        tr = tr.thinned(every)
        truth = truth.thinned(every) if truth is not None else None
    return tr, truth


def save_trajectory(out_dir: Path, relname: str, tr: Trajectory, truth: Trajectory | None,
                    every: int = 1) -> None:
    """Save a run's arrays (thinned to every ``every``-th sample) and its truth's, atomically."""
    path = Path(out_dir) / relname
    path.parent.mkdir(parents=True, exist_ok=True)
    tr_s, truth_s = thinned_for_saving(tr, truth, every)
    arrays = {f: getattr(tr_s, f) for f in _FIELDS}
    if tr_s.orthonormality_error is not None:
        arrays["orthonormality_error"] = tr_s.orthonormality_error
    if truth_s is not None:
        arrays.update({"truth_" + f: getattr(truth_s, f) for f in _FIELDS})
    write_npz_atomic(path, arrays)


def load_trajectory(path: Path) -> tuple[Trajectory, Trajectory | None]:
    """(run trajectory, truth trajectory or None) from a trajectory file."""
    with np.load(path) as z:
        tr = Trajectory(*(z[f] for f in _FIELDS),
                        orthonormality_error=z["orthonormality_error"] if "orthonormality_error" in z else None)
        truth = Trajectory(*(z["truth_" + f] for f in _FIELDS)) if "truth_t" in z else None
    return tr, truth


REQUIRED_RUN_KEYS = ("case", "engine", "integrator", "dt", "status")
MIGRATE = ("to migrate, re-run the suite with this freebody (freebody run ... --out DIR) and store a new "
           "baseline (freebody baseline DIR --to FILE --force), or compare with the freebody release that "
           "wrote it")


def load_results(source, role: str = "") -> dict:
    """A results document from a run directory, a results.json or baseline file, or a dict.

    role : e.g. "baseline" or "current", named in error messages.  InputError on anything unusable
    (missing file, bad JSON, another schema version: the message says how to migrate, malformed runs).
    """
    prefix = f"{role} " if role else ""
    if isinstance(source, dict):
        return check_results(source, f"{prefix}(in memory)")
    p = Path(source)
    if p.is_dir():
        if not (p / "results.json").is_file():
            raise InputError(f"{prefix}{p}: no results.json in this directory (run freebody run --out {p})")
        p = p / "results.json"
    return check_results(read_json(p, f"{prefix}{p}"), f"{prefix}{p}")


def check_results(doc, where: str) -> dict:
    """Validate a loaded results document's schema version and runs; InputError naming ``where``."""
    if not isinstance(doc, dict) or "schema_version" not in doc:
        raise InputError(f"{where}: schema_version: missing; not a freebody results or baseline file")
    v = doc["schema_version"]
    if v != SCHEMA_VERSION:
        raise InputError(f"{where}: schema_version: is {v!r}, this freebody reads {SCHEMA_VERSION}; {MIGRATE}")
    runs = doc.get("runs")
    if not isinstance(runs, list):
        raise InputError(f"{where}: runs: missing or not a list")
    for i, r in enumerate(runs):
        if not isinstance(r, dict):
            raise InputError(f"{where}: runs[{i}]: not an object")
        for k in REQUIRED_RUN_KEYS:
            if k not in r:
                raise InputError(f"{where}: runs[{i}].{k}: missing")
        dt = r["dt"]
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
            raise InputError(f"{where}: runs[{i}].dt: not a positive number: {dt!r}")
    return doc
