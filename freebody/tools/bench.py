"""``freebody bench``: how fast freebody is next to the engines it drives, measured side by side.

Three measurements, each repeated and quoted as the median over the repeats (the machine may be
shared and noisy; the repeats of the things compared are interleaved, so drifts of the machine's
load hit both sides alike):

1. Engine overhead, per registered engine (a missing one, or one whose adapter declares no bare
   loop, is listed under ``skipped`` with the reason): the adapter's ``bare_loop`` (the engine's
   own step plus the minimal calls any user needs to see the state, e.g. MuJoCo: ``mj_step`` +
   copy of ``qpos``/``qvel`` into preallocated arrays) for N steps, against freebody's
   ``adapter.simulate(N)`` on the same engine world (state captured and converted to the
   canonical trajectory; no truth, no metrics, no scheme identification).  Both start from a world
   built by the adapter (building is not timed).  ``overhead_ratio`` = freebody / bare.
2. The reference integrators batched over B bodies (:mod:`freebody.reference_impl.batched`),
   B = 1, 100, 1000, 10000: seconds per body-step (the batch's one-off set-up, measured with zero
   steps, subtracted), and the speed-up over one body-step of the yardstick engine
   (``adapters.base.BENCH_YARDSTICK``, MuJoCo: its bare loop, ``mujoco_body_step_s``).
3. The default suite (``freebody run``) serial (``--jobs 1``) and parallel (``--jobs <cores>``),
   wall time of the whole command in a subprocess; only serial when ``freebody run`` has no
   ``--jobs`` (the note says so).

The result is one JSON document (schema version :data:`SCHEMA_VERSION`) and a text summary.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..results.document import document_header

SCHEMA_VERSION = 1

# Targets of issue 6 (what the text summary checks).
TARGET_OVERHEAD_RATIO = 1.3      # freebody's engine loop at most 1.3 x the bare loop
TARGET_BATCH_SPEEDUP = 20.0      # engine-equivalent maps >= 20 x faster per body-step than MuJoCo
TARGET_BATCH_SIZE = 1000         # ... at B = 1000
ENGINE_EQUIVALENT_MAPS = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")

BATCH_SIZES = (1, 100, 1000, 10000)
CASE = "dzhanibekov"             # torque-free, no gravity, no loads: the engines' bare step
DT = 0.001                       # s
BATCH_OMEGA_SCALE = 5.0          # rad/s: batch bodies spin at ~ |N(0, 1)| x 5 rad/s, |h w| ~ 0.01


@dataclass(frozen=True)
class BenchConfig:
    """What one ``freebody bench`` measures.

    engine_steps : steps of each engine loop.  batch_steps : {B: steps} of each batched run.
    repeats : repeats of every measurement (medians are quoted).  suite : run the suite part.
    suite_args : arguments of ``freebody run`` for the suite (before --jobs).
    """

    engine_steps: int
    batch_steps: dict
    repeats: int
    suite: bool
    suite_args: tuple[str, ...]
    quick: bool

    @classmethod
    def make(cls, quick: bool, repeats: int | None = None, suite: bool = True) -> "BenchConfig":
        if quick:
            return cls(engine_steps=500, batch_steps={1: 20, 100: 20, 1000: 10, 10000: 3},
                       repeats=repeats or 3, suite=suite,
                       suite_args=(CASE, "--engine", "reference", "--integrator", "rk4",
                                   "--dt", "0.01", "--duration", "0.05"), quick=True)
        return cls(engine_steps=20000, batch_steps={1: 200, 100: 200, 1000: 100, 10000: 30},
                   repeats=repeats or 7, suite=suite, suite_args=(), quick=False)


def _log(msg: str, progress: bool) -> None:
    if progress:
        sys.stderr.write(f"bench: {msg}\n")
        sys.stderr.flush()


def _timed(fn: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


# --- 1. engine overhead ---------------------------------------------------------------------------

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
    b_med, o_med = float(np.median(bare)), float(np.median(ours))
    return {"integrator": integrator, "steps": steps, "repeats": repeats, "bare_step_s": b_med,
            "freebody_step_s": o_med, "overhead_ratio": o_med / b_med}


# --- 2. batched reference integrators -------------------------------------------------------------

def _batch_inputs(B: int) -> dict:
    """B copies of the case's body with seeded random attitudes and angular velocities."""
    from ..input.casefile import load_case

    body = load_case(CASE).body
    rng = np.random.default_rng(20240606)
    q = rng.normal(size=(B, 4))
    return dict(mass=body.mass, I_body=np.array(body.I_body), position=np.zeros((B, 3)),
                quaternion_wxyz=q / np.linalg.norm(q, axis=1, keepdims=True),
                linear_velocity=np.zeros((B, 3)),
                angular_velocity=BATCH_OMEGA_SCALE * rng.normal(size=(B, 3)))


