"""Closed forms of the primitives against exact polyhedral integration of their meshes, the
particle and voxel approximations' convergence, and the ray-cast inside test's robustness."""
from __future__ import annotations

import numpy as np
import pytest

from freebody.reference_impl import approx, massprops, primitives
from freebody.reference_impl.mesh import mass_properties, validate
from freebody.reference_impl.rotations import matrix_from_quat

SIZES = {"box": [0.3, 0.5, 0.7], "sphere": [0.4], "cylinder": [0.3, 1.1], "capsule": [0.2, 0.6],
         "ellipsoid": [0.3, 0.5, 0.7], "cone": [0.4, 1.2]}

EXACT_RTOL = 1e-12  # polyhedral integration of a polyhedron is exact: only float64 rounding remains
# A curved shape's inscribed mesh converges as 1/n^2; Richardson extrapolation of n = 128 and 256
# removes that term, leaving ~3e-7 (the 1/n^4 term): agreement to 2e-6 checks the closed form.
RICHARDSON_RTOL = 2e-6
ORDER2_RATIO = (3.8, 4.2)  # error(n) / error(2n) of an O(1/n^2) method at n = 128
# Particles and voxels: from N = 8 to N = 64 the I_b error must fall at least 5x (measured: 20-60x
# on the sphere, 10-30x on the T-handle; the voxel error is O(1/N) but not monotone in N).
APPROX_SHRINK = 5.0


def rel(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b))


def test_shapes_table_keeps_the_existing_shapes():
    assert {"box": 3, "sphere": 1, "cylinder": 2}.items() <= massprops.SHAPES.items()
    assert set(massprops.SHAPES) == {"box", "sphere", "cylinder", "capsule", "ellipsoid", "cone"}


def test_box_mesh_is_exact():
    size, mass = SIZES["box"], 3.0
    p = mass_properties(primitives.tessellate("box", size, 4), mass / massprops.volume("box", size))
    assert p.volume == pytest.approx(massprops.volume("box", size), rel=EXACT_RTOL)
    assert np.linalg.norm(p.com) < EXACT_RTOL
    assert rel(p.inertia, massprops.inertia("box", size, mass)) < EXACT_RTOL


@pytest.mark.parametrize("n", [3, 7, 40])
def test_regular_prism_and_pyramid_are_exact(n):
    """The n-gon prism (cylinder mesh) and pyramid (cone mesh) against their own closed forms:
    a regular n-gon of circumradius r has area n r^2 sin(a)/2 and polar moment per area
    r^2 (2 + cos a)/6, a = 2 pi / n; a pyramid's slices scale it by 3/5 and put its COM at h/4."""
    a = 2 * np.pi / n
    r, h = SIZES["cylinder"]
    prism = mass_properties(primitives.tessellate("cylinder", [r, h], n))
    area = n * r * r * np.sin(a) / 2
    polar = r * r * (2 + np.cos(a)) / 6
    m = area * h
    assert prism.volume == pytest.approx(m, rel=EXACT_RTOL)
    expected = m * np.diag([h * h / 12 + polar / 2, h * h / 12 + polar / 2, polar])
    assert rel(prism.inertia, expected) < EXACT_RTOL
    assert np.linalg.norm(prism.com) < EXACT_RTOL * h

    r, h = SIZES["cone"]
    pyr = mass_properties(primitives.tessellate("cone", [r, h], n))
    m = n * r * r * np.sin(a) / 2 * h / 3
    polar = 0.6 * r * r * (2 + np.cos(a)) / 6
    assert pyr.volume == pytest.approx(m, rel=EXACT_RTOL)
    assert np.linalg.norm(pyr.com) < EXACT_RTOL * h  # the cone's COM is the body origin
    side = polar / 2 + 3 * h * h / 80
    assert rel(pyr.inertia, m * np.diag([side, side, polar])) < EXACT_RTOL


@pytest.mark.parametrize("shape", ["sphere", "cylinder", "capsule", "ellipsoid", "cone"])
def test_curved_meshes_converge_to_the_closed_form(shape):
    size = SIZES[shape]
    V = massprops.volume(shape, size)
    I = massprops.inertia(shape, size, V)  # density 1
    coarse = mass_properties(primitives.tessellate(shape, size, 128))
    fine = mass_properties(primitives.tessellate(shape, size, 256))
    ratio = rel(coarse.inertia, I) / rel(fine.inertia, I)
    assert ORDER2_RATIO[0] < ratio < ORDER2_RATIO[1]
    extrapolated = (4 * fine.inertia - coarse.inertia) / 3
    assert rel(extrapolated, I) < RICHARDSON_RTOL
    assert (4 * fine.volume - coarse.volume) / 3 == pytest.approx(V, rel=RICHARDSON_RTOL)
    assert np.linalg.norm(fine.com) < EXACT_RTOL * max(size)


@pytest.mark.parametrize("shape", list(SIZES))
def test_tessellations_are_valid_closed_meshes(shape):
    validate(primitives.tessellate(shape, SIZES[shape], 12))


