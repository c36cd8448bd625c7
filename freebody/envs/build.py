"""Building an engine's environment (``--engine mujoco==3.1.6``), or reusing the cached one.

One environment per engine requirement: a virtual environment that holds the requested engine,
freebody's core dependencies pinned to the versions of this process (so that the truths and the
reference maps computed there are the same numbers as here) and a copy of freebody's own source.
Worker processes then run ``ENV/bin/python -m freebody.run.worker`` in it (``freebody.run``).
Where environments live, their markers and locks: :mod:`freebody.envs.cache`.

Design decisions:

- The environment is built in a temporary sibling folder and renamed into place, so a build that is
  interrupted (Ctrl-C, a full disk, a failed install) never leaves a folder that looks complete.
- freebody is not installed by pip: its package trees (``freebody``, ``freebody.adapters``,
  ``freebody.reference_impl``, ``freebody.cases``, located with importlib, so an editable install
  of a checkout works as well as a wheel) are copied into the environment's site-packages, with a
  small ``freebody-<version>.dist-info`` so that pip sees freebody as installed (an engine package
  that depends on freebody does not pull another freebody from the index).  A digest of the copied
  files is kept in the marker and compared with the current source on every use: an edited source
  is copied again, so the environment never runs stale freebody code.
- The core dependencies come from freebody's metadata (those without an ``extra`` marker), pinned
  to this process's versions.  When the engine cannot be installed beside those pins (an old engine
  needing an older numpy), the install is retried once unpinned and the marker says ``"pins":
  false``.  When this process's core versions change, the environment is rebuilt.
- Every command runs with ``-P`` (no script or working folder on sys.path), in the environment's
  folder and without PYTHONPATH/PYTHONHOME, so a source checkout in the working folder cannot
  shadow the copy.
- Failures the user sees are one line: bad requirement text is an
  :class:`~freebody.errors.InputError`, a failed build an :class:`EnvironmentFailed` naming the
  requirement, pip's or uv's key error line and the install log.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path, PurePosixPath
from typing import Callable

from ..errors import printable
from ..results.io import check_output_file
from .cache import (BUILDING_SUFFIX, TMP_PREFIX, EngineEnvironment, building_folder, env_root, environment_key,
                    freebody_version, locked, now, owned_marker, remove_environment, sealed, site_packages,
                    write_marker)
from .requirements import NAME_PATTERN, ParsedRequirement, canonical_name, declared_name, parse_requirement

# The package trees copied into an environment (the package-dir mapping of pyproject.toml).
PACKAGES = ("freebody", "freebody.adapters", "freebody.reference_impl", "freebody.cases")
# Files of those trees that are copied (source and data; never __pycache__ or numba's caches).
SOURCE_SUFFIXES = frozenset({".py", ".toml", ".obj", ".json", ".md"})
# What the build checks imports in the new environment.
IMPORT_CHECK = "import freebody, freebody.adapters.base, freebody.run.worker"


class EnvironmentFailed(Exception):
    """An environment could not be created.  ``str()`` is one line: the requirement, the
    environment's folder (when known), the cause when one is recognised (:func:`cause_of`: the
    disk is full, no such version, no network), why (pip's or uv's key error line, or the system's
    error) and, when there is one, ``install log: PATH``."""

    def __init__(self, requirement: str, why: str, log: Path | None = None, path: Path | None = None,
                 cause: str | None = None):
        self.requirement = requirement
        self.why = why
        self.log = log
        self.path = path
        self.cause = cause
        where = f" (install log: {log})" if log is not None else ""
        folder = f" in {path}" if path is not None else ""
        because = f"{cause}: " if cause else ""
        super().__init__(printable(f"cannot create the environment for {requirement}{folder}: "
                                   f"{because}{why}{where}"))


# The causes :func:`cause_of` recognises in an error number or in pip's and uv's output, in order.
_DISK_FULL = "the disk is full"
_CAUSES = (
    (_DISK_FULL, (errno.ENOSPC,), ("No space left on device",)),
    ("the disk quota is reached", (errno.EDQUOT,), ("Disk quota exceeded",)),
    ("no network (the package index cannot be reached)", (errno.ENETUNREACH, errno.ECONNREFUSED),
     ("Failed to establish a new connection", "Temporary failure in name resolution",
      "Name or service not known", "Network is unreachable", "Connection refused", "ConnectTimeout",
      "Read timed out", "dns error", "error sending request", "Failed to fetch")),
)


def cause_of(output: str = "", code: int | None = None, name: str | None = None) -> str | None:
    """Why a build failed, in words: ``the disk is full``, ``the disk quota is reached``, ``no
    network ...`` (from the error number ``code`` or the text ``output``), or ``no such version``
    (pip's or uv's output says that the distribution ``name`` has no matching version); None when
    none is recognised."""
    for cause, codes, texts in _CAUSES:
        if code in codes or any(t in output for t in texts):
            return cause
    if name is not None and _not_found(key_error(output), name):
        return "no such version"
    return None


# --- freebody's source ------------------------------------------------------------------------------

def source_files() -> dict[str, Path]:
    """freebody's source and data files to copy: relative destination (``freebody/adapters/base.py``)
    -> source file, sorted.  Each package of :data:`PACKAGES` is found with importlib (an editable
    install maps ``freebody.adapters`` to the checkout's ``adapters/``; a wheel nests it)."""
    files: dict[str, Path] = {}
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise EnvironmentFailed(name, f"freebody's package {name} cannot be found")
        top = Path(list(spec.submodule_search_locations)[0])
        prefix = PurePosixPath(*name.split("."))
        for dirpath, dirnames, filenames in os.walk(top):
            dirnames[:] = sorted(d for d in dirnames if d != "__pycache__" and not d.startswith("."))
            rel_dir = Path(dirpath).relative_to(top)
            for f in filenames:
                if not f.startswith(".") and os.path.splitext(f)[1] in SOURCE_SUFFIXES:
                    files[(prefix / PurePosixPath(rel_dir.as_posix()) / f).as_posix()] = Path(dirpath) / f
    return dict(sorted(files.items()))


def source_digest(files: dict[str, Path] | None = None) -> str:
    """sha256 over the sorted relative paths and contents of :func:`source_files`."""
    files = source_files() if files is None else files
    h = hashlib.sha256()
    for rel in sorted(files):
        data = files[rel].read_bytes()
        h.update(rel.encode() + b"\0" + str(len(data)).encode() + b"\0")
        h.update(data)
    return h.hexdigest()


def copy_source(dest: Path, files: dict[str, Path] | None = None) -> str:
    """Copy freebody's source (:func:`source_files`) into the folder ``dest`` (a site-packages: it
    gets ``dest/freebody/...``); return its digest.  An existing ``dest/freebody`` is replaced by a
    swap of folders; its ``__pycache__`` folders are kept (Python and numba check each cached
    file against its source's time stamp and size, so only edited modules compile again)."""
    files = source_files() if files is None else files
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    new = Path(tempfile.mkdtemp(prefix=".freebody-new-", dir=dest))
    try:
        for rel, src in files.items():
            target = new / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, target)
        current = dest / "freebody"
        if current.is_dir():
            for cache in list(current.rglob("__pycache__")):
                twin = new / cache.relative_to(dest)
                if twin.parent.is_dir() and not twin.exists():
                    os.rename(cache, twin)
            old = Path(tempfile.mkdtemp(prefix=".freebody-old-", dir=dest))
            os.rename(current, old / "freebody")
            os.rename(new / "freebody", current)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(new / "freebody", current)
    finally:
        shutil.rmtree(new, ignore_errors=True)
    return source_digest(files)


