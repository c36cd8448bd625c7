"""``freebody conventions``: each installed engine's conventions and the live self-checks."""
from __future__ import annotations

ORDER = 30


def add_parser(sub) -> None:
    p = sub.add_parser("conventions", help="show each engine's conventions and run the convention self-checks")
    p.add_argument("--engine", action="append", metavar="NAME", help="engine (repeatable); default: all")
    p.add_argument("--no-checks", action="store_true", help="show the conventions only")


def run(args) -> int:
    from ..adapters.base import EngineMissing, load_adapter
    from ..run import select_engines
    from ..run.selfcheck import CHECKS, run_check

    failed = False
    for engine in select_engines(args.engine):
        try:
            cls = load_adapter(engine)
            version = cls.engine_version()
        except EngineMissing as e:
            print(f"== {engine}: skipped: {e}\n")
            continue
        except Exception as e:
            print(f"== {engine}: failed to load: {type(e).__name__}: {e}\n")
            failed = True
            continue
        print(f"== {engine} {version}")
        rows = list(cls.conventions.items())
        w = max((len(k) for k, _ in rows), default=0)
        for k, v in rows:
            print(f"  {k:<{w}}  {v}")
        print(f"  {'integrators':<{w}}  {', '.join(cls.offered_integrators())}")
        if args.no_checks:
            print()
            continue
        integrators = cls.selfcheck_integrators()
        print("  self-checks:")
        for integ in integrators:
            for check in CHECKS:
                r = run_check(check, engine, integ)
                failed |= not r.passed
                print(f"    {'PASS' if r.passed else 'FAIL'}  {integ:<28} {check:<17} {r.detail}")
        print()
    return 1 if failed else 0
