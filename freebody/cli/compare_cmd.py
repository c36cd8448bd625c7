"""``freebody compare BASELINE CURRENT``: what changed between two sets of results; exit 1 on a regression.

``freebody compare RESULTS --engine mujoco==3.1.6 --against mujoco==4.0.0``: the same verdicts
between two engines (two versions of one) of one results file (:mod:`freebody.envs.versions`)."""
from __future__ import annotations

from .argtypes import nonnegative_float as _tolerance

ORDER = 50


def add_parser(sub) -> None:
    p = sub.add_parser("compare", help="compare results with a baseline (exit 1 on a regression)",
                       description="Match runs by (case, engine, integrator, precision, dt), check they are "
                                   "the same experiment, and print what changed. Exit 0: within tolerance; "
                                   "1: a regression (a metric worse beyond tolerance, a run newly "
                                   "failed/diverged or missing, another experiment under the same name, a "
                                   "changed scheme or order); 2: unusable input.")
    p.add_argument("baseline", metavar="BASELINE", help="a baseline file, a results.json or a run directory")
    p.add_argument("current", metavar="CURRENT", nargs="?",
                   help="a run directory or a results.json (not with --against)")
    p.add_argument("--rtol", type=_tolerance, metavar="X", help="relative tolerance for every metric")
    p.add_argument("--atol", type=_tolerance, metavar="X",
                   help="absolute tolerance for every metric (in each metric's unit)")
    p.add_argument("--tolerances", metavar="FILE.toml", help="per-metric tolerances (see docs/ci-gate.md)")
    p.add_argument("--all", action="store_true", help="also list the metrics within tolerance")
    p.add_argument("--strict", action="store_true",
                   help="fail on any change beyond tolerance, improvements included")
    p.add_argument("--engine", action="append", metavar="NAME",
                   help="compare only this engine's runs (repeatable; both sides)")
    p.add_argument("--against", metavar="ENGINE",
                   help="compare two engines of ONE results file: the runs of --engine (the baseline) "
                        "with those of ENGINE, e.g. RESULTS --engine mujoco==3.1.6 --against mujoco==4.0.0")
    p.add_argument("--case", action="append", metavar="NAME",
                   help="compare only this case's runs (repeatable; both sides)")
    p.add_argument("--json", action="store_true",
                   help="print the verdict as JSON (schema in docs/ci-gate.md) instead of the table")
    p.add_argument("--junit", metavar="FILE", help="also write the verdict as JUnit XML to FILE")


def run(args) -> int:
    from ..errors import InputError, printable
    from ..results.compare import compare, load_side, resolve_tolerances
    from ..results.io import write_text_atomic
    from ..results.verdict import junit_xml, write_json
    from .argtypes import writable_file

    junit = None if args.junit is None else writable_file(args.junit, "--junit")  # before the work
    tols = resolve_tolerances(args.tolerances, args.rtol, args.atol)
    if args.against is not None:
        from ..envs.versions import split_sides

        if args.current is not None:
            raise InputError("--against: compares two engines of one results file; give RESULTS only "
                             f"(not {args.current})")
        if not args.engine or len(args.engine) != 1:
            raise InputError("--against: needs one --engine, the baseline side (e.g. RESULTS --engine "
                             "mujoco==3.1.6 --against mujoco==4.0.0)")
        doc = load_side(args.baseline, "results")
        base, cur = split_sides(doc, args.engine[0], args.against)
        sources = (f"{args.baseline} [{args.engine[0]}]", f"{args.baseline} [{args.against}]")
        engines = None
    else:
        if args.current is None:
            raise InputError("CURRENT: missing (freebody compare BASELINE CURRENT, or RESULTS --engine A "
                             "--against B)")
        base = load_side(args.baseline, "baseline")
        cur = load_side(args.current, "current")
        sources, engines = (str(args.baseline), str(args.current)), args.engine
    result = compare(base, cur, tols, sources=sources, strict=args.strict, engines=engines, cases=args.case)
    for option, wanted, field in (("--engine", engines, "engine"), ("--case", args.case, "case")):
        known = {r.get(field) for r in (base.get("runs") or []) + (cur.get("runs") or [])}
        unknown = [w for w in wanted or () if w not in known]
        if unknown:
            raise InputError(f"{option} {unknown[0]}: no run of either side has this {field}; known: "
                             f"{', '.join(sorted(str(k) for k in known))}")
    if junit is not None:
        try:
            write_text_atomic(junit, junit_xml(result).decode("utf-8"), what=f"--junit {printable(args.junit)}")
        except OSError as e:
            raise InputError(f"--junit {args.junit}: cannot write: {e.strerror or e}") from None
    print(write_json(result) if args.json else result.table(show_all=args.all))
    return result.exit_code
