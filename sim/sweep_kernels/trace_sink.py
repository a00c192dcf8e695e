"""The trace sink: z-trace events (see :class:`sim.trace.ZTrace`) written by the batch
kernels as the rays change, one block per move, and the layout of the trace state ``ts``
and columns ``T`` they write (read by :mod:`sim.trace.sink` and :mod:`sim.bands`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from sim.sweep_kernels.batch import DONE, STOP_TRACE, TRACE_KEYFRAME, _save
from sim.sweep_kernels.log import finish_move


#: int64 ``ts`` of a traced batch (see :func:`finish_trace_move`): far events written,
#: general events written, their segments written, general rays of the open move, the open
#: move (-1: none), runs of far rays written, the batch's first block,
#: the event count at which a keyframe falls due, the move after which it fell due, what a
#: STOP_TRACE needs (far events and runs, general events, segments, general-ray scratch)
(TS_NF, TS_NG, TS_NS, TS_NGL, TS_OPEN, TS_NR, TS_BLK0, TS_NEXT_DUE, TS_KEY_MOVE,
 TS_NEED_F, TS_NEED_G, TS_NEED_S, TS_NEED_GEN) = range(13)
TRACE_STATE_SIZE = 13


# --- trace sink: z-trace events written as the batch cuts (see sim.trace.ZTrace) --------
#
# T: (rs int32, f_val float32, rl int32, g_ray int32, g_count int16, g_near float32,
# g_far float32, g_nid int32, g_fid int32, blk_f int64 (n_moves,), blk_g, blk_s, mark int64
# (n_rays,), slot int64 (n_rays,), gen int64 scratch, blk_r int64 (n_moves,)). A far-only
# change (rule 5: only the top segment's FarZ moved down) is one far event: its new FarZ
# in ``f_val``, its ray in the runs of consecutive rays ``rs``/``rl`` (a move's rays come
# row by row: about 16 to a run, so 4.5 bytes an event instead of 8). The face id is the
# move's, kept once per block by the trace. When a move changes a ray more than once
# (arc chords, instances) the event is rewritten in place. Any other change makes the
# ray *general* for the move: when the move closes, its whole segment list becomes one
# general event, applied after the block's far events (so an earlier far event of that
# ray in the block is harmless). ``mark[r]`` is ``2 * block`` when ray ``r`` holds a far
# event of that block at ``slot[r]``, ``2 * block + 1`` when it is general in it. Blocks
# are moves: ``blk_*[mv]`` are the columns' ends after move ``mv``.

# The kernels keep the counts (nf far events, nr runs, ngl general rays) in locals,
# written back to ``ts`` before every return: a count kept in an array is a store and a
# reload per change, several times the cost of the event itself.

@nb.njit(cache=True, inline="always")
def _run_add(rs, rl, nr, run0, runl, r):
    """Ray ``r`` onto the open run of far rays ``run0 .. run0 + runl - 1`` (held in the
    kernel's locals: a run kept in the arrays is a store and a reload per event); a ray
    that does not continue it writes it out and opens a new one. Returns (nr, run0, runl)."""
    if runl > 0 and r == run0 + runl:
        return nr, run0, runl + 1
    if runl > 0:
        rs[nr] = run0
        rl[nr] = runl
        nr += 1
    return nr, r, 1


@nb.njit(cache=True, inline="always")
def _trace_far(rs, rl, f_val, mark, slot, key, multi, r, val, nf, nr, run0, runl):
    """Far event of ray ``r`` in the block whose mark is ``key``; returns the new
    (nf, nr, run0, runl). ``multi``: the move may change the ray more than once (several
    chords or poses), so an event of this block is rewritten in place."""
    if multi:
        m = mark[r]
        if m == key:
            f_val[slot[r]] = val
            return nf, nr, run0, runl
        if m == key + 1:
            return nf, nr, run0, runl
        mark[r] = key
        slot[r] = nf
    nr, run0, runl = _run_add(rs, rl, nr, run0, runl, r)
    f_val[nf] = val
    return nf + 1, nr, run0, runl


@nb.njit(cache=True, inline="always")
def _trace_general(mark, gen, key, r, ngl):
    """Ray ``r`` is general in the block; returns the new general-ray count."""
    if mark[r] == key + 1:
        return ngl
    gen[ngl] = r
    mark[r] = key + 1
    return ngl + 1


@nb.njit(cache=True, inline="always")
def _tflush(ts, rs, rl, nf, ngl, nr, run0, runl):
    """Before a kernel returns: write out the open run, and the counts to ``ts``."""
    if runl > 0:
        rs[nr] = run0
        rl[nr] = runl
        nr += 1
    _tsync(ts, nf, ngl, nr)


@nb.njit(cache=True, inline="always")
def _tsync(ts, nf, ngl, nr):
    ts[TS_NF] = nf
    ts[TS_NGL] = ngl
    ts[TS_NR] = nr


@nb.njit(cache=True)
def finish_trace_move(S, T, ts):
    """Close the open move's block: write each general ray's segment list after the move,
    and set ``blk_*[mv]``. Returns False, changing nothing, when the general columns lack
    room (``ts[TS_NEED_G]`` / ``ts[TS_NEED_S]`` say how much)."""
    mv = ts[TS_OPEN]
    if mv < 0:
        return True
    cnt = S[0]
    gen = T[14]
    ngl = ts[TS_NGL]
    if ngl > 0:
        need_s = 0
        for q in range(ngl):
            need_s += cnt[gen[q]]
        if ts[TS_NG] + ngl > T[3].size or ts[TS_NS] + need_s > T[5].size:
            ts[TS_NEED_G] = ts[TS_NG] + ngl
            ts[TS_NEED_S] = ts[TS_NS] + need_s
            return False
    ng = ts[TS_NG]
    s = ts[TS_NS]
    for q in range(ngl):
        r = gen[q]
        c = cnt[r]
        T[3][ng] = r
        T[4][ng] = c
        ng += 1
        if c > 0:
            T[5][s] = S[1][r]
            T[6][s] = S[2][r]
            T[7][s] = S[3][r]
            T[8][s] = S[4][r]
            s += 1
            p0 = S[5][r]
            for p in range(p0, p0 + c - 1):
                T[5][s] = S[7][p]
                T[6][s] = S[8][p]
                T[7][s] = S[9][p]
                T[8][s] = S[10][p]
                s += 1
    ts[TS_NG] = ng
    ts[TS_NS] = s
    ts[TS_NGL] = 0
    T[9][mv] = ts[TS_NF]
    T[10][mv] = ng
    T[11][mv] = s
    T[15][mv] = ts[TS_NR]
    ts[TS_OPEN] = -1
    return True


@nb.njit(cache=True, inline="always")
def _close_block(S, T, ts, blk_f, blk_g, blk_s, blk_r):
    """:func:`finish_trace_move`, with the usual move (far events only) closed here:
    passing the store and column tuples to a call costs more than the work."""
    if ts[TS_OPEN] < 0:
        return True
    if ts[TS_NGL] == 0:
        _close_far_only(ts, blk_f, blk_g, blk_s, blk_r, ts[TS_NF], ts[TS_NR])
        return True
    return finish_trace_move(S, T, ts)


@nb.njit(cache=True, inline="always")
def _close_far_only(ts, blk_f, blk_g, blk_s, blk_r, nf, nr):
    """Close the usual move (far events only, no change log to close, no keyframe due)
    from the kernel's locals. Kept apart from :func:`_close_traced_move` on purpose: that
    one hands the store and column tuples on, which costs ~2 us a move in reference
    counting even when inlined, more than the cut of a short move."""
    mv = ts[TS_OPEN]
    blk_f[mv] = nf
    blk_g[mv] = ts[TS_NG]
    blk_s[mv] = ts[TS_NS]
    blk_r[mv] = nr
    ts[TS_NF] = nf
    ts[TS_NR] = nr
    ts[TS_OPEN] = -1


@nb.njit(cache=True, inline="always")
def _close_traced_move(S, T, B, ts, state, blk_f, blk_g, blk_s, blk_r, record, k, nout, mc, nf, ngl,
                       nr):
    """At the first segment (or pose) ``k`` of another move: close the open move's trace
    block, then its change-log entries. Returns ``(status, nout, mc, nf, ngl, nr)``:
    status DONE to carry on, or STOP_TRACE / TRACE_KEYFRAME for the kernel to return
    (state saved)."""
    done = ts[TS_OPEN]
    _tsync(ts, nf, ngl, nr)
    ok = _close_block(S, T, ts, blk_f, blk_g, blk_s, blk_r)
    nf = ts[TS_NF]
    ngl = ts[TS_NGL]
    nr = ts[TS_NR]
    if not ok:
        _save(state, k, -1, -1, nout, mc)
        return STOP_TRACE, nout, mc, nf, ngl, nr
    if record and mc > 0:
        nout = finish_move(S, B, done, nout, mc)
        mc = 0
    if _trace_due(ts, done):
        _save(state, k, -1, -1, nout, mc)
        return TRACE_KEYFRAME, nout, mc, nf, ngl, nr
    return DONE, nout, mc, nf, ngl, nr


@nb.njit(cache=True, inline="always")
def _trace_due(ts, mv):
    """After closing move ``mv``: has the event count reached the next keyframe?"""
    if ts[TS_NF] + ts[TS_NG] >= ts[TS_NEXT_DUE]:
        ts[TS_KEY_MOVE] = mv
        return True
    return False


#: trace buffers of a kernel call that traces nothing (never written)
NO_TRACE = (np.zeros(1, np.int32), np.zeros(1, np.float32), np.zeros(1, np.int32), np.zeros(1, np.int32),
            np.zeros(1, np.int16), np.zeros(1, np.float32), np.zeros(1, np.float32), np.zeros(1, np.int32),
            np.zeros(1, np.int32), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64),
            np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64))
NO_TS = np.zeros(TRACE_STATE_SIZE, np.int64)
