"""Numba kernels behind the error map: ray crossings of a triangle mesh and exact
point-to-triangle distances (Huang & Oliver 3.2.1, the surface near-point calculation).

All geometry here is in a frame's local coordinates (u, v, s) in mm (see
:class:`sim.frame.Frame`): rays sit at ``u = i*spacing``, ``v = j*spacing``.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _edge(ax, ay, bx, by, px, py):
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@nb.njit(cache=True, inline="always")
def _edge_c(ax, ay, bx, by, px, py):
    # Evaluated from the lexicographically smaller end so that the two triangles sharing
    # an edge get bit-identical values of opposite sign: a ray on the edge is then
    # counted exactly once (rounding alone would otherwise drop or double it).
    if ax < bx or (ax == bx and ay < by):
        return _edge(ax, ay, bx, by, px, py)
    return -_edge(bx, by, ax, ay, px, py)


@nb.njit(cache=True, inline="always")
def _top_left(ax, ay, bx, by):
    # For a counter-clockwise triangle: edges that go left (top edges) or go down (left
    # edges) own the points lying exactly on them, so a ray through a shared edge or
    # vertex is counted once.
    return (ay == by and bx < ax) or (by < ay)


@nb.njit(cache=True)
def ray_hits(tri, nu, nv, spacing, inclusive, count_only, counts, ptr, hit_s, hit_tri):
    """Crossings of the rays ``(i, j)`` with the triangles ``tri`` (n, 3, 3) local coords.

    ``count_only``: fill ``counts`` (n_rays,) int64 only. Otherwise write each hit's ``s``
    and triangle index at ``ptr[r] + k`` (``counts`` is reset to zero and used as the
    per-ray cursor). ``inclusive`` counts points on any edge (for open sheets whose
    duplicate hits are collapsed later); otherwise the top-left rule decides ties.
    """
    n = tri.shape[0]
    for t in range(n):
        ax = tri[t, 0, 0]
        ay = tri[t, 0, 1]
        bx = tri[t, 1, 0]
        by = tri[t, 1, 1]
        cx = tri[t, 2, 0]
        cy = tri[t, 2, 1]
        az = tri[t, 0, 2]
        bz = tri[t, 1, 2]
        cz = tri[t, 2, 2]
        area = _edge(ax, ay, bx, by, cx, cy)
        if area == 0.0:
            continue  # seen edge-on: no ray crosses it transversally
        if area < 0.0:  # make it counter-clockwise
            bx, cx = cx, bx
            by, cy = cy, by
            bz, cz = cz, bz
            area = -area
        umin = min(ax, bx, cx)
        umax = max(ax, bx, cx)
        vmin = min(ay, by, cy)
        vmax = max(ay, by, cy)
        i0 = max(int(np.ceil(umin / spacing - 1e-9)), 0)
        i1 = min(int(np.floor(umax / spacing + 1e-9)), nu - 1)
        j0 = max(int(np.ceil(vmin / spacing - 1e-9)), 0)
        j1 = min(int(np.floor(vmax / spacing + 1e-9)), nv - 1)
        tl0 = _top_left(bx, by, cx, cy)
        tl1 = _top_left(cx, cy, ax, ay)
        tl2 = _top_left(ax, ay, bx, by)
        eps = 1e-9 * area if inclusive else 0.0
        for j in range(j0, j1 + 1):
            py = j * spacing
            for i in range(i0, i1 + 1):
                px = i * spacing
                w0 = _edge_c(bx, by, cx, cy, px, py)
                w1 = _edge_c(cx, cy, ax, ay, px, py)
                w2 = _edge_c(ax, ay, bx, by, px, py)
                if inclusive:
                    if w0 < -eps or w1 < -eps or w2 < -eps:
                        continue
                else:
                    if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                        continue
                    if (w0 == 0.0 and not tl0) or (w1 == 0.0 and not tl1) or (w2 == 0.0 and not tl2):
                        continue
                r = j * nu + i
                if count_only:
                    counts[r] += 1
                else:
                    s = (w0 * az + w1 * bz + w2 * cz) / area
                    k = ptr[r] + counts[r]
                    hit_s[k] = s
                    hit_tri[k] = t
                    counts[r] += 1


@nb.njit(cache=True)
def sort_hits(ptr, hit_s, hit_tri):
    """Sort each ray's hits by ``s`` in place (insertion sort: rays hold few hits)."""
    for r in range(ptr.size - 1):
        a = ptr[r]
        b = ptr[r + 1]
        for k in range(a + 1, b):
            s = hit_s[k]
            t = hit_tri[k]
            m = k - 1
            while m >= a and hit_s[m] > s:
                hit_s[m + 1] = hit_s[m]
                hit_tri[m + 1] = hit_tri[m]
                m -= 1
            hit_s[m + 1] = s
            hit_tri[m + 1] = t


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
        a = ptr[r]
        b = ptr[r + 1]
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


@nb.njit(cache=True)
def bin_triangles(tri, reach, bin_size, nbu, nbv, count_only, counts, ptr, items):
    """Put every triangle in the (u, v) bins its bounding box, grown by ``reach`` mm,
    overlaps (Huang & Oliver's voxel lookup, flattened along the rays). Two passes like
    :func:`ray_hits`."""
    for t in range(tri.shape[0]):
        umin = min(tri[t, 0, 0], tri[t, 1, 0], tri[t, 2, 0]) - reach
        umax = max(tri[t, 0, 0], tri[t, 1, 0], tri[t, 2, 0]) + reach
        vmin = min(tri[t, 0, 1], tri[t, 1, 1], tri[t, 2, 1]) - reach
        vmax = max(tri[t, 0, 1], tri[t, 1, 1], tri[t, 2, 1]) + reach
        b0 = max(int(np.floor(umin / bin_size)), 0)
        b1 = min(int(np.floor(umax / bin_size)), nbu - 1)
        c0 = max(int(np.floor(vmin / bin_size)), 0)
        c1 = min(int(np.floor(vmax / bin_size)), nbv - 1)
        for c in range(c0, c1 + 1):
            for b in range(b0, b1 + 1):
                k = c * nbu + b
                if not count_only:
                    items[ptr[k] + counts[k]] = t
                counts[k] += 1


@nb.njit(cache=True, parallel=True)
def near_distances(pts, radius, tri, tri_lo, tri_hi, bin_size, nbu, nbv, bptr, bitems, out):
    """Exact distance from each point (n, 3) local coords to the mesh, searched within
    ``radius[q]`` mm; ``out[q]`` = the distance, or inf when no triangle is that close."""
    for q in nb.prange(pts.shape[0]):
        px = pts[q, 0]
        py = pts[q, 1]
        pz = pts[q, 2]
        best2 = radius[q] * radius[q]
        found = False
        b = int(np.floor(px / bin_size))
        c = int(np.floor(py / bin_size))
        if b < 0 or c < 0 or b >= nbu or c >= nbv:
            out[q] = np.inf
            continue
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
        out[q] = np.sqrt(best2) if found else np.inf
