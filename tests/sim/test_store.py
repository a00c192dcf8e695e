"""The 1-D Boolean kernels of the dexel store: every Van Hook case, face ids, pool growth."""

from __future__ import annotations

import numpy as np
import pytest

from sim import dexel_store as ds
from sim.frame import Frame
from sim.grid import DexelGrid

EPS = 1e-6


def one_ray(segments, ids=None) -> DexelGrid:
    """A 1 x 1 grid whose only ray holds ``segments`` (list of (near, far))."""
    g = DexelGrid(Frame.top(0, 0, 0, 0, 1.0))
    for k, (a, b) in enumerate(segments):
        g.add(0, 0, a, b, face_id=0 if ids is None else ids[k])
    return g


@pytest.mark.parametrize("a, b, want, removed", [
    (11, 12, [(0, 10)], 0.0),            # entirely above: untouched
    (-5, -1, [(0, 10)], 0.0),            # entirely below: untouched
    (10, 12, [(0, 10)], 0.0),            # touching the far face: untouched
    (-1, 11, [], 10.0),                  # covers it: deleted
    (0, 10, [], 10.0),                   # exactly it: deleted
    (6, 12, [(0, 6)], 4.0),              # far end shortened
    (-2, 3, [(3, 10)], 3.0),             # near end shortened
    (4, 6, [(0, 4), (6, 10)], 2.0),      # split
])
def test_subtract_cases_on_one_segment(a, b, want, removed):
    g = one_ray([(0, 10)])
    got = g.subtract(0, 0, a, b, move_id=7)
    assert got == pytest.approx(removed)
    np.testing.assert_allclose(g.segments(0, 0), np.array(want, float).reshape(-1, 2))


def test_new_faces_carry_the_move_id_and_old_faces_keep_theirs():
    g = one_ray([(0, 10)])
    g.subtract(0, 0, 4, 6, move_id=7)
    np.testing.assert_array_equal(g.face_ids(0, 0), [[0, 7], [7, 0]])
    g.subtract(0, 0, 8, 20, move_id=9)
    np.testing.assert_array_equal(g.face_ids(0, 0), [[0, 7], [7, 9]])
    g.subtract(0, 0, -1, 2, move_id=11)
    np.testing.assert_array_equal(g.face_ids(0, 0), [[11, 7], [7, 9]])


def test_subtract_across_several_segments_covers_every_case_at_once():
    # segments: [0,2] untouched, [3,5] far end cut, [6,7] deleted, [8,12] near end cut, [13,14] untouched
    g = one_ray([(0, 2), (3, 5), (6, 7), (8, 12), (13, 14)], ids=[1, 2, 3, 4, 5])
    got = g.subtract(0, 0, 4, 9, move_id=99)
    assert got == pytest.approx(1 + 1 + 1)
    np.testing.assert_allclose(g.segments(0, 0), [[0, 2], [3, 4], [9, 12], [13, 14]])
    np.testing.assert_array_equal(g.face_ids(0, 0), [[1, 1], [2, 99], [99, 4], [5, 5]])
    # a split inside one of several segments
    got = g.subtract(0, 0, 10, 11, move_id=100)
    assert got == pytest.approx(1.0)
    np.testing.assert_allclose(g.segments(0, 0), [[0, 2], [3, 4], [9, 10], [11, 12], [13, 14]])


def test_slivers_thinner_than_eps_vanish():
    g = one_ray([(0, 10)])
    g.subtract(0, 0, 1e-7, 20, move_id=1)  # would leave [0, 1e-7]
    assert g.counts[0, 0] == 0
    g = one_ray([(0, 10)])
    g.subtract(0, 0, -1, 10 - 1e-7, move_id=1)
    assert g.counts[0, 0] == 0


def test_empty_interval_and_empty_ray_change_nothing():
    g = one_ray([(0, 10)])
    assert g.subtract(0, 0, 5, 5, 1) == 0.0 and g.subtract(0, 0, 6, 5, 1) == 0.0
    np.testing.assert_allclose(g.segments(0, 0), [[0, 10]])
    e = one_ray([])
    assert e.subtract(0, 0, 0, 1, 1) == 0.0 and e.counts[0, 0] == 0


def test_add_interval_merges_and_keeps_outer_ids():
    g = one_ray([(0, 2), (5, 7)], ids=[1, 2])
    assert g.add(0, 0, 1, 6, face_id=9) == pytest.approx(3.0)
    np.testing.assert_allclose(g.segments(0, 0), [[0, 7]])
    np.testing.assert_array_equal(g.face_ids(0, 0), [[1, 2]])
    assert g.add(0, 0, 10, 11, face_id=3) == pytest.approx(1.0)
    np.testing.assert_array_equal(g.face_ids(0, 0), [[1, 2], [3, 3]])


def test_pool_grows_when_splits_need_room_and_nothing_is_lost():
    n = 3000  # more multi-segment rays than the initial pool (1024 slots) holds
    frame = Frame.top(0, 0, n - 1, 0, 1.0)
    g = DexelGrid.from_intervals(frame, np.zeros(frame.shape), np.full(frame.shape, 100.0))
    cap0 = g.store["pool_near"].size
    for i in range(n):
        for k in range(4):  # four splits per ray -> five segments
            g.subtract(i, 0, 10 + 20 * k, 15 + 20 * k, move_id=k + 1)
    assert g.store["pool_near"].size > cap0
    assert (g.counts == 5).all()
    want = np.array([[0, 10], [15, 30], [35, 50], [55, 70], [75, 100]], float)
    for i in (0, n // 2, n - 1):
        np.testing.assert_allclose(g.segments(i, 0), want)
    assert g.volume() == pytest.approx(n * 80.0)


def test_pool_full_returns_the_marker_with_nothing_changed():
    st = ds.new_store(2, pool_capacity=1)
    st["count"][:] = 1
    st["far"][:] = 10
    S = ds.store_tuple(st)
    assert ds.subtract_interval(S, 0, 4.0, 6.0, 1, EPS) == ds.POOL_FULL
    assert st["count"][0] == 1 and st["far"][0] == 10  # unchanged
    ds.grow_pool(st, 64)
    S = ds.store_tuple(st)
    assert ds.subtract_interval(S, 0, 4.0, 6.0, 1, EPS) == pytest.approx(2.0)
    assert st["count"][0] == 2


def test_compact_keeps_every_segment():
    g = one_ray([(0, 10)])
    for k in range(6):  # repeated splits abandon pool blocks as capacity doubles
        g.subtract(0, 0, 1 + k, 1.5 + k, move_id=k + 1)
    before = g.segments(0, 0)
    ids = g.face_ids(0, 0)
    ds.compact(g.store)
    np.testing.assert_array_equal(g.segments(0, 0), before)
    np.testing.assert_array_equal(g.face_ids(0, 0), ids)
    assert g.store["pool_top"][0] == len(before) - 1
