"""The one rule for a number that may be missing: a finite float, or None (JSON null).  Metrics,
results.json, comparisons, convergence fits and reports all read and write numbers through it."""
from __future__ import annotations

import math

import numpy as np


def finite_or_none(x) -> float | None:
    """A finite float, or None for anything else (None, NaN, inf, a string, a bool)."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.floating, np.integer)):
        return None
    try:
        x = float(x)
    except OverflowError:  # an integer beyond float64's range (e.g. 400 digits in a JSON file)
        return None
    return x if math.isfinite(x) else None
