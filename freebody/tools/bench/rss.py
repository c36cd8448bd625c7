"""Part "rss": the peak resident memory of one long ``freebody run`` (MuJoCo Euler on a uniform
rotation, report off, identification on) of ``--rss-steps`` steps (the target's 10^7 by default,
10^5 with ``--quick``), the largest of the command's processes (worker included), beside a
10-step run of the same command."""
from __future__ import annotations

import tempfile
from pathlib import Path

from ...results.document import load_results
from .config import DT, RSS_CASE, RSS_INTEGRATOR, BenchConfig
from .core import Child, freebody_cmd, log, run_ok

SHORT_RSS_STEPS = 10


def rss_command(steps: int, out: str) -> list[str]:
    """``freebody run`` of :data:`RSS_CASE` on the yardstick engine's Euler for ``steps`` steps of
    DT, report off (scheme identification is on in every run of an engine other than the
    reference)."""
    from ...adapters.base import BENCH_YARDSTICK

    return freebody_cmd("run", RSS_CASE, "--engine", BENCH_YARDSTICK, "--integrator", RSS_INTEGRATOR,
                        "--dt", repr(DT), "--duration", repr(steps * DT), "--no-report", "--quiet",
                        "--out", out)


def run_once(steps: int) -> Child:
    """One RSS command in a fresh output folder; RuntimeError unless it ran ``steps`` steps, ended
    ok and identified a scheme."""
    with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
        child = run_ok(rss_command(steps, tmp), f"freebody run ({steps} steps)")
        runs = load_results(Path(tmp))["runs"]
    if len(runs) != 1 or runs[0]["steps"] != steps or runs[0]["status"] != "ok":
        got = "; ".join(f"{r['status']} {r['steps']} steps {r.get('message') or ''}"[:200] for r in runs)
        raise RuntimeError(f"freebody run ({steps} steps) did not give one ok run of {steps} "
                           f"steps: {got}")
    if not runs[0].get("matches_reference"):
        raise RuntimeError("freebody run did not identify the run's scheme (matches_reference)")
    return child


def peak_rss(config: BenchConfig, progress: bool = False) -> dict:
    """Peak RSS, wall and CPU of one command of ``config.rss_steps`` steps and of 10 steps."""
    from ...adapters.base import BENCH_YARDSTICK, is_available

    if config.rss_steps <= 0:
        return {"rss_note": "not measured (--rss-steps 0)"}
    if not is_available(BENCH_YARDSTICK):
        return {"rss_note": f"{BENCH_YARDSTICK} not installed"}
    short = run_once(SHORT_RSS_STEPS)
    log(f"peak RSS: freebody run of {config.rss_steps} steps", progress)
    child = run_once(config.rss_steps)
    if child.maxrss_bytes is None:  # pragma: no cover (no resource module)
        return {"rss_note": "peak RSS not available on this platform (no resource module)"}
    return {"rss_steps": config.rss_steps, "rss_bytes": child.maxrss_bytes, "rss_run_s": child.wall_s,
            "rss_run_cpu_s": child.cpu_s, "rss_short_steps": SHORT_RSS_STEPS,
            "rss_short_bytes": short.maxrss_bytes,
            "rss_command": " ".join(["freebody"] + rss_command(config.rss_steps, "DIR")[3:])}
