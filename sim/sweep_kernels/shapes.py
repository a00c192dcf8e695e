"""Tool shapes in closed form: the interval a tool swept along one straight move occupies on
a vertical ray, per ray (:func:`linear_interval`) and per row of a move's rays (the
``_rows_*`` kernels the linear batch cut calls).

Rays along +Z, tool axis along +Z, a straight move of the tip from ``P0`` to ``P1``. The
swept body meets a vertical ray at ``(x, y)`` in one interval ``[lo, hi]``: ``hi`` is the
top of the body at an end of the part of the move where the ray is within the body's
radius, and ``lo = min_s z(s) + h*(d(s))`` where ``s`` is the distance travelled in XY,
``d(s)`` the distance from the ray to the axis and ``h*`` the lowest height of the tool at
that distance. ``z + h*(d)`` is convex in ``s`` for the convex tools, so the minimum is
found in closed form (flat: an end of the range; ball: the capsule,
``s* = a - rho * dz / |P1 - P0|``; vbit/drill: the same with the cone slope) or, for the
bull-nose torus, in closed form for level moves and otherwise from the distance to the
axis at the lowest point, the one root of a quartic found by safeguarded Newton steps
(:func:`_bull_depth`).

All lengths mm; per-ray arithmetic float64, the row kernels' intervals rounded to float32.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


CODE_FLAT = 0
CODE_BALL = 1
CODE_BULL = 2
CODE_CONE = 3

# ``tp``, a body's float64 parameters for the exact linear kernel:
# [code, R, rc, cot_half_angle, h_off (bottom above the tip), h_top, Rc (largest radius)]

#: mm: a ray this close outside a body's rim counts as on it. The tool is closed (a ray on
#: its rim is cut), and a pose two moves share must reach the same rays from both: the end
#: of one move and the start of the next are the same point, but each move measures a ray
#: in its own frame (along and across itself), where rounding moves a ray exactly on the
#: rim (a helix ending on the grid, 3 mm from a ray) in or out by ~1e-15 mm. Without the
#: margin a retract straight up from where a helix ended found that rim ray still standing
#: and reported a rapid into stock. Far below any tolerance, far above the rounding.
RIM = 1e-9


@nb.njit(cache=True, inline="always")
def within_rim(qc, s_lo, s_hi, Rc):
    """Whether a ray reaches the body: across the move within ``Rc`` (``qc = Rc^2 -
    e^2``) and along it within its reach ``s_lo <= s_hi`` (mm along the move), each with
    the :data:`RIM` margin."""
    return (qc >= -2.0 * Rc * RIM) & (s_lo <= s_hi + RIM)


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

    ``tp`` body parameters (layout at the top of this module); the move starts at tip ``(x0, y0, z0)``,
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
    if not within_rim(q, 0.0, 0.0, Rc):
        return 1.0, 0.0
    rho_c = math.sqrt(max(q, 0.0))
    if ell <= 0.0:
        if not within_rim(q - a * a, 0.0, 0.0, Rc):
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
    if not within_rim(q, s_lo, s_hi, Rc):
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
            ok = within_rim(qc, s_lo, s_hi, Rc) & (v < t)
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
            ok = within_rim(qc, s_lo, s_hi, Rc) & (v < t)
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
                                     ell, h_off, h_top, Rc)
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
                                     cot, z0, m, ell, h_off, h_top, Rc)
                lo_r[q] = v
                hi_r[q] = t
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (t > ne_r[q])))


@nb.njit(cache=True, inline="always")
def _cone_ray(a, e, e2, qc, rho_c, gs, at_start, at_end, cot, z0, m, ell, h_off, h_top, Rc):
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
    return v, t, within_rim(qc, s_lo, s_hi, Rc) & (v < t)


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
                                       ell, h_off, h_top, Rc)
                lo_r[q] = v
                hi_r[q] = top
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (top > ne_r[q])))
        else:
            for q in range(q_b - q_a):
                e2 = (e_0 + (k_a + q) * de) ** 2
                qc = Rc2 - e2
                v, top, ok = _bull_ray(a_0 + (k_a + q) * da, e2, qc, math.sqrt(max(qc, 0.0)), w_k[q], sg, a0,
                                       rc, rc2, z0, m, ell, h_off, h_top, Rc)
                lo_r[q] = v
                hi_r[q] = top
                c = cn_r[q]
                fl_r[q] = ok & ((c > 1) | ((c == 1) & (v < fa_r[q]) & (top > ne_r[q])))


@nb.njit(cache=True, inline="always")
def _bull_ray(a, e2, qc, rho_c, w_star, sg, a0, rc, rc2, z0, m, ell, h_off, h_top, Rc):
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
    return v, top, within_rim(qc, s_lo, s_hi, Rc) & (v < top)


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
