"""The closed surface of tri-dexel models (sim.tridexel_surface): watertight, outward,
volumes against the analytic solids, faces the Z grid alone cannot hold, move ids kept."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.boolean import difference, union
from sim.errors import InputError
from sim.grid import DexelGrid
from sim.solids import box_grid, cylinder_grid
from sim.tools import Tool
from sim.tridexel import TriCutter, TriDexel
from sim.tridexel_surface import export_stl, tridexel_mesh

H = 0.5  # lattice spacing, mm


def _closed(mesh):
    assert len(mesh.faces) > 0
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0  # wound outward
    assert len(mesh.face_attributes["move_id"]) == len(mesh.faces)


def _box_model(lo, hi, margin=1.0, spacing=H, face_id=0):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return TriDexel.build(lo - margin, hi + margin, spacing, lambda f: box_grid(f, lo, hi, face_id))


@pytest.mark.parametrize("margin", [1.0, 0.0])
def test_box_on_lattice_planes_is_exact(margin):
    """Faces on lattice planes: the mesh is the box, volume exact, a sphere (Euler 2);
    with no margin the material touches the lattice's boundary and closes there."""
    lo, hi = (0.0, 0.0, 0.0), (10.0, 8.0, 6.0)
    m = tridexel_mesh(_box_model(lo, hi, margin, face_id=4))
    _closed(m)
    assert m.volume == pytest.approx(480.0, rel=1e-12)
    assert m.euler_number == 2
    np.testing.assert_allclose(m.bounds, [lo, hi], atol=1e-12)
    assert set(m.face_attributes["move_id"].tolist()) == {4}


@pytest.mark.parametrize("placement", ["qef", "mean"])
def test_box_between_lattice_planes(placement):
    """Faces between lattice planes are exact either way; the box's edges and corners
    are exact where the vertices solve the crossings' planes (qef, the default) and
    bevelled by less than half a spacing squared of cross-section at their mean."""
    lo, hi = np.array([0.13, 0.27, 0.31]), np.array([9.41, 7.66, 5.52])
    m = tridexel_mesh(_box_model(lo, hi), placement)
    _closed(m)
    assert m.euler_number == 2
    if placement == "qef":
        assert m.volume == pytest.approx(np.prod(hi - lo), rel=1e-6)  # float32 dexel ends
        np.testing.assert_allclose(m.bounds, [lo, hi], atol=1e-5)
    else:
        edges = 4 * (hi - lo).sum()
        assert np.prod(hi - lo) - edges * H**2 / 2 <= m.volume <= np.prod(hi - lo) + 1e-9
    v = m.vertices
    assert np.all(v >= lo - 1e-5) and np.all(v <= hi + 1e-5)
    gap = np.minimum(v - lo, hi - v).min(axis=1)  # distance to the nearest face plane
    assert gap.max() <= H / 2 + 1e-9


def test_a_grid_that_disagrees_is_outvoted():
    """The X grid holds nothing (as if every X ray had missed the box): the other two
    grids outvote it, its edges' crossings fall on the nodes, the box stays exact."""
    lo, hi = np.zeros(3), np.array([6.0, 5.0, 4.0])
    model = _box_model(lo, hi)
    model.grids["x"] = DexelGrid(model.grids["x"].frame)
    m = tridexel_mesh(model)
    _closed(m)
    assert m.volume == pytest.approx(120.0, rel=1e-12)
    assert m.euler_number == 2


