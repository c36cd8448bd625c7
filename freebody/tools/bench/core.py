"""What every part of ``freebody bench`` shares: the checks (value op limit -> PASS/MISS/n/a), the
child processes it times (wall, CPU, peak RSS, read by a small wrapper interpreter) and small
helpers."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

MB = 1e6


# --- checks ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    """One target of the table: ``value op limit`` (both in ``unit``).

    key : the target's group ("overhead", "suite", ...), label : what is measured.
    passed : True (PASS), False (MISS), None (n/a: not measured, or not judged, e.g. in quick
    mode; ``note`` says why).  detail : the figures behind ``value``, for the reader.
    """

    key: str
    label: str
    value: float | None
    op: str
    limit: float | None
    unit: str
    passed: bool | None
    detail: str = ""
    note: str = ""

    @property
    def status(self) -> str:
        return {True: "PASS", False: "MISS", None: "n/a"}[self.passed]


def meets(value: float | None, op: str, limit: float | None) -> bool | None:
    """Whether ``value op limit`` holds (op ``<=`` or ``>=``); None when either is missing or not
    a finite number (nothing to judge)."""
    if op not in ("<=", ">="):
        raise ValueError(f"op must be '<=' or '>=', got {op!r}")
    if value is None or limit is None or not (math.isfinite(value) and math.isfinite(limit)):
        return None
    return value <= limit if op == "<=" else value >= limit


def make_check(key: str, label: str, value: float | None, op: str, limit: float | None, unit: str,
               detail: str = "", note: str = "", evaluate: bool = True) -> Check:
    """A :class:`Check` judged by :func:`meets` (``evaluate`` False: n/a, with ``note``; a
    missing value is n/a and says ``note``, or "not measured")."""
    if value is None and not note:
        note = "not measured"
    return Check(key, label, value, op, limit, unit, meets(value, op, limit) if evaluate else None,
                 detail, note)


# --- small helpers ----------------------------------------------------------------------------------

def log(msg: str, progress: bool) -> None:
    if progress:
        sys.stderr.write(f"bench: {msg}\n")
        sys.stderr.flush()


def timed(fn: Callable[[], object]) -> float:
    """Wall seconds of ``fn()``."""
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def cpu_timed(fn: Callable[[], object]) -> float:
    """CPU seconds of this process (``time.process_time``: every thread) spent in ``fn()``."""
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def median(xs) -> float:
    return float(np.median(xs))


def folder_bytes(folder: Path) -> int:
    """Total size in bytes of the regular files under ``folder`` (0 if it does not exist)."""
    if not folder.is_dir():
        return 0
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def file_bytes(path: Path) -> int | None:
    return path.stat().st_size if path.is_file() else None


def freebody_cmd(*args: str) -> list[str]:
    """The command line of ``freebody ARGS`` in this interpreter."""
    return [sys.executable, "-m", "freebody", *args]


# --- child processes --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Child:
    """A finished child process: wall seconds, CPU seconds (user + system of the command and every
    descendant it reaped: freebody's worker processes), exit code, peak RSS in bytes (None where
    the platform cannot tell) and the last lines of its stderr."""

    wall_s: float
    cpu_s: float | None
    returncode: int
    maxrss_bytes: int | None
    stderr_tail: str


# Runs the command given as its arguments and prints {"wall", "rc", "rss", "cpu"} of it.  Peak RSS
# and CPU are read here, in a small interpreter, and not by the benchmark: a child forked from the
# benchmark (hundreds of MB of engines and compiled maps) would count the benchmark's own pages in
# its ru_maxrss until it execs.  RUSAGE_CHILDREN covers the command and its reaped descendants
# (freebody's worker processes): the largest one's peak RSS, the sum of their CPU.
CHILD_WRAPPER = """
import json, subprocess, sys, time
t0 = time.perf_counter()
rc = subprocess.call(sys.argv[1:], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
wall = time.perf_counter() - t0
try:
    import resource
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    rss, cpu = ru.ru_maxrss, ru.ru_utime + ru.ru_stime
except ImportError:
    rss, cpu = -1, -1.0
print(json.dumps({"wall": wall, "rc": rc, "rss": rss, "cpu": cpu}))
"""


# Variables of this environment a timed command does not inherit: PYTHONDONTWRITEBYTECODE (set in
# some CI and container images) makes every process compile every module from source again,
# 0.14-0.5 s CPU an invocation that a user's installation, with its __pycache__, never pays.
CHILD_ENV_DROPPED = ("PYTHONDONTWRITEBYTECODE",)


def child_environ(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a timed command: this process's without :data:`CHILD_ENV_DROPPED`
    (bytecode cached as users have it), ``env`` set on top."""
    full = {k: v for k, v in os.environ.items() if k not in CHILD_ENV_DROPPED}
    return {**full, **(env or {})}


def run_child(cmd: list[str], env: dict[str, str] | None = None) -> Child:
    """Run ``cmd`` (stdout discarded, stderr kept in a temporary file so that no pipe can fill up;
    ``env``: variables set on top of this process's environment, :func:`child_environ`) through
    :data:`CHILD_WRAPPER`:
    its wall time, CPU time, exit code and peak RSS (``ru_maxrss``: KiB on Linux, bytes on
    macOS)."""
    full_env = child_environ(env)
    with tempfile.TemporaryFile() as err:
        proc = subprocess.run([sys.executable, "-c", CHILD_WRAPPER, *cmd], stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=err, text=True, check=False, env=full_env)
        err.seek(0)
        tail = "\n".join(err.read().decode("utf-8", "replace").strip().splitlines()[-3:])
    try:
        got = json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        raise RuntimeError(f"the timing wrapper failed (exit {proc.returncode}): {tail}") from None
    rss = got["rss"]
    rss_bytes = None if rss < 0 else int(rss) * (1 if sys.platform == "darwin" else 1024)
    return Child(float(got["wall"]), None if got["cpu"] < 0 else float(got["cpu"]), int(got["rc"]),
                 rss_bytes, tail)


def run_ok(cmd: list[str], what: str, env: dict[str, str] | None = None,
           ok_codes: tuple[int, ...] = (0,)) -> Child:
    """:func:`run_child`, RuntimeError naming ``what`` unless it exits with one of ``ok_codes``."""
    child = run_child(cmd, env)
    if child.returncode not in ok_codes:
        raise RuntimeError(f"{what} exited {child.returncode}: {child.stderr_tail}")
    return child
