"""Capture what engines print on the C level (file descriptors 1 and 2) during a run, so engine
noise lands in the run's record instead of the terminal."""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile

MAX_LINES = 20  # lines of engine output kept per run (the rest is counted)


class Captured:
    """The text an engine printed while captured: ``lines`` (at most MAX_LINES) and ``total``."""

    def __init__(self):
        self.lines: list[str] = []
        self.total = 0

    def summary(self) -> list[str]:
        extra = self.total - len(self.lines)
        return self.lines + ([f"... {extra} more lines"] if extra > 0 else [])


@contextlib.contextmanager
def capture_output():
    """Redirect fds 1 and 2 to a temporary file for the duration; yields a :class:`Captured`."""
    result = Captured()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved = [os.dup(1), os.dup(2)]
    tmp = tempfile.TemporaryFile(mode="w+b")
    try:
        os.dup2(tmp.fileno(), 1)
        os.dup2(tmp.fileno(), 2)
        yield result
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)
        tmp.seek(0)
        text = tmp.read().decode("utf-8", "replace")
        tmp.close()
        lines = [ln.rstrip() for ln in text.splitlines() if ln.strip()]
        result.total = len(lines)
        result.lines = lines[:MAX_LINES]
