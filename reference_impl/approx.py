"""Approximate mass properties, as in the lecture: particles and voxels, each with a resolution.

Both tile the solid's bounding box exactly with a grid of equal box-shaped cells: N cells (the
**resolution**) along the longest side L of the bounding box and ``ceil(N side / L)`` along each
other side, so the cells are cubes of side L / N or slightly flattened ones.

* **particles** -- one point mass per cell at a random position inside the cell (a stratified
  sample drawn from ``np.random.default_rng(seed)``: deterministic for a given seed), kept when
  the point is inside the solid.  I = sum m_i (|r_i|^2 1 - r_i r_i^T) about their COM: point masses
  carry no inertia of their own.  "Simple but inaccurate."
* **voxels** -- every cell whose centre is inside the solid is a solid cube of mass m_i: the
  point-mass sum at the centres plus each cell's own inertia m_i (hy^2 + hz^2) / 12, ... about its
  centre.

The inside test is analytic for primitives (:mod:`primitives`) and for meshes the winding number
of a ray cast along +z (:func:`mesh_winding`), made robust by symbolic perturbation of the ray so a
ray through an edge or a vertex is counted exactly once.

Each cell (particle or voxel) weighs ``density * hx hy hz``; when a total mass is given instead, it is
shared equally among the cells found inside.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import primitives
from .mesh import TriangleMesh

DEFAULT_SEED = 0  # the particle sample's seed when none is given: results are reproducible
_CHUNK_ELEMENTS = 2_000_000  # (columns x triangles) per vectorised block: ~100 MB of temporaries
# N side / longest that is an integer up to round-off (a cube's sides) is not rounded up past it
_CEIL_SLACK = 1e-9


@dataclass(frozen=True)
class Solid:
    """A solid to sample: its bounding box and an inside test.

    lo, hi : ndarray, shape (3,), m, bounding box in the body (or mesh) frame.
    contains : callable, points (n, 3) m -> bool (n,), inside the solid.
    contains_grid : callable, (xs (nx,), ys (ny,), zs (nz,)) m -> bool (nx, ny, nz), the same test
        on the grid xs x ys x zs (sorted ascending), possibly faster.
    """

    lo: np.ndarray
    hi: np.ndarray
    contains: Callable[[np.ndarray], np.ndarray]
    contains_grid: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ApproxProperties:
    """Mass properties from samples.

    method : "particles" or "voxels".  resolution : N, cells along the longest bounding-box side.
    cell : ndarray, shape (3,), m, the cell's edges (hx, hy, hz).  n_cells : cells in the grid.
    n_inside : cells counted inside.  mass : float, kg.  volume : float, m^3, n_inside hx hy hz.
    com : ndarray, shape (3,), m, in the solid's frame (nan when nothing is inside).
    inertia : ndarray, shape (3, 3), kg m^2, about ``com``, axes of the solid's frame.
    """

    method: str
    resolution: int
    cell: np.ndarray
    n_cells: int
    n_inside: int
    volume: float
    mass: float
    com: np.ndarray
    inertia: np.ndarray


def solid_from_shape(shape: str, size) -> Solid:
    """A primitive of :mod:`massprops` (COM at the origin), with its analytic inside test."""
    lo, hi = primitives.bounds(shape, size)

    def contains(points):
        return primitives.contains(shape, size, points)

    def contains_grid(xs, ys, zs):
        X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
        pts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
        return contains(pts).reshape(X.shape)

    return Solid(lo, hi, contains, contains_grid)


def solid_from_mesh(mesh: TriangleMesh) -> Solid:
    """A closed, outward-wound mesh (validated), inside where its winding number is non-zero."""
    lo, hi = mesh.bounds()

    def contains(points):
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        return mesh_winding(mesh, p) != 0

    def contains_grid(xs, ys, zs):
        return mesh_winding_grid(mesh, xs, ys, zs) != 0

    return Solid(lo, hi, contains, contains_grid)


# --- the ray-crossing winding number ------------------------------------------------------------

def _side(ux, uy, vx, vy, px, py) -> np.ndarray:
    """Sign of orient(u, v, p) with p perturbed to (px + e, py + e^2), e -> 0+.

    Written relative to p so that swapping u and v negates it exactly in floating point: the two
    triangles sharing an edge then always agree on which side of it the ray passes.
    """
    o = (ux - px) * (vy - py) - (uy - py) * (vx - px)
    tie = np.where(uy != vy, np.sign(uy - vy), np.sign(vx - ux))
    return np.where(o != 0, np.sign(o), tie), o


def _crossings(mesh: TriangleMesh, qx: np.ndarray, qy: np.ndarray):
    """Where the vertical lines through (qx[k], qy[k]) cross the mesh.

    Returns (k, z, sign): arrays of the line index, the crossing height (m) and the sign of the
    triangle's normal's z component (+1 upward-facing), one entry per crossing.
    """
    c = mesh.corners  # (F, 3, 3)
    ax, ay, az = c[:, 0, 0], c[:, 0, 1], c[:, 0, 2]
    bx, by, bz = c[:, 1, 0], c[:, 1, 1], c[:, 1, 2]
    cx, cy, cz = c[:, 2, 0], c[:, 2, 1], c[:, 2, 2]
    n_tri = len(c)
    block = max(1, _CHUNK_ELEMENTS // max(n_tri, 1))
    ks, zs, ss = [], [], []
    for start in range(0, len(qx), block):
        px = qx[start:start + block, None]
        py = qy[start:start + block, None]
        s_ab, o_ab = _side(ax, ay, bx, by, px, py)
        s_bc, o_bc = _side(bx, by, cx, cy, px, py)
        s_ca, o_ca = _side(cx, cy, ax, ay, px, py)
        hit = (s_ab == s_bc) & (s_bc == s_ca) & (s_ab != 0)
        k, f = np.nonzero(hit)
        if k.size == 0:
            continue
        w_a, w_b, w_c = o_bc[k, f], o_ca[k, f], o_ab[k, f]  # barycentric weights (unnormalised)
        z = (w_a * az[f] + w_b * bz[f] + w_c * cz[f]) / (w_a + w_b + w_c)
        ks.append(k + start)
        zs.append(z)
        ss.append(s_ab[k, f])
    if not ks:
        return np.zeros(0, int), np.zeros(0), np.zeros(0)
    return np.concatenate(ks), np.concatenate(zs), np.concatenate(ss)


def mesh_winding(mesh: TriangleMesh, points: np.ndarray) -> np.ndarray:
    """Winding number of a closed mesh around each point.

    Parameters
    ----------
    points : ndarray, shape (n, 3), m, mesh frame.

    Returns
    -------
    ndarray, shape (n,), int: 1 inside an outward-wound solid, 0 outside (points on the surface
    may go either way).
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    k, z, s = _crossings(mesh, p[:, 0], p[:, 1])
    above = z > p[k, 2]  # the ray goes up: an upward-facing crossing above p is an exit
    return np.bincount(k[above], weights=s[above], minlength=len(p)).round().astype(int)


