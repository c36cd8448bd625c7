"""Mass properties of primitive shapes in closed form: mass and inertia about the COM, body frame.

Sizes in m, density in kg/m^3, mass in kg, inertia in kg m^2.  Body axes: a box's edges lie along
x, y, z; a cylinder's axis is body z.
"""
from __future__ import annotations

import numpy as np

SHAPES = {"box": 3, "sphere": 1, "cylinder": 2}  # shape -> number of size entries


def volume(shape: str, size) -> float:
    """Volume, m^3.  box size = [x, y, z] full edges; sphere [radius]; cylinder [radius, length]."""
    if shape == "box":
        return float(size[0] * size[1] * size[2])
    if shape == "sphere":
        return float(4.0 / 3.0 * np.pi * size[0] ** 3)
    if shape == "cylinder":
        return float(np.pi * size[0] ** 2 * size[1])
    raise ValueError(f"unknown shape {shape!r}")


def inertia(shape: str, size, mass: float) -> np.ndarray:
    """Inertia tensor (3, 3) about the COM, body frame, kg m^2, of a solid of uniform density."""
    if shape == "box":
        x, y, z = size
        return mass / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
    if shape == "sphere":
        return 0.4 * mass * size[0] ** 2 * np.eye(3)
    if shape == "cylinder":
        r, h = size
        side = mass * (3 * r * r + h * h) / 12.0
        return np.diag([side, side, 0.5 * mass * r * r])
    raise ValueError(f"unknown shape {shape!r}")
