"""``freebody bench``: how fast freebody is on the paths users take, next to the engines it drives.

Everything is measured side by side in one run, each figure the median over repeats (the machine
may be shared and noisy; the repeats of the things compared are interleaved, so a drift of the
machine's load hits both sides alike), and every target is a ratio or a bound checked in the same
run (:class:`Check`: PASS, MISS, or n/a when not evaluated):

a. **Reference maps, one body** (:func:`reference_maps`): each reference integrator as ``freebody
   run`` steps it (``reference_impl.integrators.simulate``, the numba-compiled maps of
   ``reference_impl/compiled.py``), seconds per step (the call's one-off set-up, timed with zero
   steps, subtracted), against one step of the yardstick engine (``adapters.base.BENCH_YARDSTICK``,
   MuJoCo: its ``Adapter.bare_loop``, ``mj_step`` plus the qpos/qvel copies) on the same body.
   Target: the engines' semi-implicit maps >= 10x faster per step.
b. **One long run through the whole command** (:func:`long_run`): ``freebody run`` of
   :data:`LONG_RUN_CASE` on MuJoCo ``Euler`` for 50,000 steps (report off, scheme identification
   on, in a fresh subprocess with a fresh output folder: no cache from earlier invocations but
   numba's on-disk cache of the compiled maps, which is per machine) minus the same command at 10
   steps (start-up, imports, writing), against MuJoCo's bare stepping of 50,000 steps of the same
   body (its bare loop, in this process).  Target: <= 3 x bare + 1 s.
c. **The suite, serial and parallel** (:func:`suite_timing`): the wall time of ``freebody run``
   (report included: the command as users run it) on a PINNED run list, :data:`PINNED_SUITE_CASES`
   x :data:`PINNED_SUITE_INTEGRATORS` (the default suite without MJX when it was pinned, 525 runs),
   so that later growth of the default suite does not change the benchmark; ``--jobs 1`` and
   ``--jobs max(2, cores)``, interleaved, ``--suite-repeats`` times (default 3; medians).  Target:
   the parallel run <= 45 s.  Before timing, the list the
   command expands to is checked against the pinned one (a case whose time steps or length changed
   since is named in the note, and the targets of c and d are then not evaluated).
d. **Output sizes** of that suite run: the trajectory folder's total and report.html.  Targets:
   <= 50 MB and <= 4 MB (10^6 bytes).
e. **Peak RSS of a long run** (:func:`peak_rss`): ``ru_maxrss`` of the long-run command of b at
   ``--rss-steps`` steps (default 10^6; 10^5 with ``--quick``), the largest of the command's
   processes (worker processes included; read by a small wrapper interpreter, see
   :func:`run_child`), beside that of b's 10-step command.  Target: <= 1 GB for 10^7 steps; a
   shorter run over 1 GB misses it (a longer run needs at least as much), one under it is not
   judged (memory need not grow linearly with the steps, so it is not extrapolated).

Beside them, as before (schema 1):

1. Engine overhead, per registered engine (a missing one, or one whose adapter declares no bare
   loop, is listed under ``skipped`` with the reason): the adapter's ``bare_loop`` for N steps
   against freebody's ``adapter.simulate(N)`` on the same engine world.  Target <= 1.3x.

(Schema 2 had a part 2, the reference integrators batched over B bodies: their module was removed
with schema 3, being on no path users take; the numba-compiled single-body maps of a are faster
on a sweep's batches.)

The result is one JSON document (schema version :data:`SCHEMA_VERSION`) and a text summary: the
table of checks first, then the figures behind them.
"""
from __future__ import annotations

import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..results.document import document_header, load_results

# 2: the checks of issue 15 (a-e: "checks", "reference_map_*", "long_run_*", "rss_*",
#    "suite_pinned_*", "suite_*_bytes"); the suite is the pinned list with its report; every key
#    of version 1 is still written with its meaning (suite_* now time the pinned suite).
# 3: part 2 (batched reference integrators) removed with reference_impl/batched.py: no
#    "reference_body_step_s", "reference_speedup_vs_mujoco", "mujoco_body_step_s", "batch_steps",
#    "batch_note", no targets "batch_speedup_min", "batch_size"; every other key as in 2.
SCHEMA_VERSION = 3

CASE = "dzhanibekov"             # torque-free, no gravity, no loads: the engines' bare step
DT = 0.001                       # s

# --- targets ---------------------------------------------------------------------------------------
# issue 15
TARGET_MAP_SPEEDUP = 10.0        # a. one body: semi-implicit maps >= 10 x faster per step than mj_step
ENGINE_EQUIVALENT_MAPS = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")
LONG_RUN_STEPS = 50_000          # b. the long run's steps ...
SHORT_RUN_STEPS = 10             # ... minus the same command at this many steps
LONG_RUN_INTEGRATOR = "Euler"    # MuJoCo's Euler: identified against the reference maps
# b and e: a uniform rotation (isotropic inertia, no loads) stays bounded however long it runs
# (dzhanibekov diverges under MuJoCo's Euler after about 1.5e6 steps of 1 ms)
LONG_RUN_CASE = "spinning_sphere"
TARGET_LONG_RUN_FACTOR = 3.0     # b. long - short <= 3 x bare stepping ...
TARGET_LONG_RUN_SLACK_S = 1.0    # ... + 1 s
TARGET_SUITE_S = 45.0            # c. the pinned suite, parallel, wall s
TARGET_TRAJECTORIES_BYTES = 50e6  # d. trajectory folder of the pinned suite
TARGET_REPORT_HTML_BYTES = 4e6   # d. its report.html
TARGET_RSS_BYTES = 1e9           # e. peak RSS of a run of TARGET_RSS_STEPS steps
TARGET_RSS_STEPS = 10**7
DEFAULT_RSS_STEPS = 10**6       # a 1e7-step run may need many GB while the target is missed
QUICK_RSS_STEPS = 10**5
# issue 6
TARGET_OVERHEAD_RATIO = 1.3      # freebody's engine loop at most 1.3 x the bare loop

# --- the pinned suite (c, d) -----------------------------------------------------------------------
# The default suite without MJX (`freebody run --engine reference --engine mujoco --engine pybullet
# --engine dart`) as it was when pinned (2026-11-27): 20 bundled cases, each at its time steps
# (dt s, steps), x the engines' integrators, float64: 35 (case, dt) x 15 = 525 runs.  New cases,
# engines or integrators do not enter it; tests/test_bench.py checks it against the default suite.
PINNED_SUITE_CASES: dict[str, tuple[tuple[float, int], ...]] = {
    "body_torque_spinup": ((0.01, 200), (0.001, 2000)),
    "dzhanibekov": ((0.01, 1000), (0.001, 10000)),
    "dzhanibekov_rotated": ((0.01, 1000), (0.001, 10000)),
    "far_from_origin": ((0.01, 200), (0.001, 2000)),
    "flat_plate": ((0.01, 500), (0.001, 5000)),
    "gazebo_boxes_complex": ((0.001, 10000),),
    "gazebo_boxes_simple": ((0.001, 10000),),
    "high_spin_dt_10ms": ((0.01, 200),),
    "high_spin_dt_1ms": ((0.001, 1000),),
    "long_horizon": ((0.001, 100000),),
    "offset_push": ((0.01, 200), (0.001, 2000)),
    "projectile": ((0.01, 200), (0.001, 2000)),
    "quiz": ((0.1, 2), (0.01, 2)),
    "spinning_sphere": ((0.01, 200), (0.001, 2000)),
    "stable_major_axis": ((0.01, 1000), (0.001, 10000)),
    "stable_minor_axis": ((0.01, 500), (0.001, 5000)),
    "symmetric_top": ((0.01, 500), (0.001, 5000)),
    "t_handle": ((0.01, 1000), (0.001, 10000)),
    "thin_rod": ((0.01, 500), (0.001, 5000)),
    "world_torque": ((0.01, 200), (0.001, 2000)),
}
PINNED_SUITE_INTEGRATORS: dict[str, tuple[str, ...]] = {
    "reference": ("euler-matrix", "euler-matrix-gs", "euler-quat", "lie-euler",
                  "semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro", "rk4"),
    "mujoco": ("Euler", "RK4", "implicit", "implicitfast", "discrete"),
    "pybullet": ("multibody", "maximal"),
    "dart": ("semi-implicit-euler",),
}
PINNED_SUITE_PRECISION = "float64"
PINNED_SUITE_RUNS = 525
# --quick: two of the pinned cases (4 (case, dt) x 15 = 60 short runs): the same command, a smoke
# test of its scaling; the targets of c and d are not evaluated on it.
QUICK_SUITE_CASES = ("projectile", "quiz")

MB = 1e6


@dataclass(frozen=True)
class BenchConfig:
    """What one ``freebody bench`` measures.

    engine_steps : steps of each engine loop (1).
    map_steps : steps of each reference-map call and of the yardstick loop it is compared with (a).
    repeats : repeats of every in-process measurement and of b's commands (medians are quoted).
    suite : run the suite part (c, d).  suite_cases : its cases (the pinned ones, or a quick slice).
    suite_repeats : repeats of the serial and the parallel suite command (interleaved).
    rss_steps : steps of the run whose peak RSS is measured (e); 0: not measured.
    """

    engine_steps: int
    map_steps: int
    repeats: int
    suite: bool
    suite_cases: tuple[str, ...]
    suite_repeats: int
    rss_steps: int
    quick: bool

    @classmethod
    def make(cls, quick: bool, repeats: int | None = None, suite: bool = True,
             rss_steps: int | None = None, suite_repeats: int | None = None) -> "BenchConfig":
        if quick:
            return cls(engine_steps=500, map_steps=20_000, repeats=repeats or 3, suite=suite,
                       suite_cases=QUICK_SUITE_CASES, suite_repeats=suite_repeats or 1,
                       rss_steps=QUICK_RSS_STEPS if rss_steps is None else rss_steps, quick=True)
        return cls(engine_steps=20000, map_steps=200_000, repeats=repeats or 7, suite=suite,
                   suite_cases=tuple(PINNED_SUITE_CASES), suite_repeats=suite_repeats or 3,
                   rss_steps=DEFAULT_RSS_STEPS if rss_steps is None else rss_steps, quick=False)


