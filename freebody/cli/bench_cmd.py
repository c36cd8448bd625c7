"""``freebody bench``: freebody's speed on the paths users take, next to the engines', each target of
issue 29 checked (see :mod:`freebody.tools.bench`)."""
from __future__ import annotations

ORDER = 90

import json
from .argtypes import nonnegative_int as _nonnegative_int, positive_int as _positive_int

# the parts of freebody.tools.bench.config.PARTS (written here so that the parser imports no tool)
PARTS = ("overhead", "compile", "maps", "truth", "sweep", "suite", "rss", "engines")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bench", help="time freebody on the paths users take against the engines, with targets",
        description="Measure, side by side in one run, and check each target of issue 29 (PASS/MISS/"
                    "n/a): a run's marginal CPU and a one-run invocation's; the default suite cold and "
                    "warm, without MJX against its own engine stepping, MJX against MuJoCo; numba's "
                    "cold compilation; the numerical truth against a numba-rhs DOP853; the reference "
                    "maps against mj_step, mujoco.rollout and their flat-loop floors; freebody sweep "
                    "against mujoco.rollout and --jobs 2 against 1; report rendering and output sizes; "
                    "the peak RSS of a 10^7-step run; each engine's bare loop against freebody's.")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the text summary")
    p.add_argument("--quick", action="store_true",
                   help="fewer steps and repeats, a slice of the suite without MJX, a 10-body sweep, a "
                        "1e5-step RSS run, no cold compile: 2 to 5 minutes here (the suite, sweep "
                        "and output targets shown, not judged)")
    p.add_argument("--cold", action="store_true",
                   help="measure the cold compilation (with --quick too) and give the suite's cold run "
                        "empty numba and JAX caches")
    p.add_argument("--part", action="append", choices=PARTS, metavar="PART",
                   help=f"measure only these parts (repeatable): {', '.join(PARTS)}")
    p.add_argument("--no-suite", action="store_true",
                   help="every part but the suite (the longest: the default suite three times)")
    p.add_argument("--repeats", type=_positive_int, metavar="N",
                   help="repeats of every measurement but the suite's (default 5; 3 with --quick)")
    p.add_argument("--rss-steps", type=_nonnegative_int, metavar="N",
                   help="steps of the run whose peak RSS is measured (default 10000000, the target's; "
                        "100000 with --quick; 0: not measured)")
    p.add_argument("--out", metavar="FILE", help="also write the JSON document to FILE")
    p.add_argument("--show", metavar="FILE",
                   help="measure nothing: print the text of a saved bench document (schema 3 or 4)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args) -> int:
    from ..tools.bench import BenchConfig, format_text, load_bench, run_bench
    from ..errors import printable
    from ..results.io import write_json_atomic
    from .argtypes import writable_file

    if args.show is not None:
        doc = load_bench(args.show)
        print(json.dumps(doc, sort_keys=True, indent=1, allow_nan=False) if args.json else format_text(doc))
        return 0
    out = None if args.out is None else writable_file(args.out, "--out")  # before the measurements
    parts = tuple(args.part) if args.part else None
    if args.no_suite:
        parts = tuple(p for p in (parts or PARTS) if p != "suite"
                      and (p != "compile" or args.cold or not args.quick or args.part))
    config = BenchConfig.make(quick=args.quick, repeats=args.repeats, rss_steps=args.rss_steps,
                              cold=args.cold, parts=parts)
    doc = run_bench(config, progress=not args.quiet)
    if out is not None:
        write_json_atomic(out, doc, what=f"--out {printable(args.out)}")
    if args.json:
        print(json.dumps(doc, sort_keys=True, indent=1, allow_nan=False))
    else:
        print(format_text(doc), end="")
    return 0
