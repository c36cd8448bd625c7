"""The primitive shapes of :mod:`massprops` as geometry: bounds, inside tests, triangle meshes.

Same sizes and placement as :mod:`massprops` (COM at the origin; the cone's base at z = -h/4).
"""
from __future__ import annotations

import numpy as np

from .massprops import SHAPES, checked_size
from .mesh import TriangleMesh


def bounds(shape: str, size) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box of the shape: (lo, hi), each shape (3,), m, body frame."""
    s = checked_size(shape, size)
    if shape == "box":
        half = s / 2.0
    elif shape == "sphere":
        half = np.full(3, s[0])
    elif shape == "cylinder":
        half = np.array([s[0], s[0], s[1] / 2.0])
    elif shape == "capsule":
        half = np.array([s[0], s[0], s[1] / 2.0 + s[0]])
    elif shape == "ellipsoid":
        half = s.copy()
    else:  # cone
        r, h = s
        return np.array([-r, -r, -h / 4.0]), np.array([r, r, 3.0 * h / 4.0])
    return -half, half


def contains(shape: str, size, points: np.ndarray) -> np.ndarray:
    """Analytic inside test.

    Parameters
    ----------
    points : ndarray, shape (n, 3), m, body frame.

    Returns
    -------
    ndarray, shape (n,), bool: the point lies in the closed solid.
    """
    s = checked_size(shape, size)
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rho2 = x * x + y * y
    if shape == "box":
        return np.all(np.abs(p) <= s / 2.0, axis=1)
    if shape == "sphere":
        return rho2 + z * z <= s[0] ** 2
    if shape == "cylinder":
        return (rho2 <= s[0] ** 2) & (np.abs(z) <= s[1] / 2.0)
    if shape == "capsule":
        r, h = s
        dz = np.maximum(np.abs(z) - h / 2.0, 0.0)  # distance along the axis beyond the straight part
        return rho2 + dz * dz <= r * r
    if shape == "ellipsoid":
        return np.sum((p / s) ** 2, axis=1) <= 1.0
    r, h = s  # cone: base at -h/4, apex at 3h/4
    top = 3.0 * h / 4.0
    return (z >= -h / 4.0) & (z <= top) & (np.sqrt(rho2) <= r * (top - z) / h)


def _revolve(profile: np.ndarray, n_around: int) -> TriangleMesh:
    """Surface of revolution about z.

    profile : ndarray, shape (k, 2), (radius, z) from the bottom pole (radius 0) up to the top pole
        (radius 0), every point between with radius > 0.
    """
    phi = 2.0 * np.pi * np.arange(n_around) / n_around
    rings = profile[1:-1]
    verts = [[0.0, 0.0, profile[0, 1]]]
    for r, z in rings:
        verts.extend(np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(n_around, z)]))
    verts.append([0.0, 0.0, profile[-1, 1]])
    top = len(verts) - 1
    tris = []
    i = np.arange(n_around)
    j = (i + 1) % n_around
    ring = lambda k: 1 + k * n_around  # noqa: E731  (first vertex index of ring k)
    tris.append(np.column_stack([np.zeros(n_around, int), ring(0) + j, ring(0) + i]))
    for k in range(len(rings) - 1):
        a, b = ring(k) + i, ring(k) + j
        c, d = ring(k + 1) + j, ring(k + 1) + i
        tris.append(np.column_stack([a, b, c]))
        tris.append(np.column_stack([a, c, d]))
    last = ring(len(rings) - 1)
    tris.append(np.column_stack([np.full(n_around, top), last + i, last + j]))
    return TriangleMesh(np.array(verts), np.concatenate(tris))


def _arc(r: float, z0: float, theta0: float, theta1: float, n: int) -> np.ndarray:
    """Points (radius, z) on a circle of radius r centred at (0, z0), theta from the -z axis."""
    th = np.linspace(theta0, theta1, n + 1)
    return np.column_stack([r * np.sin(th), z0 - r * np.cos(th)])


def tessellate(shape: str, size, n: int) -> TriangleMesh:
    """A closed, outward-wound triangle mesh inscribed in the shape.

    Parameters
    ----------
    n : int
        Resolution: segments around the axis (``n`` >= 3); curved profiles get about n/2 segments
        from pole to pole.  A box is exact at any ``n`` (12 triangles).

    Returns
    -------
    TriangleMesh in the body frame of :mod:`massprops` (m); its volume converges to the shape's
    as O(1/n^2).
    """
    s = checked_size(shape, size)
    if n < 3:
        raise ValueError(f"tessellation needs n >= 3 segments, got {n}")
    if shape == "box":
        corners = np.array([[i, j, k] for i in (-0.5, 0.5) for j in (-0.5, 0.5) for k in (-0.5, 0.5)]) * s
        quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
        return TriangleMesh(corners, np.array(tris))
    half = max(2, n // 2)
    if shape in ("sphere", "ellipsoid"):
        profile = _arc(1.0, 0.0, 0.0, np.pi, half)
        profile[0, 0] = profile[-1, 0] = 0.0
        m = _revolve(profile, n)
        scale = np.full(3, s[0]) if shape == "sphere" else s
        return TriangleMesh(m.vertices * scale, m.triangles)
    if shape == "cylinder":
        r, h = s
        profile = np.array([[0.0, -h / 2], [r, -h / 2], [r, h / 2], [0.0, h / 2]])
    elif shape == "capsule":
        r, h = s
        q = max(1, half // 2)
        lower = _arc(r, -h / 2, 0.0, np.pi / 2, q)
        upper = _arc(r, h / 2, np.pi / 2, np.pi, q)
        profile = np.vstack([lower, upper])
        profile[0, 0] = profile[-1, 0] = 0.0
    else:  # cone
        r, h = s
        profile = np.array([[0.0, -h / 4], [r, -h / 4], [0.0, 3 * h / 4]])
    return _revolve(profile, n)


__all__ = ["SHAPES", "bounds", "contains", "tessellate"]
