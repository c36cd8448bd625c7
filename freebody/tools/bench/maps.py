"""Part "maps": the reference maps stepping one body as ``freebody run`` steps them, against MuJoCo's
step in a Python loop (``Adapter.bare_loop``), against ``mujoco.rollout`` (the C loop the MuJoCo
adapter itself uses) and against each map's floor, a flat loop of the same arithmetic
(``reference_impl.floors`` when it exists); part "engines": each engine's bare loop against
freebody's ``adapter.simulate``."""
from __future__ import annotations

import importlib
from typing import Callable

import numpy as np

from .config import CASE, DT, BenchConfig
from .core import cpu_timed, log, median, timed


class NoBareLoop(Exception):
    """The engine's adapter offers no bare loop: its overhead cannot be measured."""


def yardstick_step(steps: int, integrator: str | None = None, case: str = CASE) -> Callable[[], float]:
    """A timer of the yardstick engine's bare loop (``BENCH_YARDSTICK``'s ``Adapter.bare_loop``:
    its own step in a Python loop and state copies) on the case's world, built afresh, untimed, on
    every call: returns CPU seconds per step.  integrator : the engine's (default: its first)."""
    from ...adapters.base import BENCH_YARDSTICK, load_adapter
    from ...input.casefile import load_case

    cls, problem = load_adapter(BENCH_YARDSTICK), load_case(case)
    integrator = integrator or cls.offered_integrators()[0]

    def timer() -> float:
        a = cls(problem, DT, integrator)
        try:
            loop = a.bare_loop(steps)
            if loop is None:
                raise NoBareLoop(f"{BENCH_YARDSTICK} declares no bare loop")
            return cpu_timed(loop) / steps
        finally:
            a.close()
    return timer


def rollout_step(steps: int, case: str = CASE) -> Callable[[], float]:
    """A timer of ``mujoco.rollout`` (one model, one thread) stepping the case's MuJoCo world
    (built by the adapter, untimed, on every call) for ``steps`` steps: CPU seconds per step."""
    from ...adapters.base import BENCH_YARDSTICK, load_adapter
    from ...input.casefile import load_case

    cls, problem = load_adapter(BENCH_YARDSTICK), load_case(case)

    def timer() -> float:
        a = cls(problem, DT, cls.offered_integrators()[0])
        try:
            return rollout_seconds([a.model], [a.data], steps, cpu=True) / steps
        finally:
            a.close()
    return timer


def rollout_seconds(models: list, datas: list, steps: int, cpu: bool = False) -> float:
    """Wall (``cpu``: CPU) seconds of one ``mujoco.rollout`` of every model from its data's current
    state for ``steps`` steps, on one thread (the yardstick engine's own C loop: its adapter module
    holds the engine calls, ``mujoco_adapter.rollout_seconds``)."""
    from ...adapters.mujoco_adapter import rollout_seconds as engine_rollout

    return engine_rollout(models, datas, steps, cpu_timed if cpu else timed)


def _timer_or_note(make: Callable[[], Callable[[], float]]):
    """(timer, None) after one untimed call, or (None, why) when the engine is missing or broken."""
    from ...adapters.base import BENCH_YARDSTICK

    try:
        timer = make()
        timer()
    except Exception as e:
        return None, f"{BENCH_YARDSTICK} unavailable: {type(e).__name__}: {e}"
    return timer, None


def floor_timers(steps: int) -> tuple[dict[str, Callable[[], float]], str]:
    """Timers of each map's floor (CPU s of a whole ``steps``-step call), from
    ``freebody.reference_impl.floors`` (its ``FLOORS`` and ``run_floor(problem, integrator, dt,
    steps)``), each loaded (compiled, or from numba's cache) by an untimed call; or ({}, why)."""
    from ...input.casefile import load_case

    try:
        floors = importlib.import_module("freebody.reference_impl.floors")
    except ImportError:
        return {}, "no flat-loop floors yet (reference_impl/floors.py)"
    run = getattr(floors, "run_floor", None)
    if run is None:
        return {}, "reference_impl/floors.py offers no run_floor(problem, integrator, dt, steps)"
    problem, out = load_case(CASE), {}
    for name in getattr(floors, "FLOORS", ()):
        run(problem, name, DT, 2)
        out[name] = lambda name=name: cpu_timed(lambda: run(problem, name, DT, steps))
    return out, ""


def _map_times(config: BenchConfig, yard: dict, floors: dict, progress: bool):
    """Interleaved repeats: (map calls, zero-step calls, yardstick and floor figures), s."""
    from ...input.casefile import load_case
    from ...reference_impl.integrators import INTEGRATORS, simulate

    problem, n = load_case(CASE), config.map_steps
    calls = {name: [] for name in INTEGRATORS}
    setups = {name: [] for name in INTEGRATORS}
    ys = {k: [] for k in yard} | {f"floor:{k}": [] for k in floors}
    for r in range(config.repeats):
        for k, timer in yard.items():
            ys[k].append(timer())
        for k, timer in floors.items():
            ys[f"floor:{k}"].append(timer())
        for name in INTEGRATORS:
            setups[name].append(cpu_timed(lambda: simulate(problem, name, DT, 0)))
            calls[name].append(cpu_timed(lambda: simulate(problem, name, DT, n)))
        log(f"reference maps repeat {r + 1}/{config.repeats}: "
            + ", ".join(f"{k} {v[-1] * 1e9:.0f} ns" for k, v in ys.items()), progress)
    return calls, setups, ys


