"""Per-ray segment storage and the 1-D Boolean kernels on it (numba).

Layout (``n`` rays, flat index ``r = j*nu + i``)::

    count[r]                      int16   segments on the ray
    near[r], far[r]               float32 first segment [near, far], s in mm
    near_id[r], far_id[r]         int32   id of the move that made each face (0 = stock)
    xstart[r], xcap[r]            int32   block in the pool holding segments 1..count-1
    pool_near/far/near_id/far_id  (P,)    the pool; ``pool_top[0]`` = first free slot
                                          (a second element, if any, ends the free range)

Segments on a ray are sorted, disjoint and longer than ``eps``. Most rays hold one
segment, which lives in the dense first-segment arrays; only rays that need more get a
block in the pool (capacity doubling, old block abandoned until :func:`compact`), so
storage grows only where undercuts and tilted cuts split rays.

The kernels here do one ray at a time and never allocate on the one-segment fast path.
A kernel that needs a pool slot when the pool is full returns ``POOL_FULL`` having changed
nothing; the Python wrapper grows the pool and calls again.
"""

from __future__ import annotations

import numba as nb
import numpy as np

POOL_FULL = -1.0

STORE_FIELDS = ("count", "near", "far", "near_id", "far_id", "xstart", "xcap",
                "pool_near", "pool_far", "pool_near_id", "pool_far_id", "pool_top")


def new_store(n_rays: int, pool_capacity: int = 1024) -> dict[str, np.ndarray]:
    """Arrays of an empty store of ``n_rays`` rays (no material anywhere)."""
    return {
        "count": np.zeros(n_rays, np.int16),
        "near": np.zeros(n_rays, np.float32),
        "far": np.zeros(n_rays, np.float32),
        "near_id": np.zeros(n_rays, np.int32),
        "far_id": np.zeros(n_rays, np.int32),
        "xstart": np.full(n_rays, -1, np.int32),
        "xcap": np.zeros(n_rays, np.int32),
        "pool_near": np.zeros(pool_capacity, np.float32),
        "pool_far": np.zeros(pool_capacity, np.float32),
        "pool_near_id": np.zeros(pool_capacity, np.int32),
        "pool_far_id": np.zeros(pool_capacity, np.int32),
        "pool_top": np.zeros(1, np.int64),
    }


def store_tuple(store: dict[str, np.ndarray]) -> tuple:
    """The arrays in kernel argument order (numba takes the tuple as one argument)."""
    return tuple(store[k] for k in STORE_FIELDS)


def grow_pool(store: dict[str, np.ndarray], min_free: int) -> None:
    """Enlarge the pool in place (dict entries replaced) so ``min_free`` slots are free."""
    top = int(store["pool_top"][0])
    cap = store["pool_near"].size
    need = top + min_free
    if need <= cap:
        return
    new_cap = max(need, 2 * cap, 1024)
    for key in ("pool_near", "pool_far", "pool_near_id", "pool_far_id"):
        old = store[key]
        new = np.zeros(new_cap, old.dtype)
        new[:top] = old[:top]
        store[key] = new


def compact(store: dict[str, np.ndarray]) -> None:
    """Drop abandoned pool blocks; each multi-segment ray keeps exactly what it needs."""
    count = store["count"]
    multi = np.nonzero(count > 1)[0]
    sizes = count[multi].astype(np.int64) - 1
    total = int(sizes.sum())
    starts = np.zeros(len(multi), np.int64)
    if len(multi):
        starts[1:] = np.cumsum(sizes)[:-1]
    new = {k: np.zeros(max(total, 1024), store[k].dtype)
           for k in ("pool_near", "pool_far", "pool_near_id", "pool_far_id")}
    old_start = store["xstart"][multi].astype(np.int64)
    for r_i, (o, s, n) in enumerate(zip(old_start, starts, sizes)):
        for k in new:
            new[k][s:s + n] = store[k][o:o + n]
    xstart = np.full_like(store["xstart"], -1)
    xcap = np.zeros_like(store["xcap"])
    xstart[multi] = starts
    xcap[multi] = sizes
    store.update(new)
    store["xstart"] = xstart
    store["xcap"] = xcap
    store["pool_top"] = np.array([total], np.int64)


@nb.njit(cache=True, inline="always")
def get_seg(S, r, k):
    """Segment ``k`` of ray ``r`` as (near, far, near_id, far_id)."""
    if k == 0:
        return S[1][r], S[2][r], S[3][r], S[4][r]
    p = S[5][r] + k - 1
    return S[7][p], S[8][p], S[9][p], S[10][p]


