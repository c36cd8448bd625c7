"""Reading and writing files: every file freebody writes (results.json, trajectory and shared-truth npz files,
reports, baselines, sweep, bench and inertia documents, worst-case case files) goes through here.

A file is written to a temporary file in its destination folder, flushed to the disk (fsync) and
renamed over the destination (``os.replace``), so whoever reads it, or a kill at any moment, sees
the old file or the new one, never a part.  The one permission rule: a written file gets the mode
a plain ``open()`` would give it, 0o666 less the user's umask (the kernel applies the umask when
the temporary file is created; ``tempfile.mkstemp`` would make it 0600).  A temporary file is
named ``.<name>.<8 random characters>.tmp`` (:func:`is_temporary`).

The one rule for what may be written over (:func:`output_obstacle`, checked by every command before
its work starts and here again just before each rename): a regular file or a new path.  A folder,
a FIFO, a device or a socket is refused, and so is a symbolic link, whatever it points to
(``os.replace`` would replace the link itself, and writing to its target would write where the
path does not say): one line naming the option and the path, exit 2 (:class:`OutputRefused`).

JSON is written with sorted keys, numpy values as plain Python and non-finite numbers as null
(:func:`freebody.numbers.finite_or_none`: JSON has no NaN or inf; a run's status says why a
number is missing).
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import random
import re
import stat
from json.encoder import encode_basestring_ascii as _json_string  # the json module's own (C) escaping
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .. import tolerances as tol
from ..errors import InputError, printable
from ..numbers import finite_or_none

_isfinite = math.isfinite
_RANDOM = random.SystemRandom()  # temporary-file names; not the user's seeded global generator
_NAME_CHARS = "abcdefghijklmnopqrstuvwxyz0123456789_"
_TEMPORARY = re.compile(r"\..+\.[a-z0-9_]{8}\.tmp")


def json_safe(obj):
    """``obj`` with numpy scalars and arrays as plain Python and non-finite floats as None, recursively."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    if isinstance(obj, float):
        return finite_or_none(obj)
    return obj


def json_text(data) -> str:
    """``json.dumps(json_safe(data), sort_keys=True, indent=1, allow_nan=False)``, byte for byte, in
    one walk that appends to a list (the json module's indented encoder is pure Python, a generator
    a token: about 0.6 ms a run of results.json, written twice an invocation)."""
    out: list[str] = []
    _append_json(data, out, "\n")
    return "".join(out)


def _float_text(x: float) -> str:
    return float.__repr__(x) if _isfinite(x) else "null"  # json_safe: a non-finite float is null


# the JSON of a value of exactly one of these types (most of a document), without a walk
_LEAF_TEXT = {float: _float_text, str: _json_string, int: int.__repr__, bool: lambda b: "true" if b else "false",
              type(None): lambda _: "null"}


def _append_json(obj, out: list, nl: str) -> None:
    """Append the JSON of ``obj`` (made :func:`json_safe` on the way) to ``out``; ``nl`` is a new
    line and the indent of ``obj``'s own level."""
    leaf = _LEAF_TEXT.get(type(obj))
    if leaf is not None:
        out.append(leaf(obj))
    elif isinstance(obj, str):  # a subclass (StrEnum): its text
        out.append(_json_string(obj))
    elif isinstance(obj, dict):
        _append_object(obj, out, nl)
    elif isinstance(obj, (list, tuple)):
        _append_array(obj, out, nl)
    elif isinstance(obj, np.ndarray):
        _append_json(obj.tolist(), out, nl)
    elif isinstance(obj, np.generic):
        _append_json(obj.item(), out, nl)
    elif isinstance(obj, float):
        x = finite_or_none(obj)
        out.append("null" if x is None else float.__repr__(x))
    else:
        out.append(_json_scalar(obj))


def _append_object(obj: dict, out: list, nl: str) -> None:
    safe = {str(k): v for k, v in obj.items()}
    if not safe:
        out.append("{}")
        return
    inner, opening = nl + " ", "{"
    for key in sorted(safe):
        v = safe[key]
        leaf = _LEAF_TEXT.get(type(v))
        if leaf is not None:
            out.append(opening + inner + _json_string(key) + ": " + leaf(v))
        else:
            out.append(opening + inner + _json_string(key) + ": ")
            _append_json(v, out, inner)
        opening = ","
    out.append(nl + "}")


def _append_array(obj, out: list, nl: str) -> None:
    if not obj:
        out.append("[]")
        return
    inner, opening = nl + " ", "["
    for v in obj:
        leaf = _LEAF_TEXT.get(type(v))
        if leaf is not None:
            out.append(opening + inner + leaf(v))
        else:
            out.append(opening + inner)
            _append_json(v, out, inner)
        opening = ","
    out.append(nl + "]")


