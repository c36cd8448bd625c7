"""``freebody sweep``: N random physically valid bodies on the selected engines; the distribution of
each metric per engine and integrator, and the worst cases saved as case files."""
from __future__ import annotations

ORDER = 40

from pathlib import Path

from .. import tolerances as tol
from ..errors import InputError, printable
from .argtypes import (nonnegative_int as _nonneg_int, positive_float as _positive_float,
                       positive_int as _positive_int, writable_folder)

DEFAULT_OUT = "reports/sweep"


def add_parser(sub) -> None:
    p = sub.add_parser(
        "sweep", help="run N random bodies and report each metric's distribution per engine",
        description="Draw N physically valid random bodies (seeded: the same seed gives the same bodies "
                    "and numbers), run them on every selected engine and integrator, and report per "
                    "engine/integrator the median, 95th percentile and worst of each metric; the worst "
                    "cases are saved as case files under OUT/worst/.")
    p.add_argument("--seed", type=_nonneg_int, default=0, metavar="S", help="random seed (default 0)")
    p.add_argument("--count", type=_nonneg_int, default=100, metavar="N", help="number of bodies (default 100)")
    p.add_argument("--engine", action="append", metavar="NAME",
                   help="engine to run (repeatable); default: every registered engine")
    p.add_argument("--integrator", action="append", metavar="[ENGINE:]NAME",
                   help="integrator (repeatable, as for freebody run); default: all")
    p.add_argument("--dt", action="append", type=_positive_float, metavar="DT",
                   help="time step in s (repeatable); default 0.01")
    p.add_argument("--duration", type=_positive_float, default=2.0, metavar="T",
                   help="simulated time per run in s (default 2)")
    p.add_argument("--precision", action="append", choices=("float32", "float64"),
                   help="floating-point precision (repeatable, as for freebody run); default: every one "
                        "each engine offers")
    p.add_argument("--max-spin", type=float, default=10.0, metavar="W",
                   help="bound on the initial |w| in rad/s (default 10)")
    p.add_argument("--gravity", choices=("mixed", "on", "off"), default="mixed",
                   help="gravity (0, 0, -9.81) on half the bodies (mixed, default), all or none")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--jobs", type=_positive_int, metavar="N",
                   help="worker processes running runs in parallel, each run isolated, as for freebody "
                        "run (default: the number of cores); the numbers do not depend on it")
    p.add_argument("--force-large", action="store_true",
                   help="start even when the estimated memory exceeds the memory available")


def run(args) -> int:
    import math

    from ..input.casefile import check_step_count
    from ..run import Status, select_engines
    from ..run.budget import check_sweep
    from ..run.suite import default_jobs
    from ..tools.sweep import SweepSettings, first_body_specs, sweep

    if args.count < 1:
        raise InputError(f"--count: must be >= 1, got {args.count}")
    if not (math.isfinite(args.max_spin) and 0 <= args.max_spin <= tol.INPUT_MAGNITUDE_MAX):
        raise InputError(f"--max-spin: must be a finite number from 0 to {tol.INPUT_MAGNITUDE_MAX:g}, "
                         f"got {args.max_spin}")
    dts = tuple(args.dt or (0.01,))
    for d in dts:
        if args.duration < d * (1 - tol.DURATION_VS_DT_RTOL):
            raise InputError(f"--duration: {args.duration} s is shorter than dt = {d} s")
        check_step_count(args.duration, d, lambda why: _fail("--duration", why))
        if d < tol.INPUT_POSITIVE_MIN:
            raise InputError(f"--dt: must be at least {tol.INPUT_POSITIVE_MIN:g} s (smaller steps are too "
                             f"small to compute with in float64), got {d!r}")
    settings = SweepSettings(seed=args.seed, count=args.count, duration=args.duration, dts=dts,
                             max_spin=args.max_spin, gravity=args.gravity)
    engines = select_engines(args.engine)
    check_sweep(args.count, first_body_specs(settings, engines, args.integrator, args.precision),
                force=args.force_large)
    # before the runs, so that none is lost (the worst cases' files are checked when written)
    out_dir = writable_folder(args.out, "--out", files=("sweep.json", "sweep.txt"))
    out = sweep(settings, engines, args.integrator, out_dir, progress=not args.quiet,
                precisions=args.precision, jobs=args.jobs or default_jobs())
    print(out.report)
    print(f"\nreport (the text above): {printable(Path(args.out) / 'sweep.txt')}")
    print(f"data: {printable(Path(args.out) / 'sweep.json')}")
    return 1 if any(r["status"] == Status.FAILED for r in out.document["runs"]) else 0


def _fail(option: str, why: str):
    raise InputError(f"{option}: {why}")
