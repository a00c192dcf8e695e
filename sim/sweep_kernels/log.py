"""The change log of a batch cut: the changed rays of each move, with the depth of cut on
each (:func:`finish_move`), written by the kernels as they cut.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def finish_move(S, B, mv, nout, mc):
    """Close the changed-ray log of one move: its ``mc`` entries from ``nout`` on.

    B: (out_ray int64, out_depth float32, counts int64 (n_moves,), s_top float64, s_len
    float64). While a move runs every change writes its ray at ``out_ray[nout + q]`` and,
    in the small per-move scratch, the material top before that change (``s_top[q]``) and
    the length removed (``s_len[q]``). Here the move's entries are sorted by ray and
    merged (one per distinct ray: highest top, summed length; already sorted and
    distinct for a single straight segment, the common case), ``out_depth`` gets the
    depth of cut on each ray (top before the move minus the new top; the removed length
    where the top did not move or the ray was emptied) and ``counts[mv]`` the number of
    entries. Returns the new entry count.
    """
    out_ray = B[0]
    out_depth = B[1]
    counts = B[2]
    s_top = B[3]
    s_len = B[4]
    cnt = S[0]
    if mc <= 0:
        return nout
    end = nout + mc
    ordered = True
    for e in range(nout + 1, end):
        if out_ray[e] <= out_ray[e - 1]:
            ordered = False
            break
    if ordered:  # each ray changed once: its logged depth is final
        counts[mv] += mc
        return end
    order = np.argsort(out_ray[nout:end], kind="mergesort")
    rr = out_ray[nout:end].copy()
    tt = s_top[:mc].copy()
    ll = s_len[:mc].copy()
    w = 0
    for q in range(mc):
        o = order[q]
        r = rr[o]
        if w > 0 and out_ray[nout + w - 1] == r:
            if tt[o] > s_top[w - 1]:
                s_top[w - 1] = tt[o]
            s_len[w - 1] += ll[o]
        else:
            out_ray[nout + w] = r
            s_top[w] = tt[o]
            s_len[w] = ll[o]
            w += 1
    # the store's arrays are read directly (not through ds.get_seg): a call per entry
    # passing the store tuple costs more than the rest of the loop
    far = S[2]
    first = S[5]
    pool_far = S[8]
    for q in range(w):
        r = out_ray[nout + q]
        c = cnt[r]
        depth = s_len[q]
        if c > 0:
            top = far[r] if c == 1 else pool_far[first[r] + c - 2]
            drop = s_top[q] - np.float64(top)
            if drop > 0.0:
                depth = drop
        out_depth[nout + q] = depth
    counts[mv] += w
    return nout + w


@nb.njit(cache=True, inline="always")
def _log_change(B, nout, mc, r, top_before, got, depth):
    """Log a change of ray ``r``: its top before, the length removed and the depth of cut
    (final unless the move changes the ray again; see :func:`finish_move`)."""
    B[0][nout + mc] = r
    B[1][nout + mc] = depth
    B[3][mc] = top_before
    B[4][mc] = got


@nb.njit(cache=True)
def _depth_after(S, r, top_before, got):
    """Depth of cut on ray ``r`` changed once: top before minus the top now, or ``got``
    (the length removed) where the top did not drop or the ray was emptied."""
    c = S[0][r]
    if c == 0:
        return got
    top = S[2][r] if c == 1 else S[8][S[5][r] + c - 2]
    drop = top_before - np.float64(top)
    return drop if drop > 0.0 else got


#: buffers of a kernel call that records nothing (never written)
NO_LOG = (np.zeros(1, np.int64), np.zeros(1, np.float32), np.zeros(1, np.int64), np.zeros(1), np.zeros(1))
