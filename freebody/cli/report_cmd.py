"""``freebody report DIR``: re-render report.md and report.html from results.json and the
trajectory files, without running anything."""
from __future__ import annotations

ORDER = 30


def add_parser(sub) -> None:
    p = sub.add_parser("report", help="re-render report.md and report.html of a run directory",
                       description="Re-render DIR/report.md and DIR/report.html from DIR/results.json and "
                                   "the trajectory files under DIR, without re-running anything.")
    p.add_argument("dir", metavar="DIR", help="a run directory (holding results.json)")
    p.add_argument("--case", action="append", metavar="PATH", default=[],
                   help="a case TOML file (repeatable): its mass and inertia, for results.json files "
                        "that do not describe their cases")
    p.add_argument("--markdown-only", action="store_true", help="write report.md only (no plots)")
    p.add_argument("--baseline", metavar="FILE",
                   help="a baseline (freebody baseline), results.json or run directory: the report "
                        "shows the compare verdict against it")
    p.add_argument("--quiet", action="store_true",
                   help="no progress display (by default the figures done / total on stderr)")


def run(args) -> int:
    from pathlib import Path

    from ..input.casefile import load_case
    from ..errors import InputError
    from ..report.render import write_reports
    from ..results.outdir import REPORTS, check_files, output_lock

    out_dir = Path(args.dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: not a directory (expected a run directory holding results.json)")
    problems = {pb.name: pb for pb in (load_case(p) for p in args.case)}
    with output_lock(out_dir, option=""):  # not while a freebody run writes there
        check_files(out_dir, REPORTS[:1] if args.markdown_only else REPORTS, str(out_dir))  # before the work
        # write_reports reads results.json (once: a document handed to it would be checked again)
        for path in write_reports(out_dir, None, problems, html=not args.markdown_only,
                                  baseline=args.baseline, progress=not args.quiet):
            print(f"report: {path}")
    return 0
