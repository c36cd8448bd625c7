"""The progress display of ``freebody run`` and ``freebody sweep`` (one item a run).

On a terminal: one line rewritten in place, at most ``1 / TTY_INTERVAL_S`` times a second::

    [123/774 runs]  15%  0:05 elapsed  ETA 0:26  ok       dzhanibekov mujoco/Euler dt=0.01

Elsewhere (CI logs, pipes): the same line as a plain line (never a carriage return) after the first
item, at every tenth of the items or ``LOG_INTERVAL_S`` after the previous line, whichever comes
first, and after the last.  The formatting functions (:func:`format_duration`, :func:`format_eta`,
:func:`estimate_eta`, :func:`progress_line`) are pure; :class:`ProgressDisplay` takes its clock as
an argument so that tests can drive it.

A long single run (judged chunk by chunk, :func:`freebody.run.execute.chunk_steps`, or judged whole
but stepped in pieces of ``tolerances.PROGRESS_PIECE_STEPS``) also shows its steps: the process
stepping it (a worker, or freebody's own with ``--no-isolation``; not a dask worker) calls
:func:`report_steps` after each chunk or piece, which sends (at most every
``STEP_REPORT_INTERVAL_S``) the steps done and the total to the parent, whose display shows them
(:meth:`ProgressDisplay.steps`): on a terminal as the progress line's text, elsewhere as a line
at most every ``LOG_INTERVAL_S``.
"""
from __future__ import annotations

import math
import os
import sys
import time
from typing import Callable, TextIO

from ..errors import printable

TTY_INTERVAL_S = 0.1  # on a terminal, rewrite the line at most ~10 times a second (no flush storm)
LOG_INTERVAL_S = 10.0  # in a log, a line at least this often while items finish ...
LOG_FRACTION = 0.1  # ... and at every tenth of the items
ETA_MIN_DONE = 3  # items done before their rate is trusted for an ETA (the first ones carry start-up)
FALLBACK_WIDTH = 80  # columns when the terminal does not say
STEP_REPORT_INTERVAL_S = 1.0  # a worker sends a long run's steps at most this often (cheap: one pipe message)


def format_duration(seconds: float | None) -> str:
    """A duration as ``m:ss`` (``h:mm:ss`` from an hour on), rounded down to the second;
    ``--`` for None, a negative or a non-finite number (unknown)."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return "--"
    s = int(seconds)
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


def format_eta(seconds: float | None) -> str:
    """``ETA 1:23`` for the time left in s; ``ETA --`` while it is unknown (None)."""
    return f"ETA {format_duration(seconds)}"


def estimate_eta(done: int, total: int, elapsed: float) -> float | None:
    """Seconds left at the average rate of the ``done`` items so far (``elapsed`` s for them); None
    until ``ETA_MIN_DONE`` items are done (a rate from one or two, which include the start-up of
    the workers and the engines' imports, says little); 0 when every item is done."""
    if done >= total:
        return 0.0
    if done < ETA_MIN_DONE or not (elapsed > 0 and math.isfinite(elapsed)):
        return None
    return elapsed / done * (total - done)


def progress_line(done: int, total: int, elapsed: float, text: str, unit: str = "runs") -> str:
    """``[done/total unit]  pct%  m:ss elapsed  ETA m:ss  text`` (``text`` made printable: a case
    name may hold control characters or terminal escape sequences).  The percentage is rounded
    down, so 100% means every item is done."""
    count = f"[{done}/{total}{' ' + unit if unit else ''}]"
    pct = 100 * done // total if total > 0 else 100
    return (f"{count} {pct:3d}%  {format_duration(elapsed)} elapsed  "
            f"{format_eta(estimate_eta(done, total, elapsed))}  {printable(text)}")


def terminal_width(stream: TextIO, default: int = FALLBACK_WIDTH) -> int:
    """Columns of the terminal ``stream`` writes to; ``default`` when it is no terminal or does not say."""
    try:
        columns = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):  # no fileno (StringIO), not a terminal, closed
        return default
    return columns if columns > 0 else default


