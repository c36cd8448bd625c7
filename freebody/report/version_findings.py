"""Findings of an engine's versions side by side: what changed between two or more versions of an
engine that one results document ran (``freebody run --engine mujoco==3.1.6 --engine mujoco``).

- one ``version-change`` finding per (case, engine run) whose status, scheme (the reference map its
  runs reproduce) or observed order changed between the first and the last version
  (:func:`freebody.envs.versions.side_by_side` decides, as ``freebody compare --against``);
- one per engine default that freebody overrides whose default differs between the versions
  (freebody sets it, so the runs do not use it; shown because an upgrade moved it).

Each finding links to the "Engine versions side by side" table (anchor :data:`VERSIONS_ANCHOR`).
Reports present these findings; they judge nothing that the side-by-side table does not show.
"""
from __future__ import annotations

import math

from ..envs.versions import VersionCell, VersionRow, engine_of, side_by_side, version_groups
from .findings import KINDS, Finding

KIND = "version-change"
VERSIONS_ANCHOR = "versions"  # the id of report.html's "Engine versions side by side" section
SOURCE = "versions side by side"


def _version(c: VersionCell) -> str:
    """'mujoco==3.1.6' or 'mujoco (4.0.0)': the name as run, with the version it reported when the
    name does not say it."""
    return c.engine if not c.version or c.version in c.engine else f"{c.engine} ({c.version})"


def _order(c: VersionCell) -> str:
    if c.order is None or not math.isfinite(c.order):
        return "-"
    return (">= " if c.order_at_least else "") + format(c.order, ".2f")


def _row_text(row: VersionRow) -> str:
    a, b = row.cells[0], row.cells[-1]
    parts = []
    if "scheme" in row.changes:
        parts.append(f"scheme {a.scheme} -> {b.scheme}")
    if "order" in row.changes:
        kind = {"fit": "fitted", "slope": "slope between two time steps"}.get(row.order_kind or "", "")
        parts.append(f"observed order {_order(a)} -> {_order(b)}" + (f" ({kind})" if kind else ""))
    if "status" in row.changes:
        parts.append(f"status {a.status} -> {b.status}")
    return f"from {_version(a)} to {_version(b)}: " + "; ".join(parts)


def _label(row: VersionRow) -> str:
    return f"{row.engine}/{row.integrator}" + ("" if row.precision == "float64" else f"/{row.precision}")


def _default_changes(runs: list[dict]) -> list[Finding]:
    """A finding per (engine, setting) whose default (``engine_settings[key]["default"]``, first run
    of each name) differs between the first and the last version of an engine."""
    groups = version_groups({"runs": runs})
    out = []
    memo: dict[str, str] = {}
    for base, names in groups.items():
        defaults: dict[str, dict] = {n: {} for n in names}
        sets: dict[str, object] = {}
        for r in runs:
            if not isinstance(r.get("engine"), str) or engine_of(r["engine"], memo) != base:
                continue
            for k, v in (r.get("engine_settings") or {}).items():
                if isinstance(v, dict) and "default" in v:
                    defaults[r["engine"]].setdefault(k, v["default"])
                    sets.setdefault(k, v.get("set"))
        first, last = names[0], names[-1]
        for k, was in defaults[first].items():
            if k in defaults[last] and defaults[last][k] != was:
                now = defaults[last][k]
                out.append(Finding(KINDS[KIND][0], KIND, "", None, base, base,
                                   f"the default of {k} changed from {was!r} ({first}) to {now!r} ({last}); "
                                   f"freebody sets it to {sets.get(k)!r}, so no run uses either default",
                                   source=f"engine_settings ({SOURCE})"))
    return out


def version_findings(runs: list[dict], convergence: list[dict] | None = None) -> list[Finding]:
    """The ``version-change`` findings of a results document's runs (``convergence``: its fitted
    orders, results.json ``convergence``; without them the orders are the slopes of the table)."""
    doc = {"runs": runs} if convergence is None else {"runs": runs, "convergence": convergence}
    out = []
    for row in side_by_side(doc):
        if row.changes:
            out.append(Finding(KINDS[KIND][0], KIND, row.case, None, _label(row), row.engine, _row_text(row),
                               size_rad=row.final_angle_rad, source=SOURCE))
    return out + _default_changes(runs)