@nb.njit(cache=True, inline="always")
def _put_seg(S, r, k, n, f, nid, fid):
    if k == 0:
        S[1][r] = n
        S[2][r] = f
        S[3][r] = nid
        S[4][r] = fid
    else:
        p = S[5][r] + k - 1
        S[7][p] = n
        S[8][p] = f
        S[9][p] = nid
        S[10][p] = fid


@nb.njit(cache=True)
def _reserve(S, r, n_segments):
    """Make room for ``n_segments`` on ray ``r``; False (nothing changed) if the pool is full."""
    need = n_segments - 1
    if need <= S[6][r]:
        return True
    cap = max(need, 2 * S[6][r], 2)
    top = S[11][0]
    # a band of a parallel cut takes blocks from its own range [top, end) of the pool
    end = S[7].size if S[11].size < 2 else S[11][1]
    if top + cap > end:
        return False
    old = S[5][r]
    for k in range(S[0][r] - 1):
        S[7][top + k] = S[7][old + k]
        S[8][top + k] = S[8][old + k]
        S[9][top + k] = S[9][old + k]
        S[10][top + k] = S[10][old + k]
    S[5][r] = top
    S[6][r] = cap
    S[11][0] = top + cap
    return True


@nb.njit(cache=True)
def write_ray(S, r, nears, fars, nids, fids, m):
    """Replace ray ``r`` by the first ``m`` given segments (already sorted, disjoint).

    Returns False, changing nothing, when the pool is full.
    """
    if m > 1 and not _reserve(S, r, m):
        return False
    for k in range(m):
        _put_seg(S, r, k, nears[k], fars[k], nids[k], fids[k])
    S[0][r] = m
    return True


@nb.njit(cache=True)
def subtract_interval(S, r, a, b, move_id, eps):
    """Remove ``[a, b]`` from ray ``r`` (Van Hook's 1-D Boolean difference).

    The cases per segment [n, f]: untouched (b <= n or a >= f), deleted (a <= n, b >= f),
    near end shortened (a <= n < b < f), far end shortened (n < a < f <= b), split
    (n < a, b < f). New faces carry ``move_id``. Pieces not longer than ``eps`` vanish.

    Returns the removed length (mm, >= 0), or ``POOL_FULL`` with nothing changed.
    """
    c = S[0][r]
    if c == 0 or b <= a:
        return 0.0
    if c == 1:  # the common case, done in place
        n = np.float64(S[1][r])
        f = np.float64(S[2][r])
        if b <= n or a >= f:
            return 0.0
        keep_low = a - n > eps
        keep_high = f - b > eps
        if keep_low and keep_high:
            if not _reserve(S, r, 2):
                return POOL_FULL
            _put_seg(S, r, 1, np.float32(b), S[2][r], move_id, S[4][r])
            S[2][r] = np.float32(a)
            S[4][r] = move_id
            S[0][r] = 2
            return b - a
        if keep_low:
            S[2][r] = np.float32(a)
            S[4][r] = move_id
            return f - a
        if keep_high:
            S[1][r] = np.float32(b)
            S[3][r] = move_id
            return b - n
        S[0][r] = 0
        return f - n
    # several segments: rebuild the list, if [a, b] meets one (the scan is cheaper than
    # the rebuild's buffers, and a tool instance misses most rays it is tried on)
    first = c
    for k in range(c):
        n, f, _, _ = get_seg(S, r, k)
        if b <= np.float64(n):
            return 0.0  # sorted: the rest lie beyond b
        if a < np.float64(f):
            first = k
            break
    if first == c:
        return 0.0
    # one segment met and shortened at one end (a tool eating into it): in place, the
    # segment and the length the rebuild below would give
    if first + 1 == c or b <= np.float64(get_seg(S, r, first + 1)[0]):
        n, f, nid, fid = get_seg(S, r, first)
        n64 = np.float64(n)
        f64 = np.float64(f)
        keep_low = a - n64 > eps
        keep_high = f64 - b > eps
        if keep_low != keep_high:
            removed = min(b, f64) - max(a, n64)
            if keep_low:
                _put_seg(S, r, first, n, np.float32(a), nid, move_id)
            else:
                _put_seg(S, r, first, np.float32(b), f, move_id, fid)
            return removed
    nn = np.empty(c + 1, np.float32)
    ff = np.empty(c + 1, np.float32)
    ni = np.empty(c + 1, np.int32)
    fi = np.empty(c + 1, np.int32)
    m = 0
    removed = 0.0
    for k in range(c):
        n, f, nid, fid = get_seg(S, r, k)
        n64 = np.float64(n)
        f64 = np.float64(f)
        if b <= n64 or a >= f64:
            nn[m] = n
            ff[m] = f
            ni[m] = nid
            fi[m] = fid
            m += 1
            continue
        lo = max(a, n64)
        hi = min(b, f64)
        removed += hi - lo
        if a - n64 > eps:
            nn[m] = n
            ff[m] = np.float32(a)
            ni[m] = nid
            fi[m] = move_id
            m += 1
        if f64 - b > eps:
            nn[m] = np.float32(b)
            ff[m] = f
            ni[m] = move_id
            fi[m] = fid
            m += 1
    if removed == 0.0:
        return 0.0
    if not write_ray(S, r, nn, ff, ni, fi, m):
        return POOL_FULL
    return removed


