"""The cache of engine environments: where they live, under which name, their markers and locks,
and listing and clearing them (``freebody envs list`` / ``clear``).  Building one is
:mod:`freebody.envs.build`.

Layout of :func:`env_root` (``$FREEBODY_ENV_DIR``, else ``$XDG_CACHE_HOME/freebody/envs``, else
``~/.cache/freebody/envs``)::

    <key>/                  one environment (:func:`environment_key`: slug of the requirement + hash)
    <key>/freebody-env.json the marker, written last (:func:`owned_marker` checks it)
    .tmp-<key>-XXXX/        an environment being built, renamed to <key>/ when complete (atomic)
    locks/<key>.lock        fcntl lock: one process builds an environment, the others wait for it
    locks/<key>.building    the name of the ``.tmp-<key>-XXXX`` folder its build is making
    logs/<key>.log          the full output of the last build's venv, pip or uv commands

Only what freebody built is ever removed: a folder whose marker is one freebody wrote for that
folder (:func:`owned_marker`: its ``digest`` binds the marker format, the requirement, the folder's
name and the entries the build made), and of it only those entries; a ``.tmp-`` folder only when a
``locks/<key>.building`` file names it.  Anything else is left and listed as not freebody's
(:func:`foreign_entries`).
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
from typing import Callable

from ..errors import InputError
from .requirements import normalise_requirement

ENV_DIR_VARIABLE = "FREEBODY_ENV_DIR"
MARKER = "freebody-env.json"
# The marker's format: 2 adds ``marker_format``, ``entries`` and ``digest`` (:func:`owned_marker`);
# format 1 (none of them) is still read.
MARKER_FORMAT = 2
# What a format-1 environment's build made at its top level (python -m venv, uv venv, the marker):
# clearing one removes these, nothing else.
FORMAT1_ENTRIES = frozenset({"bin", "include", "lib", "lib64", "share", "pyvenv.cfg", ".gitignore",
                             "CACHEDIR.TAG", MARKER})
# The folders of env_root() that are freebody's own (never listed as not freebody's).
OWN_FOLDERS = ("locks", "logs")
BUILDING_SUFFIX = ".building"

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
    return _key(norm, freebody_version(), f"{sys.version_info[0]}.{sys.version_info[1]}", platform.machine())


def _key(norm: str, version: str, python: str, machine: str) -> str:
    """The key of a normalised requirement built by freebody ``version`` with Python ``python``
    (major.minor) on ``machine``."""
    slug = norm.lower()
    for op, word in (("===", "-"), ("==", "-"), ("~=", "-compat-"), ("!=", "-not-"), (">=", "-ge-"),
                     ("<=", "-le-"), (">", "-gt-"), ("<", "-lt-")):
        slug = slug.replace(op, word)
    slug = re.sub(r"[^a-z0-9.]+", "-", slug).strip("-.")[:60].strip("-.") or "env"
    identity = json.dumps([norm, version, python, machine])
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


def marker_digest(requirement: str, key: str, entries: list[str]) -> str:
    """The ``digest`` of a marker of format :data:`MARKER_FORMAT`: sha256 over that format, the
    normalised requirement, the environment folder's name (its key) and the sorted names of the
    entries its build made at the folder's top level.  No secret: it tells freebody's markers from a
    copied, renamed or hand-written one, so that freebody never removes a folder it did not build."""
    identity = json.dumps(["freebody-env", MARKER_FORMAT, requirement, key, sorted(entries)])
    return hashlib.sha256(identity.encode()).hexdigest()


def sealed(data: dict, key: str, entries: list[str]) -> dict:
    """The marker ``data`` of the environment folder ``key`` made of ``entries`` (the marker among
    them), with its format and digest (:func:`marker_digest`)."""
    entries = sorted(set(entries) | {MARKER})
    return {**data, "marker_format": MARKER_FORMAT, "key": key, "entries": entries,
            "digest": marker_digest(str(data.get("requirement")), key, entries)}


def owned_marker(folder: Path) -> dict | None:
    """The marker of ``folder`` when freebody built that folder, else None.  Format 2: its ``key``
    is the folder's name and its ``digest`` is :func:`marker_digest` of its fields.  Format 1 (no
    ``marker_format``; freebody before issue 28): accepted when it holds what freebody wrote, a
    ``key`` that is the folder's name and that its requirement, freebody version, Python and
    machine hash to (:func:`environment_key`); its entries are then the venv's
    (:data:`FORMAT1_ENTRIES`), and its next use rewrites it in format 2."""
    marker = read_marker(folder)
    if marker is None or marker.get("key") != folder.name or not isinstance(marker.get("requirement"), str):
        return None
    if marker.get("marker_format") == MARKER_FORMAT:
        entries = marker.get("entries")
        if isinstance(entries, list) and all(isinstance(e, str) for e in entries) \
                and marker.get("digest") == marker_digest(marker["requirement"], folder.name, entries):
            return marker
        return None
    if "marker_format" in marker:
        return None
    python = ".".join(str(marker.get("python")).split(".")[:2])
    try:
        key = _key(normalise_requirement(marker["requirement"]), str(marker.get("freebody_version")), python,
                   str(marker.get("machine")))
    except InputError:
        return None
    if key != folder.name:
        return None
    present = {p.name for p in folder.iterdir()}
    return {**marker, "entries": sorted(present & FORMAT1_ENTRIES)}


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


def locked(root: Path, key: str, waiting: Callable[[], None] | None = None):
    """Hold the lock of one environment (``root/locks/<key>.lock``, a
    :func:`freebody.results.io.file_lock`) for a ``with`` block; ``waiting()`` is called once when
    another process holds it."""
    from ..results.io import file_lock

    (root / "locks").mkdir(parents=True, exist_ok=True)
    return file_lock(root / "locks" / f"{key}.lock", waiting)


# --- listing and clearing ------------------------------------------------------------------------------

def _folder_size(folder: Path) -> int:
    total = 0
    for dirpath, _, filenames in os.walk(folder):
        for f in filenames:
            with contextlib.suppress(OSError):
                total += os.lstat(os.path.join(dirpath, f)).st_size
    return total


def _owned_environments(root: Path) -> list[tuple[Path, dict]]:
    """(folder, marker) of each environment of ``root`` that freebody built (:func:`owned_marker`)."""
    if not root.is_dir():
        return []
    found = []
    for p in sorted(root.iterdir()):
        if p.is_dir() and not p.is_symlink() and p.name not in OWN_FOLDERS:
            marker = owned_marker(p)
            if marker is not None:
                found.append((p, marker))
    return found


def building_records(root: Path) -> dict[str, Path]:
    """key -> the ``locks/<key>.building`` file of each build that was started and has not ended
    (in progress, or killed: its ``.tmp-`` folder is then a leftover freebody may remove)."""
    folder = root / "locks"
    if not folder.is_dir():
        return {}
    return {p.name[:-len(BUILDING_SUFFIX)]: p for p in sorted(folder.glob(f"*{BUILDING_SUFFIX}"))
            if p.is_file() and not p.is_symlink() and KEY_RE.match(p.name[:-len(BUILDING_SUFFIX)])}


def building_folder(root: Path, key: str) -> Path | None:
    """The ``.tmp-<key>-XXXX`` folder that ``locks/<key>.building`` names, or None."""
    try:
        name = (root / "locks" / f"{key}{BUILDING_SUFFIX}").read_text().strip()
    except OSError:
        return None
    if not name.startswith(f"{TMP_PREFIX}{key}-") or "/" in name:
        return None
    return root / name


def remove_environment(folder: Path, marker: dict) -> list[str]:
    """Remove what freebody built in ``folder`` (the ``entries`` of its owned ``marker``), the
    marker last, then the folder when nothing else is left; the names of what is left (not
    freebody's, kept)."""
    for name in marker["entries"]:
        path = folder / name
        if name == MARKER or name in ("", ".", "..") or "/" in name:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
    with contextlib.suppress(FileNotFoundError):
        (folder / MARKER).unlink()
    left = sorted(p.name for p in folder.iterdir())
    if not left:
        folder.rmdir()
    return left


def list_environments() -> list[dict]:
    """The environments freebody built in :func:`env_root`, sorted by requirement: each a dict of
    requirement, path, size_bytes, created, last_used, freebody_version, python, installed
    (distribution -> version of the engine's packages), source_digest, pins (whether freebody's
    core dependencies are pinned to this process's versions) and core_installed (their versions)."""
    out = []
    for folder, marker in _owned_environments(env_root()):
        out.append({"requirement": marker.get("requirement"), "path": str(folder),
                    "size_bytes": _folder_size(folder), "created": marker.get("created"),
                    "last_used": marker.get("last_used"), "freebody_version": marker.get("freebody_version"),
                    "python": marker.get("python"), "installed": marker.get("installed") or {},
                    "source_digest": marker.get("source_digest"), "pins": marker.get("pins"),
                    "core_installed": marker.get("core_installed") or {}})
    return sorted(out, key=lambda e: (str(e["requirement"]), e["path"]))


def foreign_entries() -> list[tuple[Path, str]]:
    """(path, why) of each entry of :func:`env_root` that is not freebody's: neither an environment
    it built, nor its ``locks``/``logs``, nor the folder of a build it started.  freebody never
    lists them as environments nor removes them."""
    root = env_root()
    if not root.is_dir():
        return []
    owned = {folder for folder, _ in _owned_environments(root)}
    building = {building_folder(root, key) for key in building_records(root)}
    out = []
    for p in sorted(root.iterdir()):
        if p in owned or p in building or (p.name in OWN_FOLDERS and p.is_dir() and not p.is_symlink()):
            continue
        if p.is_dir() and not p.is_symlink() and (p / MARKER).exists():
            why = "its marker is not one freebody wrote for this folder"
        elif KEY_RE.match(p.name) or p.name.startswith(TMP_PREFIX):
            why = "named like an environment, without freebody's marker"
        else:
            why = "not made by freebody"
        out.append((p, why))
    return out


def clear_environments(requirements: list[str] | None = None) -> list[Path]:
    """Remove every environment freebody built (``None``; also the folders of interrupted builds)
    or those of the named requirements (any freebody or Python version); return their folders.
    Each is removed under its lock (a build in progress is waited for), and of each only what its
    build made (:func:`remove_environment`): a file put there by hand is kept, with its folder.
    Nothing else of :func:`env_root` is touched (:func:`foreign_entries` lists it)."""
    root = env_root()
    wanted = None if requirements is None else {normalise_requirement(r) for r in requirements}
    removed = []
    for folder, marker in _owned_environments(root):
        if wanted is not None and marker.get("requirement") not in wanted:
            continue
        with locked(root, folder.name):
            marker = owned_marker(folder) if folder.is_dir() else None
            if marker is not None:
                remove_environment(folder, marker)
                removed.append(folder)
        with contextlib.suppress(OSError):
            (root / "logs" / f"{folder.name}.log").unlink()
    if wanted is None:
        for key, record in building_records(root).items():
            with locked(root, key):  # a build in progress ends first (and removes its record)
                leftover = building_folder(root, key)
                if leftover is not None and leftover.is_dir() and not leftover.is_symlink():
                    shutil.rmtree(leftover)
                    removed.append(leftover)
                with contextlib.suppress(FileNotFoundError):
                    record.unlink()
    return removed
