"""What an installed engine's adapter answers without stepping, cached on disk so that the parent
process of ``freebody run`` need not import the engine to ask.

Expanding the run matrix and writing results.json read, for each selected engine, its version, the
integrators and precisions it offers, its opt-in integrators, its old integrator names, its
conventions and whether it steps runs together (``freebody sweep``: whether it steps bodies as a
batch).  Those answers are the adapter class's, and asking
the class means importing the engine (JAX, Drake, SAPIEN: seconds between them).  They are static
for one installed engine, so :func:`engine_facts` keeps them in a small JSON file per engine under
:func:`facts_dir` (``$FREEBODY_ENGINE_FACTS_DIR``, else ``$XDG_CACHE_HOME/freebody/engine-facts``,
else ``~/.cache/freebody/engine-facts``), like :mod:`freebody.envs.describe` asks an isolated
environment once.

The file's name holds a digest of everything the answers depend on (:func:`fingerprint`): the
engine's registry entry; its installed module (the path, size and modification time of its file,
which installing or upgrading the engine rewrites); the folders of the import path that hold
installed packages (their modification times change when any package is installed, upgraded or
removed: a dependency such as JAX for MJX); freebody's adapter and reference sources (sizes and
modification times: an edited adapter); the interpreter.  A changed fingerprint is a miss: the
adapter is imported and asked, as without the cache, and the file rewritten.

The cache is used only where it saves an import: for a built-in adapter (a module of
``freebody.adapters``) whose module is not imported yet.  Once imported (a worker, a test that
changed a class attribute) the class is asked directly; a plug-in's adapter is always asked (its
module is probed in a child process first, see :func:`freebody.adapters.base.load_adapter`).
A missing engine, or one whose adapter fails to load, has no facts (None): its runs record why.
A cache folder that cannot be written costs only the import.
"""
from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import sys
import tempfile
from pathlib import Path

FACTS_DIR_VARIABLE = "FREEBODY_ENGINE_FACTS_DIR"
# The fields of a facts file; a change of their meaning bumps it (older files are then misses).
FACTS_FORMAT = 2  # 2: supports_batch (freebody sweep's batches)
_BUILT_IN_PREFIX = "freebody.adapters."
_memo: dict[str, dict | None] = {}  # fingerprint -> facts, this process
# (engine, entry, import path) -> its fingerprint, this process: a command asks each engine several
# times (about 1 ms of stat calls each time); a long-lived process with an adapter edited meanwhile
# has that adapter imported, which is asked directly
_fingerprints: dict[tuple, str | None] = {}


def facts_dir() -> Path:
    """The folder of the engine facts files (see the module docstring)."""
    if os.environ.get(FACTS_DIR_VARIABLE):
        return Path(os.environ[FACTS_DIR_VARIABLE])
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(cache) / "freebody" / "engine-facts"


def convention_rows(cls) -> list[list[str]]:
    """An adapter class's conventions as ``freebody conventions`` and the reports state them:
    [[convention, text], ...], its load sampling last (results.json ``conventions``, schema 7)."""
    return [[k, str(v)] for k, v in cls.conventions.items()] + [["load sampling", cls.load_sampling_text()]]


def facts_of(cls) -> dict:
    """The answers of an adapter class: ``version``, ``integrators`` (offered, default first),
    ``opt_in``, ``precisions``, ``aliases`` (old -> current), ``conventions``
    (:func:`convention_rows`), ``steps_runs_together``, ``supports_batch`` and ``unsupported``
    (why this adapter cannot drive the installed version, or None)."""
    from ..adapters.base import unsupported_version

    version = str(cls.engine_version())
    return {"version": version, "integrators": list(cls.offered_integrators()),
            "opt_in": list(cls.opt_in_integrators), "precisions": list(cls.precisions),
            "aliases": dict(cls.integrator_aliases), "conventions": convention_rows(cls),
            "steps_runs_together": bool(cls.steps_runs_together), "supports_batch": bool(cls.supports_batch),
            "unsupported": unsupported_version(cls, version)}


def _stat(path) -> list:
    try:
        st = os.stat(path)
    except OSError:
        return [str(path), None]
    return [str(path), st.st_size, st.st_mtime_ns]


def fingerprint(engine: str, entry) -> str | None:
    """A digest of what the engine's facts depend on (see the module docstring), or None when
    they are not cached: a plug-in, or the engine's module is not installed."""
    from .. import adapters, reference_impl

    if not entry.module.startswith(_BUILT_IN_PREFIX):
        return None
    spec = importlib.util.find_spec(entry.import_name)
    if spec is None or not spec.origin:
        return None
    sources = sorted(str(p) for folder in (adapters.__path__[0], reference_impl.__path__[0])
                     for p in Path(folder).glob("*.py"))
    site = [p for p in sys.path if os.path.basename(p.rstrip(os.sep)) in ("site-packages", "dist-packages")]
    key = {"format": FACTS_FORMAT, "engine": engine, "entry": list(entry), "python": sys.executable,
           "version": sys.version, "module": _stat(spec.origin), "site": [_stat(p) for p in site],
           "sources": [_stat(p) for p in sources + [__file__]]}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def engine_facts(engine: str) -> dict | None:
    """The facts of an engine of this environment (:func:`facts_of`), from its cache file when the
    fingerprint matches and its adapter is not imported yet, else from its adapter class (and
    then written to the cache); None when the engine is not installed or its adapter fails to load
    (the run records why).  ``engine`` is a registered name (not an isolated engine's: those are
    asked in their environment, :func:`freebody.envs.engines.describe`)."""
    from ..adapters.base import base_engine, is_available, registry_entry

    name = base_engine(engine)
    entry = registry_entry(name)
    if entry.module in sys.modules or not is_available(name):
        return _live(name)
    seen = (name, entry, tuple(sys.path))
    if seen not in _fingerprints:
        _fingerprints[seen] = fingerprint(name, entry)
    key = _fingerprints[seen]
    if key is None:
        return _live(name)
    if key not in _memo:
        path = facts_dir() / f"{name}-{key}.json"
        facts = _read(path)
        if facts is None:
            facts = _live(name)
            if facts is not None:
                _write(path, facts)
        _memo[key] = facts
    return _memo[key]


def _live(name: str) -> dict | None:
    """The facts asked of the adapter class (imported, its banners discarded), None when it is
    missing or fails to load."""
    from ..adapters.base import is_available, load_adapter
    from ..adapters.capture import capture_output

    try:
        if not is_available(name):
            return None
        with capture_output():  # some engines print a banner on import (pybullet)
            return facts_of(load_adapter(name))
    except Exception:  # missing or broken: the runs record which
        return None


def _read(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != FACTS_FORMAT or not isinstance(data.get("facts"), dict):
        return None
    return data["facts"]


def _write(path: Path, facts: dict) -> None:
    """Write the facts file atomically and remove the engine's older ones; a folder that cannot be
    written is left alone (the next process asks the adapter again)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump({"format": FACTS_FORMAT, "facts": facts}, f, sort_keys=True)
        os.replace(tmp, path)
        engine = path.name.rsplit("-", 1)[0]
        for old in path.parent.glob(f"{engine}-*.json"):
            if old != path and old.name.rsplit("-", 1)[0] == engine:
                old.unlink(missing_ok=True)
    except OSError:
        pass