# --- checks ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    """One target of the table: ``value op limit`` (both in ``unit``).

    passed : True (PASS), False (MISS), None (n/a: not measured, or not evaluated, e.g. in quick
    mode; ``note`` says why).  detail : the figures behind ``value``, for the reader.
    """

    key: str
    label: str
    value: float | None
    op: str
    limit: float | None
    unit: str
    passed: bool | None
    detail: str = ""
    note: str = ""

    @property
    def status(self) -> str:
        return {True: "PASS", False: "MISS", None: "n/a"}[self.passed]


def meets(value: float | None, op: str, limit: float | None) -> bool | None:
    """Whether ``value op limit`` holds (op ``<=`` or ``>=``); None when either is missing or not
    a finite number (nothing to judge)."""
    if op not in ("<=", ">="):
        raise ValueError(f"op must be '<=' or '>=', got {op!r}")
    if value is None or limit is None or not (math.isfinite(value) and math.isfinite(limit)):
        return None
    return value <= limit if op == "<=" else value >= limit


def make_check(key: str, label: str, value: float | None, op: str, limit: float | None, unit: str,
               detail: str = "", note: str = "", evaluate: bool = True) -> Check:
    """A :class:`Check` judged by :func:`meets` (``evaluate`` False: n/a, with ``note``)."""
    return Check(key, label, value, op, limit, unit, meets(value, op, limit) if evaluate else None,
                 detail, note)


def long_run_limit(bare_s: float) -> float:
    """b's bound: TARGET_LONG_RUN_FACTOR x MuJoCo's bare stepping + TARGET_LONG_RUN_SLACK_S (s)."""
    return TARGET_LONG_RUN_FACTOR * bare_s + TARGET_LONG_RUN_SLACK_S


def _log(msg: str, progress: bool) -> None:
    if progress:
        sys.stderr.write(f"bench: {msg}\n")
        sys.stderr.flush()


def _timed(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _median(xs) -> float:
    return float(np.median(xs))


# --- child processes --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Child:
    """A finished child process: wall seconds, exit code, peak RSS in bytes (None where the
    platform cannot tell) and the last lines of its stderr."""

    wall_s: float
    returncode: int
    maxrss_bytes: int | None
    stderr_tail: str


# Runs the command given as its arguments and prints "wall_s returncode ru_maxrss" of it.  The peak
# RSS is read here, in a small interpreter, and not by the benchmark: a child forked from the
# benchmark (hundreds of MB of engines and compiled maps) would count the benchmark's own pages in
# its ru_maxrss until it execs.  RUSAGE_CHILDREN covers the command and its reaped descendants
# (freebody's worker processes): the largest one's peak.
_CHILD_WRAPPER = """
import subprocess, sys, time
t0 = time.perf_counter()
rc = subprocess.call(sys.argv[1:], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
wall = time.perf_counter() - t0
try:
    import resource
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
except ImportError:
    rss = -1
print(wall, rc, rss)
"""


def run_child(cmd: list[str]) -> Child:
    """Run ``cmd`` (stdout discarded, stderr kept in a temporary file so that no pipe can fill up)
    through :data:`_CHILD_WRAPPER`: its wall time, exit code and peak RSS (``ru_maxrss``: KiB on
    Linux, bytes on macOS)."""
    with tempfile.TemporaryFile() as err:
        proc = subprocess.run([sys.executable, "-c", _CHILD_WRAPPER, *cmd], stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=err, text=True, check=False)
        err.seek(0)
        tail = "\n".join(err.read().decode("utf-8", "replace").strip().splitlines()[-3:])
    try:
        wall, rc, rss = proc.stdout.split()
    except ValueError:
        raise RuntimeError(f"the timing wrapper failed (exit {proc.returncode}): {tail}") from None
    rss_bytes = None if int(rss) < 0 else int(rss) * (1 if sys.platform == "darwin" else 1024)
    return Child(float(wall), int(rc), rss_bytes, tail)


def _freebody(*args: str) -> list[str]:
    """The command line of ``freebody ARGS`` in this interpreter."""
    return [sys.executable, "-m", "freebody", *args]


# --- 1. engine overhead ---------------------------------------------------------------------------

class NoBareLoop(Exception):
    """The engine's adapter offers no bare loop: its overhead cannot be measured."""


def engine_overhead(engine: str, steps: int, repeats: int, progress: bool = False) -> dict:
    """Bare engine loop vs ``adapter.simulate(steps)``, interleaved ``repeats`` times.

    Returns {"bare_step_s", "freebody_step_s", "overhead_ratio", "integrator", "steps",
    "repeats"}: medians, seconds per step.
    """
    from ..adapters.base import load_adapter
    from ..input.casefile import load_case

    cls = load_adapter(engine)
    problem = load_case(CASE)
    integrator = cls.offered_integrators()[0]
    bare, ours = [], []
    for r in range(repeats):
        a = cls(problem, DT, integrator)
        try:
            loop = a.bare_loop(steps)
            if loop is None:
                raise NoBareLoop(f"{engine} declares no bare loop (Adapter.bare_loop)")
            bare.append(_timed(loop) / steps)
        finally:
            a.close()
        b = cls(problem, DT, integrator)
        try:
            ours.append(_timed(lambda: b.simulate(steps)) / steps)
        finally:
            b.close()
        _log(f"{engine} repeat {r + 1}/{repeats}: bare {bare[-1] * 1e6:.2f} us/step, "
             f"freebody {ours[-1] * 1e6:.2f} us/step", progress)
    b_med, o_med = _median(bare), _median(ours)
    return {"integrator": integrator, "steps": steps, "repeats": repeats, "bare_step_s": b_med,
            "freebody_step_s": o_med, "overhead_ratio": o_med / b_med}


# --- the yardstick ----------------------------------------------------------------------------------

def yardstick_step(steps: int, integrator: str | None = None, case: str = CASE) -> Callable[[], float]:
    """A timer of the yardstick engine's bare loop (``BENCH_YARDSTICK``'s ``Adapter.bare_loop``:
    its own step and state copies) on the case's world, built afresh, untimed, by the adapter on
    every call: returns seconds per step.  integrator : the engine's (default: its first)."""
    from ..adapters.base import BENCH_YARDSTICK, load_adapter
    from ..input.casefile import load_case

    cls, problem = load_adapter(BENCH_YARDSTICK), load_case(case)
    integrator = integrator or cls.offered_integrators()[0]

    def timer() -> float:
        a = cls(problem, DT, integrator)
        try:
            loop = a.bare_loop(steps)
            if loop is None:
                raise NoBareLoop(f"{BENCH_YARDSTICK} declares no bare loop")
            return _timed(loop) / steps
        finally:
            a.close()
    return timer


def _yardstick_or_note(steps: int, integrator: str | None = None, case: str = CASE):
    """(timer, None), or (None, why) when the yardstick engine is missing or broken."""
    from ..adapters.base import BENCH_YARDSTICK

    try:
        timer = yardstick_step(steps, integrator, case)
        timer_probe = yardstick_step(1, integrator, case)
        timer_probe()  # builds a world and steps once: a broken engine shows here
    except Exception as e:
        return None, f"{BENCH_YARDSTICK} unavailable: {type(e).__name__}: {e}"
    return timer, None


# --- a. reference maps, one body --------------------------------------------------------------------

def reference_maps(config: BenchConfig, progress: bool = False) -> dict:
    """Seconds per step of every reference map on one body through ``integrators.simulate`` (the
    compiled maps, as ``freebody run`` uses them) and of the yardstick's bare loop, interleaved.

    Per step = (median of a ``map_steps`` call - median of a zero-step call) / map_steps, floored
    at a tenth of the raw figure against noise; the compiled code is loaded (numba's disk cache, or
    compiled) by an untimed first call.
    """
    from ..input.casefile import load_case
    from ..reference_impl.integrators import INTEGRATORS, simulate

    problem, n = load_case(CASE), config.map_steps
    t_first = {}
    for name in INTEGRATORS:  # load (or compile) each map outside the timing
        t_first[name] = _timed(lambda: simulate(problem, name, DT, 10))
    mj_timer, mj_note = _yardstick_or_note(n)
    mj: list[float] = []
    calls: dict[str, list[float]] = {name: [] for name in INTEGRATORS}
    setups: dict[str, list[float]] = {name: [] for name in INTEGRATORS}
    for r in range(config.repeats):
        if mj_timer is not None:
            mj.append(mj_timer())
        for name in INTEGRATORS:
            setups[name].append(_timed(lambda: simulate(problem, name, DT, 0)))
            calls[name].append(_timed(lambda: simulate(problem, name, DT, n)))
        _log(f"reference maps repeat {r + 1}/{config.repeats}"
             + (f": mj_step {mj[-1] * 1e6:.2f} us" if mj else ""), progress)
    step_s = {}
    for name in INTEGRATORS:
        raw = _median(calls[name])
        step_s[name] = max(raw - _median(setups[name]), 0.1 * raw) / n
    out = {"reference_map_steps": n, "reference_map_step_s": step_s,
           "reference_map_call_s": {name: _median(v) for name, v in calls.items()},
           "reference_map_first_call_s": t_first}
    if mj:
        mj_med = _median(mj)
        out["reference_map_mujoco_step_s"] = mj_med
        out["reference_map_speedup_vs_mujoco"] = {name: mj_med / s for name, s in step_s.items()}
    else:
        out["reference_map_mujoco_note"] = mj_note
    return out


# --- b. one long run through the command line, e. its peak RSS --------------------------------------

def long_run_command(steps: int, out: str) -> list[str]:
    """``freebody run`` of the case on the yardstick engine's Euler for ``steps`` steps of DT,
    report off (scheme identification is on in every run of an engine other than the reference)."""
    from ..adapters.base import BENCH_YARDSTICK

    return _freebody("run", LONG_RUN_CASE, "--engine", BENCH_YARDSTICK, "--integrator", LONG_RUN_INTEGRATOR,
                     "--dt", repr(DT), "--duration", repr(steps * DT), "--no-report", "--quiet",
                     "--out", out)


def _run_once(steps: int) -> Child:
    """One long-run command in a fresh output folder; RuntimeError unless it ran ``steps`` steps,
    ended ok and identified a scheme."""
    with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
        child = run_child(long_run_command(steps, tmp))
        if child.returncode != 0:
            raise RuntimeError(f"freebody run ({steps} steps) exited {child.returncode}: "
                               f"{child.stderr_tail}")
        runs = load_results(Path(tmp))["runs"]
    if len(runs) != 1 or runs[0]["steps"] != steps or runs[0]["status"] != "ok":
        got = "; ".join(f"{r['status']} {r['steps']} steps {r.get('message') or ''}"[:200] for r in runs)
        raise RuntimeError(f"freebody run ({steps} steps) did not give one ok run of {steps} "
                           f"steps: {got}")
    if not runs[0].get("matches_reference"):
        raise RuntimeError("freebody run did not identify the run's scheme (matches_reference)")
    return child


def long_run(config: BenchConfig, progress: bool = False) -> dict:
    """b: the long-run command at LONG_RUN_STEPS and SHORT_RUN_STEPS steps and the yardstick's bare
    loop of LONG_RUN_STEPS steps, interleaved ``repeats`` times; medians."""
    from ..adapters.base import BENCH_YARDSTICK, is_available

    if not is_available(BENCH_YARDSTICK):
        return {"long_run_note": f"{BENCH_YARDSTICK} not installed"}
    timer, note = _yardstick_or_note(LONG_RUN_STEPS, LONG_RUN_INTEGRATOR, LONG_RUN_CASE)
    if timer is None:
        return {"long_run_note": note}
    longs, shorts, bares = [], [], []
    for r in range(config.repeats):
        shorts.append(_run_once(SHORT_RUN_STEPS))
        longs.append(_run_once(LONG_RUN_STEPS))
        bares.append(timer() * LONG_RUN_STEPS)
        _log(f"long run repeat {r + 1}/{config.repeats}: {LONG_RUN_STEPS} steps {longs[-1].wall_s:.2f} s, "
             f"{SHORT_RUN_STEPS} steps {shorts[-1].wall_s:.2f} s, bare {bares[-1]:.3f} s", progress)
    long_s, short_s, bare_s = (_median([c.wall_s for c in longs]), _median([c.wall_s for c in shorts]),
                               _median(bares))
    out = {"long_run_case": LONG_RUN_CASE, "long_run_steps": LONG_RUN_STEPS, "short_run_steps": SHORT_RUN_STEPS,
           "long_run_command": " ".join(["freebody"] + long_run_command(LONG_RUN_STEPS, "DIR")[3:]),
           "long_run_s": long_s, "short_run_s": short_s, "long_run_extra_s": long_s - short_s,
           "long_run_bare_s": bare_s, "long_run_limit_s": long_run_limit(bare_s)}
    rss = [c.maxrss_bytes for c in shorts + longs]
    if None not in rss:
        out["short_run_rss_bytes"] = _median([c.maxrss_bytes for c in shorts])
        out["long_run_rss_bytes"] = _median([c.maxrss_bytes for c in longs])
    return out


def peak_rss(config: BenchConfig, progress: bool = False) -> dict:
    """e: peak RSS (and wall time) of one long-run command of ``config.rss_steps`` steps."""
    from ..adapters.base import BENCH_YARDSTICK, is_available

    if config.rss_steps <= 0:
        return {"rss_note": "not measured (--rss-steps 0)"}
    if not is_available(BENCH_YARDSTICK):
        return {"rss_note": f"{BENCH_YARDSTICK} not installed"}
    _log(f"peak RSS: freebody run of {config.rss_steps} steps", progress)
    child = _run_once(config.rss_steps)
    if child.maxrss_bytes is None:  # pragma: no cover (no resource module)
        return {"rss_note": "peak RSS not available on this platform (no resource module)"}
    return {"rss_steps": config.rss_steps, "rss_bytes": child.maxrss_bytes, "rss_run_s": child.wall_s}


# --- c, d. the pinned suite, serial and parallel -------------------------------------------------------

def pinned_suite_runs(cases=None) -> list[tuple[str, str, str, str, float, int]]:
    """The pinned run list as (case, engine, integrator, precision, dt, steps), in ``freebody
    run``'s order (case, dt, engine, integrator, precision); ``cases``: a subset of the pinned
    cases (default all)."""
    out = []
    for case in cases or PINNED_SUITE_CASES:
        for dt, steps in PINNED_SUITE_CASES[case]:
            for engine, integrators in PINNED_SUITE_INTEGRATORS.items():
                for integ in integrators:
                    out.append((case, engine, integ, PINNED_SUITE_PRECISION, dt, steps))
    return out


def pinned_suite_args(cases=None) -> list[str]:
    """``freebody run`` arguments selecting the pinned list (or its runs of ``cases``): the cases by
    name, each engine, each integrator as ENGINE:NAME, the precision."""
    args = list(cases or PINNED_SUITE_CASES)
    for engine in PINNED_SUITE_INTEGRATORS:
        args += ["--engine", engine]
    for engine, integrators in PINNED_SUITE_INTEGRATORS.items():
        for integ in integrators:
            args += ["--integrator", f"{engine}:{integ}"]
    return args + ["--precision", PINNED_SUITE_PRECISION]


def expanded_runs(args: list[str]) -> list[tuple[str, str, str, str, float, int]]:
    """The runs ``freebody run ARGS`` would run, as :func:`pinned_suite_runs` lists them, by the
    same parsing and expansion as the command (an engine not installed lists integrator ``*``)."""
    from ..cli import build_parser
    from ..input.casefile import load_case
    from ..run import expand, select_engines

    a = build_parser().parse_args(["run", *args])
    problems = [load_case(n) for n in a.cases]
    specs = expand(problems, select_engines(a.engine), a.integrator, a.dt, a.duration, a.precision,
                   sources=list(a.cases))
    return [(s.problem.name, s.engine, s.integrator, s.precision, float(s.dt), int(s.steps))
            for s in specs]


def pinned_suite_differences(cases=None) -> list[str]:
    """How the runs the pinned command expands to today differ from the pinned list (empty when
    they are the same): at most a few lines, each naming runs missing or added."""
    want = pinned_suite_runs(cases)
    try:
        have = expanded_runs(pinned_suite_args(cases))
    except (Exception, SystemExit) as e:  # a pinned case or integrator no longer exists
        return [f"the pinned command no longer expands: {type(e).__name__}: {e}"]
    if have == want:
        return []
    out = []
    missing = [r for r in want if r not in set(have)]
    added = [r for r in have if r not in set(want)]

    def show(rs):
        return "; ".join("/".join(str(v) for v in r) for r in rs[:3]) + (" ..." if len(rs) > 3 else "")
    if missing:
        out.append(f"{len(missing)} pinned runs not in today's list: {show(missing)}")
    if added:
        out.append(f"{len(added)} runs not pinned: {show(added)}")
    if not out:
        out.append("same runs in another order")
    return out


def folder_bytes(folder: Path) -> int:
    """Total size in bytes of the regular files under ``folder`` (0 if it does not exist)."""
    if not folder.is_dir():
        return 0
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def suite_timing(config: BenchConfig, progress: bool = False) -> dict:
    """c, d: wall time of ``freebody run`` on the pinned list (report included) with --jobs 1 and
    --jobs max(2, cores), each in a subprocess with a fresh output folder; the sizes of the
    parallel run's output."""
    from ..run.suite import default_jobs

    cases = config.suite_cases
    runs = pinned_suite_runs(cases)
    diffs = pinned_suite_differences(cases)
    jobs = max(2, default_jobs())
    args = pinned_suite_args(cases)
    out: dict = {"suite_cores": os.cpu_count(), "suite_jobs": jobs, "suite_runs": len(runs),
                 "suite_pinned": not config.quick, "suite_cases": list(cases),
                 "suite_pinned_differences": diffs,
                 "suite_args": ["--quiet"] + args}

    def wall(jobs: int) -> tuple[Child, dict]:
        with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
            child = run_child(_freebody("run", *args, "--quiet", "--out", tmp, "--jobs", str(jobs)))
            if child.returncode not in (0, 1):  # 1: some run failed, the suite still ran
                raise RuntimeError(f"freebody run exited {child.returncode}: {child.stderr_tail}")
            sizes = {"suite_trajectories_bytes": folder_bytes(Path(tmp) / "trajectories"),
                     "suite_report_html_bytes": _size(Path(tmp) / "report.html"),
                     "suite_report_md_bytes": _size(Path(tmp) / "report.md"),
                     "suite_results_json_bytes": _size(Path(tmp) / "results.json")}
        return child, sizes

    what = "pinned suite" if not config.quick else f"quick suite ({', '.join(cases)})"
    serial: list[Child] = []
    parallel: list[Child] = []
    n = config.suite_repeats
    for r in range(n):
        _log(f"{what}, {len(runs)} runs, repeat {r + 1}/{n}: freebody run ... --jobs 1", progress)
        serial.append(wall(1)[0])
        _log(f"{what}: serial {serial[-1].wall_s:.1f} s; --jobs {jobs}", progress)
        child, sizes = wall(jobs)
        parallel.append(child)
        _log(f"{what}: parallel {parallel[-1].wall_s:.1f} s", progress)
    out.update(sizes)  # of the last parallel run
    serial_s, parallel_s = _median([c.wall_s for c in serial]), _median([c.wall_s for c in parallel])
    out.update(suite_serial_s=serial_s, suite_parallel_s=parallel_s,
               suite_speedup=serial_s / parallel_s, suite_repeats=n,
               suite_serial_all_s=[c.wall_s for c in serial],
               suite_parallel_all_s=[c.wall_s for c in parallel],
               suite_exit_code=max(c.returncode for c in serial + parallel),
               suite_serial_rss_bytes=max(c.maxrss_bytes or 0 for c in serial) or None,
               suite_parallel_rss_bytes=max(c.maxrss_bytes or 0 for c in parallel) or None,
               suite_note=(f"wall time of freebody run (report included), --jobs 1 vs --jobs {jobs} "
                           f"({os.cpu_count()} cores), {len(runs)} runs, median of {n}"
                           + ("" if not config.quick else "; --quick: not the pinned list")
                           + ("" if not diffs else "; differs from the pinned list: "
                              + " | ".join(diffs))))
    return out


def _size(path: Path) -> int | None:
    return path.stat().st_size if path.is_file() else None


# --- the whole benchmark --------------------------------------------------------------------------

def _guarded(part: str, fn: Callable[[], dict], progress: bool) -> dict:
    """One part's figures, or {part_note: why} when it fails (the others still run)."""
    try:
        return fn()
    except Exception as e:
        _log(f"{part}: failed: {type(e).__name__}: {e}", progress)
        return {f"{part}_note": f"failed: {type(e).__name__}: {e}"}


def run_bench(config: BenchConfig, progress: bool = False) -> dict:
    """Every measurement as one JSON-ready document (schema :data:`SCHEMA_VERSION`), with its
    checks (:func:`checks`) under ``"checks"``."""
    from ..adapters.base import EngineMissing, engine_names, is_available, load_adapter

    versions: dict[str, str | None] = {}
    overhead: dict[str, float] = {}
    engine_steps: dict[str, dict] = {}
    skipped: dict[str, str] = {}
    for engine in engine_names():
        if not is_available(engine):
            skipped[engine] = "not installed"
            versions[engine] = None
            _log(f"{engine}: skipped (not installed)", progress)
            continue
        try:
            versions[engine] = load_adapter(engine).engine_version()
            res = engine_overhead(engine, config.engine_steps, config.repeats, progress)
        except (EngineMissing, NoBareLoop) as e:
            skipped[engine] = str(e)
            _log(f"{engine}: skipped ({e})", progress)
            continue
        except Exception as e:  # a broken engine is reported, not a crash of the benchmark
            skipped[engine] = f"failed: {type(e).__name__}: {e}"
            _log(f"{engine}: {skipped[engine]}", progress)
            continue
        overhead[engine] = res["overhead_ratio"]
        engine_steps[engine] = res
    doc = document_header(
        SCHEMA_VERSION, versions,
        platform=platform.platform(),  # the detailed OS string: timings depend on it
        python=platform.python_version(),
        numpy=np.__version__,
        cores=os.cpu_count(),
        load_average=list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        quick=config.quick,
        repeats=config.repeats,
        case=CASE,
        dt=DT,
        engine_steps=config.engine_steps,
        overhead_ratio=overhead,
        engine_step_s=engine_steps,
        skipped=skipped,
        targets={"overhead_ratio_max": TARGET_OVERHEAD_RATIO,
                 "engine_equivalent_maps": list(ENGINE_EQUIVALENT_MAPS),
                 "map_speedup_min": TARGET_MAP_SPEEDUP,
                 "long_run_factor": TARGET_LONG_RUN_FACTOR,
                 "long_run_slack_s": TARGET_LONG_RUN_SLACK_S,
                 "suite_parallel_max_s": TARGET_SUITE_S,
                 "trajectories_max_bytes": TARGET_TRAJECTORIES_BYTES,
                 "report_html_max_bytes": TARGET_REPORT_HTML_BYTES,
                 "rss_max_bytes": TARGET_RSS_BYTES,
                 "rss_steps": TARGET_RSS_STEPS},
    )
    doc.update(_guarded("reference_map", lambda: reference_maps(config, progress), progress))
    doc.update(_guarded("long_run", lambda: long_run(config, progress), progress))
    doc.update(_guarded("rss", lambda: peak_rss(config, progress), progress))
    if config.suite:
        doc.update(_guarded("suite", lambda: suite_timing(config, progress), progress))
    doc.setdefault("suite_serial_s", None)
    doc.setdefault("suite_parallel_s", None)
    if not config.suite:
        doc["suite_note"] = "suite not measured (--no-suite)"
    doc["checks"] = [asdict(c) | {"status": c.status} for c in checks(doc)]
    return doc


def checks(doc: dict) -> list[Check]:
    """The targets of a bench document, in the order of the table: a (each engine-equivalent map),
    b, c, d (trajectories, report.html), e, then the overhead targets (1)."""
    out: list[Check] = []
    quick = bool(doc.get("quick"))
    mj = doc.get("reference_map_mujoco_step_s")
    for name in ENGINE_EQUIVALENT_MAPS:
        s = doc.get("reference_map_step_s", {}).get(name)
        x = mj / s if mj and s else None
        out.append(make_check(
            "a", f"{name}: mj_step / map step", x, ">=", TARGET_MAP_SPEEDUP, "x",
            f"{_us(s)} vs {_us(mj)} a step" if x is not None else "",
            note="" if x is not None else doc.get("reference_map_mujoco_note")
            or doc.get("reference_map_note", "")))
    label = (f"run {doc.get('long_run_steps', LONG_RUN_STEPS)} MuJoCo Euler steps - run "
             f"{doc.get('short_run_steps', SHORT_RUN_STEPS)}")
    if "long_run_s" in doc:
        out.append(make_check(
            "b", label, doc["long_run_extra_s"], "<=", doc["long_run_limit_s"], "s",
            f"{doc['long_run_s']:.2f} - {doc['short_run_s']:.2f} s; limit 3 x "
            f"{doc['long_run_bare_s']:.3f} s bare + 1 s"))
    else:
        out.append(make_check("b", label, None, "<=", None, "s", note=doc.get("long_run_note", "not measured")))
    suite_ok = doc.get("suite_parallel_s") is not None
    pinned = suite_ok and bool(doc.get("suite_pinned")) and not doc.get("suite_pinned_differences")
    if pinned:
        why_not = ""
    elif not suite_ok:
        why_not = doc.get("suite_note") or "not measured"
    else:
        why_not = "quick: not the pinned list" if quick else "the run list differs from the pinned one"
    out.append(make_check(
        "c", f"suite, {doc.get('suite_runs', PINNED_SUITE_RUNS)} runs, report, --jobs "
             f"{doc.get('suite_jobs', 2)}", doc.get("suite_parallel_s"), "<=", TARGET_SUITE_S, "s",
        f"serial {doc['suite_serial_s']:.1f} s, speed-up {doc['suite_speedup']:.2f}x" if suite_ok else "",
        note=why_not, evaluate=pinned))
    tb, hb = doc.get("suite_trajectories_bytes"), doc.get("suite_report_html_bytes")
    out.append(make_check("d", "suite's trajectory files", tb / MB if tb is not None else None,
                          "<=", TARGET_TRAJECTORIES_BYTES / MB, "MB", note=why_not, evaluate=pinned))
    out.append(make_check("d", "suite's report.html", hb / MB if hb is not None else None,
                          "<=", TARGET_REPORT_HTML_BYTES / MB, "MB", note=why_not, evaluate=pinned))
    out.append(_rss_check(doc))
    for engine, res in doc.get("engine_step_s", {}).items():
        out.append(make_check("1", f"{engine} loop: freebody / bare", res["overhead_ratio"],
                              "<=", TARGET_OVERHEAD_RATIO, "x",
                              f"{_us(res['freebody_step_s'])} vs {_us(res['bare_step_s'])} a step"))
    return out


def _rss_check(doc: dict) -> Check:
    label = f"peak RSS of a {doc.get('rss_steps', TARGET_RSS_STEPS)}-step MuJoCo run"
    if "rss_bytes" not in doc:
        return make_check("e", label, None, "<=", TARGET_RSS_BYTES / MB, "MB",
                          note=doc.get("rss_note", "not measured"))
    steps, rss, short = doc["rss_steps"], doc["rss_bytes"], doc.get("short_run_rss_bytes")
    detail = ""
    if short is not None and steps > doc["short_run_steps"]:
        detail = (f"{short / MB:.0f} MB at {doc['short_run_steps']} steps: "
                  f"{(rss - short) / (steps - doc['short_run_steps']):.0f} B a step more")
    # a longer run needs at least as much: over the limit is a MISS at any length, under it a PASS
    # only at the target's length (memory need not grow linearly: no extrapolation)
    judged = steps >= TARGET_RSS_STEPS or rss > TARGET_RSS_BYTES
    return make_check("e", label, rss / MB, "<=", TARGET_RSS_BYTES / MB, "MB", detail,
                      note="" if judged else f"the target is for {TARGET_RSS_STEPS} steps "
                                             f"(--rss-steps {TARGET_RSS_STEPS})", evaluate=judged)


def _us(s: float | None) -> str:
    return "-" if s is None else f"{s * 1e6:.2f} us" if s >= 1e-6 else f"{s * 1e9:.0f} ns"


def _num(v: float, unit: str, limit: bool = False) -> str:
    """A measured figure (or with ``limit``, a target) with its unit, to a sensible precision."""
    if limit:
        return f"{v:g}x" if unit == "x" else f"{v:.3g} {unit}" if abs(v) < 100 else f"{v:.0f} {unit}"
    if unit == "x":
        return f"{v:.1f}x"
    return f"{v:.2f} {unit}" if abs(v) < 10 else f"{v:.1f} {unit}" if abs(v) < 1000 else f"{v:.0f} {unit}"


def format_checks(rows: list[dict]) -> list[str]:
    """The table of checks (dicts as in a bench document's ``"checks"``)."""
    lines = [f"   {'':3s}{'target':50s} {'measured':>10s} {'limit':>11s}  status  details",
             "   " + "-" * 104]
    for c in rows:
        value = "-" if c["value"] is None else _num(c["value"], c["unit"])
        limit = "-" if c["limit"] is None else f"{c['op']} {_num(c['limit'], c['unit'], limit=True)}"
        detail = "; ".join(x for x in (c.get("detail"), c.get("note")) if x)
        lines.append(f"   {c['key']:3s}{c['label'][:50]:50s} {value:>10s} {limit:>11s}  "
                     f"{c['status']:6s}  {detail}".rstrip())
    return lines


def format_text(doc: dict) -> str:
    """The human-readable summary of a bench document: the checks, then the figures."""
    load = doc.get("load_average")
    lines = [f"freebody bench ({'quick' if doc['quick'] else 'full'}; medians of {doc['repeats']} "
             f"repeat{'s' if doc['repeats'] != 1 else ''}; case {doc['case']}, dt = {doc['dt']} s; {doc['cores']} cores"
             + (f"; load average {load[0]:.1f} at the start" if load else "") + f"; {doc['created']})",
             ""]
    rows = doc.get("checks") or [asdict(c) | {"status": c.status} for c in checks(doc)]
    lines += format_checks(rows)
    lines.append("")
    missed = [c for c in rows if c["status"] == "MISS"]
    lines.append(f"   {sum(c['status'] == 'PASS' for c in rows)} PASS, {len(missed)} MISS, "
                 f"{sum(c['status'] == 'n/a' for c in rows)} n/a")
    lines.append("")
    for part in (_map_lines, _long_run_lines, _suite_lines, _rss_lines, _overhead_lines):
        lines += part(doc)
    return "\n".join(lines)


def _map_lines(doc: dict) -> list[str]:
    """a. the reference maps' step times (nothing when not measured)."""
    if "reference_map_step_s" not in doc:
        return []
    mj = doc.get("reference_map_mujoco_step_s")
    lines = [f"a. reference maps, one body, {doc['reference_map_steps']} steps a call "
             f"(integrators.simulate, compiled); mj_step: {_us(mj)}",
             f"   {'integrator':28s} {'per step':>10s} {'whole call':>11s} {'vs mj_step':>11s}"]
    for name, s in doc["reference_map_step_s"].items():
        lines.append(f"   {name:28s} {_us(s):>10s} {doc['reference_map_call_s'][name] * 1e3:8.2f} ms "
                     + (f"{mj / s:10.1f}x" if mj else f"{'-':>11s}"))
    return lines + [""]


def _long_run_lines(doc: dict) -> list[str]:
    """b. the long run through the command (nothing when not measured)."""
    if "long_run_s" not in doc:
        return []
    return [f"b. {doc['long_run_command']}",
            f"   {doc['long_run_steps']} steps {doc['long_run_s']:.2f} s, {doc['short_run_steps']} "
            f"steps {doc['short_run_s']:.2f} s: {doc['long_run_extra_s']:.2f} s for the steps, "
            f"MuJoCo's bare loop {doc['long_run_bare_s']:.3f} s "
            f"(limit {doc['long_run_limit_s']:.2f} s)",
            ""]


def _suite_lines(doc: dict) -> list[str]:
    """c, d. the suite's wall times and output sizes, or why they were not measured."""
    lines = ["c, d. suite wall time and output"]
    if doc.get("suite_parallel_all_s"):
        lines.append("   serial " + ", ".join(f"{t:.1f}" for t in doc["suite_serial_all_s"])
                     + " s; parallel " + ", ".join(f"{t:.1f}" for t in doc["suite_parallel_all_s"]) + " s")
    if doc.get("suite_parallel_s") is None:
        lines.append(f"   {doc.get('suite_note')}")
    else:
        lines.append(f"   serial {doc['suite_serial_s']:.1f} s, parallel {doc['suite_parallel_s']:.1f} s "
                     f"(--jobs {doc['suite_jobs']}), speed-up {doc['suite_speedup']:.2f}x; trajectories "
                     f"{doc['suite_trajectories_bytes'] / MB:.1f} MB, report.html "
                     f"{(doc['suite_report_html_bytes'] or 0) / MB:.2f} MB, results.json "
                     f"{(doc['suite_results_json_bytes'] or 0) / MB:.2f} MB")
        lines.append(f"   {doc.get('suite_note')}")
    return lines + [""]


def _rss_lines(doc: dict) -> list[str]:
    """e. the peak RSS, or why it was not measured."""
    if "rss_bytes" not in doc:
        return [f"e. peak RSS: {doc.get('rss_note')}", ""]
    return [f"e. peak RSS: {doc['rss_bytes'] / MB:.0f} MB for {doc['rss_steps']} steps "
            f"({doc['rss_run_s']:.1f} s)"
            + (f", {doc['short_run_rss_bytes'] / MB:.0f} MB for {doc['short_run_steps']}, "
               f"{doc['long_run_rss_bytes'] / MB:.0f} MB for {doc['long_run_steps']}"
               if "short_run_rss_bytes" in doc else ""),
            ""]


def _overhead_lines(doc: dict) -> list[str]:
    """1. each engine's loop overhead, and the engines skipped."""
    lines = [f"1. engine loop overhead ({doc['engine_steps']} steps; target <= {TARGET_OVERHEAD_RATIO}x)",
             f"   {'engine':10s} {'version':12s} {'bare us/step':>13s} {'freebody us/step':>17s} "
             f"{'ratio':>7s}"]
    for engine, res in doc["engine_step_s"].items():
        lines.append(f"   {engine:10s} {str(doc['engines'].get(engine)):12s} "
                     f"{res['bare_step_s'] * 1e6:13.2f} {res['freebody_step_s'] * 1e6:17.2f} "
                     f"{res['overhead_ratio']:6.2f}x")
    for engine, why in doc["skipped"].items():
        lines.append(f"   {engine:10s} skipped: {why}")
    return lines