def _write_dist_info(site: Path, core: list[str]) -> None:
    """A minimal ``freebody-<version>.dist-info`` in ``site``, so that pip and importlib.metadata see
    the copied freebody as installed (with its core requirements)."""
    info = site / f"freebody-{freebody_version()}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    lines = ["Metadata-Version: 2.1", "Name: freebody", f"Version: {freebody_version()}",
             "Summary: freebody's source, copied by freebody.envs.build (not installed by pip)",
             *(f"Requires-Dist: {r}" for r in core)]
    (info / "METADATA").write_text("\n".join(lines) + "\n")
    (info / "INSTALLER").write_text("freebody\n")


# --- freebody's core dependencies --------------------------------------------------------------------

def core_requirements() -> list[str]:
    """freebody's core dependencies as its metadata states them (``numpy>=1.24``, ...): every
    requirement without an ``extra`` marker (other markers evaluated when packaging is installed),
    the marker removed."""
    try:
        declared = importlib.metadata.requires("freebody") or []
    except importlib.metadata.PackageNotFoundError:
        raise EnvironmentFailed("freebody", "freebody's dependencies are unknown: freebody is not installed "
                                "as a package (pip install -e . in its checkout)") from None
    core = []
    for text in declared:
        spec, _, marker = text.partition(";")
        if re.search(r"\bextra\s*==", marker):
            continue
        if marker.strip():
            try:
                from packaging.markers import Marker
            except ImportError:
                pass
            else:
                if not Marker(marker.strip()).evaluate():
                    continue
        core.append(spec.strip())
    return core


