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
    from ..envs.engines import isolated
    from ..run.selfcheck import CHECKS, run_check, run_trap_checks

    failed = False
    for engine in select_engines(args.engine):
        if isolated(engine):  # another version of the engine: its own environment answers
            failed |= _in_environment(engine, args.no_checks) != 0
            continue
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
        rows = [*cls.conventions.items(), ("load sampling", cls.load_sampling_text())]
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
        traps = run_trap_checks(engine)
        if traps:
            print("  traps the adapter handles (live checks):")
        for r in traps:
            failed |= not r.passed
            print(f"    {'PASS' if r.passed else 'FAIL'}  {r.check:<46} {r.detail}")
        print()
    return 1 if failed else 0


def _in_environment(engine: str, no_checks: bool) -> int:
    """``freebody conventions`` of an engine named with a version, run by the interpreter of its
    isolated environment (built on first use); its exit code."""
    import subprocess
    import sys

    from ..adapters.base import base_engine
    from ..envs.build import clean_environ
    from ..envs.engines import environment

    env = environment(engine)
    sys.stdout.flush()
    cmd = [str(env.python), "-P", "-m", "freebody", "conventions", "--engine", base_engine(engine)]
    proc = subprocess.run(cmd + (["--no-checks"] if no_checks else []), env=clean_environ(),
                          stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
    out = proc.stdout
    head = f"== {base_engine(engine)} "
    print(out.replace(head, f"== {engine} (isolated environment {env.path}): ", 1), end="", flush=True)
    return proc.returncode
