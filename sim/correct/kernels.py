"""Compiled kernels of the tool path correction (Huang & Oliver 1994, section 4).

Everything here is in world millimetres on a top frame (rays along +Z, ray ``(i, j)`` at
``X = gx0 + i*sp``, ``Y = gy0 + j*sp``; its parameter ``s`` is the world Z). A tool
position is its tip; the tool axis is +Z (3-axis).

* :func:`sweep_gouge` - how a straight move (a single pose when both ends coincide)
  gouges the design: the exact lowest point of the swept tool on every ray
  (:func:`sim.sweep_kernels.shapes.linear_interval`) assessed like the error map does
  (:func:`sim.checks.design_kernels.point_errors`): the distance along the ray to the
  surface, replaced by the exact near-point distance where it matters. It also sums the
  guide vector of eq. 7 over the gouged points.
* :func:`correct_pose` - a gouging pose moved along the guide vector until it is within
  the target (the tool axis when the guide vector vanishes; straight up as a last resort).
* :func:`correct_move` - Fig. 14: the end pose corrected, then the move split at its worst
  instance and the split pose corrected, recursively, down to a minimum segment length.

The design is passed as the tuple :data:`DesignArrays` (see ``sim.correct.gouge``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim.checks.design_kernels import _nearest, _nearest_crossing
from sim.sweep_kernels.shapes import _hstar, linear_interval

#: layout of the float64 result of :func:`sweep_gouge`
(G_COUNT, G_DEPTH, G_RAY, G_S, G_GX, G_GY, G_GZ, G_LIFT) = range(8)
G_SIZE = 8

#: statuses of :func:`correct_move`
OK = 0
FULL = 1          # more points than the output buffer holds
NOT_CLEAN = 2     # the pose could not be freed (never expected for a height-field design)

#: most points one move may become
MAX_POINTS = 4096


@nb.njit(cache=True)
def sweep_gouge(tp, x0, y0, z0, x1, y1, z1, frame, design, thr, search, out):
    """Assess the tool (parameters ``tp``, see ``sim.sweep.body_params``) swept from tip
    ``(x0, y0, z0)`` to ``(x1, y1, z1)`` against the design; a point is gouged when it
    lies inside the design more than ``thr`` mm from its surface.

    ``frame`` = (gx0, gy0, sp, nu, nv); ``design`` = the :data:`DesignArrays` tuple;
    ``search`` (mm) bounds the exact near-point search as in the error map.
    ``out`` (G_SIZE,) float64 gets: the number of gouged rays, the deepest gouge (mm),
    its ray and the ray parameter of its point, the guide vector of eq. 7
    ``sum (d_i - thr) n_i`` (outward normals of the crossing's triangle) and the largest
    distance along the rays from a gouged point up to the surface (a lift that frees the
    pose for certain on a height field).
    """
    gx0, gy0, sp, nu, nv = frame
    ptr, hit_s, hit_tri, tri_dz, sheet, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems, normals = design
    for k in range(G_SIZE):
        out[k] = 0.0
    out[G_RAY] = -1.0
    Rc = tp[6]
    dx = x1 - x0
    dy = y1 - y0
    dz = z1 - z0
    ell = math.sqrt(dx * dx + dy * dy)
    if ell > 1e-9:
        ux = dx / ell
        uy = dy / ell
    else:
        ell = 0.0
        ux = 1.0
        uy = 0.0
    i0 = max(int(math.ceil((min(x0, x1) - Rc - gx0) / sp)), 0)
    i1 = min(int(math.floor((max(x0, x1) + Rc - gx0) / sp)), nu - 1)
    j0 = max(int(math.ceil((min(y0, y1) - Rc - gy0) / sp)), 0)
    j1 = min(int(math.floor((max(y0, y1) + Rc - gy0) / sp)), nv - 1)
    for j in range(j0, j1 + 1):
        ry = gy0 + j * sp - y0
        for i in range(i0, i1 + 1):
            rx = gx0 + i * sp - x0
            lo, hi = linear_interval(tp, x0, y0, z0, dz, ell, ux, uy, rx, ry)
            if lo > hi:
                continue
            r = j * nu + i
            best, bt, above = _nearest_crossing(hit_s, hit_tri, ptr[r], ptr[r + 1], lo)
            if bt < 0:
                continue
            inside = (above > 0) if sheet else ((above % 2) == 1)
            if not inside or best <= thr:
                continue
            rad = min(best, search)
            # the near-point search works in frame-local coordinates: (i sp, j sp, Z)
            best2, found = _nearest(i * sp, j * sp, lo, rad * rad, bt, tri, tri_lo, tri_hi, bin_size, nbu, nbv,
                                    bptr, bitems)
            d = math.sqrt(best2) if found else best
            if d <= thr:
                continue
            out[G_COUNT] += 1.0
            if d > out[G_DEPTH]:
                out[G_DEPTH] = d
                out[G_RAY] = r
                out[G_S] = lo
            w = d - thr
            out[G_GX] += w * normals[bt, 0]
            out[G_GY] += w * normals[bt, 1]
            out[G_GZ] += w * normals[bt, 2]
            up = hit_s[ptr[r + 1] - 1] - lo if sheet else best
            if up > out[G_LIFT]:
                out[G_LIFT] = up


@nb.njit(cache=True)
def lowest_instance(tp, x0, y0, z0, x1, y1, z1, px, py):
    """Where along the move (fraction ``t`` in [0, 1]) the tool makes its lowest point on
    the ray at ``(px, py)``: the minimum of the convex ``z(t) + h*(d(t))`` (golden
    section over the part of the move within the tool's radius of the ray)."""
    code = int(tp[0])
    R = tp[1]
    rc = tp[2]
    cot = tp[3]
    Rc = tp[6]
    dx = x1 - x0
    dy = y1 - y0
    ell = math.sqrt(dx * dx + dy * dy)
    if ell <= 1e-9:
        return 0.0 if z1 >= z0 else 1.0
    ux = dx / ell
    uy = dy / ell
    a = (px - x0) * ux + (py - y0) * uy
    e = -(px - x0) * uy + (py - y0) * ux
    q = Rc * Rc - e * e
    rho = math.sqrt(q) if q > 0.0 else 0.0
    s_lo = max(a - rho, 0.0)
    s_hi = min(a + rho, ell)
    if s_lo >= s_hi:
        return min(max(a / ell, 0.0), 1.0)
    m = (z1 - z0) / ell
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    lo_s = s_lo
    hi_s = s_hi
    c = hi_s - g * (hi_s - lo_s)
    d = lo_s + g * (hi_s - lo_s)
    fc = m * c + _hstar(code, R, rc, cot, math.sqrt(e * e + (a - c) ** 2))
    fd = m * d + _hstar(code, R, rc, cot, math.sqrt(e * e + (a - d) ** 2))
    for _ in range(60):
        if hi_s - lo_s <= 1e-9:
            break
        if fc <= fd:
            hi_s = d
            d = c
            fd = fc
            c = hi_s - g * (hi_s - lo_s)
            fc = m * c + _hstar(code, R, rc, cot, math.sqrt(e * e + (a - c) ** 2))
        else:
            lo_s = c
            c = d
            fc = fd
            d = lo_s + g * (hi_s - lo_s)
            fd = m * d + _hstar(code, R, rc, cot, math.sqrt(e * e + (a - d) ** 2))
    return 0.5 * (lo_s + hi_s) / ell


@nb.njit(cache=True)
def correct_pose(tp, p, frame, design, target, search, max_iter, res):
    """Move pose ``p`` (3,) in place until it gouges no point deeper than ``target``.

    Eq. 7: the guide vector ``G = sum (d_i - t) n_i`` over the gouged points, set to the
    length of the deepest gouge; the tool axis (+Z) when ``|G|`` vanishes. After
    ``max_iter`` guide steps, straight lifts by the largest distance up to the surface.
    Returns the number of guide steps taken (-1: still gouging after the lifts).
    ``res``: scratch (G_SIZE,).
    """
    for it in range(max_iter):
        sweep_gouge(tp, p[0], p[1], p[2], p[0], p[1], p[2], frame, design, target, search, res)
        if res[G_COUNT] == 0.0:
            return it
        gx = res[G_GX]
        gy = res[G_GY]
        gz = res[G_GZ]
        n = math.sqrt(gx * gx + gy * gy + gz * gz)
        if n <= 1e-12:
            gx, gy, gz, n = 0.0, 0.0, 1.0, 1.0
        step = res[G_DEPTH] / n
        p[0] += gx * step
        p[1] += gy * step
        p[2] += gz * step
    for _ in range(8):
        sweep_gouge(tp, p[0], p[1], p[2], p[0], p[1], p[2], frame, design, target, search, res)
        if res[G_COUNT] == 0.0:
            return max_iter
        p[2] += res[G_LIFT] + 0.25 * target
    return -1


@nb.njit(cache=True)
def _lift_segment(tp, a, b, frame, design, target, search, res):
    """Lift segment ``a -> b`` straight up (both ends, in place) until its sweep is clean;
    False when it is still gouging after a few lifts."""
    for _ in range(8):
        sweep_gouge(tp, a[0], a[1], a[2], b[0], b[1], b[2], frame, design, target, search, res)
        if res[G_COUNT] == 0.0:
            return True
        dz = res[G_LIFT] + 0.25 * target
        a[2] += dz
        b[2] += dz
    return False


@nb.njit(cache=True)
def correct_move(tp, p0, q, frame, design, t_l, target, search, min_len, max_iter, out, stats):
    """Correct one straight move from ``p0`` (already gouge-free, never moved) to ``q``.

    The move is left alone (one point, ``q``) when neither its end pose nor its sweep
    gouges deeper than ``t_l``. Otherwise (Fig. 14): ``q`` is corrected to ``q'``
    (:func:`correct_pose` to ``target``), and while the sweep from the current point to
    the next pending point gouges deeper than ``target``, the move is split at its
    deepest instance ``S`` and ``S'`` (``S`` corrected) becomes the next pending point; a
    piece shorter than ``min_len`` that still gouges is lifted straight up (a vertical
    step from the current point, then the lifted piece).

    ``out`` (cap, 3): the points the corrected move visits after ``p0``, last = its new
    end. ``stats`` (4,) int64 accumulates: poses corrected, guide steps, splits, lifts.
    Returns ``(n_points, status)``; status :data:`OK`, :data:`FULL` or :data:`NOT_CLEAN`.
    """
    res = np.empty(G_SIZE)
    sweep_gouge(tp, p0[0], p0[1], p0[2], q[0], q[1], q[2], frame, design, t_l, search, res)
    if res[G_COUNT] == 0.0:
        sweep_gouge(tp, q[0], q[1], q[2], q[0], q[1], q[2], frame, design, t_l, search, res)
        if res[G_COUNT] == 0.0:
            out[0, 0] = q[0]
            out[0, 1] = q[1]
            out[0, 2] = q[2]
            return 1, OK
    cap = out.shape[0]
    stack = np.empty((64, 3))
    qc = q.copy()
    got = correct_pose(tp, qc, frame, design, target, search, max_iter, res)
    if got < 0:
        return 0, NOT_CLEAN
    if got > 0:
        stats[0] += 1
        stats[1] += got
    stack[0] = qc
    ns = 1
    cur = p0.copy()
    n = 0
    s = np.empty(3)
    steps = 0
    while ns > 0:
        steps += 1
        if steps > 100000:
            return n, NOT_CLEAN
        nxt = stack[ns - 1]
        sweep_gouge(tp, cur[0], cur[1], cur[2], nxt[0], nxt[1], nxt[2], frame, design, target, search, res)
        if res[G_COUNT] == 0.0:
            if n >= cap:
                return n, FULL
            out[n] = nxt
            n += 1
            cur[:] = nxt
            ns -= 1
            continue
        length = math.sqrt((nxt[0] - cur[0]) ** 2 + (nxt[1] - cur[1]) ** 2 + (nxt[2] - cur[2]) ** 2)
        if length > min_len and ns < stack.shape[0]:
            r = int(res[G_RAY])
            gx0, gy0, sp, nu, nv = frame
            t = lowest_instance(tp, cur[0], cur[1], cur[2], nxt[0], nxt[1], nxt[2],
                                gx0 + (r % nu) * sp, gy0 + (r // nu) * sp)
            if not (0.02 < t < 0.98):
                t = 0.5
            for k in range(3):
                s[k] = cur[k] + t * (nxt[k] - cur[k])
            got = correct_pose(tp, s, frame, design, target, search, max_iter, res)
            if got < 0:
                return n, NOT_CLEAN
            if got > 0:
                stats[0] += 1
                stats[1] += got
            stats[2] += 1
            stack[ns] = s
            ns += 1
            continue
        # too short to split: a vertical step up from the current point, then the piece lifted
        a = cur.copy()
        b = nxt.copy()
        if not _lift_segment(tp, a, b, frame, design, target, search, res):
            return n, NOT_CLEAN
        stats[3] += 1
        if n + 1 >= cap:
            return n, FULL
        out[n] = a
        n += 1
        cur[:] = a
        stack[ns - 1] = b
    return n, OK


#: row codes of :func:`correct_rows`
ROW_STRAIGHT = 0  # rapid or feed: corrected
ROW_FIXED = 1     # arc, probe or turned row: never reshaped (refused when its start moved)
ROW_STILL = 2     # no motion: the path stands where it is
#: per-row statuses of :func:`correct_rows` beyond those of :func:`correct_move`
MOVED_FIXED = 3


@nb.njit(cache=True)
def _dist_to_segment(p, a, b):
    d0 = b[0] - a[0]
    d1 = b[1] - a[1]
    d2 = b[2] - a[2]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    t = 0.0
    if dd > 0.0:
        t = ((p[0] - a[0]) * d0 + (p[1] - a[1]) * d1 + (p[2] - a[2]) * d2) / dd
        t = min(max(t, 0.0), 1.0)
    e0 = p[0] - a[0] - t * d0
    e1 = p[1] - a[1] - t * d1
    e2 = p[2] - a[2] - t * d2
    return math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)


@nb.njit(cache=True)
def correct_rows(codes, tool_idx, tps, p_start, p_end, frame, design, t_l, target, search, min_len, max_iter,
                 start, end, pts, offs, status, before, shift, stats):
    """:func:`correct_move` along a whole table, the corrected path chained row to row.

    ``codes`` (n,) :data:`ROW_STRAIGHT` / :data:`ROW_FIXED` / :data:`ROW_STILL`;
    ``tps`` (k, 7) tool parameters, ``tool_idx`` (n,) the row's; ``p_start``/``p_end``
    (n, 3) programmed tips. Fills ``start``/``end`` (n, 3) on the corrected path, the
    points of straight rows ``pts[offs[k]:offs[k + 1]]``, ``status`` (n,) per row (OK,
    FULL, NOT_CLEAN, MOVED_FIXED), and for rows that changed: ``before`` the programmed
    move's deepest gouge (mm) and ``shift`` the farthest corrected point from it (mm).
    Where ``p_start[k]`` is not ``p_end[k - 1]`` the path jumps by the difference.
    Returns the number of rows done (less than n
    when ``pts`` is full: grow it and call again).
    """
    n = codes.size
    buf = np.empty((MAX_POINTS, 3))
    res = np.empty(G_SIZE)
    cur = p_start[0].copy()
    used = 0
    offs[0] = 0
    for k in range(n):
        if k > 0:
            # the table's tip jumps between rows without a motion (a G43 / G49 change, a tool
            # change): the machine stays where it is, so the corrected tip jumps the same
            a = p_start[k]
            b = p_end[k - 1]
            if a[0] != b[0] or a[1] != b[1] or a[2] != b[2]:
                if cur[0] == b[0] and cur[1] == b[1] and cur[2] == b[2]:
                    cur = a.copy()
                else:
                    cur = cur + (a - b)
        start[k] = cur
        status[k] = OK
        c = codes[k]
        if c == ROW_STRAIGHT:
            tp = tps[tool_idx[k]]
            q = p_end[k].copy()
            m, st = correct_move(tp, cur, q, frame, design, t_l, target, search, min_len, max_iter, buf, stats)
            if st != OK:
                status[k] = st
                m = 0
            if used + m > pts.shape[0]:
                return k
            if m == 0:
                cur = p_end[k].copy()
                end[k] = cur
                offs[k + 1] = used
                continue
            pts[used:used + m] = buf[:m]
            offs[k + 1] = used + m
            used += m
            last = buf[m - 1]
            moved = max(abs(last[0] - q[0]), abs(last[1] - q[1]), abs(last[2] - q[2])) > 1e-7
            if m > 1 or moved:
                a = p_start[k]
                sweep_gouge(tp, a[0], a[1], a[2], q[0], q[1], q[2], frame, design, t_l, search, res)
                deep = res[G_DEPTH]
                sweep_gouge(tp, q[0], q[1], q[2], q[0], q[1], q[2], frame, design, t_l, search, res)
                before[k] = max(deep, res[G_DEPTH])
                far = 0.0
                for i in range(m):
                    far = max(far, _dist_to_segment(buf[i], a, q))
                shift[k] = far
            cur = last.copy()
            end[k] = cur
        elif c == ROW_FIXED:
            a = p_start[k]
            if max(abs(cur[0] - a[0]), abs(cur[1] - a[1]), abs(cur[2] - a[2])) > 1e-7:
                status[k] = MOVED_FIXED
            cur = p_end[k].copy()
            end[k] = cur
            offs[k + 1] = used
        else:
            a = p_start[k]
            b = p_end[k]
            if max(abs(b[0] - a[0]), abs(b[1] - a[1]), abs(b[2] - a[2])) > 1e-7:
                cur = b.copy()
            end[k] = cur
            offs[k + 1] = used
    return n
