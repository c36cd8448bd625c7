"""Engine versions side by side: one results document holding runs of several versions of one
engine (``--engine mujoco==3.1.6 --engine mujoco==4.0.0``), read two ways.

- :func:`side_by_side`: a row per (engine, case, integrator, precision) that two or more versions
  ran: each version's status, scheme (the reference map its runs reproduce), largest orientation
  error per time step and observed order (fitted over 3 or more time steps, else the slope between
  two), and the difference between the versions (the angle between their final orientations, rad;
  whether the status, scheme or order changed).  The report's "Engine
  versions" section and ``freebody compare --against`` read it.
- :func:`split_sides`: the runs of one engine name as a baseline and those of another as the
  current results, both renamed to one label, for :func:`freebody.results.compare.compare`
  (``freebody compare RESULTS --engine mujoco==3.1.6 --against mujoco==4.0.0``).

A versioned engine name is the engine and a pip version specifier (``mujoco==3.1.6``, see
:func:`freebody.adapters.base.split_engine_name`); the unversioned name (``mujoco``) is the version
installed beside freebody, and counts as one more version of the engine.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .. import tolerances as tol
from ..adapters.base import UnknownEngine, base_engine, split_engine_name
from ..errors import InputError
from ..results.compare import run_key, scheme_of, scheme_text


def _base(engine: str, _memo: dict[str, str] | None = None) -> str:
    """The engine of a name (versioned or not); ``_memo`` caches the answers of one document
    (looking an engine up reads the entry points: milliseconds, times thousands of runs)."""
    if _memo is not None and engine in _memo:
        return _memo[engine]
    try:
        out = base_engine(engine)
    except UnknownEngine:  # an engine this freebody does not know (a third party's): its own name
        try:
            out = split_engine_name(engine)[0]
        except UnknownEngine:  # not even ENGINE==VERSION: the name as it is
            out = engine
    if _memo is not None:
        _memo[engine] = out
    return out


def engine_of(engine: str, memo: dict[str, str] | None = None) -> str:
    """The registered engine of an engine name as run (``mujoco==3.1.6`` -> ``mujoco``); an engine
    this freebody does not know keeps the name before its version specifier.  ``memo``: a dict
    caching the answers of one document."""
    return _base(engine, memo)


def version_groups(doc: dict) -> dict[str, list[str]]:
    """engine -> its names in the document's runs (in run order), for engines run under two or more
    names (versions)."""
    names: dict[str, dict[str, None]] = {}
    memo: dict[str, str] = {}
    for r in doc.get("runs") or []:
        e = r.get("engine")
        if isinstance(e, str):
            names.setdefault(_base(e, memo), {})[e] = None
    return {b: list(n) for b, n in names.items() if len(n) > 1}


@dataclass
class VersionCell:
    """One version's runs in a side-by-side row (one per time step)."""

    engine: str  # the engine name as run (mujoco==3.1.6)
    version: str | None  # the version the engine reported
    status: str  # "ok", or the first status of its runs that is not
    scheme: str  # the reference map(s) its runs reproduce, "none (closest ...)", or "-"
    errors: dict[float, float | None]  # dt -> largest orientation error, rad
    order: float | None  # observed order of the orientation error (see VersionRow.order_kind)
    # the order is a lower bound: the error at the smaller dt is below the truth's accuracy floor
    # (the true error is smaller still, the true slope steeper)
    order_at_least: bool = False


@dataclass
class VersionRow:
    """(engine, case, integrator, precision) that two or more versions of an engine ran."""

    engine: str
    case: str
    integrator: str
    precision: str
    dts: list[float]
    cells: list[VersionCell]
    # "fit": results.json's fitted order (3 or more dts); "slope": the slope of log error over
    # log dt between the two time steps (2 dts); None: one dt or no error to use
    order_kind: str | None
    # largest angle between the first and the last version's final orientations over the dts
    # both ran ok, rad (None: no such dt)
    final_angle_rad: float | None
    changes: list[str] = field(default_factory=list)  # of "status", "scheme", "order"


