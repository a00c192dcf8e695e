"""Compiled kernels: the interval a tool (or its swept volume) occupies on each dexel ray.

Two families:

* **Exact linear sweeps** (:func:`linear_interval`, :func:`cut_linear_batch`): rays along
  +Z (``Frame.top``), tool axis along +Z, a straight move of the tip from ``P0`` to ``P1``.
  The swept body meets a vertical ray at ``(x, y)`` in one interval ``[lo, hi]``:
  ``hi`` is the top of the body at an end of the part of the move where the ray is within
  the body's radius, and ``lo = min_s z(s) + h*(d(s))`` where ``s`` is the distance
  travelled in XY, ``d(s)`` the distance from the ray to the axis and ``h*`` the lowest
  height of the tool at that distance. ``z + h*(d)`` is convex in ``s`` for the convex
  tools, so the minimum is found in closed form (flat: an end of the range; ball: the
  capsule, ``s* = a - rho * dz / |P1 - P0|``; vbit/drill: the same with the cone slope)
  or, for the bull-nose torus, in closed form for level moves and otherwise from the
  distance to the axis at the lowest point, the one root of a quartic found by
  safeguarded Newton steps (:func:`_bull_depth`).

* **Instances of motion** (:func:`pose_intervals`, :func:`cut_poses`): any frame, any tool
  axis, any profile of revolution (a polyline of frusta, Huang & Oliver eq. 3-5). Each
  frustum piece meets a line in one interval found from one quadratic; the pieces'
  intervals are merged per ray.

All lengths mm. Per-ray arithmetic is float64; values written to the store are rounded
to float32 *before* comparing with the stored faces, so repeating a cut changes nothing.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim import dexel_store as ds

CODE_FLAT = 0
CODE_BALL = 1
CODE_BULL = 2
CODE_CONE = 3

#: layout of the float64 parameter vector of a body for the exact linear kernel
#: [code, R, rc, cot_half_angle, h_off (bottom above the tip), h_top, Rc (largest radius)]
N_PARAMS = 7

DONE = 0
STOP_POOL = 1
STOP_CHANGES = 2
STOP_TRACE = 4
TRACE_KEYFRAME = 5

#: mm added to a tool's reach when culling rays: a ray the kernels' rounding might put
#: inside the swept footprint is kept (a spare ray is harmless, a missed one a bug)
REACH_PAD = 1e-6

#: int64 ``state`` of a batch kernel: [k, j, i, entries closed, entries of the current move]
STATE_SIZE = 5

#: int64 ``ts`` of a traced batch (see :func:`finish_trace_move`): far events written,
#: general events written, their segments written, general rays of the open move, the open
#: move (-1: none), runs of far rays written, the batch's first block,
#: the event count at which a keyframe falls due, the move after which it fell due, what a
#: STOP_TRACE needs (far events and runs, general events, segments, general-ray scratch)
(TS_NF, TS_NG, TS_NS, TS_NGL, TS_OPEN, TS_NR, TS_BLK0, TS_NEXT_DUE, TS_KEY_MOVE,
 TS_NEED_F, TS_NEED_G, TS_NEED_S, TS_NEED_GEN) = range(13)
TRACE_STATE_SIZE = 13



@nb.njit(cache=True, inline="always")
def _hstar(code, R, rc, cot, d):
    """Lowest height of the tool above its tip at distance ``d`` from the axis."""
    if code == CODE_FLAT:
        return 0.0
    if code == CODE_BALL:
        q = R * R - d * d
        return R - math.sqrt(q if q > 0.0 else 0.0)
    if code == CODE_BULL:
        a0 = R - rc
        if d <= a0:
            return 0.0
        t = d - a0
        q = rc * rc - t * t
        return rc - math.sqrt(q if q > 0.0 else 0.0)
    return d * cot


@nb.njit(cache=True)
def linear_interval(tp, x0, y0, z0, dz, ell, ux, uy, rx, ry):
    """Interval ``(lo, hi)`` (mm) of a vertical ray within the body swept along one move.

    ``tp`` body parameters (see ``N_PARAMS``); the move starts at tip ``(x0, y0, z0)``,
    runs ``ell`` mm in XY along unit ``(ux, uy)`` and ``dz`` in Z; the ray is at
    ``(x0 + rx, y0 + ry)``. Returns ``lo > hi`` when the ray misses the body.
    """
    code = int(tp[0])
    R = tp[1]
    rc = tp[2]
    cot = tp[3]
    h_off = tp[4]
    h_top = tp[5]
    Rc = tp[6]
    a = rx * ux + ry * uy      # along the move
    e = -rx * uy + ry * ux     # across it
    q = Rc * Rc - e * e
    if q < 0.0:
        return 1.0, 0.0
    rho_c = math.sqrt(q)
    if ell <= 0.0:
        if a * a > q:
            return 1.0, 0.0
        z_lo = z0 if dz > 0.0 else z0 + dz
        z_hi = z0 + dz if dz > 0.0 else z0
        return z_lo + h_off + _hstar(code, R, rc, cot, math.sqrt(a * a + e * e)), z_hi + h_top
    s_lo = a - rho_c
    if s_lo < 0.0:
        s_lo = 0.0
    s_hi = a + rho_c
    if s_hi > ell:
        s_hi = ell
    if s_lo > s_hi:
        return 1.0, 0.0
    m = dz / ell
    za = z0 + m * s_lo
    zb = z0 + m * s_hi
    hi = (za if za > zb else zb) + h_top
    if code == CODE_FLAT:
        return (za if za < zb else zb) + h_off, hi
    if code == CODE_BALL or code == CODE_CONE:
        if code == CODE_BALL:
            rho = math.sqrt(max(R * R - e * e, 0.0))
            s = a - rho * dz / math.sqrt(ell * ell + dz * dz)
        else:
            # d/ds [m s + cot sqrt(e^2 + (a-s)^2)] = 0  ->  (a-s)/d = m / cot
            g = m / cot
            if g >= 1.0:  # climbing steeper than the cone: lowest at the start
                s = s_lo
            elif g <= -1.0:
                s = s_hi
            else:
                s = a - abs(e) * (g / math.sqrt(1.0 - g * g))
        if s < s_lo:
            s = s_lo
        elif s > s_hi:
            s = s_hi
        w = a - s
        return z0 + m * s + h_off + _hstar(code, R, rc, cot, math.sqrt(e * e + w * w)), hi
    # bull-nose: z(s) + h*(d(s)) is convex in s, lowest at s* = a - sign(m) sqrt(d^2 - e^2)
    # with d the root of a quartic in (max(d_e0, |e|), R), d_e0 the root on the path (see
    # _bull_depth); level moves pass closest at s = a
    w = 0.0
    ae = abs(e)
    if m != 0.0 and ae < R:
        k2 = 1.0 + m * m
        d_e0 = R - rc + rc * abs(m) / math.sqrt(k2)
        d = _bull_depth(R - rc, rc, R, k2, rc * rc * m * m, max(d_e0, ae), e * e, np.nan)
        w = math.sqrt(max((d - ae) * (d + ae), 0.0))
    s = a - w if m > 0.0 else a + w
    s = min(max(s, s_lo), s_hi)
    return z0 + m * s + h_off + _hstar(code, R, rc, cot, math.sqrt(e * e + (a - s) ** 2)), hi


@nb.njit(cache=True)
def linear_fill(tp, p0, dz, ell, ux, uy, xs, ys, lo, hi):
    """:func:`linear_interval` on every ray ``(xs[i], ys[j])``; writes hits into flat lo/hi."""
    nu = xs.size
    for j in range(ys.size):
        for i in range(nu):
            a, b = linear_interval(tp, p0[0], p0[1], p0[2], dz, ell, ux, uy, xs[i] - p0[0], ys[j] - p0[1])
            if a < b:
                lo[j * nu + i] = a
                hi[j * nu + i] = b


@nb.njit(cache=True)
def overlap_length(S, r, lo, hi):
    """Length (mm) of material of ray ``r`` inside ``[lo, hi]``."""
    total = 0.0
    for k in range(S[0][r]):
        n, f, nid, fid = ds.get_seg(S, r, k)
        a = max(np.float64(n), lo)
        b = min(np.float64(f), hi)
        if b > a:
            total += b - a
    return total


@nb.njit(cache=True, error_model="numpy", boundscheck=False)
def _rows_ball(R, Rc, h_off, h_top, z0, m, sin_t, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows, row_ia,
               row_ilo, row_off, cnt, near, far, lo, hi, flag):
    """Ball (its capsule) on the rays of one move, rows ``jlo .. jlo+nrows-1``.

    Row ``jj`` covers rays ``row_ilo[jj] ..`` (``row_off[jj+1] - row_off[jj]`` of them);
    the ray at ``i, j`` sits at ``(rx0 + i*sp, ry0 + j*sp)`` from the move's start. The
    row's arithmetic steps from ray ``row_ia[jj] <= row_ilo[jj]`` (the start of the
    row's bounding-box range), so a ray's value does not depend on how tightly the
    range was culled. Writes
    each ray's interval rounded to float32 into ``lo``/``hi`` (at ``row_off[jj] + q``)
    and flags the rays it may change: material there, and either several segments or the
    one segment overlapping. The inner loop is branch-free so that it vectorises; one
    call per move keeps call overhead off the rows.
    """
    R2 = R * R
    Rc2 = Rc * Rc
    two_sqrt = Rc < R
    for jj in range(nrows):
        i0 = row_ilo[jj]
        qa = i0 - row_ia[jj]
        o = row_off[jj]
        nq = row_off[jj + 1] - o
        rx = rx0 + row_ia[jj] * sp
        ry = ry0 + (jlo + jj) * sp
        a0 = rx * ux + ry * uy
        e0 = -rx * uy + ry * ux
        da = sp * ux
        de = -sp * uy
        base = (jlo + jj) * nu + i0
        # row views: plain unit-stride indexing is what lets LLVM vectorise the loop
        lo_r = lo[o:o + nq]
        hi_r = hi[o:o + nq]
        fl_r = flag[o:o + nq]
        cn_r = cnt[base:base + nq]
        ne_r = near[base:base + nq]
        fa_r = far[base:base + nq]
        for q in range(nq):
            a = a0 + (q + qa) * da
            e = e0 + (q + qa) * de
            e2 = e * e
            qc = Rc2 - e2
            rho_c = math.sqrt(max(qc, 0.0))
            rho = math.sqrt(max(R2 - e2, 0.0)) if two_sqrt else rho_c
            s_lo = max(a - rho_c, 0.0)
            s_hi = min(a + rho_c, ell)
            s = min(max(a - rho * sin_t, s_lo), s_hi)
            w = a - s
            v = np.float32(z0 + m * s + h_off + R - math.sqrt(max(rho * rho - w * w, 0.0)))
            t = np.float32(z0 + h_top + max(m * s_lo, m * s_hi))
            ok = (qc >= 0.0) & (s_lo <= s_hi) & (v < t)
            lo_r[q] = v
            hi_r[q] = t
            c = cn_r[q]
            one = (v < fa_r[q]) & (t > ne_r[q])
            fl_r[q] = ok & ((c > 1) | ((c == 1) & one))


@nb.njit(cache=True, error_model="numpy", boundscheck=False)
def _rows_flat(Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows, row_ia,
               row_ilo, row_off, cnt, near, far, lo, hi, flag):
    """Flat-bottom cylinder on the rays of one move (see :func:`_rows_ball`)."""
    Rc2 = Rc * Rc
    for jj in range(nrows):
        i0 = row_ilo[jj]
        qa = i0 - row_ia[jj]
        o = row_off[jj]
        nq = row_off[jj + 1] - o
        rx = rx0 + row_ia[jj] * sp
        ry = ry0 + (jlo + jj) * sp
        a0 = rx * ux + ry * uy
        e0 = -rx * uy + ry * ux
        da = sp * ux
        de = -sp * uy
        base = (jlo + jj) * nu + i0
        lo_r = lo[o:o + nq]
        hi_r = hi[o:o + nq]
        fl_r = flag[o:o + nq]
        cn_r = cnt[base:base + nq]
        ne_r = near[base:base + nq]
        fa_r = far[base:base + nq]
        for q in range(nq):
            a = a0 + (q + qa) * da
            e = e0 + (q + qa) * de
            qc = Rc2 - e * e
            rho_c = math.sqrt(max(qc, 0.0))
            s_lo = max(a - rho_c, 0.0)
            s_hi = min(a + rho_c, ell)
            v = np.float32(z0 + h_off + min(m * s_lo, m * s_hi))
            t = np.float32(z0 + h_top + max(m * s_lo, m * s_hi))
            ok = (qc >= 0.0) & (s_lo <= s_hi) & (v < t)
            lo_r[q] = v
            hi_r[q] = t
            c = cn_r[q]
            one = (v < fa_r[q]) & (t > ne_r[q])
            fl_r[q] = ok & ((c > 1) | ((c == 1) & one))


@nb.njit(cache=True, inline="always")
def _keep_ahead(x, da, qa, nq, flag, o):
    """The rays ``q_a .. q_b-1`` of a row along a chained move that lie past ``x`` (the cut
    between rays behind the start and ahead of it, in rays from the row's box start, see
    ``qa``), the rest unflagged: ``da > 0`` keeps those above ``x``, ``da < 0`` below."""
    q_a = 0
    q_b = nq
    if da > 0.0:
        q_a = min(max(int(math.floor(x)) + 1 - qa, 0), nq)
    else:
        q_b = max(min(int(math.ceil(x)) - qa, nq), 0)
    for q in range(q_a):
        flag[o + q] = False
    for q in range(q_b, nq):
        flag[o + q] = False
    return q_a, q_b


@nb.njit(cache=True, error_model="numpy", boundscheck=False)
def _rows_cone(cot, Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows, row_ia,
               row_ilo, row_off, cnt, near, far, lo, hi, flag, behind):
    """Cone (vbit / drill point) on the rays of one move (see :func:`_rows_ball`).

    Same arithmetic as :func:`linear_interval`'s cone: the lowest point of
    ``m s + cot sqrt(e^2 + (a - s)^2)`` at ``s = a - |e| g / sqrt(1 - g^2)``, ``g = m / cot``,
    or at the start (end) when the move climbs (descends) steeper than the cone; the
    case is the same for every ray of the move, so the loop stays branch-free.
    ``behind``: a chained move (see :func:`_rows_bull`).
    """
    Rc2 = Rc * Rc
    g = m / cot
    at_start = g >= 1.0
    at_end = g <= -1.0
    gs = g / math.sqrt(1.0 - g * g) if not (at_start or at_end) else 0.0  # no division per ray
    for jj in range(nrows):
        i0 = row_ilo[jj]
        qa = i0 - row_ia[jj]  # rays counted from the row's box start (see _rows_ball)
        o = row_off[jj]
        nq = row_off[jj + 1] - o
        rx = rx0 + row_ia[jj] * sp
        ry = ry0 + (jlo + jj) * sp
        a0 = rx * ux + ry * uy
        e0 = -rx * uy + ry * ux
        da = sp * ux
        de = -sp * uy
        base = (jlo + jj) * nu + i0
        q_a = 0
        q_b = nq
        if behind and de == 0.0 and da != 0.0 and not at_end:
            # a row along a chained move leaves out the rays whose lowest point is the start
            # pose: s* <= 0 within reach of it, a <= min(|e| g / sqrt(1 - g^2), rho_c)
            # (a <= rho_c when climbing steeper than the cone); a spare ray is harmless
            rho_row = math.sqrt(max(Rc2 - e0 * e0, 0.0))
            cut = min(rho_row, abs(e0) * gs) if not at_start else rho_row
            q_a, q_b = _keep_ahead((cut - 1e-9 - a0) / da, da, qa, nq, flag, o)
        k_a = qa + q_a  # the loop from 0 over unit-stride views, as in _rows_ball
        e_q = e0 + k_a * de
        lo_r = lo[o + q_a:o + q_b]
        hi_r = hi[o + q_a:o + q_b]
        fl_r = flag[o + q_a:o + q_b]
        cn_r = cnt[base + q_a:base + q_b]
        ne_r = near[base + q_a:base + q_b]
        fa_r = far[base + q_a:base + q_b]
        if de == 0.0:  # e, and so the reach across the path, are the row's
            e2 = e_q * e_q
            qc = Rc2 - e2
            rho_c = math.sqrt(max(qc, 0.0))
            for q in range(q_b - q_a):
                v, t, ok = _cone_ray(a0 + (k_a + q) * da, e_q, e2, qc, rho_c, gs, at_start, at_end, cot, z0, m,
                                     ell, h_off, h_top)
                lo_r[q] = v
                hi_r[q] = t
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (t > ne_r[q])))
        else:
            for q in range(q_b - q_a):
                e = e0 + (k_a + q) * de
                e2 = e * e
                qc = Rc2 - e2
                v, t, ok = _cone_ray(a0 + (k_a + q) * da, e, e2, qc, math.sqrt(max(qc, 0.0)), gs, at_start, at_end,
                                     cot, z0, m, ell, h_off, h_top)
                lo_r[q] = v
                hi_r[q] = t
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (t > ne_r[q])))


@nb.njit(cache=True, inline="always")
def _cone_ray(a, e, e2, qc, rho_c, gs, at_start, at_end, cot, z0, m, ell, h_off, h_top):
    """Interval ``(lo, hi)`` (float32) of the cone's sweep on one ray of
    :func:`_rows_cone` (``qc = Rc^2 - e^2``, ``rho_c`` its root) and whether the ray is
    within reach."""
    s_lo = max(a - rho_c, 0.0)
    s_hi = min(a + rho_c, ell)
    s = s_lo if at_start else (s_hi if at_end else a - abs(e) * gs)
    s = min(max(s, s_lo), s_hi)
    w = a - s
    v = np.float32(z0 + m * s + h_off + math.sqrt(e2 + w * w) * cot)
    t = np.float32(z0 + h_top + max(m * s_lo, m * s_hi))
    return v, t, (qc >= 0.0) & (s_lo <= s_hi) & (v < t)


@nb.njit(cache=True, inline="always")
def _bull_depth(a0, rc, R, k2, c2, lo, e2, d):
    """Distance (mm) from the axis, in ``(lo, R)``, of the bull-nose's lowest point over a
    ray at ``e2 = e^2`` from the path of a move of slope ``m != 0``: the one root of
    ``F(d) = (d - a0)^2 ((1 + m^2) d^2 - e^2) - rc^2 m^2 d^2``, ``k2 = 1 + m^2``,
    ``c2 = rc^2 m^2``, ``a0 = R - rc``.

    ``F`` has the sign of ``h*'(d)^2 (1 - e^2/d^2) - m^2`` (``h*'`` the torus' slope),
    which rises with ``d``: ``F < 0`` at ``lo`` (see :func:`_rows_bull`), ``F >= 0`` at
    ``R``. Newton steps on the polynomial from the guess ``d``, kept in the shrinking
    bracket by bisection, until a Newton step is within 1e-7 mm: convergence is
    quadratic, so the root after that step is good to ~1e-14 mm (times ``F''/2F'``), and
    the height, whose error is second order in the root's, to far below 1e-9 mm, even
    near the rim where ``h*''`` grows without bound (the oracle tests check to 1e-9).
    """
    hi = R
    if not lo < hi:
        return hi
    if not (lo < d < hi):
        d = 0.5 * (lo + hi)
    for _ in range(200):
        t = d - a0
        p = k2 * d * d - e2
        F = t * t * p - c2 * d * d
        if F < 0.0:
            lo = d
        elif F > 0.0:
            hi = d
        else:
            return d
        dF = 2.0 * (t * p + k2 * d * t * t - c2 * d)
        dn = d - F / dF
        if abs(dn - d) <= 1e-7:  # converged (the step may land on the bracket's end)
            return min(max(dn, lo), hi)
        if not (lo < dn < hi):  # Newton left the bracket (or dF <= 0): bisect
            dn = 0.5 * (lo + hi)
            if hi - lo <= 1e-13:
                return dn
        d = dn
    return d


@nb.njit(cache=True, inline="always")
def _bull_depth_slope(a0, k2, c2, e, d):
    """d(root)/d|e| of :func:`_bull_depth` at the root ``d``: ``-F_e / F_d``."""
    t = d - a0
    dF = 2.0 * (t * (k2 * d * d - e * e) + k2 * d * t * t - c2 * d)
    return 2.0 * e * t * t / dF if dF > 0.0 else 0.0


#: knots of the per-move table of bull-nose roots over |e| in [0, R] (see _rows_bull)
BULL_KNOTS = 128


@nb.njit(cache=True, inline="always")
def _bull_guess(tab_d, tab_s, h, e):
    """The root of :func:`_bull_depth` at ``|e| = e`` by cubic Hermite interpolation of
    the per-move table (roots ``tab_d`` and slopes ``tab_s`` at knots ``k h``)."""
    x = e / h
    k = min(int(x), tab_d.size - 2)
    u = x - k
    v = 1.0 - u
    return (v * v * ((1.0 + 2.0 * u) * tab_d[k] + u * h * tab_s[k])
            + u * u * ((3.0 - 2.0 * u) * tab_d[k + 1] - v * h * tab_s[k + 1]))


@nb.njit(cache=True, error_model="numpy", boundscheck=False)
def _rows_bull(R, rc, Rc, h_off, h_top, z0, m, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows, row_ia,
               row_ilo, row_off, cnt, near, far, lo, hi, flag, behind):
    """Bull-nose on the rays of one move (see :func:`_rows_ball`).

    The lowest point over a ray at ``(a, e)`` lies at ``s* = a - sign(m) w``,
    ``w = sqrt(d^2 - e^2)``, where ``d`` depends on ``|e|`` only (:func:`_bull_depth`;
    ``w = 0`` on a level move) - clamped to the part of the move within reach, as
    ``z + h*(d(s))`` is convex in ``s``. A row along the move (X) needs one root, a
    move along Y one per column; other moves one per ray, each from the cubic
    interpolation of a per-move table of ``BULL_KNOTS`` roots over ``|e|`` in a step or
    two. Then the intervals in a branch-free loop like the ball's. ``behind`` (a move
    chained to the previous one, see :func:`cut_linear_batch`): a row along the move
    leaves out the rays with ``s* < 0``, whose lowest point is the start pose, already
    cut by the previous move.
    """
    a0 = R - rc
    rc2 = rc * rc
    Rc2 = Rc * Rc
    k2 = 1.0 + m * m
    c2 = rc2 * m * m
    sg = 1.0 if m > 0.0 else (-1.0 if m < 0.0 else 0.0)
    d_e0 = a0 + rc * abs(m) / math.sqrt(k2)  # the root on the path (e = 0): F < 0 below it
    da = sp * ux
    de = -sp * uy
    nmax = 0
    for jj in range(nrows):
        nmax = max(nmax, row_off[jj + 1] - row_off[jj])
    w_row = np.zeros(nmax)
    fix_row = np.empty(nmax, np.bool_)
    h_tab = R / BULL_KNOTS
    tab_d = np.empty(BULL_KNOTS + 1)
    tab_s = np.empty(BULL_KNOTS + 1)
    # a move across the rows (along Y): e depends on the column only, one root per column
    by_column = m != 0.0 and de != 0.0 and da == 0.0
    if m != 0.0 and de != 0.0 and not by_column:  # the table, for diagonal moves only
        tab_d[0] = d_e0
        tab_s[0] = 0.0
        for k in range(1, BULL_KNOTS + 1):
            e = min(k * h_tab, R)
            d = _bull_depth(a0, rc, R, k2, c2, max(d_e0, e), e * e, tab_d[k - 1] + h_tab * tab_s[k - 1])
            tab_d[k] = d
            tab_s[k] = _bull_depth_slope(a0, k2, c2, e, d)
    i_min = nu
    i_max = 0
    for jj in range(nrows):
        if row_off[jj + 1] > row_off[jj]:
            i_min = min(i_min, row_ilo[jj])
            i_max = max(i_max, row_ilo[jj] + row_off[jj + 1] - row_off[jj])
    w_col = np.zeros(max(i_max - i_min, 0) if by_column else 0)
    d = np.nan
    for i in range(w_col.size):  # each column's search from the last column's root
        e = abs((rx0 + (i_min + i) * sp) * uy)
        if e < R:
            d = _bull_depth(a0, rc, R, k2, c2, max(d_e0, e), e * e, d)
            w_col[i] = math.sqrt(max((d - e) * (d + e), 0.0))
    d_row = np.nan
    for jj in range(nrows):
        i0 = row_ilo[jj]
        qa = i0 - row_ia[jj]  # rays counted from the row's box start (see _rows_ball)
        o = row_off[jj]
        nq = row_off[jj + 1] - o
        rx = rx0 + row_ia[jj] * sp
        ry = ry0 + (jlo + jj) * sp
        a_0 = rx * ux + ry * uy
        e_0 = -rx * uy + ry * ux
        base = (jlo + jj) * nu + i0
        w_r = w_row[:nq]
        q_a = 0
        q_b = nq
        if de == 0.0:  # the row runs along the move: one root
            e = abs(e_0)
            w = 0.0
            if m != 0.0 and e < R:
                d_row = _bull_depth(a0, rc, R, k2, c2, max(d_e0, e), e * e, d_row)
                w = math.sqrt(max((d_row - e) * (d_row + e), 0.0))
            w_r[:] = w
            if behind and da != 0.0:
                # leave out a <= cut: s* = a - sg w <= -1e-9 there (a spare ray is harmless)
                q_a, q_b = _keep_ahead((sg * w - 1e-9 - a_0) / da, da, qa, nq, flag, o)
        elif by_column:
            w_r = w_col[i0 - i_min:i0 - i_min + nq]
        elif m != 0.0:
            # the table's guesses (its lookups keep this loop scalar), one Newton step from
            # them for every ray (branch-free, so that it vectorises), then the full search
            # where that step was not yet small
            fix = fix_row[:nq]
            for q in range(nq):
                w_r[q] = _bull_guess(tab_d, tab_s, h_tab, min(abs(e_0 + (qa + q) * de), R))
            for q in range(nq):
                e = min(abs(e_0 + (qa + q) * de), R)
                d_lo = max(d_e0, e)
                d = min(max(w_r[q], d_lo), R)
                t = d - a0
                p = k2 * d * d - e * e
                step = (t * t * p - c2 * d * d) / (2.0 * (t * p + k2 * d * t * t - c2 * d))
                d = min(max(d - step, d_lo), R)
                w_r[q] = math.sqrt(max((d - e) * (d + e), 0.0))
                fix[q] = not abs(step) <= 1e-7  # as _bull_depth's test (NaN: search)
            for q in range(nq):
                if fix[q]:
                    e = abs(e_0 + (qa + q) * de)
                    w = 0.0
                    if e < R:
                        d = _bull_depth(a0, rc, R, k2, c2, max(d_e0, e), e * e,
                                        _bull_guess(tab_d, tab_s, h_tab, e))
                        w = math.sqrt(max((d - e) * (d + e), 0.0))
                    w_r[q] = w
        # the loop over the rays kept, from 0 (unit-stride views, as in _rows_ball)
        k_a = qa + q_a
        e_q = e_0 + k_a * de
        w_k = w_r[q_a:q_b]
        lo_r = lo[o + q_a:o + q_b]
        hi_r = hi[o + q_a:o + q_b]
        fl_r = flag[o + q_a:o + q_b]
        cn_r = cnt[base + q_a:base + q_b]
        ne_r = near[base + q_a:base + q_b]
        fa_r = far[base + q_a:base + q_b]
        if de == 0.0:  # e, and so the reach across the path, are the row's
            e2 = e_q * e_q
            qc = Rc2 - e2
            rho_c = math.sqrt(max(qc, 0.0))
            for q in range(q_b - q_a):
                v, top, ok = _bull_ray(a_0 + (k_a + q) * da, e2, qc, rho_c, w_k[q], sg, a0, rc, rc2, z0, m,
                                       ell, h_off, h_top)
                lo_r[q] = v
                hi_r[q] = top
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (top > ne_r[q])))
        else:
            for q in range(q_b - q_a):
                e2 = (e_0 + (k_a + q) * de) ** 2
                qc = Rc2 - e2
                v, top, ok = _bull_ray(a_0 + (k_a + q) * da, e2, qc, math.sqrt(max(qc, 0.0)), w_k[q], sg, a0,
                                       rc, rc2, z0, m, ell, h_off, h_top)
                lo_r[q] = v
                hi_r[q] = top
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (top > ne_r[q])))


@nb.njit(cache=True, inline="always")
def _bull_ray(a, e2, qc, rho_c, w_star, sg, a0, rc, rc2, z0, m, ell, h_off, h_top):
    """Interval ``(lo, hi)`` (float32) of the bull-nose sweep on one ray of
    :func:`_rows_bull` (``qc = Rc^2 - e^2``, ``rho_c`` its root, ``w_star`` the ray's
    ``w``) and whether the ray is within reach."""
    s_lo = max(a - rho_c, 0.0)
    s_hi = min(a + rho_c, ell)
    s = min(max(a - sg * w_star, s_lo), s_hi)
    w = a - s
    t = max(math.sqrt(e2 + w * w) - a0, 0.0)
    v = np.float32(z0 + m * s + h_off + rc - math.sqrt(max(rc2 - t * t, 0.0)))
    top = np.float32(z0 + h_top + max(m * s_lo, m * s_hi))
    return v, top, (qc >= 0.0) & (s_lo <= s_hi) & (v < top)


@nb.njit(cache=True)
def _rows_any(tp, x0, y0, z0, dz, ell, ux, uy, rx0, ry0, sp, nu, jlo, nrows,
              row_ilo, row_off, cnt, near, far, lo, hi, flag):
    """Any exact body (bull-nose, cone, vertical moves) through :func:`linear_interval`."""
    for jj in range(nrows):
        i0 = row_ilo[jj]
        o = row_off[jj]
        nq = row_off[jj + 1] - o
        ry = ry0 + (jlo + jj) * sp
        base = (jlo + jj) * nu + i0
        for q in range(nq):
            a, b = linear_interval(tp, x0, y0, z0, dz, ell, ux, uy, rx0 + (i0 + q) * sp, ry)
            v = np.float32(a)
            t = np.float32(b)
            lo[o + q] = v
            hi[o + q] = t
            c = cnt[base + q]
            flag[o + q] = (a < b) and (v < t) and (c > 1 or (c == 1 and v < far[base + q]
                                                       and t > near[base + q]))


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


@nb.njit(cache=True)
def _stadium_span(ax, ay, dx, dy, rad, y):
    """X range ``(lo, hi)`` of the line at height ``y`` within ``rad`` of the segment from
    ``(ax, ay)`` to ``(ax + dx, ay + dy)`` (mm); ``lo > hi`` when the line misses it.

    The stadium is convex, so its chord is the hull of the chords of the two end discs
    and of the band between them (``0 <= (p - a).d <= |d|^2``, ``|(p - a) x d| <= rad |d|``,
    each linear in ``x``).
    """
    lo = np.inf
    hi = -np.inf
    rad2 = rad * rad
    for cx, cy in ((ax, ay), (ax + dx, ay + dy)):
        t = y - cy
        if t * t <= rad2:
            w = math.sqrt(rad2 - t * t)
            lo = min(lo, cx - w)
            hi = max(hi, cx + w)
    L2 = dx * dx + dy * dy
    if L2 == 0.0:
        return lo, hi
    ry = y - ay
    band_lo = -np.inf
    band_hi = np.inf
    # along the segment: dx * x + dy * ry in [0, L2] (x relative to ax)
    if dx != 0.0:
        u0 = -dy * ry / dx
        u1 = (L2 - dy * ry) / dx
        band_lo = max(band_lo, min(u0, u1))
        band_hi = min(band_hi, max(u0, u1))
    elif not (0.0 <= dy * ry <= L2):
        return lo, hi
    # across it: dx * ry - dy * x in [-rad |d|, rad |d|]
    half = rad * math.sqrt(L2)
    if dy != 0.0:
        v0 = (dx * ry - half) / dy
        v1 = (dx * ry + half) / dy
        band_lo = max(band_lo, min(v0, v1))
        band_hi = min(band_hi, max(v0, v1))
    elif abs(dx * ry) > half:
        return lo, hi
    if band_lo <= band_hi:
        lo = min(lo, ax + band_lo)
        hi = max(hi, ax + band_hi)
    return lo, hi


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
        jlo = max(band0, int(math.ceil((ymin - Rc - gy0) / sp)))
        jhi = min(nv, band1) - 1
        jhi = min(jhi, int(math.floor((ymax + Rc - gy0) / sp)))
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
            if dym <= Rc and not clear:
                w = math.sqrt(Rc * Rc - dym * dym)
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


@nb.njit(cache=True, inline="always")
def _save(state, k, j, i, nout, mc):
    state[0] = k
    state[1] = j
    state[2] = i
    state[3] = nout
    state[4] = mc





# --- instances of motion: any frame, any axis, any profile ----------------------------

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


#: buffers of a kernel call that records nothing (never written)
NO_LOG = (np.zeros(1, np.int64), np.zeros(1, np.float32), np.zeros(1, np.int64), np.zeros(1), np.zeros(1))
#: trace buffers of a kernel call that traces nothing (never written)
NO_TRACE = (np.zeros(1, np.int32), np.zeros(1, np.float32), np.zeros(1, np.int32), np.zeros(1, np.int32),
            np.zeros(1, np.int16), np.zeros(1, np.float32), np.zeros(1, np.float32), np.zeros(1, np.int32),
            np.zeros(1, np.int32), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64),
            np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64))
NO_TS = np.zeros(TRACE_STATE_SIZE, np.int64)
