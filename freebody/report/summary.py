"""The plain-text summary table printed by ``freebody run``."""
from __future__ import annotations

from ..errors import printable
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_MAX,
                           POSITION_ERROR_MAX)
from ..run.records import STATUSES, Status


def fmt(x, spec: str = ".3e") -> str:
    """A number in a fixed format, '-' for None (undefined or not applicable)."""
    return "-" if x is None else format(x, spec)


def run_label(run: dict) -> str:
    """engine/integrator, with the precision when it is not float64."""
    label = f"{run['engine']}/{run['integrator']}"
    if run.get("precision", "float64") != "float64":
        label += f"/{run['precision']}"
    return label


def reproduced_text(match: dict) -> str:
    """What a ``matches_reference`` dict says the run reproduces: 'tie: a = b = c' when two or more
    maps are indistinguishable on the case, else the map's name ('' when none reproduces it)."""
    tie = [x for x in (match.get("indistinguishable") or []) if isinstance(x, str)]
    return f"tie: {' = '.join(tie)}" if len(tie) >= 2 else (match.get("integrator") or "")


def summary_table(runs: list[dict]) -> str:
    header = ("case", "engine/integrator", "dt", "status", "orient max", "L max rel", "E max rel",
              "pos max m", "reproduces")
    rows = []
    for r in runs:
        m = r.get("metrics") or {}
        match = r.get("matches_reference")
        if match:
            shown = reproduced_text(match) or f"none (closest {match.get('closest')})"
            repro = f"{shown} {fmt(match.get('max_orientation_diff_rad'), '.1e')}"
        else:
            repro = ""
        vs = r.get("vs_engine")
        if vs:
            diff = vs.get("max_orientation_diff_rad")
            repro += f"; vs {vs['engine']}/{vs['integrator']} " + (fmt(diff, ".1e") if diff is not None
                                                                    else vs.get("message", "-"))
        status = r["status"]
        rows.append((printable(r["case"]), printable(run_label(r)), f"{r['dt']:g}", status,
                     fmt(m.get(ORIENTATION_ERROR_MAX)), fmt(m.get(ANGULAR_MOMENTUM_ERROR_MAX_REL)),
                     fmt(m.get(ENERGY_ERROR_MAX_REL)), fmt(m.get(POSITION_ERROR_MAX)), repro))
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    lines = ["  ".join(f"{h:<{w}}" for h, w in zip(header, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    for row in rows:
        lines.append("  ".join(f"{c:<{w}}" for c, w in zip(row, widths)).rstrip())
    notes = [printable(f"  {r['case']} {run_label(r)} dt={r['dt']:g}: {r['status']}: {r['message']}")
             for r in runs if r["status"] != Status.OK and r.get("message")]
    if notes:
        lines.append("")
        lines.append("not ok:")
        lines.extend(dict.fromkeys(notes))
    counts = {s: sum(r["status"] == s for r in runs) for s in STATUSES}
    lines.append("")
    lines.append(", ".join(f"{n} {s}" for s, n in counts.items()) + f" ({len(runs)} runs)")
    return "\n".join(lines)