def _orders(doc: dict) -> dict[tuple, float]:
    """(case, engine, integrator, precision) -> fitted order of the orientation error."""
    from ..report.render import convergence_of

    out = {}
    for e in convergence_of(doc):
        if e.get("metric") == "orientation_error_max_rad" and isinstance(e.get("order"), (int, float)):
            out.setdefault((e.get("case"), e.get("engine"), e.get("integrator"), e.get("precision") or "float64"),
                           float(e["order"]))
    return out


def _slope(errors: dict[float, float | None], precision: str) -> tuple[float | None, bool]:
    """(slope of log(error) over log(dt) between two time steps, whether it is a lower bound).

    None when the larger dt's error is saturated (of order pi) or either is unusable; a lower bound
    when the smaller dt's error is below the accuracy floor (:func:`freebody.run.convergence.bounds`):
    the floor is then used as that error, so the slope shown is the least the order can be."""
    from ..run.convergence import bounds

    floor, high = bounds("orientation_error_max_rad", precision)
    pts = [(d, e) for d, e in sorted(errors.items()) if isinstance(e, (int, float)) and math.isfinite(e) and e > 0]
    if len(pts) != 2 or pts[0][0] == pts[1][0]:
        return None, False
    (d0, e0), (d1, e1) = pts  # d0 < d1
    if e1 > high or e1 <= floor:
        return None, False
    at_least = e0 < floor
    return math.log(e1 / max(e0, floor)) / math.log(d1 / d0), at_least


def _angle(a: dict | None, b: dict | None) -> float | None:
    """The rotation angle between two final states' orientations (q or -q), rad."""
    try:
        qa, qb = a["quaternion_wxyz"], b["quaternion_wxyz"]
        na = math.sqrt(sum(x * x for x in qa))
        nb = math.sqrt(sum(x * x for x in qb))
        dot = abs(sum(x * y for x, y in zip(qa, qb))) / (na * nb)
    except (TypeError, KeyError, ZeroDivisionError, ValueError):
        return None
    if not math.isfinite(dot):
        return None
    return 2.0 * math.acos(min(1.0, dot))


def _schemes(runs: list[dict]) -> tuple[str, set | None]:
    """(text, set of maps) of the schemes a version's runs reproduce over the time steps: the maps
    every identified run reproduces (a tie on one dt narrowed by the others), else each run's."""
    found = [scheme_of(r) for r in runs]
    known = [s for s in found if s is not None]
    if not known:
        return "-", None
    common = set(known[0]).intersection(*map(set, known[1:])) if all(known) else set()
    if common:
        return " = ".join(x for x in known[0] if x in common), common
    texts = dict.fromkeys(scheme_text(s, r) for s, r in zip(found, runs) if s is not None)
    return " / ".join(texts), set()


def _order_changed(a: VersionCell, b: VersionCell) -> bool:
    """Whether two versions' orders differ by more than COMPARE_ORDER_CHANGE (a lower bound counts
    only when it exceeds the other order by that much)."""
    if a.order is None or b.order is None or (a.order_at_least and b.order_at_least):
        return False
    if a.order_at_least:
        return a.order - b.order > tol.COMPARE_ORDER_CHANGE
    if b.order_at_least:
        return b.order - a.order > tol.COMPARE_ORDER_CHANGE
    return abs(b.order - a.order) > tol.COMPARE_ORDER_CHANGE


