"""Numba kernels behind the error map: nearest crossings along the rays and exact
point-to-triangle distances (Huang & Oliver 3.2.1, the surface near-point calculation).
The crossings themselves come from :func:`sim.solids.cast_triangles`.

All geometry here is in a frame's local coordinates (u, v, s) in mm (see
:class:`sim.frame.Frame`): rays sit at ``u = i*spacing``, ``v = j*spacing``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from sim.dexel_store import get_seg
from sim.solids import orient2d


@nb.njit(cache=True, inline="always")
def _nearest_crossing(hit_s, hit_tri, a, b, s):
    """Along one ray's crossings ``a <= k < b``: the distance from ``s`` to the nearest,
    its triangle (-1 if none) and how many lie above ``s``."""
    best = np.inf
    bt = -1
    above = 0
    for k in range(a, b):
        d = abs(hit_s[k] - s)
        if d < best:
            best = d
            bt = hit_tri[k]
        if hit_s[k] > s:
            above += 1
    return best, bt, above


@nb.njit(cache=True)
def vertical_errors(rays, s_pts, ptr, hit_s, hit_tri, tri_dz, sheet, out_dv, out_nz, out_inside, out_tri):
    """For each point (ray ``rays[q]``, parameter ``s_pts[q]``): the distance along the
    ray to the nearest design crossing (``out_dv``, inf when the ray misses the design),
    ``|n . d|`` of that crossing's triangle (``out_nz``), whether the point is inside the
    design (``out_inside``: odd number of crossings above it; for an open ``sheet``: below
    its top crossing) and the crossing's triangle (``out_tri``, -1 if none)."""
    for q in range(rays.size):
        r = rays[q]
        s = s_pts[q]
        best, bt, above = _nearest_crossing(hit_s, hit_tri, ptr[r], ptr[r + 1], s)
        if sheet:
            out_inside[q] = above > 0
        else:
            out_inside[q] = (above % 2) == 1
        out_dv[q] = best
        out_tri[q] = bt
        out_nz[q] = tri_dz[bt] if bt >= 0 else 0.0


@nb.njit(cache=True, inline="always")
def _dot(ax, ay, az, bx, by, bz):
    return ax * bx + ay * by + az * bz


@nb.njit(cache=True)
def point_triangle_dist2(px, py, pz, tri, t):
    """Squared distance from a point to triangle ``t`` of ``tri`` (Ericson, RTCD 5.1.5)."""
    ax = tri[t, 0, 0]
    ay = tri[t, 0, 1]
    az = tri[t, 0, 2]
    bx = tri[t, 1, 0]
    by = tri[t, 1, 1]
    bz = tri[t, 1, 2]
    cx = tri[t, 2, 0]
    cy = tri[t, 2, 1]
    cz = tri[t, 2, 2]
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = _dot(abx, aby, abz, apx, apy, apz)
    d2 = _dot(acx, acy, acz, apx, apy, apz)
    if d1 <= 0.0 and d2 <= 0.0:
        qx, qy, qz = ax, ay, az
    else:
        bpx, bpy, bpz = px - bx, py - by, pz - bz
        d3 = _dot(abx, aby, abz, bpx, bpy, bpz)
        d4 = _dot(acx, acy, acz, bpx, bpy, bpz)
        cpx, cpy, cpz = px - cx, py - cy, pz - cz
        d5 = _dot(abx, aby, abz, cpx, cpy, cpz)
        d6 = _dot(acx, acy, acz, cpx, cpy, cpz)
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx, qy, qz = bx, by, bz
        elif d6 >= 0.0 and d5 <= d6:
            qx, qy, qz = cx, cy, cz
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            qx, qy, qz = ax + v * abx, ay + v * aby, az + v * abz
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            qx, qy, qz = ax + w * acx, ay + w * acy, az + w * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx, qy, qz = bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
        else:
            den = 1.0 / (va + vb + vc)
            v = vb * den
            w = vc * den
            qx = ax + abx * v + acx * w
            qy = ay + aby * v + acy * w
            qz = az + abz * v + acz * w
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, inline="always")
def _outside_edge(ax, ay, bx, by, sign, x0, y0, x1, y1, margin):
    # all four corners of the rectangle strictly on the outer side of edge a->b (the
    # triangle's interior has edge function sign ``sign``), by more than ``margin``
    e0 = orient2d(ax, ay, bx, by, x0, y0) * sign
    e1 = orient2d(ax, ay, bx, by, x1, y0) * sign
    e2 = orient2d(ax, ay, bx, by, x0, y1) * sign
    e3 = orient2d(ax, ay, bx, by, x1, y1) * sign
    return max(e0, e1, e2, e3) < -margin


@nb.njit(cache=True)
def bin_triangles(tri, bin_size, nbu, nbv, count_only, counts, ptr, items):
    """Put every triangle in the (u, v) bins its projection along the rays overlaps.

    Bins are squares of ``bin_size`` mm from (0, 0); the outer rows and columns reach to
    infinity, so triangles beyond the frame land in the edge bins. A bin gets a triangle
    only when the projected triangle really meets it (separating-axis test), so a large
    triangle lying across the frame fills the bins along it, not its whole bounding box.
    Two passes like :func:`sim.solids.cast_triangles`: ``count_only`` fills ``counts``, otherwise
    ``items[ptr[k] + cursor]`` (``counts`` reset to zero is the cursor).
    """
    big = 1e30
    for t in range(tri.shape[0]):
        ax = tri[t, 0, 0]
        ay = tri[t, 0, 1]
        bx = tri[t, 1, 0]
        by = tri[t, 1, 1]
        cx = tri[t, 2, 0]
        cy = tri[t, 2, 1]
        umin = min(ax, bx, cx)
        umax = max(ax, bx, cx)
        vmin = min(ay, by, cy)
        vmax = max(ay, by, cy)
        b0 = min(max(int(np.floor(umin / bin_size)), 0), nbu - 1)
        b1 = min(max(int(np.floor(umax / bin_size)), 0), nbu - 1)
        c0 = min(max(int(np.floor(vmin / bin_size)), 0), nbv - 1)
        c1 = min(max(int(np.floor(vmax / bin_size)), 0), nbv - 1)
        area = orient2d(ax, ay, bx, by, cx, cy)
        ext = max(umax - umin, vmax - vmin, bin_size)
        # edge-on triangles (walls along the rays) project to a segment: keep their box
        flat = abs(area) <= 1e-12 * ext * ext
        sign = 1.0 if area > 0.0 else -1.0
        margin = 1e-9 * ext * bin_size
        for c in range(c0, c1 + 1):
            y0 = -big if c == 0 else c * bin_size
            y1 = big if c == nbv - 1 else (c + 1) * bin_size
            for b in range(b0, b1 + 1):
                if not flat and (b1 > b0 or c1 > c0):
                    x0 = -big if b == 0 else b * bin_size
                    x1 = big if b == nbu - 1 else (b + 1) * bin_size
                    if (_outside_edge(ax, ay, bx, by, sign, x0, y0, x1, y1, margin)
                            or _outside_edge(bx, by, cx, cy, sign, x0, y0, x1, y1, margin)
                            or _outside_edge(cx, cy, ax, ay, sign, x0, y0, x1, y1, margin)):
                        continue
                k = c * nbu + b
                if not count_only:
                    items[ptr[k] + counts[k]] = t
                counts[k] += 1


