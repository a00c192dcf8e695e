"""Cutting straight into a trace (``Cutter.cut_moves(..., trace=tr)``) and the time-trace
that shares the z-trace's events: every stage equals the model cut move by move."""

from __future__ import annotations

import numpy as np
import pytest

from sim import trace_kernels as tk
from sim.cut import Cutter
from sim.errors import InputError
from sim.tools import Tool, parse_tool_spec
from sim.trace import SharedTimeTrace, TimeTrace, Trace, same_model
from sim.trace.keyframes import _Chunked
from sim.trace.sink import _Sink
from tests.sim.trace_helpers import box, feed_moves as _moves, slab_cut


BALL_ROWS = [((1, 1, 12), (1, 1, 8.5)),            # plunge into the 10 mm stock
             ((1, 1, 8.5), (18, 3, 8.0)),
             ((18, 3, 8.0), (18, 12, 7.0)),
             ((18, 12, 7.0), (4, 12, 7.0)),         # an arc: several chords, rays cut twice
             ((4, 12, 7.0), (4, 4, 6.5)),
             ((4, 4, 6.5), (10, 8, 6.5)),
             ((10, 8, 6.5), (10, 8, -2.0)),         # through the bottom: rays emptied
             ((10, 8, -2.0), (16, 8, -2.0)),        # a slot through the part
             ((16, 8, -2.0), (40, 40, 30)),         # leaves the stock
             ((40, 40, 30), (41, 40, 30))]          # changes nothing


def _tops(grid):
    n = grid.frame.n_rays
    top, tid = np.empty(n, np.float32), np.empty(n, np.int32)
    tk.gather_tops(grid.S, np.arange(n), top, tid)
    return top, tid


def _cut_both(tool, moves, stock, keyframe_every=None):
    """The moves cut one at a time (snapshots) and as one batch straight into a trace."""
    ids = np.arange(1, len(moves) + 1)
    g1 = stock()
    snaps = {0: g1.copy()}
    cut = Cutter(g1, tool)
    for k in range(len(moves)):
        cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1], record_changes=False)
        snaps[k + 1] = g1.copy()
    g2 = stock()
    tr = Trace(g2, keyframe_every=keyframe_every)
    Cutter(g2, tool).cut_moves(moves, move_ids=ids, record_changes=False, trace=tr)
    assert same_model(g1, g2)
    return tr, snaps


def _assert_every_stage(tr, snaps):
    assert tr.last_stage == max(snaps) and tr.z.n_blocks == max(snaps)
    out = None
    hbuf = None
    for s in list(snaps) + list(reversed(snaps)):    # forwards, then back
        ref = snaps[s]
        assert same_model(tr.grid_at(s), ref), s
        out = tr.grid_at(s, out=out)
        assert same_model(out, ref), s
        top, tid = _tops(ref)
        h, i = tr.state_at(s)
        np.testing.assert_array_equal(h.reshape(-1), top, err_msg=f"stage {s}")
        np.testing.assert_array_equal(i.reshape(-1), tid, err_msg=f"stage {s}")
        if hbuf is None:
            hbuf = (np.empty(top.size, np.float32), np.empty(top.size, np.int32))
        tr.state_at(s, out=hbuf)
        np.testing.assert_array_equal(hbuf[0], top, err_msg=f"stage {s} (reused arrays)")
        np.testing.assert_array_equal(hbuf[1], tid, err_msg=f"stage {s} (reused arrays)")


def test_ball_batch_into_the_trace_equals_cutting_move_by_move():
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})
    tr, snaps = _cut_both(tool, moves, lambda: box(50, 34, 0.5, 0.0, 10.0), keyframe_every=300)
    assert isinstance(tr.t, SharedTimeTrace)
    assert tr.z._f_val.n > 0 and tr.z._g_ray.n > 0   # rule 5 and rules 2-4 (emptied rays)
    assert len(tr.z._keyframes) > 2                  # taken inline as the batch cut
    _assert_every_stage(tr, snaps)
    # one event per ray and block: the arc's chords rewrite their rays' events in place
    for b in range(tr.z.n_blocks):
        rays = tr.z.far_rays(b, b + 1)
        assert np.unique(rays).size == rays.size, b
    assert tr.z._f_ptr.a[-1] - tr.z._f_ptr.a[-2] == 0    # the last move changed nothing


def test_two_segment_stock_gives_general_events():
    def stock():
        g = box(40, 30, 0.5, 0.0, 10.0)
        slab_cut(g, 0, 40, 0, 15, 3.0, 5.0, 0)   # a pocket under the top: two segments
        return g

    tool = parse_tool_spec("flat:3")
    rows = [((2, 2, 12), (2, 2, 7.0)), ((2, 2, 7.0), (15, 12, 7.0)),
            ((15, 12, 7.0), (15, 12, 4.0)),       # into the hidden pocket: a general rewrite
            ((15, 12, 4.0), (5, 3, 1.0))]
    tr, snaps = _cut_both(tool, _moves(rows), stock)
    assert tr.z._g_ray.n > 0 and tr.z._f_val.n > 0
    _assert_every_stage(tr, snaps)


