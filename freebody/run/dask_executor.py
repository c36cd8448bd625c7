"""The same runs on an existing dask.distributed cluster (``--executor dask --scheduler ADDRESS``).

One dask task per group of runs that share a truth (see :func:`freebody.run.executor.plan`).  On the
dask worker, the group runs in a freebody worker process (:class:`freebody.run.executor.LocalPool` with
one worker, kept for the next group), so a crash or a run past ``--timeout`` costs that run only,
never the dask worker, and the numbers are those of a local run.  The cluster's workers need
freebody and the engines installed; trajectories come back to the client, which writes them.

dask is an optional dependency: ``pip install 'freebody[dask]'``.
"""
from __future__ import annotations

import atexit
import threading
import uuid

from ..errors import InputError
from .executor import LocalPool, OnDone, Task
from .worker import RunTask, failed_payload

CONNECT_TIMEOUT_S = 10  # how long to try reaching the scheduler before calling the address bad

_idle_pools: list[tuple[tuple, LocalPool]] = []
_lock = threading.Lock()


def _import_distributed():
    try:
        from distributed import Client, as_completed
    except ImportError as e:
        if e.name in ("dask", "distributed") or (e.name or "").startswith(("dask.", "distributed.")):
            raise InputError("--executor dask: dask.distributed is not installed: "
                             "pip install 'freebody[dask]'") from None
        raise
    return Client, as_completed


def run_group(runs: list[RunTask], options: dict) -> list[tuple[int, dict]]:
    """Execute one group's runs in order in a freebody worker process of this dask worker.

    options : ``timeout`` (s or None), ``engines`` (the client's adapter registry) and
    ``preimport`` (engine names).  Returns [(index, payload)] in completion order.
    """
    ident = (options.get("timeout"), tuple(sorted(options["engines"].items())),
             tuple(options.get("preimport") or ()))
    with _lock:
        found = next((i for i, (k, _) in enumerate(_idle_pools) if k == ident), None)
        pool = _idle_pools.pop(found)[1] if found is not None else None
    if pool is None:
        pool = LocalPool(1, timeout=options.get("timeout"), engines=options.get("preimport") or (),
                         share_truths=False, registry=options["engines"])
    out: list[tuple[int, dict]] = []
    try:
        pool.run([Task(r, ("group",)) for r in runs], lambda i, p: out.append((i, p)))
    except BaseException:
        pool.close(kill=True)
        raise
    with _lock:
        _idle_pools.append((ident, pool))
    return out


@atexit.register
def _close_idle_pools() -> None:
    with _lock:
        pools = [p for _, p in _idle_pools]
        _idle_pools.clear()
    for p in pools:
        p.close()


def run_dask(tasks: list[Task], scheduler: str, timeout: float | None, engines, on_done: OnDone) -> None:
    """Send each group of ``tasks`` to the dask cluster at ``scheduler``; ``on_done(index, payload)``
    for each run as its group comes back.  A group lost with its dask worker is ``failed``."""
    from ..adapters import base

    Client, as_completed = _import_distributed()
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as e:
        raise InputError(f"--scheduler: cannot connect to the dask scheduler at {scheduler!r}: "
                         f"{type(e).__name__}: {e}") from None
    groups: dict[tuple, list[Task]] = {}
    for t in tasks:
        groups.setdefault(t.group, []).append(t)
    options = {"timeout": timeout, "engines": dict(base.ENGINES), "preimport": list(engines)}
    tag = uuid.uuid4().hex[:8]
    futures = {}
    try:
        for i, group in enumerate(groups.values()):
            fut = client.submit(run_group, [t.run for t in group], options, pure=False,
                                key=f"freebody-{tag}-{i}")
            futures[fut] = group
        for fut in as_completed(list(futures)):
            try:
                results = fut.result()
            except Exception as e:  # the dask worker died (KilledWorker) or the task could not run
                for t in futures[fut]:
                    on_done(t.index, failed_payload(t.run.spec, f"the dask task of this run failed: "
                                                                f"{type(e).__name__}: {e}", 0.0))
                continue
            for index, payload in results:
                on_done(index, payload)
    finally:
        try:
            client.cancel(list(futures))
        finally:
            client.close()
