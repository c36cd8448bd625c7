"""Where an engine's runs execute: this Python environment, or an isolated one of its own.

An engine named with a version (``mujoco==3.1.6``) or registered with an ``environment`` (an engine
whose package pins conflict with another engine's, :class:`~freebody.adapters.base.EngineEntry`)
runs in worker processes of an isolated environment that :mod:`freebody.envs.build` creates on
first use and caches.  This module maps engine names to those environments for one invocation:
it builds them (progress on stderr), asks each what its engine offers (integrators, precisions,
version: the parent cannot import an engine version it does not hold), and gives the executor the
interpreter each run's worker must be.

Everything here is per process and cached: an environment is ensured once per invocation, an
engine described once.
"""
from __future__ import annotations

import sys
from functools import lru_cache

from ..adapters.base import (UnknownEngine, base_engine, engine_requirement, registry, registry_entry,
                             split_engine_name, version_in)
from ..errors import InputError


@lru_cache(maxsize=None)
def requirement(engine: str) -> str | None:
    """The pip requirement of the environment the engine's runs need, or None: this one.

    A versioned engine whose version installed here satisfies its specifier (``mujoco==4.0.0``
    with MuJoCo 4.0.0 installed) runs here: the same engine, without building an environment."""
    try:
        req = engine_requirement(engine)
        spec = split_engine_name(engine)[1]
        entry = registry_entry(engine)
    except UnknownEngine as e:
        raise InputError(f"--engine: {e.args[0]}") from None
    if req is not None and spec and entry.environment is None:
        import importlib.metadata

        try:
            here = importlib.metadata.version(entry.distribution)
        except importlib.metadata.PackageNotFoundError:
            here = None
        if here is not None and version_in(here, spec):
            return None
    return req


def isolated(engine: str) -> bool:
    """Whether the engine's runs execute in an isolated environment."""
    return requirement(engine) is not None


def _progress(line: str) -> None:
    sys.stderr.write(f"freebody: {line}\n")
    sys.stderr.flush()


@lru_cache(maxsize=None)
def environment(engine: str):
    """The isolated environment of an engine (:class:`freebody.envs.cache.EngineEnvironment`),
    created on first use; InputError (one line: the requirement, pip's reason, the log) when it
    cannot be built."""
    from .build import EnvironmentFailed, ensure_environment

    req = requirement(engine)
    if req is None:
        raise ValueError(f"{engine} runs in this environment")
    try:
        return ensure_environment(req, progress=_progress)
    except EnvironmentFailed as e:
        raise InputError(f"--engine {engine}: {e}") from None


@lru_cache(maxsize=None)
def describe(engine: str) -> dict:
    """What an isolated engine offers, asked in its environment: ``available``, ``version``,
    ``integrators``, ``precisions``, ``error`` (see :func:`freebody.envs.describe.describe_engine`)."""
    from .describe import describe_engine

    return describe_engine(environment(engine), engine, entry=registry()[base_engine(engine)])


def interpreters(engines) -> dict[str, str]:
    """engine -> the Python interpreter its worker processes run (isolated engines only)."""
    return {e: str(environment(e).python) for e in dict.fromkeys(engines) if isolated(e)}
