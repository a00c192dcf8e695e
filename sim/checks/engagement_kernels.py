"""Numba kernels behind :class:`sim.checks.engagement.Engagement`: the tool's lowest
point over each ray for one straight piece of the tip path, and the walk of the pieces
that lowers a top-view height map under the tool and records, per move, the thickest
cut at any ray and under the tool centre, and where an arc enters material.

Heights and positions are machine coordinates in mm; the height map is the stock's top
seen from above (``DexelGrid.top()`` flattened, NaN where empty).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from sim import dexel_store as ds


#: lower-envelope shapes with a closed form (anything else uses the sampled envelope)
SHAPE_TABLE, SHAPE_BALL, SHAPE_FLAT = 0, 1, 2  # literal ints: numba folds them


@nb.njit(cache=True, inline="always", error_model="numpy")
def _env(d, inv_dstep, env_h):
    # the tool's lower envelope at distance d from the axis (linear in the table)
    nenv = env_h.size
    f = d * inv_dstep
    m = int(f)
    if m >= nenv - 1:
        return env_h[nenv - 1]
    return env_h[m] + (env_h[m + 1] - env_h[m]) * (f - m)


@nb.njit(cache=True, error_model="numpy")
def piece_frames(p0, p1):
    """Per straight tip piece (m, 3) -> (m, 8) float64: start x y z (the lower end's z
    for a vertical piece), unit XY direction ux uy, slope dz/dxy, sin of the descent
    angle, XY length (0 for a vertical piece)."""
    out = np.empty((p0.shape[0], 8))
    for q in range(p0.shape[0]):
        x0, y0, z0 = p0[q, 0], p0[q, 1], p0[q, 2]
        dx, dy, dz = p1[q, 0] - x0, p1[q, 1] - y0, p1[q, 2] - z0
        ell = np.sqrt(dx * dx + dy * dy)
        if ell > 1e-9:
            out[q, 3] = dx / ell
            out[q, 4] = dy / ell
            out[q, 5] = dz / ell
            out[q, 6] = dz / np.sqrt(ell * ell + dz * dz)
            out[q, 7] = ell
        else:  # vertical: the lowest tip position is all that counts
            z0 = min(z0, z0 + dz)
            out[q, 3] = 1.0
            out[q, 4] = 0.0
            out[q, 5] = 0.0
            out[q, 6] = 0.0
            out[q, 7] = 0.0
        out[q, 0] = x0
        out[q, 1] = y0
        out[q, 2] = z0
    return out


@nb.njit(cache=True, inline="always", error_model="numpy")
def _bottom(shape, rx, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep, env_h, h_min, monotone):
    """Lowest point of the tool over a ray for one straight piece, and the ray's squared
    XY distance to the axis path: ``(s, d2)``, ``s = inf`` when the tool misses the ray.

    ``(rx, ry)``: the ray relative to the piece's start (mm); the piece frame as made by
    :func:`piece_frames`. Ball and flat ends are exact (the lowest point over the ray of
    the swept sphere / disc, as the cutter sweeps them); other tools try the nearest
    axis position and the lower end on the sampled envelope ``env_h``. Rays up to
    ``slack`` mm outside the tool's reach count as reached at its rim (the cutter rounds
    differently on the boundary; a ray it cut must not keep its old height here).
    """
    a = rx * ux + ry * uy       # along the piece
    e = -rx * uy + ry * ux      # across it
    ac = min(max(a, 0.0), ell) - a
    d2 = e * e + ac * ac
    qc = R2 - e * e
    if shape == SHAPE_BALL or shape == SHAPE_FLAT:
        rho = np.sqrt(max(qc, 0.0))
        s_lo = max(a - rho, 0.0)
        s_hi = min(a + rho, ell)
        if shape == SHAPE_BALL:
            s = min(max(a - rho * sin_t, s_lo), max(s_hi, s_lo))
            w = a - s
            v = z0 + m * s + R - np.sqrt(max(rho * rho - w * w, 0.0))
        else:
            v = z0 + min(m * s_lo, m * max(s_hi, s_lo))
        return (v if (qc >= -2.0 * R * slack) & (s_lo <= s_hi + slack) else np.inf), d2
    if d2 > R2 + 2.0 * R * slack:
        return np.inf, d2
    t = min(max(a, 0.0), ell)
    best = z0 + m * t + _env(np.sqrt(d2), inv_dstep, env_h)
    # an end lower than best by less than the envelope's floor cannot win; with a
    # monotone envelope only the lower end can win at all
    for c in range(2):
        if c == 0:
            if monotone and m > 0.0:
                continue
            tc = 0.0
        else:
            if monotone and m <= 0.0:
                continue
            tc = ell
        zc = z0 + m * tc
        if zc + h_min >= best:
            continue
        e2 = (a - tc) * (a - tc) + e * e
        if e2 > R2 + 2.0 * R * slack:
            continue
        z = zc + _env(np.sqrt(e2), inv_dstep, env_h)
        if z < best:
            best = z
    return best, d2


@nb.njit(cache=True, inline="always", error_model="numpy")
def _cut_run(top, r0, n, rx0, ry, sp, shape, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep, env_h,
             h_min, monotone, core2):
    """Lower ``n`` consecutive rays of one grid row (``top[r0:r0 + n]``, the first at
    ``rx0, ry`` from the piece start) under one piece; ``(thickest cut, thickest cut
    within the core)``. One loop per shape, branch-free, so that it vectorises."""
    dk = 0.0
    ck = 0.0
    if shape == SHAPE_BALL:
        for q in range(n):
            v, d2 = _bottom(SHAPE_BALL, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0  # False for empty rays (NaN) and rays the tool misses (inf)
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    elif shape == SHAPE_FLAT:
        for q in range(n):
            v, d2 = _bottom(SHAPE_FLAT, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    else:
        for q in range(n):
            v, d2 = _bottom(SHAPE_TABLE, rx0 + q * sp, ry, z0, ux, uy, m, sin_t, ell, R, R2, slack, inv_dstep,
                            env_h, h_min, monotone)
            t_old = top[r0 + q]
            cut = t_old - v
            good = cut > 0.0
            top[r0 + q] = v if good else t_old
            c = cut if good else 0.0
            dk = max(dk, c)
            ck = max(ck, c if d2 <= core2 else 0.0)
    return dk, ck


@nb.njit(cache=True, inline="always")
def _piece_box(x0, y0, sp, nu, nv, pf, q, R):
    """``(i0, i1, j0, j1)``: the grid columns and rows under piece ``q`` widened by ``R``."""
    ax, ay = pf[q, 0], pf[q, 1]
    bx = ax + pf[q, 3] * pf[q, 7]
    by = ay + pf[q, 4] * pf[q, 7]
    i0 = max(int(np.ceil((min(ax, bx) - R - x0) / sp)), 0)
    i1 = min(int(np.floor((max(ax, bx) + R - x0) / sp)), nu - 1)
    j0 = max(int(np.ceil((min(ay, by) - R - y0) / sp)), 0)
    j1 = min(int(np.floor((max(ay, by) + R - y0) / sp)), nv - 1)
    return i0, i1, j0, j1


@nb.njit(cache=True, inline="always")
def _enters(v, d2, t_old, core2):
    """A piece whose tool bottom ``v`` over a ray ``d2`` (squared) from its axis path
    cuts that ray's material (top ``t_old``, NaN empty) under the tool centre."""
    return d2 <= core2 and v < t_old


