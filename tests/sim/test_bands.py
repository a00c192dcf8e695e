"""The batch cut on bands of rows (sim.bands): the same model, change log and trace events
as one core, whatever the number of bands; the pool shared safely; clear settings."""

from __future__ import annotations

import numpy as np
import pytest

from sim import bands
from sim import trace_kernels as tk
from sim.cut import Cutter
from sim.tools import Body, parse_tool_spec
from sim.trace import Trace, same_model
from tests.sim.trace_helpers import box, feed_moves


@pytest.fixture(autouse=True)
def small_bands(monkeypatch):
    """Bands on the small grids of these tests (the defaults keep small batches on one core)."""
    monkeypatch.setattr(bands, "MIN_BAND_ROWS", 3)
    monkeypatch.setattr(bands, "MIN_PARALLEL_RAYS", 0)
    monkeypatch.setattr(bands, "CHUNK_SEGMENTS", 7)   # several chunks, a keyframe check after each


def raster(nx: float, ny: float, step: float, z: float, wave: float, seed: int = 0):
    """A zig-zag finishing raster of short straight feeds with a wavy depth (mm)."""
    rng = np.random.default_rng(seed)
    pts = []
    for k, y in enumerate(np.arange(0.5, ny, step)):
        xs = np.linspace(0.5, nx - 0.5, 9)
        for x in (xs if k % 2 == 0 else xs[::-1]):
            pts.append((x, y, z + wave * np.sin(x * 0.7) * np.cos(y * 0.5) + rng.uniform(0, 0.05)))
    pts = np.array(pts)
    return feed_moves(list(zip(pts[:-1], pts[1:])))


#: arcs (several chords a move), a plunge through the bottom (rays emptied: general
#: events), a rapid out of the stock, and moves that change nothing
MIXED_ROWS = [((1, 1, 12), (1, 1, 8.5)),
              ((1, 1, 8.5), (18, 3, 8.0)),
              ((18, 3, 8.0), (18, 12, 7.0)),
              ((18, 12, 7.0), (4, 12, 7.0)),       # arc
              ((4, 12, 7.0), (4, 4, 6.5)),
              ((4, 4, 6.5), (10, 8, 6.5)),
              ((10, 8, 6.5), (10, 8, -2.0)),       # through the bottom
              ((10, 8, -2.0), (16, 8, -2.0)),
              ((16, 8, -2.0), (16, 2, 5.0)),
              ((16, 2, 5.0), (3, 2, 5.0)),         # arc
              ((3, 2, 5.0), (40, 40, 30)),
              ((40, 40, 30), (41, 40, 30))]
MIXED_ARCS = {3: (11, 12, 7.0), 9: (9.5, 2, 5.0)}


def cut(grid_factory, spec, moves, threads, mode, body=None):
    """Cut ``moves`` on ``threads`` threads; ``mode`` plain, record or trace."""
    grid = grid_factory()
    tr = Trace(grid, keyframe_every=997) if mode == "trace" else None
    calls = []   # bands of each chunk
    real = bands.plan_bands
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bands, "plan_bands", lambda *a, **k: calls.append(len(real(*a, **k)) - 1) or real(*a, **k))
        res = Cutter(grid, parse_tool_spec(spec), threads=threads).cut_moves(
            moves, record_changes=mode == "record", trace=tr, body=body)
    # the batch went on bands (several) exactly when more than one thread was allowed
    assert (calls and max(calls) > 1) if threads > 1 else not calls
    return grid, res, tr


def block_events(z, b):
    """Block ``b``'s far events {ray: (far, id)} and general events {ray: segments}."""
    f0, f1 = z._f_ptr.a[b], z._f_ptr.a[b + 1]
    r0, r1 = z._r_ptr.a[b], z._r_ptr.a[b + 1]
    rays = np.concatenate([np.arange(s, s + n) for s, n in zip(z._f_rs.a[r0:r1], z._f_rl.a[r0:r1])]
                          + [np.zeros(0, np.int64)])
    assert rays.size == f1 - f0
    far = dict(zip(rays.tolist(), z._f_val.a[f0:f1].tolist()))
    general = {}
    s = z._gs_ptr.a[b]
    for q in range(z._g_ptr.a[b], z._g_ptr.a[b + 1]):
        c = int(z._g_count.a[q])
        general[int(z._g_ray.a[q])] = [tuple(col.a[s:s + c].tolist()) for col in
                                       (z._g_near, z._g_far, z._g_nid, z._g_fid)]
        s += c
    assert len(general) == z._g_ptr.a[b + 1] - z._g_ptr.a[b]   # each ray once a block
    return far, general


