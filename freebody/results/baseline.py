"""Regression baselines: a results document without its trajectory files, stored for ``freebody compare``.

A baseline is a results.json (same schema version, same keys) whose runs carry no ``trajectory``
path, with a ``"baseline"`` record saying where it came from.  It is made from the results as read
(:func:`freebody.results.document.load_results`: migrated to the newest shape, its
``schema_version`` the one its results were written with), so it is read back the same way.  It keeps the engine versions, the
metrics, the final states, the statuses, the fitted orders and the cases.
"""
from __future__ import annotations

from pathlib import Path

from collections import Counter

from ..errors import InputError, printable
from .io import check_output_file, write_json_atomic


def make_baseline(doc: dict, source: str) -> dict:
    """The baseline document of a results document (``source``: where it was read, for the record)."""
    out = {k: v for k, v in doc.items() if k != "runs"}
    out["runs"] = [{k: v for k, v in r.items() if k != "trajectory"} for r in doc["runs"]]
    out["baseline"] = {"source": str(source), "runs": len(out["runs"])}
    return out


def store_baseline(source: str | Path, to: str | Path, force: bool = False, allow_no_ok_runs: bool = False) -> dict:
    """Read the results of ``source`` (a run directory or a results.json), write its baseline to
    ``to`` atomically, and return it.  InputError when ``to`` exists (unless ``force``), when the
    results are unusable, when the run was interrupted (incomplete results make a bad baseline), or
    when no run is ok or diverged (every run failed or was skipped: such a baseline guards nothing;
    unless ``allow_no_ok_runs``)."""
    from .compare import load_side

    to = Path(to)
    if to.is_dir():
        raise InputError(f"--to {to}: is a directory; give a file name such as {to / 'baseline.json'}")
    check_output_file(to, f"--to {to}")  # the one rule of every file freebody writes (results/io)
    if to.exists() and not force:
        raise InputError(f"--to {to}: exists; pass --force to replace it")
    doc = load_side(source, "results")
    if doc["incomplete"]:
        raise InputError(f"results {source}: incomplete (the run was interrupted); re-run it before "
                         f"storing a baseline")
    runs = doc["runs"]
    measured = [r for r in runs if r["status"] in ("ok", "diverged")]
    if not measured and not allow_no_ok_runs:
        by = Counter(str(r["status"]) for r in runs)
        first = next((r["message"] for r in runs if r["message"]), "")
        raise InputError(f"results {source}: no run is ok or diverged ("
                         + (", ".join(f"{n} {s}" for s, n in by.items()) or "no runs")
                         + (f"; first message: {printable(str(first))[:160]}" if first else "")
                         + "); such a baseline guards nothing. Fix the runs, or pass --allow-no-ok-runs")
    base = make_baseline(doc, str(source))
    write_json_atomic(to, base)
    return base


def baseline_warnings(base: dict) -> list[str]:
    """One line per kind of run in a baseline that guards less than an ok run: failed runs."""
    failed = [r for r in base["runs"] if r["status"] == "failed"]
    if not failed:
        return []
    names = ", ".join(f"{r['case']} {r['engine']}/{r['integrator']} dt={r['dt']}" for r in failed[:3])
    more = f" and {len(failed) - 3} more" if len(failed) > 3 else ""
    return [f"{len(failed)} of {len(base['runs'])} runs failed ({printable(names)}{more}): compare "
            f"only checks that they still fail; see their messages in the results"]
