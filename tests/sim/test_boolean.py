"""Booleans between grids of one frame: identities, face ids, a brute-force reference."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.boolean import complement, difference, intersection, overlap_length, union
from sim.errors import InputError
from sim.frame import Frame
from sim.solids import box_grid, cylinder_grid, grid_from_segments, mesh_grid


def _all(g):
    n, f, ni, fi, counts = g.segments_of(np.arange(g.frame.n_rays))
    return n, f, ni, fi, counts


def _same(a, b, atol=0.0):
    an, af, ani, afi, ac = _all(a)
    bn, bf, bni, bfi, bc = _all(b)
    assert np.array_equal(ac, bc)
    np.testing.assert_allclose(an, bn, atol=atol)
    np.testing.assert_allclose(af, bf, atol=atol)
    return ani, afi, bni, bfi


@pytest.fixture(scope="module")
def solids():
    f = Frame.top(-8, -8, 8, 8, 0.25)
    a = box_grid(f, (-5.1, -4.3, -3), (4.7, 5.2, 2), face_id=1)
    b = cylinder_grid(f, (1, 0.5, -5), (0.3, 0.1, 1), 3.5, 9, face_id=2)
    ring = mesh_grid(Frame.top(-8, -8, 8, 8, 0.25),
                     trimesh.creation.torus(4, 1.5).apply_translation((0, 0, 1.0)), face_id=3)
    side = cylinder_grid(f, (-8, 0, 0), (1, 0, 0), 1.2, 16, face_id=4)
    return f, a, b, ring, side


def test_self_identities(solids):
    _, a, b, ring, _ = solids
    for g in (a, b, ring):
        _same(union(g, g), g)
        _same(intersection(g, g), g)
        assert difference(g, g).volume() == 0.0
        assert int(difference(g, g).counts.sum()) == 0


def test_inclusion_exclusion(solids):
    _, a, b, ring, side = solids
    for x, y in ((a, b), (a, ring), (ring, side), (b, side)):
        lhs = union(x, y).volume() + intersection(x, y).volume()
        assert lhs == pytest.approx(x.volume() + y.volume(), rel=1e-9)
        assert difference(x, y).volume() == pytest.approx(x.volume() - intersection(x, y).volume(),
                                                          rel=1e-9, abs=1e-9)


def test_difference_is_intersection_with_complement(solids):
    _, a, b, ring, _ = solids
    for x, y in ((a, b), (a, ring), (b, ring)):
        via = intersection(x, complement(y, -50, 50))
        assert via.volume() == pytest.approx(difference(x, y).volume(), rel=1e-9)
        _same(via, difference(x, y))


def test_difference_and_intersection_rebuild_the_operand(solids):
    _, a, b, ring, side = solids
    for x, y in ((a, b), (a, ring), (ring, side), (a, side)):
        rebuilt = union(difference(x, y), intersection(x, y))
        ani, afi, bni, bfi = _same(rebuilt, x, atol=1e-6)
        # the pieces meet on y's faces and merge back: outer faces are x's again
        assert np.array_equal(ani, bni) and np.array_equal(afi, bfi)


def test_multi_segment_results(solids):
    _, a, _, ring, side = solids
    d = difference(a, side)  # a bar along X through the box: splits rays in two
    assert int((d.counts == 2).sum()) > 0
    lid = box_grid(side.frame, (-5, -5, 3), (5, 5, 4), face_id=5)
    u = union(side, lid)  # the bar and a lid above it: two segments where both are
    assert u.counts.max() == 2
    assert u.volume() == pytest.approx(side.volume() + lid.volume())


def test_face_ids_come_from_the_operand_whose_face_it_is():
    f = Frame.top(0, 0, 0, 0, 1.0)  # one ray
    a = grid_from_segments(f, [1], [0.0], [10.0], [1], [1])
    b = grid_from_segments(f, [2], [2.0, 6.0], [4.0, 12.0], [7, 8], [9, 10])
    d = difference(a, b)
    np.testing.assert_allclose(d.segments(0, 0), [[0, 2], [4, 6]])
    assert d.face_ids(0, 0).tolist() == [[1, 7], [9, 8]]
    u = union(a, b)
    np.testing.assert_allclose(u.segments(0, 0), [[0, 12]])
    assert u.face_ids(0, 0).tolist() == [[1, 10]]
    i = intersection(a, b)
    np.testing.assert_allclose(i.segments(0, 0), [[2, 4], [6, 10]])
    assert i.face_ids(0, 0).tolist() == [[7, 9], [8, 1]]


def test_touching_and_tiny_pieces_follow_the_tolerance():
    f = Frame.top(0, 0, 0, 0, 1.0)
    a = grid_from_segments(f, [1], [0.0], [5.0], [1], [1])
    b = grid_from_segments(f, [1], [5.0], [9.0], [2], [2])
    u = union(a, b)
    np.testing.assert_allclose(u.segments(0, 0), [[0, 9]])
    assert intersection(a, b).volume() == 0.0
    c = grid_from_segments(f, [1], [0.0], [4.9999995], [3], [3])  # leaves a sliver < 1e-6
    assert difference(a, c).volume() == 0.0


def test_overlap_length_is_per_ray_intersection(solids):
    _, a, b, ring, side = solids
    for x, y in ((a, b), (ring, side), (a, ring)):
        ov = overlap_length(x, y)
        assert ov.shape == x.shape and ov.dtype == np.float32
        inter = intersection(x, y)
        n, fa, _, _, counts = _all(inter)
        per_ray = np.bincount(np.repeat(np.arange(x.frame.n_rays), counts), weights=fa - n,
                              minlength=x.frame.n_rays)
        np.testing.assert_allclose(ov.reshape(-1), per_ray, atol=1e-5)


def test_frames_must_match():
    a = box_grid(Frame.top(0, 0, 4, 4, 0.5), (1, 1, 0), (3, 3, 1))
    b = box_grid(Frame.top(0, 0, 4, 4, 0.25), (1, 1, 0), (3, 3, 1))
    c = box_grid(Frame.top(0.5, 0, 4.5, 4, 0.5), (1, 1, 0), (3, 3, 1))
    for other in (b, c):
        with pytest.raises(InputError, match="same rays"):
            union(a, other)
    with pytest.raises(InputError, match="DexelGrid"):
        difference(a, np.zeros(3))


# --- brute force reference on random small grids --------------------------------------

def _ref(op, xs, ys):
    """Reference: boundaries from both, keep elementary intervals where op holds."""
    pts = sorted({p for seg in xs + ys for p in seg})
    out = []
    for lo, hi in zip(pts[:-1], pts[1:]):
        mid = 0.5 * (lo + hi)
        ina = any(n < mid < f for n, f in xs)
        inb = any(n < mid < f for n, f in ys)
        keep = {"u": ina or inb, "i": ina and inb, "d": ina and not inb}[op]
        if keep:
            if out and out[-1][1] == lo:
                out[-1][1] = hi
            else:
                out.append([lo, hi])
    return out


def _ray_segments(draw_ints):
    cuts = sorted(set(draw_ints))
    if len(cuts) % 2:
        cuts = cuts[:-1]
    return [(float(cuts[k]), float(cuts[k + 1])) for k in range(0, len(cuts), 2)]


ray_lists = st.lists(st.lists(st.integers(-20, 20), max_size=8), min_size=6, max_size=6)


@settings(max_examples=60, deadline=None)
@given(ray_lists, ray_lists)
def test_random_grids_match_reference(rays_a, rays_b):
    f = Frame.top(0, 0, 2, 1, 1.0)  # 3 x 2 rays
    segs_a = [_ray_segments(r) for r in rays_a]
    segs_b = [_ray_segments(r) for r in rays_b]

    def build(segs, fid):
        counts = [len(s) for s in segs]
        flat = [p for s in segs for p in s]
        n = [p[0] for p in flat]
        fa = [p[1] for p in flat]
        return grid_from_segments(f, counts, n, fa, [fid] * len(n), [fid] * len(n))

    a, b = build(segs_a, 1), build(segs_b, 2)
    for op, fn in (("u", union), ("i", intersection), ("d", difference)):
        g = fn(a, b)
        for r in range(f.n_rays):
            got = g.segments(r % f.nu, r // f.nu).tolist()
            assert got == _ref(op, segs_a[r], segs_b[r]), (op, r)
