"""The abstract engine adapter and the explicit, lazily imported registry of engines.

An adapter builds one free-body :class:`~freebody.reference_impl.problem.Problem` in its engine,
applies the case's loads before each step, steps, and reads the state back in freebody's
canonical convention (``reference_impl/conventions.py``).  Engines are imported only inside their
adapter module, and adapter modules only when a run needs them: ``import freebody`` imports no
engine.  Third parties add an engine through the entry-point group ``freebody.adapters``
(``name = "package.module:AdapterClass"``).
"""
from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from ..reference_impl.conventions import Trajectory
from ..reference_impl.problem import Problem

ENTRY_POINT_GROUP = "freebody.adapters"


class EngineMissing(Exception):
    """The engine's Python package is not installed (the run is ``skipped``)."""


class UnknownEngine(KeyError):
    """No adapter is registered under that name (bad input)."""


class EngineDiverged(Exception):
    """The simulated state blew up: non-finite, beyond the case's bounds, or the engine's own
    instability warning.  Carries the time it happened and the trajectory up to that point."""

    def __init__(self, t: float, reason: str, trajectory: Trajectory | None = None):
        super().__init__(f"diverged at t = {t:.6g} s: {reason}")
        self.t = t
        self.reason = reason
        self.trajectory = trajectory


class Adapter(ABC):
    """One engine's free body.

    Class attributes (capabilities):
      name : engine name as used on the command line.
      import_name : the engine's top-level Python module (checked with ``find_spec``).
      install_hint : how to install the engine.
      integrators : integrator names the engine offers, its default first, spelt as the engine does.
      precisions : floating-point precisions offered ("float64" unless the engine says otherwise).
      supports_point_force, supports_body_torque : load kinds the adapter can apply.
      conventions : engine convention facts shown by ``freebody conventions``.
      compare_with : the engine this one ports, compared run by run (or None).

    An instance is one run: ``Adapter(problem, dt, integrator, precision)`` builds the world;
    ``simulate(steps)`` steps it and returns the canonical :class:`Trajectory`.  ``settings``
    records every engine default the adapter changed: ``{key: {"default": d, "set": v}}``.
    """

    name: ClassVar[str]
    import_name: ClassVar[str]
    install_hint: ClassVar[str] = "pip install 'freebody[engines]'"
    integrators: ClassVar[tuple[str, ...]]
    precisions: ClassVar[tuple[str, ...]] = ("float64",)
    supports_point_force: ClassVar[bool] = True
    supports_body_torque: ClassVar[bool] = True
    conventions: ClassVar[dict[str, str]] = {}
    # Another engine this one ports (e.g. mjx -> mujoco): each run is also compared with that
    # engine's run of the same integrator and dt (results.json "vs_engine").
    compare_with: ClassVar[str | None] = None

    def __init__(self, problem: Problem, dt: float, integrator: str, precision: str = "float64"):
        self.problem = problem
        self.dt = float(dt)
        self.integrator = integrator
        self.precision = precision
        self.settings: dict[str, dict] = {}
        self.k = 0  # index of the next step
        self.build()

    # --- what every adapter must do ------------------------------------------------------------
    @classmethod
    @abstractmethod
    def engine_version(cls) -> str:
        """The installed engine's version string."""

    @classmethod
    def offered_integrators(cls) -> tuple[str, ...]:
        """Integrators available in the installed version (default first)."""
        return cls.integrators

    @abstractmethod
    def build(self) -> None:
        """Create the engine world for ``self.problem`` at ``self.dt`` with ``self.integrator``."""

    @abstractmethod
    def apply_loads(self, k: int) -> None:
        """Apply the case's loads acting on step k (from t_k to t_k+1); cleared after the step."""

    @abstractmethod
    def step(self) -> None:
        """Advance the engine by one step of dt."""

    @abstractmethod
    def read_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(position (3,) m COM world, quaternion (4,) wxyz body -> world,
        linear velocity (3,) m/s COM world, angular velocity (3,) rad/s world)."""

    # --- optional hooks --------------------------------------------------------------------------
    def instability(self) -> str | None:
        """The engine's own instability warning since the last call, or None."""
        return None

    def close(self) -> None:
        """Release the engine's resources."""

    def record_setting(self, key: str, default, value) -> None:
        """Note that the adapter changed an engine default (stored as results.json engine_settings)."""
        self.settings[key] = {"default": _plain(default), "set": _plain(value)}

    def unsupported(self, feature: str) -> NotImplementedError:
        return NotImplementedError(f"{feature} is not supported by {self.name}")

    # --- the run loop ----------------------------------------------------------------------------
    def simulate(self, steps: int) -> Trajectory:
        """Step ``steps`` times from the current state (the initial state on a fresh adapter); the
        trajectory has steps + 1 samples, t = (k0 + i) dt with k0 = self.k.

        Raises :class:`EngineDiverged` (with the trajectory so far) when the engine reports an
        instability.
        """
        k0 = self.k
        out = Trajectory.empty(steps + 1)
        out.t[:] = (k0 + np.arange(steps + 1)) * self.dt
        pos, quat, vel, ang = out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity
        pos[0], quat[0], vel[0], ang[0] = self.read_state()
        for i in range(steps):
            k = k0 + i
            self.apply_loads(k)
            self.step()
            self.k = k + 1
            pos[i + 1], quat[i + 1], vel[i + 1], ang[i + 1] = self.read_state()
            warning = self.instability()
            if warning is not None:
                raise EngineDiverged(self.k * self.dt, warning, _truncate(out, i + 2))
        return out


