"""The live session: one step per ``MachineState``.

For every state: find the machine in the program (:mod:`monitor.sync`), cut the path the
tool actually travelled since the last state into the live stock, look ahead over the
horizon on a scratch model (:mod:`monitor.predict`), alert new findings with their lead
time (:mod:`monitor.alerts`) and append to the run file (:mod:`monitor.runfile`).

Positions: the live tip in work coordinates is ``mpos - wco`` when the job reads the work
offset from the controller (GRBL's WCO includes the tool length offset), otherwise
``mpos - work_offset - tool length`` of the current row.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np

from drivers.state import MachineState, RunState
from monitor.job import Job
from monitor.predict import (Lookahead, Workpiece, build_workpiece, finding_record, lead_time,
                             work_moves)
from monitor.sync import ProgramPath, ProgramSync, SyncResult, row_seconds
from sim.checks.findings import Finding
from sim.gcode.moves import MoveKind

#: progress jumps larger than this (program s) re-anchor the look-ahead on the live model
JUMP_S = 2.0
#: a trace chunk is written every this many stages
TRACE_CHUNK_STAGES = 50


@dataclass
class StepInfo:
    """What one step did (for the status line, benchmarks and tests)."""

    sync: SyncResult | None
    removed: float = 0.0            # mm^3 cut from the live model by this step
    new_findings: list = field(default_factory=list)
    seconds: float = 0.0            # wall time of the step


def load_moves(job: Job) -> np.ndarray:
    """The job's program as a move table (MOVE_DTYPE), via the G-code interpreter."""
    from sim.gcode import load_program

    kw = {}
    if job.tool_table is not None:
        kw["tool_table"] = job.tool_table
    try:
        program = load_program(job.program, dialect=job.dialect, **kw)
    except TypeError:  # an interpreter without these keywords
        program = load_program(job.program)
    return np.asarray(program.moves), program


