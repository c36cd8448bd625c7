"""Fixed costs: what one invocation and one further run cost (part "overhead"), and numba's first
compilation (part "compile"), each a ``freebody run`` command in a fresh subprocess timed in CPU
(user + system of the command and its workers: :func:`core.run_child`)."""
from __future__ import annotations

import tempfile
from pathlib import Path

from ...results.document import load_results
from .config import (CASE, DT, OVERHEAD_DURATION_S, OVERHEAD_INTEGRATOR, BenchConfig)
from .core import Child, freebody_cmd, log, median, run_ok


def overhead_command(cases: list[str], out: str, one: bool) -> list[str]:
    """``freebody run`` of 10-step runs on the yardstick engine at DT, report off, one worker:
    ``one`` -> :data:`CASE` and its Euler only (one run); else ``cases`` (every bundled case when
    empty) x every integrator of the engine."""
    from ...adapters.base import BENCH_YARDSTICK

    sel = [CASE, "--integrator", OVERHEAD_INTEGRATOR] if one else list(cases)
    return freebody_cmd("run", *sel, "--engine", BENCH_YARDSTICK, "--dt", repr(DT),
                        "--duration", repr(OVERHEAD_DURATION_S), "--no-report", "--quiet",
                        "--jobs", "1", "--out", out)


def _invocation(cases: list[str], one: bool, env: dict | None = None) -> tuple[Child, int]:
    """One overhead command in a fresh output folder: (the child, its number of ok runs)."""
    with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
        child = run_ok(overhead_command(cases, tmp, one), "freebody run", env)
        runs = load_results(Path(tmp))["runs"]
    if one and len(runs) != 1:
        raise RuntimeError(f"the one-run command ran {len(runs)} runs")
    return child, sum(r["status"] == "ok" for r in runs)


def overhead(config: BenchConfig, progress: bool = False) -> dict:
    """A one-run invocation and an N-run invocation, interleaved ``repeats`` times; medians of
    CPU seconds.  The marginal run = (N-run CPU - one-run CPU) / (N - 1)."""
    from ...adapters.base import BENCH_YARDSTICK, is_available

    if not is_available(BENCH_YARDSTICK):
        return {"overhead_note": f"{BENCH_YARDSTICK} not installed"}
    ones, manys, n_runs = [], [], 0
    cases = list(config.overhead_cases)
    for r in range(config.repeats):
        ones.append(_invocation(cases, True)[0])
        child, n_runs = _invocation(cases, False)
        manys.append(child)
        log(f"overhead repeat {r + 1}/{config.repeats}: 1 run {ones[-1].cpu_s:.2f} s CPU, "
            f"{n_runs} runs {manys[-1].cpu_s:.2f} s CPU", progress)
    one_cpu, many_cpu = median([c.cpu_s for c in ones]), median([c.cpu_s for c in manys])
    return {"overhead_one_run_cpu_s": one_cpu, "overhead_one_run_wall_s": median([c.wall_s for c in ones]),
            "overhead_n_runs": n_runs, "overhead_n_runs_cpu_s": many_cpu,
            "overhead_n_runs_wall_s": median([c.wall_s for c in manys]),
            "overhead_marginal_run_cpu_s": (many_cpu - one_cpu) / max(n_runs - 1, 1),
            "overhead_one_run_all_cpu_s": [c.cpu_s for c in ones],
            "overhead_n_runs_all_cpu_s": [c.cpu_s for c in manys],
            "overhead_command": " ".join(["freebody"] + overhead_command(cases, "DIR", True)[3:]),
            "overhead_n_command": " ".join(["freebody"] + overhead_command(cases, "DIR", False)[3:])}


def compile_command(out: str) -> list[str]:
    """What the quick start's reference maps and identification need compiled: every bundled case
    on the reference engine and the yardstick engine (identification runs the engines' maps),
    10 steps at DT, report off, one worker."""
    from ...adapters.base import BENCH_YARDSTICK, REFERENCE_ENGINE

    return freebody_cmd("run", "--engine", REFERENCE_ENGINE, "--engine", BENCH_YARDSTICK,
                        "--dt", repr(DT), "--duration", repr(OVERHEAD_DURATION_S), "--no-report",
                        "--quiet", "--jobs", "1", "--out", out)


def cold_compile(config: BenchConfig, progress: bool = False) -> dict:
    """CPU of :func:`compile_command` with an empty ``NUMBA_CACHE_DIR`` (numba compiles every map
    it needs) minus the same command right after with that cache filled (warm), once each."""
    from ...adapters.base import BENCH_YARDSTICK, is_available

    if not is_available(BENCH_YARDSTICK):
        return {"compile_note": f"{BENCH_YARDSTICK} not installed"}
    with tempfile.TemporaryDirectory(prefix="freebody-bench-numba-") as cache:
        env = {"NUMBA_CACHE_DIR": cache}
        runs = []
        for what in ("cold", "warm"):
            log(f"compile: {what} numba cache", progress)
            with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
                runs.append(run_ok(compile_command(tmp), f"freebody run ({what})", env, (0, 1)))
    cold, warm = runs
    return {"compile_cold_cpu_s": cold.cpu_s, "compile_warm_cpu_s": warm.cpu_s,
            "compile_cpu_s": cold.cpu_s - warm.cpu_s, "compile_cold_wall_s": cold.wall_s,
            "compile_warm_wall_s": warm.wall_s,
            "compile_command": " ".join(["NUMBA_CACHE_DIR=<empty>", "freebody"]
                                        + compile_command("DIR")[3:])}
