"""Union, intersection and difference of dexel grids on the same rays (Huang & Oliver 2.3).

On a shared frame a regularised Boolean reduces to one-dimensional work per ray: merge
the two sorted segment lists and keep where the operator holds. Every face of the result
is a face of one operand and keeps that operand's id (the move that made it), so a face
cut by the tool in ``a - tool`` carries the tool's id.

Pieces not longer than ``tol.length`` vanish and gaps not longer than it close, as in
the store's own kernels (:mod:`sim.dexel_store`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim.errors import InputError
from sim.grid import DexelGrid

UNION = 0
INTERSECTION = 1
DIFFERENCE = 2


def _check(a: DexelGrid, b: DexelGrid, what: str) -> None:
    if not isinstance(a, DexelGrid) or not isinstance(b, DexelGrid):
        raise InputError(f"{what} needs two DexelGrids, got {type(a).__name__} and {type(b).__name__}")
    if not a.frame.same_rays(b.frame):
        fa, fb = a.frame, b.frame
        raise InputError(
            f"{what} needs grids on the same rays; got {fa.nu}x{fa.nv} at {fa.spacing} mm "
            f"(origin {np.round(fa.origin, 4).tolist()}, direction {np.round(fa.direction, 4).tolist()}) "
            f"and {fb.nu}x{fb.nv} at {fb.spacing} mm (origin {np.round(fb.origin, 4).tolist()}, "
            f"direction {np.round(fb.direction, 4).tolist()})")


@nb.njit(cache=True, inline="always")
def _op(op, in_a, in_b):
    if op == 0:
        return in_a or in_b
    if op == 1:
        return in_a and in_b
    return in_a and not in_b


@nb.njit(cache=True, inline="always")
def _gather_ray(S, r, n, f, ni, fi):
    c = S[0][r]
    for k in range(c):
        n[k], f[k], ni[k], fi[k] = ds.get_seg(S, r, k)
    return c


@nb.njit(cache=True)
def _sweep(op, eps, an, af, ani, afi, ca, bn, bf, bni, bfi, cb, on, of, oni, ofi, o):
    """Write ``A op B`` for one ray into the outputs from slot ``o``; return the count.

    Sweep over the boundaries of both operands in order of s; at a common s all events
    are applied before the result is judged, so coincident faces cancel cleanly. A new
    result face takes the id of the operand that has a face there (``a`` first).
    """
    ka = 0  # boundary index into a: segment ka // 2, its near face if ka is even
    kb = 0
    in_a = False
    in_b = False
    inside = False
    m = 0
    start = 0.0
    start_id = np.int32(0)
    while ka < 2 * ca or kb < 2 * cb:
        sa = np.inf
        sb = np.inf
        ida = np.int32(0)
        idb = np.int32(0)
        if ka < 2 * ca:
            h = ka >> 1
            if ka & 1:
                sa = np.float64(af[h])
                ida = afi[h]
            else:
                sa = np.float64(an[h])
                ida = ani[h]
        if kb < 2 * cb:
            h = kb >> 1
            if kb & 1:
                sb = np.float64(bf[h])
                idb = bfi[h]
            else:
                sb = np.float64(bn[h])
                idb = bni[h]
        s = min(sa, sb)
        face_id = idb
        if sb == s:
            in_b = (kb & 1) == 0
            kb += 1
        if sa == s:  # a's id wins a tie
            in_a = (ka & 1) == 0
            ka += 1
            face_id = ida
        now = _op(op, in_a, in_b)
        if now and not inside:
            if m > 0 and s - of[o + m - 1] <= eps:
                m -= 1  # reopen: the gap is too small to be real
                start = np.float64(on[o + m])
                start_id = oni[o + m]
            else:
                start = s
                start_id = face_id
            inside = True
        elif inside and not now:
            inside = False
            if s - start > eps:
                on[o + m] = np.float32(start)
                of[o + m] = np.float32(s)
                oni[o + m] = start_id
                ofi[o + m] = face_id
                m += 1
    return m


@nb.njit(cache=True)
def _combine_all(SA, SB, op, eps, offsets, out_counts, on, of, oni, ofi):
    ma = max(1, np.int64(SA[0].max())) if SA[0].size else 1
    mb = max(1, np.int64(SB[0].max())) if SB[0].size else 1
    an = np.empty(ma, np.float32)
    af = np.empty(ma, np.float32)
    ani = np.empty(ma, np.int32)
    afi = np.empty(ma, np.int32)
    bn = np.empty(mb, np.float32)
    bf = np.empty(mb, np.float32)
    bni = np.empty(mb, np.int32)
    bfi = np.empty(mb, np.int32)
    for r in range(out_counts.size):
        ca = _gather_ray(SA, r, an, af, ani, afi)
        cb = _gather_ray(SB, r, bn, bf, bni, bfi)
        out_counts[r] = _sweep(op, eps, an, af, ani, afi, ca, bn, bf, bni, bfi, cb,
                               on, of, oni, ofi, offsets[r])


def _combine(a: DexelGrid, b: DexelGrid, op: int, what: str) -> DexelGrid:
    from sim.solids import grid_from_segments, pack_segments  # solids builds on this module's grids

    _check(a, b, what)
    cap = a.store["count"].astype(np.int64) + b.store["count"].astype(np.int64)
    offsets = np.zeros(cap.size, np.int64)
    np.cumsum(cap[:-1], out=offsets[1:])
    total = int(cap.sum())
    on = np.empty(total, np.float32)
    of = np.empty(total, np.float32)
    oni = np.empty(total, np.int32)
    ofi = np.empty(total, np.int32)
    counts = np.zeros(cap.size, np.int64)
    _combine_all(a.S, b.S, op, a.tol.length, offsets, counts, on, of, oni, ofi)
    return grid_from_segments(a.frame, counts, *pack_segments(offsets, counts, on, of, oni, ofi), a.tol)


def union(a: DexelGrid, b: DexelGrid) -> DexelGrid:
    """A new grid holding the material of ``a`` or ``b`` (same frame required)."""
    return _combine(a, b, UNION, "union")


def intersection(a: DexelGrid, b: DexelGrid) -> DexelGrid:
    """A new grid holding the material in both ``a`` and ``b`` (same frame required)."""
    return _combine(a, b, INTERSECTION, "intersection")


def difference(a: DexelGrid, b: DexelGrid) -> DexelGrid:
    """A new grid holding the material of ``a`` not in ``b``; faces cut by ``b`` carry b's ids."""
    return _combine(a, b, DIFFERENCE, "difference")