@nb.njit(cache=True, error_model="numpy")
def _entry_top(top, x0, y0, sp, nu, nv, pf, q, shape, R, R2, slack, inv_dstep, env_h, h_min, monotone, core2):
    """The highest material top (mm) that piece ``q`` cuts under the tool centre (where it
    enters material), NaN when it cuts none there; ``top`` is not changed."""
    i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
    hi = np.nan
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            r = j * nu + i
            v, d2 = _bottom(shape, x0 + i * sp - pf[q, 0], y0 + j * sp - pf[q, 1], pf[q, 2], pf[q, 3], pf[q, 4],
                            pf[q, 5], pf[q, 6], pf[q, 7], R, R2, slack, inv_dstep, env_h, h_min, monotone)
            if _enters(v, d2, top[r], core2) and not top[r] <= hi:
                hi = top[r]
    return hi


@nb.njit(cache=True, error_model="numpy")
def engage(top, x0, y0, sp, nu, nv, pf, row, piece_ptr, shape, R, slack, env_d, env_h, core, doc, core_depth,
            entry_q, entry_top):
    """Walk the pieces in order on the top-surface heights ``top`` (nv*nu float64, NaN =
    no material), lowering it under the tool and recording per row the largest material
    thickness cut at any ray (``doc``) and at rays within ``core`` of the axis path
    (``core_depth``). Every ray under each piece's box is looked at (used without a cut
    result). ``pf``: piece frames (:func:`piece_frames`). For an arc (more than one
    piece, ``piece_ptr`` as in :func:`engage_changed`) the first piece that cuts under
    the tool centre and the highest top it cuts there are ``entry_q[k]``/``entry_top[k]``
    (-1 / NaN on entry: where the arc enters material)."""
    inv_dstep = 1.0 / (env_d[1] - env_d[0])
    h_min = env_h.min()
    monotone = np.all(env_h[1:] >= env_h[:-1])
    R2 = R * R
    core2 = core * core
    for q in range(pf.shape[0]):
        k = row[q]
        if entry_q[k] < 0 and piece_ptr[k + 1] - piece_ptr[k] > 1:
            t_in = _entry_top(top, x0, y0, sp, nu, nv, pf, q, shape, R, R2, slack, inv_dstep, env_h, h_min,
                              monotone, core2)
            if not np.isnan(t_in):
                entry_q[k] = q
                entry_top[k] = t_in
        i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
        for j in range(j0, j1 + 1):
            if i1 < i0:
                break
            r0 = j * nu + i0
            dk, ck = _cut_run(top, r0, i1 - i0 + 1, x0 + i0 * sp - pf[q, 0], y0 + j * sp - pf[q, 1], sp,
                              shape, pf[q, 2], pf[q, 3], pf[q, 4], pf[q, 5], pf[q, 6], pf[q, 7], R, R2,
                              slack, inv_dstep, env_h, h_min, monotone, core2)
            doc[k] = max(doc[k], dk)
            core_depth[k] = max(core_depth[k], ck)


