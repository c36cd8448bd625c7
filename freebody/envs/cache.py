"""The cache of engine environments: where they live, under which name, their markers and locks,
and listing and clearing them (``freebody envs list`` / ``clear``).  Building one is
:mod:`freebody.envs.build`.

Layout of :func:`env_root` (``$FREEBODY_ENV_DIR``, else ``$XDG_CACHE_HOME/freebody/envs``, else
``~/.cache/freebody/envs``)::

    <key>/                  one environment (:func:`environment_key`: slug of the requirement + hash)
    <key>/freebody-env.json the marker, written last: a folder without it is incomplete (rebuilt)
    .tmp-<key>-XXXX/        an environment being built, renamed to <key>/ when complete (atomic)
    locks/<key>.lock        fcntl lock: one process builds an environment, the others wait for it
    logs/<key>.log          the full output of the last build's venv, pip or uv commands

Only folders that are environments (a marker, or a key's name and a ``pyvenv.cfg``) are ever
listed or removed, whatever else the folder holds.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import re
import shutil
import sys
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator

from .requirements import normalise_requirement

ENV_DIR_VARIABLE = "FREEBODY_ENV_DIR"
MARKER = "freebody-env.json"

# an environment being built: TMP_PREFIX + key + "-" + random, renamed to key when complete
TMP_PREFIX = ".tmp-"
KEY_HASH_CHARS = 12
KEY_RE = re.compile(rf"^[a-z0-9][a-z0-9.-]*-[0-9a-f]{{{KEY_HASH_CHARS}}}$")


@dataclass(frozen=True)
class EngineEnvironment:
    """A complete environment: ``requirement`` (normalised, e.g. ``mujoco==3.1.6``), its folder
    ``path`` and its interpreter ``python`` (``path/bin/python``)."""

    requirement: str
    path: Path
    python: Path

# --- where, and under which name --------------------------------------------------------------------

def freebody_version() -> str:
    """This freebody's version (part of every environment's key and marker)."""
    from .. import __version__

    return __version__


def environment_key(requirement: str) -> str:
    """The folder name of a requirement's environment: a readable slug of the normalised
    requirement and a short hash of (requirement, freebody version, Python major.minor, machine)."""
    norm = normalise_requirement(requirement)
    slug = norm.lower()
    for op, word in (("===", "-"), ("==", "-"), ("~=", "-compat-"), ("!=", "-not-"), (">=", "-ge-"),
                     ("<=", "-le-"), (">", "-gt-"), ("<", "-lt-")):
        slug = slug.replace(op, word)
    slug = re.sub(r"[^a-z0-9.]+", "-", slug).strip("-.")[:60].strip("-.") or "env"
    identity = json.dumps([norm, freebody_version(), f"{sys.version_info[0]}.{sys.version_info[1]}",
                           platform.machine()])
    return f"{slug}-{hashlib.sha256(identity.encode()).hexdigest()[:KEY_HASH_CHARS]}"


def env_root() -> Path:
    """The folder of the environments: ``$FREEBODY_ENV_DIR``, else ``$XDG_CACHE_HOME/freebody/envs``
    (an absolute XDG_CACHE_HOME only, as the XDG specification says), else
    ``~/.cache/freebody/envs``.  Always absolute."""
    chosen = os.environ.get(ENV_DIR_VARIABLE)
    if chosen:
        return Path(chosen).expanduser().absolute()
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "freebody" / "envs"
    return Path.home() / ".cache" / "freebody" / "envs"


# --- markers and locks -------------------------------------------------------------------------------

def now() -> str:
    """The current UTC time, ISO 8601 to the second (the marker's ``created`` and ``last_used``)."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def read_marker(folder: Path) -> dict | None:
    """The marker of an environment folder, or None (missing, unreadable, not a JSON object)."""
    try:
        data = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def write_marker(folder: Path, data: dict) -> None:
    """Write the marker atomically (a temporary file renamed over it)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{MARKER}.", dir=folder)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2, sort_keys=True)
            f.write("\n")
        os.replace(tmp, folder / MARKER)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def site_packages(folder: Path) -> Path:
    """The site-packages folder of the environment at ``folder`` (this interpreter's Python version)."""
    return folder / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"


@contextlib.contextmanager
def locked(root: Path, key: str, waiting: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold the fcntl lock of one environment (``root/locks/<key>.lock``); ``waiting()`` is called
    once when another process holds it."""
    import fcntl

    (root / "locks").mkdir(parents=True, exist_ok=True)
    with open(root / "locks" / f"{key}.lock", "a") as f:
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


# --- listing and clearing ------------------------------------------------------------------------------

def _folder_size(folder: Path) -> int:
    total = 0
    for dirpath, _, filenames in os.walk(folder):
        for f in filenames:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(dirpath, f)).st_size
    return total


def _environment_folders(root: Path) -> list[Path]:
    """The environment folders of ``root`` (complete or not; not the temporary ones)."""
    if not root.is_dir():
        return []
    return sorted(p for p in root.iterdir() if p.is_dir() and not p.is_symlink()
                  and ((p / MARKER).is_file() or (KEY_RE.match(p.name) and (p / "pyvenv.cfg").exists())))


def list_environments() -> list[dict]:
    """The complete environments of :func:`env_root`, sorted by requirement: each a dict of
    requirement, path, size_bytes, created, last_used, freebody_version, python, installed
    (distribution -> version of the engine's packages), source_digest, pins (whether freebody's
    core dependencies are pinned to this process's versions) and core_installed (their versions)."""
    out = []
    for folder in _environment_folders(env_root()):
        marker = read_marker(folder)
        if marker is None:
            continue
        out.append({"requirement": marker.get("requirement"), "path": str(folder),
                    "size_bytes": _folder_size(folder), "created": marker.get("created"),
                    "last_used": marker.get("last_used"), "freebody_version": marker.get("freebody_version"),
                    "python": marker.get("python"), "installed": marker.get("installed") or {},
                    "source_digest": marker.get("source_digest"), "pins": marker.get("pins"),
                    "core_installed": marker.get("core_installed") or {}})
    return sorted(out, key=lambda e: (str(e["requirement"]), e["path"]))


def clear_environments(requirements: list[str] | None = None) -> list[Path]:
    """Remove every environment (``None``; also the leftovers of interrupted builds) or those of
    the named requirements (any freebody or Python version); return the removed folders.  Each is
    removed under its lock (a build in progress is waited for).  Only folders that are
    environments are touched, whatever else :func:`env_root` holds."""
    root = env_root()
    wanted = None if requirements is None else {normalise_requirement(r) for r in requirements}
    keys = set() if wanted is None else {environment_key(r) for r in wanted}
    removed = []
    for folder in _environment_folders(root):
        if wanted is not None and folder.name not in keys \
                and (read_marker(folder) or {}).get("requirement") not in wanted:
            continue
        with locked(root, folder.name):
            if folder.exists():
                shutil.rmtree(folder)
                removed.append(folder)
        with contextlib.suppress(OSError):
            (root / "logs" / f"{folder.name}.log").unlink()
    if wanted is None and root.is_dir():
        for leftover in sorted(root.glob(f"{TMP_PREFIX}*")):
            key = leftover.name[len(TMP_PREFIX):].rsplit("-", 1)[0]
            if leftover.is_dir() and KEY_RE.match(key):
                with locked(root, key):
                    if leftover.exists():
                        shutil.rmtree(leftover)
                        removed.append(leftover)
    return removed