@nb.njit(cache=True)
def _overlap_all(SA, SB, out):
    ma = max(1, np.int64(SA[0].max())) if SA[0].size else 1
    mb = max(1, np.int64(SB[0].max())) if SB[0].size else 1
    an = np.empty(ma, np.float32)
    af = np.empty(ma, np.float32)
    ai = np.empty(ma, np.int32)
    bn = np.empty(mb, np.float32)
    bf = np.empty(mb, np.float32)
    bi = np.empty(mb, np.int32)
    for r in range(out.size):
        ca = _gather_ray(SA, r, an, af, ai, ai)
        cb = _gather_ray(SB, r, bn, bf, bi, bi)
        ka = 0
        kb = 0
        total = 0.0
        while ka < ca and kb < cb:
            lo = max(np.float64(an[ka]), np.float64(bn[kb]))
            hi = min(np.float64(af[ka]), np.float64(bf[kb]))
            if hi > lo:
                total += hi - lo
            if af[ka] < bf[kb]:
                ka += 1
            else:
                kb += 1
        out[r] = total


def overlap_length(a: DexelGrid, b: DexelGrid) -> np.ndarray:
    """Length of ``a`` and ``b`` in common on every ray: float32 (nv, nu), mm.

    ``overlap_length(stock, tool)`` is the depth of material the tool would take on each
    ray (collision and gouge depth); summed times spacing^2 it is ``intersection`` volume.
    """
    _check(a, b, "overlap_length")
    out = np.empty(a.frame.n_rays, np.float64)
    _overlap_all(a.S, b.S, out)
    return out.astype(np.float32).reshape(a.frame.shape)


def complement(a: DexelGrid, lo: float, hi: float, face_id: int = 0) -> DexelGrid:
    """What ``[lo, hi]`` on every ray holds outside ``a`` (new faces at lo/hi get ``face_id``).

    ``lo``/``hi`` are ray parameters s in mm bounding the universe; a's material must lie
    within them. Useful for identities: ``a - b == a & complement(b)``.
    """
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise InputError(f"complement needs lo < hi (mm), got {lo}, {hi}")
    shape = a.frame.shape
    universe = DexelGrid.from_intervals(a.frame, np.full(shape, lo), np.full(shape, hi),
                                        face_id, a.tol)
    return difference(universe, a)
