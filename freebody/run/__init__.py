"""Running the matrix: expand the selection into runs (:mod:`.matrix`), execute each one on its
engine (:mod:`.execute`), judge it against the truth and the reference maps (:mod:`.judge`,
:mod:`.metrics`, :mod:`.convergence`), and drive many runs through isolated worker processes that
share truths (:mod:`.suite`, :mod:`.executor`, :mod:`.worker`, :mod:`.sharedcache`,
:mod:`.dask_executor`).  :mod:`.records` holds the records a run passes through;
:mod:`.progress` the progress display of runs and sweeps; :mod:`.selfcheck` the convention
self-checks of ``freebody conventions``.
"""
from .execute import execute
from .judge import SCHEME_CANDIDATES, TruthCache, compare_with_engine, identify, judge_run, scheme_candidates
from .matrix import (engine_integrators, engine_precisions, expand, select_engines, select_integrators,
                     select_precisions)
from .records import PRECISIONS, STATUSES, RunOutput, RunResult, RunSpec, Simulated, Status

__all__ = ["execute", "SCHEME_CANDIDATES", "TruthCache", "compare_with_engine", "identify", "judge_run",
           "scheme_candidates", "engine_integrators", "engine_precisions", "expand", "select_engines",
           "select_integrators", "select_precisions", "PRECISIONS", "STATUSES", "RunOutput", "RunResult",
           "RunSpec", "Simulated", "Status"]
