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


class FdCapture:
    """Redirect file descriptors (default 1 and 2: the C-level stdout and stderr) to one temporary
    file while in the block; the descriptors are restored on exit, even on exceptions.

    Readable while capturing: :meth:`has_output` (one ``fstat``) and :meth:`read_lines`.  After
    exit ``lines`` holds every captured line.  Captures nest (an inner one takes what it captures
    from the outer one).
    """

    def __init__(self, fds: tuple[int, ...] = (1, 2)):
        self.fds = tuple(fds)
        self.lines: list[str] = []
        self._tmp = None
        self._saved: list[int] = []

    def __enter__(self) -> "FdCapture":
        self._flush_python_streams()
        self._tmp = tempfile.TemporaryFile(mode="w+b")
        try:
            for fd in self.fds:
                self._saved.append(os.dup(fd))
                os.dup2(self._tmp.fileno(), fd)
        except BaseException:
            self._restore()
            self._tmp.close()
            raise
        return self

    def has_output(self) -> bool:
        return os.fstat(self._tmp.fileno()).st_size > 0

    def read_lines(self) -> list[str]:
        """The text written so far, one entry per line that is not blank, trailing white space removed."""
        fd = self._tmp.fileno()
        size = os.fstat(fd).st_size
        if size == 0:
            return []
        text = os.pread(fd, size, 0).decode("utf-8", "replace")
        return [ln.rstrip() for ln in text.splitlines() if ln.strip()]

    def __exit__(self, *exc) -> None:
        try:
            self._flush_python_streams()
            self._restore()
        finally:
            try:
                self.lines = self.read_lines()
            finally:
                self._tmp.close()

    def _restore(self) -> None:
        for fd, saved in zip(self.fds, self._saved):
            try:
                os.dup2(saved, fd)
            finally:
                os.close(saved)
        self._saved = []

    def _flush_python_streams(self) -> None:
        """Flush sys.stdout / sys.stderr of the captured descriptors, so that what Python wrote
        before (or during) the capture lands outside (or inside) it."""
        streams = {1: sys.stdout, 2: sys.stderr}
        for fd in self.fds:
            with contextlib.suppress(Exception):  # None, closed or replaced by an object without flush
                streams[fd].flush()


@contextlib.contextmanager
def capture_output():
    """Redirect fds 1 and 2 to a temporary file for the duration; yields a :class:`Captured`
    (filled in on exit)."""
    result = Captured()
    capture = FdCapture((1, 2))
    try:
        with capture:
            yield result
    finally:
        result.total = len(capture.lines)
        result.lines = capture.lines[:MAX_LINES]