class Session:
    """Follows a machine through a program; call :meth:`step` with every state.

    Parameters
    ----------
    job : Job
    moves : MOVE_DTYPE (n,) the program's move table (as the interpreter made it)
    seconds : float64 (n,) program time per row (default: length / feed estimate)
    run : monitor.runfile.RunWriter or None
    alerter : monitor.alerts.Alerter or None
    program_text : recorded in the run file
    assume_done_before_start : when the run starts mid-program, cut the rows before the
        start into the live model (they ran before the monitor was started)
    """

    def __init__(self, job: Job, moves: np.ndarray, seconds: np.ndarray | None = None, run=None,
                 alerter=None, program_text: str = "", assume_done_before_start: bool = True,
                 workpiece: Workpiece | None = None):
        self.job = job
        self.moves_machine = moves
        self.moves = work_moves(moves)
        secs = row_seconds(self.moves) if seconds is None else np.asarray(seconds, np.float64)
        self.path = ProgramPath.from_moves(self.moves, secs)
        self.sync = ProgramSync(self.path)
        self.wp = workpiece or build_workpiece(job, moves)
        self.live = self.wp.stock
        self.lookahead = Lookahead(self.wp, self.moves, self.path, job.horizon_s, job.horizon_mm, job.limits)
        self.run = run
        self.alerter = alerter
        self.assume_done = assume_done_before_start
        self.findings: list[dict] = []   # every alerted finding
        self.stage = 0                   # live stages cut (one per step that moved)
        self.last: MachineState | None = None
        self.last_sync: SyncResult | None = None
        self._prev_tip: np.ndarray | None = None
        self._cutters: dict[int, object] = {}
        self._trace = None
        self._trace_from = 0
        self._reported: set[tuple[str, int]] = set()  # (kind, move id) already reported
        if run is not None:
            run.put_meta("job", job.text)
            run.put_meta("program", program_text)
            run.put_meta("program_path", str(job.program or ""))
            run.put_meta("frame", {"origin": self.wp.frame.origin.tolist(), "spacing": self.wp.frame.spacing,
                                   "nu": self.wp.frame.nu, "nv": self.wp.frame.nv,
                                   "coordinates": "work"})
            run.put_meta("versions", _versions())
            run.put_array("moves", moves)
            run.put_array("row_seconds", secs)
            self._start_trace()

    # -- positions
    def tip(self, state: MachineState, row: int | None = None) -> np.ndarray:
        """Live tool tip in work coordinates (3,) mm."""
        m = state.mpos_array[:3]
        if self.job.work_offset is None:
            return m - np.asarray(state.wco[:3])
        tl = float(self.moves_machine["tool_length"][row]) if row is not None and len(self.moves_machine) else 0.0
        return m - np.asarray(self.job.work_offset) - np.array([0.0, 0.0, tl])

    def _wco(self, state: MachineState, row: int) -> np.ndarray:
        if self.job.work_offset is None:
            return np.asarray(state.wco, np.float64)
        w = np.zeros(6)
        w[:3] = self.job.work_offset
        w[2] += float(self.moves_machine["tool_length"][row]) if len(self.moves_machine) else 0.0
        return w

    # -- the loop body
    def step(self, state: MachineState) -> StepInfo:
        """Process one state: sync, cut, look ahead, alert, record."""
        t0 = time.perf_counter()
        if self.run is not None:
            self.run.append_state(state)
        if state.state in (RunState.DISCONNECTED, RunState.UNKNOWN) and not np.all(np.isfinite(state.mpos_array)):
            return StepInfo(None, seconds=time.perf_counter() - t0)
        row_hint = self.last_sync.row if self.last_sync is not None else None
        tip = self.tip(state, row_hint)
        prev = self.last_sync
        s = self.sync.update(tip, t=state.t, line=state.line)
        if s.how != "line" and self.job.work_offset is not None:
            tip = self.tip(state, s.row)
        info = StepInfo(s)
        if prev is None:
            self._start(s, state)
        elif s.how in ("search", "line") and abs(s.progress - prev.progress) > JUMP_S:
            self.lookahead.anchor(self.live, s.row, self._wco(state, s.row))
        info.removed = self._cut_live(tip, s, state)
        fresh = self._predict(s, state)
        fresh += self._live_findings(info.removed, s, state, tip)
        if fresh:
            info.new_findings = self._alert(fresh, state)
        self.last, self.last_sync = state, s
        info.seconds = time.perf_counter() - t0
        return info

    def _start(self, s: SyncResult, state: MachineState) -> None:
        if self.assume_done and s.row > 0:
            from sim.cut import Cutter

            done = self.moves[:s.row]
            Cutter(self.live, self.wp.default_tool, self.wp.tol, tools=self.wp.tools).cut_moves(
                done, move_ids=np.arange(1, s.row + 1), record_changes=False)
        self.lookahead.anchor(self.live, s.row, self._wco(state, s.row))

    def _cutter(self, tool_number: int):
        c = self._cutters.get(tool_number)
        if c is None:
            from sim.cut import Cutter

            c = self._cutters[tool_number] = Cutter(self.live, self.wp.tool(tool_number), self.wp.tol)
        return c

    def _cut_live(self, tip: np.ndarray, s: SyncResult, state: MachineState) -> float:
        prev, self._prev_tip = self._prev_tip, tip
        if prev is None or not np.all(np.isfinite(tip)) or np.linalg.norm(tip - prev) < self.wp.tol.length:
            return 0.0
        self.stage += 1
        tool = int(self.moves["tool"][s.row]) if len(self.moves) else 0
        pts = self._travelled(prev, tip, s)
        cutter = self._cutter(tool)
        removed = 0.0
        for a, b in zip(pts[:-1], pts[1:]):
            removed += cutter.cut_segment(a, b, s.row + 1)
        if self.run is not None:
            self.run.append_cut(self.stage, {"points": pts}, t=state.t, move_id=s.row + 1, line=s.line)
            if removed > 0:
                self._record_trace(self._rays_near(pts, cutter.tool.radius))
        return removed

    def _rays_near(self, pts: np.ndarray, radius: float) -> np.ndarray:
        """Flat indices (int64) of the rays within ``radius`` of the points' XY bounding box."""
        f = self.live.frame
        lo = np.floor((pts[:, :2].min(axis=0) - radius - f.origin[:2]) / f.spacing).astype(int) - 1
        hi = np.ceil((pts[:, :2].max(axis=0) + radius - f.origin[:2]) / f.spacing).astype(int) + 2
        i0, j0 = max(lo[0], 0), max(lo[1], 0)
        i1, j1 = min(hi[0], f.nu), min(hi[1], f.nv)
        if i1 <= i0 or j1 <= j0:
            return np.zeros(0, np.int64)
        return (np.arange(j0, j1)[:, None] * f.nu + np.arange(i0, i1)[None, :]).reshape(-1).astype(np.int64)

    def _travelled(self, prev: np.ndarray, tip: np.ndarray, s: SyncResult) -> np.ndarray:
        """Points (k, 3) of the path from the last tip to this one: through the program's
        corners passed in between when both ends sit on the program (between two polls the
        machine followed the program, not the chord), else the straight chord."""
        last = self.last_sync
        if (last is None or s.how not in ("track", "line") or last.how == "lost"
                or s.distance > self.sync.lost or s.progress <= last.progress):
            return np.stack([prev, tip])
        path = self.path
        k0, k1 = path.segment_at(last.progress), path.segment_at(s.progress)
        corners = path.p1[k0:k1]
        keep = (path.t1[k0:k1] > last.progress) & (path.t1[k0:k1] < s.progress)
        return np.concatenate([prev[None], corners[keep], tip[None]])

    def _predict(self, s: SyncResult, state: MachineState) -> list[dict]:
        found = self.lookahead.advance(s.progress)
        ovr = state.overrides[0] if state.overrides else 100
        return [finding_record(f, lead_time(f, self.path, s.progress, ovr), state.t) for f in found]

    def _live_findings(self, removed: float, s: SyncResult, state: MachineState, tip) -> list[dict]:
        """What the real motion did that the program did not announce (lead time 0)."""
        out = []
        if removed <= 1e-3 or s.row >= len(self.moves):
            return out
        pos = tuple(float(v) for v in tip)
        if int(self.moves["kind"][s.row]) == MoveKind.RAPID:
            out.append(Finding("rapid_into_stock", line=s.line, stage=s.row + 1, position=pos, volume=removed,
                               message=f"rapid through material at line {s.line}"))
        if state.spindle == 0 and state.state == RunState.RUN:
            out.append(Finding("spindle_stopped_cutting", line=s.line, stage=s.row + 1, position=pos,
                               volume=removed))
        return [finding_record(f, 0.0, state.t, predicted=False) for f in out]

    def _alert(self, records: list[dict], state: MachineState) -> list[dict]:
        # the real motion re-doing what the look-ahead already reported is not news
        records = [r for r in records if r["predicted"] or
                   not any((r["kind"], st) in self._reported for st in r.get("stages") or [r.get("stage")])]
        for r in records:
            self._reported.update((r["kind"], st) for st in (r.get("stages") or [r.get("stage")]))
        if self.alerter is not None:
            fresh = self.alerter.offer(records, t=state.t)
        else:
            fresh = records
        self.findings += fresh
        return fresh

    # -- trace (optional hook: sim.trace)
    def _start_trace(self) -> None:
        try:
            from sim.trace import Trace
        except ImportError:
            return
        try:
            self._trace = Trace(self.live, stage=0)
            self.run.append_trace_chunk(0, 0, self._trace.take_chunk())
        except Exception:  # the trace is a replay aid; the monitor runs without it
            self._trace = None

    def _record_trace(self, rays: np.ndarray) -> None:
        if self._trace is None:
            return
        try:
            self._trace.record(self.live, rays=rays, stage=self.stage)
            if self.stage - self._trace_from >= TRACE_CHUNK_STAGES:
                self.flush_trace()
        except Exception:
            self._trace = None

    def flush_trace(self) -> None:
        if self._trace is not None and self.run is not None and self.stage > self._trace_from:
            self.run.append_trace_chunk(self._trace_from + 1, self.stage, self._trace.take_chunk())
            self._trace_from = self.stage

    def finish(self) -> dict:
        """Flush what is pending; return a summary dict."""
        self.flush_trace()
        summary = {"event": "summary", "findings": len(self.findings), "stages": self.stage,
                   "kinds": sorted({f["kind"] for f in self.findings}),
                   "progress_s": None if self.last_sync is None else round(self.last_sync.progress, 3),
                   "program_s": round(self.path.duration, 3)}
        if self.run is not None:
            self.run.put_meta("summary", summary)
            self.run.flush()
        return summary


