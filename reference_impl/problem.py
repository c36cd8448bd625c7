"""The free-body problem as plain, immutable data: body, initial state, gravity, loads.

Knows nothing of files or engines: ``freebody.input.casefile`` builds a :class:`Problem` from TOML,
adapters build engine worlds from it.  All vectors are in the canonical convention
(see :mod:`conventions`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .rotations import matrix_from_quat

# A load's start/stop times are compared with t_k = k dt; this slack (a fraction of dt) keeps
# k dt from missing a boundary by one rounding error.
_STEP_BOUNDARY_SLACK = 1e-9


def _frozen(a, shape) -> np.ndarray:
    arr = np.array(a, dtype=float).reshape(shape)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Body:
    """A rigid body.

    mass : float, kg, > 0.
    I_body : ndarray, shape (3, 3), kg m^2, about the COM, body frame, symmetric positive definite.
    """

    mass: float
    I_body: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "I_body", _frozen(self.I_body, (3, 3)))
        object.__setattr__(self, "_I_body_inv", None)  # computed on first use (not a field)

    @property
    def I_body_inv(self) -> np.ndarray:
        """I_body^-1, shape (3, 3), 1/(kg m^2), body frame: inverted once per body (every reference
        map run of identification asks for it), a fresh copy each call (callers may write to it)."""
        if self._I_body_inv is None:
            object.__setattr__(self, "_I_body_inv", np.linalg.inv(self.I_body))
        return self._I_body_inv.copy()


@dataclass(frozen=True)
class InitialState:
    """The state at t = 0, canonical convention.

    position : (3,) m, COM, world.  quaternion_wxyz : (4,) unit, body -> world.
    linear_velocity : (3,) m/s, COM, world.  angular_velocity : (3,) rad/s, world.
    """

    position: np.ndarray
    quaternion_wxyz: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray

    def __post_init__(self):
        for name, n in (("position", 3), ("quaternion_wxyz", 4), ("linear_velocity", 3),
                        ("angular_velocity", 3)):
            object.__setattr__(self, name, _frozen(getattr(self, name), (n,)))


@dataclass(frozen=True)
class Load:
    """An external load held constant over each step it is on.

    force : (3,) N, world.  Acts at ``point`` (3,) m, a point fixed in the world, or at
        ``body_point`` (3,) m, body frame (moves with the body), or else at the COM.
    torque : (3,) N m, world frame: a pure couple.
    body_torque : (3,) N m, body frame: a couple that turns with the body.
    start : s.  It acts on the step from t_k to t_k+1 when start <= t_k < stop, where stop is
        ``end`` or start + steps * dt, or infinity when neither is given.
    """

    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    point: np.ndarray | None = None
    body_point: np.ndarray | None = None
    torque: np.ndarray = field(default_factory=lambda: np.zeros(3))
    body_torque: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start: float = 0.0
    steps: int | None = None
    end: float | None = None

    def __post_init__(self):
        for name in ("force", "torque", "body_torque"):
            object.__setattr__(self, name, _frozen(getattr(self, name), (3,)))
        for name in ("point", "body_point"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _frozen(getattr(self, name), (3,)))

    def stop(self, dt: float) -> float:
        if self.end is not None:
            return self.end
        if self.steps is not None:
            return self.start + self.steps * dt
        return np.inf

    def step_range(self, dt: float) -> tuple[int, float]:
        """(k0, k1): the load acts on the steps k0 <= k < k1 (k1 may be infinite)."""
        k0 = int(np.ceil(self.start / dt - _STEP_BOUNDARY_SLACK))
        stop = self.stop(dt)
        k1 = np.inf if np.isinf(stop) else int(np.ceil(stop / dt - _STEP_BOUNDARY_SLACK))
        return max(k0, 0), k1

    def active(self, k: int, dt: float) -> bool:
        """Whether the load acts on the step from t_k = k dt to t_k+1."""
        k0, k1 = self.step_range(dt)
        return k0 <= k < k1

    def wrench(self, x: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force, torque about the COM), both world, for COM position x (3,) and R (3, 3)."""
        f = self.force
        tau = self.torque + R @ self.body_torque
        if self.point is not None:
            tau = tau + np.cross(self.point - x, f)
        elif self.body_point is not None:
            tau = tau + np.cross(R @ self.body_point, f)
        return f, tau


@dataclass(frozen=True)
class Problem:
    """A whole free-body case: body, initial state, constant gravity, loads, horizon, time steps.

    gravity : (3,) m/s^2, world.
    duration : s, or None when ``duration_steps`` (a number of steps at every dt) is given.
    dts : tuple of default time steps, s.
    """

    name: str
    description: str
    body: Body
    initial: InitialState
    gravity: np.ndarray
    loads: tuple[Load, ...] = ()
    duration: float | None = None
    duration_steps: int | None = None
    dts: tuple[float, ...] = (0.01,)

    def __post_init__(self):
        object.__setattr__(self, "gravity", _frozen(self.gravity, (3,)))
        object.__setattr__(self, "loads", tuple(self.loads))
        object.__setattr__(self, "dts", tuple(float(d) for d in self.dts))

    def steps(self, dt: float, duration: float | None = None) -> int:
        """Number of steps at dt: round(duration / dt), or duration_steps."""
        if duration is not None:
            return max(1, int(round(duration / dt)))
        if self.duration_steps is not None:
            return int(self.duration_steps)
        return max(1, int(round(self.duration / dt)))

    def active_loads(self, k: int, dt: float) -> tuple[Load, ...]:
        """The loads acting on the step from t_k to t_k+1."""
        return tuple(ld for ld in self.loads if ld.active(k, dt))

    def wrench(self, loads: tuple[Load, ...], x: np.ndarray, R: np.ndarray):
        """Sum of the given loads' (force, torque about the COM), world, gravity NOT included."""
        f = np.zeros(3)
        tau = np.zeros(3)
        for ld in loads:
            fi, ti = ld.wrench(x, R)
            f = f + fi
            tau = tau + ti
        return f, tau

    def switch_steps(self, dt: float, steps: int) -> list[int]:
        """Step indices k in (0, steps) at which the set of active loads changes, ascending."""
        ks = set()
        for ld in self.loads:
            for k in ld.step_range(dt):
                if 0 < k < steps:
                    ks.add(int(k))
        return sorted(ks)

    @property
    def R0(self) -> np.ndarray:
        """Initial rotation matrix, (3, 3), body -> world."""
        return matrix_from_quat(self.initial.quaternion_wxyz)

    @property
    def torque_free(self) -> bool:
        return len(self.loads) == 0
