"""Reading a run's scheme identification (results.json ``matches_reference``, written by
:func:`freebody.run.judge.identify`): its verdict and the words every reader prints for it.

The verdict (``matches_reference["verdict"]``; results written before schema 4 have none, and
the migration on load gives them the one their other keys imply, :func:`implied_verdict`):

- ``reproduces``: one map is within its round-off level of the run and no other map is nearer by
  more than round-off (``integrator``, ``indistinguishable`` == [integrator]);
- ``indistinguishable``: several maps are within their levels of the run and of each other: the case
  (in the run's precision) cannot tell them apart (``indistinguishable``, ``integrator`` its first);
- ``closest``: no map reproduces the run; ``closest`` is the nearest (``integrator`` None);
- ``undecidable``: the maps that could match the run identify nothing on this case (their round-off
  levels reach the cap, or their perturbed copies blow up; ``undecidable`` lists them).
"""
from __future__ import annotations

REPRODUCES = "reproduces"
INDISTINGUISHABLE = "indistinguishable"
CLOSEST = "closest"
UNDECIDABLE = "undecidable"
VERDICTS = (REPRODUCES, INDISTINGUISHABLE, CLOSEST, UNDECIDABLE)


def _names(x) -> list[str]:
    return [v for v in (x or []) if isinstance(v, str)] if isinstance(x, (list, tuple)) else []


def verdict(m: dict | None) -> str | None:
    """The verdict of a ``matches_reference`` dict (None when there is none: a reference run, a
    run that was not judged)."""
    return m["verdict"] if isinstance(m, dict) else None


def implied_verdict(m: dict) -> str:
    """The verdict a ``matches_reference`` written before schema 4 (without ``verdict``) implies, as
    its readers took it (used by the migration on load, :mod:`freebody.results.document`): a map
    named in ``integrator`` is reproduced (indistinguishable with two or more maps in the tie),
    else a ``closest`` map is the closest, else nothing could be decided."""
    if isinstance(m.get("integrator"), str):
        return INDISTINGUISHABLE if len(_names(m.get("indistinguishable"))) >= 2 else REPRODUCES
    return CLOSEST if isinstance(m.get("closest"), str) else UNDECIDABLE


def reproduced(m: dict | None) -> tuple[str, ...]:
    """The maps the run reproduces: its tie in candidate order, (integrator,) alone, () when it
    reproduces none (closest, undecidable, not judged)."""
    if verdict(m) not in (REPRODUCES, INDISTINGUISHABLE):
        return ()
    tie = _names(m["indistinguishable"])
    return tuple(tie) if tie else ((m["integrator"],) if isinstance(m["integrator"], str) else ())


def tie_text(maps: tuple[str, ...] | list[str], precision: str | None = "float64") -> str:
    """The words of reproduced maps: the map's name; 'tie: a = b' of a float64 tie, 'float32
    cannot tell these apart: a, b' of a tie in float32 (its round-off is what joins them)."""
    maps = list(maps)
    if len(maps) < 2:
        return maps[0] if maps else ""
    if precision and precision != "float64":
        return f"{precision} cannot tell these apart: {', '.join(maps)}"
    return f"tie: {' = '.join(maps)}"


def text(m: dict | None, precision: str | None = "float64", diff_format: str = ".1e") -> str:
    """One phrase for the verdict: the reproduced map (or tie), 'closest: M (d rad, r x its level)',
    'undecidable here (closest M, d rad)'; '' when nothing was judged."""
    v = verdict(m)
    if v is None:
        return ""
    d = m["max_orientation_diff_rad"]
    dist = f"{d:{diff_format}} rad" if isinstance(d, (int, float)) else "- rad"
    if v in (REPRODUCES, INDISTINGUISHABLE):
        return tie_text(reproduced(m), precision)
    closest = m["closest"] if isinstance(m["closest"], str) else None
    if v == CLOSEST and closest:
        r = m["ratios"].get(closest)
        ratio = f", {r:.2g} x its round-off level" if isinstance(r, (int, float)) else ""
        return f"closest: {closest} ({dist}{ratio})"
    return f"undecidable here (closest {closest}, {dist})" if closest else "undecidable here"
