"""``freebody bench``: freebody's speed on the paths users take, next to the engines' (see
:mod:`freebody.tools.bench`)."""
from __future__ import annotations

ORDER = 90

import json
from .argtypes import nonnegative_int as _nonnegative_int, positive_int as _positive_int


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bench", help="time freebody on the paths users take against the engines, with targets",
        description="Measure, side by side in one run, and check against targets (PASS/MISS): "
                    "a. each reference map stepping one body vs one MuJoCo mj_step; b. freebody run "
                    "of 50,000 MuJoCo Euler steps minus the same at 10 steps vs MuJoCo's bare "
                    "stepping; c. a pinned default suite (525 runs, report included) with --jobs 1 "
                    "and --jobs max(2, cores); d. its trajectory files and report.html; e. the peak RSS of a "
                    "long run; and each engine's bare loop vs freebody's. Medians over repeats "
                    "are quoted.")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the text summary")
    p.add_argument("--quick", action="store_true",
                   help="fewer steps and repeats, a 60-run slice of the suite, a 1e5-step RSS run: "
                        "well under a minute (the suite targets not judged on the slice)")
    p.add_argument("--repeats", type=_positive_int, metavar="N",
                   help="repeats of every measurement but the suite's (default 7; 3 with --quick)")
    p.add_argument("--no-suite", action="store_true",
                   help="skip the suite measurement (c, d: a few minutes here)")
    p.add_argument("--suite-repeats", type=_positive_int, metavar="N",
                   help="repeats of the serial and the parallel suite command (default 3; 1 with --quick)")
    p.add_argument("--rss-steps", type=_nonnegative_int, metavar="N",
                   help="steps of the run whose peak RSS is measured (default 1000000; 100000 with "
                        "--quick; 0: not measured); the target is for 10000000")
    p.add_argument("--out", metavar="FILE", help="also write the JSON document to FILE")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args) -> int:
    from ..tools.bench import BenchConfig, format_text, run_bench
    from ..errors import printable
    from ..results.io import write_json_atomic
    from .argtypes import writable_file

    out = None if args.out is None else writable_file(args.out, "--out")  # before the measurements
    config = BenchConfig.make(quick=args.quick, repeats=args.repeats, suite=not args.no_suite,
                              rss_steps=args.rss_steps, suite_repeats=args.suite_repeats)
    doc = run_bench(config, progress=not args.quiet)
    if out is not None:
        write_json_atomic(out, doc, what=f"--out {printable(args.out)}")
    if args.json:
        print(json.dumps(doc, sort_keys=True, indent=1, allow_nan=False))
    else:
        print(format_text(doc))
    return 0
