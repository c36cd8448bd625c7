"""Triangle-mesh files: Wavefront OBJ and STL (ASCII or binary) read into a TriangleMesh.

No dependency beyond numpy.  Units are the file's numbers taken as metres.

* OBJ: ``v x y z`` vertices and ``f`` faces (``i``, ``i/t``, ``i/t/n``, ``i//n``; negative indices
  count back from the latest vertex); a polygon with more than three corners is split into a fan
  of triangles (fine for the convex, planar polygons that exporters write).  Other statements
  (``vt``, ``vn``, ``o``, ``g``, ``s``, ``usemtl``, ``mtllib``, ``l``, ...) are ignored.
* STL: binary when the file's size is 84 + 50 n for the triangle count n in its header, else
  ASCII (``facet ... outer loop, vertex x y z (x3), endloop, endfacet``).  Facet normals are
  ignored: the winding of the vertices decides the orientation.

Vertices with bit-identical coordinates are merged (STL repeats each vertex in every triangle),
so edges shared by two triangles are recognised.  Format errors are a
:class:`~freebody.reference_impl.mesh.MeshError` naming the line.
"""
from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np

from ..reference_impl.mesh import MeshError, TriangleMesh, mass_properties, validate, weld
from ..results.io import FileRefused, read_regular_file
from ..tolerances import MESH_COORDINATE_MAX, MESH_FILE_MAX_BYTES

FORMATS = (".obj", ".stl")


