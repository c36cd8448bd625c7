"""``freebody run``: run cases x engines x integrators x time steps, write results and a summary."""
from __future__ import annotations

ORDER = 20

from pathlib import Path

from ..input.casefile import bundled_case_paths, load_case
from ..run import Status, expand, select_engines
from ..run.suite import run_specs
from ..report.summary import summary_table
from .argtypes import positive_float as _positive_float, positive_int as _positive_int

DEFAULT_OUT = "reports/latest"


def add_parser(sub) -> None:
    p = sub.add_parser("run", help="run cases on engines and write results, trajectories and a summary",
                       description="Run CASE|PATH ... (default: every bundled case) on every selected "
                                   "engine and integrator at every time step.")
    p.add_argument("cases", nargs="*", metavar="CASE|PATH", help="bundled case names or TOML files")
    p.add_argument("--engine", action="append", metavar="NAME",
                   help="engine to run (repeatable); default: every available engine")
    p.add_argument("--integrator", action="append", metavar="[ENGINE:]NAME",
                   help="integrator (repeatable, case-insensitive); NAME applies to every engine "
                        "offering it, ENGINE:NAME to one engine; default: all")
    p.add_argument("--dt", action="append", type=_positive_float, metavar="DT",
                   help="time step in s (repeatable); default: the case's")
    p.add_argument("--duration", type=_positive_float, metavar="T", help="simulated time in s; default: the case's")
    p.add_argument("--precision", action="append", choices=("float32", "float64"),
                   help="floating-point precision (repeatable); default: every one each engine offers "
                        "(mjx: float32 and float64, the others float64); engines offering none of "
                        "the chosen ones are left out, and a precision no selected engine offers is an error")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory (default {DEFAULT_OUT})")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--no-report", action="store_true",
                   help="do not write report.md and report.html (freebody report DIR writes them later)")
    p.add_argument("--jobs", type=_positive_int, metavar="N",
                   help="worker processes running runs in parallel, each run isolated (default: the "
                        "number of cores); 1: one after another in this process")
    p.add_argument("--timeout", type=_positive_float, metavar="S",
                   help="per-run time limit in s: a run past it is killed and recorded failed")
    p.add_argument("--save-every", type=_positive_int, default=1, metavar="K",
                   help="keep every K-th sample in the trajectory files (metrics use every step)")
    p.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="where runs execute: local worker processes (default) or a dask cluster")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address for --executor dask (e.g. tcp://127.0.0.1:8786)")


def run(args) -> int:
    names = args.cases or list(bundled_case_paths())
    problems = [load_case(n) for n in names]
    engines = select_engines(args.engine)
    specs = expand(problems, engines, args.integrator, args.dt, args.duration, args.precision)
    out_dir = Path(args.out)
    from ..run.suite import default_jobs

    doc, _ = run_specs(specs, out_dir, engines, progress=not args.quiet, save_every=args.save_every,
                       jobs=args.jobs or default_jobs(), timeout=args.timeout, executor=args.executor,
                       scheduler=args.scheduler)
    print(summary_table(doc["runs"]), flush=True)
    from ..report.render import finish_run  # fitted orders into results.json, then report.md/.html

    doc, reports = finish_run(out_dir, doc, {pb.name: pb for pb in problems}, report=not args.no_report)
    print(f"\nresults: {out_dir / 'results.json'}")
    for path in reports:
        print(f"report: {path}")
    return 1 if any(r["status"] == Status.FAILED for r in doc["runs"]) else 0