class NoBareLoop(Exception):
    """The engine's adapter offers no bare loop: its overhead cannot be measured."""


def yardstick_step(steps: int) -> Callable[[], float]:
    """A timer of the yardstick engine's bare loop (``BENCH_YARDSTICK``'s ``Adapter.bare_loop``:
    its own step and state copies) on the case's world, built afresh, untimed, by the adapter on
    every call: returns seconds per step."""
    from ..adapters.base import BENCH_YARDSTICK, load_adapter
    from ..input.casefile import load_case

    cls, problem = load_adapter(BENCH_YARDSTICK), load_case(CASE)

    def timer() -> float:
        a = cls(problem, DT, cls.offered_integrators()[0])
        try:
            loop = a.bare_loop(steps)
            if loop is None:
                raise NoBareLoop(f"{BENCH_YARDSTICK} declares no bare loop")
            return _timed(loop) / steps
        finally:
            a.close()
    return timer


def batched_reference(config: BenchConfig, progress: bool = False) -> dict:
    """Seconds per body-step of every batched integrator at every B, and of a bare mj_step.

    The repeats are interleaved: each repeat times MuJoCo, then every (integrator, B).
    """
    from ..reference_impl.batched import BATCHED_INTEGRATORS, simulate_batch

    try:
        mj_timer = yardstick_step(config.engine_steps)
    except Exception as e:  # MuJoCo missing or broken: batch figures without the ratio
        mj_timer, mj_note = None, f"mujoco unavailable: {type(e).__name__}: {e}"
    else:
        mj_note = None
    inputs = {B: _batch_inputs(B) for B in BATCH_SIZES}
    mj: list[float] = []
    per: dict[tuple[str, int], list[float]] = {}
    setup: dict[tuple[str, int], list[float]] = {}
    for r in range(config.repeats):
        if mj_timer is not None:
            mj.append(mj_timer())
        for name in BATCHED_INTEGRATORS:
            for B in BATCH_SIZES:
                n = config.batch_steps[B]
                kw = inputs[B]
                t0 = _timed(lambda: simulate_batch(name, dt=DT, steps=0, **kw))
                t = _timed(lambda: simulate_batch(name, dt=DT, steps=n, every=n, **kw))
                setup.setdefault((name, B), []).append(t0)
                per.setdefault((name, B), []).append((t, n * B))
        _log(f"batched reference repeat {r + 1}/{config.repeats}"
             + (f": mj_step {mj[-1] * 1e6:.2f} us" if mj else ""), progress)
    body_step: dict[str, dict[str, float]] = {}
    for (name, B), samples in per.items():
        t_setup = float(np.median(setup[(name, B)]))
        t_run = float(np.median([t for t, _ in samples]))
        body_steps = samples[0][1]
        # the set-up (zero steps) subtracted; floored at 1/10 of the raw figure against noise
        body_step.setdefault(name, {})[str(B)] = max(t_run - t_setup, 0.1 * t_run) / body_steps
    out = {"reference_body_step_s": body_step, "batch_steps": {str(B): n for B, n in
                                                               config.batch_steps.items()}}
    if mj:
        mj_med = float(np.median(mj))
        out["mujoco_body_step_s"] = mj_med
        out["reference_speedup_vs_mujoco"] = {
            name: {B: mj_med / s for B, s in row.items()} for name, row in body_step.items()}
    else:
        out["mujoco_note"] = mj_note
    return out


# --- 3. the suite, serial and parallel --------------------------------------------------------------

def _run_help() -> str:
    """``freebody run --help`` (built in this process: which options exist)."""
    import argparse

    from ..cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["run"].format_help()


def suite_timing(config: BenchConfig, progress: bool = False) -> dict:
    """Wall time of ``freebody run`` (the default suite, or a tiny one in quick mode) in a
    subprocess with --jobs 1 and --jobs <cores>; serial only when the flag does not exist."""
    help_text = _run_help()
    has_jobs = "--jobs" in help_text
    cores = os.cpu_count() or 1
    extra = ["--quiet"] + (["--no-report"] if "--no-report" in help_text else [])
    out: dict = {"suite_cores": cores, "suite_args": list(config.suite_args)}

    def wall(jobs: int | None) -> tuple[float, int]:
        with tempfile.TemporaryDirectory(prefix="freebody-bench-") as tmp:
            cmd = [sys.executable, "-m", "freebody", "run", *config.suite_args, *extra,
                   "--out", tmp] + (["--jobs", str(jobs)] if jobs is not None else [])
            t0 = time.perf_counter()
            proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True, check=False)
            t = time.perf_counter() - t0
        if proc.returncode not in (0, 1):  # 1: some run failed, the suite still ran
            raise RuntimeError(f"freebody run exited {proc.returncode}: "
                               f"{proc.stderr.strip().splitlines()[-1:] or ''}")
        return t, proc.returncode

    _log(f"suite serial: freebody run {' '.join(config.suite_args) or '(default suite)'}"
         + (" --jobs 1" if has_jobs else ""), progress)
    out["suite_serial_s"], rc = wall(1 if has_jobs else None)
    out["suite_exit_code"] = rc
    if has_jobs:
        _log(f"suite parallel: --jobs {cores}", progress)
        out["suite_parallel_s"], _ = wall(cores)
        out["suite_jobs"] = cores
        out["suite_speedup"] = out["suite_serial_s"] / out["suite_parallel_s"]
        out["suite_note"] = (f"wall time of one freebody run each, --jobs 1 vs --jobs {cores} "
                             f"({cores} cores)")
    else:
        out["suite_parallel_s"] = None
        out["suite_note"] = "freebody run has no --jobs option here: serial only"
    return out


