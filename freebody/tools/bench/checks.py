"""The table of ``freebody bench``: one :class:`~.core.Check` per target of issue 29 (and the older
targets it keeps), judged from a bench document's figures alone (so a saved document is judged
again the same way, and the logic is tested on synthetic figures)."""
from __future__ import annotations

from .config import (ENGINE_EQUIVALENT_MAPS, OTHER_FLOOR_MAPS, TARGET_COLD_COMPILE_CPU_S,
                     TARGET_MAP_SPEEDUP, TARGET_MAP_VS_FLOOR, TARGET_MARGINAL_RUN_CPU_S,
                     TARGET_MJX_VS_MUJOCO, TARGET_ONE_RUN_CPU_S, TARGET_OTHER_MAP_VS_FLOOR,
                     TARGET_OVERHEAD_RATIO, TARGET_REPORT_HTML_BYTES, TARGET_REPORT_MD_BYTES,
                     TARGET_REPORT_VS_RUN, TARGET_RSS_BYTES, TARGET_RSS_STEPS,
                     TARGET_SUITE_VS_STEPPING, TARGET_SWEEP_JOBS_GAIN, TARGET_SWEEP_VS_ROLLOUT,
                     TARGET_TRAJECTORIES_BYTES, TARGET_TRUTH_VS_COMPILED)
from .core import MB, Check, make_check

QUICK_NOTE = "--quick: not the full measurement"


def _ratio(a, b) -> float | None:
    return a / b if a is not None and b else None


def _why(doc: dict, part: str) -> str:
    return doc.get(f"{part}_note") or "not measured"


def overhead_checks(doc: dict) -> list[Check]:
    one, n = doc.get("overhead_one_run_cpu_s"), doc.get("overhead_n_runs")
    marginal = doc.get("overhead_marginal_run_cpu_s")
    detail = (f"{n} runs {doc['overhead_n_runs_cpu_s']:.2f} s - 1 run {one:.2f} s, / {n - 1}"
              if marginal is not None else "")
    return [make_check("run", "a further 10-step run in an invocation, CPU",
                       None if marginal is None else marginal * 1e3, "<=",
                       TARGET_MARGINAL_RUN_CPU_S * 1e3, "ms", detail, _why(doc, "overhead") if marginal is None else ""),
            make_check("run", "one-run invocation (10 steps), CPU, imports incl.", one, "<=",
                       TARGET_ONE_RUN_CPU_S, "s", note="" if one is not None else _why(doc, "overhead"))]


def suite_checks(doc: dict) -> list[Check]:
    quick = bool(doc.get("quick"))
    wall, step = doc.get("suite_nomjx_wall_s"), doc.get("suite_nomjx_stepping_s")
    x = _ratio(wall, step)
    out = [make_check("suite", "suite w/o MJX, --jobs 1: wall / engine stepping", x,
                      "<=", TARGET_SUITE_VS_STEPPING, "x",
                      f"{wall:.1f} s vs {step:.1f} s, {doc['suite_nomjx_runs']} runs" if x else "",
                      note=QUICK_NOTE if quick and x else "" if x else _why(doc, "suite"),
                      evaluate=not quick)]
    warm = doc.get("suite_warm_stepping_s") or {}
    mjx, mj = warm.get("mjx"), warm.get("mujoco")
    y = _ratio(mjx, mj) if doc.get("suite_with_mjx") else None
    note = ("" if y else QUICK_NOTE + " (no MJX)" if quick else "MJX not installed"
            if "suite_warm_wall_s" in doc else _why(doc, "suite"))
    out.append(make_check("suite", "warm default suite: MJX stepping / MuJoCo's", y, "<=",
                          TARGET_MJX_VS_MUJOCO, "x", f"{mjx:.1f} s vs {mj:.1f} s" if y else "", note))
    return out


def compile_checks(doc: dict) -> list[Check]:
    c = doc.get("compile_cpu_s")
    detail = (f"{doc['compile_cold_cpu_s']:.1f} s with an empty NUMBA_CACHE_DIR - "
              f"{doc['compile_warm_cpu_s']:.1f} s warm" if c is not None else "")
    return [make_check("compile", "cold first run: numba compilation, CPU", c, "<=",
                       TARGET_COLD_COMPILE_CPU_S, "s", detail,
                       "" if c is not None else doc.get("compile_note") or "not measured (--cold, or full)")]


def truth_checks(doc: dict) -> list[Check]:
    x = _ratio(doc.get("truth_cpu_s"), doc.get("truth_yardstick_cpu_s"))
    detail = (f"{doc['truth_cpu_s'] * 1e3:.2f} ms vs {doc['truth_yardstick_cpu_s'] * 1e3:.2f} ms CPU, "
              f"{doc['truth_case']} {doc['truth_steps']} steps" if x else "")
    return [make_check("truth", "numerical truth / DOP853 with a numba rhs, CPU", x, "<=",
                       TARGET_TRUTH_VS_COMPILED, "x", detail, "" if x else _why(doc, "truth"))]


