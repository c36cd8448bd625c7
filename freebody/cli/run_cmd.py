"""``freebody run``: run cases x engines x integrators x time steps, write results and a summary."""
from __future__ import annotations

ORDER = 20

# what the command runs is imported by run(): building the parser (every command's, for any
# command) imports none of it
from .argtypes import (positive_float as _positive_float, positive_int as _positive_int,
                       save_interval as _save_interval, timeout_seconds as _timeout_seconds)

DEFAULT_OUT = "reports/latest"


def add_parser(sub) -> None:
    p = sub.add_parser("run", help="run cases on engines and write results, trajectories and a summary",
                       description="Run CASE|PATH ... (default: every bundled case) on every selected "
                                   "engine and integrator at every time step.")
    p.add_argument("cases", nargs="*", metavar="CASE|PATH", help="bundled case names or TOML files")
    p.add_argument("--engine", action="append", metavar="NAME[==VERSION]",
                   help="engine to run (repeatable); default: the default set of engines (every "
                        "registered one with --all-engines).  ENGINE==VERSION "
                        "(any pip version specifier) runs that version in an isolated environment "
                        "that freebody builds on first use and caches (freebody envs list)")
    p.add_argument("--all-engines", action="store_true",
                   help="with no --engine: every registered engine, the opt-in ones too (freebody "
                        "conventions lists which are opt-in); default: the default set")
    p.add_argument("--all-integrators", action="store_true",
                   help="also run the engines' opt-in integrators (slow ones, e.g. error-controlled "
                        "implicit schemes), which otherwise run only when named with --integrator")
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
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help=f"output directory (default {DEFAULT_OUT}); one freebody process writes it at a time")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--baseline", metavar="FILE",
                   help="a baseline (freebody baseline), results.json or run directory: the terminal "
                        "summary ends with the verdict of freebody compare against it, the report shows "
                        "it, and the exit code is 1 on a regression, as freebody compare's")
    p.add_argument("--table", action="store_true",
                   help="also print the full table, one row a run (report.md has it too); default: "
                        "a summary of cases x engines and the runs that are not ok")
    p.add_argument("--no-report", action="store_true",
                   help="do not write report.md and report.html (freebody report DIR writes them later)")
    p.add_argument("--jobs", type=_positive_int, metavar="N",
                   help="worker processes running runs in parallel, each run isolated (default: the "
                        "number of cores); 1: one worker process, one run after another")
    p.add_argument("--no-isolation", action="store_true",
                   help="for debugging: run every run in this process, one after another (no worker "
                        "processes: an engine's crash ends freebody); not with --jobs N > 1, --timeout "
                        "or --executor dask")
    p.add_argument("--force-large", action="store_true",
                   help="run even when the estimated memory exceeds the memory available")
    p.add_argument("--timeout", type=_timeout_seconds, metavar="S",
                   help="per-run time limit in s: a run past it is killed and recorded failed")
    p.add_argument("--save-every", type=_save_interval, default=None, metavar="K|auto",
                   help="keep every K-th sample in the trajectory files, plus the samples of each "
                        "maximum error and of a divergence (default auto: at most 800 evenly spaced "
                        "samples a run; "
                        "1: every sample); metrics always use every step")
    p.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="where runs execute: local worker processes (default) or a dask cluster")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address for --executor dask (e.g. tcp://127.0.0.1:8786)")


def run(args) -> int:
    from ..errors import printable
    from ..input.casefile import bundled_case_paths, check_run_lengths, load_case
    from ..run.matrix import expand, select_engines
    from ..run.records import Status
    from ..run.suite import run_specs
    from ..results.outdir import REPORTS, check_files, out_folder, output_lock
    from ..report.summary import summary_table, summary_width, terminal_summary, where_to_look

    names = args.cases or list(bundled_case_paths())
    problems = [load_case(n) for n in names]
    check_run_lengths(problems, args.dt, args.duration)  # at most MAX_STEPS_PER_RUN steps a run
    engines = select_engines(args.engine, all_engines=args.all_engines)
    if args.baseline is not None:  # unusable: exit 2 now, not after the runs
        from ..results.compare import check_unique_runs
        from ..results.document import load_results

        check_unique_runs(load_results(args.baseline, "--baseline"), f"--baseline {printable(args.baseline)}")
    from ..run.budget import check_run
    from ..run.suite import check_options, default_jobs

    jobs = args.jobs or (1 if args.no_isolation else default_jobs())
    check_options(jobs, args.timeout, args.save_every, args.executor, args.scheduler,
                  isolate=not args.no_isolation, engines=engines)  # before an environment is built
    from ..adapters.base import set_plugin_import_timeout

    set_plugin_import_timeout(args.timeout)  # a plug-in's import is limited by --timeout too
    # an engine named with a version gets its isolated environment here (built on first use)
    specs = expand(problems, engines, args.integrator, args.dt, args.duration, args.precision,
                   sources=[str(n) for n in names], all_integrators=args.all_integrators)
    out_dir = out_folder(args.out)  # '' is bad input, not the current folder (before it is touched)
    check_files(out_dir, () if args.no_report else REPORTS, f"--out {printable(out_dir)}")  # before the runs
    check_run(specs, jobs, force=args.force_large)
    with output_lock(out_dir):  # one freebody process writes DIR at a time, reports included
        doc, _ = run_specs(specs, out_dir, engines, progress=not args.quiet, save_every=args.save_every,
                           jobs=jobs, timeout=args.timeout, executor=args.executor,
                           scheduler=args.scheduler, isolate=not args.no_isolation)
        if args.table:
            print(summary_table(doc["runs"]) + "\n")
        print(terminal_summary(doc["runs"], summary_width()), flush=True)  # before the reports take their time
        from ..report.render import finish_run  # fitted orders into results.json, then report.md/.html

        from ..input.casefile import defaulted_keys

        defaults = {pb.name: defaulted_keys(n) for pb, n in zip(problems, names)}
        doc, reports = finish_run(out_dir, doc, {pb.name: pb for pb in problems}, report=not args.no_report,
                                  baseline=args.baseline, defaults=defaults, progress=not args.quiet)
    code = 1 if any(r["status"] == Status.FAILED for r in doc["runs"]) else 0
    if args.baseline is not None:  # the gate of freebody compare BASELINE OUT, in the terminal and the exit code
        from ..report.render import compare_with
        from ..results.verdict import compare_command, verdict_line

        comparison = compare_with(args.baseline, doc, str(out_dir))
        print(f"\ncompared with the baseline {printable(args.baseline)}: {verdict_line(comparison)}"
              f"\n(the changes: {compare_command(comparison)})")
        code = max(code, comparison.exit_code)
    print("\n" + where_to_look(out_dir, reports))
    return code
