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

Recording, two ways, each giving the same log:

* ``Cutter.cut_moves(moves, trace=tr)``: the cut kernels write the events as the rays
  change (one block per move, as if each move were cut and recorded alone) and the
  keyframes are copies of the model being cut as they fall due. The cheapest way: the
  batch pays for storing its events, not for finding them again.
* :meth:`Trace.record` diffs the given rays of a model against the trace's own copy (the
  *mirror*, made on first use) in one compiled pass: the live monitor's pattern, where
  the model is cut a poll at a time by other code.

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

The package: :mod:`.columns` (growable columns, run-length coding, the block log both
traces share), :mod:`.keyframes`, :mod:`.ztrace`, :mod:`.sink` (a batch cut writing into
a z-trace), :mod:`.timetrace`; :class:`Trace` (both together) is here.
"""

from __future__ import annotations

import numpy as np

from sim import trace_kernels as tk
from sim.errors import InputError
from sim.grid import DexelGrid
from sim.trace.columns import (changed_rays_of, frame_from_array, frame_to_array,
                               model_difference, same_model)
from sim.trace.timetrace import SharedTimeTrace, TimeTrace
from sim.trace.ztrace import ZTrace

__all__ = ["ZTrace", "TimeTrace", "SharedTimeTrace", "Trace", "same_model", "model_difference",
           "changed_rays_of", "frame_to_array", "frame_from_array"]


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
