"""Per-step cost of each compiled reference map (one body, as ``freebody run`` calls it) against one
MuJoCo ``mj_step`` of the same body, side by side, and the numba compilation cost.

    python scripts/bench_reference_maps.py [--steps N] [--repeats R] [--numpy-steps N]

The body is the dzhanibekov case (I = diag(1, 2, 3) kg m^2, w0 = (0.01, 5, 0) rad/s) at dt = 1e-3.
Each repeat times, in turn: MuJoCo's ``mj_step`` in a Python loop (with the qpos/qvel copies any user
needs, as ``freebody bench``'s bare loop), MuJoCo stepping N steps in one call (``nstep``: the
engine alone), then every reference map through ``reference_impl.integrators.simulate`` (whole
call: setup, compiled loop, output arrays), and the numpy loop of one map for scale.  Medians of
this process's CPU time (``time.process_time``: on a shared, loaded machine wall time also counts
the waits for a core); ``--wall`` times wall-clock instead.

Cold and warm start: a fresh interpreter with an empty NUMBA_CACHE_DIR (compiles and writes the
cache) and then another fresh interpreter on that cache (loads it), each timing ``import numba``
plus the first ``simulate`` of every map (10 steps).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

CASE, DT = "dzhanibekov", 1e-3

FIRST_CALLS = """
import time
t0, c0 = time.perf_counter(), time.process_time()
import numba
t1, c1 = time.perf_counter(), time.process_time()
from freebody.input.casefile import load_case
from freebody.reference_impl.integrators import INTEGRATORS, simulate
pb = load_case("dzhanibekov")
t2, c2 = time.perf_counter(), time.process_time()
for name in INTEGRATORS:
    simulate(pb, name, 1e-3, 10)
t3, c3 = time.perf_counter(), time.process_time()
print(t1 - t0, c1 - c0, t3 - t2, c3 - c2)
"""


def first_calls(cache_dir: str) -> list[float]:
    """[import numba, first simulate() of every map] as (wall, CPU) seconds each, in a fresh
    interpreter."""
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    out = subprocess.run([sys.executable, "-c", FIRST_CALLS], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    return [float(v) for v in out]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--numpy-steps", type=int, default=2_000)
    ap.add_argument("--wall", action="store_true", help="wall-clock time instead of CPU time")
    args = ap.parse_args(argv)
    clock = time.perf_counter if args.wall else time.process_time

    with tempfile.TemporaryDirectory() as cache:
        cold = first_calls(cache)
        warm = first_calls(cache)
    print(f"import numba: {cold[0]:.2f} s wall ({cold[1]:.2f} s CPU) cold, "
          f"{warm[0]:.2f} s wall ({warm[1]:.2f} s CPU) warm")
    from freebody.reference_impl.integrators import INTEGRATORS

    print(f"first simulate() of all {len(INTEGRATORS)} maps: {cold[2]:.2f} s wall ({cold[3]:.2f} s CPU) with an empty "
          f"cache (compile + write), {warm[2]:.2f} s wall ({warm[3]:.2f} s CPU) from the cache")

    import mujoco
    from freebody.adapters.base import load_adapter
    from freebody.input.casefile import load_case
    from freebody.reference_impl.integrators import INTEGRATORS, simulate

    pb = load_case(CASE)
    n = args.steps
    for name in INTEGRATORS:  # compile (or load from cache) outside the timing
        simulate(pb, name, DT, 10)
    mj_cls = load_adapter("mujoco")

    def mujoco_loop() -> float:
        a = mj_cls(pb, DT, "Euler")
        try:
            loop = a.bare_loop(n)
            t = clock()
            loop()
            return (clock() - t) / n
        finally:
            a.close()

    def mujoco_nstep() -> float:
        a = mj_cls(pb, DT, "Euler")
        try:
            t = clock()
            mujoco.mj_step(a.model, a.data, nstep=n)
            return (clock() - t) / n
        finally:
            a.close()

    def reference(name: str, steps: int, compiled: bool = True) -> float:
        t = clock()
        simulate(pb, name, DT, steps, compiled=compiled)
        return (clock() - t) / steps

    samples: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        samples.setdefault("mj_step (Python loop + copies)", []).append(mujoco_loop())
        samples.setdefault("mj_step (nstep, engine only)", []).append(mujoco_nstep())
        for name in INTEGRATORS:
            samples.setdefault(name, []).append(reference(name, n))
        samples.setdefault("semi-implicit-explicit-gyro, numpy loop", []).append(
            reference("semi-implicit-explicit-gyro", args.numpy_steps, compiled=False))
    med = {k: float(np.median(v)) for k, v in samples.items()}
    loop_mj, nstep_mj = med["mj_step (Python loop + copies)"], med["mj_step (nstep, engine only)"]
    print(f"\n{CASE}, dt = {DT}, {n} steps, median of {args.repeats}, "
          f"{'wall-clock' if args.wall else 'CPU'} time")
    print(f"{'':42s} {'per step':>10s} {'vs mj_step loop':>16s} {'vs mj_step nstep':>17s}")
    for k, v in med.items():
        print(f"{k:42s} {v * 1e9:8.0f} ns {loop_mj / v:15.1f}x {nstep_mj / v:16.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
