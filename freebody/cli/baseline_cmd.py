"""``freebody baseline DIR --to FILE``: store a run's results (without trajectories) as a baseline."""
from __future__ import annotations

ORDER = 40


def add_parser(sub) -> None:
    p = sub.add_parser("baseline", help="store a run's results as a regression baseline",
                       description="Store DIR/results.json (or a results.json) without its trajectory files, "
                                   "with the engine versions, as a baseline for freebody compare.")
    p.add_argument("dir", metavar="DIR", help="a run directory or a results.json")
    p.add_argument("--to", required=True, metavar="FILE", help="the baseline file to write (JSON)")
    p.add_argument("--force", action="store_true", help="replace FILE if it exists")
    p.add_argument("--allow-no-ok-runs", action="store_true",
                   help="store the baseline even when none of its runs is ok or diverged (every run "
                        "failed or was skipped: such a baseline guards nothing)")


def run(args) -> int:
    from ..errors import InputError
    from ..results.baseline import baseline_warnings, store_baseline
    from .argtypes import writable_file

    if not args.to:
        raise InputError("--to: empty; give the baseline file to write (e.g. --to baseline.json)")
    writable_file(args.to, "--to")  # a regular file or a new path, its folder writable: before reading
    import sys

    base = store_baseline(args.dir, args.to, force=args.force, allow_no_ok_runs=args.allow_no_ok_runs)
    from ..results.compare import engine_version_words

    engines = ", ".join(f"{e} {v}" for e, v in engine_version_words(base).items())
    print(f"baseline: {args.to} ({len(base['runs'])} runs; engines: {engines or 'none'})")
    for line in baseline_warnings(base):
        print(f"warning: {line}", file=sys.stderr)
    return 0
