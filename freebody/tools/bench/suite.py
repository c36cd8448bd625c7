"""Part "suite": the current default suite (``freebody run`` with no case and no engine: whatever
is installed), as users run it (report included), cold and warm, its report re-rendered by
``freebody report``, the sizes of its output, and the suite without MJX with one worker against
its own engine stepping (the sum of its runs' ``wall_time_s``: from building the engine's world
to its last step, judging excluded).

With ``--quick`` the same on the default suite's runs of two cases without MJX (a slice: shown,
not judged)."""
from __future__ import annotations

import tempfile
from collections import defaultdict
from pathlib import Path

from ...results.document import load_results
from .config import QUICK_SUITE_CASES, BenchConfig
from .core import Child, file_bytes, folder_bytes, freebody_cmd, log, run_ok

MJX = "mjx"


def suite_engines(config: BenchConfig) -> tuple[list[str], list[str]]:
    """(the engines of the timed suite: [] = the default set, as users run it; the engines of the
    suite without MJX: the default set's other engines).  --quick leaves MJX out of both."""
    from ...adapters.base import default_engine_names

    without = [e for e in default_engine_names() if e != MJX]
    return (without if config.quick else []), without


def suite_command(config: BenchConfig, out: str, engines: list[str], extra: tuple[str, ...] = ()) -> list[str]:
    """``freebody run [the quick cases] [--engine E ...] --quiet --out OUT [extra]``."""
    cases = list(QUICK_SUITE_CASES) if config.quick else []
    sel = [a for e in engines for a in ("--engine", e)]
    return freebody_cmd("run", *cases, *sel, "--quiet", "--out", out, *extra)


def stepping_by_engine(folder: Path) -> tuple[int, dict[str, float], dict[str, float]]:
    """(runs, {engine: sum of its runs' wall_time_s}, {engine: sum of compile_time_s}), s."""
    runs = load_results(folder)["runs"]
    step: dict[str, float] = defaultdict(float)
    comp: dict[str, float] = defaultdict(float)
    for r in runs:
        step[r["engine"]] += r.get("wall_time_s") or 0.0
        comp[r["engine"]] += r.get("compile_time_s") or 0.0
    return len(runs), dict(step), dict(comp)


def _sizes(folder: Path) -> dict:
    return {"suite_trajectories_bytes": folder_bytes(folder / "trajectories"),
            "suite_report_html_bytes": file_bytes(folder / "report.html"),
            "suite_report_md_bytes": file_bytes(folder / "report.md"),
            "suite_results_json_bytes": file_bytes(folder / "results.json")}


def _cold_env(config: BenchConfig, tmp: str) -> dict | None:
    """--cold: empty numba and JAX compilation caches for the cold run."""
    if not config.cold:
        return None
    return {"NUMBA_CACHE_DIR": str(Path(tmp) / "numba"), "JAX_COMPILATION_CACHE_DIR": str(Path(tmp) / "jax")}


def _cold_and_report(config: BenchConfig, engines: list[str], tmp: str, progress: bool) -> dict:
    """The cold run (fresh output folder), then ``freebody report`` of its folder; the sizes."""
    cold_dir = str(Path(tmp) / "cold")
    log(f"suite: cold run{' (empty numba/JAX caches)' if config.cold else ''}", progress)
    cold = run_ok(suite_command(config, cold_dir, engines), "freebody run (cold)",
                  _cold_env(config, tmp), (0, 1))
    log(f"suite: cold {cold.wall_s:.1f} s; freebody report", progress)
    report = run_ok(freebody_cmd("report", cold_dir), "freebody report", None, (0, 1))
    n, step, comp = stepping_by_engine(Path(cold_dir))
    return {"suite_cold_wall_s": cold.wall_s, "suite_cold_cpu_s": cold.cpu_s, "suite_runs": n,
            "suite_report_wall_s": report.wall_s, "suite_report_cpu_s": report.cpu_s,
            "suite_cold_stepping_s": step, "suite_cold_compile_s": comp,
            "suite_rss_bytes": cold.maxrss_bytes, **_sizes(Path(cold_dir))}


def _warm(config: BenchConfig, engines: list[str], tmp: str, name: str, extra: tuple[str, ...],
          progress: bool) -> tuple[Child, int, dict, dict]:
    """A warm run (the caches of the runs before) in a fresh output folder ``name``."""
    folder = str(Path(tmp) / name)
    child = run_ok(suite_command(config, folder, engines, extra), f"freebody run ({name})", None, (0, 1))
    log(f"suite: {name} {child.wall_s:.1f} s", progress)
    return (child, *stepping_by_engine(Path(folder)))


def suite(config: BenchConfig, progress: bool = False) -> dict:
    """Cold run, report, warm run of the suite; then, when MJX is in the suite, the suite without
    MJX with ``--jobs 1`` (else the warm run is timed with ``--jobs 1`` and serves as that)."""
    engines, without = suite_engines(config)
    with_mjx = not config.quick and MJX in _default_available()
    with tempfile.TemporaryDirectory(prefix="freebody-bench-suite-") as tmp:
        out = _cold_and_report(config, engines, tmp, progress)
        warm, n, step, comp = _warm(config, engines, tmp, "warm", () if with_mjx else ("--jobs", "1"),
                                    progress)
        out.update(suite_warm_wall_s=warm.wall_s, suite_warm_cpu_s=warm.cpu_s,
                   suite_warm_stepping_s=step, suite_warm_compile_s=comp,
                   suite_warm_jobs="default" if with_mjx else 1)
        if with_mjx:
            warm, n, step, comp = _warm(config, without, tmp, "without-mjx", ("--jobs", "1"), progress)
    out.update(suite_nomjx_wall_s=warm.wall_s, suite_nomjx_cpu_s=warm.cpu_s, suite_nomjx_runs=n,
               suite_nomjx_stepping_s=sum(step.values()), suite_nomjx_engines=without,
               suite_cases=list(QUICK_SUITE_CASES) if config.quick else "default",
               suite_engines=engines or "default", suite_with_mjx=with_mjx,
               suite_command=" ".join(["freebody"] + suite_command(config, "DIR", engines)[3:]))
    return out


def _default_available() -> list[str]:
    from ...adapters.base import default_engine_names, is_available

    return [e for e in default_engine_names() if is_available(e)]