def tops(grid):
    n = grid.frame.n_rays
    top, tid = np.empty(n, np.float32), np.empty(n, np.int32)
    tk.gather_tops(grid.S, np.arange(n), top, tid)
    return top, tid


CASES = {
    # straight moves only: the columns come out identical, run for run
    "raster_ball": (lambda: box(81, 61, 0.25, 0.0, 10.0), "ball:3", raster(20, 15, 0.6, 6.0, 1.5)),
    "raster_bull": (lambda: box(81, 61, 0.25, 0.0, 10.0), "bull:4:1", raster(20, 15, 0.9, 6.5, 1.0, 1)),
    # a grid narrower than the tool: a move reaches both edges, its runs go on from row to row
    "narrow": (lambda: box(6, 90, 0.25, 0.0, 10.0), "flat:6", raster(1.5, 22, 1.1, 7.0, 0.5, 2)),
    "mixed": (lambda: box(50, 34, 0.5, 0.0, 10.0), "ball:4", feed_moves(MIXED_ROWS, MIXED_ARCS)),
    # flutes 2 mm long below 10 mm of stock: every cut splits rays (the pool, shared by bands)
    "splits": (lambda: box(50, 34, 0.5, 0.0, 10.0), "flat:3:L=2",
               feed_moves([((2, 2, 4), (22, 3, 4.5)), ((22, 3, 4.5), (5, 14, 3.0)),
                           ((5, 14, 3.0), (20, 15, 6.0)), ((20, 15, 6.0), (2, 2, 2.0))] * 3)),
    # a tapered body has no closed-form sweep: instances of motion (sim.sweep_kernels.cut_poses)
    "instances": (lambda: box(40, 30, 0.5, 0.0, 10.0), "flat:3",
                  feed_moves(MIXED_ROWS[:6], {3: MIXED_ARCS[3]})),
}
#: bodies swept instead of the tool (default: the tool's cutting part)
BODIES = {"instances": Body("taper", np.array([[0.0, 0.6], [2.0, 1.6], [6.0, 1.6]]))}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("threads", [2, 3])
def test_bands_cut_the_model_one_core_cuts(case, threads):
    make, spec, moves = CASES[case]
    g1, r1, _ = cut(make, spec, moves, 1, "plain", BODIES.get(case))
    g2, r2, _ = cut(make, spec, moves, threads, "plain", BODIES.get(case))
    assert same_model(g1, g2)                      # heights and face ids, every segment
    np.testing.assert_array_equal(tops(g1)[0], tops(g2)[0])
    np.testing.assert_allclose(r2.removed, r1.removed, rtol=1e-12, atol=1e-12)
    if case == "splits":
        assert (g1.store["count"] > 1).any()


@pytest.mark.parametrize("case", sorted(CASES))
def test_bands_log_the_changes_one_core_logs(case):
    make, spec, moves = CASES[case]
    _, r1, _ = cut(make, spec, moves, 1, "record", BODIES.get(case))
    _, r2, _ = cut(make, spec, moves, 3, "record", BODIES.get(case))
    np.testing.assert_array_equal(r2.changed_ptr, r1.changed_ptr)
    np.testing.assert_array_equal(r2.changed_rays, r1.changed_rays)
    np.testing.assert_array_equal(r2.changed_depth, r1.changed_depth)
    assert r1.changed_rays.size > 0


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("threads", [2, 3])
def test_bands_trace_the_events_one_core_traces(case, threads):
    make, spec, moves = CASES[case]
    g1, _, t1 = cut(make, spec, moves, 1, "trace", BODIES.get(case))
    g2, _, t2 = cut(make, spec, moves, threads, "trace", BODIES.get(case))
    z1, z2 = t1.z, t2.z
    assert z1.n_blocks == z2.n_blocks == len(moves)
    assert z1.n_changes == z2.n_changes > 0
    for b in range(z1.n_blocks):
        assert block_events(z1, b) == block_events(z2, b), f"block {b}"
    np.testing.assert_array_equal(z2._b_id.a, z1._b_id.a)
    for name in ("_f_ptr", "_g_ptr", "_gs_ptr"):
        np.testing.assert_array_equal(getattr(z2, name).a, getattr(z1, name).a, err_msg=name)
    if case.startswith("raster") or case == "narrow":   # one segment a move: the very same columns
        for name in ("_f_rs", "_f_rl", "_f_val", "_r_ptr"):
            np.testing.assert_array_equal(getattr(z2, name).a, getattr(z1, name).a, err_msg=name)
    # every stage replays to the same model, forwards and back (keyframes taken between chunks)
    assert len(z2._keyframes) > 1 or z2.n_changes < 2 * 997
    for s in list(range(len(moves) + 1)) + [3, 0]:
        assert same_model(t1.grid_at(s), t2.grid_at(s)), s
    assert same_model(t2.grid_at(len(moves)), g2) and same_model(g1, g2)


