"""The exact linear batch cut (:func:`cut_linear_batch`): a straight tip move at a time,
the rays within reach worked out per row, the tool's intervals from the row kernels of
:mod:`.shapes`, one-segment rays cut in place, the change log and the trace written as the
rays change.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim.sweep_kernels.batch import (DONE, REACH_PAD, STOP_CHANGES, STOP_POOL, STOP_TRACE, _save,
                                     _stadium_span, overlap_length)
from sim.sweep_kernels.log import _log_change, finish_move
from sim.sweep_kernels.shapes import (CODE_BALL, CODE_BULL, CODE_CONE, CODE_FLAT, RIM, _hstar, _rows_any,
                                      _rows_ball, _rows_bull, _rows_cone, _rows_flat)
from sim.sweep_kernels.trace_sink import (TS_BLK0, TS_NEED_F, TS_NEED_GEN, TS_NEXT_DUE, TS_NF, TS_NG, TS_NGL,
                                          TS_NR, TS_OPEN, _close_block, _close_far_only, _close_traced_move,
                                          _tflush, _trace_far, _trace_general)


@nb.njit(cache=True, inline="always")
def _behind_cut(code, R, rc, cot, m, sin_t):
    """``(skip, a_cut)``: on a move chained to the previous one, the rays with
    ``a <= a_cut`` (mm along the move from its start) have the lowest point of the sweep
    at the start, where the previous move's end pose already cut them (see
    :func:`cut_linear_batch`); ``skip`` False when no such half-plane is known.

    The lowest point lies at ``s* <= a`` on a level or climbing move for every convex
    tool but the flat one descending. Descending: the ball at ``s* <= a + R |sin t|``
    (the capsule); the bull-nose, a ball of radius ``rc`` about each point of its flat
    of radius ``R - rc``, at ``s* <= a + (R - rc) + rc |sin t|``; the cone, at
    ``s* = a + |e| |g| / sqrt(1 - g^2)`` with ``g = m / cot`` and ``|e| <= R``, or at the
    end of the move when ``g <= -1``. A spare 1e-9 mm keeps rays on the line cut.
    """
    if code == CODE_BALL:
        return True, -R * abs(sin_t) - 1e-9
    if m >= 0.0:
        return True, -1e-9
    if code == CODE_BULL:
        return True, -(R - rc) - rc * abs(sin_t) - 1e-9
    if code == CODE_CONE:
        g = -m / cot
        if g < 1.0:
            return True, -R * g / math.sqrt(1.0 - g * g) - 1e-9
    return False, 0.0


@nb.njit(cache=True, nogil=True)
def cut_linear_batch(S, gx0, gy0, sp, nu, nv, P0, P1, seg_move, seg_id, tp, eps, probe,
                     record, removed, B, state, trace, T, ts, top_bound, band0, band1):
    """Sweep the body ``tp`` along each straight tip move ``P0[k] -> P1[k]`` and cut it.

    S: store tuple; grid rays at ``(gx0 + i*sp, gy0 + j*sp)``, ``nu x nv`` of them.
    P0, P1: float64 (n, 3) tip positions, mm. seg_move: int64 (n,) index of the output
    move each segment belongs to; seg_id: int32 (n,) face id it writes.
    probe: measure the overlap instead of cutting. record: log changed rays (one entry
    per move and distinct ray, with its depth of cut; see :func:`finish_move`).
    removed: float64 (n_moves,) accumulates removed (or overlapping) *length* (mm).
    B: the log buffers (see :func:`finish_move`); state: int64 (STATE_SIZE,) where to
    resume. Returns DONE, STOP_POOL (grow the pool, call again) or STOP_CHANGES (grow
    B[0..1] when ``state[3] + state[4]`` fills them, the scratch B[3..4] when ``state[4]``
    does; call again); the state says where it stopped.
    A move's entries are closed when the next move starts (segments of one move are
    consecutive).
    trace: write z-trace events into ``T`` as the rays change (state ``ts``; see
    :func:`finish_trace_move`); also returns STOP_TRACE (grow ``T`` as ``ts`` says, call
    again) and TRACE_KEYFRAME (a keyframe fell due after move ``ts[TS_KEY_MOVE]``: take it
    from the model as it is now, call again).
    top_bound: no material anywhere lies above this (mm; ``inf`` when unknown).
    band0, band1: touch only rows ``band0 <= j < band1`` (a band of :mod:`sim.bands`;
    the kernel holds no lock, so bands of one store run on threads at the same time).

    A move that starts exactly where the batch's previous move ended skips the rays
    whose lowest point of the sweep lies at the start (behind it): the previous move's
    end pose was already cut there, as deep, and its flutes reached above ``top_bound``,
    so nothing is left for this move on those rays. For a level or climbing flat end mill
    and for a ball that is every ray with ``a <= -R |sin(slope)|`` (``a`` along the move);
    for the other shapes see :func:`_behind_cut` (the bull-nose and cone row kernels
    also leave out, on rows along the move, the rays past that half-plane whose lowest
    point is the start).

    Rays within reach, per row: those within ``Rc`` (+ ``REACH_PAD``) of the move's XY
    segment (its stadium; :func:`_stadium_span`); none in a row where the tool's lowest
    possible point, ``min z + h_off + h*(row's distance from the segment)``, lies above
    ``top_bound``, nor anywhere for a move wholly above it.

    Per move, the intervals of all rays within reach are computed first (one call,
    vectorised for flat and ball), then compared with the stored material; one-segment
    rays (the common case) are cut in place here, everything else goes through
    :func:`sim.dexel_store.subtract_interval`.
    """
    cnt = S[0]
    near = S[1]
    far = S[2]
    near_id = S[3]
    far_id = S[4]
    first = S[5]
    pool_far = S[8]
    code = int(tp[0])
    R = tp[1]
    h_off = tp[4]
    h_top = tp[5]
    Rc = tp[6]
    n = P0.shape[0]
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
    cap = 4096
    buf_lo = np.empty(cap, np.float32)
    buf_hi = np.empty(cap, np.float32)
    flag = np.empty(cap, np.bool_)
    row_ia = np.empty(nv + 1, np.int64)
    row_ilo = np.empty(nv + 1, np.int64)
    row_off = np.empty(nv + 2, np.int64)
    for k in range(k0, n):
        if trace and ts[TS_OPEN] >= 0 and ts[TS_OPEN] != seg_move[k]:
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
        if (record and k > 0 and seg_move[k] != seg_move[k - 1]
                and not (k == k0 and j_resume >= 0) and mc > 0):
            nout = finish_move(S, B, seg_move[k - 1], nout, mc)
            mc = 0
        if trace:
            ts[TS_OPEN] = seg_move[k]
        # a move of several segments (arc chords) may change a ray more than once
        multi = (k > 0 and seg_move[k - 1] == seg_move[k]) or (k + 1 < n and seg_move[k + 1] == seg_move[k])
        key = 2 * (ts[TS_BLK0] + seg_move[k])
        x0 = P0[k, 0]
        y0 = P0[k, 1]
        z0 = P0[k, 2]
        dx = P1[k, 0] - x0
        dy = P1[k, 1] - y0
        dz = P1[k, 2] - z0
        ell = math.sqrt(dx * dx + dy * dy)
        if ell > 1e-9:
            ux = dx / ell
            uy = dy / ell
            m = dz / ell
            sin_t = dz / math.sqrt(ell * ell + dz * dz)
        else:
            ell = 0.0
            ux = 1.0
            uy = 0.0
            m = 0.0
            sin_t = 0.0
        xmin = min(x0, x0 + dx)
        xmax = max(x0, x0 + dx)
        ymin = min(y0, y0 + dy)
        ymax = max(y0, y0 + dy)
        # the reach widened by the rim margin the shapes allow (shapes.RIM), so that a ray
        # on the rim is looked at whatever the rounding of its row's range
        reach = Rc + RIM
        jlo = max(band0, int(math.ceil((ymin - reach - gy0) / sp)))
        jhi = min(nv, band1) - 1
        jhi = min(jhi, int(math.floor((ymax + reach - gy0) / sp)))
        if jhi < jlo:
            continue
        skip_behind = False
        a_cut = 0.0
        if (not probe and k > 0 and ell > 0.0 and P1[k - 1, 0] == x0 and P1[k - 1, 1] == y0
                and P1[k - 1, 2] == z0 and min(P0[k - 1, 2], z0) + h_top >= top_bound):
            skip_behind, a_cut = _behind_cut(code, R, tp[2], tp[3], m, sin_t)
        # the tool's lowest point in a row at distance dym from the path: at or above
        # zmin + h_off + h*(dym); a row where that clears every top cannot change
        zmin = min(z0, z0 + dz) + h_off
        if not probe and zmin >= top_bound + 1e-9:
            continue
        # only when the tool's rim clears the top may a row do so (one test per move)
        rows_clear = zmin + _hstar(code, R, tp[2], tp[3], Rc) >= top_bound + 1e-9
        diagonal = dx != 0.0 and dy != 0.0
        # each row's reach: within Rc of the move's bounding box, then (diagonal moves)
        # within Rc of the segment: the stadium, a spare ray either side
        nrows = jhi - jlo + 1
        row_off[0] = 0
        for jj in range(nrows):
            y = gy0 + (jlo + jj) * sp
            dym = max(ymin - y, y - ymax, 0.0)
            ilo = 0
            ihi = -1
            clear = rows_clear and zmin + _hstar(code, R, tp[2], tp[3], dym) >= top_bound + 1e-9
            if dym <= reach and not clear:
                w = math.sqrt(max(Rc * Rc - dym * dym, 0.0)) + RIM
                ilo = max(0, int(math.ceil((xmin - w - gx0) / sp)))
                ihi = min(nu - 1, int(math.floor((xmax + w - gx0) / sp)))
                if skip_behind:
                    # keep rays with a = ux (x - x0) + uy (y - y0) > a_cut (a spare ray is harmless)
                    if ux > 1e-12:
                        ilo = max(ilo, int(math.floor((x0 + (a_cut - uy * (y - y0)) / ux - gx0) / sp)))
                    elif ux < -1e-12:
                        ihi = min(ihi, int(math.ceil((x0 + (a_cut - uy * (y - y0)) / ux - gx0) / sp)))
                    elif uy * (y - y0) < a_cut - 1e-9:
                        ihi = ilo - 1
            row_ia[jj] = ilo
            if diagonal and ilo <= ihi:
                xlo, xhi = _stadium_span(x0, y0, dx, dy, Rc + REACH_PAD, y)
                if xlo <= xhi:
                    ilo = max(ilo, int(math.ceil((xlo - gx0) / sp)))
                    ihi = min(ihi, int(math.floor((xhi - gx0) / sp)))
                else:
                    ihi = ilo - 1
            row_ilo[jj] = ilo
            row_off[jj + 1] = row_off[jj] + max(ihi - ilo + 1, 0)
        total = row_off[nrows]
        # room for every ray within reach to change, checked once per segment (not per ray)
        if trace and (nf + total > t_val.size or nr + total + 1 > t_rs.size or ngl + total > t_gen.size):
            ts[TS_NEED_F] = nf + total
            ts[TS_NEED_GEN] = ngl + total
            _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
            if k == k0 and j_resume >= 0:
                _save(state, k, j_resume, i_resume, nout, mc)
            else:
                _save(state, k, -1, -1, nout, mc)
            return STOP_TRACE
        if total > buf_lo.size:
            cap = max(total, 2 * buf_lo.size)
            buf_lo = np.empty(cap, np.float32)
            buf_hi = np.empty(cap, np.float32)
            flag = np.empty(cap, np.bool_)
        rx0 = gx0 - x0
        ry0 = gy0 - y0
        if ell > 0.0 and code == CODE_BALL:
            _rows_ball(R, Rc, h_off, h_top, z0, m, sin_t, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                       row_ia, row_ilo, row_off, cnt, near, far, buf_lo, buf_hi, flag)
        elif ell > 0.0 and code == CODE_FLAT:
            _rows_flat(Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                       row_ia, row_ilo, row_off, cnt, near, far, buf_lo, buf_hi, flag)
        elif ell > 0.0 and code == CODE_BULL:
            _rows_bull(R, tp[2], Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                       row_ia, row_ilo, row_off, cnt, near, far, buf_lo, buf_hi, flag, skip_behind)
        elif ell > 0.0 and code == CODE_CONE:
            _rows_cone(tp[3], Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                       row_ia, row_ilo, row_off, cnt, near, far, buf_lo, buf_hi, flag, skip_behind)
        else:
            _rows_any(tp, x0, y0, z0, dz, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
                      row_ilo, row_off, cnt, near, far, buf_lo, buf_hi, flag)
        resuming = k == k0 and j_resume >= 0
        mv = seg_move[k]
        fid = seg_id[k]
        for jj in range(nrows):
            j = jlo + jj
            if resuming and j < j_resume:
                continue
            o = row_off[jj]
            i0 = row_ilo[jj]
            for q in range(row_off[jj + 1] - o):
                if not flag[o + q]:
                    continue
                i = i0 + q
                if resuming and j == j_resume and i < i_resume:
                    continue
                r = j * nu + i
                c = cnt[r]
                lo = np.float64(buf_lo[o + q])
                hi = np.float64(buf_hi[o + q])
                n_ = np.float64(near[r])
                f_ = np.float64(far[r])
                if probe:
                    removed[mv] += overlap_length(S, r, lo, hi)
                    continue
                if record and (nout + mc >= out_ray.size or mc >= s_top.size):
                    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                    _save(state, k, j, i, nout, mc)
                    return STOP_CHANGES
                top_before = f_
                got = -2.0
                far_only = False
                if c == 1:
                    keep_low = lo - n_ > eps
                    keep_high = f_ - hi > eps
                    if not keep_high:
                        if keep_low:
                            far[r] = np.float32(lo)
                            far_id[r] = fid
                            got = f_ - lo
                            far_only = True
                        else:
                            cnt[r] = 0
                            got = f_ - n_
                    elif not keep_low:
                        near[r] = np.float32(hi)
                        near_id[r] = fid
                        got = hi - n_
                if got == -2.0:  # a split or a ray of several segments
                    if c > 1:
                        top_before = ds.ray_top(S, r)
                    got = ds.subtract_interval(S, r, lo, hi, fid, eps)
                    if got == ds.POOL_FULL:
                        _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
                        _save(state, k, j, i, nout, mc)
                        return STOP_POOL
                if got > 0.0:
                    removed[mv] += got
                    if trace:
                        if far_only and not multi:  # the common case: each ray once
                            if runl > 0 and r == run0 + runl:
                                runl += 1
                            else:
                                if runl > 0:
                                    t_rs[nr] = run0
                                    t_rl[nr] = runl
                                    nr += 1
                                run0 = r
                                runl = 1
                            t_val[nf] = far[r]
                            nf += 1
                        elif far_only:
                            nf, nr, run0, runl = _trace_far(t_rs, t_rl, t_val, t_mark, t_slot, key, True, r,
                                                            far[r], nf, nr, run0, runl)
                        elif not multi:  # changed once by this move: nothing to merge
                            t_gen[ngl] = r
                            ngl += 1
                        else:
                            ngl = _trace_general(t_mark, t_gen, key, r, ngl)
                    if record:
                        # the one-segment cases leave the top at ``f_ - got`` or keep it
                        dep = got
                        c2 = cnt[r]
                        if c > 1 and c2 > 0:
                            t2 = far[r] if c2 == 1 else pool_far[first[r] + c2 - 2]
                            if top_before - np.float64(t2) > 0.0:
                                dep = top_before - np.float64(t2)
                        _log_change(B, nout, mc, r, top_before, got, dep)
                        mc += 1
    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
    if trace and not _close_block(S, T, ts, t_bf, t_bg, t_bs, t_br):
        _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
        _save(state, n, -1, -1, nout, mc)
        return STOP_TRACE
    if record and mc > 0:
        nout = finish_move(S, B, seg_move[n - 1], nout, mc)
        mc = 0
    _tflush(ts, t_rs, t_rl, nf, ngl, nr, run0, runl)
    _save(state, n, -1, -1, nout, mc)
    return DONE
