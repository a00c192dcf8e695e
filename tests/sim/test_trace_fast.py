"""Round 3 of the traces: the one-segment cache behind ingest, far-only replay runs, keyframes
left to maintain() (the live loop's pattern) and corrupt logs."""

from __future__ import annotations

import numpy as np
import pytest

from sim.errors import InputError
from sim.trace import Trace, ZTrace, same_model
from tests.sim.trace_helpers import box, slab_cut


def _steps(g):
    """Ray 0..5 of row 0 go 1 -> 2 -> 1 segments, get far-only edits on one and on two
    segments, are emptied and refilled-free; the rest of the grid sees ball-like far edits."""
    nu = g.frame.nu
    row = np.arange(6)
    yield 1, slab_cut(g, 0, 6, 0, 1, 8.0, 20.0, 1)          # far-only (one segment)
    yield 2, slab_cut(g, 0, 6, 0, 1, 3.0, 4.0, 2)           # split: two segments
    yield 3, slab_cut(g, 0, 6, 0, 1, 7.0, 20.0, 3)          # far-only on the upper segment
    yield 4, slab_cut(g, 0, 6, 0, 1, 3.5, 20.0, 4)          # back to one segment (general)
    yield 5, slab_cut(g, 0, 6, 0, 1, 2.5, 20.0, 5)          # far-only again, through the cache
    yield 6, slab_cut(g, 0, 3, 0, 1, -1.0, 20.0, 6)         # emptied
    yield 7, slab_cut(g, 3, 6, 0, 1, -1.0, 0.5, 7)          # near side moved (rule 4)
    yield 8, slab_cut(g, 3, 6, 0, 1, 1.5, 20.0, 8)          # far-only after a general edit
    for s in range(9, 15):                                   # plain far-only passes elsewhere
        rays = slab_cut(g, 0, nu, 2 + s % 3, 4 + s % 3, 9.0 - 0.3 * s, 20.0, s)
        yield s, np.concatenate([rays, row])                 # over-covered: unchanged rays too


def test_cache_transitions_rebuild_every_stage_and_carry_on_recording():
    g = box(12, 8, 1.0)
    one = ZTrace(g.copy(), keyframe_every=10)
    snaps = {0: g.copy()}
    for s, rays in _steps(g):
        one.record(g, rays, s)
        snaps[s] = g.copy()
        assert same_model(one.current(), g), s             # the mirror syncs from the cache
    assert one._g_ray.n >= 6 * 2 and one._f_val.n > 6 * 4
    one.maintain(None)
    out = box(12, 8, 1.0)
    for s in list(snaps) + list(snaps)[::-1]:
        assert same_model(one.grid_at(s), snaps[s]), s
        assert same_model(one.grid_at(s, out=out), snaps[s]), s
    # read back from its arrays (mirror replayed, cache rebuilt), it carries on recording
    back = ZTrace.from_arrays(one.to_arrays())
    assert same_model(back.current(), g)
    slab_cut(g, 0, 6, 0, 1, 1.0, 20.0, 20)
    assert back.record(g, np.arange(6), 20) == 3            # rays 3..5 hold material: far-only
    assert same_model(back.grid_at(20), g) and back._g_ray.n == one._g_ray.n


def test_negative_zero_near_face_is_still_recorded_right():
    g = box(6, 4, 1.0, z0=0.0)
    z = ZTrace(g)
    h = g.copy()
    st = h.store
    st["near"][:] = np.float32(-0.0)                        # equal as floats, other bits
    st["far"][:3] = 7.0
    z.record(h, None, 1)
    rebuilt = z.grid_at(1)
    assert same_model(rebuilt, h)
    assert np.array_equal(rebuilt.store["far"][:3], np.full(3, 7.0, np.float32))


def test_record_without_auto_maintain_leaves_keyframes_to_maintain():
    g = box()
    tr = Trace(g.copy(), keyframe_every=40, auto_maintain=False)
    snaps = {0: g.copy()}
    for s in range(1, 25):
        rays = slab_cut(g, 0, 20, s % 10, s % 10 + 2, 9.5 - 0.2 * s, 20.0, s)
        tr.record(g, rays, s)
        snaps[s] = g.copy()
    assert len(tr.z._keyframes) == 1   # nothing built in record
    assert tr.t._keyframes is tr.z._keyframes   # the time-trace starts from the z keyframes
    assert tr.z._due
    assert not tr.maintain(50)                               # a slice: work left
    assert tr.maintain(None)
    assert len(tr.z._keyframes) > 3
    for s, ref in snaps.items():
        assert same_model(tr.grid_at(s), ref), s
        assert np.array_equal(tr.heights_at(s), ref.top(), equal_nan=True), s


def test_far_only_edit_of_an_empty_ray_is_a_corrupt_trace():
    g = box(6, 4, 1.0)
    z = ZTrace(g)
    slab_cut(g, 0, 2, 0, 1, 5.0, 20.0, 1)
    z.record(g, None, 1)
    arrays = z.to_arrays()
    # make the stock empty on ray 0: block 1's far-only edit then has no material to edit
    arrays["init_count"] = np.zeros(g.frame.n_rays, np.int16)
    arrays.pop("init_count.rv", None)
    arrays.pop("init_count.rl", None)
    n_segs = 0
    for k in ("init_near", "init_far", "init_nid", "init_fid"):
        arrays.pop(k + ".rv", None)
        arrays.pop(k + ".rl", None)
        arrays[k] = np.zeros(n_segs, np.float32 if "nid" not in k and "fid" not in k else np.int32)
    with pytest.raises(InputError, match="corrupt trace"):
        ZTrace.from_arrays(arrays)