def test_two_traced_batches_at_once_each_trace_as_alone():
    """Band buffers are kept from batch to batch (sim.bands._Stash): two cutters tracing
    on two threads at the same time must not share them."""
    from concurrent.futures import ThreadPoolExecutor

    def traced(case):
        make, spec, moves = CASES[case]
        g = make()
        tr = Trace(g, keyframe_every=997)
        Cutter(g, parse_tool_spec(spec), threads=2).cut_moves(moves, record_changes=False, trace=tr)
        return tr

    alone = {case: traced(case) for case in ("raster_ball", "raster_bull")}
    with ThreadPoolExecutor(2) as ex:
        together = dict(zip(alone, ex.map(traced, alone)))
    for case in alone:
        for name in ("_f_rs", "_f_rl", "_f_val", "_r_ptr", "_f_ptr"):
            np.testing.assert_array_equal(getattr(together[case].z, name).a, getattr(alone[case].z, name).a,
                                          err_msg=f"{case} {name}")


@pytest.mark.parametrize("threads", [1, 2])
def test_keyframes_after_general_edits_share_the_chunks_no_edit_touched(threads):
    """A keyframe after general rewrites (rays emptied by a plunge through the bottom)
    copies only the chunks of rays the edits since the keyframe before touched, on one
    core (keyframes due inside a batch) and on bands (at chunk ends); every stage still
    rebuilds to the model cut move by move without a trace."""
    from sim.trace.keyframes import _Chunked

    make = lambda: box(401, 401, 0.25, 0.0, 10.0)   # noqa: E731 - 10 chunks of rays
    rows = [((5, 5, 12), (5, 5, -1)), ((5, 5, -1), (5, 5, 12))]       # through the bottom
    rows += [((60, y, 12), (60, y, 8.5 + 0.01 * k)) for k, y in enumerate((80, 82))]
    for k, y in enumerate(np.arange(70, 95, 0.8)):                   # a raster far from it
        x0, x1 = (55, 95) if k % 2 == 0 else (95, 55)
        rows.append(((x0, y, 8.0 - 0.01 * k), (x1, y, 8.0 - 0.01 * k)))
    rows += [((20, 3, 12), (20, 3, -1))]                             # and again, later
    moves = feed_moves(rows)
    tool = parse_tool_spec("flat:3")   # a flat end through the bottom empties every ray it reaches
    ref = make()
    refs = [ref.copy()]
    for k in range(len(moves)):
        Cutter(ref, tool, threads=1).cut_moves(moves[k:k + 1], move_ids=[k + 1], record_changes=False)
        refs.append(ref.copy())
    g = make()
    tr = Trace(g, keyframe_every=2000)
    cutter = Cutter(g, tool, threads=threads)
    # the first plunge is a batch of its own: the next batch's first keyframe must copy
    # the chunks it emptied too
    cutter.cut_moves(moves[:2], move_ids=[1, 2], record_changes=False, trace=tr)
    cutter.cut_moves(moves[2:], move_ids=np.arange(3, len(moves) + 1), record_changes=False, trace=tr)
    assert tr.z._g_ray.n > 0 and len(tr.z._keyframes) > 2
    shared = [k for k in tr.z._keyframes[1:] if isinstance(k.data["near"], _Chunked)]
    assert shared, "no keyframe after general edits shared a chunk"
    full = tr.z._keyframes[0].data["near"].nbytes
    assert all(sum(c.nbytes for c in k.data["near"].chunks if c.base is None) < full for k in shared)
    for s, want in enumerate(refs):
        assert same_model(tr.grid_at(s), want), s
        np.testing.assert_array_equal(tr.t.heights_at(s), want.top())


