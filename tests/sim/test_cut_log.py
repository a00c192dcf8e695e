"""The change log of a batch cut: the rays each move changed, and the depth of cut."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cut import Cutter
from sim.gcode.moves import MoveKind
from sim.grid import DexelGrid
from sim.tools import Tool, parse_tool_spec

from tests.sim.test_cut import moves_of, stock  # the same stock and move helpers


def all_segments(g: DexelGrid):
    return g.segments_of(np.arange(g.frame.n_rays))


def assert_same_model(a: DexelGrid, b: DexelGrid, what=""):
    for x, y in zip(all_segments(a), all_segments(b)):
        np.testing.assert_array_equal(x, y, err_msg=what)


FEED, CW, CCW = MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW
# lines, an arc, a helix, a plunge, a cut through an earlier split and moves that miss
PROGRAM = (
    (FEED, (2, 10.1, 5), (38, 10.1, 5)),            # short flutes: splits rays below the top
    (FEED, (20.05, 1, 6), (20.05, 19, 8.5)),          # crosses the split rays, climbing
    (CW, (25, 10, 7.5), (15, 10, 7.5), (20, 10, 7.5)),  # half circle
    (CCW, (15, 10, 7.5), (20, 15, 6.5), (20, 10, 7.5)),  # quarter helix
    (FEED, (20, 15, 6.5), (20, 15, 3.0)),             # plunge
    (FEED, (0, 3, 12), (40, 3, 12)),                  # above the stock: nothing
    (FEED, (3, 3, 1), (37, 17, 9)),                   # diagonal through everything
)


@pytest.mark.parametrize("spec", ["ball:6:L=3", "flat:6:L=2", "bull:6:1:L=2.5", "vbit:6:90:L=2", "tslot"])
def test_the_log_names_exactly_the_rays_each_move_changed(spec):
    tool = (Tool.custom([[0, 3], [1.5, 3], [1.5, 1], [20, 1]]) if spec == "tslot"
            else parse_tool_spec(spec))
    g = stock()
    g.subtract(80, 40, 1, 2, move_id=99)  # a ray that already holds two segments
    before = g.copy()
    mv = moves_of(*PROGRAM)
    res = Cutter(g, tool).cut_moves(mv)
    assert (g.counts >= 2).sum() > 10  # the program did split rays
    seq = before.copy()
    for k in range(len(mv)):
        prev = seq.copy()
        Cutter(seq, tool).cut_moves(mv[k:k + 1], move_ids=[k + 1])
        # the log names exactly the rays the move changed, cut alone after the ones before
        p, s = all_segments(prev), all_segments(seq)
        pc, sc = p[4], s[4]
        differs = pc != sc
        same_count = np.nonzero(~differs)[0]
        pn, sn = prev.segments_of(same_count), seq.segments_of(same_count)
        seg_diff = np.zeros(len(same_count), bool)
        owner = np.repeat(np.arange(len(same_count)), pn[4])
        for x, y in zip(pn[:4], sn[:4]):
            np.logical_or.at(seg_diff, owner, x != y)
        differs[same_count[seg_diff]] = True
        np.testing.assert_array_equal(res.changed(k), np.nonzero(differs)[0])
    assert_same_model(seq, g)
    assert res.changed(5).size == 0


def test_emptied_rays_are_logged_with_their_whole_column():
    g = stock(z0=6.0, z1=8.0)
    res = Cutter(g, parse_tool_spec("flat:4")).cut_moves(moves_of((FEED, (10, 10, 5), (30, 10, 5))))
    assert res.changed_rays.size > 0 and not g.counts.reshape(-1)[res.changed_rays].any()
    np.testing.assert_allclose(res.changed_depth, 2.0)  # the whole 2 mm column went


def test_the_result_has_a_depth_per_changed_ray():
    g = stock()
    res = Cutter(g, parse_tool_spec("flat:6")).cut_moves(moves_of((FEED, (10, 10, 7), (30, 10, 7))))
    assert res.changed_depth.shape == res.changed_rays.shape
    assert res.changed_depth.dtype == np.float32


# --- depth of cut against analytic depths ----------------------------------------------

def _xy(g: DexelGrid, rays):
    pts = g.frame.ray_points().reshape(-1, 3)
    return pts[rays, 0], pts[rays, 1]


def test_depth_of_a_flat_slot_and_of_a_second_slot_across_it():
    g = stock()
    t = parse_tool_spec("flat:6")
    res = Cutter(g, t).cut_moves(moves_of((FEED, (10.05, 10.1, 7), (30.05, 10.1, 7)),
                                          (FEED, (20.1, 2, 5), (20.1, 18, 5))))
    np.testing.assert_array_equal(res.changed_depth[:res.changed_ptr[1]], 3.0)
    d1 = res.changed_depth[res.changed_ptr[1]:]
    x, y = _xy(g, res.changed(1))
    in_first = np.hypot(np.maximum(np.abs(x - 20.05) - 10, 0), y - 10.1) < 3
    np.testing.assert_array_equal(d1[in_first], 2.0)   # 7 -> 5 where the first slot was
    np.testing.assert_array_equal(d1[~in_first], 5.0)  # 10 -> 5 elsewhere
    assert in_first.any() and (~in_first).any()


def test_depth_of_a_ball_groove_is_its_circular_profile():
    g = stock()
    res = Cutter(g, parse_tool_spec("ball:6")).cut_moves(moves_of((FEED, (5, 10, 6), (35, 10, 6))))
    x, y = _xy(g, res.changed(0))
    mid = (x > 9) & (x < 31)
    e = y[mid] - 10
    want = np.sqrt(np.maximum(9 - e * e, 0)) + 1  # ball centre at z 9, stock top 10
    np.testing.assert_allclose(res.changed_depth[mid], want, atol=2e-5)
    assert res.changed_depth.max() == pytest.approx(4.0, abs=1e-6)


def test_depth_of_an_arc_groove_and_of_a_split_below_the_top():
    g = stock()
    res = Cutter(g, parse_tool_spec("ball:6")).cut_moves(
        moves_of((CW, (25, 10, 8), (25, 10, 8), (20, 10, 8))))
    x, y = _xy(g, res.changed(0))
    e = np.hypot(x - 20, y - 10) - 5
    want = np.sqrt(np.maximum(9 - e * e, 0)) - 1  # centre at z 11, top 10
    np.testing.assert_allclose(res.changed_depth, want, atol=0.02)  # chords within tol.chord
    g2 = stock()
    res2 = Cutter(g2, parse_tool_spec("flat:6:L=2")).cut_moves(moves_of((FEED, (5, 10, 4), (35, 10, 4))))
    np.testing.assert_allclose(res2.changed_depth, 2.0, atol=1e-6)  # [4, 6] cut out, top stays


def test_log_grows_mid_move_and_matches_the_model():
    """One move changing ~10k rays (more than the log's and the per-move scratch's first
    size): the changed rays are exactly the rays whose segments changed, the depths the
    drop of their tops."""
    g = stock(x1=60.0, y1=30.0, sp=0.1)
    before = g.copy()
    res = Cutter(g, parse_tool_spec("flat:20:L=20")).cut_moves(
        moves_of((FEED, (10, 15, 8), (50, 15, 7))))
    top0 = before.top().reshape(-1).astype(np.float64)
    top1 = g.top().reshape(-1).astype(np.float64)
    moved = np.nonzero(top1 < top0)[0]
    assert moved.size > 8000
    np.testing.assert_array_equal(res.changed_rays, moved)
    assert res.changed_rays.dtype == np.int64 and res.changed_depth.dtype == np.float32
    np.testing.assert_allclose(res.changed_depth, (top0 - top1)[moved], atol=1e-6)
    assert list(res.changed_ptr) == [0, moved.size]