def reference_maps(config: BenchConfig, progress: bool = False) -> dict:
    """CPU seconds per step of every reference map on one body through ``integrators.simulate`` (the
    compiled maps, as ``freebody run`` uses them), of MuJoCo's Python loop, of ``mujoco.rollout``
    and of each map's floor, interleaved.  Per step of a map = (median of a ``map_steps`` call -
    median of a zero-step call) / map_steps, floored at a tenth of the raw figure against noise;
    the compiled code is loaded by an untimed first call."""
    from ...input.casefile import load_case
    from ...reference_impl.integrators import INTEGRATORS, simulate

    problem, n = load_case(CASE), config.map_steps
    first = {name: timed(lambda: simulate(problem, name, DT, 10)) for name in INTEGRATORS}
    yard, notes = {}, {}
    for key, make in (("mj_step", lambda: yardstick_step(n)), ("rollout", lambda: rollout_step(n))):
        timer, note = _timer_or_note(make)
        if timer is None:
            notes[key] = note
        else:
            yard[key] = timer
    floors, floor_note = floor_timers(n)
    calls, setups, ys = _map_times(config, yard, floors, progress)
    step_s = {name: max(median(calls[name]) - median(setups[name]), 0.1 * median(calls[name])) / n
              for name in INTEGRATORS}
    out = {"maps_steps": n, "maps_step_s": step_s, "maps_first_call_s": first,
           "maps_call_s": {name: median(v) for name, v in calls.items()},
           "maps_floor_call_s": {k[6:]: median(v) for k, v in ys.items() if k.startswith("floor:")},
           "maps_floor_note": floor_note}
    out["maps_floor_step_s"] = {k: v / n for k, v in out["maps_floor_call_s"].items()}
    if "mj_step" in ys:
        out["maps_mj_step_s"] = median(ys["mj_step"])
    if "rollout" in ys:
        out["maps_rollout_step_s"] = median(ys["rollout"])
    if notes:
        out["maps_yardstick_note"] = "; ".join(notes.values())
    return out


# --- part "engines": each engine's loop overhead ---------------------------------------------------

def engine_overhead(engine: str, steps: int, repeats: int, progress: bool = False) -> dict:
    """Bare engine loop vs ``adapter.simulate(steps)``, interleaved ``repeats`` times.

    Returns {"bare_step_s", "freebody_step_s", "overhead_ratio", "integrator", "steps",
    "repeats"}: medians, seconds per step.
    """
    from ...adapters.base import load_adapter
    from ...input.casefile import load_case

    cls = load_adapter(engine)
    problem = load_case(CASE)
    integrator, precision = cls.offered_integrators()[0], cls.precisions[0]
    bare, ours = [], []
    for r in range(repeats):
        a = cls(problem, DT, integrator, precision)
        try:
            loop = a.bare_loop(steps)
            if loop is None:
                raise NoBareLoop(f"{engine} declares no bare loop (Adapter.bare_loop)")
            bare.append(cpu_timed(loop) / steps)
        finally:
            a.close()
        b = cls(problem, DT, integrator, precision)
        try:
            ours.append(cpu_timed(lambda: b.simulate(steps)) / steps)
        finally:
            b.close()
        log(f"{engine} repeat {r + 1}/{repeats}: bare {bare[-1] * 1e6:.2f} us/step, "
            f"freebody {ours[-1] * 1e6:.2f} us/step", progress)
    b_med, o_med = median(bare), median(ours)
    return {"integrator": integrator, "precision": precision, "steps": steps, "repeats": repeats, "bare_step_s": b_med,
            "freebody_step_s": o_med, "overhead_ratio": o_med / b_med}


def engines(config: BenchConfig, progress: bool = False) -> dict:
    """Part "engines": :func:`engine_overhead` of every installed engine with a bare loop; the
    others under ``skipped`` with the reason."""
    from ...adapters.base import EngineMissing, engine_names, is_available

    overhead, skipped = {}, {}
    for engine in engine_names():
        if not is_available(engine):
            skipped[engine] = "not installed"
            continue
        try:
            overhead[engine] = engine_overhead(engine, config.engine_steps, config.repeats, progress)
        except (EngineMissing, NoBareLoop) as e:
            skipped[engine] = str(e)
        except Exception as e:  # a broken engine is reported, not a crash of the benchmark
            skipped[engine] = f"failed: {type(e).__name__}: {e}"
    return {"engine_step_s": overhead, "skipped": skipped, "engine_steps": config.engine_steps,
            "overhead_ratio": {e: r["overhead_ratio"] for e, r in overhead.items()}}
