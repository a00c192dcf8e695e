"""Instances of motion: any frame, any tool axis, any profile of revolution (a polyline of
frusta, Huang & Oliver eq. 3-5). Each frustum piece meets a line in one interval found
from one quadratic; the pieces' intervals are merged per ray (:func:`pose_intervals`), and
:func:`cut_poses` cuts (or probes) one pose at a time, like the linear batch cut.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim.sweep_kernels.batch import (DONE, REACH_PAD, STOP_CHANGES, STOP_POOL, STOP_TRACE, _save,
                                     _stadium_span, overlap_length)
from sim.sweep_kernels.log import _depth_after, _log_change, finish_move
from sim.sweep_kernels.trace_sink import (TS_BLK0, TS_NEXT_DUE, TS_NF, TS_NG, TS_NGL, TS_NR, TS_OPEN,
                                          _close_block, _close_far_only, _close_traced_move, _tflush,
                                          _trace_far, _trace_general)


@nb.njit(cache=True)
def _piece_interval(prof, k, h0, az, wx2wy2, out):
    """Interval of sigma (= s - tip_s) where the line is inside frustum piece ``k``.

    The line's axial height is ``h0 + sigma*az`` and its squared distance from the axis
    ``wx2wy2 + sigma^2 - h^2``. Writes ``out[0], out[1]``; returns False when empty.
    """
    hk = prof[k, 0]
    hk1 = prof[k + 1, 0]
    if hk1 - hk <= 0.0:
        return False
    rk = prof[k, 1]
    rk1 = prof[k + 1, 1]
    beta = (rk1 - rk) / (hk1 - hk)
    alpha = rk - beta * hk
    inf = np.inf
    # slab hk <= h0 + sigma*az <= hk1
    if abs(az) > 1e-12:
        sa = (hk - h0) / az
        sb = (hk1 - h0) / az
        if sa > sb:
            sa, sb = sb, sa
    else:
        if h0 < hk or h0 > hk1:
            return False
        sa = -inf
        sb = inf
    # radius along the line: c0 + c1*sigma
    c0 = alpha + beta * h0
    c1 = beta * az
    A2 = (1.0 - az * az) - c1 * c1
    B = -2.0 * h0 * az - 2.0 * c0 * c1
    C = wx2wy2 - h0 * h0 - c0 * c0
    lo = -inf
    hi = inf
    if abs(A2) < 1e-12:
        if abs(B) < 1e-12:
            if C > 0.0:
                return False
        elif B > 0.0:
            hi = -C / B
        else:
            lo = -C / B
    else:
        disc = B * B - 4.0 * A2 * C
        if A2 > 0.0:
            if disc < 0.0:
                return False
            sq = math.sqrt(disc)
            lo = (-B - sq) / (2.0 * A2)
            hi = (-B + sq) / (2.0 * A2)
        elif disc >= 0.0:
            sq = math.sqrt(disc)
            r1 = (-B + sq) / (2.0 * A2)
            r2 = (-B - sq) / (2.0 * A2)  # r1 <= r2 since A2 < 0
            left = min(sb, r1) >= sa   # (-inf, r1] meets the slab
            right = max(sa, r2) <= sb  # [r2, inf) meets the slab
            if left and right:
                lo = -inf
                hi = inf
            elif left:
                hi = r1
            elif right:
                lo = r2
            else:
                return False
    if lo < sa:
        lo = sa
    if hi > sb:
        hi = sb
    if hi <= lo:
        return False
    out[0] = lo
    out[1] = hi
    return True


@nb.njit(cache=True, inline="always")
def _level_interval(prof, tip, h0, wx2wy2, out):
    """:func:`pose_intervals` of a ray square to the tool's axis (a vertical tool on the
    X and Y grids of a tri-dexel model): the ray stays at axial height ``h0``, so it
    crosses the one disc of the body at that height, of the largest radius the profile
    pieces through ``h0`` give there (each piece's interval is centred on the axis: their
    union is the widest). Binary search instead of every piece."""
    k1 = prof.shape[0] - 1
    if h0 < prof[0, 0] or h0 > prof[k1, 0]:
        return 0
    lo = 0
    hi = k1
    while hi - lo > 1:  # prof[lo, 0] <= h0 <= prof[hi, 0]
        mid = (lo + hi) // 2
        if prof[mid, 0] <= h0:
            lo = mid
        else:
            hi = mid
    # the pieces through h0: lo's, and those meeting at h0 when it is a vertex height
    while lo > 0 and prof[lo, 0] == h0:
        lo -= 1
    r2max = -1.0
    for k in range(lo, k1):
        hk = prof[k, 0]
        hk1 = prof[k + 1, 0]
        if hk > h0:
            break
        if hk1 - hk <= 0.0 or h0 > hk1:
            continue
        beta = (prof[k + 1, 1] - prof[k, 1]) / (hk1 - hk)
        c0 = (prof[k, 1] - beta * hk) + beta * h0
        r2 = c0 * c0 - (wx2wy2 - h0 * h0)
        if r2 > r2max:
            r2max = r2
    if r2max <= 0.0:  # a touch: no length inside, as the general pieces give
        return 0
    half = math.sqrt(r2max)
    out[0, 0] = tip[2] - half
    out[0, 1] = tip[2] + half
    return 1


#: mm: a profile piece is skipped for a ray only this far outside its radius, so that
#: the rounding of the piece's own solution can never have made a sliver of it
PIECE_SKIP_MARGIN = 1e-6
#: below this sine of the angle between the tool axis and the rays no piece is skipped
#: (the distance between two nearly parallel lines is ill-conditioned)
PIECE_SKIP_SIN = 1e-6


@nb.njit(cache=True)
def pose_intervals(prof, tip, axis, px, py, out, buf):
    """Intervals of a ray inside one tool pose, in frame-local coordinates.

    prof: float64 (k, 2) profile (h, r); tip: (3,) local (u, v, s) of the tip; axis: (3,)
    unit axis in local coordinates; the ray is ``(px, py, s)``. Writes merged, sorted
    intervals of ``s`` into ``out`` (float64 (k, 2)) and returns how many. ``buf`` is
    float64 (2,) scratch.

    A piece whose radius stays under the ray's distance from the tool's axis line (less
    :data:`PIECE_SKIP_MARGIN`) cannot hold the ray and is not solved: on a ball's many
    pieces most rays pass beside all but a few.
    """
    wx = px - tip[0]
    wy = py - tip[1]
    h0 = wx * axis[0] + wy * axis[1]
    wx2wy2 = wx * wx + wy * wy
    az = axis[2]
    if az == 0.0:
        return _level_interval(prof, tip, h0, wx2wy2, out)
    # the ray (along s) and the axis line are skew: their distance is |w . (s x axis)| /
    # |s x axis|; near parallel (the ray along the axis) nothing is skipped
    sxy = math.sqrt(axis[0] * axis[0] + axis[1] * axis[1])
    reach = -1.0
    if sxy > PIECE_SKIP_SIN:
        reach = abs(wy * axis[0] - wx * axis[1]) / sxy - PIECE_SKIP_MARGIN
    m = 0
    for k in range(prof.shape[0] - 1):
        if prof[k, 1] < reach and prof[k + 1, 1] < reach:
            continue
        if _piece_interval(prof, k, h0, az, wx2wy2, buf):
            lo = buf[0] + tip[2]
            hi = buf[1] + tip[2]
            # insert sorted by lo
            q = m
            while q > 0 and out[q - 1, 0] > lo:
                out[q, 0] = out[q - 1, 0]
                out[q, 1] = out[q - 1, 1]
                q -= 1
            out[q, 0] = lo
            out[q, 1] = hi
            m += 1
    if m <= 1:
        return m
    w = 0
    for q in range(1, m):
        if out[q, 0] <= out[w, 1] + 1e-9:
            if out[q, 1] > out[w, 1]:
                out[w, 1] = out[q, 1]
        else:
            w += 1
            out[w, 0] = out[q, 0]
            out[w, 1] = out[q, 1]
    return w + 1


@nb.njit(cache=True, nogil=True)
def cut_poses(S, sp, nu, nv, tips, axes, pose_move, pose_id, prof, rmax, eps, probe, record,
              removed, B, state, trace, T, ts, band0, band1):
    """Cut (or probe) one tool instance per row of ``tips``/``axes`` (frame-local, mm).

    Rays are at local ``(i*sp, j*sp)``. Other arguments and the return value as for
    :func:`cut_linear_batch`; ``prof`` is the body profile (k, 2) of (h, r) and ``rmax``
    its largest radius.
    """
    n = tips.shape[0]
    top_h = prof[prof.shape[0] - 1, 0]
    bot_h = prof[0, 0]
    ivs = np.empty((prof.shape[0], 2))
    buf = np.empty(2)
    k0 = state[0]
    j_resume = state[1]
    i_resume = state[2]
    nout = state[3]
    mc = state[4]
    out_ray = B[0]
    s_top = B[3]
    t_rs = T[0]
    t_val = T[1]
    t_rl = T[2]
    t_mark = T[12]
    t_slot = T[13]
    t_gen = T[14]
    t_bf = T[9]
    t_bg = T[10]
    t_bs = T[11]
    t_br = T[15]
    nf = ts[TS_NF]
    ngl = ts[TS_NGL]
    nr = ts[TS_NR]
    run0 = 0
    runl = 0
    for k in range(k0, n):
        if trace and ts[TS_OPEN] >= 0 and ts[TS_OPEN] != pose_move[k]:
            if runl > 0:  # the open run of far rays ends with its move
                t_rs[nr] = run0
                t_rl[nr] = runl
                nr += 1
                runl = 0
            if ngl == 0 and not (record and mc > 0) and nf + ts[TS_NG] < ts[TS_NEXT_DUE]:
                _close_far_only(ts, t_bf, t_bg, t_bs, t_br, nf, nr)
            else:
                st, nout, mc, nf, ngl, nr = _close_traced_move(S, T, B, ts, state, t_bf, t_bg, t_bs, t_br,
                                                               record, k, nout, mc, nf, ngl, nr)
                if st != DONE:
                    return st
        if (record and k > 0 and pose_move[k] != pose_move[k - 1]
                and not (k == k0 and j_resume >= 0) and mc > 0):
            nout = finish_move(S, B, pose_move[k - 1], nout, mc)
            mc = 0
        if trace:
            ts[TS_OPEN] = pose_move[k]
        key = 2 * (ts[TS_BLK0] + pose_move[k])
        tip = tips[k]
        ax = axes[k]
        ua = tip[0] + bot_h * ax[0]
        ub = tip[0] + top_h * ax[0]
        va = tip[1] + bot_h * ax[1]
        vb = tip[1] + top_h * ax[1]
        ilo = max(0, int(math.ceil((min(ua, ub) - rmax) / sp)))
        ihi = min(nu - 1, int(math.floor((max(ua, ub) + rmax) / sp)))
        jlo = max(band0, int(math.ceil((min(va, vb) - rmax) / sp)))
        jhi = min(min(nv, band1) - 1, int(math.floor((max(va, vb) + rmax) / sp)))
        resuming = k == k0 and j_resume >= 0
        if resuming:
            jlo = j_resume
        mv = pose_move[k]
        fid = pose_id[k]
        for j in range(jlo, jhi + 1):
            # the body lies within rmax of its axis: only the rays within rmax of the
            # axis' footprint (a stadium), a spare ray either side
            xlo, xhi = _stadium_span(ua, va, ub - ua, vb - va, rmax + REACH_PAD, j * sp)
            if xlo > xhi:
                continue
            i_start = max(ilo, int(math.ceil(xlo / sp)))
            i_end = min(ihi, int(math.floor(xhi / sp)))
            if resuming and j == j_resume and i_resume > i_start:
                i_start = i_resume
            for i in range(i_start, i_end + 1):
                r = j * nu + i
                if S[0][r] == 0:
                    continue
                m = pose_intervals(prof, tip, ax, i * sp, j * sp, ivs, buf)
                if m == 0:
                    continue
                if record and (nout + mc >= out_ray.size or mc >= s_top.size):
                    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                    _save(state, k, j, i, nout, mc)
                    return STOP_CHANGES
                if trace and (nf >= t_val.size or nr + 1 >= t_rs.size or ngl >= t_gen.size):
                    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                    _save(state, k, j, i, nout, mc)
                    return STOP_TRACE
                changed = False
                c_before = S[0][r]
                near_before = S[1][r]
                nid_before = S[3][r]
                top_before = ds.ray_top(S, r) if record else 0.0
                got_sum = 0.0
                for q in range(m):
                    lo = np.float64(np.float32(ivs[q, 0]))
                    hi = np.float64(np.float32(ivs[q, 1]))
                    if probe:
                        removed[mv] += overlap_length(S, r, lo, hi)
                        continue
                    got = ds.subtract_interval(S, r, lo, hi, fid, eps)
                    if got == ds.POOL_FULL:
                        if changed and trace:
                            ngl = _trace_general(t_mark, t_gen, key, r, ngl)
                        _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                        if changed and record:
                            _log_change(B, nout, mc, r, top_before, got_sum,
                                        _depth_after(S, r, top_before, got_sum))
                            mc += 1
                        _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                        _save(state, k, j, i, nout, mc)
                        return STOP_POOL
                    if got > 0.0:
                        removed[mv] += got
                        got_sum += got
                        changed = True
                if changed and trace:
                    if (c_before == 1 and S[0][r] == 1 and S[1][r] == near_before
                            and S[3][r] == nid_before):
                        nf, nr, run0, runl = _trace_far(t_rs, t_rl, t_val, t_mark, t_slot, key, True, r,
                                                        S[2][r], nf, nr, run0, runl)
                    else:
                        ngl = _trace_general(t_mark, t_gen, key, r, ngl)
                if changed and record:
                    _log_change(B, nout, mc, r, top_before, got_sum,
                                        _depth_after(S, r, top_before, got_sum))
                    mc += 1
    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
    if trace and not _close_block(S, T, ts, t_bf, t_bg, t_bs, t_br):
        _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
        _save(state, n, -1, -1, nout, mc)
        return STOP_TRACE
    if record and mc > 0:
        nout = finish_move(S, B, pose_move[n - 1], nout, mc)
        mc = 0
    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
    _save(state, n, -1, -1, nout, mc)
    return DONE