def core_versions() -> dict[str, str]:
    """Canonical name -> version installed in this process, of each core dependency."""
    out = {}
    for text in core_requirements():
        name = declared_name(text)
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


# --- running commands ----------------------------------------------------------------------------------

def clean_environ() -> dict[str, str]:
    """os.environ without what would put another freebody on an environment's sys.path
    (PYTHONPATH, PYTHONHOME, PYTHONSTARTUP): for every process started with an environment's
    interpreter (with ``-P``, in a folder that holds no freebody checkout)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def _run_logged(cmd: list[str], log, cwd: Path | None = None) -> tuple[int, str]:
    """Run ``cmd``, its stdout and stderr appended to the open file ``log``; (exit code, output)."""
    log.write(f"$ {' '.join(str(c) for c in cmd)}\n")
    log.flush()
    proc = subprocess.run([str(c) for c in cmd], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          stdin=subprocess.DEVNULL, cwd=cwd, env=clean_environ())
    out = proc.stdout.decode("utf-8", "replace")
    log.write(out)
    log.write(f"[exit code {proc.returncode}]\n\n")
    log.flush()
    return proc.returncode, out


def find_uv() -> str | None:
    """The ``uv`` executable (on PATH, or from the ``uv`` Python package), or None."""
    found = shutil.which("uv")
    if found:
        return found
    try:
        import uv  # type: ignore[import-not-found]

        return uv.find_uv_bin()
    except Exception:
        return None


def key_error(output: str) -> str:
    """The line of pip's or uv's output that says why it failed (``No matching distribution found
    for mujoco==9.9``; a conflict's ``Cannot install ...``; uv's ``Because ...`` explanation)."""
    lines = [ln.strip() for ln in output.splitlines()]
    errors = [ln[len("ERROR:"):].strip() for ln in lines if ln.startswith("ERROR:")]
    errors = [e for e in errors if e and not e.startswith("ResolutionImpossible")]
    if errors:
        return errors[-1]
    for i, ln in enumerate(lines):  # uv: "× No solution found ...", then "╰─▶ Because ..." wrapped
        if ln.startswith("╰─▶"):
            text = [ln[len("╰─▶"):].strip()]
            for more in lines[i + 1:]:
                if not more:
                    break
                text.append(more)
            return " ".join(text)
    for ln in reversed(lines):
        if ln.lower().startswith("error") or ln.startswith("×"):
            return ln.lstrip("× ").strip()
    nonblank = [ln for ln in lines if ln and not ln.startswith("[exit code")]
    return nonblank[-1] if nonblank else "no output"


def _not_found(why: str, name: str) -> bool:
    """Whether the key error says that the requested distribution itself cannot be found (then
    retrying without the pins cannot help)."""
    m = (re.search(r"(?:No matching distribution found for|satisfies the requirement|there is no version of)"
                   rf"\s+({NAME_PATTERN})", why)
         or re.search(rf"({NAME_PATTERN}) was not found in the package registry", why))
    return bool(m) and canonical_name(m.group(1)) == name


# --- building ------------------------------------------------------------------------------------------

def _usable(marker: dict | None, env: EngineEnvironment, core: dict[str, str]) -> bool:
    """Whether a marker (one freebody wrote: :func:`~freebody.envs.cache.owned_marker`) describes
    a complete environment for ``env`` built beside this process's core versions, whose
    interpreter still exists."""
    return (marker is not None and marker.get("requirement") == env.requirement
            and marker.get("core") == core and os.path.exists(env.python))


def ensure_environment(requirement: str, progress: Callable[[str], None] | None = None) -> EngineEnvironment:
    """The environment of ``requirement`` (e.g. ``mujoco==3.1.6``), built on first use.

    A complete cached environment is reused (its ``last_used`` updated; freebody's source copied
    again when it changed).  Otherwise it is built under the environment's lock (a second process
    waits, then reuses it).  ``progress`` receives one line per stage.  InputError for a bad
    requirement; :class:`EnvironmentFailed` when the build fails (also for an error of the system,
    a full disk, named with its cause), or when the environment's folder exists and is not one
    freebody built (it is never removed).
    """
    req = parse_requirement(requirement)
    key = environment_key(req.normalised)
    root = env_root()
    path = root / key
    env = EngineEnvironment(req.normalised, path, path / "bin" / "python")
    log = root / "logs" / f"{key}.log"
    try:
        _ensure(req, env, key, progress or (lambda line: None))
    except EnvironmentFailed as e:
        if e.path is None:
            raise EnvironmentFailed(e.requirement, e.why, e.log, path, e.cause) from None
        raise
    except OSError as e:
        why = f"{e.strerror or e}: {printable(e.filename)}" if e.filename is not None else str(e.strerror or e)
        raise EnvironmentFailed(req.normalised, why, log if log.is_file() else None, path,
                                cause_of(why, e.errno)) from None
    return env


def _ensure(req: ParsedRequirement, env: EngineEnvironment, key: str, say: Callable[[str], None]) -> None:
    """:func:`ensure_environment`'s work."""
    root, path = env.path.parent, env.path
    files = source_files()
    digest = source_digest(files)
    core = core_versions()

    marker = owned_marker(path) if path.is_dir() else None
    if _usable(marker, env, core) and marker.get("source_digest") == digest:
        _touch(path, marker)
        return
    root.mkdir(parents=True, exist_ok=True)
    with locked(root, key, lambda: say(f"waiting for another freebody process creating the environment "
                                        f"for {req.normalised}")):
        marker = owned_marker(path) if path.is_dir() else None
        if _usable(marker, env, core):
            if marker.get("source_digest") != digest:
                say(f"copying freebody's changed source into the environment for {req.normalised}")
                marker["source_digest"] = copy_source(site_packages(path), files)
            _touch(path, marker)
            return
        _make_room(root, key, path, marker, req.normalised)
        _build(req, env, key, files, core, say)


