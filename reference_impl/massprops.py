"""Mass properties of primitive shapes in closed form: mass and inertia about the COM, body frame.

Sizes in m, density in kg/m^3, mass in kg, inertia in kg m^2.  Every shape is a solid of uniform
density placed with its **centre of mass at the body origin**; the size conventions are

=========  ==========================  ===============================================================
shape      size                        placement in the body frame
=========  ==========================  ===============================================================
box        [x, y, z]                   full edge lengths along body x, y, z; centred
sphere     [radius]                    centred
cylinder   [radius, length]            axis along body z, total length ``length``; centred
capsule    [radius, length]            axis along body z; ``length`` is the straight (cylindrical)
                                       part, between the centres of the two hemispherical caps, so
                                       the total length is ``length + 2 radius``; centred
ellipsoid  [a, b, c]                   semi-axes along body x, y, z; centred
cone       [radius, height]            solid right circular cone, axis along body z, apex up.  Its COM
                                       lies on the axis at height/4 above the base, and that COM is
                                       the body origin: the base disc is at z = -height/4 and the apex
                                       at z = +3 height/4
=========  ==========================  ===============================================================

:mod:`primitives` holds the same shapes as geometry (inside tests, bounds, triangle meshes), in
the same placement, for the particle and voxel approximations and for tests.
"""
from __future__ import annotations

import numpy as np

SHAPES = {"box": 3, "sphere": 1, "cylinder": 2, "capsule": 2, "ellipsoid": 3, "cone": 2}
"""shape -> number of size entries (all in m, all > 0)."""

SIZE_DOC = {
    "box": "[x, y, z] full edge lengths",
    "sphere": "[radius]",
    "cylinder": "[radius, length], axis along z",
    "capsule": "[radius, length], axis along z, length of the straight part (total length + 2 radius)",
    "ellipsoid": "[a, b, c] semi-axes along x, y, z",
    "cone": "[radius, height], axis along z, apex up, origin at the COM (base at z = -height/4)",
}
"""shape -> its size convention in one line (for messages and ``--help``)."""


def checked_size(shape: str, size) -> np.ndarray:
    """``size`` as a flat float array with the entries ``shape`` takes (:data:`SHAPES`), or
    ValueError naming the shape's size convention."""
    if shape not in SHAPES:
        raise ValueError(f"unknown shape {shape!r}; known: {', '.join(SHAPES)}")
    s = np.asarray(size, dtype=float).reshape(-1)
    if s.shape != (SHAPES[shape],):
        raise ValueError(f"{shape} size must have {SHAPES[shape]} entries ({SIZE_DOC[shape]}), got {list(s)}")
    return s


def volume(shape: str, size) -> float:
    """Volume, m^3, of ``shape`` with ``size`` (m; see the module docstring for the conventions)."""
    s = checked_size(shape, size)
    if shape == "box":
        return float(s[0] * s[1] * s[2])
    if shape == "sphere":
        return float(4.0 / 3.0 * np.pi * s[0] ** 3)
    if shape == "cylinder":
        return float(np.pi * s[0] ** 2 * s[1])
    if shape == "capsule":
        r, h = s
        return float(np.pi * r * r * h + 4.0 / 3.0 * np.pi * r ** 3)
    if shape == "ellipsoid":
        return float(4.0 / 3.0 * np.pi * s[0] * s[1] * s[2])
    r, h = s  # cone
    return float(np.pi * r * r * h / 3.0)


def inertia(shape: str, size, mass: float) -> np.ndarray:
    """Inertia tensor about the COM of a solid of uniform density.

    Parameters
    ----------
    shape : str
        One of :data:`SHAPES`.
    size : sequence of float
        Size in m, see the module docstring.
    mass : float
        Total mass, kg.

    Returns
    -------
    ndarray, shape (3, 3)
        kg m^2, about the COM (the body origin), body frame; diagonal (the body axes are principal).
    """
    s = checked_size(shape, size)
    m = float(mass)
    if shape == "box":
        x, y, z = s
        return m / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
    if shape == "sphere":
        return 0.4 * m * s[0] ** 2 * np.eye(3)
    if shape == "cylinder":
        r, h = s
        side = m * (3 * r * r + h * h) / 12.0
        return np.diag([side, side, 0.5 * m * r * r])
    if shape == "capsule":
        r, h = s
        v_cyl, v_caps = np.pi * r * r * h, 4.0 / 3.0 * np.pi * r ** 3
        m_cyl = m * v_cyl / (v_cyl + v_caps)
        m_caps = m - m_cyl  # both hemispheres
        # each hemisphere: 2/5 m r^2 about its flat face's centre, COM 3r/8 from that face, whose
        # centre is h/2 from the capsule's centre -> parallel-axis shift of (h/2 + 3r/8)^2 - (3r/8)^2
        side = (m_cyl * (3 * r * r + h * h) / 12.0
                + m_caps * (0.4 * r * r + h * h / 4.0 + 3.0 * h * r / 8.0))
        axial = 0.5 * m_cyl * r * r + 0.4 * m_caps * r * r
        return np.diag([side, side, axial])
    if shape == "ellipsoid":
        a, b, c = s
        return m / 5.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    r, h = s  # cone, about its COM (h/4 above the base)
    side = m * (3.0 * r * r / 20.0 + 3.0 * h * h / 80.0)
    return np.diag([side, side, 0.3 * m * r * r])


def principal(I: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments and axes of an inertia tensor.

    Parameters
    ----------
    I : ndarray, shape (3, 3)
        kg m^2, symmetric, in some frame F.

    Returns
    -------
    moments : ndarray, shape (3,)
        kg m^2, ascending.
    axes : ndarray, shape (3, 3)
        Columns are the unit principal axes in frame F, right-handed (det +1); each column's sign
        is fixed so that its largest-magnitude component is positive (deterministic output).
    """
    moments, axes = np.linalg.eigh(0.5 * (I + I.T))
    for j in range(3):
        k = int(np.argmax(np.abs(axes[:, j])))
        if axes[k, j] < 0:
            axes[:, j] = -axes[:, j]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes
