"""A batch cut recorded into a trace, rebuilding into a caller's grid, amortised keyframes."""

from __future__ import annotations

import numpy as np
import pytest

from sim.cut import Cutter
from sim.errors import InputError
from sim.tools import parse_tool_spec
from sim.trace import Trace, TimeTrace, ZTrace, model_difference, same_model
from sim.trace import keyframes as keyframes_mod
from tests.sim.trace_helpers import box, feed_moves, program


def _per_stage(n_moves=30, seed=2, keyframe_every=300):
    """The mixed program recorded ray set by ray set, and the model after every stage."""
    g = box()
    one = Trace(g.copy(), keyframe_every=keyframe_every)
    snaps = {0: g.copy()}
    for s, rays in program(g, n_moves=n_moves, seed=seed):
        one.record(g, rays, s)
        snaps[s] = g.copy()
    return one, snaps


def _moves():
    return feed_moves([((1, 1, 12), (1, 1, 8.5)),           # plunge into the 10 mm stock
                       ((1, 1, 8.5), (18, 3, 8.0)),
                       ((18, 3, 8.0), (18, 12, 7.0)),
                       ((18, 12, 7.0), (4, 12, 7.0)),          # an arc below
                       ((4, 12, 7.0), (4, 4, 6.5)),
                       ((4, 4, 6.5), (40, 40, 6.5)),           # leaves the stock: changes few rays
                       ((40, 40, 6.5), (40, 40, 30))],         # changes nothing
                      {3: (11, 12, 7.0)})


def test_real_batch_cut_into_the_trace_equals_cutting_move_by_move():
    moves = _moves()
    ids = np.arange(1, len(moves) + 1)
    tool = parse_tool_spec("ball:4")
    g1 = box(50, 34, 0.5, 0.0, 10.0)
    per_move = Trace(g1, keyframe_every=400)
    cut = Cutter(g1, tool)
    snaps = {0: g1.copy()}
    for k in range(len(moves)):
        res = cut.cut_moves(moves[k:k + 1], move_ids=ids[k:k + 1])
        per_move.record_cut(g1, res, k + 1)
        snaps[k + 1] = g1.copy()
    g2 = box(50, 34, 0.5, 0.0, 10.0)
    batch = Trace(g2, keyframe_every=400)
    Cutter(g2, tool).cut_moves(moves, move_ids=ids, trace=batch)
    assert same_model(g1, g2)
    assert batch.z.n_blocks == len(moves) and batch.t.n_blocks == len(moves)
    assert batch.z.n_changes == per_move.z.n_changes and batch.t.n_changes == per_move.t.n_changes
    out = None
    for s in range(len(moves) + 1):
        assert same_model(batch.grid_at(s), snaps[s]), s
        out = batch.grid_at(s, out=out)
        assert same_model(out, snaps[s]), s
        assert np.array_equal(batch.heights_at(s), snaps[s].top(), equal_nan=True), s


@pytest.fixture(scope="module")
def recorded():
    one, snaps = _per_stage(n_moves=36, seed=11, keyframe_every=150)
    one.maintain(None)
    return one, snaps


def test_grid_at_into_a_reused_grid_any_order(recorded):
    tr, snaps = recorded
    assert len(tr.z._keyframes) > 3
    out = box()   # any grid on the frame; its contents are overwritten
    rng = np.random.default_rng(0)
    order = list(range(37)) + list(range(36, -1, -1)) + list(rng.integers(-3, 40, 60))
    for s in order:
        got = tr.grid_at(int(s), out=out)
        assert got is out
        ref = snaps[min(max(int(s), 0), 36)]
        assert model_difference(out, ref).size == 0, s


def test_two_reused_grids_do_not_share_state(recorded):
    tr, snaps = recorded
    a, b = box(), box()
    for s in (5, 30, 12, 36, 2):
        tr.grid_at(s, out=a)
        tr.grid_at(36 - s, out=b)
        assert same_model(a, snaps[s]) and same_model(b, snaps[36 - s])
    c = tr.grid_at(9)   # a fresh grid is independent of the reused ones
    c.subtract(0, 0, -100, 100, 99)
    assert same_model(tr.grid_at(9, out=a), snaps[9])


