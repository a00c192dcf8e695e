"""The complete trace (Blasquez & Poiraudeau rules 1-5): every change of every ray."""

from __future__ import annotations

import numpy as np

from sim import dexel_store as ds
from sim import trace_kernels as tk
from sim.bands import mark_ray_chunks
from sim.errors import InputError
from sim.grid import DexelGrid, store_segments
from sim.tolerance import DEFAULT, Tolerance
from sim.trace import keyframes  # KEYFRAME_BUDGET read at call time (tests lower it)
from sim.trace.columns import (
    _BlockLog, _Column, _Cursor, _check_stage, _expand_consecutive, _get,
    _get_rle, _get_runs, _pack_column, _rays_arg, _runs_of_equal, _unpack_column,
    frame_from_array, frame_to_array)
from sim.trace.keyframes import (
    _Chunked, _FAR_FIELDS, _KeyBuilder, _Keyframe, _POOL_FIELDS, _RAY_FIELDS,
    _snapshot_sharing, _stock_snapshot, _store_copy)
from sim.trace.sink import _Sink


class ZTrace(_BlockLog):
    """Complete trace of a dexel model (Blasquez & Poiraudeau rules 1-5) with keyframes.

    Parameters
    ----------
    grid : DexelGrid
        The model at ``stage``; the trace keeps a copy of it, and (from the first
        :meth:`record` on) of the state it last saw, so :meth:`record` knows what each ray
        was before.
    stage : int
        The stage of ``grid`` (normally 0: the stock).
    keyframe_every : int, optional
        A keyframe (a copy of the model) falls due after this many recorded ray changes;
        default ``2 * n_rays`` (far-only events replay at ~3-5 ns each, so a rebuild from
        the nearest keyframe costs under 10 ms; the shared time-trace starts from the same
        keyframes). Keyframes are an in-memory index, not serialised. They are
        built a slice at a time by later record calls (:meth:`maintain`), never all at
        once on the recording path; keyframes between which only far-only edits happened
        share every array but the FarZ values and ids.
    max_keyframes : int
        When exceeded, every other keyframe is dropped and the spacing doubles, so memory
        stays bounded on long runs.
    """

    def __init__(self, grid: DexelGrid, stage: int = 0, keyframe_every: int | None = None,
                 max_keyframes: int = 48):
        self.frame = grid.frame
        self.tol = grid.tol
        self.n_rays = grid.frame.n_rays
        # the model at the last stage, kept for diffing later records: made when first
        # needed (a trace fed only by batch cuts never needs it; see _ensure_mirror)
        self._mirror: DexelGrid | None = None
        self._rec = self._recf = None
        self.first_stage = int(stage)
        self.keyframe_every = int(keyframe_every or max(2 * self.n_rays, 1))
        self.max_keyframes = int(max_keyframes)
        self._init = _stock_snapshot(grid.store)
        self._keyframes = [_Keyframe(0, self.first_stage, self._init)]
        #: build due keyframes a slice at a time inside record calls; False leaves them to
        #: :meth:`maintain` (a live loop calls it off the poll's critical path)
        self.auto_maintain = True
        self._next_due = self.keyframe_every  # events count at which a keyframe falls due
        self._due: list[int] = []  # block counts whose keyframes are still to build
        self._builder: _KeyBuilder | None = None
        self.truncated = False
        self._state = np.zeros(2, np.int64)
        self._cnt = np.zeros(3, np.int64)
        # block columns
        self._stage = _Column(np.int64)
        self._f_ptr = _Column(np.int64)
        self._g_ptr = _Column(np.int64)
        self._gs_ptr = _Column(np.int64)
        self._r_ptr = _Column(np.int64)
        for c in (self._f_ptr, self._g_ptr, self._gs_ptr, self._r_ptr):
            c.push(0)
        # event columns
        # far events: their rays as runs of consecutive rays (start, length; block b's runs
        # end at _r_ptr[b + 1]), one value each in _f_val
        self._f_rs = _Column(np.int32, 1 << 14)
        self._f_rl = _Column(np.int32, 1 << 14)
        self._f_val = _Column(np.float32, 1 << 16)
        self._f_id = _Column(np.int32, 1 << 16)
        # per block: the face id of all its far events (a traced batch's move), or -1 when
        # they carry their own in _f_id (index for index with _f_val; a block with one id
        # leaves its stretch of _f_id unwritten: untouched pages cost no memory)
        self._b_id = _Column(np.int32)
        self._g_ray = _Column(np.int32)
        self._g_count = _Column(np.int16)
        self._g_near = _Column(np.float32)
        self._g_far = _Column(np.float32)
        self._g_nid = _Column(np.int32)
        self._g_fid = _Column(np.int32)
        # per ray: the block and slot of its latest event while a batch cuts straight into
        # the trace (see sink); made on first use
        self._mark: np.ndarray | None = None
        self._slot: np.ndarray | None = None

    # --- recording ------------------------------------------------------------------
    @property
    def n_changes(self) -> int:
        """Ray changes recorded (far-only edits plus general rewrites)."""
        return self._f_val.n + self._g_ray.n

    def _event_columns(self, rays_scratch: np.ndarray, n_events: int, n_segs: int) -> tuple:
        """The event column buffers with room for ``n_events`` events / ``n_segs`` segments
        (far events' rays go to ``rays_scratch``, made into runs afterwards)."""
        return (rays_scratch, self._f_val.reserve(n_events), self._f_id.reserve(n_events),
                self._g_ray.reserve(n_events), self._g_count.reserve(n_events),
                self._g_near.reserve(n_segs), self._g_far.reserve(n_segs),
                self._g_nid.reserve(n_segs), self._g_fid.reserve(n_segs))

    def _set_counts(self) -> None:
        self._f_val.n = self._f_id.n = int(self._cnt[0])
        self._g_ray.n = self._g_count.n = int(self._cnt[1])
        self._g_near.n = self._g_far.n = self._g_nid.n = self._g_fid.n = int(self._cnt[2])

    def record(self, grid: DexelGrid, rays=None, stage: int | None = None) -> int:
        """Record the changes of ``rays`` (flat indices; None = all) of ``grid`` as ``stage``.

        ``rays`` may over-cover (unchanged rays are skipped) but must include every ray that
        changed since the last record. Returns the number of rays that changed. One
        compiled pass over ``rays``; keyframe work due is done a slice at a time.
        """
        stage = self.last_stage + 1 if stage is None else _check_stage(self.last_stage, stage)
        if grid.frame is not self.frame and not grid.frame.same_rays(self.frame):
            raise InputError("recorded grid is not on the trace's dexel frame")
        rays = _rays_arg(rays, self.n_rays)
        # the rays' segments as a one-move journal: one compiled pass does the rest
        n, f, ni, fi, counts = grid.segments_of(rays)
        seg_ptr = np.zeros(rays.size + 1, np.int64)
        np.cumsum(counts, out=seg_ptr[1:])
        return self._ingest(np.array([0, rays.size], np.int64), rays, seg_ptr, (n, f, ni, fi),
                            np.array([stage], np.int64))

    def _ensure_mirror(self) -> None:
        """Make the mirror (the model at the last stage, rebuilt from the nearest keyframe)
        and its cache of one-segment rays (one 16-byte read per journal entry decides the
        common far-only edit; the mirror is stale for the rays it holds)."""
        if self._mirror is not None:
            return
        self._mirror = self.grid_at(self.last_stage)
        self._rec = np.empty((self.n_rays, 4), np.int32)
        self._recf = self._rec.view(np.float32)
        tk.simple_rec_from_store(self._mirror.S, self._rec, self._recf)

    def sink(self, grid: DexelGrid, n_moves: int, stages=None, move_ids=None) -> "_Sink":
        """Where a batch cut writes this trace's events as it cuts (``Cutter.cut_moves(...,
        trace=...)``): one block per move, equal to cutting and recording each move alone.
        ``grid`` is the model being cut, equal to the trace's last stage; ``move_ids`` int
        (n_moves,) the face ids the moves write (default 1, 2, ...)."""
        return _Sink(self, grid, n_moves, stages, move_ids)

    def _ingest(self, ptr, rays, seg_ptr, segs, stages) -> int:
        self._ensure_mirror()
        n_moves = ptr.size - 1
        n_entries, n_segs = rays.size, int(seg_ptr[-1])
        before = self.n_changes
        blk = [np.empty(n_moves, np.int64) for _ in range(3)]
        cnt, state = self._cnt, self._state
        cnt[:] = (self._f_val.n, self._g_ray.n, self._g_near.n)
        f0 = int(cnt[0])
        scratch = np.empty(n_entries, np.int32)
        state[:] = 0
        segs = [np.ascontiguousarray(x, dt) for x, dt in
                zip(segs, (np.float32, np.float32, np.int32, np.int32))]
        jn, jf = segs[0], segs[1]
        jnb, jfb = jn.view(np.int32), jf.view(np.int32)
        while True:
            out = self._event_columns(scratch, n_entries, n_segs)
            status = tk.ingest_journal_fast(self._rec, self._recf, self._mirror.S, ptr, rays, seg_ptr,
                                            *segs, jnb, jfb, state, cnt, *blk, *out, f0)
            if status == tk.DONE:
                break
            ds.grow_pool(self._mirror.store, 2 * n_segs + 64)
        self._set_counts()
        r_end = self._append_runs(scratch[:int(cnt[0]) - f0], np.diff(blk[0], prepend=f0))
        new = self.n_changes - before
        self._close_blocks(stages, *blk, r_end)
        return new

    def _append_runs(self, rays: np.ndarray, per_block: np.ndarray) -> np.ndarray:
        """Append far events' ``rays`` (``per_block`` of them to each new block, in order) as
        runs of consecutive rays that stop at block ends; returns each block's run end."""
        per_block = np.asarray(per_block, np.int64)
        r0 = self._f_rs.n
        if rays.size == 0:
            return np.full(per_block.size, r0, np.int64)
        rays = rays.astype(np.int64)
        ends = np.cumsum(per_block)
        cut = np.diff(rays) != 1
        inner = ends[:-1][(ends[:-1] > 0) & (ends[:-1] < rays.size)]
        cut[inner - 1] = True
        first = np.concatenate([[0], np.flatnonzero(cut) + 1])
        lens = np.diff(np.concatenate([first, [rays.size]]))
        self._f_rs.append(rays[first].astype(np.int32))
        self._f_rl.append(lens.astype(np.int32))
        # runs starting before each block's end
        return r0 + np.searchsorted(first, ends, side="left")

    def _dirty_chunks(self, r0: int, r1: int, g0: int, g1: int) -> np.ndarray:
        """bool (n_chunks,): which :class:`_Chunked` chunks of rays the far-event runs
        ``r0:r1`` and the general events ``g0:g1`` touch (what a keyframe after them copies;
        it shares the rest with the keyframe before)."""
        ch = _Chunked.CHUNK
        return mark_ray_chunks(np.zeros(-(-self.n_rays // ch), np.bool_), ch, self._f_rs.buf[r0:r1],
                               self._f_rl.buf[r0:r1], self._g_ray.buf[g0:g1])

    def _close_blocks(self, stages, f_end, g_end, s_end, r_end, budget: int = 0, block_ids=None) -> None:
        """Append block rows (stage, column ends, the blocks' one face id or -1) and schedule
        the keyframes that fall due."""
        b0 = self.n_blocks
        self._r_ptr.append(r_end)
        self._b_id.append(np.full(len(stages), -1, np.int32) if block_ids is None
                          else np.asarray(block_ids, np.int32))
        self._stage.append(stages)
        self._f_ptr.append(f_end)
        self._g_ptr.append(g_end)
        self._gs_ptr.append(s_end)
        ev = self._f_ptr.a + self._g_ptr.a
        total = int(ev[-1])
        while total >= self._next_due:
            b = int(np.searchsorted(ev, self._next_due, side="left", sorter=None))
            b = max(b, b0 + 1)
            self._due.append(b)
            self._next_due = int(ev[b]) + self.keyframe_every
        if self.auto_maintain and (self._due or self._builder is not None):
            self.maintain(max(budget, keyframes.KEYFRAME_BUDGET))

    def maintain(self, budget: int | None = None) -> bool:
        """Advance the keyframes that fell due by up to ``budget`` units of work (array
        elements copied or events replayed; None = finish them). True when none is left.
        """
        left = np.inf if budget is None else int(budget)
        while left > 0:
            if self._builder is None:
                due = self._pop_due_block()
                if due is None:
                    return True
                self._builder = _KeyBuilder(self, due)
            used = self._builder.step(int(min(left, 1 << 62)))
            left -= max(used, 1)
            if self._builder.done:
                self._add_keyframe(self._builder.finish())
                self._builder = None
        return self._builder is None and not self._due

    def _append_blocks(self, stage, f_n, g_n, f_ray, f_val, f_id, g_ray, g_count, gsegs) -> None:
        """Append decoded blocks in bulk, then bring the mirror (and keyframes) up to date."""
        self._ensure_mirror()
        b0 = self.n_blocks
        self._stage.append(stage)
        self._b_id.append(np.full(len(stage), -1, np.int32))
        self._r_ptr.append(self._append_runs(np.asarray(f_ray), f_n))
        self._f_ptr.append(self._f_ptr.a[-1] + np.cumsum(f_n))
        self._g_ptr.append(self._g_ptr.a[-1] + np.cumsum(g_n))
        seg_n = np.zeros(g_n.size, np.int64)
        if g_count.size:
            seg_cum = np.concatenate([[0], np.cumsum(g_count.astype(np.int64))])
            ends = np.cumsum(g_n)
            seg_n = np.diff(np.concatenate([[0], seg_cum[ends]]))
        self._gs_ptr.append(self._gs_ptr.a[-1] + np.cumsum(seg_n))
        self._f_val.append(f_val)
        self._f_id.append(f_id.astype(np.int32))
        self._g_ray.append(g_ray.astype(np.int32))
        self._g_count.append(g_count.astype(np.int16))
        for col, x in zip((self._g_near, self._g_far, self._g_nid, self._g_fid), gsegs):
            col.append(x)
        # replay into the mirror, stopping where a keyframe falls due to snapshot it
        tk.sync_mirror(self._rec, self._recf, self._mirror.S)
        ev = self._f_ptr.a + self._g_ptr.a
        b = b0
        while b < self.n_blocks:
            due = int(np.searchsorted(ev, self._next_due, side="left"))
            stop = min(max(due, b + 1), self.n_blocks)
            self._replay(self._mirror, b, stop)
            b = stop
            if int(ev[b]) >= self._next_due:
                prev = self._keyframes[-1]
                g0, g1 = int(self._g_ptr.a[prev.block]), int(self._g_ptr.a[b])
                dirty = self._dirty_chunks(int(self._r_ptr.a[prev.block]), int(self._r_ptr.a[b]), g0, g1)
                self._add_keyframe(_Keyframe(b, int(self._stage.a[b - 1]),
                                             _snapshot_sharing(self._mirror.store, prev.data, g1 > g0, dirty)))
                self._next_due = int(ev[b]) + self.keyframe_every
        tk.simple_rec_from_store(self._mirror.S, self._rec, self._recf)

    # --- rebuilding -----------------------------------------------------------------

    def _events(self, b0: int, b1: int) -> int:
        return int(self._f_ptr.a[b1] - self._f_ptr.a[b0] + self._g_ptr.a[b1] - self._g_ptr.a[b0])

    def forget_blocks(self) -> None:
        """Drop every recorded block and keyframe (and the first stage's model), keeping
        the model at the last stage that records diff against and the columns' room.

        For a trace whose blocks are handed on as they come (a :class:`Trace` made with
        ``keep_history=False``): memory and work per record then stay those of one chunk
        however long the run (no column doubling, no keyframe). The trace records on from
        its last stage but rebuilds no stage: read its chunks back with
        :meth:`Trace.from_chunks`."""
        self._ensure_mirror()
        self.first_stage = self.last_stage
        for c in (self._stage, self._b_id, self._f_rs, self._f_rl, self._f_val, self._f_id, self._g_ray,
                  self._g_count, self._g_near, self._g_far, self._g_nid, self._g_fid):
            c.n = 0
        for c in (self._f_ptr, self._g_ptr, self._gs_ptr, self._r_ptr):
            c.n = 0
            c.push(0)
        self._init = None
        self._keyframes = []
        self._due, self._builder = [], None
        self._next_due = np.iinfo(np.int64).max  # no keyframe: there is no history to index

    def _key_for(self, b: int) -> _Keyframe:
        if not self._keyframes:
            raise InputError("this trace hands its blocks on as it records (keep_history=False) and "
                             "rebuilds no stage: read its chunks back with Trace.from_chunks")
        key = self._keyframes[0]
        for k in self._keyframes:
            if k.block <= b:
                key = k
        return key

    def grid_at(self, stage: int, out: DexelGrid | None = None) -> DexelGrid:
        """The model as it was at ``stage`` (ray for ray equal).

        Stages before the first give the initial model; stages after the last, the last.
        out : DexelGrid, optional
            A grid to fill and return instead of a new one. When ``out`` was last filled by
            this trace (and not edited since), only the changes between its stage and
            ``stage`` are applied when that is cheaper than restoring the nearest keyframe
            (copying the arrays that differ from it) and replaying from there; stepping
            back always goes through a keyframe.
        """
        b = self._blocks_upto(stage)
        key = self._key_for(b)
        spare = 2 * int(self._gs_ptr.a[b] - self._gs_ptr.a[key.block]) + 64
        if out is None:
            grid = DexelGrid(self.frame, self.tol, _store_copy(key.data, spare))
            self._replay(grid, key.block, b)
            return grid
        if not out.frame.same_rays(self.frame):
            raise InputError("grid_at: out is not on the trace's dexel frame")
        cur = getattr(out, "_ztrace_cursor", None)
        if cur is not None and cur.owner is not self:
            cur = None
        from_key = self._events(key.block, b) + self.n_rays // 2  # restoring costs a copy
        if cur is not None and key.block <= cur.block <= b and self._events(cur.block, b) <= from_key:
            start, clean = cur.block, cur.clean
        else:
            self._restore(out, key, spare, cur.clean if cur is not None else {})
            start, clean = key.block, dict(key.data)
        self._replay(out, start, b)
        if self._g_ptr.a[b] > self._g_ptr.a[start]:
            clean = {}
        elif self._f_ptr.a[b] > self._f_ptr.a[start]:
            clean = {k: v for k, v in clean.items() if k not in _FAR_FIELDS}
        out._ztrace_cursor = _Cursor(self, b, clean)
        return out

    def _restore(self, out: DexelGrid, key: _Keyframe, spare: int, clean: dict) -> None:
        """Make ``out`` equal to keyframe ``key`` copying only what differs from it."""
        st = out.store
        out._ztrace_cursor = None  # half-restored until the caller sets it again
        top = int(key.data["pool_top"][0])
        for k in ds.STORE_FIELDS:
            src = key.data[k]
            if clean.get(k) is src and st[k].size >= (top if k in _POOL_FIELDS else src.size):
                continue
            if k in _POOL_FIELDS:
                if st[k].size < top + spare:
                    st[k] = np.zeros(max(top + spare, 1024), src.dtype)
                st[k][:top] = src[:top]
            elif k == "pool_top":
                st[k][0] = top
            elif isinstance(src, _Chunked):
                src.copy_into(st[k])
            else:
                np.copyto(st[k], src)

    def rewind(self, stage: int, out: DexelGrid | None = None) -> DexelGrid:
        """Alias of :meth:`grid_at` for going back in time (keyframes make it cheap)."""
        return self.grid_at(stage, out)

    def _replay(self, grid: DexelGrid, b0: int, b1: int) -> None:
        self._replay_store(grid.store, b0, b1)

    def _replay_store(self, store: dict, b0: int, b1: int) -> None:
        """Apply blocks ``b0 <= b < b1`` to ``store``: runs of far-only blocks in one tight
        loop over their events, blocks with general rewrites one at a time."""
        if b1 <= b0:
            return
        gp = self._g_ptr.a
        gen = b0 + np.flatnonzero(gp[b0 + 1:b1 + 1] > gp[b0:b1])
        b = b0
        for g in [*gen.tolist(), b1]:
            if g > b:
                self._replay_far(store, b, g)
            if g < b1:
                self._replay_general(store, g, g + 1)
            b = g + 1

    def _replay_far(self, store: dict, b0: int, b1: int) -> None:
        st = tk.replay_far_only(store["count"], store["far"], store["far_id"], store["xstart"],
                                store["pool_far"], store["pool_far_id"], self._f_ptr.a, self._r_ptr.a,
                                self._f_rs.a, self._f_rl.a, self._f_val.a, self._f_id.buf, self._b_id.a,
                                b0, b1)
        if st < 0:
            b = -1 - st
            raise InputError(f"corrupt trace: block {b} (stage {self._stage.a[b]}) "
                             "edits the top of a ray that holds no material")

    def _replay_general(self, store: dict, b0: int, b1: int) -> None:
        cols = (self._f_ptr.a, self._r_ptr.a, self._f_rs.a, self._f_rl.a, self._f_val.a, self._f_id.buf,
                self._b_id.a, self._g_ptr.a,
                self._gs_ptr.a, self._g_ray.a, self._g_count.a, self._g_near.a, self._g_far.a,
                self._g_nid.a, self._g_fid.a)
        redo = False  # a block stopped by a full pool is redone without its far edits
        while b0 < b1:
            b0 = tk.replay_blocks(ds.store_tuple(store), b0, b1, *cols, redo)
            if b0 < 0:
                raise InputError(f"corrupt trace: block {-1 - b0} (stage {self._stage.a[-1 - b0]}) "
                                 "edits the top of a ray that holds no material")
            if b0 < b1:
                ds.grow_pool(store, 2 * int(self._gs_ptr.a[b0 + 1] - self._gs_ptr.a[b0]) + 64)
                redo = True

    def current(self) -> DexelGrid:
        """A copy of the model at the last recorded stage."""
        self._ensure_mirror()
        tk.sync_mirror(self._rec, self._recf, self._mirror.S)
        return self._mirror.copy()

    # --- the paper's view: Z elements ---------------------------------------------
    def ray_history(self, i: int, j: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """States of ray (i, j): a list of ``(stage, segments (k,2) float32, ids (k,2) int32)``,
        the first at the trace's first stage, then one per stage that changed the ray."""
        r = int(j) * self.frame.nu + int(i)
        cur = self._init_ray(r)
        out = [(self.first_stage, cur[0].copy(), cur[1].copy())]
        f_hits = self._far_events_of(r)
        g_hits = np.nonzero(self._g_ray.a == r)[0]
        fb = np.searchsorted(self._f_ptr.a, f_hits, side="right") - 1
        gb = np.searchsorted(self._g_ptr.a, g_hits, side="right") - 1
        events = sorted([(int(b), "f", int(q)) for b, q in zip(fb, f_hits)]
                        + [(int(b), "g", int(q)) for b, q in zip(gb, g_hits)])
        for b, kind, q in events:
            segs, ids = out[-1][1].copy(), out[-1][2].copy()
            if kind == "f":
                segs[-1, 1] = self._f_val.a[q]
                ids[-1, 1] = self._b_id.a[b] if self._b_id.a[b] >= 0 else self._f_id.buf[q]
            else:
                s0 = int(self._gs_ptr.a[b] + self._g_count.a[self._g_ptr.a[b]:q].astype(np.int64).sum())
                c = int(self._g_count.a[q])
                segs = np.stack([self._g_near.a[s0:s0 + c], self._g_far.a[s0:s0 + c]], axis=1)
                ids = np.stack([self._g_nid.a[s0:s0 + c], self._g_fid.a[s0:s0 + c]], axis=1)
            out.append((int(self._stage.a[b]), segs, ids))
        return out

    def _far_events_of(self, r: int) -> np.ndarray:
        """Indices of the far events of ray ``r``, in order (from the runs that hold it)."""
        rs, rl = self._f_rs.a.astype(np.int64), self._f_rl.a.astype(np.int64)
        k = np.flatnonzero((rs <= r) & (r < rs + rl))
        first_event = np.cumsum(rl) - rl
        return first_event[k] + (r - rs[k])

    def far_rays(self, b0: int, b1: int) -> np.ndarray:
        """The ray of every far event of blocks ``b0 <= b < b1`` (int64, in event order)."""
        r0, r1 = int(self._r_ptr.a[b0]), int(self._r_ptr.a[b1])
        return _expand_consecutive(self._f_rs.a[r0:r1], self._f_rl.a[r0:r1])

    def _init_ray(self, r: int):
        """Ray ``r`` at the first stage: segments (k, 2) float32, face ids (k, 2) int32 (read
        from a one-ray store: the first keyframe's per-ray arrays may be broadcast)."""
        one = {k: np.ascontiguousarray(v[r:r + 1]) if k in _RAY_FIELDS else v for k, v in self._init.items()}
        n, f, ni, fi, _ = store_segments(one, np.zeros(1, np.int64))
        return np.stack([n, f], axis=1), np.stack([ni, fi], axis=1)

    def z_elements(self, i: int, j: int) -> np.ndarray:
        """Z elements of ray (i, j) as in the paper: a structured array sorted by value with
        fields ``z`` (float32 mm), ``far`` (bool: a FarZ, else a NearZ), ``face_id`` (int32,
        the "colour"), ``created`` and ``deleted`` (int64 stages; deleted = 2**62 while alive).

        Rules 2-5 hold: a new segment adds two elements, a deleted one closes two, a moved
        NearZ or FarZ closes one and adds one. Selecting ``created <= n < deleted`` and
        pairing in order gives the ray at stage ``n``.
        """
        alive: dict[tuple, int] = {}
        rows: list[list] = []
        for stage, segs, ids in self.ray_history(i, j):
            now = {}
            for (n, f), (ni, fi) in zip(segs.tolist(), ids.tolist()):
                now[(float(n), False, int(ni))] = None
                now[(float(f), True, int(fi))] = None
            for key in list(alive):
                if key not in now:
                    rows[alive.pop(key)][4] = stage
            for key in now:
                if key not in alive:
                    alive[key] = len(rows)
                    rows.append([key[0], key[1], key[2], stage, 2**62])
        dt = np.dtype([("z", np.float32), ("far", bool), ("face_id", np.int32),
                       ("created", np.int64), ("deleted", np.int64)])
        out = np.array([tuple(r) for r in rows], dtype=dt)
        return np.sort(out, order=["z", "created"])

    # --- size -----------------------------------------------------------------------
    def nbytes(self) -> int:
        """Bytes of the recorded log in memory (keyframes and the mirror not counted)."""
        cols = (self._stage, self._f_ptr, self._g_ptr, self._gs_ptr, self._r_ptr, self._f_rs, self._f_rl,
                self._f_val,
                self._b_id, self._g_ray, self._g_count, self._g_near, self._g_far, self._g_nid, self._g_fid)
        fp = self._f_ptr.a
        own_ids = int(np.sum(np.diff(fp)[self._b_id.a < 0])) if self.n_blocks else 0
        return int(sum(c.nbytes for c in cols)) + 4 * own_ids

    def keyframe_nbytes(self) -> int:
        """Bytes of the keyframes (arrays shared between keyframes counted once; the stock's
        arrays not counted)."""
        def parts(v):
            return v.chunks if isinstance(v, _Chunked) else [v]
        if not self._keyframes:  # forgotten (forget_blocks)
            return 0
        def root(a):   # the array owning the memory (a view's base is its owner's)
            return a if a.base is None else a.base
        seen = {id(p) for v in self._keyframes[0].data.values() for p in parts(v)}
        # chunks that are views of the stock's arrays (or of its broadcast values) are
        # the stock's bytes
        stock = {id(root(v)) for v in self._keyframes[0].data.values() if isinstance(v, np.ndarray)}
        seen |= {id(p) for k in self._keyframes for v in k.data.values() for p in parts(v)
                 if isinstance(p, np.ndarray) and id(root(p)) in stock}
        total = 0
        for k in self._keyframes[1:]:
            for v in k.data.values():
                for p in parts(v):
                    if id(p) not in seen:
                        seen.add(id(p))
                        total += p.nbytes
        return int(total)

    # --- serialisation -------------------------------------------------------------
    def header_arrays(self) -> dict[str, np.ndarray]:
        """Frame, tolerance and the model at the first stage (run-length coded where it pays)."""
        if self._init is None:
            raise InputError("this trace handed its header and blocks on (keep_history=False)")
        plain = {k: np.ascontiguousarray(v) for k, v in self._init.items()}   # broadcast ones too
        n, f, ni, fi, c = store_segments(plain, np.arange(self.n_rays))
        out = {"frame": frame_to_array(self.frame),
               "tol_length": np.array([self.tol.length]),
               "first_stage": np.array([self.first_stage], np.int64)}
        _pack_column(out, "init_count", c.astype(np.int16))
        _pack_column(out, "init_near", n)
        _pack_column(out, "init_far", f)
        _pack_column(out, "init_nid", ni)
        _pack_column(out, "init_fid", fi)
        return out

    def _blocks_arrays(self, b0: int, b1: int) -> dict[str, np.ndarray]:
        """Blocks ``b0 <= b < b1``: ``stage`` (B,) int64, ``f_n``/``g_n`` (B,) events per
        block, ``f_ray_start``/``f_ray_len`` runs of consecutive far-only rays, ``f_val``
        float32, ``f_id.rv``/``f_id.rl`` run-length coded face ids, ``g_ray`` int32,
        ``g_count`` int16, ``g_near``/``g_far`` float32, ``g_nid``/``g_fid`` int32."""
        fp, gp, sp = self._f_ptr.a, self._g_ptr.a, self._gs_ptr.a
        f0, f1, g0, g1, s0, s1 = fp[b0], fp[b1], gp[b0], gp[b1], sp[b0], sp[b1]
        out = {"stage": self._stage.a[b0:b1].copy(),
               "f_n": np.diff(fp[b0:b1 + 1]).astype(np.int64),
               "g_n": np.diff(gp[b0:b1 + 1]).astype(np.int64)}
        r0, r1 = int(self._r_ptr.a[b0]), int(self._r_ptr.a[b1])
        out["f_ray_start"], out["f_ray_len"] = self._f_rs.a[r0:r1].copy(), self._f_rl.a[r0:r1].copy()
        out["f_val"] = self._f_val.a[f0:f1].copy()
        out["f_id.rv"], out["f_id.rl"] = _runs_of_equal(self._event_ids(b0, b1))
        out["g_ray"] = self._g_ray.a[g0:g1].copy()
        out["g_count"] = self._g_count.a[g0:g1].copy()
        for name, col in (("g_near", self._g_near), ("g_far", self._g_far),
                          ("g_nid", self._g_nid), ("g_fid", self._g_fid)):
            out[name] = col.a[s0:s1].copy()
        return out

    def _event_ids(self, b0: int, b1: int) -> np.ndarray:
        """Face id of every far event of blocks ``b0 <= b < b1`` (int32)."""
        fp = self._f_ptr.a
        f0, f1 = int(fp[b0]), int(fp[b1])
        bid = self._b_id.a[b0:b1]
        if np.all(bid < 0):
            return self._f_id.buf[f0:f1].copy()
        per_event = np.repeat(bid, np.diff(fp[b0:b1 + 1]))
        own = per_event < 0
        per_event[own] = self._f_id.buf[f0:f1][own]
        return per_event

    @classmethod
    def from_chunks(cls, chunks, where: str = "z-trace", **kw) -> "ZTrace":
        """Rebuild a trace from a header (the first chunk, or keys in it) and block chunks.

        A chunk whose arrays are cut short keeps its complete blocks; decoding stops there
        (``.truncated`` is then True). Keyframes are taken again while the log is replayed.
        """
        chunks = list(chunks)
        if not chunks:
            raise InputError("no trace arrays", where)
        head = chunks[0]
        frame = frame_from_array(_get(head, "frame", np.float64, where), where)
        tol_len = _get(head, "tol_length", np.float64, where, required=False)
        tol = Tolerance(length=float(tol_len[0])) if tol_len.size else DEFAULT
        n = frame.n_rays
        counts = _unpack_column(head, "init_count", np.int64, n, where)
        if counts.min(initial=0) < 0:
            raise InputError("negative segment count in init_count", where)
        total = int(counts.sum())
        segs = [_unpack_column(head, k, dt, total, where) for k, dt in
                (("init_near", np.float32), ("init_far", np.float32),
                 ("init_nid", np.int32), ("init_fid", np.int32))]
        grid = DexelGrid(frame, tol)
        grid._write_rays(np.arange(n), counts, *segs)
        first = _get(head, "first_stage", np.int64, where, required=False)
        return cls(grid, int(first[0]) if first.size else 0, **kw)._append_chunks(chunks, where)

    def _append_chunk(self, ch: dict, where: str) -> bool:
        """Decode one chunk's complete blocks into the log; False if some were cut off."""
        stage = _get(ch, "stage", np.int64, where)
        f_n = _get(ch, "f_n", np.int64, where)
        g_n = _get(ch, "g_n", np.int64, where)
        f_ray = _get_runs(ch, "f_ray_start", "f_ray_len", where)
        f_val = _get(ch, "f_val", np.float32, where)
        f_id = _get_rle(ch, "f_id", where)
        g_ray = _get(ch, "g_ray", np.int64, where)
        g_count = _get(ch, "g_count", np.int16, where)
        gsegs = [_get(ch, k, dt, where) for k, dt in (("g_near", np.float32), ("g_far", np.float32),
                                                      ("g_nid", np.int32), ("g_fid", np.int32))]
        # the blocks complete in every column
        nb = min(stage.size, f_n.size, g_n.size)
        if np.any(f_n[:nb] < 0) or np.any(g_n[:nb] < 0) or np.any(g_count < 0):
            raise InputError("negative event count", where)
        f_end = np.cumsum(f_n[:nb])
        g_end = np.cumsum(g_n[:nb])
        f_have = min(f_ray.size, f_val.size, f_id.size)
        g_have = min(g_ray.size, g_count.size)
        seg_cum = np.concatenate([[0], np.cumsum(g_count[:g_have].astype(np.int64))])
        s_have = min(x.size for x in gsegs)
        ok = (f_end <= f_have) & (g_end <= g_have)
        ok &= seg_cum[np.minimum(g_end, g_have)] <= s_have
        good = nb if ok.all() else int(np.argmin(ok))
        if good:
            if stage[0] < self.last_stage or np.any(np.diff(stage[:good]) < 0):
                raise InputError("trace stages decrease", where)
            fe, ge = int(f_end[good - 1]), int(g_end[good - 1])
            if f_ray[:fe].max(initial=0) >= self.n_rays or g_ray[:ge].max(initial=0) >= self.n_rays \
                    or f_ray[:fe].min(initial=0) < 0 or g_ray[:ge].min(initial=0) < 0:
                raise InputError("ray index beyond the frame", where)
            se = int(seg_cum[ge])
            self._append_blocks(stage[:good], f_n[:good], g_n[:good], f_ray[:fe], f_val[:fe], f_id[:fe],
                                g_ray[:ge], g_count[:ge], [x[:se] for x in gsegs])
        used_f = int(f_end[good - 1]) if good else 0
        used_g = int(g_end[good - 1]) if good else 0
        return good == nb and used_f == f_have and used_g == g_have
