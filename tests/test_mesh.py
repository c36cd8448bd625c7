"""Mesh files: readers, validation (bad meshes are exit 2 with one line), the shipped meshes against
trimesh, the body.mesh case key, the t_handle case and ``freebody inertia``."""
from __future__ import annotations

import struct
import subprocess
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from freebody.input.casefile import load_case
from freebody.cli import main
from freebody.errors import InputError
from freebody.input.meshfile import body_from_mesh, format_obj, read_mesh
from freebody.reference_impl import primitives
from freebody.reference_impl.mesh import MeshError, TriangleMesh, mass_properties, validate

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "cases" / "meshes"
SHIPPED = ["t_handle", "wing_nut", "l_shape"]

TRIMESH_RTOL = 1e-10  # the bar: an independent implementation agrees to 1e-10 of |I|
READER_RTOL = 1e-6  # binary STL stores float32: coordinates round to ~6e-8 relative
EXACT_RTOL = 1e-12  # same mesh, same integration: only rounding differs


def rel(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b))


def box_mesh(size=(0.3, 0.5, 0.7)) -> TriangleMesh:
    return primitives.tessellate("box", list(size), 4)


def write_ascii_stl(path: Path, mesh: TriangleMesh) -> None:
    lines = ["solid test"]
    for tri in mesh.corners:
        lines += ["  facet normal 0 0 0", "    outer loop"]
        lines += [f"      vertex {x!r} {y!r} {z!r}" for x, y, z in tri.tolist()]
        lines += ["    endloop", "  endfacet"]
    path.write_text("\n".join(lines + ["endsolid test"]) + "\n")


def write_binary_stl(path: Path, mesh: TriangleMesh) -> None:
    out = bytearray(b"solid but binary".ljust(80, b" ")) + struct.pack("<I", len(mesh.triangles))
    for tri in mesh.corners:
        out += struct.pack("<3f", 0, 0, 0) + struct.pack("<9f", *tri.ravel()) + b"\0\0"
    path.write_bytes(bytes(out))


# --- readers ------------------------------------------------------------------------------------

def test_obj_and_stl_readers_agree(tmp_path):
    mesh = box_mesh()
    ref = mass_properties(mesh, 1000.0)
    (tmp_path / "b.obj").write_text(format_obj(mesh, "box"))
    write_ascii_stl(tmp_path / "a.stl", mesh)
    write_binary_stl(tmp_path / "b.stl", mesh)
    for name, rtol in (("b.obj", EXACT_RTOL), ("a.stl", EXACT_RTOL), ("b.stl", READER_RTOL)):
        m = read_mesh(tmp_path / name)
        validate(m)
        assert len(np.unique(m.triangles)) == 8, name  # STL corners welded back into 8 vertices
        p = mass_properties(m, 1000.0)
        assert p.mass == pytest.approx(ref.mass, rel=rtol), name
        assert rel(p.inertia, ref.inertia) < rtol, name


def test_obj_polygons_slashes_and_negative_indices(tmp_path):
    text = """# a unit cube written with quads, v/vt/vn references and negative indices
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
vt 0 0
vn 0 0 1
f 1/1/1 4/1/1 3/1/1 2/1/1
f 5//1 6//1 7//1 8//1
f 1 2 6 5
f 2 3 7 6
f -5 -1 -2 -6
f 4 1 5 8
"""
    (tmp_path / "cube.obj").write_text(text)
    m = read_mesh(tmp_path / "cube.obj")
    validate(m)
    p = mass_properties(m, 1.0)
    assert p.volume == pytest.approx(1.0, rel=EXACT_RTOL)
    assert np.allclose(p.com, 0.5)
    assert rel(p.inertia, np.eye(3) / 6) < EXACT_RTOL


@pytest.mark.parametrize("text, words", [
    ("v 0 0 0\nv 1 0 0\nf 1 2 3\n", ["line 3", "vertex index"]),
    ("v 0 0 zero\n", ["line 1", "three numbers"]),
    ("v 0 0 0\nf 1 1\n", ["line 2", "at least three"]),
    ("# nothing\n", ["no triangles"]),
])
def test_malformed_obj(tmp_path, text, words):
    (tmp_path / "bad.obj").write_text(text)
    with pytest.raises(MeshError) as e:
        read_mesh(tmp_path / "bad.obj")
    for w in words:
        assert w in str(e.value)


