"""Stopping ``freebody run`` from outside: Ctrl-C (SIGINT), SIGTERM (a cancelled CI job, ``kill``)
and SIGHUP (a closed terminal) all interrupt it the same way: the workers are ended, the finished
runs are kept (marked incomplete) and freebody exits with 128 + the signal's number (130, 143, 129).

SIGINT raises Python's own KeyboardInterrupt; SIGTERM and SIGHUP raise :class:`Interrupted`, a
KeyboardInterrupt carrying the signal, while :func:`signals_interrupt` is active.
"""
from __future__ import annotations

import contextlib
import signal
import threading

# the signals that interrupt a run (SIGHUP does not exist on Windows)
SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)


class Interrupted(KeyboardInterrupt):
    """A run interrupted by a signal other than SIGINT (``signum``)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def signal_of(exc: BaseException) -> int:
    """The signal that interrupted: ``exc.signum``, or SIGINT for a plain KeyboardInterrupt."""
    return int(getattr(exc, "signum", signal.SIGINT))


def exit_code(exc: BaseException) -> int:
    """128 + the signal's number: 130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP."""
    return 128 + signal_of(exc)


def describe(exc: BaseException) -> str:
    """'interrupted' (Ctrl-C) or 'terminated by SIGTERM' / 'terminated by SIGHUP'."""
    signum = signal_of(exc)
    return "interrupted" if signum == signal.SIGINT else f"terminated by {signal.Signals(signum).name}"


def _raise(signum, frame):
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise Interrupted(signum)


@contextlib.contextmanager
def signals_interrupt():
    """SIGTERM and SIGHUP raise :class:`Interrupted` in the block (SIGINT raises KeyboardInterrupt
    as always); the previous handlers are restored after.  Only in the main thread (elsewhere a
    no-op: Python delivers signals to the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, _raise) for s in SIGNALS if s != signal.SIGINT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextlib.contextmanager
def deferred():
    """Hold off SIGINT, SIGTERM and SIGHUP while results are being written; the first one that
    arrived is raised afterwards (as KeyboardInterrupt or :class:`Interrupted`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = {s: signal.signal(s, lambda signum, frame: caught.append(signum)) for s in SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if caught:
        _raise(caught[0], None)
