"""numba kernels behind :mod:`sim.trace`: diff a grid against the trace's mirror, replay.

All kernels take dexel stores as the tuple of :func:`sim.dexel_store.store_tuple` and work
one ray at a time with no allocation per ray.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from sim import dexel_store as ds


@nb.njit(cache=True)
def replay_blocks(S, b0, b1, f_ptr, rn_ptr, rs, rl, f_val, f_id, b_id, g_ptr, gs_ptr, g_ray,
                  g_count, g_near, g_far, g_nid, g_fid, skip_far_first):
    """Apply the trace blocks ``b0 <= b < b1`` to store ``S`` in order.

    Each block applies its far-only edits, then its general rewrites: a general rewrite
    is the ray's whole state after the block, so it stands whatever far edit of the same
    ray came before it in the block. Far events are stored as runs of consecutive rays
    (``rs``/``rl``, block ``b``'s runs ``rn_ptr[b]:rn_ptr[b+1]``) with one value each.
    Returns ``b1`` when done, or the index of the block whose rewrite found the pool full
    (blocks before it are applied; call again from it with ``skip_far_first`` after growing
    the pool: its far edits are done, and its rewrites set whole values), or ``-1 - b``
    when block ``b`` edits the FarZ of an empty ray (a corrupt trace).
    """
    for b in range(b0, b1):
        if not (skip_far_first and b == b0):
            u = b_id[b]
            q = f_ptr[b]
            for k in range(rn_ptr[b], rn_ptr[b + 1]):
                r = rs[k]
                for _ in range(rl[k]):
                    c = S[0][r] - 1
                    if c < 0:
                        return -1 - b
                    i = u if u >= 0 else f_id[q]
                    if c == 0:
                        S[2][r] = f_val[q]
                        S[4][r] = i
                    else:
                        p = S[5][r] + c - 1
                        S[8][p] = f_val[q]
                        S[10][p] = i
                    q += 1
                    r += 1
        s = gs_ptr[b]
        for q in range(g_ptr[b], g_ptr[b + 1]):
            c = g_count[q]
            if not ds.write_ray(S, g_ray[q], g_near[s:s + c], g_far[s:s + c], g_nid[s:s + c],
                                g_fid[s:s + c], c):
                return b
            s += c
    return b1


@nb.njit(cache=True)
def gather_tops(S, rays, top, top_id):
    """Top (last FarZ) and its face id of each ray; NaN and 0 where the ray is empty."""
    for q in range(rays.size):
        r = rays[q]
        c = S[0][r]
        if c == 0:
            top[q] = np.nan
            top_id[q] = 0
        else:
            n, f, ni, fi = ds.get_seg(S, r, c - 1)
            top[q] = f
            top_id[q] = fi


@nb.njit(cache=True)
def top_changes(S, rays, cur_top, cur_id, out_ray, out_top, out_id, out_prev, out_prev_id):
    """Rule 6: rays whose visible surface (last FarZ or emptiness) changed.

    Compares each ray's top in ``S`` with ``cur_top``/``cur_id`` (n_rays,), updates those in
    place and writes the changes (ray, new top, new id, previous top, previous id) to the
    ``out_*`` arrays. Returns the number of changes.
    """
    m = 0
    for q in range(rays.size):
        r = rays[q]
        c = S[0][r]
        if c == 0:
            t = np.float32(np.nan)
            tid = np.int32(0)
        else:
            n, f, ni, fi = ds.get_seg(S, r, c - 1)
            t = f
            tid = fi
        old = cur_top[r]
        same = (t == old) or (np.isnan(t) and np.isnan(old))
        if same and tid == cur_id[r]:
            continue
        out_ray[m] = r
        out_top[m] = t
        out_id[m] = tid
        out_prev[m] = old
        out_prev_id[m] = cur_id[r]
        cur_top[r] = t
        cur_id[r] = tid
        m += 1
    return m


@nb.njit(cache=True)
def scatter_values(dst_val, dst_id, rays, vals, ids):
    """``dst_val[rays] = vals; dst_id[rays] = ids`` in order (later entries win)."""
    for q in range(rays.size):
        dst_val[rays[q]] = vals[q]
        dst_id[rays[q]] = ids[q]


@nb.njit(cache=True)
def chain_prev(top, top_id, rays, vals, ids, prev, prev_id):
    """Walk time elements in order: note each ray's previous top, then set the new one."""
    for q in range(rays.size):
        r = rays[q]
        prev[q] = top[r]
        prev_id[q] = top_id[r]
        top[r] = vals[q]
        top_id[r] = ids[q]


# --- ingest: diff new ray states against the mirror, update it, emit trace events ------------

#: ingest kernels' return codes
DONE = 0
POOL_FULL = 1


@nb.njit(cache=True)
def undo_values(dst_val, dst_id, rays, prev, prev_id, lo, hi):
    """Undo time elements ``hi-1`` down to ``lo``: each ray ends at its oldest previous top."""
    for q in range(hi - 1, lo - 1, -1):
        dst_val[rays[q]] = prev[q]
        dst_id[rays[q]] = prev_id[q]


# --- the fast ingest: a one-segment cache in front of the mirror ------------------------------

#: ``rec[r, 0]`` when ray r is not a one-segment ray (the bits of a NaN no journal holds)
NOT_SIMPLE = np.int32(-1)


@nb.njit(cache=True)
def simple_rec_from_store(S, rec, recf):
    """Fill ``rec`` (n_rays, 4) int32 = (near bits, far bits, near_id, far_id) of every
    one-segment ray of store ``S``; ``rec[r, 0] = NOT_SIMPLE`` for the others."""
    for r in range(S[0].size):
        if S[0][r] == 1:
            recf[r, 0] = S[1][r]
            recf[r, 1] = S[2][r]
            rec[r, 2] = S[3][r]
            rec[r, 3] = S[4][r]
        else:
            rec[r, 0] = NOT_SIMPLE


@nb.njit(cache=True)
def ingest_journal_fast(rec, recf, M, ptr, rays, seg_ptr, jn, jf, jni, jfi, jnb, jfb, state, cnt,
                        blk_f, blk_g, blk_s, f_ray, f_val, f_id, g_ray, g_count, g_near,
                        g_far, g_nid, g_fid, f_base):
    """Record a cut journal move by move into the z-trace columns (one block per move),
    with a one-segment cache ``rec`` in front of the mirror.

    ptr (n_moves+1,) int64, rays (n_entries,) int64: the CSR of changed rays; entry e's
    segments after its move are ``j*[seg_ptr[e]:seg_ptr[e+1]]``. Each entry is compared
    with the mirror ``M`` (the model before it), which is brought up to date; changes go
    to the output columns: far-only (rule 5: value and id of the last FarZ) or general
    (the ray's new segment list). ``state`` (2,) int64 = (move, entry) to resume from;
    ``cnt`` (3,) int64 = far-only events, general events, general segments written so
    far. ``blk_*[k]`` get the column ends after move k. Returns DONE, or POOL_FULL with
    ``state`` set to redo (grow the mirror's pool and call again). The body is one loop on
    purpose: a helper per entry cost ~1 us of argument passing per call.

    rec : (n_rays, 4) int32: (near bits, far bits, near_id, far_id) of each ray that holds
        exactly one segment, ``rec[r, 0] = NOT_SIMPLE`` otherwise; for those rays ``rec``
        is the truth and ``M`` may be stale (see :func:`sync_mirror`). One 16-byte read
        decides the common entry (a one-segment ray whose top was lowered: rule 5)
        instead of five scattered ones.
    recf : the same memory as ``rec`` viewed as float32 (values are copied through it,
        compared as bits through ``rec``). jnb, jfb : int32 views of ``jn`` / ``jf``.
    f_base : int
        Far event ``nf`` writes its ray at ``f_ray[nf - f_base]`` (a scratch the caller
        turns into runs), its value and id at ``f_val[nf]`` / ``f_id[nf]``.
    """
    n_moves = ptr.size - 1
    nf = cnt[0]
    ng = cnt[1]
    ns = cnt[2]
    for k in range(state[0], n_moves):
        e0 = ptr[k] if state[1] < ptr[k] else state[1]
        for e in range(e0, ptr[k + 1]):
            r = rays[e]
            a = seg_ptr[e]
            c = seg_ptr[e + 1] - a
            if c == 1 and rec[r, 0] == jnb[a] and rec[r, 2] == jni[a]:
                # the common case: far-only (or no change) on a one-segment ray
                if rec[r, 1] != jfb[a] or rec[r, 3] != jfi[a]:
                    rec[r, 1] = jfb[a]
                    rec[r, 3] = jfi[a]
                    f_ray[nf - f_base] = r
                    f_val[nf] = jf[a]
                    f_id[nf] = jfi[a]
                    nf += 1
                continue
            # rare: bring the mirror's ray up to date, then compare against it
            if rec[r, 0] != NOT_SIMPLE:
                M[0][r] = 1
                M[1][r] = recf[r, 0]
                M[2][r] = recf[r, 1]
                M[3][r] = rec[r, 2]
                M[4][r] = rec[r, 3]
            general = c != M[0][r]
            if not general:
                if c == 0:
                    continue
                for i in range(c):
                    n0, f0, ni0, fi0 = ds.get_seg(M, r, i)
                    if jn[a + i] != n0 or jni[a + i] != ni0:
                        general = True
                        break
                    if i < c - 1 and (jf[a + i] != f0 or jfi[a + i] != fi0):
                        general = True
                        break
            if not general:
                last = a + c - 1
                if c == 1:
                    # the near face differs only in its bits (-0.0 / 0.0): a far-only edit
                    if jf[last] == M[2][r] and jfi[last] == M[4][r]:
                        continue
                    M[2][r] = jf[last]
                    M[4][r] = jfi[last]
                else:
                    p = M[5][r] + c - 2
                    if jf[last] == M[8][p] and jfi[last] == M[10][p]:
                        continue
                    M[8][p] = jf[last]
                    M[10][p] = jfi[last]
                f_ray[nf - f_base] = r
                f_val[nf] = jf[last]
                f_id[nf] = jfi[last]
                nf += 1
            else:
                if not ds.write_ray(M, r, jn[a:a + c], jf[a:a + c], jni[a:a + c], jfi[a:a + c], c):
                    state[0] = k
                    state[1] = e
                    cnt[0] = nf
                    cnt[1] = ng
                    cnt[2] = ns
                    return POOL_FULL
                g_ray[ng] = r
                g_count[ng] = c
                for i in range(c):
                    g_near[ns + i] = jn[a + i]
                    g_far[ns + i] = jf[a + i]
                    g_nid[ns + i] = jni[a + i]
                    g_fid[ns + i] = jfi[a + i]
                ng += 1
                ns += c
            if M[0][r] == 1:
                recf[r, 0] = M[1][r]
                recf[r, 1] = M[2][r]
                rec[r, 2] = M[3][r]
                rec[r, 3] = M[4][r]
            else:
                rec[r, 0] = NOT_SIMPLE
        blk_f[k] = nf
        blk_g[k] = ng
        blk_s[k] = ns
    cnt[0] = nf
    cnt[1] = ng
    cnt[2] = ns
    state[0] = n_moves
    return DONE


@nb.njit(cache=True)
def sync_mirror(rec, recf, S):
    """Write the one-segment rays cached in ``rec`` into store ``S`` (the mirror)."""
    for r in range(S[0].size):
        if rec[r, 0] != NOT_SIMPLE:
            S[0][r] = 1
            S[1][r] = recf[r, 0]
            S[2][r] = recf[r, 1]
            S[3][r] = rec[r, 2]
            S[4][r] = rec[r, 3]


@nb.njit(cache=True)
def replay_far_only(count, far, far_id, xstart, pool_far, pool_far_id, f_ptr, rn_ptr, rs, rl, f_val,
                    f_id, b_id, b0, b1):
    """Apply the far-only events of blocks ``b0 <= b < b1`` (rule 5: set the last FarZ and
    its id: the block's ``b_id`` when it is one for all its events, else ``f_id``).

    The arrays are the store's own fields passed one by one: this loop runs ~6x faster
    than the same work inside :func:`replay_blocks`. Returns ``-1 - b`` for the first block
    with an event that edits an empty ray (a corrupt trace), else ``b1``.
    """
    for b in range(b0, b1):
        u = b_id[b]
        q = f_ptr[b]
        for j in range(rn_ptr[b], rn_ptr[b + 1]):
            r = rs[j]
            for _ in range(rl[j]):
                k = count[r] - 1
                i = u if u >= 0 else f_id[q]
                if k == 0:
                    far[r] = f_val[q]
                    far_id[r] = i
                elif k > 0:
                    p = xstart[r] + k - 1
                    pool_far[p] = f_val[q]
                    pool_far_id[p] = i
                else:
                    return -1 - b
                q += 1
                r += 1
    return b1


_NAN_BITS = np.int32(0x7FC00000)


@nb.njit(cache=True)
def tops_of_store(count, far, far_id, xstart, pool_far, pool_far_id, top, top_id):
    """Every ray's top (last FarZ; NaN where empty) and its face id (0 where empty), from a
    store's fields (a keyframe's or a grid's)."""
    for r in range(count.size):
        k = count[r] - 1
        if k == 0:
            top[r] = far[r]
            top_id[r] = far_id[r]
        elif k > 0:
            p = xstart[r] + k - 1
            top[r] = pool_far[p]
            top_id[r] = pool_far_id[p]
        else:
            top[r] = np.nan
            top_id[r] = 0


@nb.njit(cache=True, inline="always")
def _far_tops(top, top_id, b, f_ptr, rn_ptr, rs, rl, f_val, f_id, b_id):
    """Block ``b``'s far events onto the visible surface."""
    u = b_id[b]
    q = f_ptr[b]
    for j in range(rn_ptr[b], rn_ptr[b + 1]):
        r = rs[j]
        for _ in range(rl[j]):
            top[r] = f_val[q]
            top_id[r] = u if u >= 0 else f_id[q]
            q += 1
            r += 1


@nb.njit(cache=True)
def apply_tops(top, top_id, b0, b1, f_ptr, rn_ptr, rs, rl, f_val, f_id, b_id, g_ptr, gs_ptr, g_ray,
               g_count, g_far, g_fid):
    """The visible surface (rule 6) carried from block ``b0`` to ``b1`` by a z-trace's events:
    per block, the far-only edits, then each general rewrite's new top (its last FarZ, NaN
    if it emptied the ray), in the order of :func:`replay_blocks`."""
    for b in range(b0, b1):
        _far_tops(top, top_id, b, f_ptr, rn_ptr, rs, rl, f_val, f_id, b_id)
        s = gs_ptr[b]
        for q in range(g_ptr[b], g_ptr[b + 1]):
            c = g_count[q]
            r = g_ray[q]
            if c == 0:
                top[r] = np.nan
                top_id[r] = 0
            else:
                top[r] = g_far[s + c - 1]
                top_id[r] = g_fid[s + c - 1]
            s += c


@nb.njit(cache=True, inline="always")
def _drop(old, new, bottom):
    """How far a ray's visible surface went down (mm): from ``old`` (NaN: nothing there)
    to ``new`` (NaN: emptied, so down to ``bottom``)."""
    a = 0.0 if np.isnan(old) else np.float64(old)
    b = bottom if np.isnan(new) else np.float64(new)
    return a - b


@nb.njit(cache=True)
def surface_drops(top, bottom, f_ptr, rn_ptr, rs, rl, f_val, g_ptr, gs_ptr, g_ray, g_count, g_far, out):
    """Per block of a z-trace, the summed drop of the visible surface over its rays (mm;
    times the cell area, the volume taken from the top). ``top`` (n_rays,) float32 holds
    the tops before block 0 and is carried to the end; ``bottom`` (n_rays,) float64 is
    each ray's lowest material (where an emptied ray's surface falls to); ``out`` float64
    (n_blocks,). Far events apply before general rewrites, as in :func:`apply_tops`."""
    for b in range(out.size):
        acc = 0.0
        q = f_ptr[b]
        for j in range(rn_ptr[b], rn_ptr[b + 1]):
            r = rs[j]
            for _ in range(rl[j]):
                acc += _drop(top[r], f_val[q], bottom[r])
                top[r] = f_val[q]
                q += 1
                r += 1
        s = gs_ptr[b]
        for q in range(g_ptr[b], g_ptr[b + 1]):
            r = g_ray[q]
            c = g_count[q]
            new = np.float32(np.nan) if c == 0 else g_far[s + c - 1]
            s += c
            acc += _drop(top[r], new, bottom[r])
            top[r] = new
        out[b] = acc