def test_unknown_suffix_and_missing_file(tmp_path):
    (tmp_path / "m.ply").write_text("ply\n")
    with pytest.raises(MeshError, match="unknown mesh format"):
        read_mesh(tmp_path / "m.ply")
    with pytest.raises(MeshError, match="no such file"):
        read_mesh(tmp_path / "missing.obj")


# --- validation ---------------------------------------------------------------------------------

def _bad_meshes() -> dict[str, tuple[TriangleMesh, list[str]]]:
    box = box_mesh()
    v, t = box.vertices, box.triangles
    flipped = t.copy()
    flipped[3] = flipped[3, ::-1]
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    sheet = np.array([[0, 1, 2], [0, 2, 3], [3, 1, 0], [3, 2, 1]])  # both sides of a square
    sliver = np.vstack([v, [[2, 0, 0], [3, 0, 0], [4, 0, 0]]])
    tet = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    two_tets = np.vstack([tet, np.array([[0, 1, 4], [0, 5, 1], [1, 5, 4], [0, 4, 5]])])
    tv = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1]], float)
    return {
        "open": (TriangleMesh(v, t[:-1]), ["not closed", "boundary edge"]),
        "flipped_face": (TriangleMesh(v, flipped), ["inconsistent winding", "flipped"]),
        "zero_volume": (TriangleMesh(square, sheet), ["zero volume"]),
        "degenerate_triangle": (TriangleMesh(sliver, np.vstack([t, [[8, 9, 10]]])),
                                ["degenerate triangle 12", "collinear"]),
        "repeated_vertex": (TriangleMesh(v, np.vstack([t, [[0, 0, 1]]])), ["degenerate triangle 12", "twice"]),
        "inward": (TriangleMesh(v, t[:, ::-1]), ["negative volume", "inward"]),
        "non_manifold": (TriangleMesh(tv, two_tets), ["not a surface", "shared by 4"]),
    }


BAD = _bad_meshes()


@pytest.mark.parametrize("name", list(BAD))
def test_validation_rejects(name):
    mesh, words = BAD[name]
    with pytest.raises(MeshError) as e:
        validate(mesh)
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


