"""The exact linear batch cut on every core: bands of rows on threads, merged move by move.

A ray's material depends only on the moves that reach it and on their order, so disjoint
bands of rows can be cut at the same time by independent calls of
:func:`sim.sweep_kernels.cut_linear_batch` (its ``band0, band1`` clamp), each taking every
segment but touching only its own rows. The kernel holds no lock, so the calls run on
threads. What a band records per move (the length removed, changed rays, trace events)
goes to buffers of its own and is merged move by move, band by band: within a move the
one-core kernel visits the rays row by row, so band order is its order, and heights,
face ids, the change log and the trace's events come out as one core makes them. (A move
of several segments, an arc's chords, lists its far events in the order the rays were
first reached, chord by chord on one core, band by band here: the same events, each ray
once per block, in another order.)

The pool of the store (rays of several segments) is shared: each band takes new blocks
from a range of its own (its ``pool_top`` carries ``[top, end]``). A band that runs out,
or fills its log or trace buffers, stops; the calling thread grows what is full between
rounds and sends it on, so no thread grows an array another one is writing.

Logged or traced batches are cut in chunks of whole moves: the band buffers stay small,
and the trace's keyframes fall due at a chunk's end (the same chunks whatever the number
of bands, so the trace is the same).
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np

from sim import dexel_store as ds
from sim import sweep_kernels as K

#: a band holds at least this many rows (a thinner one is mostly overhead)
MIN_BAND_ROWS = 16
#: segments per chunk of a logged or traced batch
CHUNK_SEGMENTS = 4096
#: below this many rays within reach of a batch, one core is faster than handing off
MIN_PARALLEL_RAYS = 200_000

def default_threads() -> int:
    """Threads a cut may use: ``DEXMON_THREADS`` if set, else the cores this process may run on."""
    env = os.environ.get("DEXMON_THREADS", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise ValueError(f"DEXMON_THREADS={env!r}: expected a whole number of threads") from None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class ThreadPool:
    """A thread pool started on first use with at least the workers asked for, and
    started again in a forked child (the parent's threads do not survive a fork)."""

    def __init__(self, prefix: str):
        self.prefix = prefix
        self._ex: ThreadPoolExecutor | None = None
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(after_in_child=self._forget)

    def get(self, workers: int) -> ThreadPoolExecutor:
        if self._ex is None or self._ex._max_workers < workers:
            self._ex = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=self.prefix)
        return self._ex

    def _forget(self) -> None:
        self._ex = None


#: the threads bands are cut on
BAND_POOL = ThreadPool("dexmon-band")


def reach_rays(p0: np.ndarray, p1: np.ndarray, reach: float, spacing: float) -> np.ndarray:
    """Rays within reach of each segment, about: float64 (n,) from tips (n, 3) mm, the
    body's largest radius ``reach`` and the ray spacing (mm)."""
    run = np.hypot(*(p1[:, :2] - p0[:, :2]).T) / spacing
    r = reach / spacing + 1.0
    return (run + 2 * r) * 2 * r