def mesh_winding_grid(mesh: TriangleMesh, xs, ys, zs) -> np.ndarray:
    """:func:`mesh_winding` on the grid xs x ys x zs (each ascending, m): int (nx, ny, nz).

    One ray per (x, y) column serves every z of the column.
    """
    xs, ys, zs = (np.asarray(a, dtype=float) for a in (xs, ys, zs))
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    k, z, s = _crossings(mesh, X.ravel(), Y.ravel())
    n_col, nz = X.size, len(zs)
    # a crossing at height z counts for every grid z below it: a difference array along z
    below = np.searchsorted(zs, z, side="left")
    diff = np.zeros((n_col, nz + 1))
    np.add.at(diff, (k, np.zeros_like(k)), s)
    np.add.at(diff, (k, below), -s)
    return np.cumsum(diff, axis=1)[:, :nz].round().astype(int).reshape(len(xs), len(ys), nz)


# --- the approximations -------------------------------------------------------------------------

def grid_counts(lo, hi, resolution: int) -> tuple[int, int, int]:
    """Cells along x, y, z of the grid at ``resolution`` tiling the box ``lo``..``hi`` (each (3,),
    m): N = ``resolution`` along the longest side, ceil(N side / longest) (at least 1) along the
    others.  The particle and voxel approximations use it, and so does
    :func:`freebody.run.budget.grid_cells` to estimate their cost before they start.  ValueError
    when the box has no extent."""
    ext = [float(h) - float(l) for l, h in zip(lo, hi)]
    longest = max(ext)
    if not longest > 0:
        raise ValueError(f"the box {list(lo)}..{list(hi)} has no extent")
    return tuple(max(1, math.ceil(int(resolution) * e / longest - _CEIL_SLACK)) for e in ext)


