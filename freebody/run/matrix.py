"""The run matrix: the engines, integrators, precisions and time steps selected on the command
line, expanded into one :class:`~freebody.run.records.RunSpec` per run."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from .. import tolerances as tol
from ..adapters.base import (UnknownEngine, base_engine, default_engine_names, engine_names, resolve_engine,
                             split_engine_name)
from ..errors import InputError
from ..input.casefile import check_run_settings
from ..reference_impl.problem import Problem
from ..envs import engines as engine_envs
from ..envs.facts import engine_facts
from .records import PRECISIONS, RunSpec


def select_engines(requested: list[str] | None, all_engines: bool = False) -> list[str]:
    """Requested engines (validated, case-insensitive; an engine may be named with a version,
    ``mujoco==3.1.6``, run in an isolated environment: :mod:`freebody.envs.engines`), or the default set
    (registry entries with ``default``; every registered engine with ``all_engines``)."""
    if not requested:
        return engine_names() if all_engines else default_engine_names()
    try:
        out = []
        for name in requested:
            e = resolve_engine(name)
            if e not in out:
                out.append(e)
        return out
    except UnknownEngine as e:
        raise InputError(f"--engine: {e.args[0]}") from None


def engine_integrators(engine: str) -> tuple[str, ...] | None:
    """Integrators the installed engine offers (default first), or None if it is not installed or
    its adapter fails to load (its runs then record skipped or failed, with the reason).  An isolated
    engine is asked in its environment; another from its cached facts (:mod:`freebody.envs.facts`:
    no engine import once they are cached)."""
    if engine_envs.isolated(engine):
        info = engine_envs.describe(engine)
        return tuple(info["integrators"]) if info.get("integrators") else None
    facts = engine_facts(engine)
    return tuple(facts["integrators"]) if facts is not None else None


def engine_opt_in(engine: str) -> tuple[str, ...]:
    """The engine's opt-in integrators (``Adapter.opt_in_integrators``: run only when named), ()
    when it has none or is not installed here."""
    if engine_envs.isolated(engine):
        return tuple(engine_envs.describe(engine).get("opt_in") or ())
    facts = engine_facts(engine)
    return tuple(facts["opt_in"]) if facts is not None else ()


def engine_precisions(engine: str) -> tuple[str, ...] | None:
    """Precisions the installed engine offers (``Adapter.precisions``), or None if it is not
    installed or its adapter fails to load."""
    if engine_envs.isolated(engine):
        info = engine_envs.describe(engine)
        return tuple(info["precisions"]) if info.get("precisions") else None
    facts = engine_facts(engine)
    return tuple(facts["precisions"]) if facts is not None else None


def select_precisions(offered: dict[str, tuple[str, ...] | None],
                      requested: list[str] | None) -> dict[str, list[str]]:
    """Apply ``--precision`` selections to every engine: engine -> its precisions to run.

    None: every precision each engine offers.  Otherwise an engine runs the requested ones it
    offers and is left out of the matrix when it offers none; a requested precision that no
    selected engine offers is bad input.  An engine that is not installed (offered None) keeps one
    run (float64, or the first requested), to be recorded as skipped.
    """
    if requested:
        for p in requested:
            if p not in PRECISIONS:
                raise InputError(f"--precision: unknown precision {p!r}; known: {', '.join(PRECISIONS)}")
        known = {e: o for e, o in offered.items() if o is not None}
        if len(known) == len(offered):
            for p in requested:
                if not any(p in o for o in known.values()):
                    have = "; ".join(f"{e}: {', '.join(o)}" for e, o in known.items())
                    raise InputError(f"--precision: no selected engine offers {p} ({have})")
    out = {}
    for engine, o in offered.items():
        if o is None:
            out[engine] = ["float64" if not requested or "float64" in requested else requested[0]]
        elif requested:
            out[engine] = [p for p in o if p in requested]
        else:
            out[engine] = list(o)
    return out


def integrator_aliases(engine: str) -> dict[str, str]:
    """Old integrator names the engine still takes, old -> current (the adapter class's
    ``integrator_aliases``, e.g. the reference engine's ``symplectic-euler`` -> ``lie-euler``);
    {} when it has none or its adapter does not load."""
    facts = engine_facts(engine)  # this environment's adapter (an isolated engine's too, as before)
    return dict(facts["aliases"]) if facts is not None else {}


def _current_name(engine: str, offered: tuple[str, ...], name: str) -> str:
    """``name``, or the offered integrator an old name of the engine's now stands for (with a
    one-line warning that the old name is deprecated); the runs are recorded under the current name."""
    if any(o.lower() == name.lower() for o in offered):
        return name
    for old, new in integrator_aliases(engine).items():
        if old.lower() == name.lower() and new in offered:
            warnings.warn(f"--integrator {name}: the {engine} integrator {old!r} is now called {new!r}; "
                          f"running {new} (the old name is deprecated)", FutureWarning, stacklevel=2)
            return new
    return name


def select_integrators(engine: str, offered: tuple[str, ...], requested: list[str] | None,
                       opt_in: tuple[str, ...] = ()) -> list[str]:
    """Apply ``--integrator`` selections: NAME applies to every engine, ENGINE:NAME to one engine
    (every version of it, unless ENGINE names a version: ``mujoco:RK4`` applies to ``mujoco==3.1.6``).

    An engine to which no selection applies runs all its integrators; one to which selections
    apply but which offers none of them is bad input (the message lists what it offers).  An old
    name of an integrator (:func:`integrator_aliases`) selects the integrator by its current name.
    ``opt_in`` integrators run only when named (a NAME or ENGINE:NAME selection).
    """
    names = []
    for item in requested or []:
        eng, sep, name = item.partition(":")
        if not sep:
            names.append(_current_name(engine, offered, item))
            continue
        try:
            target = resolve_engine(eng)
        except UnknownEngine:
            raise InputError(f"--integrator: unknown engine {eng!r} in {item!r}; "
                             f"known engines: {', '.join(engine_names())}") from None
        if target == engine or (not split_engine_name(target)[1] and target == base_engine(engine)):
            name = _current_name(engine, offered, name)
            if not any(o.lower() == name.lower() for o in offered):
                raise InputError(f"--integrator: {engine} has no integrator {name!r}; "
                                 f"it offers: {', '.join(offered)}")
            names.append(name)
    if not names:
        return [o for o in offered if o not in opt_in]
    chosen = [o for o in offered if any(o.lower() == n.lower() for n in names)]
    if not chosen:
        raise InputError(f"--integrator: {engine} offers none of {', '.join(repr(n) for n in names)}; "
                         f"it offers: {', '.join(offered)}")
    return chosen


def expand(problems: list[Problem], engines: list[str], integrators: list[str] | None,
           dts: list[float] | None, duration: float | None,
           precisions: list[str] | None = None, *, sources: list[str] | None = None,
           all_integrators: bool = False) -> list[RunSpec]:
    """Every run of the matrix, in a stable order (case, dt, engine, integrator, precision), each
    run once: a run is identified by (case name, engine, integrator, precision, dt).

    precisions : None for every precision each engine offers (``Adapter.precisions``), else the
    ones to run (see :func:`select_precisions`).
    sources : where each problem came from (case names or paths), for messages.
    all_integrators : run the engines' opt-in integrators too (``--all-integrators``).

    Duplicates: a case given twice with the same content, or a time step listed twice (``--dt``
    or the case's ``dt``), runs once, with a warning; two different cases with the same name are
    bad input (InputError: their runs could not be told apart)."""
    if dts is not None:
        for d in dts:
            if not (np.isfinite(d) and d > 0):
                raise InputError(f"--dt: must be a finite number > 0, got {d}")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise InputError(f"--duration: must be a finite number > 0, got {duration}")
    check_run_settings(problems, dts, duration, sources)  # a case without dt or duration needs --dt, --duration
    per_engine: dict[str, list[str]] = {}
    for engine in engines:
        offered = engine_integrators(engine)
        if offered is None:
            per_engine[engine] = ["*"]
        else:
            per_engine[engine] = select_integrators(engine, offered, integrators,
                                                    () if all_integrators else engine_opt_in(engine))
    per_precision = select_precisions({e: engine_precisions(e) for e in engines}, precisions)
    specs = []
    for pb in unique_problems(problems, sources):
        for d in _unique_dts(dts or pb.dts, "--dt" if dts else f"case {pb.name!r}: dt"):
            if duration is not None and duration < d:
                raise InputError(f"--duration: {duration} s is shorter than dt = {d} s")
            if duration is None and pb.duration is not None and pb.duration < d * (1 - tol.DURATION_VS_DT_RTOL):
                raise InputError(f"--dt: {d} s is longer than case {pb.name}'s duration ({pb.duration} s)")
            steps = pb.steps(d, duration)
            for engine in engines:
                for integ in per_engine[engine]:
                    for prec in per_precision[engine]:
                        specs.append(RunSpec(pb, engine, integ, float(d), steps, prec))
    return specs


def unique_problems(problems: list[Problem], sources: list[str] | None = None) -> list[Problem]:
    """The problems with exact duplicates (same name, same content) merged, with a warning;
    InputError for two problems with the same name and different contents."""
    sources = list(sources) if sources is not None else [f"case #{i + 1}" for i in range(len(problems))]
    first: dict[str, tuple[int, bytes]] = {}
    out = []
    for i, pb in enumerate(problems):
        content = problem_content(pb)
        if pb.name not in first:
            first[pb.name] = (i, content)
            out.append(pb)
            continue
        j, seen = first[pb.name]
        where = f"{sources[j]}" if sources[j] == sources[i] else f"{sources[j]} and {sources[i]}"
        if content != seen:
            raise InputError(f"case {pb.name!r}: two different cases have this name ({where}); runs are "
                             f"identified by the case name, so give each case its own name")
        warnings.warn(f"case {pb.name!r} is given twice ({where}); running it once")
    return out


def _unique_dts(dts, where: str) -> list[float]:
    """The time steps, each once (exactly equal floats), with a warning for a repeated one."""
    out: list[float] = []
    seen: set[float] = set()  # a set beside the list: a million dts stay linear
    for d in dts:
        if float(d) in seen:
            warnings.warn(f"{where}: {float(d)!r} s is listed twice; running it once")
        else:
            seen.add(float(d))
            out.append(float(d))
    return out


def problem_content(pb: Problem) -> bytes:
    """A canonical encoding of everything in a Problem (arrays bit for bit): equal for two
    problems exactly when they are the same case."""
    def enc(v):
        if isinstance(v, np.ndarray):
            return ("array", v.dtype.str, v.shape, v.tobytes())
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return (type(v).__name__,) + tuple((f.name, enc(getattr(v, f.name))) for f in dataclasses.fields(v))
        if isinstance(v, (list, tuple)):
            return tuple(enc(x) for x in v)
        if isinstance(v, float):
            return ("float", v.hex())
        return (type(v).__name__, repr(v))

    return repr(enc(pb)).encode("utf-8")
