"""Blasquez & Poiraudeau's traces of a dexel model: rebuild or picture any stage of a run.

* :class:`ZTrace` (the *complete* trace, rules 1-5): every change of every ray, stamped
  with the stage that made it. The whole model (a :class:`~sim.grid.DexelGrid`) is rebuilt
  at any stage ``n`` ray for ray, so a simulation can carry on from there with another
  program. :meth:`ZTrace.z_elements` lists a ray's Z elements with their creation and
  deletion stages exactly as in the paper.
* :class:`TimeTrace` (the *fast* trace, rule 6): the history of the visible surface (the
  last FarZ and the id of the move that made it) of each ray; the heights picture at any
  stage, and animation forwards and backwards in time proportional to the changes shown.
  Beside a z-trace it is a :class:`SharedTimeTrace`: the z-trace's far-only events *are*
  time elements and its general rewrites carry their new top, so the two traces are one
  log read two ways (half the memory, half the recording work). A stand-alone
  :class:`TimeTrace` (own log, with rewind links) remains for heights without a model.
* Beyond the paper: periodic keyframes, so a rebuild costs the changes since the nearest
  keyframe rather than the length of the run. They are built a slice at a time by later
  record calls (or :meth:`Trace.maintain`), or copied from the model while a batch cuts
  into the trace, and share the arrays far-only edits cannot touch: a 3-axis keyframe
  costs the FarZ values and ids, and only of the chunks of rays touched since the one
  before when the batch path takes it.
  ``grid_at(stage, out=grid)`` / ``state_at(stage, out=(heights, ids))`` reuse a
  caller's model and apply only the changes between its stage and the next one asked
  for (or restore the nearest keyframe when that is cheaper): a viewer scrubbing a run
  pays a few milliseconds per stage.

Recording, three ways, each giving the same log:

* ``Cutter.cut_moves(moves, trace=tr)``: the cut kernels write the events as the rays
  change (one block per move, as if each move were cut and recorded alone) and the
  keyframes are copies of the model being cut as they fall due. The cheapest way: the
  batch pays for storing its events, not for finding them again.
* :meth:`Trace.record` diffs the given rays of a model against the trace's own copy (the
  *mirror*, made on first use) in one compiled pass: the live monitor's pattern, where
  the model is cut a poll at a time by other code.
* :meth:`Trace.record_batch` does the same from a batch cut's journal
  (``Cutter.cut_moves(..., journal=True)``).

Stages are integers chosen by the caller (a move number, a sync step ...) that never
decrease from one :meth:`record` to the next; stage ``n`` means "after every record with
stage <= n". The trace at construction holds the model at ``stage`` (normally 0).

Storage. A trace is a log of *blocks*, one per :meth:`record` or per move of a batch.
Within a block, rays whose only change is the last FarZ (the usual 3-axis cut, rule 5)
store just the new value: their rays as runs of consecutive rays, their face id once for
the block when it is one (a batch's move) or per event; any other change (rules 2-4:
segments created, deleted or shortened from the near side) stores the ray's new segment
list, applied after the block's far edits. Serialised (:meth:`to_arrays`,
:meth:`chunk_since`) ray indices and face ids are run-length coded; everything is plain
numpy arrays (no pickle) so a run file stores them as raw bytes + dtype + shape, and a
sequence of chunks cut short anywhere rebuilds up to its last complete stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import dexel_store as ds
from sim.bands import ray_chunks_touched
from sim import sweep_kernels as K
from sim import trace_kernels as tk
from sim.checks.arrays import distinct
from sim.errors import InputError
from sim.frame import Frame
from sim.grid import DexelGrid
from sim.tolerance import DEFAULT, Tolerance

__all__ = ["ZTrace", "TimeTrace", "SharedTimeTrace", "Trace", "same_model", "model_difference",
           "changed_rays_of", "frame_to_array", "frame_from_array"]


# --- small helpers ----------------------------------------------------------------------

class _Column:
    """A growable 1-D array (capacity doubling), so appends are amortised O(1)."""

    __slots__ = ("buf", "n")

    def __init__(self, dtype, capacity: int = 1024):
        self.buf = np.empty(capacity, dtype)
        self.n = 0

    def grow_to(self, m: int) -> np.ndarray:
        """Capacity at least ``m``, keeping the filled part (the new room is ``np.empty``:
        untouched pages cost no memory until written, so a generous reserve is cheap).
        Returns the buffer."""
        if m > self.buf.size:
            new = np.empty(max(m, 2 * self.buf.size, 1024), self.buf.dtype)
            new[:self.n] = self.buf[:self.n]
            self.buf = new
        return self.buf

    def reserve(self, m: int) -> np.ndarray:
        """Make room for ``m`` more values; returns the buffer (fill ``buf[n:n+m]``, then
        advance ``n``)."""
        return self.grow_to(self.n + m)

    def append(self, values: np.ndarray) -> None:
        m = values.size
        self.reserve(m)[self.n:self.n + m] = values
        self.n += m

    def push(self, value) -> None:
        self.reserve(1)[self.n] = value
        self.n += 1

    @property
    def a(self) -> np.ndarray:
        """The filled part (a view; valid until the next append)."""
        return self.buf[:self.n]

    @property
    def nbytes(self) -> int:
        return self.n * self.buf.itemsize


def frame_to_array(frame: Frame) -> np.ndarray:
    """A frame as 12 float64: origin(3), direction(3), u(3), spacing, nu, nv."""
    return np.concatenate([frame.origin, frame.direction, frame.u,
                           [frame.spacing, frame.nu, frame.nv]]).astype(np.float64)


def frame_from_array(a: np.ndarray, where: str = "trace") -> Frame:
    a = np.asarray(a, np.float64).reshape(-1)
    if a.size != 12 or not np.all(np.isfinite(a)):
        raise InputError(f"frame must be 12 finite numbers, got {a.size}", where)
    return Frame(a[0:3], a[3:6], a[6:9], float(a[9]), int(a[10]), int(a[11]))


def _runs_of_consecutive(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Code ``x`` (int) as runs ``x = start, start+1, ...``: (starts, lengths) int32."""
    x = np.asarray(x, np.int64)
    if x.size == 0:
        return np.zeros(0, np.int32), np.zeros(0, np.int32)
    brk = np.nonzero(np.diff(x) != 1)[0] + 1
    first = np.concatenate([[0], brk])
    lens = np.diff(np.concatenate([first, [x.size]]))
    return x[first].astype(np.int32), lens.astype(np.int32)