def test_custom_tslot_poses_into_the_trace():
    # a T-slot cutter (radius 2.5 at the tip, neck 1) slotting under the top surface:
    # instances of motion, splits (general) and far-only edits in the same moves
    tool = Tool.custom([(0.0, 2.5), (1.0, 2.5), (1.0, 1.0), (15.0, 1.0)])
    rows = [((-4, 7, 5.0), (8, 7, 5.0)),          # slot at z 5..6 under 10 mm of stock
            ((8, 7, 5.0), (8, 7, 9.0)),           # up through the top
            ((8, 7, 9.0), (14, 10, 9.0))]
    tr, snaps = _cut_both(tool, _moves(rows), lambda: box(30, 24, 0.5, 0.0, 10.0), keyframe_every=200)
    assert tr.z._g_ray.n > 0 and tr.z._f_val.n > 0
    _assert_every_stage(tr, snaps)


def test_columns_grow_and_keyframes_fall_due_while_the_kernel_runs(monkeypatch):
    monkeypatch.setattr(_Sink, "reserve", lambda self, n: None)
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})

    def stock():
        g = box(50, 34, 0.5, 0.0, 10.0)
        slab_cut(g, 0, 50, 20, 34, 2.0, 3.0, 0)
        return g

    g = stock()
    tr = Trace(g, keyframe_every=60)
    for c in (tr.z._f_rs, tr.z._f_rl, tr.z._f_val, tr.z._f_id):   # start tiny: the kernel must stop
        c.buf = c.buf[:8].copy()
    grown = []
    real_grow = _Sink.grow
    monkeypatch.setattr(_Sink, "grow", lambda self: (grown.append(1), real_grow(self)))
    Cutter(g, tool).cut_moves(moves, record_changes=False, trace=tr)
    assert grown and len(tr.z._keyframes) > 5
    _, snaps = _cut_both(tool, moves, stock)
    _assert_every_stage(tr, snaps)


def test_batches_and_records_mix_and_stages_carry_on():
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})
    ids = np.arange(1, len(moves) + 1)
    g = box(50, 34, 0.5, 0.0, 10.0)
    tr = Trace(g, keyframe_every=250)
    snaps = {0: g.copy()}
    cut = Cutter(g, tool)
    cut.cut_moves(moves[:4], move_ids=ids[:4], record_changes=False, trace=tr, stages=[2, 4, 6, 8])
    for k, s in zip(range(4), (2, 4, 6, 8)):
        ref = box(50, 34, 0.5, 0.0, 10.0)
        Cutter(ref, tool).cut_moves(moves[:k + 1], move_ids=ids[:k + 1], record_changes=False)
        snaps[s] = ref
    # then the live pattern (a diff against the trace's mirror, rebuilt on demand) ...
    res = cut.cut_moves(moves[4:6], move_ids=ids[4:6])
    tr.record_cut(g, res, 9)
    snaps[9] = g.copy()
    # ... then a batch again
    cut.cut_moves(moves[6:], move_ids=ids[6:], record_changes=False, trace=tr)
    assert tr.last_stage == 9 + len(moves) - 6
    snaps[tr.last_stage] = g.copy()
    for s, ref in snaps.items():
        assert same_model(tr.grid_at(s), ref), s
        np.testing.assert_array_equal(tr.heights_at(s).reshape(-1), _tops(ref)[0], err_msg=str(s))
    with pytest.raises(InputError, match="decrease"):
        cut.cut_moves(moves[:1], record_changes=False, trace=tr, stages=[3])


def test_direct_trace_refuses_an_own_time_trace_and_another_frame():
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS[:2])
    g = box()
    with pytest.raises(InputError, match="shared time-trace"):
        Cutter(g, tool).cut_moves(moves, trace=Trace(g, shared_time=False))
    with pytest.raises(InputError, match="frame"):
        Cutter(g, tool).cut_moves(moves, trace=Trace(box(20, 20)))


def test_shared_time_trace_removal_equals_an_own_time_trace():
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})
    ids = np.arange(1, len(moves) + 1)
    g1 = box(50, 34, 0.5, 0.0, 10.0)
    own = Trace(g1, shared_time=False)
    cut = Cutter(g1, tool)
    for k in range(len(moves)):
        res = cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
        own.record_cut(g1, res, k + 1)
    assert isinstance(own.t, TimeTrace) and not isinstance(own.t, SharedTimeTrace)
    g2 = box(50, 34, 0.5, 0.0, 10.0)
    shared = Trace(g2)
    Cutter(g2, tool).cut_moves(moves, move_ids=ids, record_changes=False, trace=shared)
    bottoms = lambda: np.zeros(g2.frame.n_rays)  # noqa: E731 - the stock's floor is z 0
    s1, v1 = own.t.removal_per_block(bottoms)
    s2, v2 = shared.t.removal_per_block(bottoms)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_allclose(v1, v2, rtol=1e-9, atol=1e-9)
    assert v2.sum() > 0
    # the frames of an animation, both ways, are the two traces' pictures
    for (a, h1, i1), (b, h2, i2) in zip(own.t.frames(len(moves), 0, 3), shared.t.frames(len(moves), 0, 3)):
        assert a == b
        np.testing.assert_array_equal(h1, h2)
        np.testing.assert_array_equal(i1, i2)


