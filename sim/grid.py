"""DexelGrid: a solid as sorted material segments on the rays of a :class:`Frame`."""

from __future__ import annotations

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim.errors import InputError
from sim.frame import Frame
from sim.tolerance import DEFAULT, Tolerance

#: the grid memory limit checked before allocating (bytes); see ``DexelGrid.estimate_bytes``
DEFAULT_MEMORY_LIMIT = 4 * 1024**3
#: bytes per ray of the dense first-segment arrays
BYTES_PER_RAY = 2 + 4 + 4 + 4 + 4 + 4 + 4


class DexelGrid:
    """A dexel model: on each ray of ``frame``, a sorted list of material segments.

    Segment values are ray parameters ``s`` in mm (see :class:`Frame`); every face keeps
    the id of the move that made it (0 = stock). The arrays live in ``store`` (layout in
    :mod:`sim.dexel_store`); kernels take ``self.S``, the same arrays as a tuple.
    """

    def __init__(self, frame: Frame, tol: Tolerance = DEFAULT, store: dict | None = None,
                 memory_limit: int = DEFAULT_MEMORY_LIMIT):
        self.frame = frame
        self.tol = tol
        if store is None:
            need = self.estimate_bytes(frame.n_rays)
            if need > memory_limit:
                raise InputError(
                    f"a {frame.nu} x {frame.nv} dexel grid needs about {need / 2**20:.0f} MB, "
                    f"over the {memory_limit / 2**20:.0f} MB limit; use a coarser resolution")
            store = ds.new_store(frame.n_rays)
        self.store = store

    # --- construction -------------------------------------------------------------
    @staticmethod
    def estimate_bytes(n_rays: int) -> int:
        """Bytes of the dense arrays for ``n_rays`` rays (the pool adds what undercuts need)."""
        return int(n_rays) * BYTES_PER_RAY

    @classmethod
    def from_intervals(cls, frame: Frame, near: np.ndarray, far: np.ndarray,
                       face_id: int = 0, tol: Tolerance = DEFAULT) -> "DexelGrid":
        """One segment ``[near, far]`` per ray (arrays of shape (nv, nu), mm).

        Rays where ``far - near <= tol.length`` or either value is NaN stay empty.
        """
        grid = cls(frame, tol)
        near = np.asarray(near, np.float64).reshape(-1)
        far = np.asarray(far, np.float64).reshape(-1)
        if near.size != frame.n_rays or far.size != frame.n_rays:
            raise InputError(f"expected {frame.shape} intervals, got {near.size} and {far.size}")
        ok = np.isfinite(near) & np.isfinite(far) & (far - near > tol.length)
        st = grid.store
        st["count"][ok] = 1
        st["near"][ok] = near[ok]
        st["far"][ok] = far[ok]
        st["near_id"][ok] = face_id
        st["far_id"][ok] = face_id
        return grid

    def copy(self) -> "DexelGrid":
        return DexelGrid(self.frame, self.tol, {k: v.copy() for k, v in self.store.items()})

    def window(self, i0: int, i1: int, j0: int, j1: int) -> "DexelGrid":
        """A copy of the rays ``i0 <= i < i1``, ``j0 <= j < j1`` as a grid of its own.

        Used for scratch work (look-ahead) that must never touch the live model.
        """
        i0, j0 = max(i0, 0), max(j0, 0)
        i1, j1 = min(i1, self.frame.nu), min(j1, self.frame.nv)
        if i1 <= i0 or j1 <= j0:
            raise InputError(f"empty window i {i0}..{i1}, j {j0}..{j1}")
        frame = self.frame.window(i0, i1, j0, j1)
        idx = (np.arange(j0, j1)[:, None] * self.frame.nu + np.arange(i0, i1)[None, :]).reshape(-1)
        out = DexelGrid(frame, self.tol)
        nears, fars, nids, fids, counts = self.segments_of(idx)
        out._write_rays(np.arange(idx.size), counts, nears, fars, nids, fids)
        return out

    # --- access ---------------------------------------------------------------------
    @property
    def S(self) -> tuple:
        """The store as the tuple kernels take. Rebuild after anything that grows the pool."""
        return ds.store_tuple(self.store)

    @property
    def shape(self) -> tuple[int, int]:
        return self.frame.shape

    @property
    def counts(self) -> np.ndarray:
        """Segments per ray, int16 (nv, nu)."""
        return self.store["count"].reshape(self.frame.shape)

    def segments(self, i: int, j: int) -> np.ndarray:
        """Segments of ray (i, j): float64 (k, 2) of [near, far] in mm."""
        r = j * self.frame.nu + i
        nears, fars, _, _, _ = self.segments_of(np.array([r]))
        return np.stack([nears, fars], axis=1).astype(np.float64)

    def face_ids(self, i: int, j: int) -> np.ndarray:
        """Face ids of ray (i, j): int32 (k, 2) of [near_id, far_id]."""
        r = j * self.frame.nu + i
        _, _, nids, fids, _ = self.segments_of(np.array([r]))
        return np.stack([nids, fids], axis=1)

    def segments_of(self, rays: np.ndarray):
        """All segments of the given flat rays, concatenated in ray order.

        Returns ``(near, far, near_id, far_id, counts)``: four arrays of the total segment
        count (float32, float32, int32, int32) and ``counts`` (len(rays),) int64.
        """
        return store_segments(self.store, rays)

    def _write_rays(self, rays, counts, nears, fars, nids, fids) -> None:
        """Replace the given rays by the given segments (layout of :meth:`segments_of`)."""
        rays = np.asarray(rays, np.int64)
        counts = np.asarray(counts, np.int64)
        need = int(np.maximum(counts - 1, 0).sum()) * 2
        if need:
            ds.grow_pool(self.store, need)
        done = _scatter(self.S, rays, counts, nears, fars, nids, fids)
        if done != rays.size:  # only if the estimate above was short
            raise RuntimeError("dexel pool exhausted while writing rays")

    def top(self) -> np.ndarray:
        """Top (largest ``s``) of the material on every ray, float32 (nv, nu); NaN where empty."""
        out = np.empty(self.frame.n_rays, np.float32)
        ds.top_all(self.S, out)
        return out.reshape(self.frame.shape)

    def top_of(self, rays) -> np.ndarray:
        """Top (largest ``s``) of the material on each of the flat ray indices ``rays``,
        float64 (k,); NaN where empty. What :meth:`top` says of those rays, without
        reading every ray."""
        # numpy on the store's arrays (as dexel_store.get_seg lays them out: a ray's first
        # segment in near/far, the rest in the pool from first[r]), no kernel to compile
        # mid-run
        rays = np.asarray(rays, np.int64).reshape(-1)
        cnt, far, first, pool_far = self.S[0], self.S[2], self.S[5], self.S[8]
        c = cnt[rays]
        out = np.where(c > 0, far[rays].astype(np.float64), np.nan)
        many = np.flatnonzero(c > 1)
        out[many] = pool_far[first[rays[many]] + c[many] - 2]
        return out

    def max_top(self) -> float:
        """The largest top over all rays, mm (``-inf`` when every ray is empty), without
        a per-ray array (:meth:`top` of 10M rays is 36 MB)."""
        return float(ds.max_top(self.S))

    def volume(self, weights: str | None = None) -> float:
        """Material volume, mm^3.

        ``weights=None``: each ray stands for a full spacing x spacing column (the rays
        include both ends of the frame, so a box is overstated by its edge half-cells).
        ``weights="trapezoid"``: the trapezoid rule over the frame's rectangle, edge rays
        count half a column and corner rays a quarter; a box whose sides lie on the first
        and last rays then gives its exact volume.
        """
        if weights is None:
            return ds.total_length(self.S) * self.frame.spacing**2
        if weights != "trapezoid":
            raise ValueError(f"weights must be None or 'trapezoid', got {weights!r}")
        f = self.frame
        length = np.empty(f.n_rays)
        _ray_lengths(self.S, length)
        length = length.reshape(f.shape)  # (nv, nu)
        wu = np.ones(f.nu)
        wv = np.ones(f.nv)
        if f.nu > 1:
            wu[[0, -1]] = 0.5
        if f.nv > 1:
            wv[[0, -1]] = 0.5
        return float(wv @ length @ wu) * f.spacing**2

    def nbytes(self) -> int:
        """Bytes held by the store (dense arrays plus the whole pool)."""
        return int(sum(a.nbytes for a in self.store.values()))

    # --- editing one ray at a time (Python-level; kernels do the bulk) ------------
    def subtract(self, i: int, j: int, a: float, b: float, move_id: int) -> float:
        """Remove ``[a, b]`` from ray (i, j); return the removed length in mm."""
        return self._retry(ds.subtract_interval, j * self.frame.nu + i, a, b, move_id)

    def add(self, i: int, j: int, a: float, b: float, face_id: int = 0) -> float:
        """Add ``[a, b]`` to ray (i, j); return the added length in mm."""
        r = j * self.frame.nu + i
        while True:
            got = ds.add_interval(self.S, r, float(a), float(b), face_id, face_id, self.tol.length)
            if got != ds.POOL_FULL:
                return got
            ds.grow_pool(self.store, 64)

    def _retry(self, kernel, r, a, b, move_id):
        while True:
            got = kernel(self.S, r, float(a), float(b), int(move_id), self.tol.length)
            if got != ds.POOL_FULL:
                return got
            ds.grow_pool(self.store, 64)

    def __repr__(self) -> str:
        f = self.frame
        return (f"DexelGrid({f.nu}x{f.nv} rays at {f.spacing} mm, "
                f"{int((self.store['count'] > 1).sum())} multi-segment, {self.nbytes() / 2**20:.1f} MB)")


