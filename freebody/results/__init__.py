"""Results: the versioned results.json document and the per-run trajectory files (writing,
loading, checking), baselines stored from them, ``compare`` (the regression gate) and the pytest
helper :func:`assert_no_regression` (public path ``freebody.testing``)."""
from .baseline import make_baseline, store_baseline
from .compare import compare, format_comparison
from .document import load_results, load_trajectory, results_document
from .testing import assert_no_regression

__all__ = ["make_baseline", "store_baseline", "compare", "format_comparison", "load_results",
           "load_trajectory", "results_document", "assert_no_regression"]
