"""The judgement of a run stored with it (results.json run field ``judgement``, schema 5): the
per-run facts that the findings and the report tables present, computed once by one pure function
of the run's stored fields, :func:`run_judgement`.

The run layer calls it when it records a run (:func:`freebody.run.judge.judge_run`); the schema-5
migration (:func:`freebody.results.document.migrate`) calls it on the fields of an older
document's runs, so an old baseline's findings are today's.  Readers (:mod:`freebody.report.findings`,
:mod:`freebody.report.data`) read these facts and judge nothing of a run again; what compares runs
with each other (pairs, scheme groups, outliers, majorities) stays with them: that is presenting a
set of runs.

``judgement``::

    {"scheme": str | null,            # the map the run reproduces (the first of its tie) or, reproducing
                                      #   none, its closest map; null: not judged (a reference run, a run
                                      #   that is not ok, a run without identification)
     "reproduced": bool | null,       # whether it reproduces ``scheme`` (null: not judged)
     "schemes": [str],                # the maps it reproduces (its tie, in candidate order), [] for none
     "scheme_distance_rad": float | null,  # its largest orientation difference from ``scheme`` (rad)
     "scheme_level_rad": float | null,     # that map's round-off level on the run (rad, last sample,
                                           #   floored at SCHEME_ROUNDOFF_FLOOR_RAD)
     "scheme_ratio": float | null,         # max over samples of difference / level (<= 1: reproduces)
     "saturated": bool,               # reproduces no map and is as far from its closest as a lost
                                      #   orientation (beyond CONVERGENCE_ORIENTATION_SATURATED_RAD)
     "order": int | null,             # the run's formal order: a reference run's integrator's; an engine
                                      #   run's, the lowest of the maps it reproduces (or of its closest)
     "order_maps": [[str, int | null]],  # the maps an expected order is taken from, with their formal
                                      #   orders: its tie, else its closest map; [] when not judged or
                                      #   saturated
     "blew_up": bool,                 # an ok run whose |w| or kinetic energy passed the blow-up bounds
                                      #   (``state_growth["blow_up_t_s"]``)
     "capped": bool,                  # an ok run whose |w| dt passed its engine's declared rotation cap
                                      #   per step (``state_growth["rotation_cap_t_s"]``)
     "non_unit_quaternion": bool}     # an ok run whose quaternions, as its engine handed them out, are
                                      #   not unit: metric ``quaternion_norm_error_max`` beyond
                                      #   QUATERNION_NORM_ROUNDOFF of its precision (schema 6; False
                                      #   when the metric is unknown: a run written before)
"""
from __future__ import annotations

from .. import tolerances as tol
from ..adapters.base import REFERENCE_ENGINE
from ..numbers import finite_or_none
from . import identification

JUDGEMENT = "judgement"  # the results.json run field
OK = "ok"  # freebody.run.records.Status.OK (a StrEnum: equal to its string); results/ imports no run/


def match(run: dict) -> dict | None:
    """The run's ``matches_reference`` when it is an identified engine run (never a reference
    run's: its runs *are* the maps), else None."""
    m = run.get("matches_reference")
    return m if isinstance(m, dict) and run["engine"] != REFERENCE_ENGINE else None


def map_level(m: dict | None, name: str) -> float | None:
    """The round-off level (rad, at the run's last sample) of map ``name`` in a ``matches_reference``
    ``m``: its ``levels_rad``, else ``threshold_rad`` when ``name`` is the closest map; floored at
    SCHEME_ROUNDOFF_FLOOR_RAD."""
    m = m or {}
    level = finite_or_none((m.get("levels_rad") or {}).get(name))
    if level is None and m.get("closest") == name:
        level = finite_or_none(m.get("threshold_rad"))
    return None if level is None else max(level, tol.SCHEME_ROUNDOFF_FLOOR_RAD)


def map_distance(m: dict | None, name: str) -> float | None:
    """The largest orientation difference (rad) from map ``name`` in a ``matches_reference`` ``m``."""
    m = m or {}
    d = finite_or_none((m.get("candidates") or {}).get(name))
    if d is None and m.get("closest") == name:
        d = finite_or_none(m.get("max_orientation_diff_rad"))
    return d


