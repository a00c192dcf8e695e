"""A batch cut writing straight into a z-trace (see :meth:`ZTrace.sink`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim import sweep_kernels as K
from sim.errors import InputError
from sim.grid import DexelGrid
from sim.trace.columns import _batch_stages
from sim.trace.keyframes import _Chunked, _Keyframe, _snapshot_sharing, copy_rays

if TYPE_CHECKING:
    from sim.trace.ztrace import ZTrace


#: stands in for the per-ray marks of a batch whose moves change each ray once at most
_NO_MARK = np.zeros(1, np.int64)


class _Sink:
    """A batch cut writing straight into a :class:`ZTrace` (see :meth:`ZTrace.sink`).

    The kernels (``sim.sweep_kernels``, trace sink) append far events and general
    rewrites to the trace's own columns as rays change and close one block per move; this
    object grows the columns when they fill, takes keyframes from the model being cut
    when they fall due (a copy of the arrays that changed: no replay), and at the end
    appends the block rows and brings the trace's mirror up to date.
    """

    #: rays a chunk of the keyframes' arrays holds (what a keyframe copies or shares)
    RAY_CHUNK = _Chunked.CHUNK

    def __init__(self, z: ZTrace, grid: DexelGrid, n_moves: int, stages, move_ids=None):
        if not grid.frame.same_rays(z.frame):
            raise InputError("the traced grid is not on the trace's dexel frame")
        self.z, self.grid, self.n = z, grid, int(n_moves)
        self.stages = _batch_stages(z.last_stage, stages, self.n)
        self.ids = (np.arange(1, self.n + 1, dtype=np.int32) if move_ids is None
                    else np.asarray(move_ids, np.int32).reshape(-1))
        if self.ids.size != self.n:
            raise InputError(f"{self.ids.size} move ids given for {self.n} moves")
        self.b0 = z.n_blocks
        # block ends per move: far events, general events, their segments, far-ray runs
        self.blk = [np.full(max(self.n, 1), -1, np.int64) for _ in range(4)]
        self.gen = np.empty(4096, np.int64)
        ts = self.ts = np.zeros(K.TRACE_STATE_SIZE, np.int64)
        ts[K.TS_NF], ts[K.TS_NG], ts[K.TS_NS] = z._f_val.n, z._g_ray.n, z._g_near.n
        ts[K.TS_NR] = z._f_rs.n
        self.start = np.array([ts[K.TS_NF], ts[K.TS_NG], ts[K.TS_NS], ts[K.TS_NR]])
        ts[K.TS_OPEN] = -1
        ts[K.TS_BLK0] = self.b0
        # keyframes are taken inline unless keyframe work from earlier records is pending
        self.inline = z.auto_maintain and not z._due and z._builder is None
        ts[K.TS_NEXT_DUE] = z._next_due if self.inline else np.iinfo(np.int64).max
        # events at the latest keyframe: what changed since decides what a new one copies
        self.g_at_key = int(z._g_ptr.a[z._keyframes[-1].block])
        self.r_at_key = int(z._r_ptr.a[z._keyframes[-1].block])
        self._key_before_merge = False   # see chunk_end / merged
        self._dirty = None   # chunks of rays changed since the latest keyframe (see chunk_end)
        # in the kernels' order (T); _f_id grows with _f_val (index for index), unwritten
        self.cols = (z._f_rs, z._f_val, z._f_rl, z._g_ray, z._g_count,
                     z._g_near, z._g_far, z._g_nid, z._g_fid)
        for c in self.cols[3:]:
            c.grow_to(c.n + 1024)

    def reserve(self, n_changes: int) -> None:
        """Room for about ``n_changes`` more far events (the cutter's bound from the rays
        the moves can reach), so the columns rarely grow while the kernels run."""
        self._sync_counts()
        for c in (*self.cols[:3], self.z._f_id):
            c.grow_to(c.n + int(n_changes) + 4096)

    def _sync_counts(self) -> None:
        """The columns' fill counts from the kernels' state (growing keeps what is filled)."""
        ts = self.ts
        for c, k in zip(self.cols, (K.TS_NR, K.TS_NF, K.TS_NR) + (K.TS_NG,) * 2 + (K.TS_NS,) * 4):
            c.n = int(ts[k])
        self.z._f_id.n = int(ts[K.TS_NF])

    def buffers(self) -> tuple:
        return (*(c.buf for c in self.cols), *self.blk[:3], *self.marks(), self.gen, self.blk[3])

    def marks(self) -> tuple[np.ndarray, np.ndarray]:
        """The per-ray (mark, slot) arrays, or placeholders until :meth:`need_marks`."""
        z = self.z
        return (z._mark, z._slot) if z._mark is not None else (_NO_MARK, _NO_MARK)

    def make_room(self, n_far: int, n_general: int, n_segments: int, n_runs: int) -> None:
        """Room for this many more far events, general events, their segments and runs
        (``sim.bands`` merges what its bands recorded into the columns)."""
        self._sync_counts()
        for c, extra in zip((*self.cols, self.z._f_id),
                            (n_runs, n_far, n_runs, n_general, n_general, *(n_segments,) * 4, n_far)):
            c.grow_to(c.n + int(extra) + 1)

    def chunk_end(self, mv: int, far_pending: int, general_pending: int, pending_dirty,
                  later: list) -> None:
        """Moves up to ``mv`` are cut (a chunk of ``sim.bands``, which runs with keyframes
        off); the columns hold them but for the last chunk's events, merged later
        (``far_pending`` far and ``general_pending`` general events;
        ``pending_dirty()`` says which chunks of ``RAY_CHUNK`` rays they touch). Take a
        keyframe of the model now if one fell due: its copies of the model's per-ray
        arrays go to the list ``later``, for the bands to make before they cut on (see
        ``sim.trace.keyframes.copy_rays``)."""
        if not self.inline:
            return
        self._sync_counts()
        ts = self.ts
        if self._dirty is None:   # the edits since the latest keyframe, of earlier batches
            self._dirty = self.z._dirty_chunks(self.r_at_key, int(ts[K.TS_NR]), self.g_at_key, int(ts[K.TS_NG]))
        # each chunk's runs are read once, as they come (not again at every keyframe)
        self._dirty |= pending_dirty()
        ng = int(ts[K.TS_NG]) + general_pending
        events = int(ts[K.TS_NF]) + far_pending + ng
        if events < ts[K.TS_NEXT_DUE]:
            return
        self._snapshot(mv, ng > self.g_at_key, self._dirty, events, later)
        self._dirty[:] = False
        self._key_before_merge = True

    @staticmethod
    def copy_rays(later: list, r0: int, r1: int) -> None:
        """The copies ``chunk_end`` left in ``later``, for rays ``r0 .. r1-1``."""
        copy_rays(later, r0, r1)

    def merged(self) -> None:
        """``sim.bands`` merged a chunk into the columns: if the keyframe before was taken
        at that chunk's end, what changes from now on is what the next keyframe copies."""
        if self._key_before_merge:
            self.g_at_key = int(self.ts[K.TS_NG])
            self.r_at_key = int(self.ts[K.TS_NR])
            self._key_before_merge = False

    def need_marks(self) -> None:
        """The moves to come may change a ray more than once (arc chords, instances of
        motion): the per-ray marks that merge such changes into one event per block."""
        z = self.z
        if z._mark is None:
            z._mark = np.full(z.n_rays, -1, np.int64)
            z._slot = np.zeros(z.n_rays, np.int64)

    def grow(self) -> None:
        ts = self.ts
        self._sync_counts()
        need_f = max(int(ts[K.TS_NF]) + 1, int(ts[K.TS_NEED_F]))
        need_r = int(ts[K.TS_NR]) + max(need_f - int(ts[K.TS_NF]), 1)   # a run per event at most
        for c, need in ((self.cols[1], need_f), (self.z._f_id, need_f), (self.cols[0], need_r),
                        (self.cols[2], need_r)):
            if need > c.buf.size:
                c.grow_to(max(2 * c.buf.size, need))
        need_gen = max(int(ts[K.TS_NGL]) + 1, int(ts[K.TS_NEED_GEN]))
        if need_gen > self.gen.size:
            gen = np.empty(max(2 * self.gen.size, need_gen), np.int64)
            gen[:self.gen.size] = self.gen
            self.gen = gen
        if ts[K.TS_NEED_G] > self.cols[3].buf.size:
            for c in self.cols[3:5]:
                c.grow_to(int(ts[K.TS_NEED_G]) * 2)
        if ts[K.TS_NEED_S] > self.cols[5].buf.size:
            for c in self.cols[5:]:
                c.grow_to(int(ts[K.TS_NEED_S]) * 2)

    def keyframe(self) -> None:
        """A keyframe fell due after move ``ts[TS_KEY_MOVE]``: snapshot the model now."""
        self._keyframe_now(int(self.ts[K.TS_KEY_MOVE]))

    def _keyframe_now(self, mv: int) -> None:
        """A keyframe after move ``mv``, every event so far in the columns."""
        ts = self.ts
        ng, nr = int(ts[K.TS_NG]), int(ts[K.TS_NR])
        dirty = self.z._dirty_chunks(self.r_at_key, nr, self.g_at_key, ng)
        self._snapshot(mv, ng > self.g_at_key, dirty, int(ts[K.TS_NF]) + ng)
        self.g_at_key = ng
        self.r_at_key = nr

    def _snapshot(self, mv: int, general: bool, dirty, events: int, later: list | None = None) -> None:
        """Keyframe after move ``mv``: the ``dirty`` chunks of rays of the model's arrays
        (every per-ray array when ``general``, else those of the FarZ values), the rest
        shared with the keyframe before (see ``_snapshot_sharing``); ``events``:
        far and general events up to ``mv``, from which the next one falls due;
        ``later``: see :meth:`chunk_end`."""
        z = self.z
        data = _snapshot_sharing(self.grid.store, z._keyframes[-1].data, general, dirty, later)
        z._add_keyframe(_Keyframe(self.b0 + mv + 1, int(self.stages[mv]), data))
        z._next_due = events + z.keyframe_every
        self.ts[K.TS_NEXT_DUE] = z._next_due

    def end(self) -> None:
        """Append the block rows (a keyframe at the end if one fell due); the mirror is left
        stale, rebuilt from the keyframes if a later record needs it."""
        z, ts = self.z, self.ts
        ends = []
        for blk, start in zip(self.blk, self.start):
            e = np.where(blk[:self.n] < 0, start, blk[:self.n])
            ends.append(np.maximum.accumulate(e) if e.size else e)
        self._sync_counts()
        if self.n and self.inline and int(ts[K.TS_NF] + ts[K.TS_NG]) >= z._next_due:
            self._keyframe_now(self.n - 1)
        # the mirror is stale: rebuilt from the keyframes if a later record needs it
        z._mirror = None
        z._rec = z._recf = None
        # every far event of a move carries the move's id: kept once per block
        z._close_blocks(self.stages, *ends, budget=0, block_ids=self.ids)