# --- the whole benchmark --------------------------------------------------------------------------

def run_bench(config: BenchConfig, progress: bool = False) -> dict:
    """All three measurements as one JSON-ready document (schema :data:`SCHEMA_VERSION`)."""
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
        quick=config.quick,
        repeats=config.repeats,
        case=CASE,
        dt=DT,
        engine_steps=config.engine_steps,
        overhead_ratio=overhead,
        engine_step_s=engine_steps,
        skipped=skipped,
        targets={"overhead_ratio_max": TARGET_OVERHEAD_RATIO,
                 "batch_speedup_min": TARGET_BATCH_SPEEDUP,
                 "batch_size": TARGET_BATCH_SIZE,
                 "engine_equivalent_maps": list(ENGINE_EQUIVALENT_MAPS)},
    )
    doc.update(batched_reference(config, progress))
    if config.suite:
        doc.update(suite_timing(config, progress))
    else:
        doc.update(suite_serial_s=None, suite_parallel_s=None, suite_note="suite not measured (--no-suite)")
    return doc


def format_text(doc: dict) -> str:
    """The human-readable summary of a bench document."""
    lines = [f"freebody bench ({'quick' if doc['quick'] else 'full'}; medians of {doc['repeats']} "
             f"repeats; case {doc['case']}, dt = {doc['dt']} s; {doc['cores']} cores)", ""]
    lines.append(f"1. engine loop overhead ({doc['engine_steps']} steps; target <= "
                 f"{TARGET_OVERHEAD_RATIO}x)")
    lines.append(f"   {'engine':10s} {'version':12s} {'bare us/step':>13s} {'freebody us/step':>17s} "
                 f"{'ratio':>7s}  target")
    for engine, res in doc["engine_step_s"].items():
        ok = "met" if res["overhead_ratio"] <= TARGET_OVERHEAD_RATIO else "NOT met"
        lines.append(f"   {engine:10s} {str(doc['engines'].get(engine)):12s} "
                     f"{res['bare_step_s'] * 1e6:13.2f} {res['freebody_step_s'] * 1e6:17.2f} "
                     f"{res['overhead_ratio']:6.2f}x  {ok}")
    for engine, why in doc["skipped"].items():
        lines.append(f"   {engine:10s} skipped: {why}")
    lines.append("")
    mj = doc.get("mujoco_body_step_s")
    lines.append("2. batched reference integrators: ns per body-step"
                 + (f" (speed-up over one MuJoCo mj_step = {mj * 1e9:.0f} ns)" if mj else
                    f" ({doc.get('mujoco_note')})"))
    Bs = [str(B) for B in BATCH_SIZES]
    lines.append(f"   {'integrator':28s} " + " ".join(f"{'B=' + B:>16s}" for B in Bs))
    for name, row in doc["reference_body_step_s"].items():
        cells = []
        for B in Bs:
            s = row[B]
            cells.append(f"{s * 1e9:8.1f} ({mj / s:5.1f}x)" if mj else f"{s * 1e9:16.1f}")
        lines.append(f"   {name:28s} " + " ".join(f"{c:>16s}" for c in cells))
    if mj:
        for name in ENGINE_EQUIVALENT_MAPS:
            x = mj / doc["reference_body_step_s"][name][str(TARGET_BATCH_SIZE)]
            met = "met" if x >= TARGET_BATCH_SPEEDUP else "NOT met"
            lines.append(f"   target {name} >= {TARGET_BATCH_SPEEDUP:.0f}x at B = "
                         f"{TARGET_BATCH_SIZE}: {x:.1f}x, {met}")
    lines.append("")
    lines.append("3. suite wall time")
    if doc.get("suite_serial_s") is None:
        lines.append(f"   {doc.get('suite_note')}")
    else:
        lines.append(f"   serial {doc['suite_serial_s']:.2f} s"
                     + (f", parallel {doc['suite_parallel_s']:.2f} s (--jobs {doc['suite_jobs']}), "
                        f"speed-up {doc['suite_speedup']:.2f}x" if doc.get("suite_parallel_s") else ""))
        lines.append(f"   {doc.get('suite_note')}")
    return "\n".join(lines)