def side_by_side(doc: dict) -> list[VersionRow]:
    """A row per (engine, case, integrator, precision) that two or more versions of an engine ran,
    in the order of the document's runs (see the module docstring)."""
    groups = version_groups(doc)
    if not groups:
        return []
    orders = _orders(doc)
    versions = doc.get("engines") or {}
    rows: dict[tuple, dict[str, dict[float, dict]]] = {}
    memo: dict[str, str] = {}
    for r in doc.get("runs") or []:
        base = _base(r["engine"], memo) if isinstance(r.get("engine"), str) else None
        if base not in groups:
            continue
        case, _, integ, prec, dt = run_key(r)
        rows.setdefault((base, case, integ, prec), {}).setdefault(r["engine"], {}).setdefault(dt, r)
    out = []
    for (base, case, integ, prec), by_name in rows.items():
        if len(by_name) < 2:
            continue
        names = [n for n in groups[base] if n in by_name]
        dts = sorted({d for runs in by_name.values() for d in runs})
        fitted = all((case, n, integ, prec) in orders for n in names)
        cells, scheme_sets = [], []
        for n in names:
            runs = [by_name[n][d] for d in sorted(by_name[n])]
            bad = [r.get("status") for r in runs if r.get("status") != "ok"]
            errors = {d: (by_name[n][d].get("metrics") or {}).get("orientation_error_max_rad")
                      if by_name[n][d].get("status") == "ok" else None for d in sorted(by_name[n])}
            text, maps = _schemes(runs)
            scheme_sets.append(maps)
            order, at_least = (orders.get((case, n, integ, prec)), False) if fitted else _slope(errors, prec)
            version = next((r.get("engine_version") for r in runs if r.get("engine_version")), None)
            cells.append(VersionCell(n, version or versions.get(n), bad[0] if bad else "ok", text, errors, order,
                                     at_least))
        kind = ("fit" if fitted else "slope") if any(c.order is not None for c in cells) else None
        s0, s1 = scheme_sets[0], scheme_sets[-1]
        scheme_changed = s0 is not None and s1 is not None and bool(s0 or s1) and not (s0 & s1)
        order_changed = _order_changed(cells[0], cells[-1])
        first, last = by_name[names[0]], by_name[names[-1]]
        angles = [_angle(first[d].get("final_state"), last[d].get("final_state")) for d in dts
                  if d in first and d in last and first[d].get("status") == last[d].get("status") == "ok"]
        angles = [a for a in angles if a is not None]
        changes = [w for w, c in (("status", len({c.status for c in cells}) > 1), ("scheme", scheme_changed),
                                  ("order", order_changed)) if c]
        out.append(VersionRow(base, case, integ, prec, dts, cells, kind, max(angles) if angles else None, changes))
    return out


def split_sides(doc: dict, engine: str, against: str) -> tuple[dict, dict]:
    """(baseline, current): the runs of ``engine`` and those of ``against`` from one results
    document, each renamed to the engine's common name (``mujoco`` for two MuJoCo versions, else
    ``engine|against``) so that :func:`~freebody.results.compare.compare` matches them run by run;
    ``engines`` and ``convergence`` renamed alike.  InputError when either has no run."""
    known = list(dict.fromkeys(r.get("engine") for r in doc.get("runs") or []))
    for option, name in (("--engine", engine), ("--against", against)):
        if name not in known:
            raise InputError(f"{option} {name}: no run of this engine in the results; engines there: "
                             f"{', '.join(str(k) for k in known)}")
    if engine == against:
        raise InputError(f"--against {against}: the same engine as --engine; name two versions")
    label = _base(engine) if _base(engine) == _base(against) else f"{engine}|{against}"

    def side(name: str) -> dict:
        out = {k: v for k, v in doc.items() if k not in ("runs", "engines", "convergence")}
        out["runs"] = [{**r, "engine": label} for r in doc.get("runs") or [] if r.get("engine") == name]
        out["engines"] = {label: (doc.get("engines") or {}).get(name)}
        out["convergence"] = [{**e, "engine": label} for e in doc.get("convergence") or []
                              if isinstance(e, dict) and e.get("engine") == name]
        return out

    return side(engine), side(against)