def test_solids_touching_along_an_edge_are_joined():
    """Two bars whose lattice nodes touch only diagonally (checkerboard squares of the
    lattice) come out as one closed body, not as edges shared by four faces."""
    def bars(f):
        return union(box_grid(f, (0, 0, 0), (2, 2, 4)), box_grid(f, (2.5, 2.5, 0), (4.5, 4.5, 4)))

    m = tridexel_mesh(TriDexel.build((-1, -1, -1), (5.5, 5.5, 5), H, bars))
    _closed(m)
    assert m.euler_number == 2
    # the joining adds a bridge about a spacing wide along the touching edge
    assert 2 * 2 * 2 * 4 < m.volume < 2 * 2 * 2 * 4 + 2 * H * (4 + 2 * H) * 2


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_any_solid_is_closed(seed):
    """Boxes less or plus cylinders of any axis, radius and place (holes, bosses, thin
    walls, material outside the lattice): always watertight and wound outward, and
    still watertight read back from an STL (which merges vertices by position)."""
    rs = np.random.default_rng(seed)
    parts = [(rs.uniform(-1, 9, 3), rs.normal(size=3) + 1e-3, rs.uniform(0.2, 2.5), rs.random() < 0.7)
             for _ in range(4)]

    def solid(f):
        g = box_grid(f, (0, 0, 0), (8, 8, 6))
        for k, (c, a, r, cut) in enumerate(parts):
            cyl = cylinder_grid(f, c - 6 * a / np.linalg.norm(a), a, r, 12, face_id=k + 1)
            g = difference(g, cyl) if cut else union(g, cyl)
        return g

    model = TriDexel.build((-1, -1, -1), (9, 9, 7), H, solid)
    m = tridexel_mesh(model)
    if len(m.faces):
        _closed(m)
        with tempfile.TemporaryDirectory() as tmp:
            back = trimesh.load(export_stl(model, Path(tmp) / "part.stl"))
        assert back.is_watertight
        assert back.volume == pytest.approx(m.volume, rel=1e-5)


def _distance_to_cylinder(p, x0, x1, r):
    """Distance (mm) of points (n, 3) to the surface of the cylinder on the X axis."""
    x = p[:, 0]
    rho = np.hypot(p[:, 1], p[:, 2])
    inside = (x >= x0) & (x <= x1) & (rho <= r)
    d_in = np.minimum(r - rho, np.minimum(x - x0, x1 - x))
    d_out = np.hypot(np.maximum(np.maximum(x0 - x, x - x1), 0), np.maximum(rho - r, 0))
    return np.where(inside, d_in, d_out)


def test_cylinder_on_the_x_axis():
    """Stock of revolution (a bar on the A axis): closed, volume within 0.3% of pi r^2 L,
    every vertex within a tenth of a spacing of the true surface, no face of the mantle
    folded inwards."""
    r, length, h = 5.0, 30.0, 0.4
    model = TriDexel.build((-1, -6, -6), (31, 6, 6), h,
                           lambda f: cylinder_grid(f, (0, 0, 0), (1, 0, 0), r, length))
    m = tridexel_mesh(model)
    _closed(m)
    assert m.euler_number == 2
    assert m.volume == pytest.approx(np.pi * r**2 * length, rel=0.003)
    assert _distance_to_cylinder(m.vertices, 0.0, length, r).max() <= h / 10
    c, n = m.triangles_center, m.face_normals
    mantle = (c[:, 0] > h) & (c[:, 0] < length - h)
    assert np.all(n[mantle, 1] * c[mantle, 1] + n[mantle, 2] * c[mantle, 2] > 0)


def _holed_box(f):
    """A 12 x 10 x 8 box with a radius-2 hole through it along X (id 3)."""
    box = box_grid(f, (0, 0, 0), (12, 10, 8))
    return difference(box, cylinder_grid(f, (-1, 5, 4), (1, 0, 0), 2.0, 14, face_id=3))


@pytest.fixture(scope="module")
def holed():
    return TriDexel.build((-0.5, -0.5, -0.5), (12.5, 10.5, 8.5), H, _holed_box)