def map_checks(doc: dict) -> list[Check]:
    step, calls = doc.get("maps_step_s") or {}, doc.get("maps_call_s") or {}
    floors = doc.get("maps_floor_call_s") or {}
    mj, roll = doc.get("maps_mj_step_s"), doc.get("maps_rollout_step_s")
    n = doc.get("maps_steps")
    out = []
    for names, limit in ((ENGINE_EQUIVALENT_MAPS, TARGET_MAP_VS_FLOOR), (OTHER_FLOOR_MAPS, TARGET_OTHER_MAP_VS_FLOOR)):
        for name in names:
            x = _ratio(calls.get(name), floors.get(name))  # whole calls of n steps, as freebody run makes them
            note = ("" if x else doc.get("maps_floor_note") or
                    (f"no floor of {name} in reference_impl/floors.py (FLOORS)" if floors else _why(doc, "maps")))
            out.append(make_check("maps", f"{name} / its flat loop", x, "<=", limit, "x",
                                  f"{calls[name] * 1e3:.2f} vs {floors[name] * 1e3:.2f} ms for {n} steps"
                                  if x else "", note))
    for name in ENGINE_EQUIVALENT_MAPS:
        x = _ratio(mj, step.get(name))
        r = _ratio(roll, step.get(name))
        detail = (f"{_us(step.get(name))} vs mj_step {_us(mj)}"
                  + (f"; mujoco.rollout {_us(roll)}: {r:.1f}x" if r else "")) if x else ""
        out.append(make_check("maps", f"{name}: mj_step / map step", x, ">=",
                              TARGET_MAP_SPEEDUP, "x", detail,
                              "" if x else doc.get("maps_yardstick_note") or _why(doc, "maps")))
    return out


def sweep_checks(doc: dict) -> list[Check]:
    quick, n = bool(doc.get("quick")), doc.get("sweep_bodies")
    x = _ratio(doc.get("sweep_body_steps_per_s"), doc.get("sweep_rollout_body_steps_per_s"))
    g = doc.get("sweep_jobs_gain")
    note = QUICK_NOTE + f" ({n} bodies)" if quick and x else "" if x else _why(doc, "sweep")
    return [make_check("sweep", f"sweep of {n or 200} bodies / mujoco.rollout, body-steps/s", x, ">=",
                       TARGET_SWEEP_VS_ROLLOUT, "x",
                       f"{doc['sweep_body_steps_per_s']:.0f} vs {doc['sweep_rollout_body_steps_per_s']:.0f}"
                       if x else "", note, evaluate=not quick),
            make_check("sweep", "sweep --jobs 2 / --jobs 1 speed", g, ">=", TARGET_SWEEP_JOBS_GAIN, "x",
                       f"--jobs 1 {doc['sweep_jobs1_wall_s']:.1f} s, --jobs 2 {doc['sweep_jobs2_wall_s']:.1f} s wall"
                       if g else "",
                       note, evaluate=not quick)]


def report_checks(doc: dict) -> list[Check]:
    quick = bool(doc.get("quick"))
    x = _ratio(doc.get("suite_report_wall_s"), doc.get("suite_cold_wall_s"))
    note = QUICK_NOTE if quick and x else "" if x else _why(doc, "suite")
    out = [make_check("report", "freebody report / the run's wall", x, "<=", TARGET_REPORT_VS_RUN, "x",
                      f"{doc['suite_report_wall_s']:.1f} s vs {doc['suite_cold_wall_s']:.1f} s" if x else "",
                      note, evaluate=not quick)]
    for key, label, limit, unit in (("suite_trajectories_bytes", "default suite's trajectory files", TARGET_TRAJECTORIES_BYTES, MB),
                                    ("suite_report_html_bytes", "default suite's report.html", TARGET_REPORT_HTML_BYTES, MB),
                                    ("suite_report_md_bytes", "default suite's report.md", TARGET_REPORT_MD_BYTES, 1e3)):
        v = doc.get(key)
        out.append(make_check("output", label, None if v is None else v / unit, "<=", limit / unit,
                              "MB" if unit == MB else "KB", note=note if v is not None else _why(doc, "suite"),
                              evaluate=not quick))
    return out


def rss_checks(doc: dict) -> list[Check]:
    label = f"peak RSS of a {doc.get('rss_steps', TARGET_RSS_STEPS)}-step MuJoCo run"
    if "rss_bytes" not in doc:
        return [make_check("rss", label, None, "<=", TARGET_RSS_BYTES / MB, "MB", note=_why(doc, "rss"))]
    steps, rss, short = doc["rss_steps"], doc["rss_bytes"], doc.get("rss_short_bytes")
    detail = ""
    if short is not None and steps > doc.get("rss_short_steps", 10):
        detail = (f"{short / MB:.0f} MB at {doc['rss_short_steps']} steps: "
                  f"{(rss - short) / (steps - doc['rss_short_steps']):.0f} B a step more")
    # a longer run needs at least as much: over the limit is a MISS at any length, under it a PASS
    # only at the target's length (memory need not grow linearly: no extrapolation)
    judged = steps >= TARGET_RSS_STEPS or rss > TARGET_RSS_BYTES
    return [make_check("rss", label, rss / MB, "<=", TARGET_RSS_BYTES / MB, "MB", detail,
                       note="" if judged else f"the target is for {TARGET_RSS_STEPS} steps "
                                              f"(--rss-steps {TARGET_RSS_STEPS})", evaluate=judged)]


def engine_checks(doc: dict) -> list[Check]:
    return [make_check("engine", f"{engine} loop: freebody / bare", res["overhead_ratio"], "<=",
                       TARGET_OVERHEAD_RATIO, "x",
                       f"{_us(res['freebody_step_s'])} vs {_us(res['bare_step_s'])} a step")
            for engine, res in (doc.get("engine_step_s") or {}).items()]


CHECK_GROUPS = (overhead_checks, suite_checks, compile_checks, truth_checks, map_checks,
                sweep_checks, report_checks, rss_checks, engine_checks)


def checks(doc: dict) -> list[Check]:
    """Every target of a bench document (schema 4), in the order of the table."""
    return [c for group in CHECK_GROUPS for c in group(doc)]


def _us(s: float | None) -> str:
    return "-" if s is None else f"{s * 1e6:.2f} us" if s >= 1e-6 else f"{s * 1e9:.0f} ns"