@nb.njit(cache=True, inline="always")
def _nearest(px, py, pz, best2, seed, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems):
    """Smallest squared distance from the point to the mesh if below ``best2``, else
    ``best2``; with a flag saying whether any triangle came that close. ``seed`` (a
    triangle known to be near, -1 for none) is tried first so the search radius shrinks
    before the bins are scanned."""
    found = False
    if seed >= 0:
        d2 = point_triangle_dist2(px, py, pz, tri, seed)
        if d2 <= best2:
            best2 = d2
            found = True
    r = np.sqrt(best2)
    b0 = min(max(int(np.floor((px - r) / bin_size)), 0), nbu - 1)
    b1 = min(max(int(np.floor((px + r) / bin_size)), 0), nbu - 1)
    c0 = min(max(int(np.floor((py - r) / bin_size)), 0), nbv - 1)
    c1 = min(max(int(np.floor((py + r) / bin_size)), 0), nbv - 1)
    for c in range(c0, c1 + 1):
        for b in range(b0, b1 + 1):
            k = c * nbu + b
            for m in range(bptr[k], bptr[k + 1]):
                t = bitems[m]
                # distance to the triangle's box first: most candidates end here
                dx = max(tri_lo[t, 0] - px, 0.0, px - tri_hi[t, 0])
                dy = max(tri_lo[t, 1] - py, 0.0, py - tri_hi[t, 1])
                dz = max(tri_lo[t, 2] - pz, 0.0, pz - tri_hi[t, 2])
                if dx * dx + dy * dy + dz * dz > best2:
                    continue
                d2 = point_triangle_dist2(px, py, pz, tri, t)
                if d2 <= best2:
                    best2 = d2
                    found = True
    return best2, found


@nb.njit(cache=True)
def near_distances(pts, radius, seed, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems, out):
    """Exact distance from each point (n, 3) local coords to the mesh, searched within
    ``radius[q]`` mm; ``out[q]`` = the distance, or inf when no triangle is that close.
    ``seed[q]``: a triangle to try first (-1: none). Bins from :func:`bin_triangles`."""
    for q in range(pts.shape[0]):
        best2, found = _nearest(pts[q, 0], pts[q, 1], pts[q, 2], radius[q] * radius[q], seed[q],
                                tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems)
        out[q] = np.sqrt(best2) if found else np.inf


@nb.njit(cache=True)
def point_errors(rays, s_pts, nu, spacing, ptr, hit_s, hit_tri, tri_dz, sheet, limit_in, limit_out,
                 search, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems, out_err, out_dv):
    """Signed error (mm) of each dexel point (ray ``rays[q]``, parameter ``s_pts[q]``).

    Huang's estimate first: the distance ``dv`` along the ray to the nearest crossing
    times ``|n . d|`` of its triangle. The exact near-point distance replaces it only when
    ``dv`` exceeds the limit of the point's side (``limit_in`` inside the design,
    ``limit_out`` outside): the crossing is a surface point, so the true distance is at
    most ``dv`` and a point with ``dv`` within the limit is within it for certain. The
    exact search looks within ``min(dv, search)`` starting from the crossing's triangle;
    when nothing is that close the point keeps ``dv``. Negative inside (gouge), positive
    outside; ``+inf`` on rays that miss the design. ``out_dv`` gets ``dv``.
    """
    for q in range(rays.size):
        out_err[q], out_dv[q] = _point_error(rays[q], s_pts[q], nu, spacing, ptr, hit_s, hit_tri, tri_dz, sheet,
                                             limit_in, limit_out, search, tri, tri_lo, tri_hi, bin_size, nbu,
                                             nbv, bptr, bitems)