# --- gather / scatter kernels ---------------------------------------------------------

@nb.njit(cache=True)
def _ray_lengths(S, out):
    """Fill ``out`` (n_rays,) float64 with each ray's material length, mm."""
    for r in range(S[0].size):
        total = 0.0
        for k in range(S[0][r]):
            n, f, nid, fid = ds.get_seg(S, r, k)
            total += np.float64(f) - np.float64(n)
        out[r] = total


def store_segments(store: dict, rays: np.ndarray):
    """:meth:`DexelGrid.segments_of` of a store (see :mod:`sim.dexel_store`): the segments
    of the flat ``rays``, concatenated in ray order, and their counts."""
    rays = np.asarray(rays, np.int64)
    counts = store["count"][rays].astype(np.int64)
    total = int(counts.sum())
    out = (np.empty(total, np.float32), np.empty(total, np.float32), np.empty(total, np.int32),
           np.empty(total, np.int32))
    _gather(ds.store_tuple(store), rays, counts, *out)
    return (*out, counts)


@nb.njit(cache=True)
def _gather(S, rays, counts, out_n, out_f, out_ni, out_fi):
    m = 0
    for q in range(rays.size):
        r = rays[q]
        for k in range(counts[q]):
            n, f, ni, fi = ds.get_seg(S, r, k)
            out_n[m] = n
            out_f[m] = f
            out_ni[m] = ni
            out_fi[m] = fi
            m += 1


@nb.njit(cache=True)
def _scatter(S, rays, counts, nears, fars, nids, fids):
    m = 0
    for q in range(rays.size):
        c = counts[q]
        if not ds.write_ray(S, rays[q], nears[m:m + c], fars[m:m + c], nids[m:m + c], fids[m:m + c], c):
            return q
        m += c
    return rays.size