def test_capsule_limits():
    """A capsule with a vanishing straight part is a sphere; its mass splits by volume."""
    r = 0.3
    assert massprops.volume("capsule", [r, 1e-12]) == pytest.approx(massprops.volume("sphere", [r]))
    assert np.allclose(massprops.inertia("capsule", [r, 1e-12], 2.0), massprops.inertia("sphere", [r], 2.0))


def test_mass_properties_under_rigid_motion():
    """Moving a mesh moves its COM with it; rotating it turns I_b into R I_b R^T."""
    rng = np.random.default_rng(7)
    mesh = primitives.tessellate("cone", SIZES["cone"], 9)
    base = mass_properties(mesh, 500.0)
    q = rng.normal(size=4)
    R = matrix_from_quat(q / np.linalg.norm(q))
    offset = rng.normal(size=3)
    moved = mass_properties(type(mesh)(mesh.vertices @ R.T + offset, mesh.triangles), 500.0)
    assert moved.mass == pytest.approx(base.mass, rel=EXACT_RTOL)
    assert np.allclose(moved.com, R @ base.com + offset, atol=EXACT_RTOL * 10)
    assert rel(moved.inertia, R @ base.inertia @ R.T) < 10 * EXACT_RTOL


def test_principal_axes_are_right_handed_and_diagonalise():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(3, 3))
    I = A @ A.T + np.eye(3)
    moments, axes = massprops.principal(I)
    assert np.all(np.diff(moments) >= 0)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    assert np.allclose(axes @ np.diag(moments) @ axes.T, I)


# --- approximations -----------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["particles", "voxels"])
def test_approximation_errors_shrink_on_a_sphere(method):
    size = SIZES["sphere"]
    V = massprops.volume("sphere", size)
    I = massprops.inertia("sphere", size, 1000.0 * V)
    solid = approx.solid_from_shape("sphere", size)
    errs = [rel(approx.METHODS[method](solid, n, density=1000.0).inertia, I) for n in (8, 64)]
    assert errs[1] < errs[0] / APPROX_SHRINK


def test_voxels_are_exact_for_a_box():
    """The voxel grid tiles the bounding box exactly, so a box's voxels are the box."""
    size = SIZES["box"]
    r = approx.voxels(approx.solid_from_shape("box", size), 5, density=2.0)
    assert r.mass == pytest.approx(2.0 * massprops.volume("box", size), rel=EXACT_RTOL)
    assert rel(r.inertia, massprops.inertia("box", size, r.mass)) < EXACT_RTOL


def test_particles_are_deterministic_per_seed():
    solid = approx.solid_from_shape("cone", SIZES["cone"])
    a = approx.particles(solid, 10, mass=1.0, seed=5)
    b = approx.particles(solid, 10, mass=1.0, seed=5)
    c = approx.particles(solid, 10, mass=1.0, seed=6)
    assert np.array_equal(a.inertia, b.inertia) and np.array_equal(a.com, b.com)
    assert not np.array_equal(a.inertia, c.inertia)
    assert a.mass == pytest.approx(1.0)


def test_mesh_winding_through_vertices_and_edges():
    """Rays through a pole vertex shared by many triangles, and along face diagonals, count once."""
    sphere = primitives.tessellate("sphere", [1.0], 16)  # poles are vertices at (0, 0, +-1)
    z = np.array([-1.5, -0.5, 0.0, 0.5, 1.5])
    pts = np.column_stack([np.zeros(5), np.zeros(5), z])
    assert approx.mesh_winding(sphere, pts).tolist() == [0, 1, 1, 1, 0]
    box = primitives.tessellate("box", [1.0, 1.0, 1.0], 4)  # top/bottom diagonals through x = +-y
    t = np.linspace(-0.4, 0.4, 9)
    for zz, expected in ((0.25, 1), (0.75, 0), (-0.75, 0)):
        for sign in (1, -1):
            pts = np.column_stack([t, sign * t, np.full_like(t, zz)])
            assert set(approx.mesh_winding(box, pts).tolist()) == {expected}
    # a grid whose columns pass exactly through the box's edges and vertices
    xs = np.linspace(-0.5, 0.5, 5)
    grid = approx.mesh_winding_grid(box, xs, xs, np.array([-0.75, -0.25, 0.25, 0.75]))
    inner = grid[1:-1, 1:-1]
    assert np.all(inner[:, :, 1:3] == 1) and np.all(inner[:, :, [0, 3]] == 0)


def test_mesh_inside_test_matches_analytic():
    rng = np.random.default_rng(11)
    size = SIZES["capsule"]
    mesh = primitives.tessellate("capsule", size, 24)
    lo, hi = primitives.bounds("capsule", size)
    pts = rng.uniform(lo * 1.2, hi * 1.2, size=(4000, 3))
    inside_mesh = approx.mesh_winding(mesh, pts) != 0
    # the inscribed mesh lies inside the capsule: every mesh-inside point is capsule-inside
    assert not np.any(inside_mesh & ~primitives.contains("capsule", size, pts))
    # and a capsule of radius 0.97 r lies inside the mesh: 24 segments around and 15 degrees along
    # the caps put the mesh at least r cos^2(7.5 deg) = 0.983 r from the axis (or the cap centres)
    shrunk = primitives.contains("capsule", [size[0] * 0.97, size[1]], pts)
    assert not np.any(shrunk & ~inside_mesh)