def _expand_consecutive(starts: np.ndarray, lens: np.ndarray) -> np.ndarray:
    lens = np.asarray(lens, np.int64)
    total = int(lens.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offs = np.cumsum(lens) - lens
    return np.repeat(np.asarray(starts, np.int64) - offs, lens) + np.arange(total)


def _runs_of_equal(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run-length code ``x``: (values, lengths int32)."""
    x = np.asarray(x)
    if x.size == 0:
        return x[:0].copy(), np.zeros(0, np.int32)
    brk = np.nonzero(x[1:] != x[:-1])[0] + 1
    first = np.concatenate([[0], brk])
    lens = np.diff(np.concatenate([first, [x.size]]))
    return x[first].copy(), lens.astype(np.int32)


def _expand_equal(values: np.ndarray, lens: np.ndarray) -> np.ndarray:
    return np.repeat(values, np.asarray(lens, np.int64))


def _pack_column(out: dict, name: str, x: np.ndarray) -> None:
    """Store ``x`` raw, or run-length coded (``name.rv``/``name.rl``) when that is smaller."""
    vals, lens = _runs_of_equal(x)
    if vals.nbytes + lens.nbytes < x.nbytes:
        out[name + ".rv"] = vals
        out[name + ".rl"] = lens
    else:
        out[name] = np.ascontiguousarray(x)


def _unpack_column(arrays: dict, name: str, dtype, size: int, where: str) -> np.ndarray:
    if name in arrays:
        x = np.asarray(arrays[name])
    elif name + ".rv" in arrays and name + ".rl" in arrays:
        x = _expand_equal(np.asarray(arrays[name + ".rv"]), np.asarray(arrays[name + ".rl"]))
    else:
        raise InputError(f"missing array {name!r}", where)
    if x.size != size:
        raise InputError(f"array {name!r} has {x.size} values, expected {size}", where)
    return x.astype(dtype, copy=False)


def _get_runs(arrays: dict, start: str, length: str, where: str) -> np.ndarray:
    """Rays run-length coded as (``start``, ``length``) arrays, expanded (int64); a chunk cut
    short keeps the runs both arrays hold."""
    starts = _get(arrays, start, np.int64, where)
    lens = _get(arrays, length, np.int64, where)
    m = min(starts.size, lens.size)
    if np.any(lens[:m] < 0):
        raise InputError(f"negative run length in {length}", where)
    return _expand_consecutive(starts[:m], lens[:m])


def _get_rle(arrays: dict, name: str, where: str) -> np.ndarray:
    """Ids run-length coded as ``name.rv`` (values) / ``name.rl`` (lengths), expanded (int32)."""
    idv = _get(arrays, name + ".rv", np.int32, where)
    idl = _get(arrays, name + ".rl", np.int64, where)
    m = min(idv.size, idl.size)
    if np.any(idl[:m] < 0):
        raise InputError(f"negative run length in {name}.rl", where)
    return _expand_equal(idv[:m], idl[:m]).astype(np.int32)


def _get(arrays: dict, name: str, dtype, where: str, required: bool = True) -> np.ndarray:
    if name not in arrays:
        if not required:
            return np.zeros(0, dtype)
        raise InputError(f"missing array {name!r}", where)
    x = np.asarray(arrays[name]).reshape(-1)
    if x.dtype.kind != np.dtype(dtype).kind and x.size:
        raise InputError(f"array {name!r} has dtype {x.dtype}, expected {np.dtype(dtype)}", where)
    return x.astype(dtype, copy=False)


def changed_rays_of(cut_result, first: int = 0, last: int | None = None) -> np.ndarray:
    """Flat ray indices changed by moves ``first .. last-1`` of a ``sim.cut.CutResult``.

    Reads ``changed_ptr`` (n+1,) and ``changed_rays``; returns sorted unique int64.
    """
    ptr = np.asarray(cut_result.changed_ptr)
    last = len(ptr) - 1 if last is None else last
    rays = np.asarray(cut_result.changed_rays)[int(ptr[first]):int(ptr[last])]
    return np.unique(rays.astype(np.int64))


def model_difference(a: DexelGrid, b: DexelGrid, ids: bool = True) -> np.ndarray:
    """Flat indices of the rays where two models on the same frame differ.

    Compares segment counts, values (exactly, float32) and, when ``ids``, face ids.
    """
    if not a.frame.same_rays(b.frame):
        raise InputError("models are on different dexel frames")
    rays = np.arange(a.frame.n_rays)
    na, fa, nia, fia, ca = a.segments_of(rays)
    nb_, fb, nib, fib, cb = b.segments_of(rays)
    bad = ca != cb
    if not bad.any():
        seg_bad = (na != nb_) | (fa != fb)
        if ids:
            seg_bad |= (nia != nib) | (fia != fib)
        owner = np.repeat(rays, ca)
        bad[owner[seg_bad]] = True
    return np.nonzero(bad)[0]


def same_model(a: DexelGrid, b: DexelGrid, ids: bool = True) -> bool:
    """True when two models hold the same segments (and face ids) on every ray."""
    return model_difference(a, b, ids).size == 0


def _check_stage(last: int, stage: int) -> int:
    stage = int(stage)
    if stage < last:
        raise InputError(f"trace stages must not decrease: got stage {stage} after {last}")
    return stage


def _batch_stages(last_stage: int, stages, n_moves: int) -> np.ndarray:
    """Stages of a batch's moves: given (checked non-decreasing from ``last_stage``) or
    ``last_stage + 1, + 2, ...``; int64 (n_moves,)."""
    if stages is None:
        return last_stage + 1 + np.arange(n_moves, dtype=np.int64)
    st = np.asarray(stages, np.int64).reshape(-1)
    if st.size != n_moves:
        raise InputError(f"{st.size} stages given for {n_moves} moves")
    if n_moves and (st[0] < last_stage or np.any(np.diff(st) < 0)):
        raise InputError(f"trace stages must not decrease: got stage {int(st.min())} after {last_stage}")
    return st


def _rays_arg(rays, n_rays: int) -> np.ndarray:
    """``rays`` as sorted distinct int64 (all rays for None)."""
    if rays is None:
        return np.arange(n_rays, dtype=np.int64)
    rays = np.ascontiguousarray(np.asarray(rays, np.int64).reshape(-1))
    if rays.size > 1 and not np.all(rays[1:] > rays[:-1]):  # a live loop's lists are sorted already
        rays = distinct(rays)
    if rays.size and (rays[0] < 0 or rays[-1] >= n_rays):
        raise InputError(f"ray index out of range 0..{n_rays - 1}")
    return rays


def _store_snapshot(store: dict) -> dict:
    """A copy of a store with the pool trimmed to what is in use."""
    top = int(store["pool_top"][0])
    out = {}
    for k, v in store.items():
        if k.startswith("pool_") and k != "pool_top":
            out[k] = v[:max(top, 16)].copy()
        else:
            out[k] = v.copy()
    return out


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


# --- the z-trace --------------------------------------------------------------------------

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

    def updated(self, src: np.ndarray, dirty: np.ndarray) -> "_Chunked":
        """These chunks with the ``dirty`` ones (bool per chunk) copied anew from ``src``."""
        ch = self.CHUNK
        chunks = [src[i * ch:(i + 1) * ch].copy() if d else c
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
    return a.copy() if isinstance(a, _Chunked) else a


def _snapshot_sharing(store: dict, prev: dict | None, general: bool, dirty=None) -> dict:
    """A snapshot of ``store``; when only far-only edits happened since keyframe ``prev``
    (``general`` False), the fields they cannot touch are ``prev``'s arrays, shared, and
    with ``dirty`` (bool per :class:`_Chunked` chunk of rays: where those edits fell) the
    FarZ values and ids share their untouched chunks too."""
    if prev is None or general:
        return _store_snapshot(store)
    out = dict(prev)
    top = int(store["pool_top"][0])
    for k in _FAR_FIELDS:
        v = store[k]
        if k.startswith("pool_"):
            out[k] = v[:max(top, 16)].copy()
        elif dirty is not None:
            out[k] = _Chunked.of(prev[k]).updated(v, dirty)
        else:
            out[k] = v.copy()
    return out


class _KeyBuilder:
    """A keyframe built in small steps off the recording path.

    Starts from the latest keyframe (sharing every array no event in between can touch),
    copies the rest in slices, then replays the blocks up to ``block`` in slices, so no
    single call costs more than about ``budget`` array elements / events.
    """

    def __init__(self, trace: "ZTrace", block: int):
        self.trace = trace
        self.block = int(block)
        base = trace._keyframes[-1]
        self.base = base
        self.cur = base.block
        tr = trace
        self.general = bool(tr._g_ptr.a[self.block] > tr._g_ptr.a[base.block])
        self.work = dict(base.data)
        fields = ds.STORE_FIELDS if self.general else _FAR_FIELDS
        # (field, destination, source) copies still to do, sliced as the budget allows
        self.copies = []
        top = int(base.data["pool_top"][0])
        spare = 2 * int(tr._gs_ptr.a[self.block] - tr._gs_ptr.a[base.block]) + 64 if self.general else 0
        for k in fields:
            src = _plain(base.data[k])
            size = max(top + spare, src.size) if k in _POOL_FIELDS else src.size
            dst = np.zeros(size, src.dtype) if size != src.size else np.empty_like(src)
            self.work[k] = dst
            self.copies.append([dst, src, 0])

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
        data = self.work
        if self.general:  # trim the pool's spare room
            data = _store_snapshot(data)
        return _Keyframe(self.block, int(self.trace._stage.a[self.block - 1]), data)


class _Cursor:
    """What a caller's grid holds: the trace's state after ``block`` blocks, and which of
    its arrays still equal which keyframe arrays (so a restore can skip them)."""

    __slots__ = ("owner", "block", "clean")

    def __init__(self, owner, block, clean):
        self.owner = owner
        self.block = block
        self.clean = clean


class _BlockLog:
    """What both traces share: a log of blocks, each with its stage (``_stage``, a
    :class:`_Column`), read back as blocks and serialised through ``_blocks_arrays``."""

    first_stage: int
    _stage: _Column

    @property
    def n_blocks(self) -> int:
        return self._stage.n

    @property
    def stages(self) -> np.ndarray:
        """Stage of every recorded block, int64 (n_blocks,), non-decreasing."""
        return self._stage.a.copy()

    @property
    def last_stage(self) -> int:
        return int(self._stage.a[-1]) if self._stage.n else self.first_stage

    def _blocks_upto(self, stage: int) -> int:
        return int(np.searchsorted(self._stage.a, int(stage), side="right"))

    def chunk_since(self, stage: int | None = None) -> dict[str, np.ndarray]:
        """The blocks with stage > ``stage`` (all when None) as plain arrays (the keys are
        each trace's ``_blocks_arrays``)."""
        b0 = 0 if stage is None else self._blocks_upto(stage)
        return self._blocks_arrays(b0, self.n_blocks)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Header and every block in one dict of arrays (see :meth:`from_arrays`)."""
        return {**self.header_arrays(), **self.chunk_since(None)}

    @classmethod
    def from_arrays(cls, arrays: dict, **kw):
        return cls.from_chunks([arrays], **kw)

    def _append_chunks(self, chunks: list, where: str):
        """Decode the chunks' blocks in order (``_append_chunk`` each); the first one cut
        short ends the log there and marks it truncated. Returns self."""
        for k, ch in enumerate(chunks):
            if "stage" not in ch:
                continue
            if not self._append_chunk(ch, f"{where} chunk {k}"):
                self.truncated = True
                break
        return self


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
        self._init = _store_snapshot(grid.store)
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
                            np.array([stage], np.int64), 0)

    def record_journal(self, changed_ptr, changed_rays, seg_ptr, near, far, near_id, far_id,
                       stages=None) -> int:
        """Record a batch cut's journal: one block per move, equal to recording each move
        by itself.

        changed_ptr : int64 (n_moves + 1,), changed_rays : int (n_entries,)
            The CSR of rays each move changed (``CutResult.changed_ptr`` / ``changed_rays``).
        seg_ptr : int64 (n_entries + 1,); near, far : float32 (n_segs,) mm; near_id,
            far_id : int32 (n_segs,)
            Entry e's complete segment list after its move (``CutResult.journal_*``).
        stages : int (n_moves,), optional
            Stage of each move, non-decreasing and not below :attr:`last_stage`; default
            ``last_stage + 1, + 2, ...``.

        Returns the number of ray changes recorded. One compiled pass over the entries.
        """
        ptr = np.ascontiguousarray(changed_ptr, np.int64)
        n_moves = ptr.size - 1
        stages = _batch_stages(self.last_stage, stages, n_moves)
        rays = np.ascontiguousarray(changed_rays, np.int64)
        seg_ptr = np.ascontiguousarray(seg_ptr, np.int64)
        cols = [np.ascontiguousarray(x, dt) for x, dt in
                ((near, np.float32), (far, np.float32), (near_id, np.int32), (far_id, np.int32))]
        n_entries = rays.size
        if ptr[0] != 0 or ptr[-1] != n_entries or np.any(np.diff(ptr) < 0) \
                or seg_ptr.size != n_entries + 1 or (n_entries and (seg_ptr[0] != 0 or np.any(np.diff(seg_ptr) < 0))):
            raise InputError("cut journal pointers are inconsistent with its entries")
        n_segs = int(seg_ptr[-1])
        if any(c.size < n_segs for c in cols):
            raise InputError(f"cut journal holds fewer than its {n_segs} segments")
        if n_entries and (rays.min() < 0 or rays.max() >= self.n_rays):
            raise InputError("cut journal ray index beyond the frame")
        return self._ingest(ptr, rays, seg_ptr, cols, stages, budget=None)

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

    def _ingest(self, ptr, rays, seg_ptr, segs, stages, budget) -> int:
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
        # a batch (budget None) with no keyframe work pending snapshots the mirror where each
        # keyframe falls due: a copy, instead of replaying the events again later
        inline = budget is None and self.auto_maintain and not self._due and self._builder is None
        b0 = self.n_blocks
        while True:
            out = self._event_columns(scratch, n_entries, n_segs)
            stop_at = self._next_due if inline else np.iinfo(np.int64).max
            status = tk.ingest_journal_fast(self._rec, self._recf, self._mirror.S, ptr, rays, seg_ptr,
                                            *segs, jnb, jfb, state, cnt, *blk, *out, stop_at, f0)
            if status == tk.DONE:
                break
            if status == tk.KEYFRAME:
                self._snapshot_inline(b0, int(state[0]), stages, blk[1])
                continue
            ds.grow_pool(self._mirror.store, 2 * n_segs + 64)
        self._set_counts()
        r_end = self._append_runs(scratch[:int(cnt[0]) - f0], np.diff(blk[0], prepend=f0))
        new = self.n_changes - before
        self._close_blocks(stages, *blk, r_end, budget=4 * new if budget is None else budget)
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

    def _snapshot_inline(self, b0: int, k: int, stages, g_end) -> None:
        """A keyframe of the mirror after the batch's first ``k`` moves (block ``b0 + k``,
        not yet appended; ``g_end`` holds the batch's general-event ends per move)."""
        prev = self._keyframes[-1]
        g_prev = int(self._g_ptr.a[prev.block]) if prev.block <= b0 else int(g_end[prev.block - b0 - 1])
        general = int(self._cnt[1]) > g_prev
        tk.sync_mirror(self._rec, self._recf, self._mirror.S)
        self._add_keyframe(_Keyframe(b0 + k, int(stages[k - 1]),
                                     _snapshot_sharing(self._mirror.store, prev.data, general)))
        self._next_due = int(self._cnt[0] + self._cnt[1]) + self.keyframe_every

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
            self.maintain(max(budget, KEYFRAME_BUDGET))

    def maintain(self, budget: int | None = None) -> bool:
        """Advance the keyframes that fell due by up to ``budget`` units of work (array
        elements copied or events replayed; None = finish them). True when none is left.
        """
        left = np.inf if budget is None else int(budget)
        while left > 0:
            if self._builder is None:
                while self._due and self._due[0] <= self._keyframes[-1].block:
                    self._due.pop(0)
                if not self._due:
                    return True
                self._builder = _KeyBuilder(self, self._due.pop(0))
            used = self._builder.step(int(min(left, 1 << 62)))
            left -= max(used, 1)
            if self._builder.done:
                self._add_keyframe(self._builder.finish())
                self._builder = None
        return self._builder is None and not self._due

    def _add_keyframe(self, key: _Keyframe) -> None:
        self._keyframes.append(key)
        if len(self._keyframes) > self.max_keyframes:
            # keep the stock and every other one: memory bounded, spacing doubles
            self._keyframes = [self._keyframes[0]] + self._keyframes[2::2]
            self.keyframe_every *= 2

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
                general = bool(self._g_ptr.a[b] > self._g_ptr.a[prev.block])
                self._add_keyframe(_Keyframe(b, int(self._stage.a[b - 1]),
                                             _snapshot_sharing(self._mirror.store, prev.data, general)))
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
        g = DexelGrid(self.frame, self.tol, self._init)
        n, f, ni, fi, _ = g.segments_of(np.array([r]))
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
        seen = {id(p) for v in self._keyframes[0].data.values() for p in parts(v)}
        # chunks that are views of the stock's arrays are the stock's bytes
        seen |= {id(p) for k in self._keyframes for v in k.data.values() for p in parts(v)
                 if isinstance(p, np.ndarray) and p.base is not None
                 and any(p.base is b for b in self._keyframes[0].data.values())}
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
        g = DexelGrid(self.frame, self.tol, self._init)
        n, f, ni, fi, c = g.segments_of(np.arange(self.n_rays))
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

    def chunk_end(self, mv: int, far_pending: int, general_pending: int, pending_dirty) -> None:
        """Moves up to ``mv`` are cut (a chunk of ``sim.bands``, which runs with keyframes
        off); the columns hold them but for the last chunk's events, merged later
        (``far_pending`` far and ``general_pending`` general events;
        ``pending_dirty(chunk, n_chunks)`` says which chunks of rays they touch). Take a
        keyframe of the model now if one fell due."""
        self._sync_counts()
        ts = self.ts
        ng = int(ts[K.TS_NG]) + general_pending
        events = int(ts[K.TS_NF]) + far_pending + ng
        if not (self.inline and events >= ts[K.TS_NEXT_DUE]):
            return
        general = ng > self.g_at_key
        dirty = None
        if not general:
            dirty = self._dirty_chunks(self.r_at_key, int(ts[K.TS_NR]))
            dirty |= pending_dirty(_Chunked.CHUNK, dirty.size)
        self._snapshot(mv, general, dirty, events)
        self._key_before_merge = True

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
        general = ng > self.g_at_key
        dirty = None if general else self._dirty_chunks(self.r_at_key, nr)
        self._snapshot(mv, general, dirty, int(ts[K.TS_NF]) + ng)
        self.g_at_key = ng
        self.r_at_key = nr

    def _snapshot(self, mv: int, general: bool, dirty, events: int) -> None:
        """Keyframe after move ``mv``: the model's arrays (all when ``general``, else the
        ``dirty`` chunks of rays, the rest shared with the keyframe before); ``events``:
        far and general events up to ``mv``, from which the next one falls due."""
        z = self.z
        z._add_keyframe(_Keyframe(self.b0 + mv + 1, int(self.stages[mv]),
                                  _snapshot_sharing(self.grid.store, z._keyframes[-1].data, general, dirty)))
        z._next_due = events + z.keyframe_every
        self.ts[K.TS_NEXT_DUE] = z._next_due

    def _dirty_chunks(self, r0: int, r1: int) -> np.ndarray:
        """Which :class:`_Chunked` chunks of rays the far-event runs ``r0:r1`` touch."""
        ch = _Chunked.CHUNK
        return ray_chunks_touched(self.z._f_rs.buf[r0:r1], self.z._f_rl.buf[r0:r1], ch, -(-self.z.n_rays // ch))

    def end(self) -> None:
        """Append the block rows, sync the mirror, trim the columns."""
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


# --- the time-trace -----------------------------------------------------------------------

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

    def record_journal(self, changed_ptr, changed_rays, seg_ptr, far, far_id, stages=None) -> int:
        """Record a batch cut's journal (see :meth:`ZTrace.record_journal`): one block per
        move, equal to recording each move by itself. Returns the elements recorded."""
        ptr = np.ascontiguousarray(changed_ptr, np.int64)
        n_moves = ptr.size - 1
        stages = _batch_stages(self.last_stage, stages, n_moves)
        rays = np.ascontiguousarray(changed_rays, np.int64)
        seg_ptr = np.ascontiguousarray(seg_ptr, np.int64)
        far = np.ascontiguousarray(far, np.float32)
        far_id = np.ascontiguousarray(far_id, np.int32)
        if seg_ptr.size != rays.size + 1 or ptr[-1] != rays.size or far.size < seg_ptr[-1] \
                or far_id.size < seg_ptr[-1]:
            raise InputError("cut journal pointers are inconsistent with its entries")
        if rays.size and (rays.min() < 0 or rays.max() >= self.n_rays):
            raise InputError("cut journal ray index beyond the frame")
        m = rays.size
        n0 = self._ray.n
        cols = (self._ray.reserve(m), self._val.reserve(m), self._id.reserve(m),
                self._prev.reserve(m), self._prev_id.reserve(m))
        blk = np.empty(n_moves, np.int64)
        o = [c[n0:] for c in cols]
        k = tk.top_changes_journal_packed(ptr, rays, seg_ptr, far.view(np.int32), far_id, self._cur,
                                          o[0], o[1].view(np.int32), o[2], o[3].view(np.int32), o[4], blk)
        for c in (self._ray, self._val, self._id, self._prev, self._prev_id):
            c.n = n0 + int(k)
        self._stage.append(stages)
        self._ptr.append(n0 + blk)
        self._schedule(int(k), budget=4 * int(k))
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
            self.maintain(max(budget, KEYFRAME_BUDGET))

    def maintain(self, budget: int | None = None) -> bool:
        """Advance due keyframes by up to ``budget`` elements (None = finish them)."""
        left = np.inf if budget is None else int(budget)
        while left > 0:
            if self._builder is None:
                while self._due and self._due[0] <= self._keyframes[-1].block:
                    self._due.pop(0)
                if not self._due:
                    return True
                base = self._keyframes[-1]
                self._builder = [self._due.pop(0), base.data[0].copy(), base.data[1].copy(), base.block]
            b1, top, tid, cur = self._builder
            p = self._ptr.a
            stop = int(np.searchsorted(p, p[cur] + left, side="left")) if np.isfinite(left) else b1
            stop = min(max(stop, cur + 1), b1)
            tk.scatter_values(top, tid, self._ray.a[p[cur]:p[stop]], self._val.a[p[cur]:p[stop]],
                              self._id.a[p[cur]:p[stop]])
            left -= max(int(p[stop] - p[cur]), 1)
            self._builder[3] = stop
            if stop >= b1:
                self._keyframes.append(_Keyframe(b1, int(self._stage.a[b1 - 1]), (top, tid)))
                self._builder = None
                if len(self._keyframes) > self.max_keyframes:
                    self._keyframes = [self._keyframes[0]] + self._keyframes[2::2]
                    self.keyframe_every *= 2
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
                self._keyframes.append(_Keyframe(self.n_blocks, self.last_stage,
                                                 (self._top.copy(), self._top_id.copy())))
                self._since_key = 0
                if len(self._keyframes) > self.max_keyframes:
                    self._keyframes = [self._keyframes[0]] + self._keyframes[2::2]
                    self.keyframe_every *= 2


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

    record_journal = record_heights = record

    def maintain(self, budget: int | None = None) -> bool:
        return True

    def nbytes(self) -> int:
        return 0

    def keyframe_nbytes(self) -> int:
        return 0

    def _key_tops(self, key: _Keyframe, top: np.ndarray, tid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The visible surface of keyframe ``key`` into ``top`` / ``tid`` (n_rays,)."""
        d = key.data
        far, fid = _Chunked.of(d["far"]), _Chunked.of(d["far_id"])
        ch = _Chunked.CHUNK
        for i, (f, fi) in enumerate(zip(far.chunks, fid.chunks)):   # chunk by chunk: no copy
            sl = slice(i * ch, i * ch + f.size)
            tk.tops_of_store(d["count"][sl], f, fi, d["xstart"][sl], d["pool_far"], d["pool_far_id"],
                             top[sl], tid[sl])
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


# --- both traces together -----------------------------------------------------------------

class Trace:
    """The z-trace and the time-trace of one run, fed together.

    ``record(grid, rays, stage)`` after each cut; ``take_chunk()`` returns the arrays
    recorded since the previous call (keys prefixed ``z/`` and ``t/``; the first call also
    carries both headers) for the run file; :meth:`from_chunks` reads them back.
    """

    def __init__(self, grid: DexelGrid, stage: int = 0, z: bool = True, time: bool = True,
                 keyframe_every: int | None = None, auto_maintain: bool = True,
                 shared_time: bool = True, keep_history: bool = True):
        self.frame = grid.frame
        self.z = ZTrace(grid, stage, keyframe_every) if z else None
        if time and self.z is not None and shared_time:
            # the time elements are the z-trace's events: one log, read two ways
            self.t = SharedTimeTrace(self.z)
        else:
            self.t = TimeTrace(grid, stage, keyframe_every=keyframe_every) if time else None
        # auto_maintain False: record calls never build keyframes; call maintain() when idle
        for tr in (self.z, self.t):
            if tr is not None:
                tr.auto_maintain = bool(auto_maintain)
        self._sent_z = 0
        self._sent_t = 0
        self._header_sent = False
        #: False: :meth:`take_chunk` drops what it hands on (a live loop writing a run
        #: file: bounded memory and work however long the run; see ZTrace.forget_blocks)
        self.keep_history = bool(keep_history)
        if not self.keep_history and (self.z is None or self._own_t):
            raise InputError("a trace that hands its blocks on needs a z-trace with a shared time-trace")

    @property
    def last_stage(self) -> int:
        return (self.z or self.t).last_stage

    @property
    def truncated(self) -> bool:
        return bool((self.z and self.z.truncated) or (self.t and self.t.truncated))

    @property
    def _own_t(self) -> bool:
        """Whether the time-trace keeps a log of its own (not shared with the z-trace)."""
        return self.t is not None and not isinstance(self.t, SharedTimeTrace)

    def record(self, grid: DexelGrid, rays=None, stage: int | None = None) -> None:
        if stage is None:
            stage = self.last_stage + 1
        if self.z is not None:
            self.z.record(grid, rays, stage)
        if self._own_t:
            self.t.record(grid, rays, stage)

    def ready_for_records(self) -> "Trace":
        """Make now the copy :meth:`record` diffs against (made on the first record
        otherwise): a live loop calls this before its first poll, so no poll pays for it."""
        if self.z is not None:
            self.z._ensure_mirror()
        return self

    def sink(self, grid: DexelGrid, n_moves: int, stages=None, move_ids=None):
        """Where ``Cutter.cut_moves(..., trace=self)`` writes (see :meth:`ZTrace.sink`)."""
        if self.z is None or self._own_t:
            raise InputError("cutting straight into a trace needs a z-trace with a shared time-trace")
        return self.z.sink(grid, n_moves, stages, move_ids)

    def record_cut(self, grid: DexelGrid, cut_result, stage: int | None = None) -> None:
        """Record a ``sim.cut.CutResult`` (all its moves) as one stage."""
        self.record(grid, changed_rays_of(cut_result), stage)

    def record_batch(self, cut_result, stages=None) -> None:
        """Record every move of a batch cut as its own stage, from the cut's journal.

        cut_result : ``sim.cut.CutResult`` of ``Cutter.cut_moves(..., journal=True)``
            (``changed_ptr``, ``changed_rays``, ``journal_seg_ptr``, ``journal_near``,
            ``journal_far``, ``journal_near_id``, ``journal_far_id``).
        stages : int (n_moves,), optional
            Stage of each move (non-decreasing); default ``last_stage + 1, + 2, ...``.

        Equal, stage for stage, to cutting and recording the moves one at a time; costs
        one compiled pass over the changed rays per trace (plus keyframe work spread over
        later calls).
        """
        need = ("changed_ptr", "changed_rays", "journal_seg_ptr", "journal_near", "journal_far",
                "journal_near_id", "journal_far_id")
        if any(getattr(cut_result, k, None) is None for k in need) \
                or not getattr(cut_result, "has_journal", True):
            raise InputError("the cut result carries no journal: cut with journal=True")
        n_moves = len(cut_result.changed_ptr) - 1
        stages = _batch_stages(self.last_stage, stages, n_moves)
        j = cut_result
        if self.z is not None:
            self.z.record_journal(j.changed_ptr, j.changed_rays, j.journal_seg_ptr, j.journal_near,
                                  j.journal_far, j.journal_near_id, j.journal_far_id, stages)
        if self._own_t:
            self.t.record_journal(j.changed_ptr, j.changed_rays, j.journal_seg_ptr, j.journal_far,
                                  j.journal_far_id, stages)

    def maintain(self, budget: int | None = None) -> bool:
        """Advance keyframes that fell due (None = finish them): for idle moments or the
        run-file writer, off the poll loop's critical path. True when none is left."""
        done = True
        if self.z is not None:
            done &= self.z.maintain(budget)
        if self._own_t:
            done &= self.t.maintain(budget)
        return done

    def grid_at(self, stage: int, out: DexelGrid | None = None) -> DexelGrid:
        """The model at ``stage``; ``out`` is a grid to reuse (see :meth:`ZTrace.grid_at`)."""
        if self.z is None:
            raise InputError("this run has no z-trace: the model cannot be rebuilt")
        return self.z.grid_at(stage, out)

    def heights_at(self, stage: int, out: tuple | None = None) -> np.ndarray:
        if self.t is not None:
            return self.t.heights_at(stage, out)
        return self.z.grid_at(stage).top()

    def state_at(self, stage: int, out: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Heights (nv, nu) and top face ids (nv, nu) at ``stage`` (``out``: arrays to reuse,
        see :meth:`TimeTrace.state_at`)."""
        if self.t is not None:
            return self.t.state_at(stage, out)
        g = self.z.grid_at(stage)
        top = np.empty(g.frame.n_rays, np.float32)
        tid = np.empty(g.frame.n_rays, np.int32)
        tk.gather_tops(g.S, np.arange(g.frame.n_rays), top, tid)
        return top.reshape(g.frame.shape), tid.reshape(g.frame.shape)

    def take_chunk(self) -> dict[str, np.ndarray]:
        """Arrays recorded since the last call (headers on the first); {} when nothing new.
        Without ``keep_history`` the trace then forgets them."""
        out: dict[str, np.ndarray] = {}
        if not self._header_sent:
            if self.z is not None:
                out.update({"z/" + k: v for k, v in self.z.header_arrays().items()})
            if self.t is not None:
                out.update({"t/" + k: v for k, v in self.t.header_arrays().items()})
            self._header_sent = True
        if self.z is not None and self.z.n_blocks > self._sent_z:
            out.update({"z/" + k: v for k, v in self.z._blocks_arrays(self._sent_z, self.z.n_blocks).items()})
            self._sent_z = self.z.n_blocks
        if self.t is not None and self.t.n_blocks > self._sent_t:
            out.update({"t/" + k: v for k, v in self.t._blocks_arrays(self._sent_t, self.t.n_blocks).items()})
            self._sent_t = self.t.n_blocks
        if not self.keep_history and self.z.n_blocks:
            self.z.forget_blocks()  # the shared time-trace's blocks are the z-trace's
            self._sent_z = self._sent_t = 0
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {}
        if self.z is not None:
            out.update({"z/" + k: v for k, v in self.z.to_arrays().items()})
        if self.t is not None:
            out.update({"t/" + k: v for k, v in self.t.to_arrays().items()})
        return out

    @classmethod
    def from_chunks(cls, chunks, where: str = "trace") -> "Trace":
        """Read back chunks of :meth:`take_chunk` / :meth:`to_arrays` (in order)."""
        chunks = list(chunks)
        zc = [{k[2:]: v for k, v in c.items() if k.startswith("z/")} for c in chunks]
        tc = [{k[2:]: v for k, v in c.items() if k.startswith("t/")} for c in chunks]
        zc = [c for c in zc if c]
        tc = [c for c in tc if c]
        self = cls.__new__(cls)
        self.z = ZTrace.from_chunks(zc, where + " (z)") if zc else None
        shared = bool(tc) and "shared" in tc[0]
        if shared and self.z is None:
            raise InputError("the time-trace shares the z-trace's events, but there is no z-trace", where)
        if shared:
            self.t = SharedTimeTrace(self.z)
            self.t.truncated = self.z.truncated
        else:
            self.t = TimeTrace.from_chunks(tc, where + " (time)") if tc else None
        if self.z is None and self.t is None:
            raise InputError("no trace recorded", where)
        if self.z is not None and self._own_t:
            # a stage is complete only when both traces hold it
            last = min(self.z.last_stage, self.t.last_stage)
            self.z, self.t = _cut_to(self.z, last), _cut_to(self.t, last)
        self.frame = (self.z or self.t).frame
        self._sent_z = self.z.n_blocks if self.z else 0
        self._sent_t = self.t.n_blocks if self.t else 0
        self._header_sent = True
        return self

    @classmethod
    def from_arrays(cls, arrays: dict) -> "Trace":
        return cls.from_chunks([arrays])


def _cut_to(trace, last_stage: int):
    """Drop blocks beyond ``last_stage`` (used when one trace was cut shorter than the other)."""
    if trace.last_stage <= last_stage:
        return trace
    b = trace._blocks_upto(last_stage)
    arrays = {**trace.header_arrays(), **trace._blocks_arrays(0, b)}
    out = type(trace).from_arrays(arrays)
    out.truncated = True
    return out
