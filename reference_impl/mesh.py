"""Closed triangle meshes: validation and exact mass properties of the solid they bound.

A :class:`TriangleMesh` is plain data (vertices and triangles); reading OBJ/STL files is the
harness's job (``freebody.input.meshfile``).  :func:`validate` checks that the mesh bounds a solid:

* every vertex is finite and every triangle has three distinct vertices and a non-zero area;
* it is **closed** and **consistently wound**: every edge is shared by exactly two triangles that
  traverse it in opposite directions (a hole leaves an edge with one triangle; a flipped triangle
  makes two neighbours traverse an edge the same way; three or more triangles on an edge is not a
  surface);
* its signed volume is non-zero, and positive: triangles are wound counter-clockwise seen from
  outside (outward normals).  A negative volume means the whole mesh is wound inward.

Self-intersections are not detected (their volume would be counted twice).  Nested shells are
allowed: an inner shell wound inward is a cavity.

:func:`mass_properties` integrates exactly over the polyhedron.  The volume integrals of 1, x and
x x^T become, by the divergence theorem (Mirtich 1996, "Fast and accurate computation of polyhedral
mass properties"), sums over the triangles; we evaluate each triangle's term in the equivalent
closed form of the tetrahedron it spans with a reference point (the signed-simplex decomposition):
exact for polyhedra up to floating-point rounding.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A triangle is degenerate when its area is below this fraction of the squared bounding-box
# diagonal: 1e-12 is far below any modelled feature and far above the rounding of a cross product.
DEGENERATE_AREA_RTOL = 1e-12
# A mesh has zero volume when |V| is below this fraction of the cubed bounding-box diagonal
# (a flat or doubled-over sheet: its signed volume is rounding noise, ~1e-16 of the scale).
ZERO_VOLUME_RTOL = 1e-12

# second moments of the reference tetrahedron (0, e1, e2, e3) per unit determinant:
# integral of x x^T over it = (1 + 1 1^T) / 120
_CANONICAL_SECOND_MOMENT = (np.eye(3) + np.ones((3, 3))) / 120.0


class MeshError(ValueError):
    """A mesh that does not bound a solid; the message is one line saying why and where."""


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle mesh.

    vertices : ndarray, shape (n, 3), float64, m, in the mesh's own frame.
    triangles : ndarray, shape (m, 3), int64, indices into ``vertices``; counter-clockwise seen
        from outside (outward normals by the right-hand rule).
    """

    vertices: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        v = np.array(self.vertices, dtype=float).reshape(-1, 3)
        t = np.array(self.triangles, dtype=np.int64).reshape(-1, 3)
        v.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", t)

    @property
    def corners(self) -> np.ndarray:
        """Triangle corners, shape (m, 3, 3): [triangle, corner, xyz], m."""
        return self.vertices[self.triangles]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box of the used vertices: (lo, hi), each shape (3,), m."""
        used = self.vertices[np.unique(self.triangles)]
        return used.min(axis=0), used.max(axis=0)


@dataclass(frozen=True)
class PolyhedronProperties:
    """Mass properties of a solid of uniform density.

    volume : float, m^3.  mass : float, kg.
    com : ndarray, shape (3,), m, the centre of mass in the mesh's frame.
    inertia : ndarray, shape (3, 3), kg m^2, about the COM, axes of the mesh's frame.
    """

    volume: float
    mass: float
    com: np.ndarray
    inertia: np.ndarray


def weld(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical coordinates (STL repeats each vertex per triangle).

    Parameters
    ----------
    vertices : ndarray, shape (n, 3), m.
    triangles : ndarray, shape (m, 3), indices into ``vertices``.

    Returns
    -------
    (vertices, triangles) with unique vertex rows (in order of first use) and re-indexed triangles.
    """
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    # +0.0 turns -0.0 into 0.0 so the two spellings of zero weld together
    _, first, inverse = np.unique(vertices + 0.0, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")  # keep the file's vertex order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first[order]], rank[inverse][triangles]


def _scale(mesh: TriangleMesh) -> float:
    lo, hi = mesh.bounds()
    return float(np.linalg.norm(hi - lo))


def signed_volume(mesh: TriangleMesh) -> float:
    """Signed volume, m^3: positive for outward (counter-clockwise from outside) winding."""
    c = mesh.corners - mesh.vertices[mesh.triangles].reshape(-1, 3).mean(axis=0)
    return float(np.einsum("ij,ij->i", c[:, 0], np.cross(c[:, 1], c[:, 2])).sum() / 6.0)


def validate(mesh: TriangleMesh) -> None:
    """Raise :class:`MeshError` unless ``mesh`` is a closed, consistently and outward wound surface
    of non-zero volume made of non-degenerate triangles (see the module docstring).

    Triangles are named by their 0-based index in ``mesh.triangles`` (for a file: in file order,
    polygons split into triangles), vertices and edges by their coordinates.
    """
    v, t = mesh.vertices, mesh.triangles
    if t.shape[0] < 4:
        raise MeshError(f"has {t.shape[0]} triangles; a closed surface needs at least 4")
    if t.min() < 0 or t.max() >= v.shape[0]:
        bad = int(np.argmax((t < 0).any(axis=1) | (t >= v.shape[0]).any(axis=1)))
        raise MeshError(f"triangle {bad} refers to a vertex that does not exist "
                        f"(indices {t[bad].tolist()}, {v.shape[0]} vertices)")
    if not np.all(np.isfinite(v[np.unique(t)])):
        raise MeshError("has a vertex with a non-finite coordinate")
    scale = _scale(mesh)
    if scale == 0:
        raise MeshError("all vertices coincide")

    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    if repeated.any():
        i = int(np.argmax(repeated))
        raise MeshError(f"degenerate triangle {i}: it uses the vertex {_point(v[_dup(t[i])])} twice")
    c = mesh.corners
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    thin = area <= DEGENERATE_AREA_RTOL * scale * scale
    if thin.any():
        i = int(np.argmax(thin))
        raise MeshError(f"degenerate triangle {i}: zero area ({area[i]:.3g} m^2; its corners "
                        f"{', '.join(_point(x) for x in c[i])} are collinear)")

    _check_edges(v, t)

    vol = signed_volume(mesh)
    if abs(vol) <= ZERO_VOLUME_RTOL * scale ** 3:
        raise MeshError(f"zero volume ({vol:.3g} m^3): the surface encloses no solid")
    if vol < 0:
        raise MeshError(f"negative volume ({vol:.6g} m^3): the triangles are wound inward "
                        "(clockwise seen from outside); reverse the vertex order of every face")


def _dup(tri) -> int:
    a, b, c = (int(x) for x in tri)
    return a if a in (b, c) else b


def _check_edges(v: np.ndarray, t: np.ndarray) -> None:
    """Every undirected edge used exactly twice, once in each direction."""
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])  # (3m, 2)
    owner = np.concatenate([np.arange(len(t))] * 3)
    key = np.sort(directed, axis=1)
    uniq, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if (counts == 1).any():
        n_open = int((counts == 1).sum())
        j = int(np.argmax(counts == 1))
        i = int(owner[np.argmax(inverse == j)])
        raise MeshError(f"not closed: the edge from {_edge(v, uniq[j])} belongs to triangle {i} only "
                        f"({n_open} such boundary edges; every edge must join two triangles)")
    if (counts > 2).any():
        j = int(np.argmax(counts > 2))
        tris = sorted(set(owner[inverse == j].tolist()))
        raise MeshError(f"not a surface: the edge from {_edge(v, uniq[j])} is shared by {counts[j]} "
                        f"triangles {tris} (every edge must join exactly two)")
    # counts are all 2: the two uses must run in opposite directions
    forward = directed[:, 0] < directed[:, 1]
    n_forward = np.bincount(inverse, weights=forward, minlength=len(uniq))
    same = n_forward != 1
    if same.any():
        j = int(np.argmax(same))
        tris = sorted(owner[inverse == j].tolist())
        raise MeshError(f"inconsistent winding: triangles {tris[0]} and {tris[1]} both run along the "
                        f"edge {_edge(v, directed[inverse == j][0], True)} in the same direction (one of "
                        "them is flipped)")