@pytest.mark.parametrize("name", ["open", "flipped_face", "zero_volume", "degenerate_triangle", "inward"])
def test_cli_bad_mesh_is_exit_2_one_line(tmp_path, capsys, name):
    mesh, words = BAD[name]
    path = tmp_path / f"{name}.obj"
    path.write_text(format_obj(mesh))
    assert main(["inertia", str(path), "--density", "1000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("freebody: error: ") and str(path) in err
    for w in words:
        assert w in err


# --- the shipped meshes -------------------------------------------------------------------------

@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_meshes_agree_with_trimesh(name):
    trimesh = pytest.importorskip("trimesh", reason="trimesh is a test dependency: pip install 'freebody[test]'")
    path = MESHES / f"{name}.obj"
    _, props = body_from_mesh(path, density=1000.0)
    tm = trimesh.load(path, process=False, force="mesh")
    tm.density = 1000.0
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.mass == pytest.approx(props.mass, rel=TRIMESH_RTOL)
    assert np.linalg.norm(tm.center_mass - props.com) < TRIMESH_RTOL * np.linalg.norm(tm.extents)
    assert rel(tm.moment_inertia, props.inertia) < TRIMESH_RTOL


def test_shipped_meshes_are_what_the_script_writes():
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_meshes.py"), "--check"],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_meshes_ship_as_package_data():
    root = resources.files("freebody.cases")
    for name in SHIPPED:
        assert (root / "meshes" / f"{name}.obj").is_file()


# --- cases --------------------------------------------------------------------------------------

CASE = """name = "mesh_case"
description = "A body from a mesh."
duration = 0.02
dt = [0.01]
[body]
mesh = "{mesh}"
{amount}
[initial]
position = [1.0, 2.0, 3.0]
orientation = [1.0, 0.0, 0.0, 0.0]
linear_velocity = [0.0, 0.0, 0.0]
angular_velocity = [0.0, 0.0, 1.0]
"""


def test_case_mesh_relative_to_the_case_file(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "l.obj").write_text((MESHES / "l_shape.obj").read_text())
    case = tmp_path / "c.toml"
    case.write_text(CASE.format(mesh="parts/l.obj", amount="mass = 2.5"))
    pb = load_case(str(case))
    _, props = body_from_mesh(MESHES / "l_shape.obj", mass=2.5)
    assert pb.body.mass == 2.5
    assert rel(pb.body.I_body, props.inertia) < EXACT_RTOL
    assert abs(pb.body.I_body[0, 1]) > 0.1 * np.abs(pb.body.I_body).max()  # the L's full tensor
    assert np.array_equal(pb.initial.position, [1.0, 2.0, 3.0])  # the COM's position, as given


@pytest.mark.parametrize("mesh, amount, words", [
    ("missing.obj", "density = 1000.0", ["body.mesh", "missing.obj", "no such file"]),
    ("open.obj", "density = 1000.0", ["body.mesh", "open.obj", "not closed"]),
    ("box.obj", "", ["body.mass", "mass and density"]),
    ("box.obj", "density = 1000.0\nshape = \"box\"", ["body.shape", "exactly one of inertia, shape and mesh"]),
])
def test_case_mesh_errors(tmp_path, mesh, amount, words):
    (tmp_path / "open.obj").write_text(format_obj(BAD["open"][0]))
    (tmp_path / "box.obj").write_text(format_obj(box_mesh()))
    case = tmp_path / "c.toml"
    case.write_text(CASE.format(mesh=mesh, amount=amount))
    with pytest.raises(InputError) as e:
        load_case(str(case))
    msg = str(e.value)
    assert str(case) in msg and "\n" not in msg
    for w in words:
        assert w in msg


def test_t_handle_case_runs_on_the_reference_engine():
    from freebody import run_case

    pb = load_case("t_handle")
    _, props = body_from_mesh(MESHES / "t_handle.obj", density=7850.0)
    assert pb.body.mass == pytest.approx(props.mass, rel=EXACT_RTOL)
    moments = np.linalg.eigvalsh(pb.body.I_body)
    assert moments[0] < pb.body.I_body[2, 2] < moments[2]  # spun about z: the intermediate axis
    out = run_case("t_handle", engine="reference", integrator="rk4", dt=0.01, duration=0.2)
    assert out.result.status == "ok"
    assert out.result.metrics["orientation_error_max_rad"] < 1e-6  # RK4 at 0.01 s over 0.2 s


# --- freebody inertia ---------------------------------------------------------------------------

def test_inertia_cli_box_closed_form(capsys):
    assert main(["inertia", "box", "--size", "1", "2", "3", "--mass", "12"]) == 0
    out = capsys.readouterr().out
    assert "mass               12 kg" in out
    assert "[ 13,  0,  0]" in out and "[ 0,  10,  0]" in out and "[ 0,  0,  5]" in out


def test_inertia_cli_compare_writes_table_and_plot(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    assert main(["inertia", str(MESHES / "t_handle.obj"), "--density", "1000", "--compare",
                 "--resolution", "8", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "I_b err" in out and "particles" in out and "voxels" in out
    png = tmp_path / "inertia_t_handle.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "inertia_t_handle.json").is_file()


@pytest.mark.parametrize("argv, words", [
    (["inertia", "torus", "--mass", "1"], ["torus", "not a shape"]),
    (["inertia", "box", "--size", "1", "2", "--mass", "1"], ["--size", "3 number"]),
    (["inertia", "sphere", "--mass", "1"], ["--size", "missing"]),
])
def test_inertia_cli_bad_input(capsys, argv, words):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    for w in words:
        assert w in err


def test_inertia_cli_approximation(capsys):
    assert main(["inertia", "cone", "--size", "0.4", "1.2", "--density", "1000", "--method", "voxels",
                 "--resolution", "16"]) == 0
    out = capsys.readouterr().out
    assert "voxels, resolution 16" in out and "error vs exact" in out


@pytest.mark.parametrize("method", ["particles", "voxels"])
def test_approximation_errors_shrink_on_the_t_handle(method):
    """The mesh inside test (ray-cast winding number) drives both; from N = 8 to 64 the I_b error
    falls at least 5x (measured: particles 110x, voxels 24x)."""
    from freebody.reference_impl import approx

    mesh, props = body_from_mesh(MESHES / "t_handle.obj", density=1000.0)
    solid = approx.solid_from_mesh(mesh)
    errs = [rel(approx.METHODS[method](solid, n, density=1000.0).inertia, props.inertia) for n in (8, 64)]
    assert errs[1] < errs[0] / 5.0
