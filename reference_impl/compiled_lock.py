"""One numba compilation at a time across the worker processes of a pool, so that a function
two workers need is compiled once (by the first; the second loads it from numba's on-disk cache).

With a cold cache (a fresh machine, a new numba, an edited map) each worker used to compile every
function its runs need: with ``--jobs 2`` the quick start's ~100 compiled functions were compiled
twice, 80 s CPU against 45 s with ``--jobs 1``.  :class:`freebody.run.executor.LocalPool` names a
lock file in its shared store (:data:`COMPILE_LOCK_ENV`); :mod:`compiled` (imported by every
compiled map) installs the lock when that variable is set.  Importing this module imports no numba.
"""
from __future__ import annotations

import os
import threading

# A file whose lock the worker processes of one pool take around each numba compilation (set by
# freebody.run.executor.LocalPool for two workers or more): see serialize_compilation.
COMPILE_LOCK_ENV = "FREEBODY_NUMBA_COMPILE_LOCK"


def serialize_compilation(lock_path: str) -> None:
    """Make every numba compilation of this process hold an exclusive lock on ``lock_path``
    (``flock``; a compilation's own nested ones hold it already), so workers that need the same
    function compile it once: the second waits, then loads what the first wrote to the on-disk
    cache (``Dispatcher.compile`` looks in the cache before it compiles).  Once per process; no
    lock where ``fcntl`` is missing.  The holder waits on nothing else, so no deadlock."""
    from numba.core.dispatcher import Dispatcher

    try:
        import fcntl
    except ImportError:  # not POSIX: each worker compiles for itself, as before
        return
    if getattr(Dispatcher.compile, "lock_path", None) is not None:
        return
    compile_, guard, depth = Dispatcher.compile, threading.RLock(), [0]
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o600)

    def compile_locked(self, sig):
        with guard:
            if depth[0] == 0 and in_disk_cache(self, sig):  # only a load: workers load side by side
                return compile_(self, sig)
            if depth[0] == 0:
                fcntl.flock(fd, fcntl.LOCK_EX)
            depth[0] += 1
            try:
                return compile_(self, sig)
            finally:
                depth[0] -= 1
                if depth[0] == 0:
                    fcntl.flock(fd, fcntl.LOCK_UN)

    compile_locked.lock_path = lock_path
    Dispatcher.compile = compile_locked


def in_disk_cache(dispatcher, sig) -> bool:
    """Whether numba's on-disk cache holds ``sig`` of ``dispatcher`` (its index names the entry and
    the entry's file exists): ``Dispatcher.compile`` then only loads it, which needs no lock (a
    warm pool's workers loaded their maps one at a time behind it: ~0.5 s of each start-up).  False
    when unsure (no cache, another numba's internals): the lock is taken, as before."""
    try:
        cache = dispatcher._cache
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        name = cache._cache_file._load_index().get(key)
        return name is not None and os.path.exists(os.path.join(cache._cache_path, name))
    except Exception:
        return False


def serialize_if_asked() -> None:
    """:func:`serialize_compilation` of the file named by :data:`COMPILE_LOCK_ENV`, if set."""
    if os.environ.get(COMPILE_LOCK_ENV):
        serialize_compilation(os.environ[COMPILE_LOCK_ENV])