def test_runs_join_across_a_band_edge():
    """The narrow grid's moves reach both edges: the run of changed rays goes on from one
    row into the next, across the band boundary too, as on one core."""
    make, spec, moves = CASES["narrow"]
    _, _, t1 = cut(make, spec, moves, 1, "trace")
    rl = t1.z._f_rl.a
    assert rl.max() > make().frame.nu      # runs longer than a row exist


def test_the_pool_is_handed_out_in_ranges_and_its_unused_end_given_back():
    make, spec, moves = CASES["splits"]
    g1, _, _ = cut(make, spec, moves, 1, "plain")
    g2, _, _ = cut(make, spec, moves, 3, "plain")
    used1 = int(g1.store["pool_top"][0])
    used2 = int(g2.store["pool_top"][0])
    assert used1 > 0
    # bands take their blocks from ranges of at least 1024 slots: all but the last range's
    # unused end may stay behind, no more than a range per band
    assert used2 <= used1 + 3 * 1024
    assert g2.store["pool_top"].size == 1


def test_plan_bands_balances_the_rows_the_moves_reach():
    p0 = np.array([[0.0, 10.0, 0.0]] * 50)
    p1 = np.array([[50.0, 10.0, 0.0]] * 50)   # all the work in rows near y = 10
    b = bands.plan_bands(p0, p1, 3.0, 0.0, 0.1, 1001, 2)
    assert b[0] == 0 and b[-1] == 1001 and len(b) == 3
    assert 70 <= b[1] <= 130                   # split within the rows 70 .. 130 the moves reach


def test_plan_bands_keeps_bands_thick(monkeypatch):
    monkeypatch.setattr(bands, "MIN_BAND_ROWS", 16)
    p0 = np.zeros((4, 3))
    p1 = np.array([[10.0, 1.0, 0.0]] * 4)
    assert bands.plan_bands(p0, p1, 3.0, 0.0, 0.5, 20, 4).tolist() == [0, 20]


def test_chunks_never_split_a_move():
    sm = np.array([0, 0, 0, 1, 2, 2, 2, 2, 3, 4])
    ch = bands.chunk_bounds(sm, 2, first=2)
    assert ch[0] == (0, 3) and ch[-1][1] == len(sm)
    for a, b in ch:
        assert a == 0 or sm[a] != sm[a - 1]


def test_chunks_grow_from_short_to_full():
    sm = np.arange(100)
    ch = bands.chunk_bounds(sm, 16)
    assert [b - a for a, b in ch] == [2, 4, 8, 16, 16, 16, 16, 16, 6]


def test_threads_setting(monkeypatch):
    monkeypatch.setenv("DEXMON_THREADS", "3")
    assert bands.default_threads() == 3
    monkeypatch.setenv("DEXMON_THREADS", "lots")
    with pytest.raises(ValueError, match="DEXMON_THREADS='lots': expected a whole number"):
        bands.default_threads()
    monkeypatch.delenv("DEXMON_THREADS")
    assert bands.default_threads() >= 1


def test_a_forked_child_cuts_on_bands_of_its_own():
    """The pool's threads do not survive a fork: a child that cuts must not wait on them."""
    import multiprocessing as mp
    make, spec, moves = CASES["raster_ball"]
    g1, _, _ = cut(make, spec, moves, 2, "plain")      # the parent's pool exists now
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        top = pool.apply_async(_child_cut, ()).get(timeout=300)
    np.testing.assert_array_equal(top, tops(g1)[0])


def _child_cut():
    bands.MIN_BAND_ROWS, bands.MIN_PARALLEL_RAYS = 3, 0
    make, spec, moves = CASES["raster_ball"]
    grid = make()
    Cutter(grid, parse_tool_spec(spec), threads=2).cut_moves(moves, record_changes=False)
    return tops(grid)[0]
