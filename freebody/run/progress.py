"""The progress display of ``freebody run`` (one item a run) and ``freebody sweep`` (one item a body)."""
from __future__ import annotations

import sys
import time
from typing import TextIO

from ..errors import printable

WIDTH = 150  # characters of a progress line shown on a terminal


class ProgressDisplay:
    """``[done/total unit] elapsed text``: one line rewritten in place on a terminal; elsewhere (e.g.
    CI logs) a line every ``every`` items and after the last.

    total : items to do.  unit : what an item is, shown after the total ("" or e.g. "bodies").
    enabled : False shows nothing (the count still advances).
    """

    def __init__(self, total: int, unit: str = "", stream: TextIO | None = None, enabled: bool = True,
                 every: int = 1):
        self.total, self.done = total, 0
        self.unit = f" {unit}" if unit else ""
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = self.enabled and self.stream.isatty()
        self.every = max(1, every)
        self.t0 = time.perf_counter()

    def update(self, text: str) -> None:
        """One more item done; ``text`` says what (after the count and the elapsed time)."""
        self.done += 1
        if not self.enabled:
            return
        # printable: a case name may hold control characters or terminal escape sequences
        line = f"[{self.done}/{self.total}{self.unit}] {time.perf_counter() - self.t0:6.1f}s {printable(text)}"
        if self.tty:
            self.stream.write("\r\033[K" + line[:WIDTH] + ("\n" if self.done == self.total else ""))
        elif self.done % self.every == 0 or self.done == self.total:
            self.stream.write(line + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        """End the line being rewritten (on a terminal) and write ``text`` as a line of its own."""
        if not self.enabled:
            return
        if self.tty:
            self.stream.write("\n")
        self.stream.write(printable(text) + "\n")
        self.stream.flush()