def _make_room(root: Path, key: str, path: Path, marker: dict | None, requirement: str) -> None:
    """Before a build (under the lock): remove the folder of an earlier build of ``key`` that was
    killed, and the outdated environment at ``path`` when freebody built it; EnvironmentFailed
    when ``path`` holds anything freebody did not make (it is left as it is)."""
    leftover = building_folder(root, key)
    if leftover is not None:
        shutil.rmtree(leftover, ignore_errors=True)
    with contextlib.suppress(FileNotFoundError):
        (root / "locks" / f"{key}{BUILDING_SUFFIX}").unlink()
    if path.is_symlink() or path.exists() and not path.is_dir():
        left = [path.name]
    elif not path.exists():
        return
    elif marker is not None:
        left = remove_environment(path, marker)
    else:
        left = sorted(p.name for p in path.iterdir())
        if not left:
            path.rmdir()
    if left:
        raise EnvironmentFailed(requirement, f"{path} exists and holds what freebody did not build "
                                f"({', '.join(left[:5])}{', ...' if len(left) > 5 else ''}); freebody "
                                f"removes nothing it did not make: move it away, then retry")


def _touch(path: Path, marker: dict) -> None:
    """Set the marker's ``last_used`` to now, in the current marker format (nothing when the folder
    is not writable)."""
    marker["last_used"] = now()
    with contextlib.suppress(OSError):
        write_marker(path, sealed(marker, path.name, marker["entries"]))


