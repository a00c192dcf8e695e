"""The design cast on an open sheet: the inclusive mode keeps the rays on the sheet's
outer edges, the default (tie rule) mode claims each ray once and drops half of them."""

import numpy as np
import trimesh

from sim.checks.error_map import DesignModel
from sim.frame import Frame
from sim.solids import cast_triangles

SPACING = 0.5


def sheet(plane=(1.0, 0.25, 0.5)):
    """Open square sheet over X 0..2, Y 0..2 (two triangles), z = a + b x + c y (mm)."""
    a, b, c = plane
    xy = np.array([(0, 0), (2, 0), (2, 2), (0, 2)], np.float64)
    verts = np.column_stack([xy, a + b * xy[:, 0] + c * xy[:, 1]])
    return trimesh.Trimesh(vertices=verts, faces=[(0, 1, 2), (0, 2, 3)], process=False)


def frame():
    # rays every 0.5 mm from -0.5 to 3: the sheet's edges lie exactly on rays
    return Frame.top(-0.5, -0.5, 3.0, 3.0, SPACING)


def cast_counts(mesh, f, inclusive, nudge_u=1.0):
    """Crossings per ray (nv, nu) as the design cast counts them."""
    tri = f.to_local(np.asarray(mesh.triangles, np.float64))
    _, counts, _, _ = cast_triangles(tri, f.nu, f.nv, f.spacing, inclusive, nudge_u)
    return counts.reshape(f.shape)


def footprint(f):
    """(inner, edge) bool (nv, nu): rays strictly inside the sheet's square / on its border."""
    x = -0.5 + SPACING * np.arange(f.nu)
    y = -0.5 + SPACING * np.arange(f.nv)
    X, Y = np.meshgrid(x, y)
    closed = (X >= 0) & (X <= 2) & (Y >= 0) & (Y <= 2)
    inner = (X > 0) & (X < 2) & (Y > 0) & (Y < 2)
    return inner, closed & ~inner


def test_inclusive_mode_counts_every_ray_on_the_sheets_outer_edges():
    f = frame()
    inner, edge = footprint(f)
    counts = cast_counts(sheet(), f, inclusive=True)
    assert inner.sum() == 9 and edge.sum() == 16
    assert np.all(counts[inner | edge] >= 1)
    assert np.all(counts[~(inner | edge)] == 0)
    # rays on the shared diagonal belong to both triangles: counted twice, collapsed later
    assert counts.max() == 2


def test_default_mode_claims_each_ray_once_and_drops_half_the_outer_edge():
    f = frame()
    inner, edge = footprint(f)
    counts = cast_counts(sheet(), f, inclusive=False)
    assert counts.max() == 1  # the diagonal is claimed by one triangle only
    assert np.all(counts[inner] == 1)
    assert np.all(counts[~(inner | edge)] == 0)
    # half-open ownership: one ray per 0.5 mm cell of the 2 x 2 mm sheet, so 7 of the
    # 16 border rays (two sides less their far corners) and the other 9 are dropped
    assert counts.sum() == (2.0 / SPACING) ** 2
    assert counts[edge].sum() == 7


def test_open_design_model_has_the_plane_on_every_ray_of_the_closed_square():
    f = frame()
    inner, edge = footprint(f)
    d = DesignModel(f, sheet())
    assert not d.closed
    top = d.top()
    x = -0.5 + SPACING * np.arange(f.nu)
    y = -0.5 + SPACING * np.arange(f.nv)
    X, Y = np.meshgrid(x, y)
    want = 1.0 + 0.25 * X + 0.5 * Y
    on = inner | edge
    np.testing.assert_allclose(top[on], want[on], rtol=0, atol=1e-12)
    assert np.all(np.isnan(top[~on]))
    # one crossing per ray after the duplicates on the diagonal collapsed
    assert np.array_equal(np.diff(d.ptr).reshape(f.shape), on.astype(np.int64))


def test_both_tie_directions_claim_each_ray_once_and_the_design_keeps_its_first_column():
    f = frame()
    inner, edge = footprint(f)
    block = trimesh.creation.box(bounds=[(0, 0, 0), (2, 2, 1)])  # walls exactly on rays
    x = -0.5 + SPACING * np.arange(f.nu)
    for nudge_u in (1.0, -1.0):
        counts = cast_counts(block, f, inclusive=False, nudge_u=nudge_u)
        assert set(np.unique(counts)) == {0, 2}  # top and bottom once each: parity holds
        assert (counts == 2).sum() == (2.0 / SPACING) ** 2
        assert np.all(counts[inner] == 2)
        # the ray is taken as nudged along +u (or -u): the wall column on that side stays
        kept, dropped = (0.0, 2.0) if nudge_u > 0 else (2.0, 0.0)
        j_in = (np.arange(f.nv) >= 2) & (np.arange(f.nv) <= 4)  # Y 0.5..1.5: off the Y walls
        assert np.all(counts[j_in][:, x == kept] == 2)
        assert np.all(counts[j_in][:, x == dropped] == 0)
    d = DesignModel(f, block)
    assert d.closed
    top = d.top()
    assert np.all(top[2:5, x == 0.0] == 1.0)  # the design keeps the X0 column of the block
    assert np.all(np.isnan(top[:, x == 2.0]))
