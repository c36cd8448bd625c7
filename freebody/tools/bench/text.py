"""The text of a bench document: the table of checks (each target, its measured figure, the limit,
PASS/MISS/n/a and the figures behind it), the count of each status, then the figures of each
part."""
from __future__ import annotations

from dataclasses import asdict

from .checks import checks
from .core import MB


def _num(v: float, unit: str, limit: bool = False) -> str:
    """A measured figure (or with ``limit``, a target) with its unit, to a sensible precision."""
    if limit:
        if unit == "x" and 0 < v < 1:
            return f"1/{1 / v:g}"
        return f"{v:g}x" if unit == "x" else f"{v:.3g} {unit}" if abs(v) < 100 else f"{v:.0f} {unit}"
    if unit == "x":
        if 0 < v < 0.1:
            return f"1/{1 / v:.0f}"
        return f"{v:.2f}x" if abs(v) < 10 else f"{v:.1f}x"
    return f"{v:.2f} {unit}" if abs(v) < 10 else f"{v:.1f} {unit}" if abs(v) < 1000 else f"{v:.0f} {unit}"


def format_checks(rows: list[dict]) -> list[str]:
    """The table of checks (dicts as in a bench document's ``"checks"``)."""
    lines = [f"   {'':8s}{'target':56s} {'measured':>10s} {'limit':>10s}  status  details",
             "   " + "-" * 110]
    for c in rows:
        value = "-" if c["value"] is None else _num(c["value"], c["unit"])
        limit = "-" if c["limit"] is None else f"{c['op']} {_num(c['limit'], c['unit'], limit=True)}"
        detail = "; ".join(x for x in (c.get("detail"), c.get("note")) if x)
        lines.append(f"   {c['key']:8s}{c['label'][:56]:56s} {value:>10s} {limit:>10s}  "
                     f"{c['status']:6s}  {detail}".rstrip())
    return lines


def format_text(doc: dict) -> str:
    """The human-readable summary of a bench document: the checks, then the figures."""
    load, end = doc.get("load_average"), doc.get("load_average_end")
    mode = "quick" if doc.get("quick") else "full"
    head = (f"freebody bench ({mode}{', cold' if doc.get('cold') else ''}; medians of {doc['repeats']} "
            f"repeat{'s' if doc['repeats'] != 1 else ''}; {doc.get('cores')} cores"
            + (f"; load average {load[0]:.1f} at the start" if load else "")
            + (f", {end[0]:.1f} at the end" if end else "") + f"; {doc.get('created')}"
            + (f"; schema {doc['migrated_from']} document" if doc.get("migrated_from") else "") + ")")
    rows = doc.get("checks") or [asdict(c) | {"status": c.status} for c in checks(doc)]
    lines = [head, ""] + format_checks(rows) + [""]
    count = {s: sum(c["status"] == s for c in rows) for s in ("PASS", "MISS", "n/a")}
    lines += [f"   {count['PASS']} PASS, {count['MISS']} MISS, {count['n/a']} n/a", ""]
    for part in (_command_lines, _map_lines, _suite_lines, _engine_lines):
        lines += part(doc)
    return "\n".join(lines).rstrip() + "\n"


def _command_lines(doc: dict) -> list[str]:
    """The commands timed, as a user would type them."""
    keys = (("overhead_command", "one run"), ("overhead_n_command", "N runs"),
            ("compile_command", "compile"), ("sweep_command", "sweep"), ("suite_command", "suite"),
            ("rss_command", "RSS"))
    got = [f"   {what:8s} {doc[k]}" for k, what in keys if doc.get(k)]
    return (["commands timed (in a fresh subprocess and output folder each):"] + got + [""]) if got else []


def _map_lines(doc: dict) -> list[str]:
    """The reference maps' step times (nothing when not measured)."""
    if "maps_step_s" not in doc:
        return []
    mj, roll, floors = doc.get("maps_mj_step_s"), doc.get("maps_rollout_step_s"), doc.get("maps_floor_step_s") or {}
    lines = [f"reference maps, one body, {doc.get('maps_steps', '?')} steps a call (integrators.simulate, compiled); "
             f"mj_step in Python {_ns(mj)}, mujoco.rollout {_ns(roll)} a step",
             f"   {'integrator':28s} {'per step':>10s} {'floor':>10s} {'vs mj_step':>11s} {'vs rollout':>11s}"]
    for name, s in doc["maps_step_s"].items():
        lines.append(f"   {name:28s} {_ns(s):>10s} {_ns(floors.get(name)):>10s} "
                     + (f"{mj / s:10.1f}x " if mj else f"{'-':>11s} ")
                     + (f"{roll / s:10.1f}x" if roll else f"{'-':>11s}"))
    return lines + [""]


def _f(doc: dict, key: str, scale: float = 1.0, fmt: str = ".1f") -> str:
    """``doc[key] / scale`` formatted, or "-" when it is missing."""
    v = doc.get(key)
    return "-" if v is None else format(v / scale, fmt)


def _suite_lines(doc: dict) -> list[str]:
    """The suite's runs, walls and stepping by engine."""
    if "suite_cold_wall_s" not in doc:
        return [f"suite: {doc.get('suite_note')}", ""] if doc.get("suite_note") else []
    warm = doc.get("suite_warm_stepping_s") or {}
    return [f"suite ({_f(doc, 'suite_runs', fmt='.0f')} runs): cold {_f(doc, 'suite_cold_wall_s')} s wall "
            f"({_f(doc, 'suite_cold_cpu_s')} s CPU), warm {_f(doc, 'suite_warm_wall_s')} s "
            f"({_f(doc, 'suite_warm_cpu_s')} s CPU, --jobs {doc.get('suite_warm_jobs')}), freebody report "
            f"{_f(doc, 'suite_report_wall_s')} s; without MJX, --jobs 1: {_f(doc, 'suite_nomjx_wall_s')} s "
            f"for {_f(doc, 'suite_nomjx_stepping_s')} s of engine stepping",
            "   warm engine stepping (sum of wall_time_s): "
            + ", ".join(f"{e} {s:.1f} s" for e, s in sorted(warm.items(), key=lambda kv: -kv[1])),
            f"   output: trajectories {_f(doc, 'suite_trajectories_bytes', MB)} MB, report.html "
            f"{_f(doc, 'suite_report_html_bytes', MB, '.2f')} MB, report.md "
            f"{_f(doc, 'suite_report_md_bytes', 1e3, '.0f')} KB, results.json "
            f"{_f(doc, 'suite_results_json_bytes', MB, '.2f')} MB", ""]


def _engine_lines(doc: dict) -> list[str]:
    """Each engine's loop overhead, and the engines skipped."""
    if "engine_step_s" not in doc:
        return []
    lines = [f"engine loops (bare loop vs adapter.simulate, {doc.get('engine_steps', '')} steps)"]
    for engine, res in doc["engine_step_s"].items():
        lines.append(f"   {engine:10s} {str((doc.get('engines') or {}).get(engine)):12s} bare "
                     f"{_ns(res['bare_step_s']):>10s}, freebody {_ns(res['freebody_step_s']):>10s} a step")
    for engine, why in (doc.get("skipped") or {}).items():
        lines.append(f"   {engine:10s} skipped: {why}")
    return lines


def _ns(s: float | None) -> str:
    return "-" if s is None else f"{s * 1e6:.2f} us" if s >= 1e-6 else f"{s * 1e9:.0f} ns"
