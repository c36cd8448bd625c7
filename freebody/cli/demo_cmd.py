"""``freebody demo``: slide-ready teaching figures (PNG and SVG) with a short Markdown page each."""
from __future__ import annotations

ORDER = 50

DEMO_NAMES = ("integrators", "quiz", "dzhanibekov")  # freebody.tools.demo.DEMOS, without importing it
DEFAULT_OUT = "reports/demo"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "demo", help="teaching figures: integrator error, the push quiz, the Dzhanibekov flip",
        description="Write slide-ready 16:9 figures (PNG 1600x900 and SVG, the exact motion drawn on "
                    "top) and a Markdown page with a sentence for every number. "
                    "integrators: signed energy error and orientation error of euler-matrix, "
                    "euler-matrix-gs, euler-quat, lie-euler, symplectic-splitting, implicit-midpoint "
                    "and rk4, R's orthonormality, convergence slopes (and why euler-matrix-gs fits "
                    "1.27); quiz: the lecture's push quiz in closed form and on every engine; "
                    "dzhanibekov: the flip and its times on every engine, and a 960x540 GIF of the "
                    "tumbling box.  No NAME: all three.  The Jupyter lessons in examples/ teach the "
                    "same step by step (docs/teaching.md).")
    p.add_argument("names", nargs="*", metavar="NAME", help=f"demo(s) to make: {', '.join(DEMO_NAMES)}")
    p.add_argument("--engine", action="append", metavar="NAME",
                   help="engine for quiz and dzhanibekov (repeatable); default: every registered engine")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--quiet", action="store_true", help="no progress display")


def run(args) -> int:
    from ..tools.demo import log_to_stderr, run_demo
    from ..errors import InputError
    from ..run import select_engines
    from .argtypes import writable_folder

    names = args.names or list(DEMO_NAMES)
    for n in names:
        if n not in DEMO_NAMES:
            raise InputError(f"demo: unknown demo {n!r}; known: {', '.join(DEMO_NAMES)}")
    engines = select_engines(args.engine) if args.engine else None
    log = None if args.quiet else log_to_stderr
    out_dir = writable_folder(args.out, "--out")  # before the work; each file is checked when written
    for n in dict.fromkeys(names):
        if log:
            log(f"demo {n} ...")
        res = run_demo(n, out_dir, engines, log=log)
        print(f"{n}: {res.page}")
        for f in res.figures:
            print(f"  {f.with_suffix('.png')}  {f.with_suffix('.svg')}")
        for f in res.files:
            print(f"  {f}")
    return 0