def _json_scalar(obj) -> str:
    """The JSON of None, a bool or an int, as :func:`json.dumps` writes it; TypeError otherwise."""
    if obj is None:
        return "null"
    if obj is True:
        return "true"
    if obj is False:
        return "false"
    if isinstance(obj, int):
        return int.__repr__(obj)
    raise TypeError(f"Object of type {obj.__class__.__name__} is not JSON serializable")


class FileRefused(InputError):
    """An input file that is missing, unreadable, not a regular file or too large: the message is
    ``"<what>: <reason>"``; ``reason`` alone is kept for callers that name the file themselves."""

    def __init__(self, what: str, reason: str):
        super().__init__(f"{what}: {reason}")
        self.reason = reason


def file_kind(mode: int) -> str:
    """What a non-regular file is, from its ``st_mode``: "a folder", "a FIFO (named pipe)", ..."""
    for test, kind in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "a special file"


class OutputRefused(InputError):
    """A path freebody was asked to write that is no regular file nor a new path: the message is
    ``"<what>: <reason>"`` (what: the option and the path, e.g. ``--junit out.xml``)."""

    def __init__(self, what: str, reason: str):
        super().__init__(f"{what}: {reason}")
        self.reason = reason


def output_obstacle(path: str | Path) -> str | None:
    """What is at ``path`` that freebody will not write over ("a FIFO (named pipe)", "a symbolic
    link (to a regular file)", ...), or None when it may write there: nothing is there, or a regular
    file (replaced atomically).  Checked with ``lstat``: the last part of the path must not be a
    symbolic link (the folders on the way to it may be).  A path that cannot be checked (a part of
    it is a file, no permission) is None here: writing it fails with the system's reason."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return None
    if stat.S_ISREG(mode):
        return None
    if not stat.S_ISLNK(mode):
        return file_kind(mode)
    try:
        target = os.stat(path).st_mode
        to = "a regular file" if stat.S_ISREG(target) else file_kind(target)
    except OSError:
        to = "nothing: a dangling link"
    return f"a symbolic link (to {to})"


def check_output_file(path: str | Path, what: str | None = None) -> Path:
    """``path`` as a Path when freebody may write it (:func:`output_obstacle`), else
    :class:`OutputRefused` (one line ``"<what>: <reason>"``; ``what`` defaults to the path)."""
    if path is None or not str(path):
        raise OutputRefused(what or "output file", "empty; give a file's path")
    kind = output_obstacle(path)
    if kind is not None:
        raise OutputRefused(what or printable(path),
                            f"is {kind}, not a regular file; freebody writes only to a regular file or a "
                            f"new path (never over a folder, FIFO, device or socket, nor through a "
                            f"symbolic link)")
    return Path(path)


def make_folder(path: Path, where: str) -> None:
    """Create the folder ``path`` (and its parents) if needed; InputError naming ``where`` when it
    exists as something else or cannot be created."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise InputError(f"{where}: exists and is not a folder") from None
    except NotADirectoryError:
        raise InputError(f"{where}: cannot create the folder: a part of its path is a file") from None
    except OSError as e:
        raise InputError(f"{where}: cannot create the folder: {e.strerror or e}") from None
    if not path.is_dir():
        raise InputError(f"{where}: exists and is not a folder")


def _mib(n: int) -> str:
    return f"{n / 2 ** 20:.4g} MiB"


