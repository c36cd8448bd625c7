"""Regression baselines: a results document without its trajectory files, stored for ``freebody compare``.

A baseline is a results.json (same schema version, same keys) whose runs carry no ``trajectory``
path, with a ``"baseline"`` record saying where it came from.  It keeps the engine versions, the
metrics, the final states, the statuses, the fitted orders and the cases.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

from ..errors import InputError
from .io import file_kind, write_json_atomic


def make_baseline(doc: dict, source: str) -> dict:
    """The baseline document of a results document (``source``: where it was read, for the record)."""
    out = {k: v for k, v in doc.items() if k != "runs"}
    out["runs"] = [{k: v for k, v in r.items() if k != "trajectory"} for r in doc.get("runs") or []]
    out["baseline"] = {"source": str(source), "runs": len(out["runs"])}
    return out


def store_baseline(source: str | Path, to: str | Path, force: bool = False) -> dict:
    """Read the results of ``source`` (a run directory or a results.json), write its baseline to
    ``to`` atomically, and return it.  InputError when ``to`` exists (unless ``force``), when the
    results are unusable, or when the run was interrupted (incomplete results make a bad baseline)."""
    from .compare import load_side

    to = Path(to)
    if to.is_dir():
        raise InputError(f"--to {to}: is a directory; give a file name such as {to / 'baseline.json'}")
    _check_regular(to)
    if to.exists() and not force:
        raise InputError(f"--to {to}: exists; pass --force to replace it")
    doc = load_side(source, "results")
    if doc.get("incomplete"):
        raise InputError(f"results {source}: incomplete (the run was interrupted); re-run it before "
                         f"storing a baseline")
    base = make_baseline(doc, str(source))
    write_json_atomic(to, base)
    return base


def _check_regular(to: Path) -> None:
    """InputError if ``to`` exists and is not a regular file (a device such as /dev/null, a FIFO,
    a socket; through a symbolic link too): ``--force`` replaces files, never those."""
    try:
        mode = os.stat(to).st_mode
    except FileNotFoundError:
        return
    except OSError as e:
        raise InputError(f"--to {to}: cannot check it: {e.strerror or e}") from None
    if not stat.S_ISREG(mode):
        raise InputError(f"--to {to}: is {file_kind(mode)}, not a regular file; freebody writes baselines to "
                         f"regular files only (--force does not replace it)")