def _point(p) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in p) + ")"


def _edge(v: np.ndarray, e, directed: bool = False) -> str:
    return f"{_point(v[e[0]])}{' -> ' if directed else ' to '}{_point(v[e[1]])}"


def mass_properties(mesh: TriangleMesh, density: float = 1.0) -> PolyhedronProperties:
    """Exact mass properties of the solid bounded by ``mesh`` (validate it first).

    Parameters
    ----------
    mesh : TriangleMesh
        Closed, outward-wound (see :func:`validate`), m.
    density : float
        kg/m^3, uniform.

    Returns
    -------
    PolyhedronProperties
        Volume, mass, COM in the mesh frame, inertia about the COM in the mesh frame's axes.

    Notes
    -----
    Each triangle (a, b, c) with the reference point p spans a signed tetrahedron of determinant
    d = (a-p) . ((b-p) x (c-p)); the solid's integrals are the sums
    V = sum d/6,  int x dV = sum d/24 (a+b+c-3p),  int x x^T dV = sum d A C A^T  (A = [a-p b-p c-p],
    C = (1 + 1 1^T)/120).  The reference point is the vertex centroid, which keeps the terms small
    and the cancellation mild.  Then I = tr(P) 1 - P with P the second moment about the COM.
    """
    p = mesh.vertices[np.unique(mesh.triangles)].mean(axis=0)
    A = mesh.corners - p  # (m, 3 corners, 3 xyz): row k of A[i] is corner k
    det = np.einsum("ij,ij->i", A[:, 0], np.cross(A[:, 1], A[:, 2]))
    vol = det.sum() / 6.0
    if not vol > 0:
        raise MeshError(f"volume {vol:.6g} m^3 is not positive; validate the mesh first")
    first = (det[:, None] * A.sum(axis=1)).sum(axis=0) / 24.0  # int (x - p) dV
    second = np.einsum("i,ika,kl,ilb->ab", det, A, _CANONICAL_SECOND_MOMENT, A)  # int (x-p)(x-p)^T dV
    com_rel = first / vol
    P = second - vol * np.outer(com_rel, com_rel)  # about the COM
    P = 0.5 * (P + P.T)
    I = density * (np.trace(P) * np.eye(3) - P)
    return PolyhedronProperties(volume=float(vol), mass=float(density * vol), com=p + com_rel, inertia=I)