@nb.njit(cache=True, error_model="numpy")
def engage_changed(top, x0, y0, sp, nu, nv, pf, piece_ptr, shape, R, slack, env_d, env_h, core, chg_ptr,
                    chg_rays,
                    best_buf, dmin_buf, doc, core_depth, entry_q, entry_top):
    """Like :func:`engage`, but row ``k`` looks only at the rays its real cut changed,
    ``chg_rays[chg_ptr[k]:chg_ptr[k + 1]]`` (sorted; a ray the tool did not change lost
    nothing), and a row's cut at a ray is measured against the lowest of all its pieces
    (an arc's entry, ``entry_q``/``entry_top``, as :func:`engage` finds it).

    ``piece_ptr`` (n_rows + 1,): row ``k``'s pieces are ``piece_ptr[k]:piece_ptr[k + 1]``.
    ``best_buf`` / ``dmin_buf`` (n_rays,) float64 scratch, NaN on entry and on return.
    """
    inv_dstep = 1.0 / (env_d[1] - env_d[0])
    h_min = env_h.min()
    monotone = np.all(env_h[1:] >= env_h[:-1])
    R2 = R * R
    core2 = core * core
    for k in range(doc.size):
        qa = piece_ptr[k]
        qb = piece_ptr[k + 1]
        ca = chg_ptr[k]
        cb = chg_ptr[k + 1]
        if qa == qb or ca == cb:
            continue
        if qb - qa == 1:  # a line: through its changed rays, a row's run at a time
            dk = doc[k]
            ck = core_depth[k]
            m = ca
            while m < cb:
                r0 = chg_rays[m]
                j = r0 // nu
                i0 = r0 - j * nu
                e = m + 1
                while e < cb and chg_rays[e] == r0 + (e - m) and i0 + (e - m) < nu:
                    e += 1
                d1, c1 = _cut_run(top, r0, e - m, x0 + i0 * sp - pf[qa, 0], y0 + j * sp - pf[qa, 1], sp,
                                  shape, pf[qa, 2], pf[qa, 3], pf[qa, 4], pf[qa, 5], pf[qa, 6], pf[qa, 7], R, R2,
                                  slack, inv_dstep, env_h, h_min, monotone, core2)
                dk = max(dk, d1)
                ck = max(ck, c1)
                m = e
            doc[k] = dk
            core_depth[k] = ck
            continue
        # chords of an arc: mark the changed rays, let every chord lower its marks
        for m in range(ca, cb):
            r = chg_rays[m]
            best_buf[r] = np.inf
            dmin_buf[r] = np.inf
        for q in range(qa, qb):
            ax, ay = pf[q, 0], pf[q, 1]
            i0, i1, j0, j1 = _piece_box(x0, y0, sp, nu, nv, pf, q, R)
            # the heights are this row's before it: the first piece cutting under the
            # centre is where the arc enters material
            entering = entry_q[k] < 0 or entry_q[k] == q
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    r = j * nu + i
                    if np.isnan(best_buf[r]):
                        continue
                    v, d2 = _bottom(shape, x0 + i * sp - ax, y0 + j * sp - ay, pf[q, 2], pf[q, 3], pf[q, 4],
                                    pf[q, 5], pf[q, 6], pf[q, 7], R, R2, slack, inv_dstep, env_h, h_min,
                                    monotone)
                    if v < best_buf[r]:
                        best_buf[r] = v
                    if d2 < dmin_buf[r]:
                        dmin_buf[r] = d2
                    if entering and _enters(v, d2, top[r], core2) and not top[r] <= entry_top[k]:
                        entry_q[k] = q
                        entry_top[k] = top[r]
        for m in range(ca, cb):
            r = chg_rays[m]
            best = best_buf[r]
            d2 = dmin_buf[r]
            best_buf[r] = np.nan
            dmin_buf[r] = np.nan
            t_old = top[r]
            if np.isnan(t_old) or not best < t_old:
                continue
            cut = t_old - best
            if cut > doc[k]:
                doc[k] = cut
            if d2 <= core2 and cut > core_depth[k]:
                core_depth[k] = cut
            top[r] = best


@nb.njit(cache=True)
def resync_top(S, rays, top, mark):
    """``top[r]`` = the real model's top of every ray in ``rays`` (NaN where empty), each
    distinct ray once (``mark`` (n_rays,) float64 scratch, NaN on entry and on return)."""
    for m in range(rays.size):
        r = rays[m]
        if np.isnan(mark[r]):
            mark[r] = 0.0
            top[r] = ds.ray_top(S, r)
    for m in range(rays.size):
        mark[rays[m]] = np.nan