def test_state_at_into_reused_arrays_forwards_and_backwards(recorded):
    tr, snaps = recorded
    n = tr.frame.n_rays
    top, tid = np.empty(n, np.float32), np.empty(n, np.int32)
    for s in (0, 3, 4, 20, 36, 35, 10, 1, 36, 0, 18):
        h, ids = tr.state_at(s, out=(top, tid))
        assert h is top
        ref_h, ref_id = tr.t.state_at(s)   # fresh arrays, from a keyframe
        assert np.array_equal(top.reshape(ref_h.shape), snaps[s].top(), equal_nan=True), s
        assert np.array_equal(tid, ref_id.reshape(-1)), s
    with pytest.raises(InputError, match="float32"):
        tr.state_at(3, out=(np.empty(n, np.float64), tid))


def test_keyframes_are_built_a_slice_per_record_and_match_the_model(monkeypatch):
    monkeypatch.setattr(keyframes_mod, "KEYFRAME_BUDGET", 64)   # force many small steps
    g = box()
    z = ZTrace(g, keyframe_every=120)
    t = TimeTrace(g, keyframe_every=120)
    snaps = {0: g.copy()}
    partial = 0
    for s, rays in program(g, n_moves=40, seed=9):
        z.record(g, rays, s)
        t.record(g, rays, s)
        snaps[s] = g.copy()
        partial += z._builder is not None
    assert partial > 0            # some keyframes took several record calls
    z.maintain(None)
    t.maintain(None)
    assert len(z._keyframes) > 4 and len(t._keyframes) > 4
    for key in z._keyframes:      # each keyframe is the model at its stage
        from sim.grid import DexelGrid
        kg = DexelGrid(z.frame, z.tol, {k: v.copy() for k, v in key.data.items()})
        assert same_model(kg, snaps[key.stage]), key.stage
    for key in t._keyframes:
        assert np.array_equal(key.data[0].reshape(g.frame.shape), snaps[key.stage].top(), equal_nan=True)
    for s in snaps:
        assert same_model(z.grid_at(s), snaps[s])
        assert np.array_equal(t.heights_at(s), snaps[s].top(), equal_nan=True)


def test_far_only_keyframes_share_the_arrays_cuts_from_above_cannot_touch():
    from tests.sim.trace_helpers import ball_cut
    g = box(30, 30, 1.0)
    z = ZTrace(g, keyframe_every=50)
    for s in range(1, 30):
        rays = ball_cut(g, (s % 29, (7 * s) % 29, 9.5 - 0.1 * s), 3.0, s)
        z.record(g, rays, s)
    z.maintain(None)
    keys = z._keyframes
    assert len(keys) > 3
    for k in keys[1:]:
        assert k.data["count"] is keys[0].data["count"]
        assert k.data["near"] is keys[0].data["near"]
        assert k.data["far"] is not keys[0].data["far"]
    assert z.keyframe_nbytes() <= (len(keys) - 1) * g.frame.n_rays * 8 + 4096


def _plunge_then_raster(nx=401, ny=401, spacing=0.25):
    """A grid of several chunks of rays, a flat end mill through its bottom (general
    rewrites: rays emptied), then a raster of far-only cuts well away from it."""
    from sim.trace.keyframes import _Chunked

    assert nx * ny > 2 * _Chunked.CHUNK
    rows = [((5, 5, 12), (5, 5, -1)), ((5, 5, -1), (5, 5, 12))]
    for k, y in enumerate(np.arange(20, 38, 0.6)):
        x0, x1 = (8, 36) if k % 2 == 0 else (36, 8)
        rows.append(((x0, y, 8.0 - 0.01 * k), (x1, y, 8.0 - 0.01 * k)))
    return (lambda: box(nx, ny, spacing, 0.0, 10.0)), feed_moves(rows), parse_tool_spec("flat:3")