class ProgressDisplay:
    """The progress of ``total`` items (see the module docstring).

    unit : what an item is, shown after the total ("runs"; "" for nothing).
    stream : where to write (default: standard error); a terminal (``isatty()``) gets the line
        rewritten in place, anything else plain lines.
    enabled : False shows nothing (the count still advances, for the callers' messages).
    every : in a log, a line every ``every`` items (default: a tenth of the total); the first and
        the last item and ``LOG_INTERVAL_S`` without a line also give one.
    clock : seconds, monotonic (default :func:`time.monotonic`).
    """

    def __init__(self, total: int, unit: str = "runs", stream: TextIO | None = None, enabled: bool = True,
                 every: int | None = None, clock: Callable[[], float] = time.monotonic):
        self.total, self.done = total, 0
        self.unit = unit
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        isatty = getattr(self.stream, "isatty", None)
        self.tty = self.enabled and bool(isatty and isatty())
        self.every = max(1, every if every else math.ceil(total * LOG_FRACTION))
        self.clock = clock
        self.t0 = clock()
        self._last_write: float | None = None  # clock() at the last line written
        self._last_logged = 0  # items done at the last log line
        self._pending: str | None = None  # a terminal line held back by the throttle

    def line(self, text: str) -> str:
        """The progress line now, ``text`` saying what the last item was."""
        return progress_line(self.done, self.total, self.clock() - self.t0, text, self.unit)

    def update(self, text: str) -> None:
        """One more item done; ``text`` says which (shown after the count, the times and the ETA)."""
        self.done += 1
        if not self.enabled:
            return
        now = self.clock()
        last = self.done == self.total
        since = None if self._last_write is None else now - self._last_write
        if self.tty:
            line = self.line(text)
            if not last and since is not None and since < TTY_INTERVAL_S:
                self._pending = line  # shown by the next write, or by note()
                return
            self._rewrite(line, end="\n" if last else "")
        elif (last or self._last_write is None or since >= LOG_INTERVAL_S
              or self.done // self.every > self._last_logged // self.every):
            self.stream.write(self.line(text) + "\n")
            self._last_logged = self.done
        else:
            return
        self._last_write = now
        self.stream.flush()

    def note(self, text: str) -> None:
        """Write ``text`` as a line of its own (on a terminal: after the progress line, brought up
        to date and ended)."""
        if not self.enabled:
            return
        if self.tty:
            if self._pending is not None:
                self._rewrite(self._pending, end="")
            if self._last_write is not None and self.done < self.total:
                self.stream.write("\n")  # end the line being rewritten (the last one ended itself)
        self.stream.write(printable(text) + "\n")
        self.stream.flush()

    def steps(self, done: int, total: int, text: str) -> None:
        """A run not finished yet has stepped ``done`` of its ``total`` steps (``text``: which run):
        on a terminal the progress line says so (throttled as :meth:`update`); in a log, a line
        if none was written for ``LOG_INTERVAL_S``."""
        if not self.enabled:
            return
        now = self.clock()
        since = None if self._last_write is None else now - self._last_write
        # the steps first: a terminal's line is cut at its width, the run's name may be long
        line = self.line(f"step {done}/{total} ({100 * done // max(1, total)}%) of {text}")
        if self.tty:
            if since is not None and since < TTY_INTERVAL_S:
                self._pending = line
                return
            self._rewrite(line, end="")
        elif since is None or since >= LOG_INTERVAL_S:
            self.stream.write(line + "\n")
        else:
            return
        self._last_write = now
        self.stream.flush()

    def _rewrite(self, line: str, end: str) -> None:
        # one column short of the width: a line that fills the last column wraps on some terminals,
        # and "\r" then rewrites only the wrapped part
        width = max(20, terminal_width(self.stream) - 1)
        self.stream.write("\r\033[K" + line[:width] + end)
        self._pending = None


# --- the steps of a long run, from the process stepping it ------------------------------------

_reporter: Callable[[int, int], None] | None = None
_last_report = -math.inf


def set_step_reporter(reporter: Callable[[int, int], None] | None) -> None:
    """Where :func:`report_steps` sends (steps done, total) in this process (a worker: to its
    parent, for the run it executes); None: nowhere."""
    global _reporter, _last_report
    _reporter, _last_report = reporter, -math.inf


def report_steps(done: int, total: int) -> None:
    """A long run has stepped ``done`` of ``total`` steps: sent to the reporter, at most every
    STEP_REPORT_INTERVAL_S (a no-op without one).  Never raises: progress is not worth a run."""
    global _last_report
    if _reporter is None:
        return
    now = time.monotonic()
    if now - _last_report < STEP_REPORT_INTERVAL_S:
        return
    _last_report = now
    try:
        _reporter(int(done), int(total))
    except Exception:
        pass
