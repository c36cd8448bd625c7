"""``freebody bench``: freebody's speed next to the engines' (see :mod:`freebody.tools.bench`)."""
from __future__ import annotations

ORDER = 90

import json
from pathlib import Path

from ..errors import InputError


def add_parser(sub) -> None:
    p = sub.add_parser(
        "bench", help="measure freebody's overhead over the engines, the batched reference "
                      "integrators and the suite's parallel speed-up",
        description="Measure, side by side in one run: each engine's bare step loop vs freebody "
                    "stepping the same world; the reference integrators batched over B = 1, 100, "
                    "1000, 10000 bodies vs one MuJoCo step; the default suite serial vs parallel. "
                    "Medians over repeats are quoted.")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the text summary")
    p.add_argument("--quick", action="store_true",
                   help="few steps and repeats and a one-case suite: a smoke run of a few seconds")
    p.add_argument("--repeats", type=int, metavar="N",
                   help="repeats of every measurement (default 7; 3 with --quick)")
    p.add_argument("--no-suite", action="store_true",
                   help="skip the suite measurement (the default suite takes minutes)")
    p.add_argument("--out", metavar="FILE", help="also write the JSON document to FILE")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")


def run(args) -> int:
    from ..tools.bench import BenchConfig, format_text, run_bench
    from ..results.io import write_json_atomic

    if args.repeats is not None and args.repeats < 1:
        raise InputError(f"--repeats: must be an integer >= 1, got {args.repeats}")
    config = BenchConfig.make(quick=args.quick, repeats=args.repeats, suite=not args.no_suite)
    doc = run_bench(config, progress=not args.quiet)
    if args.out:
        write_json_atomic(Path(args.out), doc)
    if args.json:
        print(json.dumps(doc, sort_keys=True, indent=1, allow_nan=False))
    else:
        print(format_text(doc))
    return 0