def _truncate(tr: Trajectory, n: int) -> Trajectory:
    return tr.head(n)


def _plain(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, (list, tuple)):
        return [_plain(a) for a in v]
    return v


# --- the registry -------------------------------------------------------------------------------
# engine name -> (the engine's import name, adapter module, adapter class).  Order = report order.
ENGINES: dict[str, tuple[str, str, str]] = {
    "reference": ("numpy", "freebody.adapters.reference", "ReferenceAdapter"),
    "mujoco": ("mujoco", "freebody.adapters.mujoco_adapter", "MujocoAdapter"),
    "pybullet": ("pybullet", "freebody.adapters.pybullet_adapter", "PybulletAdapter"),
    "dart": ("dartpy", "freebody.adapters.dart_adapter", "DartAdapter"),
    "mjx": ("jax", "freebody.adapters.mjx_adapter", "MjxAdapter"),
}


# How to install an engine that is missing (default: the `engines` extra).
INSTALL_HINTS: dict[str, str] = {"mjx": "pip install 'freebody[jax]'"}


def install_hint(name: str) -> str:
    return INSTALL_HINTS.get(name, "pip install 'freebody[engines]'")


def _entry_point_engines() -> dict[str, tuple[str, str, str]]:
    found = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        module, _, cls = ep.value.partition(":")
        found.setdefault(ep.name, (module.split(".")[0], module, cls))
    return found


def registry() -> dict[str, tuple[str, str, str]]:
    """All engines: the built-in ones, then third parties' (entry points)."""
    reg = dict(ENGINES)
    for name, spec in _entry_point_engines().items():
        reg.setdefault(name, spec)
    return reg


def engine_names() -> list[str]:
    return list(registry())


def resolve_engine(name: str) -> str:
    """The registered spelling of an engine name (case-insensitive); UnknownEngine otherwise."""
    for known in registry():
        if known.lower() == name.lower():
            return known
    raise UnknownEngine(f"unknown engine {name!r}; known engines: {', '.join(engine_names())}")


def is_available(name: str) -> bool:
    """Whether the engine's package can be found, without importing it."""
    import_name = registry()[resolve_engine(name)][0]
    return importlib.util.find_spec(import_name) is not None


def load_adapter(name: str) -> type[Adapter]:
    """Import and return the adapter class of an engine.

    Raises EngineMissing when the engine's own package is not installed (only that ImportError:
    a broken install raises its real error, to be recorded as a failed run).
    """
    name = resolve_engine(name)
    import_name, module, cls = registry()[name]
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        # only "no module named <engine>" means missing; "cannot import name X from <engine>"
        # (also e.name == engine) is a broken install
        if isinstance(e, ModuleNotFoundError) and e.name == import_name:
            raise EngineMissing(f"{name} is not installed (import {import_name!r} failed): "
                                f"{install_hint(name)}") from e
        raise
    return getattr(mod, cls)
