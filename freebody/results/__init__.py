"""Results: the versioned results.json document and the per-run trajectory files (writing,
loading, checking), baselines stored from them, ``compare`` (the regression gate) and the pytest
helper :func:`assert_no_regression` (public path ``freebody.testing``); :mod:`.verdict` writes the
comparison as text, JSON or JUnit XML.  :mod:`.io` writes every
file freebody writes (atomically, with one permission rule) and reads JSON documents."""
from .baseline import make_baseline, store_baseline
from .compare import compare
from .document import document_header, load_results, load_trajectory, results_document
from .io import read_json, write_json_atomic, write_npz_atomic, write_text_atomic
from .testing import assert_no_regression
from .verdict import format_comparison, junit_xml, verdict_json

__all__ = ["make_baseline", "store_baseline", "compare", "format_comparison", "document_header",
           "load_results", "load_trajectory", "results_document", "read_json", "write_json_atomic",
           "write_npz_atomic", "write_text_atomic", "assert_no_regression", "junit_xml", "verdict_json"]