def _versions() -> dict:
    import sys

    import numba
    import numpy

    out = {"python": sys.version.split()[0], "numpy": numpy.__version__, "numba": numba.__version__}
    try:
        from importlib.metadata import version

        out["dexmon"] = version("dexmon")
    except Exception:
        pass
    return out


def run_controller(session: Session, controller, period: float, status=None, stop=None,
                   done=None, max_seconds: float | None = None) -> int:
    """Poll ``controller`` every ``period`` s and step ``session`` until the program ends.

    ``done()`` (optional) says the run is over (the virtual controller's ``done``); without
    it the loop ends when the machine is idle at the program's end, on ``stop`` (an Event)
    or ``KeyboardInterrupt``. Returns the number of states processed.
    """
    n = 0
    start = time.monotonic()
    end_row = len(session.moves) - 1
    for state in controller.states(period):
        info = session.step(state)
        n += 1
        if status is not None:
            status.update(state, info.sync, session.path.duration, len(session.findings), info.seconds * 1e3)
        if stop is not None and stop.is_set():
            break
        if done is not None and done():
            # one more state so the last motion is cut
            session.step(controller.poll())
            n += 1
            break
        if done is None and info.sync is not None and info.sync.row >= end_row and state.state == RunState.IDLE:
            break
        if state.state == RunState.ALARM and done is None:
            break
        if max_seconds is not None and time.monotonic() - start > max_seconds:
            break
    return n


def findings_json_line(f: dict) -> str:
    return json.dumps({"event": "finding", **f})
