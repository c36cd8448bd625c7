"""Truth and reference trajectories computed once per (case, dt, steps) and shared between runs.

A run needs its case's truth at its time steps; an engine run also needs the reference maps it is
compared with (scheme identification: :data:`freebody.run.judge.SCHEME_CANDIDATES`, every reference
integrator) and each map's round-off spread (the same map from a start one ulp away,
:func:`freebody.run.judge.roundoff_spread`).  They cost more than most engine runs, so
:class:`GroupTruthCache`

- keeps them in memory for one group (problem, dt, steps) at a time, so memory stays bounded by
  the largest group, not the whole suite;
- takes a reference engine run's own trajectory as the reference map of the same name: the
  reference adapter returns exactly :func:`freebody.reference_impl.integrators.simulate` (a test
  checks it bit for bit), so identification need not integrate it a second time; of a map, only
  its orientations stay in memory (all that identification compares);
- optionally shares them between worker processes through a directory (``store``): one ``.npz``
  file per trajectory or spread, written atomically, so a worker that reads one reads exactly what
  another computed.

The numbers are the same whichever process computed them: results are identical to a serial run.
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from ..reference_impl.conventions import Trajectory
from ..reference_impl.engine_maps import map_load_sampling
from ..reference_impl.integrators import INTEGRATORS
from ..reference_impl.sampling import LOAD_SAMPLING_PER_STAGE
from ..results.io import file_lock, write_npz_atomic
from .judge import SCHEME_CANDIDATES, TruthCache
from .records import RunOutput, RunSpec, Status

# reference maps a run of the reference engine can stand in for (identify() compares with these;
# the engine-equivalent maps are not reference-engine integrators)
SHAREABLE_REFERENCES = tuple(n for n in SCHEME_CANDIDATES if n in INTEGRATORS)
_FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


def group_prefix(problem_key: str, dt: float, steps: int) -> str:
    """Store file-name prefix of a group (problem, dt, steps)."""
    return f"{problem_key}_dt{float(dt).hex()}_n{int(steps)}_"


def _save(path: Path, tr: Trajectory) -> None:
    arrays = {f: getattr(tr, f) for f in _FIELDS}
    if tr.orthonormality_error is not None:
        arrays["orthonormality_error"] = tr.orthonormality_error
    # read back at once by the group's other runs; a scratch file (the store goes at the suite's end)
    write_npz_atomic(path, arrays, compressed=False, durable=False)


def _load(path: Path) -> Trajectory | None:
    try:
        with np.load(path) as z:
            ortho = z["orthonormality_error"] if "orthonormality_error" in z else None
            return Trajectory(*(z[f] for f in _FIELDS), orthonormality_error=ortho)
    except (OSError, ValueError, KeyError):  # unreadable: compute it again
        return None


def _claimed(path: Path | None):
    """Hold an exclusive lock on ``path``'s ``.lock`` file for the block
    (:func:`freebody.results.io.file_lock`); None (no store): no lock.  The first worker of a group
    to need a map or a spread computes it while the others wait, then read it: each is computed
    once per suite, not once per worker that raced for it."""
    if path is None:
        return contextlib.nullcontext()
    return file_lock(path.with_name(path.name + ".lock"))


def _load_array(path: Path, name: str) -> np.ndarray | None:
    """The array ``name`` of a store file (a map's quaternion_wxyz, a round-off spread), or None."""
    try:
        with np.load(path) as z:
            return z[name]
    except (OSError, ValueError, KeyError):  # unreadable: compute it again
        return None


class GroupTruthCache(TruthCache):
    """A :class:`~freebody.run.judge.TruthCache` for one group at a time, optionally shared.

    store : directory shared by the workers of one suite, or None (this process only).
    Call :meth:`enter` before each run and :meth:`offer` after it.
    """

    def __init__(self, store: Path | None = None):
        super().__init__()
        self.store = Path(store) if store is not None else None
        self._group: tuple | None = None
        self._keys: dict[int, str] = {}  # id(problem) -> stable key, for store file names
        self._memo: dict[tuple, Trajectory] = {}
        self._share = True

    def enter(self, problem, problem_key: str, dt: float, steps: int, share: bool = True) -> None:
        """Switch to the group (problem, dt, steps); forget the arrays of any other group.
        ``share``: read and write the store for this group (a group of one run needs no store)."""
        self._share = share
        self._keys[id(problem)] = problem_key
        group = (problem_key, float(dt), int(steps))
        if group != self._group:
            super().__init__()
            self._memo = {}
            self._group = group

    def get(self, problem, dt: float, steps: int) -> Trajectory:
        return self._lookup(problem, dt, steps, None, lambda: super(GroupTruthCache, self).get(problem, dt, steps))

    def reference(self, problem, integrator: str, dt: float, steps: int) -> Trajectory:
        return self._lookup(problem, dt, steps, integrator,
                            lambda: super(GroupTruthCache, self).reference(problem, integrator, dt, steps))

    def orientation(self, problem, integrator: str, dt: float, steps: int,
                    load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> np.ndarray:
        """The map's q (steps + 1, 4) only: from an offered reference run, the store or computed
        (then its whole trajectory goes to the store, for the other workers); ``load_sampling``:
        the variant of a multi-stage engine map (:func:`map_load_sampling`)."""
        load_sampling = map_load_sampling(problem, integrator, load_sampling)
        name = integrator if load_sampling == LOAD_SAMPLING_PER_STAGE else f"{integrator}.{load_sampling}"
        full = (id(problem), float(dt), int(steps), name)
        if full in self._memo:  # the map's whole trajectory, computed by reference()
            return self._memo[full].quaternion_wxyz
        key = full[:3] + (f"{name}.q",)
        if key not in self._memo:
            path = self._path(problem, dt, steps, name)
            with _claimed(path):
                q = _load_array(path, "quaternion_wxyz") if path is not None and path.exists() else None
                if q is None:
                    tr = self._simulate_map(problem, integrator, dt, steps, load_sampling)
                    if path is not None:
                        _save(path, tr)
                    q = tr.quaternion_wxyz
            self._memo[key] = q
        return self._memo[key]

    def roundoff(self, problem, integrator: str, dt: float, steps: int, precision: str = "float64",
                 load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> np.ndarray:
        load_sampling = map_load_sampling(problem, integrator, load_sampling)
        sampled = "" if load_sampling == LOAD_SAMPLING_PER_STAGE else f".{load_sampling}"
        tag = f"{integrator}{sampled}.roundoff-{precision}"
        key = (id(problem), float(dt), int(steps), tag)
        if key in self._memo:
            return self._memo[key]
        path = self._path(problem, dt, steps, tag)
        with _claimed(path):  # the map's lock is taken inside (orientation): always in this order
            spread = _load_array(path, "spread") if path is not None and path.exists() else None
            if spread is None:
                spread = super().roundoff(problem, integrator, dt, steps, precision, load_sampling)
                if path is not None:
                    write_npz_atomic(path, {"spread": spread}, compressed=False, durable=False)
        self._memo[key] = spread
        return spread

    def offer(self, spec: RunSpec, out: RunOutput) -> None:
        """Keep a reference engine run's orientations as the reference map of the same name (and
        its trajectory in the store)."""
        tr = out.trajectory
        if (not spec.is_reference or spec.precision != "float64"
                or spec.integrator not in SHAREABLE_REFERENCES or tr is None
                or len(tr) != spec.steps + 1 or out.result.status not in (Status.OK, Status.DIVERGED)):
            return
        key = (id(spec.problem), float(spec.dt), int(spec.steps), f"{spec.integrator}.q")
        if key in self._memo:
            return
        self._memo[key] = tr.quaternion_wxyz  # what identification compares: not the whole run
        path = self._path(spec.problem, spec.dt, spec.steps, spec.integrator)
        if path is not None and not path.exists():
            _save(path, tr)

    def _path(self, problem, dt, steps, integrator) -> Path | None:
        key = self._keys.get(id(problem))
        if self.store is None or key is None or not self._share:
            return None
        return self.store / f"{group_prefix(key, dt, steps)}{integrator or '_truth'}.npz"

    def _lookup(self, problem, dt, steps, integrator, compute) -> Trajectory:
        key = (id(problem), float(dt), int(steps), integrator)
        if key in self._memo:
            return self._memo[key]
        path = self._path(problem, dt, steps, integrator)
        tr = _load(path) if path is not None and path.exists() else None
        if tr is None:
            tr = compute()
            if path is not None:
                _save(path, tr)
        self._memo[key] = tr
        return tr