def read_mesh(path: str | Path) -> TriangleMesh:
    """Read an OBJ or STL file (by its suffix, case-insensitive) into a welded TriangleMesh.

    Raises :class:`MeshError` for an unreadable file, an unknown suffix or a malformed file, and
    for anything but a regular file of at most ``MESH_FILE_MAX_BYTES`` (freebody.tolerances): a
    FIFO or /dev/zero is refused, never read.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in FORMATS:
        raise MeshError(f"unknown mesh format {p.suffix!r}; use one of {', '.join(FORMATS)}")
    try:
        data = read_regular_file(p, MESH_FILE_MAX_BYTES, str(p))
    except FileRefused as e:  # missing, unreadable, a FIFO or device, too large
        raise MeshError(e.reason) from None
    v, t = parse_obj(data) if suffix == ".obj" else parse_stl(data)
    if len(t) == 0:
        raise MeshError("has no triangles")
    return TriangleMesh(*weld(v, t))


def read_valid_mesh(path: str | Path) -> TriangleMesh:
    """:func:`read_mesh` then :func:`~freebody.reference_impl.mesh.validate`."""
    mesh = read_mesh(path)
    validate(mesh)
    return mesh


def _text(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise MeshError("not UTF-8 text") from None


def _floats(tokens: list[str], lineno: int, what: str) -> list[float]:
    try:
        xyz = [float(x) for x in tokens[:3]]
    except ValueError:
        raise MeshError(f"line {lineno}: {what} needs three numbers, got {' '.join(tokens)!r}") from None
    if len(xyz) != 3:
        raise MeshError(f"line {lineno}: {what} needs three numbers, got {' '.join(tokens)!r}")
    if not all(np.isfinite(xyz)):
        raise MeshError(f"line {lineno}: {what} has a non-finite coordinate")
    if max(abs(x) for x in xyz) > MESH_COORDINATE_MAX:
        raise MeshError(f"line {lineno}: {what} has a coordinate of magnitude {max(abs(x) for x in xyz):g} m; "
                        f"at most {MESH_COORDINATE_MAX:g} m (the mass-property integrals multiply five "
                        f"coordinates: larger ones overflow float64)")
    return xyz


def parse_obj(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """OBJ text -> (vertices (n, 3) m, triangles (m, 3) 0-based indices)."""
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    for lineno, line in enumerate(_text(data).splitlines(), start=1):
        tokens = line.split("#", 1)[0].split()
        if not tokens:
            continue
        if tokens[0] == "v":
            verts.append(_floats(tokens[1:], lineno, "vertex 'v'"))
        elif tokens[0] == "f":
            if len(tokens) < 4:
                raise MeshError(f"line {lineno}: a face needs at least three vertices, got {line.strip()!r}")
            idx = []
            for tok in tokens[1:]:
                head = tok.split("/", 1)[0]
                try:
                    i = int(head)
                except ValueError:
                    raise MeshError(f"line {lineno}: bad vertex index {tok!r}") from None
                i = i - 1 if i > 0 else len(verts) + i  # 1-based, or counted back from the latest
                if i < 0 or i >= len(verts) or head in ("0", "-0"):
                    raise MeshError(f"line {lineno}: vertex index {tok!r} does not refer to one of the "
                                    f"{len(verts)} vertices defined so far")
                idx.append(i)
            tris.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    return np.array(verts, dtype=float).reshape(-1, 3), np.array(tris, dtype=np.int64).reshape(-1, 3)


def parse_stl(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """STL (binary or ASCII) -> (vertices (3m, 3) m, triangles (m, 3)), one vertex per corner."""
    if len(data) >= 84:
        (n,) = struct.unpack_from("<I", data, 80)
        if len(data) == 84 + 50 * n:
            rec = np.frombuffer(data, dtype=np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)),
                                                      ("attr", "<u2")]), count=n, offset=84)
            v = rec["v"].astype(float).reshape(-1, 3)
            if not np.all(np.isfinite(v)):
                raise MeshError("binary STL has a non-finite coordinate")
            return v, np.arange(3 * n, dtype=np.int64).reshape(-1, 3)
    text = _text(data)
    if not text.lstrip().lower().startswith("solid"):
        raise MeshError("neither a binary STL (size does not match its triangle count) nor an ASCII "
                        "STL (does not start with 'solid')")
    verts: list[list[float]] = []
    in_facet, corners, facet_line = False, 0, 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0].lower()
        if key == "facet":
            if in_facet:
                raise MeshError(f"line {lineno}: 'facet' before the 'endfacet' of line {facet_line}'s facet")
            in_facet, corners, facet_line = True, 0, lineno
        elif key == "vertex":
            if not in_facet:
                raise MeshError(f"line {lineno}: 'vertex' outside a facet")
            verts.append(_floats(tokens[1:], lineno, "'vertex'"))
            corners += 1
        elif key == "endfacet":
            if not in_facet or corners != 3:
                raise MeshError(f"line {lineno}: a facet needs exactly three vertices, got {corners}")
            in_facet = False
    if in_facet:
        raise MeshError(f"line {facet_line}: facet without 'endfacet'")
    v = np.array(verts, dtype=float).reshape(-1, 3)
    return v, np.arange(len(v), dtype=np.int64).reshape(-1, 3)


def format_obj(mesh: TriangleMesh, comment: str = "") -> str:
    """OBJ text of ``mesh`` (1-based indices, coordinates with 17 significant digits: exact)."""
    lines = [f"# {c}" for c in comment.splitlines()]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.triangles.tolist()]
    return "\n".join(lines) + "\n"


def body_from_mesh(path: str | Path, *, density: float | None = None,
                   mass: float | None = None):
    """Read, validate and integrate a mesh file for a body of uniform density.

    Parameters
    ----------
    density : float, kg/m^3; or mass : float, kg (exactly one).

    Returns
    -------
    (mesh, PolyhedronProperties)
        The mesh in its file's frame and its exact properties (mass, COM in the file's frame,
        inertia about the COM).
    """
    if (density is None) == (mass is None):
        raise ValueError("give exactly one of density and mass")
    mesh = read_valid_mesh(path)
    props = mass_properties(mesh, 1.0)
    rho = density if density is not None else mass / props.volume
    props = mass_properties(mesh, rho)
    if mass is not None:  # exactly the mass asked for, not rho V rounded
        props = dataclasses.replace(props, mass=float(mass))
    return mesh, props