def align_engine_names(baseline: dict, current: dict) -> tuple[dict, dict, list[tuple[str, str, str]]]:
    """(baseline, current, renamed): the two results documents with an engine's runs named alike
    on both sides when each side ran that engine under one name and the names differ (a baseline
    of ``--engine mujoco==3.1.6`` against a run of ``--engine mujoco``, the installed 4.0.0), so
    that :func:`~freebody.results.compare.compare` matches them run by run as it matches two
    versions of one file (``--against``) and reports their scheme, order and setting changes.

    Both sides take the engine's registered name (``mujoco``); ``runs``, ``engines`` and
    ``convergence`` are renamed, the documents given are not modified.  An engine run under two or
    more names on a side (both versions in one file) keeps its names: its runs match by name.
    renamed : (common name, baseline name, current name) of every engine renamed."""
    def names(doc: dict, memo: dict) -> dict[str, list[str]]:
        out: dict[str, dict[str, None]] = {}
        for r in doc.get("runs") or []:
            if isinstance(r.get("engine"), str):
                out.setdefault(_base(r["engine"], memo), {})[r["engine"]] = None
        return {b: list(n) for b, n in out.items()}

    memo: dict[str, str] = {}
    nb, nc = names(baseline, memo), names(current, memo)
    rename_b, rename_c, renamed = {}, {}, []
    for base in nb:
        if base in nc and len(nb[base]) == 1 and len(nc[base]) == 1 and nb[base] != nc[base]:
            (b_name,), (c_name,) = nb[base], nc[base]
            rename_b[b_name], rename_c[c_name] = base, base
            renamed.append((base, b_name, c_name))
    if not renamed:
        return baseline, current, []

    def apply(doc: dict, mapping: dict[str, str]) -> dict:
        out = dict(doc)
        out["runs"] = [{**r, "engine": mapping[r["engine"]]} if r.get("engine") in mapping else r
                       for r in doc.get("runs") or []]
        if isinstance(doc.get("engines"), dict):
            out["engines"] = {mapping.get(e, e): v for e, v in doc["engines"].items()}
        if isinstance(doc.get("convergence"), list):
            out["convergence"] = [{**e, "engine": mapping[e["engine"]]}
                                  if isinstance(e, dict) and e.get("engine") in mapping else e
                                  for e in doc["convergence"]]
        return out

    return apply(baseline, rename_b), apply(current, rename_c), renamed


VERSIONS_NOTE = ("Runs that two or more versions of an engine ran, one line per version: the reference "
                 "map its runs reproduce, its largest orientation error at each time step, its observed "
                 "order (fitted over 3 or more time steps; over 2, the slope between them, '>=' when the "
                 "smaller step reached the truth's accuracy floor), and, on the first line, what changed "
                 "between the first and the last version and the largest angle between their final "
                 "orientations.")


def version_table(rows: list[VersionRow]) -> tuple[tuple[str, ...], list[tuple]]:
    """(header, rows of text) of the side-by-side rows, one line per version, for the reports."""
    def num(x, spec=".3e"):
        return "-" if not isinstance(x, (int, float)) or not math.isfinite(x) else format(x, spec)

    header = ("case", "engine run", "version", "status", "reproduces", "orientation max (rad) per dt",
              "order p", "changed", "final angle (rad)")
    out = []
    for r in rows:
        run = f"{r.engine}/{r.integrator}" + ("" if r.precision == "float64" else f"/{r.precision}")
        for i, c in enumerate(r.cells):
            errs = ", ".join(f"{d:g}: {num(c.errors.get(d))}" for d in r.dts if d in c.errors)
            order = "-" if c.order is None else ((">= " if c.order_at_least else "") + format(c.order, ".2f")
                                                 + (" (slope)" if r.order_kind == "slope" else ""))
            first = i == 0
            out.append((r.case if first else "", run if first else "", c.version or c.engine, c.status, c.scheme,
                        errs, order, (", ".join(r.changes) or "nothing") if first else "",
                        num(r.final_angle_rad) if first else ""))
    return header, out
