"""Part "sweep": ``freebody sweep`` of random bodies on MuJoCo's Euler (identification on, as
always) with ``--jobs 1`` and ``--jobs 2``, against ``mujoco.rollout`` stepping the same bodies'
MuJoCo models (built by the adapter) in one call on one thread."""
from __future__ import annotations

import tempfile

from .config import SWEEP_DT, SWEEP_DURATION_S, BenchConfig
from .core import freebody_cmd, log, median, run_ok
from .maps import rollout_seconds

SWEEP_INTEGRATOR = "Euler"


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


def sweep(config: BenchConfig, progress: bool = False) -> dict:
    """The sweep command with --jobs 1 and --jobs 2, once each (they are long; each in a fresh
    output folder), and the rollout of the same bodies before each and ``repeats - 2`` times more
    (at least once); the rollout's median wall and CPU seconds."""
    from ...adapters.base import BENCH_YARDSTICK, is_available

    if not is_available(BENCH_YARDSTICK):
        return {"sweep_note": f"{BENCH_YARDSTICK} not installed"}
    n = config.sweep_count
    runs: dict[str, list] = {"1": [], "2": [], "rollout": []}
    for jobs in ("1", "2"):
        runs["rollout"].append(rollout_of_bodies(n))
        with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
            runs[jobs].append(run_ok(sweep_command(n, int(jobs), tmp), f"freebody sweep --jobs {jobs}"))
        log(f"sweep --jobs {jobs}: {runs[jobs][-1].wall_s:.1f} s", progress)
    runs["rollout"] += [rollout_of_bodies(n) for _ in range(max(config.repeats - 2, 1))]
    steps = int(round(SWEEP_DURATION_S / SWEEP_DT))
    w1, w2 = median([c.wall_s for c in runs["1"]]), median([c.wall_s for c in runs["2"]])
    roll_wall, roll_cpu = median([x[0] for x in runs["rollout"]]), median([x[1] for x in runs["rollout"]])
    return {"sweep_bodies": n, "sweep_steps": steps, "sweep_jobs1_wall_s": w1, "sweep_jobs2_wall_s": w2,
            "sweep_jobs1_cpu_s": median([c.cpu_s for c in runs["1"]]),
            "sweep_jobs2_cpu_s": median([c.cpu_s for c in runs["2"]]),
            "sweep_rollout_wall_s": roll_wall, "sweep_rollout_cpu_s": roll_cpu,
            "sweep_body_steps_per_s": n * steps / w1, "sweep_rollout_body_steps_per_s": n * steps / roll_wall,
            "sweep_jobs_gain": w1 / w2,
            "sweep_command": " ".join(["freebody"] + sweep_command(n, 1, "DIR")[3:])}
