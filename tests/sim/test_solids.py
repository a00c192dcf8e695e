"""Solids by ray casting: box, cylinder, closed meshes, heightfields; analytic oracles."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

from sim.errors import InputError
from sim.frame import Frame
from sim.solids import (box_grid, cylinder_grid, grid_from_segments, heightfield_grid, mesh_grid,
                        ray_hits)


def _inside_count(x0, spacing, n, lo, hi):
    x = x0 + np.arange(n) * spacing
    return int(((x >= lo) & (x <= hi)).sum())


def _tilted_frame(spacing=0.2, n=121, centre=(0, 0, 0)):
    d = np.array([1.0, 2.0, 3.0])
    d /= np.linalg.norm(d)
    u = np.cross(d, [0.3, -1.0, 0.2])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    half = (n - 1) * spacing / 2
    origin = np.asarray(centre) - half * u - half * v - 20 * d
    return Frame(origin, d, u, spacing, n, n)


# --- box -------------------------------------------------------------------------------

def test_box_on_top_grid_is_ray_columns_times_height():
    f = Frame.top(-10, -8, 10, 8, 0.5)
    lo, hi = (-3.3, -2.1, -4.0), (4.1, 5.7, 2.5)
    g = box_grid(f, lo, hi, face_id=3)
    nx = _inside_count(-10, 0.5, f.nu, lo[0], hi[0])
    ny = _inside_count(-8, 0.5, f.nv, lo[1], hi[1])
    assert g.volume() == pytest.approx(nx * ny * 0.25 * 6.5, rel=1e-6)
    assert int((g.counts == 1).sum()) == nx * ny
    i, j = 20, 16  # x = 0, y = 0
    np.testing.assert_allclose(g.segments(i, j), [[-4.0, 2.5]])
    assert g.face_ids(i, j).tolist() == [[3, 3]]


def test_box_includes_rays_on_its_faces():
    f = Frame.top(0, 0, 4, 4, 1.0)
    g = box_grid(f, (1, 1, 0), (3, 3, 1))
    assert int(g.counts.sum()) == 9  # x, y in {1, 2, 3}


def test_box_on_tilted_frame_matches_analytic_volume():
    f = _tilted_frame()
    g = box_grid(f, (-4, -3, -2), (4, 3, 2.5))
    exact = 8 * 6 * 4.5
    area = 2 * (8 * 6 + 8 * 4.5 + 6 * 4.5)
    assert abs(g.volume() - exact) < area * f.spacing * 0.5
    assert g.counts.max() == 1


def test_box_rays_parallel_to_faces_on_side_frame():
    f = Frame([0, -5, -5], [1, 0, 0], [0, 1, 0], 0.5, 21, 21)  # rays along +X
    g = box_grid(f, (2, -2, -1), (6, 2, 1))
    ny = _inside_count(-5, 0.5, 21, -2, 2)
    nz = _inside_count(-5, 0.5, 21, -1, 1)
    assert g.volume() == pytest.approx(ny * nz * 0.25 * 4)
    segs = g.segments(10, 10)  # y = 0, z = 0 -> s is x measured from the origin plane x=0
    np.testing.assert_allclose(segs, [[2, 6]])


def test_box_bad_extent_is_input_error():
    with pytest.raises(InputError, match="lo < hi"):
        box_grid(Frame.top(0, 0, 1, 1, 0.5), (0, 0, 0), (1, -1, 1))


# --- cylinder ----------------------------------------------------------------------------

def test_upright_cylinder_is_disc_ray_count_times_height():
    f = Frame.top(-6, -6, 6, 6, 0.25)
    g = cylinder_grid(f, (0.1, -0.2, -1), (0, 0, 2), radius=4.3, height=5)
    x, y = np.meshgrid(-6 + np.arange(f.nu) * 0.25, -6 + np.arange(f.nv) * 0.25)
    inside = ((x - 0.1) ** 2 + (y + 0.2) ** 2 <= 4.3**2).sum()
    assert g.volume() == pytest.approx(inside * 0.0625 * 5, rel=1e-6)
    assert abs(g.volume() - np.pi * 4.3**2 * 5) < 2 * np.pi * 4.3 * 5 * 0.25


def test_lying_cylinder_chords_are_exact():
    f = Frame.top(-10, -10, 10, 10, 0.5)
    g = cylinder_grid(f, (-6, 0, 0), (1, 0, 0), radius=3, height=12)
    for y in (0.0, 1.5, 2.5):
        j = int(round((y + 10) / 0.5))
        i = int(round((0 + 10) / 0.5))
        h = np.sqrt(9 - y * y)
        np.testing.assert_allclose(g.segments(i, j), [[-h, h]], atol=1e-5)
    assert g.segments(0, 20).size == 0  # x = -10 is beyond the base at x = -6


def test_cylinder_on_tilted_frame_volume():
    f = _tilted_frame(0.2, 121)
    g = cylinder_grid(f, (1, -2, -3), (0.2, 0.3, 1.0), radius=3, height=7)
    exact = np.pi * 9 * 7
    area = 2 * np.pi * 3 * 7 + 2 * np.pi * 9
    assert abs(g.volume() - exact) < area * f.spacing * 0.5


def test_cylinder_bad_spec():
    with pytest.raises(InputError, match="radius"):
        cylinder_grid(Frame.top(0, 0, 1, 1, 0.5), (0, 0, 0), (0, 0, 1), -1, 2)
    with pytest.raises(InputError, match="axis"):
        cylinder_grid(Frame.top(0, 0, 1, 1, 0.5), (0, 0, 0), (0, 0, 0), 1, 2)


# --- meshes ------------------------------------------------------------------------------

def test_mesh_box_matches_box_grid_off_lattice():
    f = Frame.top(-10, -10, 10, 10, 0.5)
    lo, hi = np.array([-3.3, -2.1, -4.0]), np.array([4.1, 5.7, 2.5])
    mesh = trimesh.creation.box(bounds=[lo, hi])
    g = mesh_grid(f, mesh, face_id=5)
    ref = box_grid(f, lo, hi)
    assert np.array_equal(g.counts, ref.counts)
    n, fa, ni, fi, _ = g.segments_of(np.arange(f.n_rays))
    rn, rf, _, _, _ = ref.segments_of(np.arange(f.n_rays))
    np.testing.assert_allclose(n, rn, atol=1e-5)
    np.testing.assert_allclose(fa, rf, atol=1e-5)
    assert set(ni.tolist()) == {5} and set(fi.tolist()) == {5}


def test_rays_through_shared_edges_and_vertices_count_once():
    # box corners and its triangulated faces' diagonals lie exactly on rays
    f = Frame.top(-2, -2, 2, 2, 0.5)
    mesh = trimesh.creation.box(extents=(2, 2, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an odd crossing count would warn
        g = mesh_grid(f, mesh)
    x = -2 + np.arange(f.nu) * 0.5
    strictly = (np.abs(x) < 1)
    inner = strictly[None, :] & strictly[:, None]
    assert np.all(g.counts[inner] == 1)  # interior rays, including the face diagonals
    assert g.counts.max() == 1
    # boundary rays follow the half-open tie rule: some, not all, of the rim is solid
    on_rim = (np.abs(x) <= 1)[None, :] & (np.abs(x) <= 1)[:, None] & ~inner
    assert 0 <= int(g.counts[on_rim].sum()) < int(on_rim.sum())
    n, fa, *_ = g.segments_of(np.arange(f.n_rays))
    np.testing.assert_allclose(fa - n, 2.0, atol=1e-6)


def test_icosphere_volume_and_outward_normals():
    radius = 5.0
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    f = Frame.top(-6, -6, 6, 6, 0.1)
    g, faces = mesh_grid(f, mesh, return_normals=True)
    area = mesh.area
    assert abs(g.volume() - mesh.volume) < 0.05 * area * f.spacing
    n, fa, _, _, counts = g.segments_of(np.arange(f.n_rays))
    assert faces.near_normal.shape == (n.size, 3) and faces.near_normal.dtype == np.float32
    assert np.all(faces.near_normal[:, 2] < 0) and np.all(faces.far_normal[:, 2] > 0)
    # the normal of the hit triangle points roughly along the hit position (sphere)
    rays = np.repeat(np.arange(f.n_rays), counts)
    foot = f.ray_points().reshape(-1, 3)[rays]
    top_pts = foot + fa[:, None] * f.direction
    cos = np.einsum("ij,ij->i", top_pts / radius, faces.far_normal)
    assert np.median(cos) > 0.999 and cos.min() > 0.9
    assert np.all(faces.far_tri >= 0) and np.all(faces.far_tri < len(mesh.faces))


def test_icosphere_on_tilted_frame():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=4.0)
    f = _tilted_frame(0.1, 101)
    g = mesh_grid(f, mesh)
    assert abs(g.volume() - mesh.volume) < 0.05 * mesh.area * f.spacing


def test_torus_gives_two_segments_on_rays_across_the_hole():
    R, r = 6.0, 2.0
    mesh = trimesh.creation.torus(major_radius=R, minor_radius=r)
    # rays along +X through the equatorial plane: centre ray crosses ring, hole, ring
    f = Frame([-10, -10, -10], [1, 0, 0], [0, 1, 0], 0.25, 81, 81)
    g = mesh_grid(f, mesh)
    centre = (40, 40)  # y = 0, z = 0: the ray passes through mesh vertices at x = +-4, +-8
    np.testing.assert_allclose(g.segments(*centre), [[2, 6], [14, 18]], atol=1e-6)
    assert int((g.counts == 2).sum()) > 100
    # this lattice is aligned with the torus (rays tangent along z = +-2): sampling error
    # is larger than for a generic lattice but still of order area x spacing
    assert abs(g.volume() - mesh.volume) < 0.1 * mesh.area * f.spacing


def test_open_mesh_is_one_clear_error(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    holed = trimesh.Trimesh(mesh.vertices, mesh.faces[1:], process=False)
    f = Frame.top(-1, -1, 1, 1, 0.1)
    with pytest.raises(InputError, match=r"not watertight: 3 open edges"):
        mesh_grid(f, holed)
    path = tmp_path / "holed.stl"
    holed.export(path)
    with pytest.raises(InputError) as err:
        mesh_grid(f, path)
    msg = str(err.value)
    assert str(path) in msg and "open edges" in msg and "\n" not in msg


def test_triangle_soup_that_closes_is_accepted():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=2)
    soup = trimesh.Trimesh(mesh.triangles.reshape(-1, 3), np.arange(len(mesh.faces) * 3).reshape(-1, 3),
                           process=False)
    assert not soup.is_watertight
    f = Frame.top(-3, -3, 3, 3, 0.2)
    assert mesh_grid(f, soup).volume() == pytest.approx(mesh_grid(f, mesh).volume())


def test_missing_and_garbage_mesh_files(tmp_path):
    f = Frame.top(0, 0, 1, 1, 0.5)
    with pytest.raises(InputError, match="not found"):
        mesh_grid(f, tmp_path / "nope.stl")
    bad = tmp_path / "bad.stl"
    bad.write_text("solid x\n  facet normal 0 0\n garbage\n")
    with pytest.raises(InputError, match="bad.stl"):
        mesh_grid(f, bad)


def test_mesh_from_obj_file(tmp_path):
    mesh = trimesh.creation.box(bounds=[[0.2, 0.3, 0], [2.2, 1.3, 1.5]])
    path = tmp_path / "b.obj"
    mesh.export(path)
    f = Frame.top(0, 0, 3, 3, 0.25)
    g = mesh_grid(f, path)
    nx = _inside_count(0, 0.25, f.nu, 0.2, 2.2)
    ny = _inside_count(0, 0.25, f.nv, 0.3, 1.3)
    assert g.volume() == pytest.approx(nx * ny * 0.0625 * 1.5, rel=1e-5)


def test_ray_hits_sorted_and_even_for_closed_mesh():
    mesh = trimesh.creation.torus(major_radius=3, minor_radius=1)
    f = Frame([-5, -5, -5], [1, 0.2, 0.1], [0, 1, 0], 0.2, 51, 51)
    offsets, counts, s, tri = ray_hits(f, mesh)
    assert np.all(counts % 2 == 0)
    for r in np.nonzero(counts > 2)[0][:50]:
        seg = s[offsets[r]:offsets[r] + counts[r]]
        assert np.all(np.diff(seg) >= 0)


# --- heightfields --------------------------------------------------------------------------

def test_heightfield_of_a_tilted_plane():
    # z = 1 + 0.5 x over [0, 4] x [0, 2], two triangles, open
    v = np.array([[0, 0, 1], [4, 0, 3], [4, 2, 3], [0, 2, 1]], float)
    plane = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    f = Frame.top(0.25, 0.25, 3.75, 1.75, 0.5)
    g, faces = heightfield_grid(f, plane, floor=-1.0, face_id=2, return_normals=True)
    x = 0.25 + np.arange(f.nu) * 0.5
    np.testing.assert_allclose(g.top(), np.broadcast_to(1 + 0.5 * x, f.shape), atol=1e-6)
    assert np.all(g.segments(0, 0)[:, 0] == -1.0)
    expected_n = np.array([-0.5, 0, 1]) / np.linalg.norm([-0.5, 0, 1])
    np.testing.assert_allclose(faces.far_normal, np.tile(expected_n, (f.n_rays, 1)), atol=1e-6)
    assert np.all(faces.near_tri == -1)


def test_grid_from_segments_builds_multi_segment_rays():
    f = Frame.top(0, 0, 1, 0, 1.0)  # two rays
    g = grid_from_segments(f, [3, 1], [0, 2, 4, 1], [1, 3, 5, 2], [1, 2, 3, 4], [5, 6, 7, 8])
    np.testing.assert_allclose(g.segments(0, 0), [[0, 1], [2, 3], [4, 5]])
    assert g.face_ids(0, 0).tolist() == [[1, 5], [2, 6], [3, 7]]
    assert g.face_ids(1, 0).tolist() == [[4, 8]]
    g.subtract(0, 0, 0.5, 2.5, 9)  # the store kernels still work on the built pool
    np.testing.assert_allclose(g.segments(0, 0), [[0, 0.5], [2.5, 3], [4, 5]])


# --- corpus --------------------------------------------------------------------------------

def test_sphere_on_plate_volume(shared):
    path = shared / "corpus" / "parts" / "sphere_on_plate.stl"
    mesh = trimesh.load(path, force="mesh")
    side = 76.4923
    n = 306  # rays at cell centres: the 306 columns of 0.25 mm tile 76.5 mm, about the part
    h = 0.25
    f = Frame([h / 2, h / 2, 0], [0, 0, 1], [1, 0, 0], h, n, n)
    g, faces = mesh_grid(f, path, return_normals=True)
    height = 31.8718
    sliver = (n * h - side) * n * h * 2 * height  # columns reach 0.008 mm beyond the part
    assert abs(g.volume() - mesh.volume) < 0.01 * mesh.area * h + sliver
    assert np.all(g.counts == 1)
    np.testing.assert_allclose(g.segments(0, 0), [[2.18718, 14.9359]], atol=1e-4)  # plate
    assert np.nanmin(g.segments_of(np.arange(f.n_rays))[0]) == pytest.approx(-1, abs=0.01)
    # dome top near (38.25, 38.25) at z = 30.8718
    assert np.nanmax(g.top()) == pytest.approx(30.8718, abs=0.01)
    assert faces.far_normal[:, 2].min() > 0 and faces.near_normal[:, 2].max() < 0


def test_carpet_heightfield_volume(shared):
    path = shared / "corpus" / "parts" / "carpet1.stl"
    mesh = trimesh.load(path, force="mesh")
    f = Frame.top(0.25, -81.75, 151.75, 65.75, 0.5)
    with pytest.raises(InputError, match="open edges"):
        mesh_grid(f, path)
    g = heightfield_grid(f, path, floor=-10.0)
    # under a planar triangle: projected area x (mean height - floor), summed
    tri = mesh.triangles
    e1 = tri[:, 1, :2] - tri[:, 0, :2]
    e2 = tri[:, 2, :2] - tri[:, 0, :2]
    a = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    exact = float((a * (tri[:, :, 2].mean(axis=1) + 10)).sum())
    covered = (151.5 + 0.5) * (147.5 + 0.5)  # each ray stands for a 0.5 x 0.5 column
    exact_covered = exact * covered / (152 * 148)
    assert g.volume() == pytest.approx(exact_covered, rel=5e-3)
