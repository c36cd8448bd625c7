"""The output folder of ``freebody run`` (``--out DIR``): one writer at a time, one atomic publish,
and freebody deletes only what it wrote.

Layout (the documented one; only the folder level under ``trajectories/`` is per invocation)::

    DIR/results.json              the published results; names every trajectory file it uses
    DIR/results.previous.json     the last complete results, kept while results.json is incomplete
    DIR/report.md, DIR/report.html
    DIR/trajectories/<n>/*.npz    the trajectory files of the invocation numbered n (and the truth
                                  files ``truth__<hash>.npz`` they name: one per case and dt)
    DIR/.freebody.lock            locked (flock) by the freebody process writing DIR
    DIR/.freebody-owned.json      what freebody wrote in DIR that it may delete later, the last n

Protocol of one invocation (:class:`OutputFolder`, under :func:`output_lock`):

1. lock ``DIR`` (a second process refuses at once with one line, exit 2; the kernel drops the lock
   when its process dies, even by SIGKILL, so a lock never outlives its process);
2. delete what freebody wrote that no results document names any more (a folder left by a killed
   invocation, the files of a results.json replaced just before a kill, stray temporary files);
3. create ``trajectories/<n>/`` (n above every number used in DIR so far), listed as owned first;
   the runs write their trajectory files there while the previous results.json is untouched;
4. publish: replace results.json (a rename: the one atomic step) with a document naming only files
   in ``trajectories/<n>/``; only then delete the files of the previous results.json.

So a kill at any moment leaves a results.json whose trajectory files all exist.  An interrupted
invocation (Ctrl-C, SIGTERM, SIGHUP) never destroys a complete result: with no run finished it
leaves results.json untouched; with some finished it writes them marked ``"incomplete": true``
and keeps the previous complete results.json as ``results.previous.json`` with its files, until
the next complete run replaces both.

Deleting: an owned folder loses only the trajectory files freebody names (``*__<12 hex>.npz``, truth
files included) and temporary files, and is removed if that empties it; an owned file (a trajectory of the older flat
layout, ``trajectories/<name>.npz``, named by a results.json) is removed alone.  Anything else in
DIR (a user's files, even inside ``trajectories/``) is never touched.

Fault injection (tests): ``FREEBODY_FAULT=after-trajectories|before-publish|after-publish`` makes
the process kill itself with SIGKILL at that point of the publish (:func:`fault_point`).
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import stat
import sys
import threading
from pathlib import Path, PurePosixPath

from ..errors import InputError
from .io import is_temporary, make_folder, output_obstacle, write_json_atomic, write_text_atomic

RESULTS = "results.json"
PREVIOUS = "results.previous.json"
TRAJECTORIES = "trajectories"
LOCK = ".freebody.lock"
OWNED = ".freebody-owned.json"
REPORTS = ("report.md", "report.html")
FAULT_ENV = "FREEBODY_FAULT"
FAULT_POINTS = ("after-trajectories", "before-publish", "after-publish")
# the file names of trajectory files (results.document.trajectory_filename): readable part, hash
_TRAJECTORY_FILE = re.compile(r".+__[0-9a-f]{12}\.npz")
_NUMBER = re.compile(r"[0-9]{1,18}")


def fault_point(name: str) -> None:
    """Kill this process with SIGKILL if the environment variable FREEBODY_FAULT is ``name``
    (a test hook: a kill at an exact point of the publish; see FAULT_POINTS)."""
    if os.environ.get(FAULT_ENV) == name:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os.kill(os.getpid(), signal.SIGKILL)


def out_folder(value) -> Path:
    """``--out`` as a Path; InputError for an empty value ('' would silently mean the current folder)."""
    if value is None or (isinstance(value, str) and not value):
        raise InputError("--out: empty; give an output folder (e.g. --out reports/latest)")
    return Path(value)


# --- one writer at a time ---------------------------------------------------------------------

_held: dict[str, list] = {}  # lock file (real path) -> [descriptor, depth]: re-entrant per process
_held_guard = threading.Lock()


@contextlib.contextmanager
def output_lock(out_dir, option: str = "--out"):
    """Hold DIR's lock (``DIR/.freebody.lock``, ``flock``) for the block, creating DIR if needed.
    ``option`` names DIR in messages (e.g. "--out"; "" for a positional argument).

    Re-entrant within a process.  InputError (one line, exit 2) when another process holds it or
    DIR cannot be created or written.  The kernel releases the lock when its holder dies, so a
    killed freebody never leaves a stale lock behind.
    """
    out_dir = out_folder(out_dir)
    where = f"{option} {out_dir}" if option else str(out_dir)
    make_folder(out_dir, where)
    check_files(out_dir, [LOCK], where)  # its pid is written there: never a device, a link, ...
    key = os.path.realpath(out_dir / LOCK)
    with _held_guard:
        entry = _held.get(key)
        if entry is not None:
            entry[1] += 1
    if entry is not None:
        try:
            yield out_dir
        finally:
            with _held_guard:
                entry[1] -= 1
        return
    fd = _lock(key, where, option)
    with _held_guard:
        _held[key] = [fd, 1]
    try:
        yield out_dir
    finally:
        with _held_guard:
            del _held[key]
        os.close(fd)  # releases the flock


def _lock(key: str, where: str, option: str) -> int:
    try:
        import fcntl
    except ImportError:  # not POSIX: no lock
        fcntl = None
    try:  # not following a link, not blocking on a FIFO: both put there since the check
        fd = os.open(key, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
                     | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0), 0o666)
    except OSError as e:
        raise InputError(f"{where}: cannot write there: {e.strerror or e}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise InputError(f"{where}: {LOCK} is not a regular file; freebody writes {LOCK} there, so "
                         f"move it away or choose another folder")
    if fcntl is None:
        return fd
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
        os.close(fd)
        pid = f" (pid {holder})" if holder.isdigit() else ""
        other = f" or choose another {option}" if option else ""
        raise InputError(f"{where}: another freebody process{pid} is writing to this folder; "
                         f"wait for it to finish{other}") from None
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    return fd


# --- one invocation's trajectory folder and its publish -----------------------------------------

class OutputFolder:
    """One invocation's use of an output folder: its trajectory folder ``trajectories/<n>/``
    (:attr:`trajectory_dir`), :meth:`publish` and :meth:`abandon`.  Create it under
    :func:`output_lock`; creating it cleans up what freebody wrote that nothing names any more."""

    def __init__(self, out_dir):
        self.path = out_folder(out_dir)
        # before any work: never replaced, never read
        check_files(self.path, (RESULTS, PREVIOUS, OWNED), f"--out {self.path}")
        self.previous_text, self.previous = _read_document(self.path / RESULTS)
        _, self.kept = _read_document(self.path / PREVIOUS)
        if _complete(self.previous) and self.kept is not None:
            _unlink(self.path / PREVIOUS)  # superseded (a kill came before its removal)
            self.kept = None
        owned, self.last = _read_owned(self.path / OWNED)
        self.owned = owned | _entries(_named(self.previous) | _named(self.kept))
        self._collect()
        _remove_temporaries(self.path)
        _remove_temporaries(self.path / TRAJECTORIES)
        self.folder = self._new_folder()

    @property
    def trajectory_dir(self) -> Path:
        """Where this invocation's trajectory files go."""
        return self.path / self.folder

    def relative(self, filename: str) -> str:
        """The path (relative to the output folder, as results.json stores it) of one of this
        invocation's trajectory files."""
        return f"{self.folder}/{filename}"

    def publish(self, doc: dict) -> None:
        """Replace results.json by ``doc`` (one atomic rename), then delete what the previous one
        named.  An incomplete ``doc`` keeps a complete previous results.json as
        results.previous.json (with its files)."""
        fault_point("after-trajectories")
        _remove_temporaries(self.trajectory_dir)  # left by a worker killed while saving
        incomplete = bool(doc.get("incomplete"))
        if incomplete and _complete(self.previous):
            write_text_atomic(self.path / PREVIOUS, self.previous_text)
            self.kept = self.previous
        write_json_atomic(self.path / RESULTS, doc, before_replace=lambda: fault_point("before-publish"))
        fault_point("after-publish")
        self.previous = doc
        if not incomplete and self.kept is not None:
            _unlink(self.path / PREVIOUS)
            self.kept = None
        self._collect()

    def abandon(self) -> None:
        """Nothing to publish (interrupted before any run finished): remove this invocation's
        folder, leave results.json as it was."""
        self._collect()

    def _collect(self) -> None:
        """Delete every owned entry that no results document names; record the rest."""
        named = _named(self.previous) | _named(self.kept)
        keep = set()
        for entry in sorted(self.owned):
            if entry in named or any(n.startswith(entry + "/") for n in named):
                keep.add(entry)
            else:
                _remove_owned(self.path, entry)
        self.owned = keep
        self._write_owned()

    def _new_folder(self) -> str:
        """Create ``trajectories/<n>`` with n above every number in use; listed as owned first,
        so that a kill right after its creation leaves nothing freebody would not delete."""
        base = self.path / TRAJECTORIES
        try:
            base.mkdir(exist_ok=True)
            used = [int(c.name) for c in base.iterdir() if _NUMBER.fullmatch(c.name)]
        except OSError as e:
            raise InputError(f"--out {self.path}: cannot write {base}: {e.strerror or e}") from None
        used += [int(PurePosixPath(e).parts[1]) for e in self.owned if _NUMBER.fullmatch(PurePosixPath(e).parts[1])]
        n = max(used + [self.last], default=0) + 1  # never a number used before in this folder
        for _ in range(1000):
            rel = f"{TRAJECTORIES}/{n}"
            self.owned.add(rel)
            self.last = n
            self._write_owned()
            try:
                (self.path / rel).mkdir()
                return rel
            except FileExistsError:
                self.owned.discard(rel)
                n += 1
            except OSError as e:
                raise InputError(f"--out {self.path}: cannot write {self.path / rel}: {e.strerror or e}") from None
        raise InputError(f"--out {self.path}: no free trajectory folder name under {base}")

    def _write_owned(self) -> None:
        write_json_atomic(self.path / OWNED, {"owned": sorted(self.owned), "last": self.last,
                                              "about": "written by freebody: what it may delete here "
                                                       "(owned) and the last trajectory folder number"})


