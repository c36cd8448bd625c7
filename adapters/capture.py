"""Capture what engines print on the C level (file descriptors 1 and 2) during a run, so engine
noise lands in the run's record instead of the terminal."""
from __future__ import annotations

import codecs
import contextlib
import os
import re
import sys
import tempfile

MAX_LINES = 20  # lines of engine output kept per run (the rest is counted)
MAX_LINE_CHARS = 500  # characters kept of one line of engine output (the rest is counted)
_READ_CHUNK = 1 << 20  # bytes read at a time from the capture file


def cap_line(line: str, limit: int = MAX_LINE_CHARS) -> str:
    """``line`` cut to ``limit`` characters, saying how many more there were, so that an engine
    printing a 50 MB line cannot bloat results.json.  A line cut already is left as it is."""
    line = str(line)
    if len(line) <= limit or (line.endswith(" more characters)")
                              and re.fullmatch(r"\.\.\. \(\d+ more characters\)", line[limit:])):
        return line
    return f"{line[:limit]}... ({len(line) - limit} more characters)"


class Captured:
    """The text an engine printed while captured: ``lines`` (at most MAX_LINES) and ``total``."""

    def __init__(self):
        self.lines: list[str] = []
        self.total = 0

    def summary(self) -> list[str]:
        """At most MAX_LINES lines, each at most MAX_LINE_CHARS characters (:func:`cap_line`),
        then ``"... N more lines"`` if there were more."""
        kept = [cap_line(ln) for ln in self.lines[:MAX_LINES]]
        extra = max(self.total, len(self.lines)) - len(kept)
        return kept + ([f"... {extra} more lines"] if extra > 0 else [])


class FdCapture:
    """Redirect file descriptors (default 1 and 2: the C-level stdout and stderr) to one temporary
    file while in the block; the descriptors are restored on exit, even on exceptions.

    Readable while capturing: :meth:`has_output` (one ``fstat``) and :meth:`read_lines`.  After
    exit ``lines`` holds every captured line, each cut to MAX_LINE_CHARS characters
    (:func:`cap_line`).  Captures nest (an inner one takes what it captures from the outer one).
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
        """The text written so far, one entry per line that is not blank, trailing white space
        removed, each cut to MAX_LINE_CHARS characters (read in chunks: a huge line is never held
        whole in memory)."""
        fd = self._tmp.fileno()
        size = os.fstat(fd).st_size
        reader = _LineReader()
        for offset in range(0, size, _READ_CHUNK):
            reader.feed(os.pread(fd, min(_READ_CHUNK, size - offset), offset))
        return reader.close()

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


class _LineReader:
    """Bytes in, lines out, as ``[cap_line(ln.rstrip()) for ln in text.splitlines() if ln.strip()]``
    on the decoded text, keeping at most MAX_LINE_CHARS characters of the line being read."""

    def __init__(self, limit: int = MAX_LINE_CHARS):
        self.limit = limit
        self.decoder = codecs.getincrementaldecoder("utf-8")("replace")
        self.lines: list[str] = []
        self._start_line()

    def _start_line(self) -> None:
        self.head, self.length, self.trailing_space = "", 0, 0

    def feed(self, data: bytes, final: bool = False) -> None:
        for piece in self.decoder.decode(data, final).splitlines(keepends=True):
            content = piece.splitlines()[0] if piece.splitlines() else ""
            if len(self.head) < self.limit:
                self.head += content[:self.limit - len(self.head)]
            self.length += len(content)
            stripped = content.rstrip()
            self.trailing_space = (self.trailing_space + len(content)) if not stripped else len(content) - len(stripped)
            if len(content) < len(piece):  # the piece ends a line
                self._end_line()

    def _end_line(self) -> None:
        n = self.length - self.trailing_space  # length without trailing white space
        if n > 0:
            self.lines.append(self.head[:n] if n <= self.limit
                              else f"{self.head}... ({n - self.limit} more characters)")
        self._start_line()

    def close(self) -> list[str]:
        self.feed(b"", final=True)
        self._end_line()
        return self.lines


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