@nb.njit(cache=True, inline="always")
def _point_error(r, s, nu, spacing, ptr, hit_s, hit_tri, tri_dz, sheet, limit_in, limit_out, search, tri,
                 tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems):
    """``(signed error, dv)`` of the point at ``s`` on design ray ``r`` (see
    :func:`point_errors`)."""
    best, bt, above = _nearest_crossing(hit_s, hit_tri, ptr[r], ptr[r + 1], s)
    if bt < 0:
        return np.inf, best
    inside = (above > 0) if sheet else ((above % 2) == 1)
    limit = limit_in if inside else limit_out
    err = best * tri_dz[bt]
    if best > limit:
        rad = min(best, search)
        px = (r % nu) * spacing
        py = (r // nu) * spacing
        best2, found = _nearest(px, py, s, rad * rad, bt, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems)
        err = np.sqrt(best2) if found else best
    return (-err if inside else err), best


@nb.njit(cache=True)
def update_rays(S, rays, design_rays, cut_only, nu, spacing, ptr, hit_s, hit_tri, tri_dz, sheet, limit_in,
                limit_out, search, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems, gouge, gouge_id,
                gouge_s, gouge_len, excess, excess_id, excess_s, excess_len):
    """The error map of rays ``rays`` of the dexel store ``S`` in one pass: every face of
    their segments (``cut_only``: only faces with an id, i.e. a move made them) assessed
    with :func:`point_errors` on design ray ``design_rays[q]``, and per ray the most
    negative and the most positive error kept: ``gouge = min(err, 0)`` and ``excess =
    max(err, 0)`` with the face id and ``s`` of that point, ``*_len`` its ``dv`` when the
    error has that sign, else 0. The near faces are looked at before the far faces and the
    first of equal errors wins. Rays with no assessed face get NaN in ``gouge`` and
    ``excess``."""
    for q in range(rays.size):
        r = rays[q]
        dr = design_rays[q]
        gouge[r] = np.nan
        excess[r] = np.nan
        lo_e = 0.0
        hi_e = 0.0
        lo_dv = 0.0
        hi_dv = 0.0
        lo_s = 0.0
        hi_s = 0.0
        lo_id = 0
        hi_id = 0
        seen = False
        for far in range(2):
            for k in range(S[0][r]):
                n, f, nid, fid = get_seg(S, r, k)
                pid = fid if far else nid
                if cut_only and pid == 0:
                    continue
                ps = np.float64(f) if far else np.float64(n)
                e, dv = _point_error(dr, ps, nu, spacing, ptr, hit_s, hit_tri, tri_dz, sheet, limit_in,
                                     limit_out, search, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems)
                if not seen or e < lo_e:
                    lo_e, lo_dv, lo_s, lo_id = e, dv, ps, pid
                if not seen or e > hi_e:
                    hi_e, hi_dv, hi_s, hi_id = e, dv, ps, pid
                seen = True
        if not seen:
            continue
        gouge[r] = min(lo_e, 0.0)
        gouge_id[r] = lo_id
        gouge_s[r] = lo_s
        gouge_len[r] = lo_dv if lo_e < 0.0 else 0.0
        excess[r] = max(hi_e, 0.0)
        excess_id[r] = hi_id
        excess_s[r] = hi_s
        excess_len[r] = hi_dv if hi_e > 0.0 else 0.0


@nb.njit(cache=True)
def tool_reach_floor(z, di, dj, dh, mi, mj, max_steps):
    """The lowest a vertical tool's lower face reaches over rays ``(mi, mj)`` of a height
    field without cutting into it: the field closed by the tool (its gouge-free tip
    heights, then the surface those tips sweep).

    z: float64 (nv, nu) design heights (mm, -inf where there is no design); di, dj: int64
    (k,) ray offsets of the tool's footprint (a disc of its cutting radius), dh: float64
    (k,) the tool's lowest height above its tip there; mi, mj: int64 (m,) the rays asked
    for. Returns (float64 (m,), bool): the lowest ``tip + dh`` over the tips whose
    footprint covers each ray, each tip the highest ``z - dh`` under its footprint
    (computed once, for the tips near the rays asked for only); False, and the rays not
    all measured, when that took more than ``max_steps`` footprint steps. The field must
    reach two cutting radii past the rays asked for: a tip off its edge is not tried."""
    nv, nu = z.shape
    tip = np.full((nv, nu), np.nan)
    out = np.full(mi.size, np.nan)
    steps = 0
    for q in range(mi.size):
        best = np.inf
        steps += di.size
        for k in range(di.size):
            tj = mj[q] - dj[k]
            ti = mi[q] - di[k]
            if not (0 <= tj < nv and 0 <= ti < nu):
                continue
            t = tip[tj, ti]
            if t != t:   # not computed yet
                t = -np.inf
                steps += di.size
                for kk in range(di.size):
                    jj = tj + dj[kk]
                    ii = ti + di[kk]
                    if 0 <= jj < nv and 0 <= ii < nu:
                        v = z[jj, ii] - dh[kk]
                        if v > t:
                            t = v
                tip[tj, ti] = t
            v = t + dh[k]
            if v < best:
                best = v
        out[q] = best
        if steps > max_steps:
            return out, False
    return out, True
