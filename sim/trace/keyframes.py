"""Keyframes of a z-trace: snapshots of the model that share the arrays a far-only
edit cannot touch, and the builder that makes them a slice at a time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sim import dexel_store as ds

if TYPE_CHECKING:
    from sim.trace.ztrace import ZTrace


def _store_snapshot(store: dict, later: list | None = None) -> dict:
    """A copy of a store with the pool trimmed to what is in use (``later``: the per-ray
    arrays' copies left to whoever runs that list, see :func:`copy_rays`)."""
    top = int(store["pool_top"][0])
    out = {}
    for k, v in store.items():
        if k.startswith("pool_") and k != "pool_top":
            out[k] = v[:max(top, 16)].copy()
        elif k in _RAY_FIELDS:
            out[k] = _copy_rays_of(v, 0, v.size, later)
        else:
            out[k] = v.copy()
    return out


def _stock_snapshot(store: dict) -> dict:
    """The first keyframe of a trace: a copy of the store, but a per-ray array that holds
    one value throughout (a block of stock: every ray one segment, the same bottom, top
    and face ids) is kept as that value broadcast to every ray, read-only. At 1M rays
    that is 26 MB a trace neither copies nor holds; later keyframes share its chunks as
    they share any (restoring reads them; nothing may write a keyframe)."""
    out = _store_snapshot({k: v for k, v in store.items() if k not in _RAY_FIELDS})
    for k in _RAY_FIELDS:
        v = store[k]
        out[k] = np.broadcast_to(v[:1].copy(), v.shape) if v.size and _uniform(v) else v.copy()
    return out


def _uniform(a: np.ndarray) -> bool:
    """Every element of ``a`` (1-D) has the same bits (compared as integers: -0.0 is not
    0.0 here, and a NaN is a value). Two vectorised passes, no temporary array."""
    bits = a.view(f"i{a.itemsize}")
    return bool(bits.min() == bits.max())


def _writable(a) -> bool:
    """A plain array a kernel may be handed (not a chunked or broadcast keyframe array)."""
    return isinstance(a, np.ndarray) and a.flags.writeable and a.flags.c_contiguous


def _copy_rays_of(src: np.ndarray, lo: int, hi: int, later: list | None) -> np.ndarray:
    """``src[lo:hi]`` copied now, or into an array returned empty and filled when the
    ``later`` list is run (:func:`copy_rays`)."""
    if later is None:
        return src[lo:hi].copy()
    dst = np.empty(hi - lo, src.dtype)
    later.append((src, lo, hi, dst))
    return dst


def copy_rays(later: list, r0: int, r1: int) -> None:
    """Do the copies of ``later`` (see :func:`_store_snapshot`) for the rays ``r0 .. r1-1``
    (``sim.bands``: each band copies its own rows of a keyframe before it cuts them)."""
    for src, lo, hi, dst in later:
        a, b = max(lo, r0), min(hi, r1)
        if a < b:
            dst[a - lo:b - lo] = src[a:b]


def _store_copy(snap: dict, spare: int) -> dict:
    """A working copy of a snapshot with ``spare`` free pool slots."""
    top = int(snap["pool_top"][0])
    out = {}
    for k, v in snap.items():
        if k.startswith("pool_") and k != "pool_top":
            w = np.zeros(max(top + spare, 1024), v.dtype)
            w[:top] = v[:top]
            out[k] = w
        else:
            out[k] = v.copy()
    return out


@dataclass
class _Keyframe:
    block: int  # number of blocks applied
    stage: int
    data: object


#: the store's arrays of one value per ray
_RAY_FIELDS = ("count", "near", "far", "near_id", "far_id", "xstart", "xcap")
#: fields a far-only (rule 5) edit writes; the others stay shared between keyframes
_FAR_FIELDS = ("far", "far_id", "pool_far", "pool_far_id")
_POOL_FIELDS = ("pool_near", "pool_far", "pool_near_id", "pool_far_id")
#: keyframe work (array elements copied or events replayed) done per record call at least
KEYFRAME_BUDGET = 1 << 18


class _Chunked:
    """A keyframe's per-ray array kept as fixed-size chunks, so that a keyframe copies only
    the chunks its far-only edits touched and shares the others with the keyframe before
    it (a finishing pass touches a band of the part between two keyframes, not all of it).
    Restoring copies the chunks into the caller's array; code that needs one array gets
    it from ``np.asarray``."""

    CHUNK = 1 << 14
    __slots__ = ("chunks", "size", "dtype")

    def __init__(self, chunks: list, size: int, dtype):
        self.chunks, self.size, self.dtype = chunks, int(size), np.dtype(dtype)

    @classmethod
    def of(cls, a: np.ndarray) -> "_Chunked":
        """Views of ``a`` (no copy)."""
        if isinstance(a, _Chunked):
            return a
        return cls([a[i:i + cls.CHUNK] for i in range(0, a.size, cls.CHUNK)], a.size, a.dtype)

    def updated(self, src: np.ndarray, dirty: np.ndarray, later: list | None = None) -> "_Chunked":
        """These chunks with the ``dirty`` ones (bool per chunk) copied anew from ``src``
        (``later``: see :func:`_store_snapshot`)."""
        ch = self.CHUNK
        chunks = [_copy_rays_of(src, i * ch, min((i + 1) * ch, src.size), later) if d else c
                  for i, (c, d) in enumerate(zip(self.chunks, dirty))]
        return _Chunked(chunks, self.size, self.dtype)

    def copy_into(self, dst: np.ndarray) -> None:
        for i, c in enumerate(self.chunks):
            dst[i * self.CHUNK:i * self.CHUNK + c.size] = c

    def copy(self) -> np.ndarray:
        out = np.empty(self.size, self.dtype)
        self.copy_into(out)
        return out

    def __array__(self, dtype=None, copy=None):
        out = self.copy()
        return out if dtype is None else out.astype(dtype)

    @property
    def nbytes(self) -> int:
        return int(sum(c.nbytes for c in self.chunks))


def _plain(a) -> np.ndarray:
    """``a`` as an array a kernel may be handed: itself, or a copy of a chunked or
    broadcast keyframe array."""
    return a if _writable(a) else a.copy()


def _snapshot_sharing(store: dict, prev: dict | None, general: bool, dirty=None,
                      later: list | None = None) -> dict:
    """A snapshot of ``store`` sharing with keyframe ``prev`` what no edit since touched.

    ``dirty``: bool per :class:`_Chunked` chunk of rays, the chunks the edits since
    ``prev`` fell in (their far runs, and their general rays when ``general``). Only
    far-only edits (``general`` False): the fields they cannot touch are ``prev``'s
    arrays, and the FarZ values and ids share their clean chunks. General rewrites too:
    every per-ray field shares its clean chunks, the pool is copied. Without ``dirty`` a
    general snapshot copies everything. ``later``: see :func:`_store_snapshot`.
    """
    if prev is None or (general and dirty is None):
        return _store_snapshot(store, later)
    out = dict(prev)
    top = int(store["pool_top"][0])
    for k in (ds.STORE_FIELDS if general else _FAR_FIELDS):
        v = store[k]
        if k == "pool_top":
            out[k] = v.copy()
        elif k.startswith("pool_"):
            out[k] = v[:max(top, 16)].copy()
        elif dirty is not None:
            out[k] = _Chunked.of(prev[k]).updated(v, dirty, later)
        else:
            out[k] = _copy_rays_of(v, 0, v.size, later)
    return out


class _KeyBuilder:
    """A keyframe built in small steps off the recording path.

    Starts from the latest keyframe and shares with it every chunk of rays
    (:class:`_Chunked`) no event up to ``block`` touched, and every field the events
    cannot write (far-only edits write FarZ values and ids only). The touched chunks are
    copied, a slice at a time, into scratch arrays the size of the model, the blocks are
    replayed on those in slices (an event reads and writes its own ray only, so the
    scratch's other chunks are never read, nor its untouched pages ever made), and the
    keyframe takes the touched chunks from the scratch at the end. No call costs more
    than about ``budget`` array elements / events. Moves recorded one by one cut a strip of
    the part between two keyframes: their keyframes hold that strip, not the whole model.
    """

    def __init__(self, trace: "ZTrace", block: int):
        self.trace = trace
        self.block = int(block)
        base = trace._keyframes[-1]
        self.base = base
        self.cur = base.block
        tr = trace
        g0, g1 = int(tr._g_ptr.a[base.block]), int(tr._g_ptr.a[self.block])
        self.general = g1 > g0
        self.dirty = tr._dirty_chunks(int(tr._r_ptr.a[base.block]), int(tr._r_ptr.a[self.block]), g0, g1)
        self.written = ds.STORE_FIELDS if self.general else _FAR_FIELDS
        self.work = dict(base.data)
        # [destination, source, next element] copies still to do, sliced as the budget allows
        self.copies = []
        top = int(base.data["pool_top"][0])
        spare = 2 * int(tr._gs_ptr.a[self.block] - tr._gs_ptr.a[base.block]) + 64 if self.general else 0
        ch = _Chunked.CHUNK
        for k, v in base.data.items():
            if k in _RAY_FIELDS:
                if k not in self.written and _writable(v):
                    continue   # read by the replay as it is
                src = _Chunked.of(v)
                dst = np.empty(src.size, src.dtype)
                for i in np.flatnonzero(self.dirty):
                    self.copies.append([dst[i * ch:i * ch + src.chunks[i].size], src.chunks[i], 0])
                self.work[k] = dst
            elif k in self.written:
                src = _plain(v)
                size = max(top + spare, src.size) if k in _POOL_FIELDS else src.size
                dst = np.zeros(size, src.dtype) if size != src.size else np.empty_like(src)
                self.work[k] = dst
                self.copies.append([dst[:src.size], src, 0])

    def step(self, budget: int) -> int:
        """Do up to ``budget`` units of work; returns the units used (0 when finished)."""
        used = 0
        while self.copies and used < budget:
            dst, src, lo = self.copies[0]
            hi = min(src.size, lo + budget - used)
            dst[lo:hi] = src[lo:hi]
            used += hi - lo
            self.copies[0][2] = hi
            if hi >= src.size:
                self.copies.pop(0)
        tr = self.trace
        while not self.copies and self.cur < self.block and used < budget:
            ev = tr._f_ptr.a + tr._g_ptr.a  # events before each block boundary (view)
            stop = int(np.searchsorted(ev, ev[self.cur] + (budget - used), side="left"))
            stop = min(max(stop, self.cur + 1), self.block)
            tr._replay_store(self.work, self.cur, stop)
            used += int(ev[stop] - ev[self.cur])
            self.cur = stop
        return used

    @property
    def done(self) -> bool:
        return not self.copies and self.cur >= self.block

    def finish(self) -> _Keyframe:
        """The keyframe: the base's data with what the replay wrote (its touched chunks of
        rays; the pool trimmed to its use)."""
        data = dict(self.base.data)
        top = int(self.work["pool_top"][0])
        for k in self.written:
            v = self.work[k]
            if k in _RAY_FIELDS:
                data[k] = _Chunked.of(self.base.data[k]).updated(v, self.dirty)
            elif k.startswith("pool_") and k != "pool_top":
                data[k] = v[:max(top, 16)].copy()
            else:
                data[k] = v
        self.work = None
        return _Keyframe(self.block, int(self.trace._stage.a[self.block - 1]), data)