@pytest.mark.parametrize("threads", [1, 2])
def test_moves_recorded_one_by_one_after_a_traced_batch_build_their_keyframes(threads, monkeypatch):
    """A traced batch whose keyframes share chunks (after its general rewrites), then
    moves recorded one at a time as a live session does: the keyframes those records
    make are built from the batch's (its per-ray arrays kept as chunks). That crashed
    (the replay was handed a chunked array); every stage must rebuild to the model."""
    from sim import bands

    monkeypatch.setattr(bands, "MIN_PARALLEL_RAYS", 0)   # the batch on bands too
    monkeypatch.setattr(bands, "CHUNK_SEGMENTS", 4)
    make, moves, tool = _plunge_then_raster()
    refs = [make()]
    for k in range(len(moves)):
        g = refs[-1].copy()
        Cutter(g, tool, threads=1).cut_moves(moves[k:k + 1], move_ids=[k + 1], record_changes=False)
        refs.append(g)
    g = make()
    n_batch = 12
    tr = Trace(g, keyframe_every=3000)
    cutter = Cutter(g, tool, threads=threads)
    cutter.cut_moves(moves[:n_batch], move_ids=np.arange(1, n_batch + 1), record_changes=False, trace=tr)
    before = len(tr.z._keyframes)
    for k in range(n_batch, len(moves)):
        tr.record_cut(g, cutter.cut_moves(moves[k:k + 1], move_ids=[k + 1]), k + 1)
    tr.maintain(None)
    assert len(tr.z._keyframes) > before + 2
    for s, want in enumerate(refs):
        assert same_model(tr.grid_at(s), want), s
        np.testing.assert_array_equal(tr.t.heights_at(s), want.top())


@pytest.mark.parametrize("path", ["records", "read back"])
def test_keyframes_of_records_and_of_a_read_back_trace_copy_only_the_chunks_edited(path):
    """Keyframes made off the batch path (moves recorded one at a time, as a live session
    does, and a run file's trace read back) copy only the chunks of rays the events since
    the keyframe before touched, after general rewrites too: a raster over a strip of the
    part made keyframes of the whole FarZ array each time (8 MB a keyframe at 1M rays)."""
    from sim.trace.keyframes import _Chunked

    make, moves, tool = _plunge_then_raster()
    g = make()
    tr = Trace(g, keyframe_every=3000)
    cutter = Cutter(g, tool, threads=1)
    snaps = [g.copy()]
    for k in range(len(moves)):
        tr.record_cut(g, cutter.cut_moves(moves[k:k + 1], move_ids=[k + 1]), k + 1)
        snaps.append(g.copy())
    tr.maintain(None)
    z = tr.z
    if path == "read back":   # the run file's z-trace, its keyframes taken as it is read
        chunk = tr.take_chunk()
        z = ZTrace.from_chunks([{k[2:]: v for k, v in chunk.items() if k.startswith("z/")}],
                               keyframe_every=3000)
    keys = z._keyframes
    assert len(keys) > 3 and z._g_ray.n > 0
    n_chunks = -(-z.n_rays // _Chunked.CHUNK)
    for key in keys[1:]:
        far = key.data["far"]
        assert isinstance(far, _Chunked)
        own = sum(c.base is None for c in far.chunks)   # copied for this keyframe, not shared
        assert 0 < own < n_chunks / 2, key.stage
    # the chunks edited by the plunge are the only ones of count a keyframe holds anew
    assert any(isinstance(key.data["count"], _Chunked) for key in keys[1:])
    full = z.n_rays * 4
    assert z.keyframe_nbytes() < (len(keys) - 1) * full
    for s, want in enumerate(snaps):
        assert same_model(z.grid_at(s), want), s
        np.testing.assert_array_equal(tr.t.heights_at(s), want.top())
