"""Test helpers for projects that guard their numbers with freebody (pytest or any test runner).

    from freebody.testing import assert_no_regression

    def test_engine_upgrade_changes_nothing(tmp_path):
        freebody.cli.main(["run", "dzhanibekov", "--engine", "mujoco", "--out", str(tmp_path), "--quiet",
                           "--no-report"])
        assert_no_regression("reports/baselines/mujoco.json", tmp_path)
"""
from __future__ import annotations

from pathlib import Path


def assert_no_regression(baseline: str | Path | dict, current: str | Path | dict, *,
                         rtol: float | None = None, atol: float | None = None,
                         tolerances: str | Path | None = None):
    """Fail (AssertionError with the comparison table) when ``current`` regressed against ``baseline``.

    baseline, current : a baseline file, a results.json, a run directory, or a loaded results dict.
    rtol, atol, tolerances : as ``freebody compare --rtol/--atol/--tolerances`` (defaults: the
        regression-gate constants of :mod:`freebody.tolerances`).
    Returns the :class:`freebody.results.compare.Comparison` when nothing regressed.  Unusable input raises
    :class:`freebody.errors.InputError`.
    """
    __tracebackhide__ = True  # pytest: show the failure, not this frame
    from .compare import compare, load_side, resolve_tolerances

    src = lambda x: "(in memory)" if isinstance(x, dict) else str(x)  # noqa: E731
    result = compare(load_side(baseline, "baseline"), load_side(current, "current"),
                     resolve_tolerances(tolerances, rtol, atol), sources=(src(baseline), src(current)))
    if result.regressions:
        raise AssertionError("freebody regression against the baseline:\n" + result.table())
    return result
