"""What an engine offers in an environment, asked there: the parent process cannot import an
engine version it does not hold, so it runs ``ENV/bin/python -m freebody.envs.describe describe
ENGINE`` (:func:`describe_engine`), which prints the engine's availability, version, integrators
and precisions as one JSON line (:func:`describe_here` in the environment's freebody).
"""
from __future__ import annotations

import json
import subprocess
import sys

from .build import clean_environ
from .cache import EngineEnvironment

DESCRIBE_PREFIX = "freebody-describe: "


def describe_engine(env: EngineEnvironment, engine: str, timeout: float = 300, entry=None) -> dict:
    """What the environment's freebody says of ``engine`` (a name, versioned or not): {"engine",
    "available", "version", "integrators", "precisions", "error", "unsupported"} (``unsupported``:
    why freebody's adapter cannot drive that version, or None), from ``python -m
    freebody.envs.describe describe ENGINE`` run with the environment's interpreter.  A crash or a
    timeout is ``available: False`` with the reason in ``error``.  ``entry``: the engine's
    :class:`~freebody.adapters.base.EngineEntry` in this process's registry, registered there first
    (an engine registered at run time, which the environment's freebody does not know)."""
    extra = [json.dumps(entry._asdict())] if entry is not None else []
    failed = {"engine": engine, "available": False, "version": None, "integrators": None,
              "precisions": None, "unsupported": None}
    try:
        proc = subprocess.run([str(env.python), "-P", "-m", "freebody.envs.describe", "describe", engine,
                               *extra],
                              capture_output=True, stdin=subprocess.DEVNULL, cwd=env.path,
                              env=clean_environ(), timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**failed, "error": f"describing {engine} timed out after {timeout:g} s"}
    except OSError as e:
        return {**failed, "error": f"cannot run {env.python}: {e.strerror or e}"}
    for line in reversed(proc.stdout.decode("utf-8", "replace").splitlines()):
        if line.startswith(DESCRIBE_PREFIX):
            try:
                data = json.loads(line[len(DESCRIBE_PREFIX):])
            except ValueError:
                break
            if isinstance(data, dict):
                return data
    stderr = [ln for ln in proc.stderr.decode("utf-8", "replace").splitlines() if ln.strip()]
    why = stderr[-1].strip() if stderr else f"exit code {proc.returncode}"
    return {**failed, "error": f"describing {engine} failed: {why}"}


def describe_here(engine: str, entry: dict | None = None) -> dict:
    """The description of ``engine`` in this process (see :func:`describe_engine`); ``entry``: the
    fields of its registry entry, registered under its base name first."""
    from ..adapters import base
    from ..adapters.base import EngineMissing, UnknownEngine, is_available, load_adapter
    from ..adapters.capture import capture_output

    if entry is not None:
        name = base.split_engine_name(engine)[0]
        base.ENGINES[name] = base.EngineEntry(**entry)

    out = {"engine": engine, "available": False, "version": None, "integrators": None,
           "precisions": None, "error": None, "unsupported": None}
    try:
        with capture_output():  # engine banners must not reach stdout, which carries the JSON
            if not is_available(engine):
                raise EngineMissing(f"{engine} is not installed in this environment")
            cls = load_adapter(engine)
            version = str(cls.engine_version())
            out.update(version=version, integrators=list(cls.offered_integrators()),
                       precisions=list(cls.precisions), available=True,
                       opt_in=list(cls.opt_in_integrators))
            out["unsupported"] = base.unsupported_version(cls, version)  # the adapter's version range
    except UnknownEngine as e:
        out["error"] = str(e.args[0]) if e.args else str(e)
    except Exception as e:
        out["error"] = str(e) if isinstance(e, EngineMissing) else f"{type(e).__name__}: {e}"
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m freebody.envs.describe describe ENGINE``: one JSON line prefixed with
    :data:`DESCRIBE_PREFIX` on stdout."""
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) not in (2, 3) or argv[0] != "describe":
        sys.stderr.write("usage: python -m freebody.envs.describe describe ENGINE [ENTRY-JSON]\n")
        return 2
    entry = json.loads(argv[2]) if len(argv) == 3 else None
    sys.stdout.write(DESCRIBE_PREFIX + json.dumps(describe_here(argv[1], entry)) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
