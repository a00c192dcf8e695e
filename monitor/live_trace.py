"""The trace that rebuilds the live model, written to the run file in chunks as it is cut.

A :class:`LiveTrace` records the rays each live cut changed (:class:`sim.trace.Trace`,
keeping no history) and hands them to the run file every :data:`TRACE_CHUNK_STAGES`
stages and at least every :data:`TRACE_CHUNK_S` of its clock, so a crash leaves little
of the run recorded but not rebuildable. The trace is a replay aid: whatever fails in it
drops it, and the monitor runs on without.
"""

from __future__ import annotations

import time

import numpy as np

#: a trace chunk is written every this many stages, and at least every TRACE_CHUNK_S
TRACE_CHUNK_STAGES = 50
#: wall s: the trace that rebuilds the model keeps up with the cuts the run file commits
#: (RunWriter's commit_interval, 0.25 s), so a crash leaves at most this much of the run
#: recorded but not rebuildable (replay then ends where the trace does)
TRACE_CHUNK_S = 0.25


class LiveTrace:
    """The live model's trace for ``run`` (a :class:`monitor.runfile.RunWriter`).

    Parameters
    ----------
    run : RunWriter, given the stock as chunk 0 at once
    live : DexelGrid, the live model (before any cut)
    clock : () -> s, what times the chunks (the wall clock; tests give their own)
    """

    def __init__(self, run, live, clock=time.monotonic):
        self.run = run
        self.clock = clock
        #: the sim.trace.Trace, or None (sim.trace missing, or it failed: dropped)
        self.trace = None
        #: the last stage handed to the run file, and when (clock s)
        self.stage_from = 0
        self.at = 0.0
        try:
            from sim.trace import Trace
        except ImportError:
            return
        try:
            # the trace only encodes the stages for the run file: it keeps no history (no
            # keyframes, columns of one chunk), so no poll pays for growing or indexing it
            self.trace = Trace(live, stage=0, auto_maintain=False, keep_history=False)
            self.trace.ready_for_records()
            self.run.append_trace_chunk(0, 0, self.trace.take_chunk())
            self.at = self.clock()
        except Exception:  # the trace is a replay aid; the monitor runs without it
            self.trace = None

    def record(self, live, rays: np.ndarray, stage: int) -> None:
        """Record that live stage ``stage`` changed ``rays``."""
        if self.trace is None:
            return
        try:
            self.trace.record(live, rays=rays, stage=stage)
        except Exception:
            self.trace = None

    def due(self, stage: int) -> None:
        """Write the trace chunk when it is due: every TRACE_CHUNK_STAGES stages, and
        TRACE_CHUNK_S after the last one whenever stages were cut since (cutting or not: a
        chunk's ``stage_to`` tells the reader the model is rebuilt up to there, air cuts
        and a machine standing in a hold included)."""
        if self.trace is None or stage == self.stage_from:
            return
        if (stage - self.stage_from >= TRACE_CHUNK_STAGES
                or self.clock() - self.at >= TRACE_CHUNK_S):
            try:
                self.flush(stage)
            except Exception:  # the trace is a replay aid (a run-file error is the writer's to say)
                self.trace = None

    def flush(self, stage: int) -> None:
        """Hand the trace recorded since the last chunk to the run file as stages
        ``stage_from + 1 .. stage`` (an empty chunk when those stages removed nothing)."""
        if self.trace is not None and self.run is not None and stage > self.stage_from:
            self.run.append_trace_chunk(self.stage_from + 1, stage, self.trace.take_chunk())
            self.stage_from = stage
            self.at = self.clock()