def test_side_hole_along_x_is_held(holed):
    """A through-hole along X (a Z heightfield would hide it under the top): the mesh
    has it (genus 1: Euler 0), its walls face +-Y and +-Z towards the hole's axis and
    carry the id of the cut."""
    m = tridexel_mesh(holed)
    _closed(m)
    assert m.euler_number == 0
    assert m.volume == pytest.approx(12 * 10 * 8 - np.pi * 4 * 12, rel=0.01)
    c, n = m.triangles_center, m.face_normals
    radial = np.stack([np.zeros(len(c)), c[:, 1] - 5, c[:, 2] - 4], axis=1)
    wall = (np.linalg.norm(radial, axis=1) < 2.5) & (c[:, 0] > H) & (c[:, 0] < 12 - H)
    assert wall.sum() > 100
    assert np.all(np.einsum("ij,ij->i", n[wall], radial[wall]) < 0)  # towards the axis
    for d in np.array([[0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]):
        assert (n[wall] @ d > 0.9).sum() > 10
    assert set(m.face_attributes["move_id"][wall].tolist()) == {3}
    assert set(m.face_attributes["move_id"][~wall].tolist()) == {0, 3}  # the hole's mouths


def _sdf_box(p, lo, hi):
    """Signed distance (mm, < 0 inside) of points (n, 3) to the box [lo, hi]."""
    q = np.abs(p - (lo + hi) / 2) - (hi - lo) / 2
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def _sdf_cylinder(p, tip, axis, radius, length):
    """Signed distance (mm, < 0 inside) of points (n, 3) to a flat end mill's cutting
    cylinder standing on ``tip`` along unit ``axis``."""
    w = p - tip
    h = w @ axis
    qx = np.linalg.norm(w - h[:, None] * axis, axis=1) - radius
    qy = np.abs(h - length / 2) - length / 2
    return np.minimum(np.maximum(qx, qy), 0) + np.hypot(np.maximum(qx, 0), np.maximum(qy, 0))


def test_tilted_tool_slot():
    """A flat end mill tilted 30 degrees in XZ cuts a slot (TriCutter.cut_poses): the
    surface is closed, every vertex within half a spacing of the analytic part (the box
    less the tool at each pose), its volume within 1.5% of each grid's (the lattice is
    the stock, so the grids' trapezoid volumes are exact for it), the cut faces carry
    the move and include the slot's floor and its side walls (+-Y)."""
    lo, hi = np.zeros(3), np.array([12.0, 10.0, 8.0])
    model = TriDexel.build(lo, hi, H, lambda f: box_grid(f, lo, hi))
    tilt = np.radians(30)
    axis = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    tips = np.stack([np.linspace(2, 10, 40), np.full(40, 5.0), np.full(40, 6.0)], axis=1)
    removed = TriCutter(model, Tool("flat", diameter=4, flute_length=15)).cut_poses(tips, axis, 7)
    assert min(removed.values()) > 50
    m = tridexel_mesh(model)
    _closed(m)
    assert m.euler_number == 2
    tool = np.min([_sdf_cylinder(m.vertices, t, axis, 2.0, 15.0) for t in tips], axis=0)
    part = np.maximum(_sdf_box(m.vertices, lo, hi), -tool)
    assert np.abs(part).max() <= H / 2
    for a, v in model.volumes().items():
        assert m.volume == pytest.approx(v, rel=0.015), a
    ids = m.face_attributes["move_id"]
    assert set(ids.tolist()) == {0, 7}
    cut_normals = m.face_normals[ids == 7]
    assert (cut_normals[:, 2] > 0.5).any() and (cut_normals[:, 1] > 0.9).any() and (cut_normals[:, 1] < -0.9).any()


def test_export_stl_round_trip(holed, tmp_path):
    path = export_stl(holed, tmp_path / "holed.stl")
    back = trimesh.load(path)
    assert back.is_watertight
    assert back.volume == pytest.approx(tridexel_mesh(holed).volume, rel=1e-6)


def test_export_stl_errors(tmp_path):
    empty = _box_model((0, 0, 0), (2, 2, 2))
    for a in ("x", "y", "z"):
        empty.grids[a] = DexelGrid(empty.grids[a].frame)
    assert len(tridexel_mesh(empty).faces) == 0
    with pytest.raises(InputError, match="no material"):
        export_stl(empty, tmp_path / "x.stl")
    with pytest.raises(InputError, match="does not exist"):
        export_stl(_box_model((0, 0, 0), (2, 2, 2)), tmp_path / "missing" / "x.stl")
    with pytest.raises(InputError, match="TriDexel"):
        tridexel_mesh(empty.grids["z"])