def _grid(solid: Solid, resolution: int):
    """Cell edges h (3,), counts (3,) and the grid's lower corner (3,) tiling the bounding box."""
    if isinstance(resolution, bool) or int(resolution) != resolution or resolution < 1:
        raise ValueError(f"resolution must be an integer >= 1, got {resolution!r}")
    counts = np.array(grid_counts(solid.lo, solid.hi, resolution))
    return (solid.hi - solid.lo) / counts, counts, solid.lo.copy()


def _summarise(method, resolution, h, n_cells, points, cell_mass, own_inertia):
    """Mass properties of equal masses at ``points`` (n, 3), each with ``own_inertia`` (3, 3) per kg."""
    n = len(points)
    if n == 0:
        nan = np.full(3, np.nan)
        return ApproxProperties(method, int(resolution), h, int(n_cells), 0, 0.0, 0.0, nan,
                                np.full((3, 3), np.nan))
    mass = cell_mass * n
    com = points.mean(axis=0)
    d = points - com
    P = cell_mass * d.T @ d
    I = np.trace(P) * np.eye(3) - P + mass * own_inertia
    return ApproxProperties(method, int(resolution), h, int(n_cells), n, float(n * np.prod(h)),
                            float(mass), com, 0.5 * (I + I.T))


def _cell_mass(h: np.ndarray, n_inside: int, density: float | None, mass: float | None) -> float:
    if (density is None) == (mass is None):
        raise ValueError("give exactly one of density and mass")
    if density is not None:
        return float(density) * float(np.prod(h))
    return float(mass) / n_inside if n_inside else 0.0


def particles(solid: Solid, resolution: int, *, density: float | None = None, mass: float | None = None,
              seed: int = DEFAULT_SEED) -> ApproxProperties:
    """Point masses at one seeded random point per grid cell, kept when inside the solid.

    Parameters
    ----------
    solid : Solid
    resolution : int
        N, cells along the longest bounding-box side.
    density : float, kg/m^3 (each particle weighs density hx hy hz); or
    mass : float, kg, shared equally among the particles inside.
    seed : int
        Seed of ``np.random.default_rng``: the same seed gives the same sample.
    """
    h, counts, start = _grid(solid, resolution)
    idx = np.indices(counts).reshape(3, -1).T
    u = np.random.default_rng(seed).random(idx.shape)
    pts = start + (idx + u) * h
    inside = pts[solid.contains(pts)]
    m = _cell_mass(h, len(inside), density, mass)
    return _summarise("particles", resolution, h, int(np.prod(counts)), inside, m, np.zeros((3, 3)))


def voxels(solid: Solid, resolution: int, *, density: float | None = None,
           mass: float | None = None) -> ApproxProperties:
    """Solid cells (boxes) of the grid, kept when their centre is inside the solid.

    Parameters as :func:`particles` (no seed: the grid is fixed).
    """
    h, counts, start = _grid(solid, resolution)
    axes = [start[a] + (np.arange(counts[a]) + 0.5) * h[a] for a in range(3)]
    inside = solid.contains_grid(*axes)
    ii, jj, kk = np.nonzero(inside)
    centres = np.column_stack([axes[0][ii], axes[1][jj], axes[2][kk]])
    m = _cell_mass(h, len(centres), density, mass)
    hx2, hy2, hz2 = h * h
    own = np.diag([hy2 + hz2, hx2 + hz2, hx2 + hy2]) / 12.0  # a box cell about its centre, per kg
    return _summarise("voxels", resolution, h, int(np.prod(counts)), centres, m, own)


METHODS = {"particles": particles, "voxels": voxels}
