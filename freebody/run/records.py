"""The records of a run: what to run (:class:`RunSpec`), what an engine produced
(:class:`Simulated`), and the judged outcome (:class:`RunResult`, serialised as a ``runs`` entry of
results.json, and :class:`RunOutput` with its arrays).

Plain data and its serialisation: building these records (a run's identity, its judgement) is
:mod:`freebody.run.judge`'s.

A run's status is data, a :class:`Status` (a ``StrEnum``: each member is its string, so it
compares equal to, and serialises as, ``"ok"`` etc.; :data:`STATUSES` lists the plain strings):
- ``ok``: the engine ran to the end and stayed within the case's bounds;
- ``diverged``: non-finite state, beyond the bounds (see :func:`freebody.run.metrics.divergence`), or the
  engine's own instability warning; ``diverged_at_s`` says when;
- ``failed``: the engine (or its adapter) raised; the message says what;
- ``skipped``: the engine is not installed; the message says how to install it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from ..adapters.base import REFERENCE_ENGINE
from ..reference_impl.conventions import Trajectory
from ..reference_impl.problem import Problem
from .metrics import Series


class Status(StrEnum):
    """A run's status: the fixed set (see the module docstring)."""

    OK = "ok"
    DIVERGED = "diverged"
    FAILED = "failed"
    SKIPPED = "skipped"


STATUSES = tuple(s.value for s in Status)  # ("ok", "diverged", "failed", "skipped"), plain strings
PRECISIONS = ("float32", "float64")  # floating-point precisions an engine may offer


@dataclass(frozen=True)
class RunSpec:
    """One run to execute.  ``problem`` is the validated case; ``integrator`` is spelt as the engine
    spells it ("*" for an engine that is not installed)."""

    problem: Problem
    engine: str
    integrator: str
    dt: float
    steps: int
    precision: str = "float64"

    @property
    def is_reference(self) -> bool:
        """Whether this run is one of freebody's own reference maps (the registry's reference
        engine): shared with scheme identification, never identified itself."""
        return self.engine == REFERENCE_ENGINE

    @property
    def key(self) -> tuple:
        """A run's identity (:func:`run_identity_key`)."""
        return run_identity_key(self.problem.name, self.engine, self.integrator, self.precision, self.dt)


def run_identity_key(case: str, engine: str, integrator: str, precision: str, dt: float) -> tuple:
    """A run's identity, in the one order every key of a run uses: (case, engine, integrator,
    precision, dt) (``RunSpec.key``, ``RunResult.key``, :func:`freebody.results.compare.run_key`)."""
    return (case, engine, integrator, precision, dt)


@dataclass(frozen=True)
class RunResult:
    """The outcome of one run: the serialised form is a ``runs`` entry of results.json."""

    case: str
    engine: str
    integrator: str
    precision: str
    dt: float
    steps: int
    status: Status
    message: str
    truth: str
    metrics: dict
    final_state: dict | None
    wall_time_s: float
    engine_version: str | None = None
    engine_settings: dict = field(default_factory=dict)
    matches_reference: dict | None = None
    diverged_at_s: float | None = None
    trajectory: str | None = None
    engine_output: list = field(default_factory=list)
    vs_engine: dict | None = None
    # s spent compiling the engine's step (JIT engines, e.g. mjx; 0 when cached; None: no JIT),
    # included in wall_time_s
    compile_time_s: float | None = None
    # what was simulated (freebody.run.experiment): compare matches runs of the same experiment only
    experiment: dict | None = None
    # how far |w| and the kinetic energy grew beyond the truth's, and the largest rotation per step
    # (freebody.run.metrics.GrowthStats); None for a run without samples (and in older results)
    state_growth: dict | None = None
    # where inside a step the engine evaluated the case's loads (reference_impl.sampling:
    # "per-stage" or "per-step", the adapter's declared rule; Adapter.run_load_sampling); None when
    # the case has no loads or the engine was not built.  Optional: older results lack it.
    load_sampling: str | None = None
    # the facts the findings and report tables present (freebody.results.judgement.run_judgement,
    # computed once when the run is recorded: freebody.run.judge.recorded); None only before that
    judgement: dict | None = None

    def __post_init__(self):
        object.__setattr__(self, "status", Status(self.status))  # ValueError for a status not in the set

    def to_json(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["status"] = self.status.value  # a plain string
        return d

    @property
    def key(self) -> tuple:
        """The run's identity (:func:`run_identity_key`), as its RunSpec's."""
        return run_identity_key(self.case, self.engine, self.integrator, self.precision, self.dt)


@dataclass(frozen=True)
class RunOutput:
    """A run's result with its arrays (for the Python API, trajectory files and reports).

    saved_index : None when the arrays are the whole run; a run judged in chunks (longer than
        ``tolerances.CHUNKED_JUDGING_MIN_STEPS``) keeps only the samples its trajectory file saves,
        and these are their indices (int64 (K,)): ``trajectory``, ``truth`` and ``series`` hold
        those K samples.
    """

    result: RunResult
    trajectory: Trajectory | None
    truth: Trajectory | None
    series: Series | None
    saved_index: np.ndarray | None = None


@dataclass(frozen=True)
class Simulated:
    """What an engine produced for one run, before it is judged against the truth.

    trajectory : the canonical samples (up to the blow-up when the engine reported one).
    diverged_at : s, when the engine itself reported an instability, else None.
    """

    trajectory: Trajectory | None
    diverged_at: float | None
    reason: str
    version: str | None
    settings: dict | None
    wall_time_s: float
    compile_time_s: float | None = None