def _build(req: ParsedRequirement, env: EngineEnvironment, key: str, files: dict[str, Path],
           core: dict[str, str], say: Callable[[str], None]) -> None:
    """Build the environment in a temporary sibling folder (named in ``locks/<key>.building`` until
    the build ends), check it, write its marker and rename it into place (under the lock held by
    the caller; the folder ``env.path`` no longer exists)."""
    started = time.monotonic()
    root = env.path.parent
    say(f"creating environment for {req.normalised} in {env.path} (first use; this takes a minute)")
    (root / "logs").mkdir(parents=True, exist_ok=True)
    log_path = check_output_file(root / "logs" / f"{key}.log", "environment log")  # as every file freebody writes
    record = root / "locks" / f"{key}{BUILDING_SUFFIX}"
    tmp = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{key}-", dir=root))
    try:
        record.write_text(f"{tmp.name}\n")
        os.chmod(tmp, 0o755)  # mkdtemp's 0700 would hide a shared FREEBODY_ENV_DIR's environment
        with open(log_path, "w") as log:
            log.write(f"freebody {freebody_version()}: environment for {req.normalised}, built in {tmp} "
                      f"and renamed to {env.path}, {now()}\n\n")
            uv = find_uv()
            marker = _build_in(req, tmp, files, core, uv, log, log_path, say)
            built = time.monotonic() - started
            log.write(f"ready in {built:.1f} s\n")
        stamp = now()
        entries = [p.name for p in tmp.iterdir()]
        write_marker(tmp, sealed({**marker, "created": stamp, "last_used": stamp,
                                  "build_seconds": round(built, 1)}, key, entries))
        os.rename(tmp, env.path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        with contextlib.suppress(OSError):
            record.unlink()
    say(f"ready in {built:.0f} s")


def _build_in(req: ParsedRequirement, tmp: Path, files: dict[str, Path], core: dict[str, str], uv: str | None,
              log, log_path: Path, say: Callable[[str], None]) -> dict:
    """The venv, the copy of freebody, the install and the checks, in the folder ``tmp``; the
    marker's fields (without its times)."""
    py = tmp / "bin" / "python"
    venv = [uv, "venv", "--python", sys.executable, tmp] if uv else [sys.executable, "-m", "venv", tmp]
    code, out = _run_logged(venv, log)
    if code != 0:
        raise EnvironmentFailed(req.normalised, f"creating the virtual environment failed: {key_error(out)}",
                                log_path, cause=cause_of(out))

    def install(requirements: list[str]) -> tuple[int, str]:
        cmd = ([uv, "pip", "install", "--python", py] if uv
               else [py, "-m", "pip", "install", "--disable-pip-version-check", "--no-input"])
        return _run_logged([*cmd, *requirements], log)

    say("copying freebody")
    site = site_packages(tmp)
    digest = copy_source(site, files)
    declared = core_requirements()
    _write_dist_info(site, declared)

    pinned = _install_engine(req, core, declared, install, say, log_path)

    say("checking")
    code, out = _run_logged([py, "-P", "-c", IMPORT_CHECK], log, cwd=tmp)
    if code != 0:
        raise EnvironmentFailed(req.normalised, f"freebody does not import there: {key_error(out)}", log_path,
                                cause=cause_of(out))
    installed, core_installed = _installed(py, req, core, log, tmp)
    if installed is None:
        raise EnvironmentFailed(req.normalised, f"{req.name} is not installed after the install", log_path)
    _check_version(req, installed, log_path)
    return {"requirement": req.normalised, "freebody_version": freebody_version(),
            "python": platform.python_version(), "base_python": sys.executable,
            "machine": platform.machine(), "installer": "uv" if uv else "pip", "pins": pinned,
            "core": core, "core_installed": core_installed, "installed": installed, "source_digest": digest}


def _install_engine(req: ParsedRequirement, core: dict[str, str], declared: list[str],
                    install: Callable[[list[str]], tuple[int, str]], say: Callable[[str], None],
                    log_path: Path) -> bool:
    """Install the engine beside freebody's core dependencies, each pinned to this process's version
    (as declared when it is not installed here); when that fails for another reason than the engine
    not existing, once more with the core dependencies as declared.  Whether the pins held."""
    pins = [f"{n}=={core[n]}" if n in core else r
            for r in declared for n in [declared_name(r)] if n != req.name]
    say(f"installing {' '.join([req.normalised, *pins])}")
    code, out = install([req.normalised, *pins])
    if code == 0:
        return True
    why = key_error(out)
    if _not_found(why, req.name):
        raise EnvironmentFailed(req.normalised, why, log_path, cause=cause_of(out, name=req.name))
    say(f"installing beside freebody's pinned versions failed ({why.rstrip('.')}); "
        f"retrying without the pins")
    unpinned = [r for r in declared if declared_name(r) != req.name]
    code, out = install([req.normalised, *unpinned])
    if code != 0:
        raise EnvironmentFailed(req.normalised, key_error(out), log_path, cause=cause_of(out, name=req.name))
    return False


_INSTALLED_SCRIPT = r"""
import importlib.metadata as m, json, re, sys
def version(name):
    try:
        d = m.distribution(name)
    except m.PackageNotFoundError:
        return None
    return d.metadata["Name"], d.version, d.requires or []
engine = {}
found = version(sys.argv[1])
if found:
    engine[found[0]] = found[1]
    for r in found[2]:
        if not re.search(r"\bextra\s*==", r):
            dep = version(re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", r).group(0))
            if dep:
                engine[dep[0]] = dep[1]
core = {n: (version(n) or (None, None))[1] for n in sys.argv[2:]}
print(json.dumps([engine, core]))
"""


def _installed(py: Path, req: ParsedRequirement, core: dict[str, str], log,
               cwd: Path) -> tuple[dict[str, str] | None, dict[str, str | None]]:
    """(distribution -> version in the environment of the requirement's distribution, first, and of
    its direct dependencies, or None when it is not installed; the versions there of the core
    dependencies, which differ from this process's when the pins were dropped)."""
    code, out = _run_logged([py, "-P", "-c", _INSTALLED_SCRIPT, req.name, *core], log, cwd=cwd)
    try:
        engine, core_there = json.loads(out.strip().splitlines()[-1]) if code == 0 else (None, {})
    except (ValueError, IndexError, TypeError):
        return None, {}
    return (engine if isinstance(engine, dict) and engine else None), core_there


def _check_version(req: ParsedRequirement, installed: dict[str, str], log: Path) -> None:
    """EnvironmentFailed when the installed version does not satisfy the requirement (checked when
    packaging is importable; pip and uv guarantee it anyway)."""
    if not req.specifier:
        return
    try:
        from packaging.specifiers import SpecifierSet
    except ImportError:
        return
    version = next(iter(installed.values()))
    if not SpecifierSet(req.specifier).contains(version, prereleases=True):
        raise EnvironmentFailed(req.normalised, f"{req.name} {version} was installed, which is not "
                                                f"{req.specifier}", log)

