"""Compare two ``freebody run --save-every 1`` output folders: every trajectory array equal
(``np.array_equal``, NaN == NaN) and results.json equal but for timings and timestamps.

Used to prove that a refactoring changed no number:

    freebody run --save-every 1 --no-report --out /tmp/before   # on the old commit
    freebody run --save-every 1 --no-report --out /tmp/after    # on the new one
    python scripts/compare_outputs.py /tmp/before /tmp/after

Exit 0 when identical, 1 with the differences listed otherwise.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from freebody.results.document import open_run_trajectory

# Keys that legitimately differ between two runs of the same inputs.
VOLATILE = {"wall_time_s", "compile_time_s", "created", "platform"}


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _diff(a, b, path="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}/{k}: only in {'after' if k in b else 'before'}")
            else:
                out += _diff(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _diff(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"[:300]]


def main(before: str, after: str) -> int:
    A, B = Path(before), Path(after)
    ra, rb = (json.loads((p / "results.json").read_text()) for p in (A, B))
    problems = []
    key = lambda r: (r["case"], r["engine"], r["integrator"], r["precision"], r["dt"])  # noqa: E731
    runs_a, runs_b = ({key(r): r for r in d["runs"]} for d in (ra, rb))
    if set(runs_a) != set(runs_b):
        problems.append(f"run sets differ: {len(set(runs_a) ^ set(runs_b))} runs in one only")
    arrays = 0
    for k in sorted(set(runs_a) & set(runs_b), key=str):
        x, y = runs_a[k], runs_b[k]
        problems += [f"{k}: {d}" for d in _diff(_strip({**x, "trajectory": None}),
                                               _strip({**y, "trajectory": None}))]
        if (x["trajectory"] is None) != (y["trajectory"] is None):
            problems.append(f"{k}: trajectory file in one only")
            continue
        if x["trajectory"] is None:
            continue
        # the arrays by their names whatever the trajectory format (1 or 2: truth in a truth file)
        with open_run_trajectory(A, x) as za, open_run_trajectory(B, y) as zb:
            if set(za.files) != set(zb.files):
                problems.append(f"{k}: arrays {sorted(za.files)} != {sorted(zb.files)}")
            for name in set(za.files) & set(zb.files):
                arrays += 1
                if not np.array_equal(za[name], zb[name], equal_nan=True):
                    problems.append(f"{k}: array {name} differs")
    rest_a = _strip({k: v for k, v in ra.items() if k != "runs"})
    rest_b = _strip({k: v for k, v in rb.items() if k != "runs"})
    problems += [f"results.json{d}" for d in _diff(rest_a, rest_b)]
    for p in problems[:50]:
        print(p)
    print(f"{len(runs_a)} runs before, {len(runs_b)} after; {arrays} arrays compared; "
          f"{len(problems)} differences")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
