"""freebody's one canonical convention, written once.

Every number that crosses a freebody boundary (case files, adapters, trajectories, results.json)
is in this convention; adapters convert at their boundary with the named helpers below.

- Units: SI (m, kg, s, rad, N, N m, J).
- Quaternions: Hamilton convention, stored scalar first ``(w, x, y, z)``, rotating body -> world:
  ``v_world = R(q) @ v_body``. ``q`` and ``-q`` are the same rotation; comparisons accept either.
- Position: centre of mass (COM) in the world frame, m.
- Linear velocity: COM velocity in the world frame, m/s.
- Angular velocity: in the world frame, rad/s (``w_world = R @ w_body``).
- Inertia ``I_body``: about the COM, in the body frame, kg m^2, shape (3, 3), symmetric.
- Derived quantities: ``p = M v``; ``L = R I_body R^T w`` (world, about the COM);
  kinetic energy ``1/2 M v.v + 1/2 w.L``; potential energy ``-M g.x`` (g the gravity vector).

Arrays may carry leading batch/time axes: a "(..., 3)" shape means any number of leading axes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rotations import matrix_from_quat

__all__ = [
    "State",
    "Trajectory",
    "quat_wxyz_from_xyzw",
    "quat_xyzw_from_wxyz",
    "angular_velocity_world_from_body",
    "angular_velocity_body_from_world",
    "linear_momentum",
    "angular_momentum",
    "kinetic_energy",
    "potential_energy",
]


def quat_wxyz_from_xyzw(q_xyzw: np.ndarray) -> np.ndarray:
    """Reorder a quaternion from scalar-last (x, y, z, w) to scalar-first (w, x, y, z).

    q_xyzw : array_like, shape (..., 4), Hamilton, scalar last.
    """
    q = np.asarray(q_xyzw, dtype=float)
    return np.concatenate([q[..., 3:4], q[..., 0:3]], axis=-1)


def quat_xyzw_from_wxyz(q_wxyz: np.ndarray) -> np.ndarray:
    """Reorder a quaternion from scalar-first (w, x, y, z) to scalar-last (x, y, z, w).

    q_wxyz : array_like, shape (..., 4), Hamilton, scalar first.
    """
    q = np.asarray(q_wxyz, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def angular_velocity_world_from_body(q_wxyz: np.ndarray, w_body: np.ndarray) -> np.ndarray:
    """w_world = R(q) w_body.  q_wxyz: (..., 4) body -> world; w_body: (..., 3) rad/s, body frame."""
    R = matrix_from_quat(q_wxyz)
    return np.einsum("...ij,...j->...i", R, np.asarray(w_body, dtype=float))


def angular_velocity_body_from_world(q_wxyz: np.ndarray, w_world: np.ndarray) -> np.ndarray:
    """w_body = R(q)^T w_world.  q_wxyz: (..., 4) body -> world; w_world: (..., 3) rad/s, world."""
    R = matrix_from_quat(q_wxyz)
    return np.einsum("...ji,...j->...i", R, np.asarray(w_world, dtype=float))


def linear_momentum(mass: float, v: np.ndarray) -> np.ndarray:
    """p = M v.  v: (..., 3) COM velocity, world, m/s. Returns (..., 3), kg m/s, world."""
    return mass * np.asarray(v, dtype=float)


def angular_momentum(I_body: np.ndarray, q_wxyz: np.ndarray, w_world: np.ndarray) -> np.ndarray:
    """L = R I_body R^T w about the COM, world frame, kg m^2/s.

    I_body : (3, 3) kg m^2, COM, body frame.  q_wxyz : (..., 4).  w_world : (..., 3) rad/s.
    Returns (..., 3).
    """
    R = matrix_from_quat(q_wxyz)
    w_body = np.einsum("...ji,...j->...i", R, w_world)
    return np.einsum("...ij,...j->...i", R, w_body @ np.asarray(I_body, dtype=float).T)


def kinetic_energy(mass: float, I_body: np.ndarray, q_wxyz: np.ndarray, v: np.ndarray,
                   w_world: np.ndarray) -> np.ndarray:
    """1/2 M v.v + 1/2 w.L, J.  Shapes as in :func:`angular_momentum`; returns shape (...)."""
    L = angular_momentum(I_body, q_wxyz, w_world)
    return 0.5 * mass * np.sum(v * v, axis=-1) + 0.5 * np.sum(w_world * L, axis=-1)


def potential_energy(mass: float, gravity: np.ndarray, x: np.ndarray) -> np.ndarray:
    """-M g.x, J.  gravity: (3,) m/s^2 world; x: (..., 3) COM position, world, m."""
    return -mass * np.asarray(x, dtype=float) @ np.asarray(gravity, dtype=float)


@dataclass(frozen=True)
class State:
    """One instant of a free rigid body, canonical convention.

    t : float, s.
    position : ndarray, shape (3,), COM, world, m.
    quaternion_wxyz : ndarray, shape (4,), Hamilton (w, x, y, z), body -> world, unit.
    linear_velocity : ndarray, shape (3,), COM velocity, world, m/s.
    angular_velocity : ndarray, shape (3,), world, rad/s.
    """

    t: float
    position: np.ndarray
    quaternion_wxyz: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray

    def as_dict(self) -> dict:
        return {
            "t": float(self.t),
            "position": [float(a) for a in self.position],
            "quaternion_wxyz": [float(a) for a in self.quaternion_wxyz],
            "linear_velocity": [float(a) for a in self.linear_velocity],
            "angular_velocity": [float(a) for a in self.angular_velocity],
        }


@dataclass(frozen=True)
class Trajectory:
    """A sampled motion, canonical convention, float64, one row per instant t_k = k dt.

    t : ndarray, shape (N,), s.
    position : ndarray, shape (N, 3), COM, world, m.
    quaternion_wxyz : ndarray, shape (N, 4), Hamilton (w, x, y, z), body -> world.
    linear_velocity : ndarray, shape (N, 3), COM, world, m/s.
    angular_velocity : ndarray, shape (N, 3), world, rad/s.
    orthonormality_error : ndarray, shape (N,), or None: ||R^T R - 1||_F of the 3x3 matrix as
        integrated (matrix integrators only; their quaternion is that of the nearest rotation).
    """

    t: np.ndarray
    position: np.ndarray
    quaternion_wxyz: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    orthonormality_error: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    def state(self, k: int) -> State:
        """The k-th sample as a :class:`State` (negative k counts from the end)."""
        return State(float(self.t[k]), self.position[k].copy(), self.quaternion_wxyz[k].copy(),
                     self.linear_velocity[k].copy(), self.angular_velocity[k].copy())

    @classmethod
    def on_grid(cls, k0: int, dt: float, position: np.ndarray, quaternion_wxyz: np.ndarray,
                linear_velocity: np.ndarray, angular_velocity: np.ndarray) -> "Trajectory":
        """N samples of a fixed-step run at t_i = (k0 + i) dt, i = 0 .. N - 1 (what an engine
        adapter's ``advance`` returns: its first sample is step k0's state).

        k0 : int, the step index of the first sample.  dt : float, s.
        position, quaternion_wxyz, linear_velocity, angular_velocity : array_like, shapes (N, 3),
            (N, 4), (N, 3), (N, 3), already in the canonical convention (see the module
            docstring); stored as C-contiguous float64 arrays, copied only when they are not
            already (a column slice of an engine's state rows is copied; an array that is
            already one is kept as it is, so pass one the adapter does not write again).
        """
        arrays = [np.ascontiguousarray(a, dtype=np.float64)
                  for a in (position, quaternion_wxyz, linear_velocity, angular_velocity)]
        return cls((k0 + np.arange(len(arrays[0]))) * dt, *arrays)

    @classmethod
    def empty(cls, n: int, with_orthonormality: bool = False) -> "Trajectory":
        """Preallocated arrays for n samples (filled with NaN until written)."""
        nan = np.full
        return cls(
            t=nan(n, np.nan), position=nan((n, 3), np.nan), quaternion_wxyz=nan((n, 4), np.nan),
            linear_velocity=nan((n, 3), np.nan), angular_velocity=nan((n, 3), np.nan),
            orthonormality_error=nan(n, np.nan) if with_orthonormality else None,
        )

    def head(self, n: int) -> "Trajectory":
        """The first n samples (views, no copy); the trajectory itself when it has n samples."""
        if len(self.t) == n:
            return self
        ortho = None if self.orthonormality_error is None else self.orthonormality_error[:n]
        return Trajectory(self.t[:n], self.position[:n], self.quaternion_wxyz[:n],
                          self.linear_velocity[:n], self.angular_velocity[:n], ortho)

    def tail(self, start: int) -> "Trajectory":
        """The samples from index ``start`` on (views, no copy)."""
        ortho = None if self.orthonormality_error is None else self.orthonormality_error[start:]
        return Trajectory(self.t[start:], self.position[start:], self.quaternion_wxyz[start:],
                          self.linear_velocity[start:], self.angular_velocity[start:], ortho)

    @classmethod
    def concatenate(cls, pieces: "list[Trajectory]") -> "Trajectory":
        """Consecutive pieces (no repeated samples) as one trajectory (copies)."""
        ortho = None
        if all(p.orthonormality_error is not None for p in pieces):
            ortho = np.concatenate([p.orthonormality_error for p in pieces])
        return cls(*(np.concatenate([getattr(p, f) for p in pieces])
                     for f in ("t", "position", "quaternion_wxyz", "linear_velocity",
                               "angular_velocity")), ortho)

    def without_orthonormality(self) -> "Trajectory":
        """The same samples without the matrix integrators' orthonormality error (as truths have)."""
        return Trajectory(self.t, self.position, self.quaternion_wxyz, self.linear_velocity,
                          self.angular_velocity)

    def take(self, idx: np.ndarray) -> "Trajectory":
        """The samples at the indices ``idx`` (ascending ints, shape (K,)), copies."""
        ortho = None if self.orthonormality_error is None else self.orthonormality_error[idx]
        return Trajectory(self.t[idx], self.position[idx], self.quaternion_wxyz[idx],
                          self.linear_velocity[idx], self.angular_velocity[idx], ortho)
