"""argparse value types shared by the subcommands: each rejects bad values with one line (exit 2);
and :func:`writable_folder` and :func:`writable_file`, the checks of a command's output folder or
file before its work starts (the rule of :func:`freebody.results.io.output_obstacle`: a regular
file or a new path; checked again when each file is written)."""
from __future__ import annotations

import argparse
import math
import os
import tempfile
from pathlib import Path
from typing import Callable

from .. import tolerances as tol

# --timeout at most this many seconds (~3 years): the system's timed waits overflow beyond ~9e9 s.
MAX_TIMEOUT_S = 1e8


def number(minimum: float = -math.inf, strict: bool = False,
           maximum: float = tol.INPUT_MAGNITUDE_MAX) -> Callable[[str], float]:
    """A finite float >= minimum (> minimum when ``strict``) and <= maximum (by default
    INPUT_MAGNITUDE_MAX of freebody.tolerances: squares of larger numbers overflow float64)."""
    sign = ">" if strict else ">="

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {_shown(text)}") from None
        if not math.isfinite(x) or x < minimum or (strict and x == minimum):
            raise argparse.ArgumentTypeError(f"must be a finite number {sign} {minimum:g}, got {_shown(text)}")
        if x > maximum:
            raise argparse.ArgumentTypeError(f"must be at most {maximum:g}, got {_shown(text)}")
        return x

    return parse


def integer(minimum: int = 0, maximum: int | None = None) -> Callable[[str], int]:
    """An integer in [minimum, maximum]."""
    def parse(text: str) -> int:
        span = f">= {minimum}" + (f" and <= {maximum}" if maximum is not None else "")
        try:
            n = int(text)
        except ValueError:
            if text.strip().lstrip("+-").isdigit():  # beyond Python's 4300-digit conversion limit
                raise argparse.ArgumentTypeError(f"must be an integer {span}, got one of "
                                                 f"{len(text.strip().lstrip('+-'))} digits") from None
            raise argparse.ArgumentTypeError(f"not an integer: {_shown(text)}") from None
        if n < minimum or (maximum is not None and n > maximum):
            raise argparse.ArgumentTypeError(f"must be an integer {span}, got {_shown(text)}")
        return n

    return parse


def _shown(text: str) -> str:
    """The user's text in a message: quoted, printable, at most 40 characters."""
    from ..errors import abbreviated

    return abbreviated(text, 40)


positive_float = number(0.0, strict=True)
nonnegative_float = number(0.0)
positive_int = integer(1)
nonnegative_int = integer(0)
# A physical size, density or mass (freebody inertia): from INPUT_POSITIVE_MIN to INPUT_MAGNITUDE_MAX.
quantity = number(tol.INPUT_POSITIVE_MIN)
# --save-every: 'auto' (None: about SAVED_SAMPLES samples a run) or at most the most steps a run
# has (MAX_STEPS_PER_RUN).
_save_stride = integer(1, tol.MAX_STEPS_PER_RUN)


def save_interval(text: str) -> int | None:
    """--save-every: ``auto`` (None) or an integer stride."""
    if text.strip().lower() == "auto":
        return None
    try:
        return _save_stride(text)
    except argparse.ArgumentTypeError as e:
        raise argparse.ArgumentTypeError(f"{e} or 'auto'") from None
timeout_seconds = number(0.0, strict=True, maximum=MAX_TIMEOUT_S)


def writable_folder(value, option: str, files=()) -> Path:
    """The output folder ``value`` of a command (``sweep --out``, ``inertia --compare --out``, the
    folder of ``baseline --to``), created with its parents and checked writable by creating (and
    removing) a one-byte file in it, so that a command fails before its work starts, not after.
    InputError (one line naming ``option``) when it is empty, exists and is not a folder, lies under
    a file, or cannot be created or written (permissions, a read-only or full file system), or when
    one of ``files`` (the names the command writes in it) is there as anything but a regular file
    (:func:`freebody.results.io.check_output_file`)."""
    from ..errors import InputError, printable

    if value is None or not str(value):
        raise InputError(f"{option}: empty; give a folder")
    from ..results.io import make_folder

    path = Path(value)
    where = f"{option} {printable(value)}"
    make_folder(path, where)
    try:
        fd, probe = tempfile.mkstemp(prefix=".freebody-write-check.", dir=path)
    except OSError as e:
        raise InputError(f"{where}: cannot write there: {e.strerror or e}") from None
    try:
        os.write(fd, b"\n")
    except OSError as e:
        raise InputError(f"{where}: cannot write there: {e.strerror or e}") from None
    finally:
        os.close(fd)
        os.unlink(probe)
    from ..results.io import check_output_file

    for name in files:
        check_output_file(path / name, f"{where}: {printable(name)}")
    return path


def writable_file(value, option: str) -> Path:
    """The output file ``value`` of a command (``compare --junit``, ``bench --out``, ``baseline
    --to``), checked before the work starts: a regular file or a new path
    (:func:`freebody.results.io.check_output_file`) in a folder that :func:`writable_folder` creates
    and checks.  InputError, one line naming ``option`` and the path, otherwise."""
    from ..errors import InputError, printable
    from ..results.io import check_output_file

    if value is None or not str(value):
        raise InputError(f"{option}: empty; give the file to write")
    where = f"{option} {printable(value)}"
    path = check_output_file(value, where)
    writable_folder(path.parent, f"{where}: its folder")
    return path
