"""What a command will need, estimated before it starts: memory (refused, exit 2, when it exceeds
the memory available, unless ``--force-large``) and time (a warning when long).

Used by ``freebody run`` (the runs: how many, how many steps), ``freebody sweep`` (bodies x runs)
and ``freebody inertia`` (the particle or voxel grid).  The per-unit costs are measured constants of
:mod:`freebody.tolerances` (section "resource estimates"); an estimate is an order of magnitude
meant to stop a command that cannot fit (``--count 1000000000``, ``--resolution 1024``, a case with
two million time steps) before it fills the memory, not a prediction to the megabyte.  It counts
the data that grows with the input, not the fixed size of the Python processes themselves.
"""
from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

from .. import tolerances as tol
from ..errors import InputError

FORCE_OPTION = "--force-large"
MEMINFO = Path("/proc/meminfo")
CGROUP = Path("/sys/fs/cgroup")  # cgroup v2: a container's own limit, below the machine's


@dataclass(frozen=True)
class Estimate:
    """what : the work, for messages ("735 runs of up to 10000 steps on 2 workers").
    memory_bytes : estimated peak of the data held.  seconds : estimated wall time (None: not
    estimated).  reduce : how to ask for less ("fewer cases, time steps or engines")."""

    what: str
    memory_bytes: float
    seconds: float | None
    reduce: str


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation: MemAvailable of /proc/meminfo (and a
    cgroup v2 memory limit, if lower), else the free physical pages (os.sysconf); None if unknown."""
    found = None
    try:
        for line in MEMINFO.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found = int(line.split()[1]) * 1024  # kB
                break
    except (OSError, ValueError, IndexError):
        pass
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            return None
    try:
        limit = (CGROUP / "memory.max").read_text().strip()
        if limit != "max":
            used = int((CGROUP / "memory.current").read_text().strip())
            found = min(found, max(0, int(limit) - used))
    except (OSError, ValueError):
        pass
    return found


def _size(n: float) -> str:
    for unit, scale in (("TiB", 2 ** 40), ("GiB", 2 ** 30), ("MiB", 2 ** 20)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 2 ** 10:.3g} KiB"


def _duration(s: float) -> str:
    if s >= 2 * 86400:
        return f"{s / 86400:.3g} days"
    if s >= 2 * 3600:
        return f"{s / 3600:.3g} hours"
    return f"{s / 60:.3g} minutes"


def enforce(estimate: Estimate, force: bool) -> None:
    """InputError (exit 2) if the estimated memory exceeds the memory available, unless ``force``;
    a warning if the estimated time exceeds ``LONG_RUN_WARNING_S``."""
    available = available_memory()
    if available is not None and estimate.memory_bytes > available and not force:
        raise InputError(f"{estimate.what}: needs about {_size(estimate.memory_bytes)} of memory "
                         f"(estimate), more than the {_size(available)} available; "
                         f"{estimate.reduce}, or pass {FORCE_OPTION} to start anyway")
    if estimate.seconds is not None and estimate.seconds > tol.LONG_RUN_WARNING_S:
        warnings.warn(f"{estimate.what}: will take about {_duration(estimate.seconds)} (estimate); "
                      f"Ctrl-C keeps the finished runs", stacklevel=2)


def _parallel(jobs: int, n: int) -> int:
    return max(1, min(jobs, n, os.cpu_count() or 1))


def run_estimate(n_runs: int, total_steps: int, max_steps: int, jobs: int) -> Estimate:
    """``n_runs`` runs of ``total_steps`` steps in all (the longest ``max_steps``) on ``jobs``
    workers: each worker holds one run's arrays, this process every run's record."""
    workers = max(1, min(jobs, n_runs))
    memory = n_runs * tol.RUN_RECORD_BYTES + workers * held_samples(max_steps) * tol.RUN_BYTES_PER_STEP
    seconds = (total_steps * tol.SECONDS_PER_STEP + n_runs * tol.SECONDS_PER_RUN) / _parallel(jobs, n_runs)
    return Estimate(f"{n_runs} run{'s' if n_runs != 1 else ''} of up to {max_steps} steps", memory, seconds,
                    "run fewer cases, time steps, engines or integrators, or a shorter --duration")


def held_samples(steps: int) -> int:
    """The samples a worker holds at once for a run of ``steps`` steps: all of them for a run judged
    whole, one chunk's for a longer one (judged in chunks of JUDGE_CHUNK_STEPS: its memory is
    bounded by the chunk, not by its length; tolerances.CHUNKED_JUDGING_MIN_STEPS)."""
    steps = int(steps)
    if steps > tol.CHUNKED_JUDGING_MIN_STEPS:
        return tol.JUDGE_CHUNK_STEPS + 1
    return steps + 1


def check_run(specs, jobs: int, force: bool = False) -> Estimate:
    """:func:`enforce` the estimate of ``freebody run``'s runs (RunSpecs) on ``jobs`` workers."""
    steps = [int(s.steps) for s in specs]
    est = run_estimate(len(steps), sum(steps), max(steps, default=0), jobs)
    enforce(est, force)
    return est


def sweep_estimate(count: int, body_specs) -> Estimate:
    """``freebody sweep``: ``count`` bodies, each with the runs ``body_specs`` (those of one body),
    run one after another in this process, every body and run record kept for the summary."""
    steps = [int(s.steps) for s in body_specs]
    n_runs = count * len(steps)
    memory = (count * tol.SWEEP_BODY_BYTES + n_runs * tol.RUN_RECORD_BYTES
              + (max(steps, default=0) + 1) * tol.RUN_BYTES_PER_STEP)
    seconds = count * (sum(steps) * tol.SECONDS_PER_STEP + len(steps) * tol.SECONDS_PER_RUN)
    return Estimate(f"--count {count}: {n_runs} runs", memory, seconds,
                    "use a smaller --count, fewer engines or time steps")


def check_sweep(count: int, body_specs, force: bool = False) -> Estimate:
    est = sweep_estimate(count, body_specs)
    enforce(est, force)
    return est


def inertia_estimate(cells: int, method: str, mesh: bool) -> Estimate:
    """``freebody inertia --method particles|voxels`` on a grid of ``cells`` cells (a mesh's inside
    test adds its vectorised blocks)."""
    memory = cells * tol.INERTIA_BYTES_PER_CELL[method] + (tol.INERTIA_MESH_FIXED_BYTES if mesh else 0)
    return Estimate(f"--resolution: {method} on a grid of {cells} cells", memory, None,
                    "use a smaller --resolution")


def check_inertia(cells: int, method: str, mesh: bool, force: bool = False) -> Estimate:
    est = inertia_estimate(cells, method, mesh)
    enforce(est, force)
    return est


def grid_cells(lo, hi, resolution: int) -> int:
    """Cells of the particle/voxel grid at ``resolution`` over the box lo..hi, as
    :func:`freebody.reference_impl.approx.grid_counts` tiles it (1 for a box without extent)."""
    from ..reference_impl.approx import grid_counts

    if not max(float(h) - float(l) for l, h in zip(lo, hi)) > 0:
        return 1
    return math.prod(grid_counts(lo, hi, resolution))
