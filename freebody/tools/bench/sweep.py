"""Part "sweep": ``freebody sweep`` of random bodies on MuJoCo's Euler (identification on, as
always) with ``--jobs 1`` and ``--jobs 2``, interleaved, against ``mujoco.rollout`` stepping the
same bodies' MuJoCo models (built by the adapter) in one call on one thread."""
from __future__ import annotations

import tempfile

from .config import SWEEP_DT, SWEEP_DURATION_S, BenchConfig
from .core import freebody_cmd, log, median, run_ok
from .maps import rollout_seconds

SWEEP_INTEGRATOR = "Euler"
SWEEP_PAIRS_MAX = 3  # interleaved (--jobs 1, --jobs 2) pairs of a full bench: medians of three


def sweep_command(count: int, jobs: int, out: str) -> list[str]:
    """``freebody sweep`` of ``count`` bodies (seed 0) on the yardstick engine's Euler at
    SWEEP_DT for SWEEP_DURATION_S."""
    from ...adapters.base import BENCH_YARDSTICK

    return freebody_cmd("sweep", "--count", str(count), "--engine", BENCH_YARDSTICK,
                        "--integrator", SWEEP_INTEGRATOR, "--dt", repr(SWEEP_DT),
                        "--duration", repr(SWEEP_DURATION_S), "--jobs", str(jobs), "--quiet",
                        "--out", out)


def rollout_of_bodies(count: int) -> tuple[float, float]:
    """(wall s, CPU s) of ``mujoco.rollout`` stepping the sweep's ``count`` bodies (the same
    draws: ``tools.sweep.random_bodies``) on the yardstick's Euler for the sweep's steps, all
    models in one call on one thread; the worlds are built before the clock."""
    import time

    from ...adapters.base import BENCH_YARDSTICK, load_adapter
    from ..sweep import SweepSettings, random_bodies

    settings = SweepSettings(seed=0, count=count, duration=SWEEP_DURATION_S, dts=(SWEEP_DT,))
    cls = load_adapter(BENCH_YARDSTICK)
    adapters = [cls(b.problem, SWEEP_DT, SWEEP_INTEGRATOR) for b in random_bodies(settings)]
    try:
        steps = int(round(SWEEP_DURATION_S / SWEEP_DT))
        c0 = time.process_time()
        wall = rollout_seconds([a.model for a in adapters], [a.data for a in adapters], steps)
        return wall, time.process_time() - c0
    finally:
        for a in adapters:
            a.close()


def sweep_pairs(config: BenchConfig) -> int:
    """How many (``--jobs 1``, ``--jobs 2``) pairs the bench times: one with ``--quick`` (not
    judged), else ``repeats``, at most SWEEP_PAIRS_MAX (a full pair is about 20 s on two quiet
    cores), at least one."""
    return 1 if config.quick else max(1, min(config.repeats, SWEEP_PAIRS_MAX))


def sweep(config: BenchConfig, progress: bool = False) -> dict:
    """The sweep command with --jobs 1 then --jobs 2, interleaved, :func:`sweep_pairs` times (each
    in a fresh output folder), and the rollout of the same bodies before each pair and once more;
    medians.  The --jobs gain is the median of each pair's ratio (the two sweeps side by side, as
    the machine's load was then); the load average before and after says how shared the two cores
    were (a gain needs two free cores)."""
    import os

    from ...adapters.base import BENCH_YARDSTICK, is_available

    if not is_available(BENCH_YARDSTICK):
        return {"sweep_note": f"{BENCH_YARDSTICK} not installed"}
    n = config.sweep_count
    runs: dict[str, list] = {"1": [], "2": [], "rollout": []}
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    for _ in range(sweep_pairs(config)):
        runs["rollout"].append(rollout_of_bodies(n))
        for jobs in ("1", "2"):
            with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
                runs[jobs].append(run_ok(sweep_command(n, int(jobs), tmp), f"freebody sweep --jobs {jobs}"))
            log(f"sweep --jobs {jobs}: {runs[jobs][-1].wall_s:.1f} s", progress)
    runs["rollout"].append(rollout_of_bodies(n))
    steps = int(round(SWEEP_DURATION_S / SWEEP_DT))
    w1, w2 = median([c.wall_s for c in runs["1"]]), median([c.wall_s for c in runs["2"]])
    roll_wall, roll_cpu = median([x[0] for x in runs["rollout"]]), median([x[1] for x in runs["rollout"]])
    return {"sweep_bodies": n, "sweep_steps": steps, "sweep_jobs1_wall_s": w1, "sweep_jobs2_wall_s": w2,
            "sweep_jobs1_cpu_s": median([c.cpu_s for c in runs["1"]]),
            "sweep_jobs2_cpu_s": median([c.cpu_s for c in runs["2"]]),
            "sweep_rollout_wall_s": roll_wall, "sweep_rollout_cpu_s": roll_cpu,
            "sweep_body_steps_per_s": n * steps / w1, "sweep_rollout_body_steps_per_s": n * steps / roll_wall,
            "sweep_jobs_gain": median([a.wall_s / b.wall_s for a, b in zip(runs["1"], runs["2"])]),
            "sweep_pairs": len(runs["1"]),
            "sweep_load_avg": [load_before, os.getloadavg()[0] if load_before is not None else None],
            "sweep_command": " ".join(["freebody"] + sweep_command(n, 1, "DIR")[3:])}
