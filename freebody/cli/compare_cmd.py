"""``freebody compare BASELINE CURRENT``: what changed between two sets of results; exit 1 on a regression."""
from __future__ import annotations

from .argtypes import nonnegative_float as _tolerance

ORDER = 50


def add_parser(sub) -> None:
    p = sub.add_parser("compare", help="compare results with a baseline (exit 1 on a regression)",
                       description="Match runs by (case, engine, integrator, precision, dt) and print what "
                                   "changed. Exit 0: within tolerance; 1: a regression (a metric worse "
                                   "beyond tolerance, a run newly failed/diverged, a run missing); "
                                   "2: unusable input.")
    p.add_argument("baseline", metavar="BASELINE", help="a baseline file, a results.json or a run directory")
    p.add_argument("current", metavar="CURRENT", help="a run directory or a results.json")
    p.add_argument("--rtol", type=_tolerance, metavar="X", help="relative tolerance for every metric")
    p.add_argument("--atol", type=_tolerance, metavar="X",
                   help="absolute tolerance for every metric (in each metric's unit)")
    p.add_argument("--tolerances", metavar="FILE.toml", help="per-metric tolerances (see docs/ci-gate.md)")
    p.add_argument("--all", action="store_true", help="also list the metrics within tolerance")


def run(args) -> int:
    from ..results.compare import compare, load_side, resolve_tolerances

    tols = resolve_tolerances(args.tolerances, args.rtol, args.atol)
    base = load_side(args.baseline, "baseline")
    cur = load_side(args.current, "current")
    result = compare(base, cur, tols, sources=(str(args.baseline), str(args.current)))
    print(result.table(show_all=args.all))
    return result.exit_code
