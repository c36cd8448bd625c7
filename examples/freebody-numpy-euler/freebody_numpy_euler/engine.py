"""A tiny rigid-body "engine": one free body, stepped by Euler on the momentum form (x, q, p, L).

It knows nothing of freebody and, like a real engine, has conventions and defaults of its own
that an adapter must convert or override:

- the quaternion is stored scalar-LAST, (x, y, z, w) (Hamilton, body -> world);
- the state is momenta: p (kg m/s, world) and L (kg m^2/s, world, about the COM); velocities
  are derived, v = p / M and w = R I_b^-1 R^T L (world);
- defaults: dt = 0.01 s, gravity (0, 0, -9.81) m/s^2, and a little angular damping (0.05 1/s);
- a force and torque applied with ``apply_force_torque`` act on the next step only;
- ``warning`` is set when a step leaves a non-finite state (its "instability warning").

Schemes: ``symplectic`` (momenta first, then x and q with the new velocities, q rotated by the
exponential map) and ``explicit`` (every rate taken at the start of the step, q renormalised).
"""
from __future__ import annotations

import numpy as np

SCHEMES = ("symplectic", "explicit")


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of two (x, y, z, w) quaternions."""
    av, aw, bv, bw = a[:3], a[3], b[:3], b[3]
    return np.r_[aw * bv + bw * av + np.cross(av, bv), aw * bw - av @ bv]


def quat_exp(phi: np.ndarray) -> np.ndarray:
    """The (x, y, z, w) unit quaternion of the rotation vector phi (rad)."""
    angle = np.linalg.norm(phi)
    if angle == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.r_[np.sin(0.5 * angle) / angle * phi, np.cos(0.5 * angle)]


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """R (3, 3), body -> world, of an (x, y, z, w) unit quaternion."""
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class FreeBody:
    """One rigid body of mass (kg) and inertia (3, 3) (kg m^2, about the COM, body frame)."""

    def __init__(self, mass: float, inertia, scheme: str = "symplectic", dt: float = 0.01,
                 gravity=(0.0, 0.0, -9.81), angular_damping: float = 0.05):
        if scheme not in SCHEMES:
            raise ValueError(f"unknown scheme {scheme!r}")
        self.mass, self.inertia_inv = float(mass), np.linalg.inv(inertia)
        self.scheme, self.dt, self.angular_damping = scheme, float(dt), float(angular_damping)
        self.gravity = np.array(gravity, dtype=float)
        self.x, self.p, self.L = np.zeros(3), np.zeros(3), np.zeros(3)
        self.q = np.array([0.0, 0.0, 0.0, 1.0])
        self.warning: str | None = None
        self._force, self._torque = np.zeros(3), np.zeros(3)

    def apply_force_torque(self, force, torque) -> None:
        """A force (N, world, at the COM) and torque (N m, world) for the next step only."""
        self._force, self._torque = np.asarray(force, float), np.asarray(torque, float)

    def angular_velocity(self) -> np.ndarray:
        """w (rad/s, world) = R I_b^-1 R^T L."""
        R = rotation_matrix(self.q)
        return R @ self.inertia_inv @ R.T @ self.L

    def step(self) -> None:
        dt, M = self.dt, self.mass
        f = self._force + M * self.gravity
        if self.scheme == "explicit":  # every rate at the start of the step
            v, w = self.p / M, self.angular_velocity()
            q = self.q + dt * 0.5 * quat_multiply(np.r_[w, 0.0], self.q)
            self.x, self.q = self.x + dt * v, q / np.linalg.norm(q)
            self.p, self.L = self.p + dt * f, self.L + dt * self._torque
        else:  # symplectic: momenta first, then x and q with the new velocities
            self.p, self.L = self.p + dt * f, self.L + dt * self._torque
            self.x = self.x + dt * self.p / M
            q = quat_multiply(quat_exp(dt * self.angular_velocity()), self.q)
            self.q = q / np.linalg.norm(q)
        self.L = self.L * (1.0 - dt * self.angular_damping)
        self._force, self._torque = np.zeros(3), np.zeros(3)
        if not all(np.all(np.isfinite(a)) for a in (self.x, self.q, self.p, self.L)):
            self.warning = "non-finite state after a step"