def test_run_file_chunks_of_a_shared_trace_round_trip_and_truncate():
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})
    g = box(50, 34, 0.5, 0.0, 10.0)
    tr = Trace(g)
    cut = Cutter(g, tool)
    chunks = [tr.take_chunk()]
    for lo in range(0, len(moves), 3):
        cut.cut_moves(moves[lo:lo + 3], move_ids=np.arange(lo, min(lo + 3, len(moves))) + 1,
                      record_changes=False, trace=tr)
        chunks.append(tr.take_chunk())
    assert "t/shared" in chunks[0] and not any(k.startswith("t/") for c in chunks[1:] for k in c)
    back = Trace.from_chunks(chunks)
    assert isinstance(back.t, SharedTimeTrace) and back.last_stage == len(moves)
    for s in range(len(moves) + 1):
        assert same_model(back.grid_at(s), tr.grid_at(s)), s
        np.testing.assert_array_equal(back.heights_at(s), tr.heights_at(s))
    # the last chunk cut short: the stages before it replay, and the trace says truncated
    cut_short = chunks[:-2] + [{k: v[:v.size // 2] for k, v in chunks[-2].items()}]
    part = Trace.from_chunks(cut_short)
    assert part.truncated and 6 <= part.last_stage < 9
    assert isinstance(part.t, SharedTimeTrace) and part.t.last_stage == part.last_stage
    for s in range(part.last_stage + 1):
        assert same_model(part.grid_at(s), tr.grid_at(s)), s


def test_direct_log_equals_the_diffed_log_block_for_block():
    """On one-segment stock the kernels' events are the ones a diff of each move finds:
    the same far events (ray, FarZ, face id) and general rewrites per block."""
    tool = parse_tool_spec("ball:4")
    moves = _moves(BALL_ROWS, {3: (11, 12, 7.0)})
    ids = np.arange(1, len(moves) + 1) * 10
    g1 = box(50, 34, 0.5, 0.0, 10.0)
    diffed = Trace(g1)
    cut = Cutter(g1, tool)
    for k in range(len(moves)):
        res = cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
        diffed.record_cut(g1, res, k + 1)
    g2 = box(50, 34, 0.5, 0.0, 10.0)
    direct = Trace(g2)
    Cutter(g2, tool).cut_moves(moves, move_ids=ids, record_changes=False, trace=direct)
    a, b = diffed.z.to_arrays(), direct.z.to_arrays()
    for k in ("stage", "f_n", "g_n", "g_count"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert np.all(direct.z._b_id.a == ids) and np.all(diffed.z._b_id.a == -1)
    za, zb = diffed.z, direct.z
    for blk in range(len(moves)):
        def far_events(z):
            f0, f1 = z._f_ptr.a[blk], z._f_ptr.a[blk + 1]
            ev = np.stack([z.far_rays(blk, blk + 1), z._f_val.a[f0:f1].view(np.int32),
                           z._event_ids(blk, blk + 1)], axis=1)
            return ev[np.lexsort(ev.T[::-1])]
        np.testing.assert_array_equal(far_events(za), far_events(zb), err_msg=f"block {blk}")
        g0, g1_ = za._g_ptr.a[blk], za._g_ptr.a[blk + 1]
        assert set(za._g_ray.a[g0:g1_]) == set(zb._g_ray.a[g0:g1_]), blk


def test_keyframes_copy_only_the_chunks_of_rays_the_moves_touched():
    """A far-only keyframe shares the FarZ chunks nothing touched since the keyframe before."""
    tool = parse_tool_spec("ball:3")
    # 240 x 240 rays (57,600: four chunks of 16,384); passes along the first rows only,
    # then one at the far end
    rows = [((2, 2, 12), (2, 2, 9.0)), ((2, 2, 9.0), (100, 2, 9.0)), ((100, 2, 9.0), (100, 6, 9.0)),
            ((100, 6, 9.0), (2, 6, 9.0)), ((2, 6, 9.0), (2, 12, 12)),
            ((2, 112, 12), (2, 112, 9.0)), ((2, 112, 9.0), (100, 112, 9.0))]
    moves = _moves(rows)
    tr, snaps = _cut_both(tool, moves, lambda: box(240, 240, 0.5, 0.0, 10.0), keyframe_every=400)
    keys = tr.z._keyframes
    assert len(keys) >= 3
    shared = 0
    for a, b in zip(keys[1:], keys[2:]):
        ca, cb = _Chunked.of(a.data["far"]).chunks, _Chunked.of(b.data["far"]).chunks
        shared += sum(x is y for x, y in zip(ca, cb))
    assert shared > 0
    assert tr.z.keyframe_nbytes() < (len(keys) - 1) * 240 * 240 * 8
    _assert_every_stage(tr, snaps)
