"""What the two batch cuts (:mod:`.linear`, :mod:`.poses`) share: the statuses a batch
kernel returns, the int64 state it resumes from, which rays of a row are within reach
(:func:`_stadium_span`, :data:`REACH_PAD`) and the length a probe measures on a ray.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from sim import dexel_store as ds


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


@nb.njit(cache=True, inline="always")
def _save(state, k, j, i, nout, mc):
    state[0] = k
    state[1] = j
    state[2] = i
    state[3] = nout
    state[4] = mc