def open_regular_file(path: str | Path, limit: int, what: str, follow_symlinks: bool = True) -> int:
    """A read-only descriptor of the regular file ``path`` of at most ``limit`` bytes, else
    :class:`FileRefused` (one line ``"<what>: <reason>"``): checked with stat before opening (a
    device is never opened) and with fstat of the descriptor, opened non-blocking (a FIFO swapped in
    between cannot block).  ``follow_symlinks`` False: a symbolic link is refused too (lstat, and
    O_NOFOLLOW where the system has it).  The caller closes the descriptor."""
    try:
        mode = (os.stat if follow_symlinks else os.lstat)(path).st_mode
        if stat.S_ISLNK(mode):
            raise FileRefused(what, "a symbolic link, not a regular file")
        if not stat.S_ISREG(mode):
            raise FileRefused(what, f"not a regular file ({file_kind(mode)})")
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
                     | getattr(os, "O_BINARY", 0) | (0 if follow_symlinks else getattr(os, "O_NOFOLLOW", 0)))
    except FileNotFoundError:
        raise FileRefused(what, "no such file") from None
    except OSError as e:
        raise FileRefused(what, f"cannot read: {e.strerror or e}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced between the two checks
            raise FileRefused(what, f"not a regular file ({file_kind(st.st_mode)})")
        if st.st_size > limit:
            raise FileRefused(what, f"too large: {_mib(st.st_size)}, more than the {_mib(limit)} "
                                    f"freebody reads from such a file")
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_regular_file(path: str | Path, limit: int, what: str) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` bytes; else :class:`FileRefused`
    (an InputError, one line ``"<what>: <reason>"``).

    Every input file goes through here (case files, meshes, results documents and baselines,
    ``--tolerances``; trajectory files through :func:`open_regular_file`): a FIFO would block
    forever and /dev/zero or /dev/urandom would be read until memory runs out, so only regular
    files are read (:func:`open_regular_file`), and only up to ``limit`` bytes (the limits are in
    :mod:`freebody.tolerances`); a file that grows past the limit while being read is refused as well.
    """
    fd = open_regular_file(path, limit, what)
    try:
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(limit + 1 - size, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:  # grew while being read
            raise FileRefused(what, f"too large: more than the {_mib(limit)} freebody reads from "
                                    f"such a file")
        return b"".join(chunks)
    except OSError as e:
        raise FileRefused(what, f"cannot read: {e.strerror or e}") from None
    finally:
        os.close(fd)


def read_json(path: Path, where: str, limit: int = tol.RESULTS_FILE_MAX_BYTES):
    """The parsed JSON of a regular file of at most ``limit`` bytes; InputError starting with
    ``where`` if it cannot be read or parsed."""
    text = read_regular_file(path, limit, where).decode("utf-8")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{where}: not valid JSON: {e.msg} (line {e.lineno}, column {e.colno})") from None


@contextlib.contextmanager
def file_lock(path: Path, waiting: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold an exclusive lock (fcntl ``flock``) on the file ``path`` for the block (the file is
    created if missing and left in place: its name is the lock); ``waiting()`` is called once when
    another process holds it, before waiting for it.  The one file lock of freebody: the shared
    store's maps (:mod:`freebody.run.sharedcache`) and the engine environments
    (:func:`freebody.envs.cache.locked`)."""
    import fcntl

    with open(path, "a") as f:  # closing it releases the lock too
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if waiting is not None:
                waiting()
            fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def is_temporary(name: str) -> bool:
    """Whether a file name is that of a temporary file of this module (left by a killed writer)."""
    return _TEMPORARY.fullmatch(name) is not None


def write_text_atomic(path: Path, text: str, *, what: str | None = None) -> None:
    """Write text (UTF-8) atomically.  ``what`` (e.g. "--junit FILE") names ``path`` if it is
    refused (:func:`check_output_file`)."""
    _write_atomic(path, lambda f: f.write(text.encode("utf-8")), what=what)


def write_bytes_atomic(path: Path, data: bytes, *, what: str | None = None) -> None:
    """Write bytes atomically (``what`` as for :func:`write_text_atomic`)."""
    _write_atomic(path, lambda f: f.write(data), what=what)


def write_json_atomic(path: Path, data: dict, *, before_replace=None, what: str | None = None) -> None:
    """Write JSON (sorted keys, indent 1, non-finite -> null, a final newline) atomically.

    before_replace : called once the temporary file is complete on the disk, just before it is
        renamed over ``path`` (the fault-injection point of :mod:`freebody.results.outdir`).
    what : names ``path`` if it is refused (as for :func:`write_text_atomic`)."""
    text = json_text(data) + "\n"
    _write_atomic(path, lambda f: f.write(text.encode("utf-8")), before_replace, what=what)


def write_npz_atomic(path: Path, arrays: dict, compressed: bool = True, durable: bool = True) -> None:
    """Write arrays to an npz file (``np.savez_compressed``, or ``np.savez``) atomically.
    ``durable`` False: no fsync, for a scratch file that other processes read while this run lasts
    (the rename alone makes it whole to them) and that no one needs after a crash."""
    _write_atomic(path, lambda f: (np.savez_compressed if compressed else np.savez)(f, **arrays),
                  durable=durable)


def _write_atomic(path: Path, write, before_replace=None, what: str | None = None,
                  durable: bool = True) -> None:
    """Check ``path`` (:func:`check_output_file`), create the parent folders, ``write(binary file)``
    to a new temporary file beside ``path``, fsync it (if ``durable``), call ``before_replace()``
    if given, check ``path`` again (it may have changed meanwhile) and rename the temporary file to
    ``path``; the temporary file is removed if anything fails."""
    path = check_output_file(path, what)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _new_temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            if durable:
                os.fsync(f.fileno())
        if before_replace is not None:
            before_replace()
        check_output_file(path, what)
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.filename is None:  # a failed write names no file: name it
            e.filename = str(path)
        raise


def _new_temporary(path: Path) -> tuple[int, str]:
    """A new, empty temporary file beside ``path``, opened for writing: (descriptor, path).  Created
    with mode 0o666, which the kernel reduces by the umask as for any new file."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{''.join(_RANDOM.choices(_NAME_CHARS, k=8))}.tmp"
        try:
            return os.open(tmp, flags, 0o666), str(tmp)
        except FileExistsError:
            continue
    raise FileExistsError(f"{path.parent}: no free temporary file name for {path.name}")