def plan_bands(p0: np.ndarray, p1: np.ndarray, reach: float, origin_y: float, spacing: float,
               nv: int, n_bands: int, shares: np.ndarray | None = None) -> np.ndarray:
    """Row bounds (int64 (m + 1,), 0 ... nv) of ``m <= n_bands`` bands holding about the same
    work: each segment's rays within reach spread evenly over the rows it spans.
    ``shares``: float (n_bands,), the part of the work each band gets instead (relative)."""
    j0 = np.floor((np.minimum(p0[:, 1], p1[:, 1]) - reach - origin_y) / spacing)
    j1 = np.ceil((np.maximum(p0[:, 1], p1[:, 1]) + reach - origin_y) / spacing) + 1
    j0 = np.clip(j0, 0, nv).astype(np.int64)
    j1 = np.clip(j1, 0, nv).astype(np.int64)
    rows = np.maximum(j1 - j0, 1)
    per_row = reach_rays(p0, p1, reach, spacing) / rows
    density = np.bincount(j0, per_row, nv + 1) - np.bincount(j1, per_row, nv + 1)
    work = np.cumsum(np.cumsum(density)[:nv])
    n_bands = max(1, min(n_bands, nv // MIN_BAND_ROWS))
    if work[-1] <= 0 or n_bands == 1:
        return np.array([0, nv], np.int64)
    if shares is None or len(shares) != n_bands:
        shares = np.ones(n_bands)
    cuts = np.searchsorted(work, work[-1] * np.cumsum(shares)[:-1] / np.sum(shares))
    bounds = np.unique(np.concatenate([[0], cuts, [nv]])).astype(np.int64)
    # no band thinner than MIN_BAND_ROWS: merge a thin one into its neighbour
    keep = [0]
    for b in bounds[1:-1]:
        if b - keep[-1] >= MIN_BAND_ROWS and nv - b >= MIN_BAND_ROWS:
            keep.append(int(b))
    keep.append(nv)
    return np.array(keep, np.int64)


class _Balance:
    """The part of a chunk's estimated work each band gets, corrected chunk by chunk by
    how long each band took.

    The estimate (rays within reach, :func:`plan_bands`) misses what the rays cost: on a
    raster, the rows ahead of the tool change on every pass and those behind it rarely,
    so equal estimates left one band idle for up to half of a chunk. Consecutive chunks
    of a program look alike, so the speed each band showed (its share over its time)
    sets the next chunk's shares, half and half with the shares before.
    """

    #: no band gets more than this many times an even share, nor less than its inverse
    LIMIT = 3.0

    def __init__(self, n_bands: int):
        self.shares = np.ones(n_bands)

    def update(self, times: np.ndarray) -> None:
        """The bands took ``times`` (s, one per band of the last plan of all of them)."""
        if times.size != self.shares.size or not np.all(times > 0):
            return
        before = self.shares / self.shares.sum()
        speed = before / times
        shares = 0.5 * before + 0.5 * speed / speed.sum()
        even = 1.0 / shares.size
        self.shares = np.clip(shares, even / self.LIMIT, even * self.LIMIT)


def chunk_bounds(seg_move: np.ndarray, chunk: int, first: int | None = None) -> list[tuple[int, int]]:
    """Segment ranges ``[a, b)`` that never split a move: the first of about ``first``
    segments (default ``chunk // 8``), each next one twice as long up to ``chunk``.

    Short chunks first: the bands' shares of the first chunk are a guess (see
    :class:`_Balance`), so the first chunk's wait for its slowest band should be short.
    """
    n = len(seg_move)
    out = []
    a = 0
    size = max(1, chunk // 8 if first is None else first)
    while a < n:
        b = min(a + size, n)
        size = min(2 * size, chunk)
        while b < n and seg_move[b] == seg_move[b - 1]:
            b += 1
        out.append((a, b))
        a = b
    return out


class _Buffers:
    """Per-band arrays, one row per band (a row of a C array is the 1-D array a kernel
    takes). Grown only between rounds, by the calling thread."""

    def __init__(self, n_bands: int, spec: dict[str, tuple[int, type]]):
        self.n_bands = n_bands
        self.a = {name: np.empty((n_bands, size), dtype) for name, (size, dtype) in spec.items()}

    def row(self, name: str, t: int) -> np.ndarray:
        return self.a[name][t]

    def grow(self, names, size: int, keep: bool = True) -> None:
        """Room for ``size`` values a band in the columns ``names`` (``keep``: their contents)."""
        for name in names:
            old = self.a[name]
            if old.shape[1] < size:
                new = np.empty((self.n_bands, max(size, old.shape[1] + old.shape[1] // 2)), old.dtype)
                if keep:
                    new[:, :old.shape[1]] = old
                self.a[name] = new


class _BandLogs(_Buffers):
    """The change logs of the bands (see ``sweep_kernels.finish_move``)."""

    def __init__(self, n_bands: int, n_moves: int):
        super().__init__(n_bands, {"ray": (1 << 14, np.int64), "depth": (1 << 14, np.float32),
                                   "s_top": (1 << 12, np.float64), "s_len": (1 << 12, np.float64)})
        self.counts = np.zeros((n_bands, n_moves), np.int64)

    def start_chunk(self, m0: int, m1: int, changes: int) -> None:
        """Empty logs with room for ``changes`` entries a band (the rays within reach of
        the chunk's segments bound them, so the kernels rarely stop for room)."""
        self.counts[:, m0:m1] = 0
        self.grow(("ray", "depth"), changes, keep=False)

    def buffers(self, t: int) -> tuple:
        return (self.row("ray", t), self.row("depth", t), self.counts[t], self.row("s_top", t),
                self.row("s_len", t))

    def grow_for(self, state: np.ndarray) -> None:
        used, cur = int(state[3]), int(state[4])
        self.grow(("ray", "depth"), used + cur + 1)
        self.grow(("s_top", "s_len"), cur + 1)


_TRACE_COLS = (("rs", np.int32), ("f_val", np.float32), ("rl", np.int32), ("g_ray", np.int32),
               ("g_count", np.int16), ("g_near", np.float32), ("g_far", np.float32),
               ("g_nid", np.int32), ("g_fid", np.int32))


class _BandTraces(_Buffers):
    """The trace events of the bands, in the kernels' column order (see
    ``sweep_kernels`` trace sink), and a trace state per band. Kept between batches (see
    :class:`_Stash`): :meth:`attach` readies them for a batch."""

    def __init__(self, n_bands: int):
        spec = {name: (1 << 12 if k < 3 else 1024, dt) for k, (name, dt) in enumerate(_TRACE_COLS)}
        spec["gen"] = (4096, np.int64)
        super().__init__(n_bands, spec)
        self.ts = np.zeros((n_bands, K.TRACE_STATE_SIZE), np.int64)
        self.touched = 0   # bytes of the columns written so far (their pages are resident)

    def attach(self, sink, n_moves: int) -> "_BandTraces":
        self.sink = sink
        self.blk = np.full((4, self.n_bands, max(n_moves, 1)), -1, np.int64)
        # the chunks of rays (of the trace's keyframes) each band's chunk touched
        self.dirty = np.zeros((self.n_bands, -(-sink.z.n_rays // sink.RAY_CHUNK)), np.bool_)
        return self

    def note_touched(self) -> None:
        """After a chunk: about the bytes its events reached in the columns."""
        per_event = sum(np.dtype(dt).itemsize for _, dt in _TRACE_COLS[:3])
        self.touched = max(self.touched, int(self.ts[:, K.TS_NF].max()) * per_event * self.n_bands)

    def start_chunk(self, m0: int, m1: int, changes: int) -> None:
        """Empty columns with room for ``changes`` far events a band (see
        :meth:`_BandLogs.start_chunk`); keyframes off."""
        self.grow(("rs", "f_val", "rl"), changes, keep=False)
        ts = self.ts
        ts[:] = 0
        ts[:, K.TS_OPEN] = -1
        ts[:, K.TS_BLK0] = self.sink.ts[K.TS_BLK0]
        ts[:, K.TS_NEXT_DUE] = np.iinfo(np.int64).max   # keyframes: at chunk ends only
        self.blk[:, :, m0:m1] = -1
        self.dirty[:] = False

    def mark_dirty(self, t: int) -> None:
        """Band ``t`` cut its chunk: mark the chunks of rays its far runs and its general
        rays touch (on its own thread, not between chunks on the calling one)."""
        nr, ng = int(self.ts[t, K.TS_NR]), int(self.ts[t, K.TS_NG])
        mark_ray_chunks(self.dirty[t], self.sink.RAY_CHUNK, self.a["rs"][t, :nr], self.a["rl"][t, :nr],
                        self.a["g_ray"][t, :ng])

    def buffers(self, t: int) -> tuple:
        mark, slot = self.sink.marks()
        cols = tuple(self.row(name, t) for name, _ in _TRACE_COLS)
        return (*cols, self.blk[0, t], self.blk[1, t], self.blk[2, t], mark, slot,
                self.row("gen", t), self.blk[3, t])

    def grow_for(self, t: int) -> None:
        """Room for what band ``t`` stopped on (as ``sim.trace.sink._Sink.grow`` does)."""
        ts = self.ts[t]
        need_f = max(int(ts[K.TS_NF]) + 1, int(ts[K.TS_NEED_F]))
        need_r = int(ts[K.TS_NR]) + max(need_f - int(ts[K.TS_NF]), 1)
        self.grow(("f_val",), need_f)
        self.grow(("rs", "rl"), need_r)
        self.grow(("gen",), max(int(ts[K.TS_NGL]) + 1, int(ts[K.TS_NEED_GEN])))
        self.grow(("g_ray", "g_count"), int(ts[K.TS_NEED_G]))
        self.grow(("g_near", "g_far", "g_nid", "g_fid"), int(ts[K.TS_NEED_S]))

    def dirty_chunks(self) -> np.ndarray:
        """Which chunks of rays (``sink.RAY_CHUNK`` each) the bands' far runs and general
        rays touch: bool (n_chunks,)."""
        return self.dirty.any(axis=0)

    def totals(self) -> tuple[int, int, int, int]:
        """Far events, general events, their segments and runs over all bands."""
        ts = self.ts
        return (int(ts[:, K.TS_NF].sum()), int(ts[:, K.TS_NG].sum()), int(ts[:, K.TS_NS].sum()),
                int(ts[:, K.TS_NR].sum()))


class _Stash:
    """Band trace buffers kept from one batch to the next.

    Pages a process has not touched yet cost a page fault and a zeroing on first write:
    on fresh buffers the band kernels of wavy_finish ran a fifth slower traced than
    plain, on buffers written before 5 % slower. A batch takes a pair out while it runs
    (cutters on two threads never share one) and gives it back unless its columns reached
    more than ``MAX_BYTES`` (a huge chunk's buffers are not held on to).
    """

    MAX_BYTES = 128 << 20

    def __init__(self):
        self._lock = threading.Lock()
        self._kept: list[list[_BandTraces]] = []

    def take(self, n_bands: int) -> list[_BandTraces]:
        with self._lock:
            for k, pair in enumerate(self._kept):
                if pair[0].n_bands == n_bands:
                    return self._kept.pop(k)
        return [_BandTraces(n_bands), _BandTraces(n_bands)]

    def give(self, pair: list[_BandTraces]) -> None:
        if sum(b.touched for b in pair) > self.MAX_BYTES:
            return
        for b in pair:
            b.sink = b.blk = b.dirty = None   # the batch's, not to be held
        with self._lock:
            self._kept = [p for p in self._kept if p[0].n_bands != pair[0].n_bands] + [pair]


_STASH = _Stash()


def mark_ray_chunks(dirty: np.ndarray, chunk: int, starts: np.ndarray, lengths: np.ndarray,
                    rays: np.ndarray) -> np.ndarray:
    """Mark in ``dirty`` (bool per chunk of ``chunk`` consecutive rays) the chunks that the
    runs of rays (``starts``, ``lengths``) and the single ``rays`` touch (far events and
    general rewrites: what a keyframe after them must copy). Returns ``dirty``."""
    _mark_chunks(starts, lengths, chunk, dirty)
    dirty[np.asarray(rays) // chunk] = True
    return dirty


@nb.njit(cache=True, nogil=True)
def _mark_chunks(starts, lengths, chunk, dirty):
    for q in range(starts.size):
        first = np.int64(starts[q])
        for c in range(first // chunk, (first + lengths[q] - 1) // chunk + 1):
            dirty[c] = True


def cut_in_bands(grid, kernel, seg_move: np.ndarray, plan, removed: np.ndarray,
                 log=None, sink=None, reach: np.ndarray | None = None, threads: int | None = None) -> None:
    """Run a linear batch cut band by band on threads, and merge what the bands recorded.

    kernel(S, state, B, T, ts, removed, band, segs): one call of ``cut_linear_batch`` on
    rows ``band = (j0, j1)`` and the slice ``segs = (a, b)`` of the segment arrays,
    returning the kernel's status (``state[0]``, counted from the slice's start, says
    where to begin: the slice holds one segment before the chunk, for the kernel to look
    back at).
    plan(a, b, shares): the row bounds of the bands (:func:`plan_bands`, at most ``threads``,
    sharing the work as ``shares`` says) for the segments ``a .. b-1``: planned per chunk,
    as a chunk of a raster covers only part of the rows and bands planned for the whole
    batch would leave all its work to one;
    removed: float64 (n_moves,) accumulates the length removed per move (mm). log: the
    cutter's change log or None; sink: the trace sink (``sim.trace.sink._Sink``) or None;
    reach: the rays within reach of each segment (:func:`reach_rays`: they bound the
    changes a band logs).
    """
    threads = threads or default_threads()
    n_bands = threads   # buffers for as many bands as a chunk may have
    n_moves = removed.size
    store = grid.store
    rem = np.zeros((n_bands, n_moves))
    pools = np.zeros((n_bands, 2), np.int64)   # each band's [top, end) in the pool; empty at first
    logs = _BandLogs(n_bands, n_moves) if log is not None else None
    chunks = chunk_bounds(seg_move, CHUNK_SEGMENTS) if (log is not None or sink is not None) \
        else [(0, len(seg_move))]
    if reach is None:
        reach = np.zeros(len(seg_move))
    bound = np.concatenate([[0.0], np.cumsum(reach)])
    ex = BAND_POOL.get(threads) if threads > 1 else None
    # two sets of trace buffers: the bands cut a chunk into one while the chunk before,
    # in the other, is merged into the trace: each band's thread first copies a part of
    # it, the columns' places split evenly (a merge on the calling thread took a core from
    # a band; copied band by band, each thread touching the pages the other touched, it
    # cost twice the CPU: most of its cost is the first touch of the trace's fresh pages)
    trace_bufs = [b.attach(sink, n_moves) for b in _STASH.take(n_bands)] if sink is not None else None
    traces = None
    pending = None   # the _Merge of the chunk cut but not merged yet
    balance = _Balance(n_bands)
    key_copies = []   # a keyframe's copies of the model at the chunk's end, see below
    nu = grid.frame.nu

    for ci, (a, b) in enumerate(chunks):
        m0, m1 = int(seg_move[a]), int(seg_move[b - 1]) + 1
        s0 = max(a - 1, 0)   # the slice starts one segment early: the kernel looks back one
        states = np.zeros((n_bands, K.STATE_SIZE), np.int64)
        states[:, 0] = a - s0
        states[:, 1] = states[:, 2] = -1
        changes = min(int(bound[b] - bound[a]), grid.frame.n_rays * (b - a)) + 4096
        if trace_bufs is not None:
            traces = trace_bufs[ci % 2]
            traces.start_chunk(m0, m1, changes)
        if logs is not None:
            logs.start_chunk(m0, m1, changes)
        bounds = plan(a, b, balance.shares)
        todo = list(range(len(bounds) - 1))
        took = np.zeros(len(todo))
        # a keyframe taken at the last chunk's end: each band copies its own rows of the
        # model into it before it cuts them (not the calling thread, between chunks)
        owed, key_copies = key_copies, []
        merge, parts = pending, len(todo)
        if merge is not None:
            merge.place()
        while todo:
            def run(t, S=grid.S, traces=traces, owed=owed, merge=merge):
                t0 = time.perf_counter()
                if merge is not None:
                    merge.copy_part(t, parts)
                if owed:
                    sink.copy_rays(owed, int(bounds[t]) * nu, int(bounds[t + 1]) * nu)
                band_S = (*S[:11], pools[t])
                st = kernel(band_S, states[t], logs.buffers(t) if logs is not None else K.NO_LOG,
                            traces.buffers(t) if traces is not None else K.NO_TRACE,
                            traces.ts[t] if traces is not None else K.NO_TS, rem[t],
                            (int(bounds[t]), int(bounds[t + 1])), (s0, b))
                if st == K.DONE and traces is not None:
                    traces.mark_dirty(t)
                took[t] += time.perf_counter() - t0
                return st
            if ex is not None and len(todo) > 1:
                status = list(ex.map(run, todo))
            else:
                status = [run(t) for t in todo]
            if merge is not None:
                merge.finish()
                merge = pending = None
            owed = None
            again = []
            for t, st in zip(todo, status):
                if st == K.DONE:
                    continue
                again.append(t)
                if st == K.STOP_POOL:
                    _new_pool_range(store, pools, t)
                elif st == K.STOP_CHANGES:
                    logs.grow_for(states[t])
                elif st == K.STOP_TRACE:
                    traces.grow_for(t)
                else:  # keyframes are off in bands
                    raise RuntimeError(f"band cut stopped with status {st}")
            todo = again
        balance.update(took)
        if logs is not None:
            _merge_logs(log, logs, states, m0, m1)
        if trace_bufs is not None:
            traces.note_touched()
            if ci < len(chunks) - 1:   # the sink's end takes the batch's last keyframe
                sink.chunk_end(m1 - 1, *traces.totals()[:2], traces.dirty_chunks, key_copies)
            pending = _Merge(sink, traces, m0, m1)
    if pending is not None:   # the last chunk's events: copied on every thread
        pending.place()
        if ex is not None:
            list(ex.map(lambda k: pending.copy_part(k, threads), range(threads)))
        else:
            pending.copy_part(0, 1)
        pending.finish()
        _STASH.give(trace_bufs)
    removed += rem.sum(axis=0)
    _end_pool_ranges(store, pools)


def _new_pool_range(store: dict, pools: np.ndarray, t: int) -> None:
    """Give band ``t`` a fresh range at the end of the pool (grown if need be), twice the
    last one it had (at least 1024 slots)."""
    size = max(1024, 2 * int(pools[t, 1] - pools[t, 0]))
    ds.grow_pool(store, size)
    top = int(store["pool_top"][0])
    pools[t] = (top, top + size)
    store["pool_top"][0] = top + size


def _end_pool_ranges(store: dict, pools: np.ndarray) -> None:
    """Give back the unused end of the range handed out last (it ends the pool's used part)."""
    top = int(store["pool_top"][0])
    for band_top, end in pools:
        if end == top and end > 0:
            store["pool_top"][0] = band_top


def _merge_logs(log, logs: _BandLogs, states: np.ndarray, m0: int, m1: int) -> None:
    """Append the bands' change-log entries of moves ``m0 .. m1-1`` to ``log``, move by
    move, band by band."""
    total = int(states[:, 3].sum())
    need = log.n + total
    if need > log.ray.size:
        cap = max(need, log.ray.size + log.ray.size // 2)
        log.ray.resize(cap, refcheck=False)
        log.depth.resize(cap, refcheck=False)
    log.n = _merge_log_kernel(m0, m1, logs.counts, logs.a["ray"], logs.a["depth"], log.ray,
                              log.depth, log.counts, log.n)


@nb.njit(cache=True, nogil=True)
def _merge_log_kernel(m0, m1, counts, ray, depth, out_ray, out_depth, out_counts, n):
    nb_ = counts.shape[0]
    pos = np.zeros(nb_, np.int64)
    for mv in range(m0, m1):
        for t in range(nb_):
            c = counts[t, mv]
            p = pos[t]
            for q in range(c):
                out_ray[n + q] = ray[t, p + q]
                out_depth[n + q] = depth[t, p + q]
            n += c
            pos[t] = p + c
            out_counts[mv] += c
    return n


class _Merge:
    """The bands' trace events of moves ``m0 .. m1-1`` appended to the sink's columns, and
    their blocks closed.

    :meth:`place` works out where each band's events of each move go (move by move, band
    by band) and makes room in the columns; the threads of the bands cutting the next
    chunk each first copy a part (:meth:`copy_part`: the columns' places split evenly, so
    each thread touches fresh pages of its own); :meth:`finish` closes the blocks. A band
    whose first run of far rays goes on from the previous band's last one (a move
    reaching both edges of a narrow grid) adds its length to that run, as one core would
    have made one run.
    """

    def __init__(self, sink, traces: _BandTraces, m0: int, m1: int):
        self.sink, self.traces, self.m0, self.m1 = sink, traces, m0, m1

    def place(self) -> None:
        """Where each band's events of each move go; room for them in the columns."""
        sink, traces, m0, m1 = self.sink, self.traces, self.m0, self.m1
        ts = sink.ts
        base = np.array([ts[K.TS_NF], ts[K.TS_NG], ts[K.TS_NS], ts[K.TS_NR]], np.int64)
        E = traces.blk[:, :, m0:m1]   # (4 columns, bands, moves): ends, -1 unopened
        self.starts, self.cnt, self.dest, self.join, self.block_end, self.opened, written = \
            _place_events(E, traces.a["rs"], traces.a["rl"], base)
        sink.make_room(*(int(x) for x in written))
        a = traces.a
        self.args = (self.starts, self.cnt, self.dest, self.join, a["rs"], a["f_val"], a["rl"], a["g_ray"],
                     a["g_count"], a["g_near"], a["g_far"], a["g_nid"], a["g_fid"], *sink.buffers()[:9])
        self.base = base

    def copy_part(self, k: int, n: int) -> None:
        """Copy part ``k`` of ``n`` of the events (each column's places split evenly)."""
        end = self.block_end[:, -1] if self.m1 > self.m0 else self.base
        lo = self.base + (end - self.base) * k // n
        hi = self.base + (end - self.base) * (k + 1) // n
        _copy_events(lo, hi, *self.args)

    def finish(self) -> None:
        """Every part copied: join the runs that go on across bands, close the blocks."""
        sink, rl_b = self.sink, self.traces.a["rl"]
        jt, jq = np.nonzero(self.join)
        if jt.size:
            np.add.at(self.args[15], self.dest[3, jt, jq] - 1, rl_b[jt, self.starts[3, jt, jq]])
        for c, blk in enumerate(sink.blk):
            blk[self.m0:self.m1][self.opened] = self.block_end[c][self.opened]
        ts = sink.ts
        ts[K.TS_NF], ts[K.TS_NG], ts[K.TS_NS], ts[K.TS_NR] = \
            self.block_end[:, -1] if self.m1 > self.m0 else self.base
        sink.merged()


@nb.njit(cache=True, nogil=True)
def _place_events(E, rs_b, rl_b, base):
    """Where the bands' events of a chunk go in the trace's columns, move by move, band by
    band (the one-core order).

    E: int64 (4, bands, moves) each band's column ends after each move (far events,
    general events, their segments, far runs; -1: the move never opened in the band);
    rs_b/rl_b: the bands' far runs; base: the columns' fill before the chunk. Returns
    (starts, cnt, dest, join, block_end, opened, written): where each (column, band,
    move) piece starts in the band's buffers, its length and its place in the columns;
    join (bands, moves): the band's first run of the move goes on from the run before it
    (written by the band before: its length is added there, not written anew);
    block_end (4, moves): the columns' ends after each move; opened (moves,): the move
    was opened by some band; written (4,): what the chunk adds to each column.
    """
    nc, nb_, m = E.shape
    starts = np.zeros((nc, nb_, m), np.int64)
    cnt = np.zeros((nc, nb_, m), np.int64)
    dest = np.zeros((nc, nb_, m), np.int64)
    join = np.zeros((nb_, m), np.bool_)
    block_end = np.zeros((nc, m), np.int64)
    opened = np.zeros(m, np.bool_)
    written = np.zeros(nc, np.int64)
    for c in range(nc):
        for t in range(nb_):
            end = 0
            for q in range(m):
                e = E[c, t, q]
                if c == 0 and e >= 0:
                    opened[q] = True
                if e > end:
                    starts[c, t, q] = end
                    cnt[c, t, q] = e - end
                    end = e
                else:
                    starts[c, t, q] = end
    pos = base.copy()
    for q in range(m):
        prev_end = -1   # the end of the last run written for this move
        for t in range(nb_):
            for c in range(nc):
                n = cnt[c, t, q]
                if c == 3 and n > 0:
                    s = starts[3, t, q]
                    if rs_b[t, s] == prev_end:
                        join[t, q] = True
                        n -= 1
                    last = starts[3, t, q] + cnt[3, t, q] - 1
                    prev_end = rs_b[t, last] + rl_b[t, last]
                dest[c, t, q] = pos[c]
                pos[c] += n
                written[c] += n
        for c in range(nc):
            block_end[c, q] = pos[c]
    return starts, cnt, dest, join, block_end, opened, written


@nb.njit(cache=True, nogil=True)
def _copy_events(lo, hi, starts, cnt, dest, join, b_rs, b_val, b_rl, b_gray, b_gcnt, b_gn, b_gf, b_gni,
                 b_gfi, rs, val, rl, gray, gcnt, gn, gf, gni, gfi):
    """Copy the bands' events to where :class:`_Merge` placed them, those whose places lie
    in ``lo[c] <= place < hi[c]`` of each column c (far events, general events, their
    segments, far runs): threads copying disjoint ranges touch pages of their own.
    (``starts``/``cnt``/``dest``: (4 columns, bands, moves); a joined first run is left
    for the caller to add.)"""
    for t in range(starts.shape[1]):
        for q in range(starts.shape[2]):
            for c in range(4):
                j = 1 if (c == 3 and join[t, q]) else 0
                d = dest[c, t, q]
                a = max(d, lo[c])
                b = min(d + cnt[c, t, q] - j, hi[c])
                if a >= b:
                    continue
                s = starts[c, t, q] + j + a - d
                e = s + b - a
                if c == 0:
                    val[a:b] = b_val[t, s:e]
                elif c == 3:
                    rs[a:b] = b_rs[t, s:e]
                    rl[a:b] = b_rl[t, s:e]
                elif c == 1:
                    gray[a:b] = b_gray[t, s:e]
                    gcnt[a:b] = b_gcnt[t, s:e]
                else:
                    gn[a:b] = b_gn[t, s:e]
                    gf[a:b] = b_gf[t, s:e]
                    gni[a:b] = b_gni[t, s:e]
                    gfi[a:b] = b_gfi[t, s:e]
