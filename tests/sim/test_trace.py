"""z-trace and time-trace: rebuilt stages equal the model as it was, ray for ray."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import InputError
from sim.trace import Trace, TimeTrace, ZTrace, model_difference, same_model
from tests.sim.trace_helpers import ball_cut, box, feed_moves, program, slab_cut


@pytest.fixture(scope="module")
def run():
    """A mixed program recorded with small keyframe spacing, with a copy of every stage."""
    g = box()
    tr = Trace(g, keyframe_every=250)
    snaps = {0: g.copy()}
    for s, rays in program(g, n_moves=30):
        tr.record(g, rays, s)
        snaps[s] = g.copy()
    return tr, snaps


def test_rebuilt_stages_equal_the_model_at_that_stage(run):
    tr, snaps = run
    last = max(snaps)
    assert len(tr.z._keyframes) > 2  # the keyframe path is exercised
    for s in (0, last // 4, last // 2, 3 * last // 4, last):
        assert same_model(tr.grid_at(s), snaps[s]), s
    for s in snaps:  # every stage, including multi-segment ones
        assert model_difference(tr.grid_at(s), snaps[s]).size == 0, s
    assert same_model(tr.grid_at(10**6), snaps[last])
    assert same_model(tr.grid_at(-5), snaps[0])


def test_rebuild_does_not_disturb_later_rebuilds(run):
    tr, snaps = run
    g = tr.grid_at(7)
    g.subtract(0, 0, -100, 100, 99)  # editing a rebuilt model must not reach the trace
    assert same_model(tr.grid_at(7), snaps[7])


def test_fresh_simulation_stopped_at_stage_equals_rebuild():
    # an independent run of the same cuts stopped at stage n, not a copy taken en route
    g = box()
    tr = ZTrace(g, keyframe_every=100)
    for s, rays in program(g, n_moves=20, seed=4):
        tr.record(g, rays, s)
    for stop in (5, 10, 15, 20):
        fresh = box()
        for s, _ in program(fresh, n_moves=stop, seed=4):
            pass
        assert same_model(tr.grid_at(stop), fresh)


def test_rules_classify_changes(run):
    tr, snaps = run
    z = tr.z
    assert z._f_val.n > 0 and z._g_ray.n > 0  # far-only (rule 5) and general (rules 2-4)


def test_z_elements_follow_the_rules():
    g = box(10, 10, 1.0, 0.0, 10.0)
    z = ZTrace(g)
    slab_cut(g, 3, 4, 3, 4, 8.0, 20.0, 1)     # FarZ lowered: rule 5
    z.record(g, [3 * 10 + 3], 1)
    slab_cut(g, 3, 4, 3, 4, 4.0, 5.0, 2)      # a split: rule 2 (two new Z)
    z.record(g, [33], 2)
    slab_cut(g, 3, 4, 3, 4, -1.0, 1.0, 3)     # NearZ raised: rule 4
    z.record(g, [33], 3)
    slab_cut(g, 3, 4, 3, 4, 4.5, 9.0, 4)      # upper dixel deleted: rule 3
    z.record(g, [33], 4)
    el = z.z_elements(3, 3)
    rows = {(float(e["z"]), bool(e["far"]), int(e["created"]), int(e["deleted"])) for e in el}
    alive = 2**62
    assert rows == {
        (0.0, False, 0, 3), (10.0, True, 0, 1),
        (8.0, True, 1, 4), (4.0, True, 2, alive), (5.0, False, 2, 4),
        (1.0, False, 3, alive),
    }
    # the paper's reconstruction: alive elements at n, paired in order
    for n, expect in ((0, [[0, 10]]), (1, [[0, 8]]), (2, [[0, 4], [5, 8]]), (3, [[1, 4], [5, 8]]), (4, [[1, 4]])):
        sel = el[(el["created"] <= n) & (el["deleted"] > n)]
        assert sel["z"].reshape(-1, 2).tolist() == expect
        assert z.grid_at(n).segments(3, 3).tolist() == expect


def test_time_trace_pictures_and_animation(run):
    tr, snaps = run
    t = tr.t
    for s in snaps:
        h, ids = t.state_at(s)
        ref = snaps[s]
        assert np.array_equal(h, ref.top(), equal_nan=True)
        assert np.array_equal(ids, tr.z.grid_at(s).store["far_id"].reshape(ref.shape)
                              * (ref.counts == 1) + ids * (ref.counts != 1))
    fwd = [(s, h.copy()) for s, h, _ in t.frames(2, 29, step=3)]
    assert [s for s, _ in fwd] == [2, 5, 8, 11, 14, 17, 20, 23, 26, 29]
    back = [(s, h.copy()) for s, h, _ in t.frames(30, 0, step=4)]
    assert [s for s, _ in back] == [30, 26, 22, 18, 14, 10, 6, 2, 0]
    for s, h in fwd + back:
        assert np.array_equal(h, snaps[s].top(), equal_nan=True), s


def test_empty_ray_shows_background(run):
    tr, snaps = run
    assert np.isnan(tr.heights_at(12)[2:5, 2:5]).all()   # the through cut at stage 12
    assert not np.isnan(tr.heights_at(11)[2:5, 2:5]).any()


def test_round_trip_arrays_are_plain_numpy(run):
    tr, snaps = run
    arrays = tr.to_arrays()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in arrays.values())
    back = Trace.from_arrays(arrays)
    assert not back.truncated
    for s in snaps:
        assert same_model(back.grid_at(s), snaps[s])
        assert np.array_equal(back.heights_at(s), snaps[s].top(), equal_nan=True)
    # the box stock is stored run-length coded, far smaller than the model
    assert sum(v.nbytes for k, v in arrays.items() if "init_" in k) < 1000


def test_chunks_streamed_during_the_run_read_back():
    g = box()
    tr = Trace(g, keyframe_every=200)
    chunks, snaps = [], {0: g.copy()}
    for s, rays in program(g, n_moves=18, seed=7):
        tr.record(g, rays, s)
        snaps[s] = g.copy()
        if s % 5 == 0:
            chunks.append(tr.take_chunk())
    chunks.append(tr.take_chunk())
    assert tr.take_chunk() == {}
    back = Trace.from_chunks(chunks)
    assert back.z.last_stage == 18 and not back.truncated
    for s in snaps:
        assert same_model(back.grid_at(s), snaps[s])
    # a stream cut after the second chunk replays to the last stage it holds
    part = Trace.from_chunks(chunks[:2])
    assert part.z.last_stage == 10
    assert same_model(part.grid_at(10), snaps[10])


def test_chunk_cut_short_mid_array_keeps_complete_stages():
    g = box()
    tr = Trace(g)
    snaps = {0: g.copy()}
    for s, rays in program(g, n_moves=12, seed=3):
        tr.record(g, rays, s)
        snaps[s] = g.copy()
    arrays = tr.to_arrays()
    cut = dict(arrays)
    cut["z/f_val"] = arrays["z/f_val"][: arrays["z/f_val"].size // 2]   # write died mid-array
    back = Trace.from_arrays(cut)
    assert back.truncated
    last = back.z.last_stage
    assert 0 < last < 12 and back.t.last_stage == last
    for s in range(last + 1):
        assert same_model(back.grid_at(s), snaps[s])
        assert np.array_equal(back.heights_at(s), snaps[s].top(), equal_nan=True)


def test_bad_arrays_give_clear_errors(run):
    tr, _ = run
    arrays = tr.z.to_arrays()
    bad = dict(arrays)
    del bad["frame"]
    with pytest.raises(InputError, match="frame"):
        ZTrace.from_arrays(bad)
    bad = dict(arrays)
    bad["g_ray"] = arrays["g_ray"] + 10**7
    with pytest.raises(InputError, match="ray index"):
        ZTrace.from_arrays(bad)
    bad = dict(arrays)
    bad["stage"] = arrays["stage"][::-1].copy()
    with pytest.raises(InputError, match="decrease"):
        ZTrace.from_arrays(bad)


def test_stages_must_not_decrease():
    g = box(8, 8)
    z = ZTrace(g)
    z.record(g, None, 5)
    with pytest.raises(InputError, match="decrease"):
        z.record(g, None, 4)


def test_over_covering_rays_records_only_changes():
    g = box(20, 20, 1.0)
    z = ZTrace(g)
    ball_cut(g, (10, 10, 8.0), 3.0, 1)
    n = z.record(g, None, 1)   # all rays offered
    assert n == int((g.top() < 10).sum())
    assert z.n_changes == n


def test_rays_in_any_order_with_repeats_record_as_the_sorted_distinct_ones():
    # a live loop hands sorted distinct rays (taken as they are); any other order is sorted
    g1, g2 = box(20, 20, 1.0), box(20, 20, 1.0)
    t1, t2 = Trace(g1), Trace(g2)
    rng = np.random.default_rng(2)
    for s in range(1, 12):
        r1 = ball_cut(g1, (s % 17 + 1, (5 * s) % 17 + 1, 9.5 - 0.2 * s), 2.5, s)
        r2 = ball_cut(g2, (s % 17 + 1, (5 * s) % 17 + 1, 9.5 - 0.2 * s), 2.5, s)
        mixed = rng.permutation(np.concatenate([r2, r2[::3]]))
        t1.record(g1, np.unique(r1), s)
        t2.record(g2, mixed, s)
    a, b = t1.take_chunk(), t2.take_chunk()
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    with pytest.raises(InputError, match="out of range"):
        t2.record(g2, np.array([3, 2, g2.frame.n_rays]), 12)


def test_a_trace_that_hands_its_blocks_on_writes_the_same_chunks_and_keeps_nothing():
    # a live loop writes each chunk to the run file: the trace need not keep it
    g1, g2 = box(20, 20, 1.0), box(20, 20, 1.0)
    keep = Trace(g1, keyframe_every=50)
    stream = Trace(g2, keyframe_every=50, auto_maintain=False, keep_history=False).ready_for_records()
    snaps = {0: g2.copy()}
    kept, streamed = [], []
    for s in range(1, 41):
        centre = (s % 17 + 1, (7 * s) % 17 + 1, 9.6 - 0.15 * s)
        keep.record(g1, ball_cut(g1, centre, 2.5, s), s)
        stream.record(g2, ball_cut(g2, centre, 2.5, s), s)
        snaps[s] = g2.copy()
        if s % 7 == 0 or s == 40:
            kept.append(keep.take_chunk())
            streamed.append(stream.take_chunk())
            assert stream.z.n_blocks == 0 and stream.z.n_changes == 0 and stream.last_stage == s
    assert len(keep.z._keyframes) > 2 and stream.z._keyframes == []
    for a, b in zip(kept, streamed):
        assert a.keys() == b.keys()
        for k in a:
            assert np.array_equal(a[k], b[k]), k
    back = Trace.from_chunks(streamed)
    for s, snap in snaps.items():
        assert same_model(back.grid_at(s), snap), s
    # it records on from its last stage, but rebuilds none
    with pytest.raises(InputError, match="decrease"):
        stream.record(g2, None, 39)
    with pytest.raises(InputError, match="keep_history"):
        stream.grid_at(40)
    with pytest.raises(InputError, match="shared time-trace"):
        Trace(box(4, 4, 1.0), shared_time=False, keep_history=False)


def test_keyframes_stay_bounded_on_long_runs():
    g = box(20, 20, 1.0)
    z = ZTrace(g, keyframe_every=10, max_keyframes=6)
    t = TimeTrace(g, keyframe_every=10, max_keyframes=6)
    ref = {}
    for s in range(1, 80):
        rays = ball_cut(g, (s % 19, (3 * s) % 19, 9.8 - 0.05 * s), 2.0, s)
        z.record(g, rays, s)
        t.record(g, rays, s)
        ref[s] = g.copy()
    assert len(z._keyframes) <= 6 and len(t._keyframes) <= 6
    for s in (1, 33, 64, 79):
        assert same_model(z.grid_at(s), ref[s])
        assert np.array_equal(t.heights_at(s), ref[s].top(), equal_nan=True)


def test_cut_kernel_results_drive_the_trace():
    cut = pytest.importorskip("sim.cut")
    tools = pytest.importorskip("sim.tools")
    from sim.gcode.moves import MoveKind, empty_moves
    g = box(61, 41, 0.5, 0.0, 10.0)
    moves = empty_moves(4)
    pts = [(2, 2, 8), (25, 5, 8), (25, 18, 7), (5, 15, 6), (15, 10, 5)]
    for k in range(4):
        moves["kind"][k] = MoveKind.FEED
        moves["start"][k, :3] = pts[k]
        moves["end"][k, :3] = pts[k + 1]
        moves["feed"][k] = 600
        moves["line"][k] = k + 1
    tool = tools.parse_tool_spec("ball:6")
    tr = Trace(g)
    cutter = cut.Cutter(g, tool)
    ref = {0: g.copy()}
    for k in range(4):
        res = cutter.cut_moves(moves[k:k + 1], move_ids=np.array([k + 1]))
        tr.record_cut(g, res, k + 1)
        ref[k + 1] = g.copy()
    for s in ref:
        assert same_model(tr.grid_at(s), ref[s])


@pytest.mark.parametrize("max_keyframes", [5, 6])
def test_thinning_keyframes_keeps_the_latest(max_keyframes):
    # an odd limit dropped the newest keyframe when thinning; the next one of the same
    # batch, sharing the chunks of rays its own edits left clean with the newest kept,
    # then held stale rays
    from sim.cut import Cutter
    from sim.tools import parse_tool_spec

    g = box(401, 401, 0.25, 0.0, 10.0)   # 10 chunks of rays: keyframes share the clean ones
    rng = np.random.default_rng(5)
    rows = []
    for s in range(1, 90):
        # all over the part, then along one edge (one chunk of rays) only
        a = rng.uniform(5, 95, 2) if s < 50 else np.array([rng.uniform(5, 95), 3.0])
        b = a + rng.uniform(-4, 4, 2)
        rows.append(((a[0], a[1], 9.0 - 0.05 * s), (b[0], b[1], 9.0 - 0.05 * s)))
    moves = feed_moves(rows)
    ref = g.copy()
    refs = {}
    for k in range(len(moves)):   # the model after each move, cut one at a time
        Cutter(ref, parse_tool_spec("ball:3"), threads=1).cut_moves(moves[k:k + 1], move_ids=[k + 1], record_changes=False)
        refs[k + 1] = ref.copy()
    tr = Trace(g, keyframe_every=300)
    tr.z.max_keyframes = max_keyframes
    Cutter(g, parse_tool_spec("ball:3"), threads=1).cut_moves(moves, record_changes=False, trace=tr)
    assert len(tr.z._keyframes) <= max_keyframes and tr.z.keyframe_every > 300   # thinned
    for key in tr.z._keyframes:
        assert np.array_equal(np.asarray(key.data["far"]), refs[key.stage].store["far"]) if key.stage else True
    for s, want in refs.items():
        assert same_model(tr.z.grid_at(s), want), s


def test_a_block_of_stock_is_held_once_as_its_values_and_a_shaped_one_copied():
    """The first keyframe of a box stock holds each per-ray array as its one value,
    broadcast (nothing copied: 26 MB at 1M rays); a stock whose rays differ is copied.
    Either way the first stage stays the stock while the grid is cut, and reads back."""
    from sim import trace_kernels as tk
    from sim.trace.keyframes import _RAY_FIELDS, _uniform

    flat = box()
    shaped = box()
    ball_cut(shaped, (5.0, 5.0, 9.0), 2.0, 7)     # a stock with a dimple: its rays differ
    for g, uniform in ((flat, True), (shaped, False)):
        stock = g.copy()
        tr = Trace(g, keyframe_every=40)
        first = tr.z._keyframes[0].data
        if uniform:
            assert all(first[k].strides == (0,) for k in _RAY_FIELDS)
        else:   # the dimple's tops and their face ids: copies of their own
            assert all(first[k].strides != (0,) and first[k].base is None for k in ("far", "far_id"))
        for s in range(1, 12):
            tr.record(g, ball_cut(g, (2.0 * s, 7.0, 9.5 - 0.3 * s), 3.0, s), s)
        tr.maintain(None)
        assert same_model(tr.grid_at(0), stock)
        assert same_model(tr.grid_at(11), g)
        # kernels are handed plain arrays, never the broadcast ones (a new compile)
        kernels = (tk.tops_of_store, tk.replay_blocks, tk.replay_far_only)
        before = [set(k.signatures) for k in kernels]
        for s in (0, 5, 11):
            np.testing.assert_array_equal(tr.t.heights_at(s), tr.grid_at(s).top(), err_msg=str(s))
        for k, sigs in zip(kernels, before):
            assert all(getattr(a, "mutable", True) for sig in set(k.signatures) - sigs for a in sig), k
        stages = [st for st, _, _ in tr.z.ray_history(3, 3)]
        assert stages[0] == 0
        segs0, ids0 = tr.z.ray_history(10, 10)[0][1:]
        n, f, ni, fi, _ = stock.segments_of(np.array([10 * stock.frame.nu + 10]))
        np.testing.assert_array_equal(segs0, np.stack([n, f], axis=1))
        np.testing.assert_array_equal(ids0, np.stack([ni, fi], axis=1))
        back = Trace.from_chunks([tr.take_chunk()])
        assert same_model(back.grid_at(0), stock) and same_model(back.grid_at(11), g)
        assert tr.z.keyframe_nbytes() < len(tr.z._keyframes) * g.frame.n_rays * 8
    # "one value" means the same bits: a -0.0 among 0.0 keeps the array as it is
    signed = np.zeros(8, np.float32)
    signed[5] = -0.0
    assert not _uniform(signed) and _uniform(np.zeros(8, np.float32))