def check_files(folder: Path, names, where: str) -> None:
    """InputError naming ``where`` (e.g. "--out DIR") if one of the files ``names`` that freebody
    writes in ``folder`` is there as anything but a regular file (the rule of
    :func:`.io.output_obstacle`: a folder, a FIFO, a device, a socket, a symbolic link): freebody
    neither reads it (a FIFO would block) nor replaces it."""
    for name in names:
        kind = output_obstacle(Path(folder) / name)
        if kind is not None:
            raise InputError(f"{where}: {name} is not a regular file ({kind}); freebody writes "
                             f"{name} there, so move it away or choose another folder")


def _read_document(path: Path) -> tuple[str | None, dict | None]:
    """(text, parsed document) of a results file, or (None, None) if it is missing or unusable."""
    try:
        text = path.read_text(encoding="utf-8")
        doc = json.loads(text)
    except (OSError, ValueError):
        return None, None
    if not isinstance(doc, dict) or not isinstance(doc.get("runs"), list):
        return None, None
    return text, doc


def _complete(doc: dict | None) -> bool:
    return doc is not None and not doc.get("incomplete")


def _read_owned(path: Path) -> tuple[set[str], int]:
    """(owned entries, the last folder number) of the owned list; (empty, 0) if there is none."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        owned, last = data.get("owned"), data.get("last")
    except (OSError, ValueError, AttributeError):
        return set(), 0
    owned = {e for e in owned if _safe(e)} if isinstance(owned, list) else set()
    return owned, last if isinstance(last, int) and not isinstance(last, bool) and 0 <= last < 10**18 else 0


def _safe(rel) -> bool:
    """Whether ``rel`` is a relative path under trajectories/ without '..' (a path freebody may own)."""
    if not isinstance(rel, str) or not rel or "\\" in rel or "\x00" in rel:
        return False
    p = PurePosixPath(rel)
    return (not p.is_absolute() and len(p.parts) >= 2 and p.parts[0] == TRAJECTORIES
            and str(p) == rel and not any(part in ("..", ".") for part in p.parts))


def _named(doc: dict | None) -> set[str]:
    """The trajectory paths a results document names (those freebody may own)."""
    if doc is None:
        return set()
    return {r["trajectory"] for r in doc["runs"] if isinstance(r, dict) and _safe(r.get("trajectory"))}


def _entries(paths: set[str]) -> set[str]:
    """What freebody owns for these trajectory paths: the folder ``trajectories/<n>`` of a path in
    it, a file of the flat layout (``trajectories/<name>.npz``) itself."""
    out = set()
    for rel in paths:
        parts = PurePosixPath(rel).parts
        out.add(rel if len(parts) == 2 else f"{parts[0]}/{parts[1]}")
    return out


def _remove_owned(root: Path, entry: str) -> None:
    """Delete an owned entry: a file (a trajectory of the flat layout), or from a folder the
    trajectory and temporary files freebody writes, and the folder if that empties it."""
    path = root / entry
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return
    if stat.S_ISDIR(mode):
        with contextlib.suppress(OSError):
            for child in path.iterdir():
                if _TRAJECTORY_FILE.fullmatch(child.name) or is_temporary(child.name):
                    if not child.is_dir():
                        _unlink(child)
        with contextlib.suppress(OSError):
            path.rmdir()
    elif path.name.endswith(".npz"):
        _unlink(path)


def _remove_temporaries(folder: Path) -> None:
    """Delete the temporary files of writes a kill interrupted (see results.io.is_temporary)."""
    with contextlib.suppress(OSError):
        for child in folder.iterdir():
            if is_temporary(child.name) and not child.is_dir():
                _unlink(child)


def _unlink(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
