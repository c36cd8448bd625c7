"""pytest helpers for regression gates: the public path of :mod:`freebody.results.testing`.

    from freebody.testing import assert_no_regression
"""
from .results.testing import assert_no_regression

__all__ = ["assert_no_regression"]
