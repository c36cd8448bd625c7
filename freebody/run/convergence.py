"""Observed order of convergence: a least-squares fit of log(error) against log(dt).

For every (case, engine, integrator, precision) that ran at >= 3 distinct time steps, and for each
metric in :data:`FITTED_METRICS`, the errors e(dt) are fitted as ``log e = p log dt + c``; ``p`` is
the observed order.  A point is *saturated*, and left out of the fit, when its error says nothing
about the time step: of order pi (the orientation is simply wrong) or below the truth's accuracy
floor.  The fit uses the unsaturated points if at least 3 remain; otherwise the order is null and
``reason`` says why.  Runs that are not ``ok`` (diverged, failed, skipped) have no usable error.

Each entry of the results.json ``"convergence"`` list::

    {"case", "engine", "integrator", "precision", "metric",   # metric: a results.json metrics key
     "order": float | null,         # observed order p (null when it cannot be fitted)
     "dts": [s, ...],               # every time step of the group, ascending
     "errors": [float | null, ...], # the metric at each of those dts (null: run not ok / undefined)
     "fitted_dts": [s, ...],        # the dts the fit used
     "log10_coefficient": float | null,  # c / ln 10: the fitted line is e = 10**c10 * dt**p
     "fit_rms_decades": float | null,    # fit quality: RMS residual of log10(error) about the line
     "saturated": bool,             # true when saturation left fewer than 3 points
     "reason": str | null}          # why there is no order, or a caveat about the one given

``fit_rms_decades`` says how well one power law describes the fitted points, in decades of error:
sqrt(mean((log10 e_i - log10 e_fit(dt_i))^2)).  0.01 means the points sit within about 2 % of the
line (a scheme in its asymptotic range: halving dt divides the error by 2**p at every step);
0.05 and more means the local slope changes across the dts (errors not yet, or no longer, in the
asymptotic range, or two error terms of different orders), so ``order`` is an average slope, not
a clean order.  With 3 points the line has 1 degree of freedom left, so a curved
series shows as a residual too.  Null when there is no order.
"""
from __future__ import annotations

import math

import numpy as np

from .. import tolerances as tol
from ..numbers import finite_or_none
from .metrics import ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_MAX
from .records import Status

FITTED_METRICS = (ORIENTATION_ERROR_MAX, ENERGY_ERROR_MAX_REL)
MIN_POINTS = 3  # two points always fit a line exactly: a third one makes the order a measurement

SHORT_NAMES = {ORIENTATION_ERROR_MAX: "orientation", ENERGY_ERROR_MAX_REL: "energy"}


def bounds(metric: str, precision: str = "float64") -> tuple[float, float]:
    """(floor, saturation) of a fitted metric: points outside (floor, saturation) are left out
    (the thresholds and their reasons: the convergence section of :mod:`freebody.tolerances`)."""
    single = precision in ("float32", "single")
    if metric == ORIENTATION_ERROR_MAX:
        return ((tol.CONVERGENCE_ORIENTATION_FLOOR_FLOAT32_RAD if single else tol.CONVERGENCE_ORIENTATION_FLOOR_RAD),
                tol.CONVERGENCE_ORIENTATION_SATURATED_RAD)
    if metric == ENERGY_ERROR_MAX_REL:
        return ((tol.CONVERGENCE_ENERGY_FLOOR_FLOAT32_REL if single else tol.CONVERGENCE_ENERGY_FLOOR_REL),
                tol.CONVERGENCE_ENERGY_SATURATED_REL)
    raise KeyError(f"no saturation bounds for metric {metric!r}")


def group_key(run: dict) -> tuple[str, str, str, str]:
    """(case, engine, integrator, precision): the runs that differ only in dt."""
    return (run["case"], run["engine"], run["integrator"], run.get("precision") or "float64")


def fit_orders(runs: list[dict]) -> list[dict]:
    """The ``"convergence"`` list of results.json for these runs (see the module docstring).

    Deterministic: groups in the order they first appear in ``runs``, metrics in FITTED_METRICS order.
    """
    groups: dict[tuple, dict[float, dict]] = {}
    for run in runs:
        dt = finite_or_none(run.get("dt"))
        if dt is None or dt <= 0:
            continue
        groups.setdefault(group_key(run), {}).setdefault(dt, run)  # first run of a repeated dt wins
    out = []
    for key, by_dt in groups.items():
        if len(by_dt) < MIN_POINTS:
            continue
        dts = sorted(by_dt)
        for metric in FITTED_METRICS:
            out.append(_fit_one(key, metric, dts, [by_dt[d] for d in dts]))
    return out


def _fit_one(key: tuple, metric: str, dts: list[float], runs: list[dict]) -> dict:
    case, engine, integrator, precision = key
    errors = [(finite_or_none((r.get("metrics") or {}).get(metric)) if r.get("status") == Status.OK else None)
              for r in runs]
    entry = {"case": case, "engine": engine, "integrator": integrator, "precision": precision,
             "metric": metric, "order": None, "dts": dts, "errors": errors, "fitted_dts": [],
             "log10_coefficient": None, "fit_rms_decades": None, "saturated": False, "reason": None}
    floor, high = bounds(metric, precision)
    usable = [(d, e) for d, e in zip(dts, errors) if e is not None]
    not_ok = [f"{d:g} ({r.get('status')})" for d, r in zip(dts, runs) if r.get("status") != Status.OK]
    n_high = sum(e > high for _, e in usable)
    n_low = sum(e < floor for _, e in usable)
    kept = [(d, e) for d, e in usable if floor <= e <= high]
    notes = []
    if not_ok:
        notes.append(f"not ok at dt = {', '.join(not_ok)}")
    if n_high:
        notes.append(f"{n_high} point(s) saturated above {high:g} (error of order pi)"
                     if metric == ORIENTATION_ERROR_MAX else
                     f"{n_high} point(s) saturated above {high:g} (error as large as the energy)")
    if n_low:
        notes.append(f"{n_low} point(s) at the accuracy floor (< {floor:g}: "
                     f"{'float32 round-off' if precision in ('float32', 'single') else 'the truth or round-off'})")
    if len(kept) < MIN_POINTS:
        entry["saturated"] = bool(n_high or n_low)
        head = "saturated" if entry["saturated"] else "too few usable points"
        entry["reason"] = f"{head}: {len(kept)} of {len(dts)} points usable; " + "; ".join(
            notes or [f"metric undefined ({metric} is null)"])
        return entry
    x = np.log([d for d, _ in kept])
    y = np.log([e for _, e in kept])
    p, c = np.polyfit(x, y, 1)
    entry["order"] = float(p)
    entry["log10_coefficient"] = float(c / math.log(10.0))
    entry["fit_rms_decades"] = float(np.sqrt(np.mean((y - (p * x + c)) ** 2)) / math.log(10.0))
    entry["fitted_dts"] = [d for d, _ in kept]
    steps = {r.get("steps") for r in runs}
    horizons = {round(float(r["steps"]) * d, tol.CONVERGENCE_HORIZON_DECIMALS)
                for r, d in zip(runs, dts) if finite_or_none(r.get("steps"))}
    if len(horizons) > 1 and len(steps) == 1:
        notes.append("the horizon is a fixed number of steps, so this is a local (one-horizon) order")
    entry["reason"] = "; ".join(notes) if notes else None
    return entry
