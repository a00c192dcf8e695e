"""The storage every trace is made of: growable columns, run-length coding of
serialised arrays, stage arguments, the block log both traces share, and model
comparisons."""

from __future__ import annotations

import numpy as np

from sim.checks.arrays import distinct
from sim.errors import InputError
from sim.frame import Frame
from sim.grid import DexelGrid


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

    def _add_keyframe(self, key) -> None:
        """Keep keyframe ``key``; past ``max_keyframes`` keep the stock's and every other one
        of the rest counted back from the newest (memory bounded, spacing doubled; the
        newest is kept, as a batch's next keyframe copies only what changed since it)."""
        self._keyframes.append(key)
        if len(self._keyframes) > self.max_keyframes:
            rest = self._keyframes[1:]
            self._keyframes = self._keyframes[:1] + rest[(len(rest) - 1) % 2::2]
            self.keyframe_every *= 2

    def _pop_due_block(self) -> int | None:
        """The block of the next keyframe that fell due (those a later keyframe already
        covers dropped), taken off the list; None when none is due."""
        while self._due and self._due[0] <= self._keyframes[-1].block:
            self._due.pop(0)
        return self._due.pop(0) if self._due else None

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