@nb.njit(cache=True)
def add_interval(S, r, a, b, near_id, far_id, eps):
    """Union ``[a, b]`` into ray ``r``; faces of the new material carry the given ids.

    Overlapping or touching (within ``eps``) segments merge; where they merge the outer
    faces keep their ids. Returns the added length (mm, >= 0), or ``POOL_FULL``.
    """
    if b - a <= eps:
        return 0.0
    c = S[0][r]
    if c == 0:
        S[1][r] = np.float32(a)
        S[2][r] = np.float32(b)
        S[3][r] = near_id
        S[4][r] = far_id
        S[0][r] = 1
        return b - a
    nn = np.empty(c + 1, np.float32)
    ff = np.empty(c + 1, np.float32)
    ni = np.empty(c + 1, np.int32)
    fi = np.empty(c + 1, np.int32)
    m = 0
    covered = 0.0
    cur_n = a
    cur_f = b
    cur_ni = near_id
    cur_fi = far_id
    placed = False
    for k in range(c):
        n, f, nid, fid = get_seg(S, r, k)
        n64 = np.float64(n)
        f64 = np.float64(f)
        if placed or f64 < cur_n - eps:
            nn[m] = n
            ff[m] = f
            ni[m] = nid
            fi[m] = fid
            m += 1
        elif n64 > cur_f + eps:
            nn[m] = np.float32(cur_n)
            ff[m] = np.float32(cur_f)
            ni[m] = cur_ni
            fi[m] = cur_fi
            m += 1
            placed = True
            nn[m] = n
            ff[m] = f
            ni[m] = nid
            fi[m] = fid
            m += 1
        else:  # overlaps or touches: merge into the current piece
            covered += max(0.0, min(f64, b) - max(n64, a))
            if n64 < cur_n:
                cur_n = n64
                cur_ni = nid
            if f64 > cur_f:
                cur_f = f64
                cur_fi = fid
    if not placed:
        nn[m] = np.float32(cur_n)
        ff[m] = np.float32(cur_f)
        ni[m] = cur_ni
        fi[m] = cur_fi
        m += 1
    added = (b - a) - covered
    if added <= 0.0:
        return 0.0
    if not write_ray(S, r, nn, ff, ni, fi, m):
        return POOL_FULL
    return added


@nb.njit(cache=True)
def ray_top(S, r):
    """Largest ``far`` on ray ``r`` (NaN when the ray is empty)."""
    c = S[0][r]
    if c == 0:
        return np.nan
    n, f, nid, fid = get_seg(S, r, c - 1)
    return np.float64(f)


@nb.njit(cache=True)
def top_all(S, out):
    """Fill ``out`` (n_rays,) float32 with each ray's top (NaN where empty)."""
    for r in range(S[0].size):
        out[r] = ray_top(S, r)


@nb.njit(cache=True, fastmath={"nnan", "reassoc", "nsz"})   # not ninf: -inf is a value here
def max_top(S):
    """Largest top over all rays (mm, float64 of the stored float32); -inf if all are empty."""
    cnt = S[0]
    far = S[2]
    # rays of one segment (nearly all) in a loop the compiler vectorises, then the others
    best = np.float32(-np.inf)
    multi = False
    for r in range(cnt.size):
        c = cnt[r]
        best = max(best, far[r] if c == 1 else np.float32(-np.inf))
        multi |= c > 1
    best64 = np.float64(best)
    if multi:
        for r in range(cnt.size):
            c = cnt[r]
            if c > 1:
                best64 = max(best64, np.float64(S[8][S[5][r] + c - 2]))
    return best64


@nb.njit(cache=True)
def total_length(S):
    """Sum of segment lengths over all rays, mm."""
    total = 0.0
    for r in range(S[0].size):
        for k in range(S[0][r]):
            n, f, nid, fid = get_seg(S, r, k)
            total += np.float64(f) - np.float64(n)
    return total
