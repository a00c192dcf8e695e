"""The fast trace (rule 6): the visible surface of every ray through time."""

from __future__ import annotations

import numpy as np

from sim import trace_kernels as tk
from sim.errors import InputError
from sim.frame import Frame
from sim.grid import DexelGrid
from sim.trace import keyframes  # KEYFRAME_BUDGET read at call time (tests lower it)
from sim.trace.columns import (
    _BlockLog, _Column, _check_stage, _get, _get_rle, _get_runs,
    _pack_column, _rays_arg, _runs_of_consecutive, _runs_of_equal, _unpack_column,
    frame_from_array, frame_to_array)
from sim.trace.keyframes import _Chunked, _Keyframe, _plain
from sim.trace.ztrace import ZTrace


class TimeTrace(_BlockLog):
    """Fast trace (rule 6): the visible surface of every ray through time.

    A time element is (ray, stage, top value, top face id): the last FarZ of the ray from
    that stage on (NaN where the ray became empty: the background). Pictures at any stage
    come from the nearest keyframe of the (nv, nu) heights plus the elements since it;
    :meth:`frames` animates forwards or backwards applying only the elements in between.
    """

    def __init__(self, grid_or_heights, stage: int = 0, ids: np.ndarray | None = None,
                 frame: Frame | None = None, keyframe_every: int | None = None,
                 max_keyframes: int = 48):
        if isinstance(grid_or_heights, DexelGrid):
            frame = grid_or_heights.frame
            top = grid_or_heights.top().reshape(-1).copy()
            rays = np.arange(frame.n_rays)
            tid = np.empty(frame.n_rays, np.int32)
            tk.gather_tops(grid_or_heights.S, rays, np.empty(frame.n_rays, np.float32), tid)
        else:
            if frame is None:
                raise InputError("a TimeTrace made from heights needs its frame")
            top = np.asarray(grid_or_heights, np.float32).reshape(-1).copy()
            tid = (np.zeros(frame.n_rays, np.int32) if ids is None
                   else np.asarray(ids, np.int32).reshape(-1).copy())
        self.frame = frame
        self.n_rays = frame.n_rays
        self.first_stage = int(stage)
        # the current surface packed (top bits, id) per ray: one 8-byte read per journal
        # entry; _top / _top_id are strided views of it
        self._cur = np.empty((self.n_rays, 2), np.int32)
        self._top = self._cur[:, 0].view(np.float32)
        self._top_id = self._cur[:, 1]
        self._top[:] = top
        self._top_id[:] = tid
        self._init = (top.copy(), tid.copy())
        # a rebuild scatters at most this many elements (~5 ns each: ~10 ms for 1M rays)
        self.keyframe_every = int(keyframe_every or 2 * self.n_rays)
        self.max_keyframes = int(max_keyframes)
        self._keyframes = [_Keyframe(0, self.first_stage, self._init)]
        self._since_key = 0
        self.auto_maintain = True   # see ZTrace.auto_maintain
        self._due: list[int] = []   # block counts whose keyframes are still to build
        self._builder = None        # [block, top, tid, copied, element done]
        self._cursors: dict[int, tuple] = {}
        self.truncated = False
        self._stage = _Column(np.int64)
        self._ptr = _Column(np.int64)
        self._ptr.push(0)
        self._ray = _Column(np.int32, 1 << 16)
        self._val = _Column(np.float32, 1 << 16)
        self._id = _Column(np.int32, 1 << 16)
        self._prev = _Column(np.float32, 1 << 16)   # previous element: rewinding (doubly linked)
        self._prev_id = _Column(np.int32, 1 << 16)

    @property
    def n_changes(self) -> int:
        return self._ray.n

    def record(self, grid: DexelGrid, rays=None, stage: int | None = None) -> int:
        """Record the visible-surface changes of ``rays`` (None = all) of ``grid``."""
        stage = self.last_stage + 1 if stage is None else _check_stage(self.last_stage, stage)
        rays = _rays_arg(rays, self.n_rays)
        m = rays.size
        out = (np.empty(m, np.int64), np.empty(m, np.float32), np.empty(m, np.int32),
               np.empty(m, np.float32), np.empty(m, np.int32))
        k = tk.top_changes(grid.S, rays, self._top, self._top_id, *out)
        self._append(stage, *(x[:k] for x in out))
        return int(k)

    def record_heights(self, heights: np.ndarray, ids: np.ndarray, stage: int | None = None) -> int:
        """Record a whole new visible surface (nv, nu) heights / face ids (e.g. from a viewer)."""
        stage = self.last_stage + 1 if stage is None else _check_stage(self.last_stage, stage)
        h = np.asarray(heights, np.float32).reshape(-1)
        i = np.asarray(ids, np.int32).reshape(-1)
        ch = np.nonzero(~((h == self._top) | (np.isnan(h) & np.isnan(self._top))) | (i != self._top_id))[0]
        prev, prev_id = self._top[ch].copy(), self._top_id[ch].copy()
        self._top[ch] = h[ch]
        self._top_id[ch] = i[ch]
        self._append(stage, ch, h[ch], i[ch], prev, prev_id)
        return int(ch.size)

    def _append(self, stage, ray, val, tid, prev, prev_id) -> None:
        self._ray.append(ray.astype(np.int32))
        self._val.append(val)
        self._id.append(tid)
        self._prev.append(prev)
        self._prev_id.append(prev_id)
        self._stage.push(stage)
        self._ptr.push(self._ray.n)
        self._schedule(ray.size)

    def _schedule(self, n_new: int, budget: int = 0) -> None:
        """Note ``n_new`` elements just appended; keyframes due are built a slice at a time."""
        self._since_key += n_new
        if self._since_key >= self.keyframe_every:
            # a batch may span several spacings: a keyframe at each block where one falls due
            p = self._ptr.a
            total = int(p[-1])
            nxt = total - self._since_key + self.keyframe_every
            while nxt <= total:
                b = int(np.searchsorted(p, nxt, side="left"))
                self._due.append(b)
                nxt = int(p[b]) + self.keyframe_every
            self._since_key = total - (nxt - self.keyframe_every)
        if self.auto_maintain and (self._due or self._builder is not None):
            self.maintain(max(budget, keyframes.KEYFRAME_BUDGET))

    def maintain(self, budget: int | None = None) -> bool:
        """Advance due keyframes by up to ``budget`` elements (None = finish them)."""
        left = np.inf if budget is None else int(budget)
        while left > 0:
            if self._builder is None:
                due = self._pop_due_block()
                if due is None:
                    return True
                base = self._keyframes[-1]
                self._builder = [due, base.data[0].copy(), base.data[1].copy(), base.block]
            b1, top, tid, cur = self._builder
            p = self._ptr.a
            stop = int(np.searchsorted(p, p[cur] + left, side="left")) if np.isfinite(left) else b1
            stop = min(max(stop, cur + 1), b1)
            tk.scatter_values(top, tid, self._ray.a[p[cur]:p[stop]], self._val.a[p[cur]:p[stop]],
                              self._id.a[p[cur]:p[stop]])
            left -= max(int(p[stop] - p[cur]), 1)
            self._builder[3] = stop
            if stop >= b1:
                self._add_keyframe(_Keyframe(b1, int(self._stage.a[b1 - 1]), (top, tid)))
                self._builder = None
        return self._builder is None and not self._due

    def state_at(self, stage: int, out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Heights (nv, nu) float32 mm (NaN = no material) and top face ids (nv, nu) int32.

        out : (heights, ids), optional
            Arrays of ``n_rays`` values (float32, int32, C-contiguous) to fill and return.
            When this trace filled them last (and they were not edited since), only the
            elements between their stage and ``stage`` are applied, forwards or backwards
            (each element keeps the value it replaced), when that is cheaper than copying
            the nearest keyframe.
        """
        import weakref
        b = self._blocks_upto(stage)
        key = self._keyframes[0]
        for k in self._keyframes:
            if k.block <= b:
                key = k
        p = self._ptr.a
        if out is None:
            top, tid = key.data[0].copy(), key.data[1].copy()
            start = key.block
        else:
            top, tid = (np.asarray(x).reshape(-1) for x in out)
            if top.size != self.n_rays or tid.size != self.n_rays or top.dtype != np.float32 \
                    or tid.dtype != np.int32 or not (np.shares_memory(top, out[0]) and np.shares_memory(tid, out[1])):
                raise InputError(f"state_at: out must be float32 and int32 arrays of {self.n_rays} values")
            cur = self._cursors.get(id(out[0]))
            cur_b = None
            if cur is not None and cur[0]() is out[0] and cur[1]() is out[1]:
                cur_b = cur[2]
            from_key = int(p[b] - p[key.block]) + self.n_rays // 4
            if cur_b is not None and abs(int(p[b] - p[cur_b])) <= from_key:
                start = cur_b
            else:
                np.copyto(top, key.data[0])
                np.copyto(tid, key.data[1])
                start = key.block
            if len(self._cursors) > 64:
                self._cursors = {k: v for k, v in self._cursors.items() if v[0]() is not None}
            self._cursors[id(out[0])] = (weakref.ref(out[0]), weakref.ref(out[1]), b)
        if start <= b:
            p0, p1 = int(p[start]), int(p[b])
            tk.scatter_values(top, tid, self._ray.a[p0:p1], self._val.a[p0:p1], self._id.a[p0:p1])
        else:
            tk.undo_values(top, tid, self._ray.a, self._prev.a, self._prev_id.a, int(p[b]), int(p[start]))
        if out is not None:
            return out
        return top.reshape(self.frame.shape), tid.reshape(self.frame.shape)

    def heights_at(self, stage: int, out: tuple | None = None) -> np.ndarray:
        """The visible surface at ``stage``: heights (nv, nu) float32 mm, NaN where empty."""
        return self.state_at(stage, out)[0]

    def removal_per_block(self, bottoms) -> tuple[np.ndarray, np.ndarray]:
        """(stages (B,) int64, volume taken from the top in each block (B,) mm^3).

        bottoms: a callable returning each ray's lowest material (n_rays,) mm at the first
        stage (where a ray emptied in a block falls to); called only when needed. Exact
        for material taken from the top of each ray (3-axis milling); material removed
        under an overhang is not seen from above.
        """
        ptr = self._ptr.a
        drop = np.nan_to_num(self._prev.a, nan=0.0).astype(np.float64) - np.nan_to_num(self._val.a, nan=0.0)
        empty_now = np.isnan(self._val.a)
        if empty_now.any():
            lo = np.asarray(bottoms(), np.float64)[self._ray.a[empty_now]]
            drop[empty_now] = np.nan_to_num(self._prev.a[empty_now], nan=0.0) - lo
        cs = np.concatenate([[0.0], np.cumsum(drop)])
        per_block = cs[ptr[1:]] - cs[ptr[:-1]]
        return self._stage.a.copy(), per_block * self.frame.spacing ** 2

    def keyframe_nbytes(self) -> int:
        return int(sum(k.data[0].nbytes + k.data[1].nbytes for k in self._keyframes[1:]))

    def frames(self, first: int, last: int, step: int = 1):
        """Yield ``(stage, heights, ids)`` from stage ``first`` to ``last`` (both included),
        every ``step`` stages; backwards when ``last < first``. The yielded arrays are one
        buffer updated in place (copy to keep). Each step costs the elements in between.
        """
        step = max(1, int(step))
        top, tid = self.state_at(first)
        top, tid = top.reshape(-1), tid.reshape(-1)
        shape = self.frame.shape
        yield int(first), top.reshape(shape), tid.reshape(shape)
        cur = int(first)
        direction = 1 if last >= first else -1
        while cur != last:
            nxt = cur + direction * step
            nxt = min(nxt, last) if direction > 0 else max(nxt, last)
            b_cur, b_nxt = self._blocks_upto(cur), self._blocks_upto(nxt)
            if direction > 0:
                p0, p1 = int(self._ptr.a[b_cur]), int(self._ptr.a[b_nxt])
                tk.scatter_values(top, tid, self._ray.a[p0:p1], self._val.a[p0:p1], self._id.a[p0:p1])
            else:
                p0, p1 = int(self._ptr.a[b_nxt]), int(self._ptr.a[b_cur])
                # undo newest first so each ray ends at its oldest previous value
                tk.scatter_values(top, tid, self._ray.a[p0:p1][::-1], self._prev.a[p0:p1][::-1],
                                  self._prev_id.a[p0:p1][::-1])
            cur = nxt
            yield cur, top.reshape(shape), tid.reshape(shape)

    def nbytes(self) -> int:
        """Bytes of the log in memory (values, ids, rays, stages; the rewind links excluded)."""
        return int(sum(c.nbytes for c in (self._stage, self._ptr, self._ray, self._val, self._id)))

    # --- serialisation --------------------------------------------------------------
    def header_arrays(self) -> dict[str, np.ndarray]:
        out = {"frame": frame_to_array(self.frame),
               "first_stage": np.array([self.first_stage], np.int64)}
        _pack_column(out, "init_top", self._init[0])
        _pack_column(out, "init_id", self._init[1])
        return out

    def _blocks_arrays(self, b0: int, b1: int) -> dict[str, np.ndarray]:
        """Blocks ``b0 <= b < b1``: ``stage``, ``t_n`` (B,) int64, ``t_ray_start``/
        ``t_ray_len`` int32 runs, ``t_val`` float32, ``t_id.rv``/``t_id.rl``."""
        p = self._ptr.a
        p0, p1 = int(p[b0]), int(p[b1])
        out = {"stage": self._stage.a[b0:b1].copy(), "t_n": np.diff(p[b0:b1 + 1]).astype(np.int64)}
        out["t_ray_start"], out["t_ray_len"] = _runs_of_consecutive(self._ray.a[p0:p1])
        out["t_val"] = self._val.a[p0:p1].copy()
        out["t_id.rv"], out["t_id.rl"] = _runs_of_equal(self._id.a[p0:p1])
        return out

    @classmethod
    def from_chunks(cls, chunks, where: str = "time-trace", **kw) -> "TimeTrace":
        chunks = list(chunks)
        if not chunks:
            raise InputError("no trace arrays", where)
        head = chunks[0]
        frame = frame_from_array(_get(head, "frame", np.float64, where), where)
        top = _unpack_column(head, "init_top", np.float32, frame.n_rays, where)
        tid = _unpack_column(head, "init_id", np.int32, frame.n_rays, where)
        first = _get(head, "first_stage", np.int64, where, required=False)
        trace = cls(top, int(first[0]) if first.size else 0, ids=tid, frame=frame, **kw)
        return trace._append_chunks(chunks, where)

    def _append_chunk(self, ch: dict, where: str) -> bool:
        stage = _get(ch, "stage", np.int64, where)
        t_n = _get(ch, "t_n", np.int64, where)
        if np.any(t_n < 0):
            raise InputError("negative count in t_n", where)
        ray = _get_runs(ch, "t_ray_start", "t_ray_len", where)
        val = _get(ch, "t_val", np.float32, where)
        tid = _get_rle(ch, "t_id", where)
        nb = min(stage.size, t_n.size)
        end = np.cumsum(t_n[:nb])
        have = min(ray.size, val.size, tid.size)
        ok = end <= have
        good = nb if ok.all() else int(np.argmin(ok))
        used = int(end[good - 1]) if good else 0
        if good:
            if np.any(np.diff(stage[:good]) < 0) or stage[0] < self.last_stage:
                raise InputError("trace stages decrease", where)
            if ray[:used].max(initial=0) >= self.n_rays or ray[:used].min(initial=0) < 0:
                raise InputError("ray index beyond the frame", where)
            self._append_bulk(stage[:good], t_n[:good], ray[:used], val[:used], tid[:used])
        return good == nb and used == have

    def _append_bulk(self, stage, t_n, ray, val, tid) -> None:
        """Append decoded blocks; the rewind links and keyframes are rebuilt on the way."""
        ray = ray.astype(np.int64)
        end = np.cumsum(t_n)
        b, o = 0, 0
        while b < stage.size:
            due = int(np.searchsorted(end, o + self.keyframe_every - self._since_key, side="left"))
            stop = min(due + 1, stage.size)
            e = int(end[stop - 1])
            prev = np.empty(e - o, np.float32)
            prev_id = np.empty(e - o, np.int32)
            tk.chain_prev(self._top, self._top_id, ray[o:e], val[o:e], tid[o:e], prev, prev_id)
            self._ray.append(ray[o:e].astype(np.int32))
            self._val.append(val[o:e])
            self._id.append(tid[o:e])
            self._prev.append(prev)
            self._prev_id.append(prev_id)
            self._stage.append(stage[b:stop])
            self._ptr.append(self._ptr.a[-1] + np.cumsum(t_n[b:stop]))
            self._since_key += e - o
            b, o = stop, e
            if self._since_key >= self.keyframe_every:
                self._add_keyframe(_Keyframe(self.n_blocks, self.last_stage,
                                             (self._top.copy(), self._top_id.copy())))
                self._since_key = 0


class SharedTimeTrace(TimeTrace):
    """The time-trace of a :class:`ZTrace`, sharing its events (one log, two indexes).

    A z-trace's far-only events (rule 5) *are* time elements: the new last FarZ of a ray
    and its face id. Its general rewrites carry their new top too (the last FarZ of the
    segment list, NaN when emptied). So the pictures of rule 6 need no log of their own:
    this class reads the z-trace's columns, starts from its keyframes (the tops of a
    keyframe's store, read straight into the caller's arrays: as cheap as a copy), and
    applies the events in between in one compiled loop. Recording goes through the z-trace; nothing
    of this trace is serialised but a marker (``shared``).
    """

    def __init__(self, z: ZTrace):  # noqa: D107 - no TimeTrace state of its own
        self._z = z
        self._stage = z._stage  # the same blocks: stages, last stage, lookups come with it
        self.frame = z.frame
        self.n_rays = z.n_rays
        self.auto_maintain = True
        self.truncated = False
        self._cursors: dict[int, tuple] = {}

    # the log is the z-trace's
    @property
    def first_stage(self) -> int:
        return self._z.first_stage

    @property
    def n_changes(self) -> int:
        return self._z.n_changes

    @property
    def _keyframes(self) -> list:
        return self._z._keyframes

    @property
    def _init(self) -> tuple:
        n = self.n_rays
        return self._key_tops(self._z._keyframes[0], np.empty(n, np.float32), np.empty(n, np.int32))

    def record(self, grid, rays=None, stage=None) -> int:
        raise InputError("a shared time-trace is recorded through its z-trace")

    record_heights = record

    def maintain(self, budget: int | None = None) -> bool:
        return True

    def nbytes(self) -> int:
        return 0

    def keyframe_nbytes(self) -> int:
        return 0

    def _key_tops(self, key: _Keyframe, top: np.ndarray, tid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The visible surface of keyframe ``key`` into ``top`` / ``tid`` (n_rays,)."""
        d = key.data
        parts = zip(*(_Chunked.of(d[k]).chunks for k in ("count", "far", "far_id", "xstart")))
        ch = _Chunked.CHUNK
        for i, chunk in enumerate(parts):   # chunk by chunk: no copy of the model
            # but of a block of stock's broadcast values (a chunk of 16k rays): the kernel
            # takes plain arrays (a read-only one would compile it again, slower)
            c, f, fi, x = (_plain(p) for p in chunk)
            sl = slice(i * ch, i * ch + f.size)
            tk.tops_of_store(c, f, fi, x, d["pool_far"], d["pool_far_id"], top[sl], tid[sl])
        return top, tid

    def _apply(self, top: np.ndarray, tid: np.ndarray, b0: int, b1: int) -> None:
        z = self._z
        if b1 > b0:
            tk.apply_tops(top, tid, b0, b1, z._f_ptr.a, z._r_ptr.a, z._f_rs.a, z._f_rl.a, z._f_val.a,
                          z._f_id.buf, z._b_id.a,
                          z._g_ptr.a, z._gs_ptr.a, z._g_ray.a, z._g_count.a, z._g_far.a, z._g_fid.a)

    def state_at(self, stage: int, out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`TimeTrace.state_at`. With ``out`` last filled by this trace, going
        forwards applies only the events in between when that is cheaper than starting
        from the nearest keyframe; going backwards starts from the keyframe."""
        import weakref
        z = self._z
        b = z._blocks_upto(stage)
        key = z._key_for(b)
        if out is None:
            top, tid = self._key_tops(key, np.empty(self.n_rays, np.float32), np.empty(self.n_rays, np.int32))
            self._apply(top, tid, key.block, b)
            return top.reshape(self.frame.shape), tid.reshape(self.frame.shape)
        top, tid = (np.asarray(x).reshape(-1) for x in out)
        if top.size != self.n_rays or tid.size != self.n_rays or top.dtype != np.float32 \
                or tid.dtype != np.int32 or not (np.shares_memory(top, out[0]) and np.shares_memory(tid, out[1])):
            raise InputError(f"state_at: out must be float32 and int32 arrays of {self.n_rays} values")
        cur = self._cursors.get(id(out[0]))
        cur_b = cur[2] if cur is not None and cur[0]() is out[0] and cur[1]() is out[1] else None
        if cur_b is not None and key.block <= cur_b <= b \
                and z._events(cur_b, b) <= z._events(key.block, b) + self.n_rays // 4:
            start = cur_b
        else:
            self._key_tops(key, top, tid)
            start = key.block
        self._apply(top, tid, start, b)
        if len(self._cursors) > 64:
            self._cursors = {k: v for k, v in self._cursors.items() if v[0]() is not None}
        self._cursors[id(out[0])] = (weakref.ref(out[0]), weakref.ref(out[1]), b)
        return out

    def frames(self, first: int, last: int, step: int = 1):
        """As :meth:`TimeTrace.frames`; backwards each frame starts from a keyframe."""
        step = max(1, int(step))
        shape = self.frame.shape
        buf = (np.empty(shape, np.float32), np.empty(shape, np.int32))
        cur = int(first)
        self.state_at(cur, buf)
        yield cur, buf[0], buf[1]
        direction = 1 if last >= first else -1
        while cur != last:
            nxt = cur + direction * step
            cur = min(nxt, last) if direction > 0 else max(nxt, last)
            self.state_at(cur, buf)
            yield cur, buf[0], buf[1]

    def removal_per_block(self, bottoms) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`TimeTrace.removal_per_block`: one pass over the z-trace's events."""
        z = self._z
        top = self._init[0]
        out = np.zeros(z.n_blocks)
        tk.surface_drops(top, np.asarray(bottoms(), np.float64), z._f_ptr.a, z._r_ptr.a, z._f_rs.a,
                         z._f_rl.a, z._f_val.a,
                         z._g_ptr.a, z._gs_ptr.a, z._g_ray.a, z._g_count.a, z._g_far.a, out)
        return z.stages, out * self.frame.spacing ** 2

    def header_arrays(self) -> dict[str, np.ndarray]:
        return {"shared": np.array([1], np.int8)}

    def _blocks_arrays(self, b0: int, b1: int) -> dict[str, np.ndarray]:
        return {}