def map_ratio(m: dict | None, name: str) -> float | None:
    """max over samples of (difference from map ``name``) / (its round-off level): <= 1 reproduces."""
    r = finite_or_none(((m or {}).get("ratios") or {}).get(name))
    if r is None:
        d, level = map_distance(m, name), map_level(m, name)
        r = d / level if d is not None and level else None
    return r


def map_order(name: str) -> int | None:
    """The formal order of a reference map (reference integrators and engine-equivalent maps)."""
    from ..reference_impl.engine_maps import ENGINE_MAPS
    from ..reference_impl.integrators import INTEGRATORS

    entry = INTEGRATORS.get(name) or ENGINE_MAPS.get(name)
    return entry.order if entry is not None else None


def _scheme(run: dict, m: dict | None) -> tuple[str, bool] | None:
    """(map, reproduced) of a judged ok engine run, or None (see ``scheme`` in the module docstring)."""
    if m is None or run["status"] != OK:
        return None
    tie = identification.reproduced(m)
    if tie:
        return tie[0], True
    if isinstance(m.get("closest"), str):
        return m["closest"], False
    return None


def _growth_flags(run: dict) -> tuple[bool, bool]:
    """(blew_up, capped) of a run from its ``state_growth`` (None: a run without samples, or an
    older document that has none)."""
    g = run.get("state_growth")
    if run["status"] != OK or not isinstance(g, dict):
        return False, False
    blew_up = finite_or_none(g.get("blow_up_t_s")) is not None
    capped = (finite_or_none(g.get("rotation_cap_t_s")) is not None
              and finite_or_none(g.get("step_rotation_cap_rad")) is not None)
    return blew_up, capped


def non_unit_quaternion(run: dict) -> bool:
    """Whether an ok run's largest |1 - |q|| (its metric ``quaternion_norm_error_max``) is beyond
    QUATERNION_NORM_ROUNDOFF of its precision (float64's for a precision it does not list)."""
    from ..run.metrics import QUATERNION_NORM_ERROR_MAX  # here: run/ imports this module

    metrics = run.get("metrics")
    x = finite_or_none(metrics.get(QUATERNION_NORM_ERROR_MAX)) if isinstance(metrics, dict) else None
    bound = tol.QUATERNION_NORM_ROUNDOFF.get(run.get("precision") or "float64",
                                             tol.QUATERNION_NORM_ROUNDOFF["float64"])
    return run["status"] == OK and x is not None and x > bound


def run_judgement(run: dict) -> dict:
    """The ``judgement`` of a run (see the module docstring) from its results.json fields
    (``engine``, ``integrator``, ``status``, ``matches_reference``, ``state_growth``, ``metrics``)."""
    m = match(run)
    key = _scheme(run, m)
    schemes = list(identification.reproduced(m)) if m is not None else []
    name, reproduced = key if key is not None else (None, None)
    distance = map_distance(m, name) if key else None
    saturated = key is not None and not reproduced and (
        distance is None or distance > tol.CONVERGENCE_ORIENTATION_SATURATED_RAD)
    if run["engine"] == REFERENCE_ENGINE:
        order = map_order(str(run["integrator"]))
    else:
        names = schemes or ([name] if key else [])
        orders = [o for o in map(map_order, names) if o is not None]
        order = min(orders) if orders else None
    order_maps = [] if key is None or saturated else [[n, map_order(n)] for n in (schemes or [name])]
    blew_up, capped = _growth_flags(run)
    return {"scheme": name, "reproduced": reproduced, "schemes": schemes,
            "scheme_distance_rad": distance, "scheme_level_rad": map_level(m, name) if key else None,
            "scheme_ratio": map_ratio(m, name) if key else None, "saturated": saturated,
            "order": order, "order_maps": order_maps, "blew_up": blew_up, "capped": capped,
            "non_unit_quaternion": non_unit_quaternion(run)}


def with_judgement(run: dict) -> dict:
    """A copy of a results.json run with its ``judgement`` (re)computed from its fields: what the run
    layer stores (the schema-5 migration, and runs built by hand, e.g. in tests)."""
    return {**run, JUDGEMENT: run_judgement(run)}
