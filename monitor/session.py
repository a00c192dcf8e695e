"""The live session: one step per ``MachineState``.

For every state: find the machine in the program (:mod:`monitor.sync`), cut the path the
tool actually travelled since the last state into the live stock *and check it*, look
ahead over the horizon on a scratch model, both through :class:`sim.checks.Checker`
(:mod:`monitor.predict`), alert new findings with their lead time (:mod:`monitor.alerts`;
a predicted finding that then happens is one alert, updated to "happened") and append to
the run file (:mod:`monitor.runfile`), with the trace that rebuilds the live model
(:mod:`monitor.live_trace`). The program comes as a move table (:mod:`monitor.program_moves`).

Link trouble: a state that is not fresh (``drivers.state.NOT_FRESH``: missed, bad,
disconnected; or fresh with numbers :func:`drivers.state.implausible` refuses, taken as
bad) is recorded and counted, never synced or cut. After a gap -- a disconnect, a reset
the controller tells (:meth:`Session.link_event`), or :data:`monitor.gaps.GAP_POLLS` not-fresh polls in
a row -- the path in between is unknown: the first fresh state is not joined to the last
one but found again by a search of the program, the rows the program ran meanwhile are
cut as programmed (unchecked) when both ends sit on the program, and a gap record says
what happened (:attr:`Session.gaps`, the run file's ``link_events``, the summary).

Program time (and so lead times) comes from ``Program.cycle_time`` (GRBL-like planner,
:func:`monitor.program_moves.program_seconds`) with the machine limits in force
(:mod:`monitor.machine`: the job's ``[machine]`` field by field over the controller's over
defaults), falling back to length / feed only if it fails. Limits the controller states
after the session was built (GRBL reads ``$$`` at connect when Idle, else at the next
Idle) retime the path between two steps (:meth:`Session.use_controller_limits`).

Two frames. The *model* frame is the job's work system (G54 unless the job says), in
which stock, fixtures and design sit and the program's rows are placed by their machine
tips (``monitor.work_coords.work_moves`` with the job's reference offset): a G55 station of a
multi-fixture program lands at its offset relative to G54. The *sync* frame is each row's
own work coordinates, what the controller reports as work position (``mpos - WCO``): the
program is found by matching that against the rows (:attr:`Session.sync_path`).

The live tip in the model frame is ``mpos - tool length - zero`` where ``zero`` is the
machine position of the job system's zero: the job's ``work_offset``, or with
``work_offset = "controller"`` derived from the WCO the controller reports while the
program runs in the job's system (WCO - the row's own offset + the reference offset), and
kept when the program switches to another system -- so a stale .var entry for G55 shows
where the machine really cut, not where the file says.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from drivers.state import LinkEvent, MachineState, RunState, implausible, stale_state
from monitor.alerts import Alerter
from monitor.gaps import GapLedger
from monitor.job import Job
from monitor.live_trace import LiveTrace
from monitor.machine import in_force
from monitor.program_moves import program_seconds
from monitor.predict import LiveChecks, Lookahead, finding_record, lead_time
from monitor.work_coords import limits_in_work, reference_wco, row_shifts, work_moves
from monitor.workpiece import Workpiece, build_workpiece
from monitor.sync import ProgramPath, ProgramSync, SyncResult
from sim.checks.arrays import distinct
from sim.gcode.moves import MoveKind

#: progress jumps larger than this (program s) re-anchor the look-ahead on the live model
JUMP_S = 2.0


def rotary_scale(job: Job) -> float:
    """mm per degree of A B C when the sync compares poses (:mod:`monitor.sync`): the arc
    one degree turns at the stock's reach (half its box's diagonal; 10 mm unknown)."""
    b = job.stock.bounds() if job.stock is not None else None
    reach = 0.5 * float(np.linalg.norm(np.subtract(b[1], b[0]))) if b is not None else 10.0
    return math.radians(1.0) * max(reach, 1.0)


@dataclass
class StepInfo:
    """What one step did (for the status line, benchmarks and tests)."""

    sync: SyncResult | None
    removed: float = 0.0            # mm^3 cut from the live model by this step
    new_findings: list = field(default_factory=list)
    seconds: float = 0.0            # wall time of the step
    skipped: str = ""               # why the state was not followed (not fresh), else ""
    gap: dict | None = None         # the gap record this (first fresh) state closed
    #: program rows ``(first, last)`` the spindle ran before the look-ahead predicted them
    #: (it overtook the look-ahead: the monitor fell behind), else None
    overtaken: tuple | None = None


class Session:
    """Follows a machine through a program; call :meth:`step` with every state.

    Parameters
    ----------
    job : Job
    moves : MOVE_DTYPE (n,) the program's move table (as the interpreter made it)
    seconds : float64 (n,) program time per row (default:
        :func:`monitor.program_moves.program_seconds` of ``program`` with the job's machine limits)
    run : monitor.runfile.RunWriter or None
    alerter : monitor.alerts.Alerter or None (None: a silent one, still alerting once)
    program_text : recorded in the run file
    assume_done_before_start : when the run starts mid-program, cut the rows before the
        start into the live model (they ran before the monitor was started)
    trace_clock : () -> s, what times the trace chunks written to ``run`` (at least every
        :data:`monitor.live_trace.TRACE_CHUNK_S`); the wall clock, tests give their own
    """

    def __init__(self, job: Job, moves: np.ndarray, seconds: np.ndarray | None = None, run=None,
                 alerter=None, program_text: str = "", assume_done_before_start: bool = True,
                 workpiece: Workpiece | None = None, program=None, controller_limits=None,
                 trace_clock=time.monotonic):
        self.job = job
        self.moves_machine = moves
        #: offset (machine - work) of the job's work system in the interpreter, (6,) mm
        self.reference_wco = reference_wco(job)
        self.moves = work_moves(moves, self.reference_wco)
        #: per row, own work coordinates -> model frame, (n, 3) mm (0: the job's system)
        self.row_shift = row_shifts(moves, self.reference_wco)
        #: machine - interpreter machine coordinates, learned from the WCO while the
        #: program runs in the job's system (None until then)
        self._machine_shift: np.ndarray | None = None
        #: the machine limits in force (monitor.machine.InForce): timing and travel
        self.in_force = in_force(job.machine, controller_limits, job.limits)
        self._program = program
        self._fixed_seconds = seconds is not None
        secs = (program_seconds(program, moves, self.in_force.machine) if seconds is None
                else np.asarray(seconds, np.float64))
        # the travelled path between polls follows these chords: on arcs they must stay
        # well inside the gouge band, or the live check would see the chords' sagitta
        tol = job.tolerance
        self._chord = max(tol.chord, min(0.05, tol.gouge / 4))
        self.path = ProgramPath.from_moves(self.moves, secs, chord=self._chord)
        # the same segments in each row's own work coordinates (a translation per row)
        self.sync_path = self.path
        #: mm per degree of A B C in the sync's 6-D points (None: the kinematics turns nothing)
        self.rotary_scale = rotary_scale(job) if job.kinematics.rotaries else None
        self._prev_angles: np.ndarray | None = None  # work A B C of the last state cut (rotary jobs)
        if np.any(self.row_shift != 0.0) or self.rotary_scale is not None:
            seg_shift = self.row_shift[self.path.row]
            p0, p1 = self.path.p0, self.path.p1
            if self.rotary_scale is not None:  # the same segments, with their angles
                six = ProgramPath.from_moves(self.moves, secs, chord=self._chord, rotary_scale=self.rotary_scale)
                p0, p1 = six.p0, six.p1
                seg_shift = np.hstack([seg_shift, np.zeros_like(seg_shift)])
            self.sync_path = replace(self.path, p0=p0 - seg_shift, p1=p1 - seg_shift)
        self.sync = ProgramSync(self.sync_path)
        self.wp = workpiece or build_workpiece(job, moves)
        self.live = self.wp.stock
        travel = self.in_force.travel
        self.lookahead = Lookahead(self.wp, self.moves, self.path, job.horizon_s, job.horizon_mm, travel)
        self.live_checks = LiveChecks(self.wp, self.moves, travel)
        #: ``controller.machine_limits`` while the controller has not said them (the
        #: session asks at every step until it has), else None
        self.limits_from = None
        #: called with the new ``in_force`` when limits learned later change it, or None
        self.on_limits = None
        self.run = run
        self.alerter = alerter if alerter is not None else Alerter()
        self.assume_done = assume_done_before_start
        self.findings: list[dict] = []   # every alerted finding
        self.stage = 0                   # live stages cut (one per step that moved)
        self.last: MachineState | None = None   # the last fresh state followed
        self.last_sync: SyncResult | None = None
        #: not-fresh polls counted, gaps opened and closed (:mod:`monitor.gaps`)
        self.ledger = GapLedger(run)
        #: why :func:`run_controller` ended ("program end", "done", "alarm", "gave up: ...")
        self.end_reason = ""
        self._prev_tip: np.ndarray | None = None
        self._prev_row: int | None = None   # program row of the last piece cut live
        self._predicted_to = 0            # rows before it were predicted (before this step's anchor)
        #: the trace that rebuilds the live model, written to ``run`` (None without a run)
        self._live_trace: LiveTrace | None = None
        self._fill_horizon = False
        self.view = None                 # a monitor.render.feed.ViewFeed, or None
        self.line_source = None          # a monitor.linesync.StreamedLines, or None
        self._changed: np.ndarray | None = None
        #: compares the reported WCO with the job's work_offset (:meth:`check_setup`), or None
        self._offset_check = None
        if run is not None:
            run.put_meta("job", job.text)
            run.put_meta("program", program_text)
            run.put_meta("program_path", str(job.program or ""))
            run.put_meta("frame", {"origin": self.wp.frame.origin.tolist(), "spacing": self.wp.frame.spacing,
                                   "nu": self.wp.frame.nu, "nv": self.wp.frame.nv,
                                   "coordinates": "work", "work_system": job.work_system,
                                   "reference_wco": self.reference_wco.tolist()})
            run.put_meta("versions", _versions())
            run.put_array("moves", moves)
            run.put_array("row_seconds", secs)
            run.put_meta("machine", self.in_force.to_json())
            self._live_trace = LiveTrace(run, self.live, trace_clock)

    def warm_up(self, rows: int = 12) -> float:
        """Run every kernel the loop uses once on a scratch copy, so that JIT compilation
        (numba, on a cold cache: seconds) happens before the machine is followed, not in
        the first poll while the machine runs on. Returns the seconds it took; the live
        model, the look-ahead and the run file are untouched."""
        from dataclasses import replace

        from monitor.predict import make_checker

        t0 = time.perf_counter()
        if len(self.moves) == 0:
            return 0.0
        scratch = self.live.copy()
        trace = None
        if self._live_trace is not None and self._live_trace.trace is not None:
            try:
                from sim.trace import Trace

                # as the live one, before the cuts, so it sees them change rays
                trace = Trace(scratch, stage=0, auto_maintain=False, keep_history=False)
            except Exception:  # the trace is a replay aid; warming it is optional
                trace = None
        moving = np.nonzero(np.isin(self.moves["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW,
                                                         MoveKind.ARC_CCW)))[0]
        pick = []
        for tool in np.unique(self.moves["tool"][moving]):  # each tool's kernels, arcs included
            mine = moving[self.moves["tool"][moving] == tool]
            arcs = mine[np.isin(self.moves["kind"][mine], (MoveKind.ARC_CW, MoveKind.ARC_CCW))]
            pick += list(mine[:rows]) + list(arcs[:2])
        idx = np.unique(np.asarray(pick, np.int64))
        if idx.size:
            checker = make_checker(self.wp, scratch, self.in_force.travel, np.zeros(6))
            res, _ = checker.cut_and_check(self.moves[idx], move_ids=idx + 1)
            live = LiveChecks(replace(self.wp, stock=scratch), self.moves, self.in_force.travel)
            k = int(idx[0])
            a, b = self.moves["start"][k, :3], self.moves["end"][k, :3]
            _, rays, _ = live.cut(np.stack([a, (a + b) / 2, b]), np.array([k, k]), None)
            changed = np.union1d(res.changed_rays, rays).astype(np.int64)
            # the programmed cut of the rows run during a gap (_cut_gap_rows)
            from sim.cut import Cutter

            Cutter(scratch, self.wp.default_tool, self.wp.tol, tools=self.wp.tools).cut_moves(
                self.moves[idx[:2]], move_ids=idx[:2] + 1, record_changes=True)
            if trace is not None:
                try:
                    trace.record(scratch, rays=changed, stage=1)
                    trace.take_chunk()
                except Exception:
                    pass
        return time.perf_counter() - t0

    def use_controller_limits(self, limits) -> bool:
        """Take the limits the controller stated (``drivers.state.ControllerLimits`` or
        None). When they change what is in force, the rows are timed again and the path
        retimed in place (sync, look-ahead and view share its arrays), the progress
        followed so far kept at the same place on the path, the run file given the new
        row seconds; travel limits learned from the controller apply to later checks.
        Call between steps. True when anything in force changed."""
        new = in_force(self.job.machine, limits, self.job.limits)
        if new == self.in_force:
            return False
        old, self.in_force = self.in_force, new
        if new.machine != old.machine and not self._fixed_seconds:
            self._retime(program_seconds(self._program, self.moves_machine, new.machine))
        if new.travel != old.travel:
            for checks in (self.lookahead, self.live_checks):
                checks.limits = {k.upper(): v for k, v in (new.travel or {}).items()}
                if checks.checker is not None:
                    checks.checker.limits = limits_in_work(checks.limits, checks.wco)
        if self.run is not None:
            self.run.put_meta("machine", new.to_json())
        return True

    def _retime(self, secs: np.ndarray) -> None:
        """Program time per row ``secs`` (n,) s into the path's arrays, in place."""
        path = self.path
        moved = [self.sync.progress, None if self.last_sync is None else self.last_sync.progress]
        where = [None if p is None else (path.segment_at(p), _fraction(path, p)) for p in moved]
        new = ProgramPath.from_moves(self.moves, secs, chord=self._chord)
        for name in ("t0", "t1", "row_t0", "row_t1"):
            getattr(path, name)[:] = getattr(new, name)
        now = [None if w is None else float(path.t0[w[0]] + w[1] * (path.t1[w[0]] - path.t0[w[0]])) for w in where]
        self.sync.progress = now[0]
        if self.last_sync is not None:
            self.last_sync = replace(self.last_sync, progress=now[1])
        if self.run is not None:
            self.run.put_array("row_seconds", secs)

    def _learn_limits(self) -> None:
        """Ask the controller for its limits until it has said them (see :attr:`limits_from`)."""
        try:
            limits = self.limits_from()
        except Exception:  # a driver that cannot say: keep what is in force
            limits = None
        if limits is not None:
            self.limits_from = None
            if self.use_controller_limits(limits) and self.on_limits is not None:
                self.on_limits(self.in_force)

    def attach_view(self, feed) -> None:
        """Post every state to ``feed`` (a :class:`monitor.render.feed.ViewFeed`): the
        rays each step changed with their new tops, the tool pose, the progress and the
        findings. Costs the loop O(changed rays) per state; the drawing is the feed's."""
        self.view = feed

    def _post_view(self, tip: np.ndarray, s: SyncResult, wco: np.ndarray) -> None:
        from monitor.render.feed import tops_of

        rays, self._changed = self._changed, None
        tops = tops_of(self.live, rays) if rays is not None and rays.size else None
        tool = self.wp.tool(int(self.moves["tool"][s.row])) if len(self.moves) else None
        self.view.post(rays, tops, tip=tip, tool=tool, progress=s.progress, findings=self.findings, wco=wco,
                       stage=self.stage)

    # -- positions
    def _row(self, row: int | None) -> int | None:
        return None if row is None or not len(self.moves_machine) else int(row)

    def tip(self, state: MachineState, row: int | None = None) -> np.ndarray:
        """Live tool tip in the model frame (the job's work system) (3,) mm."""
        return np.asarray(state.mpos_array[:3], np.float64) - self._wco(state, row)[:3]

    def sync_point(self, state: MachineState, tip: np.ndarray, row: int | None) -> np.ndarray:
        """The tip in the sync frame (row ``row``'s own work coordinates) (3,) mm: the
        controller's work position when it reports the offset, else the model tip moved
        back by the row's shift."""
        if self.job.work_offset is None:
            return np.asarray(state.mpos_array[:3], np.float64) - np.asarray(state.wco[:3], np.float64)
        r = self._row(row)
        return tip if r is None else tip - self.row_shift[r]

    def angles(self, state: MachineState) -> np.ndarray:
        """The rotaries' work position A B C (3,) deg: the controller's work position when
        it reports the offset, else its machine position (a job's ``work_offset`` is X Y Z)."""
        a = np.asarray(state.mpos_array[3:6], np.float64)
        return a - np.asarray(state.wco[3:6], np.float64) if self.job.work_offset is None else a

    def _wco(self, state: MachineState, row: int | None, learn: bool = False) -> np.ndarray:
        """Machine position of the controlled point minus the model-frame tip, (6,) mm:
        the job system's zero + the row's tool length.

        With the offset from the controller, the job system's zero is what its WCO says
        while the program is in that system (``learn``: the state is synced on ``row``;
        a WCO that switched before the machine left the row is not learned from)."""
        r = self._row(row)
        tl = float(self.moves_machine["tool_length"][r]) if r is not None else 0.0
        w = np.zeros(6)
        if self.job.work_offset is not None:
            w[:3] = self.job.work_offset
            w[2] += tl
            return w
        sw = np.asarray(state.wco, np.float64)
        if r is None:
            return sw
        own = np.asarray(self.moves_machine["wco"][r], np.float64)
        ok = bool(np.all(np.isfinite(sw)))
        in_job_system = not np.any(self.row_shift[r])
        if ok and (self._machine_shift is None or (learn and in_job_system)):
            self._machine_shift = sw - own
        if in_job_system and ok:
            return sw.copy()
        w = own + (self._machine_shift if self._machine_shift is not None else 0.0)
        w[:3] -= self.row_shift[r]
        return w

    # -- the loop body
    def step(self, state: MachineState) -> StepInfo:
        """Process one state: sync, cut, look ahead, alert, record.

        A state that is not fresh (missed, bad, disconnected; or fresh with numbers
        :func:`drivers.state.implausible` refuses, recorded as BAD) is recorded and
        counted, never synced or cut. After a gap the first fresh state is not joined to
        the last one: it is found again in the program (see :meth:`_close_gap`)."""
        t0 = time.perf_counter()
        self.ledger.started(state.t)
        why = implausible(state) if state.fresh else None
        if why is not None:
            state = stale_state(self.last, RunState.BAD, state.t, f"{why}: {state.raw}")
        if self.run is not None:
            self.run.append_state(state)
        if not state.fresh:
            self.ledger.not_fresh(state)
            return StepInfo(self.last_sync, skipped=state.state.value, seconds=time.perf_counter() - t0)
        if self.limits_from is not None:
            self._learn_limits()
        gap = self.ledger.fresh(state.t)
        self._predicted_to = self.lookahead.next_row
        row_hint = self.last_sync.row if self.last_sync is not None else None
        tip = self.tip(state, row_hint)
        point = self.sync_point(state, tip, row_hint)
        if self.rotary_scale is not None:  # a move turning only A moves the sync point too
            point = np.concatenate([point, self.rotary_scale * self.angles(state)])
        prev = self.last_sync
        line = state.line
        if self.line_source is not None:
            # the lines a sender streams (passthrough) say where in the program it is
            line = self.line_source.line_for(state, point, self.sync)
        s = self.sync.update(point, t=state.t, line=line, search=gap is not None)
        info = StepInfo(s)
        wco = self._wco(state, s.row, learn=s.how in ("track", "line") and s.distance <= self.sync.lost)
        tip = np.asarray(state.mpos_array[:3], np.float64) - wco[:3]
        restart = None   # the look-ahead starts again from the live model (behind: overtaken)
        if prev is None:
            self._start(s, state)
        elif gap is not None:
            info.gap = self._close_gap(gap, state, tip, prev, s)
            restart = False
        elif s.how in ("search", "line") and abs(s.progress - prev.progress) > JUMP_S:
            restart = False  # a jump: predict again from the live model
        elif self.lookahead.next_row < s.row:
            # the spindle overtook the look-ahead: its rows are history now, unpredicted
            info.overtaken = (self.lookahead.next_row, s.row - 1)
            restart = True
        elif not np.array_equal(wco, self.lookahead.wco):
            self.lookahead.set_wco(wco)
        self.live_checks.set_wco(wco)
        fresh = self._offset_check.see(state, tip) if self._offset_check is not None else []
        cut, info.removed = self._cut_live(tip, s, state)
        if self._live_trace is not None:
            self._live_trace.due(self.stage)
        if restart is not None:
            # from the live model with the path since the last state cut in: taken before,
            # the rows the machine has just run were not in it, and the row it is on (a
            # retract out of the slot it just cut) rose through stock it had removed
            self.lookahead.anchor(self.live, s.row, wco, behind=restart)
        fresh += cut + self._predict(s, state)
        if fresh:
            info.new_findings = self._alert(fresh, state)
        if self.view is not None:
            self._post_view(tip, s, wco)
        self.last, self.last_sync = state, s
        info.seconds = time.perf_counter() - t0
        return info

    # -- link trouble: the ledger counts and files; the session closes gaps on the model
    @property
    def counts(self) -> dict:
        """Not-fresh states seen, by kind (missed, bad, disconnected)."""
        return self.ledger.counts

    @property
    def gaps(self) -> list[dict]:
        """Closed gap records, oldest first."""
        return self.ledger.gaps

    @property
    def on_gap(self):
        """Called with every gap record (a JSON-ready dict) when it closes, or None."""
        return self.ledger.on_gap

    @on_gap.setter
    def on_gap(self, fn) -> None:
        self.ledger.on_gap = fn

    def link_event(self, ev: LinkEvent) -> dict:
        """Take one :class:`drivers.state.LinkEvent` from the controller (see
        :meth:`monitor.gaps.GapLedger.link_event`); returns it as a JSON-ready dict."""
        return self.ledger.link_event(ev)

    def _close_gap(self, gap: dict, state: MachineState, tip: np.ndarray, before: SyncResult,
                   s: SyncResult) -> dict:
        """Finish the gap record at ``state``, the first fresh state after it.

        The path during the gap is unknown, so it is not cut: the tip is not joined to the
        last one. When both ends sit on the program and the machine went forward, the rows
        the program ran in between are cut into the live model as programmed (unchecked:
        what happened there was not seen), so the model stays right."""
        last_tip = self._prev_tip
        self._prev_tip, self._prev_row = None, None
        # a controller that reset lost its program: the rows between did not run
        rows = [] if gap["reset"] else self._cut_gap_rows(before, s, state)
        return self.ledger.close(
            gap, state.t, jump_mm=None if last_tip is None else float(np.linalg.norm(tip - last_tip)),
            from_line=int(before.line), resync={"how": s.how, "line": int(s.line), "row": int(s.row),
                                                "progress_s": round(float(s.progress), 3),
                                                "distance_mm": round(float(s.distance), 3)},
            rows_cut_unchecked=[int(self.moves["line"][r]) for r in rows])

    def _cut_gap_rows(self, before: SyncResult, s: SyncResult, state: MachineState) -> list[int]:
        """Cut what the program ran between ``before`` and ``s`` (both on the program, ``s``
        ahead) as programmed: rows ``before.row .. s.row - 1`` whole and row ``s.row`` up
        to the re-synced point when it is straight. Returns the rows cut."""
        lost = self.sync.lost
        if (before.how == "lost" or s.how == "lost" or before.distance > lost or s.distance > lost
                or s.progress <= before.progress):
            return []
        from sim.cut import Cutter

        r0, r1 = int(before.row), int(s.row)
        pieces = self.moves[r0:r1 + 1].copy()
        ids = np.arange(r0 + 1, r1 + 2)
        last = pieces[-1:]
        if int(last["kind"][0]) in (MoveKind.FEED, MoveKind.RAPID):
            last["end"][0, :3] = self.path.point_at(s.progress)
            if self.rotary_scale is not None:  # and the rotaries only as far as they turned
                last["end"][0, 3:] = self.sync_path.point_at(s.progress)[3:] / self.rotary_scale
        elif r1 > r0:  # an arc: its part up to here is left to the live cut from here on
            pieces, ids = pieces[:-1], ids[:-1]
        else:
            return []
        res = Cutter(self.live, self.wp.default_tool, self.wp.tol, tools=self.wp.tools, kinematics=self.wp.kinematics,
                   origin=self.wp.origin, tool_lengths=self.wp.tool_lengths).cut_moves(
            pieces, move_ids=ids, record_changes=True)
        rays = (distinct(res.changed_rays).astype(np.int64) if res.changed_rays is not None
                else np.zeros(0, np.int64))
        self.stage += 1
        if self.view is not None and rays.size:
            self._changed = rays if self._changed is None else distinct(np.concatenate([self._changed, rays]))
        if self.run is not None:
            pts = np.concatenate([pieces["start"][:1, :3], pieces["end"][:, :3]])
            self.run.append_cut(self.stage, {"points": pts}, t=state.t, move_id=r1 + 1, line=int(s.line))
            if rays.size:
                self._live_trace.record(self.live, rays, self.stage)
        return list(range(r0, r0 + len(pieces)))

    def _start(self, s: SyncResult, state: MachineState) -> None:
        if self.assume_done and s.row > 0:
            # rows that ran before the monitor started: cut, not checked (their findings
            # are history the monitor did not see)
            from sim.cut import Cutter

            done = self.moves[:s.row]
            Cutter(self.live, self.wp.default_tool, self.wp.tol, tools=self.wp.tools, kinematics=self.wp.kinematics,
                   origin=self.wp.origin, tool_lengths=self.wp.tool_lengths).cut_moves(
                done, move_ids=np.arange(1, s.row + 1), record_changes=False)
            if self.view is not None:  # the whole model may have changed
                self._changed = np.arange(self.live.frame.n_rays, dtype=np.int64)
        self.lookahead.anchor(self.live, s.row, self._wco(state, s.row))
        self._fill_horizon = True  # the first state may take long: predict the whole horizon now

    def _cut_live(self, tip: np.ndarray, s: SyncResult, state: MachineState) -> tuple[list[dict], float]:
        """Cut and check the path travelled since the last state; (finding records, mm^3)."""
        prev, self._prev_tip = self._prev_tip, tip
        turned = False
        if self.rotary_scale is not None:
            prev_angles, self._prev_angles = self._prev_angles, self.angles(state)
            turned = prev_angles is not None and bool(np.any(np.abs(self._prev_angles - prev_angles) > 1e-9))
        if prev is None or not np.all(np.isfinite(tip)) or (
                np.linalg.norm(tip - prev) < self.wp.tol.length and not turned):
            return [], 0.0
        self.stage += 1
        pts, rows = self._travelled(prev, tip, s)
        if self.rotary_scale is not None and prev_angles is not None:
            pts = np.hstack([pts, self._travelled_angles(prev_angles, self._prev_angles, len(pts), s)])
        # a stopped spindle counts only when both ends of the piece say so (a state after
        # M5 must not make the whole path since the last poll a stopped-spindle cut)
        rpm = _spindle_rpm(state)
        if rpm == 0.0 and self.last is not None and _spindle_rpm(self.last) != 0.0:
            rpm = None
        polled = (self.last_sync.row if self.last_sync is not None else None, s.row)
        removed, rays, found = self.live_checks.cut(pts, rows, rpm, arrived_row=self._prev_row, polled_rows=polled)
        self._prev_row = int(rows[-1])
        if self.view is not None and rays.size:
            self._changed = rays if self._changed is None else distinct(np.concatenate([self._changed, rays]))
        if self.run is not None:
            self.run.append_cut(self.stage, {"points": pts}, t=state.t, move_id=s.row + 1, line=s.line)
            if removed > 0 and rays.size:
                self._live_trace.record(self.live, rays, self.stage)
        out = [finding_record(f, 0.0, state.t, predicted=False, stage=self.stage, path=self.path, moves=self.moves)
               for f in found]
        for rec, f in zip(out, found):
            rec["lead_note"] = self._unpredicted_note(f)
        return out, removed

    def _unpredicted_note(self, f) -> str:
        """Why a finding on the real motion comes with lead time 0 (when it was not
        predicted; a predicted one is merged into its alert and this is not said)."""
        row = int(min(f.stages or (f.stage,))) - 1
        if row >= self._predicted_to or self.last_sync is None:
            return "happened before it could be predicted (the look-ahead had not reached it)"
        return "happened on the real motion, not as the program says (the look-ahead checks the program)"

    def _travelled(self, prev: np.ndarray, tip: np.ndarray, s: SyncResult) -> tuple[np.ndarray, np.ndarray]:
        """The path from the last tip to this one: points (k+1, 3) mm and the program row of
        each piece (k,) int64.

        When both ends sit on the program, between two polls the machine followed the
        program, not the chord: the program's corners passed in between are inserted,
        moved by the live deviation from the program (interpolated between the two ends,
        so a machine running with a shifted work offset is followed where it really is),
        except along an axis the program does not move between a corner and a polled end:
        there the corner has that end's coordinate (:func:`hold_still_axes`). Otherwise the
        straight chord, on the current row.
        """
        last = self.last_sync
        if (last is None or s.how not in ("track", "line") or last.how == "lost"
                or s.distance > self.sync.lost or s.progress <= last.progress):
            return np.stack([prev, tip]), np.array([s.row], np.int64)
        path = self.path
        k0, k1 = path.segment_at(last.progress), path.segment_at(s.progress)
        t1 = path.t1[k0:k1]
        keep = np.nonzero((t1 > last.progress) & (t1 < s.progress))[0]
        if keep.size == 0:
            return np.stack([prev, tip]), np.array([path.row[k1]], np.int64)
        d0 = self._deviation(prev, last.progress)
        d1 = self._deviation(tip, s.progress)
        f = (t1[keep] - last.progress) / (s.progress - last.progress)
        corners = path.p1[k0 + keep] + d0 + f[:, None] * (d1 - d0)
        # the segments are consecutive: piece q runs along segment segs[q]
        segs = np.concatenate([k0 + keep, [k1]])
        pts = hold_still_axes(np.concatenate([prev[None], corners, tip[None]]),
                              path.p0[segs] != path.p1[segs])
        return pts, path.row[segs].astype(np.int64)

    def _travelled_angles(self, a0: np.ndarray, a1: np.ndarray, count: int, s: SyncResult) -> np.ndarray:
        """Work A B C (count, 3) deg at the points :meth:`_travelled` gave: ``a0`` at the
        first, ``a1`` at the last, the program's angles at the corners between (moved by
        the live deviation, interpolated as the corners' positions are)."""
        out = np.empty((count, 3))
        out[0], out[-1] = a0, a1
        if count > 2:
            path, sp, scale = self.path, self.sync_path, self.rotary_scale
            last = self.last_sync
            k0, k1 = path.segment_at(last.progress), path.segment_at(s.progress)
            t1 = path.t1[k0:k1]
            keep = np.nonzero((t1 > last.progress) & (t1 < s.progress))[0]
            d0 = a0 - sp.point_at(last.progress)[3:] / scale
            d1 = a1 - sp.point_at(s.progress)[3:] / scale
            f = (t1[keep] - last.progress) / (s.progress - last.progress)
            out[1:-1] = sp.p1[k0 + keep, 3:] / scale + d0 + f[:, None] * (d1 - d0)
        return out

    def _deviation(self, tip: np.ndarray, progress: float) -> np.ndarray:
        """The live tip minus the program's tip at ``progress``, (3,) mm.

        Components within the tolerance's ``length`` are 0: they are the rounding of
        ``point_at``'s interpolation, not a machine off the program. Kept, they would put
        every inserted corner an ulp beside the program's corner: the piece arriving there
        would stop just short of the rays at exactly the tool radius from it, and the next
        row (a retract at the same XY, from the exactly polled tip) would be the first to
        cut them -- a false rapid into stock."""
        d = np.asarray(tip, np.float64) - self.path.point_at(progress)
        d[np.abs(d) <= self.wp.tol.length] = 0.0
        return d

    def _predict(self, s: SyncResult, state: MachineState) -> list[dict]:
        if self._fill_horizon:
            self._fill_horizon = False
            found = self.lookahead.advance(s.progress, budget_rays=math.inf)
        else:
            found = self.lookahead.advance(s.progress)
        ovr = state.overrides[0] if state.overrides else 100
        out = []
        for f in found:
            rec = finding_record(f, lead_time(f, self.path, s.progress, ovr), state.t, path=self.path,
                                 moves=self.moves)
            late = self.lookahead.late_s(f, s.progress)
            if late > 0:
                rec["late_s"] = round(late, 3)
                rec["lead_note"] = f"predicted {late:.1f} s late: the monitor fell behind the machine"
            elif not rec["lead_time_s"]:
                rec["lead_note"] = "predicted as the machine reached it (the monitor started or re-synced there)"
            out.append(rec)
        return out

    def _alert(self, records: list[dict], state: MachineState) -> list[dict]:
        """Offer findings to the alerter (each alerted once; a predicted one that then
        happens on the live model is updated, not alerted again)."""
        fresh = self.alerter.offer(records, t=state.t)
        self.findings += fresh
        return fresh

    def check_setup(self, inch: bool = False, reports_wco: bool = True, t: float | None = None) -> list[dict]:
        """Alert what cannot be the setup the user meant, before any cutting is judged
        (:mod:`monitor.setup_check`): a stock the path never reaches, a design outside the
        stock (``inch``: the program is in G20); and from now on, when the job gives a
        ``work_offset`` and the controller ``reports_wco``, a reported WCO that differs
        (once). Returns the records alerted."""
        from monitor.setup_check import WorkOffsetCheck, setup_records

        if self.job.work_offset is not None and reports_wco:
            self._offset_check = WorkOffsetCheck(self.job.work_offset, self.moves_machine, self.reference_wco)
        fresh = self.alerter.offer(setup_records(self.wp, self.moves, inch, t), t=t)
        self.findings += fresh
        return fresh

    def finish(self) -> dict:
        """Flush what is pending; return a summary dict."""
        if self._live_trace is not None:
            self._live_trace.flush(self.stage)
        summary = {"event": "summary", "findings": len(self.findings), "stages": self.stage,
                   "kinds": sorted({f["kind"] for f in self.findings}),
                   "progress_s": None if self.last_sync is None else round(self.last_sync.progress, 3),
                   "program_s": round(self.path.duration, 3), **self.counts, "gaps": list(self.gaps)}
        if self.ledger.open is not None:  # the run ended inside a gap: say so too (once)
            gap = self.ledger.close(self.ledger.open, self.last.t if self.last is not None else None, back=False)
            summary["gaps"].append(gap)
        if self.run is not None:
            self.run.put_meta("summary", summary)
            self.run.flush()
        return summary


def hold_still_axes(points: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """The travelled polyline with every axis held where the program holds it.

    ``points`` (k+1, 3) mm: the last polled tip, the program corners passed since (placed
    by an interpolated deviation), the polled tip now. ``moving`` bool (k, 3): whether the
    program moves along each axis on piece ``q`` (``points[q] -> points[q+1]``).

    Points joined by pieces that do not move along an axis share one coordinate there:
    the polled one when the run of such points reaches a polled end (both ends: only if
    they agree, else the interpolation stays), else the run's first corner's. The machine
    does not move along an axis the program holds, so that is where it was; an
    interpolated deviation would put the corner beside it -- by an ulp, enough to hand a
    retract the rays at exactly the tool radius that the feed into the corner missed, or
    by millimetres where the deviation changes between the polls (a work offset switched
    in between: the retract before the move to the next fixture drawn slanted).
    Returns a new (k+1, 3) array; the polled ends are unchanged.
    """
    out = np.array(points, np.float64)
    last = out.shape[0] - 1
    if last < 2:
        return out
    for i in range(out.shape[1]):
        run = np.concatenate([[0], np.cumsum(moving[:, i])])   # run of each point, nondecreasing
        value = out[np.searchsorted(run, run), i]              # its run's first point
        tail = run == run[-1]
        if run[-1] != 0:
            value[tail] = out[last, i]
        elif out[0, i] != out[last, i]:                         # one run from end to end
            continue
        value[0], value[last] = out[0, i], out[last, i]
        out[:, i] = value
    return out


def _spindle_rpm(state: MachineState) -> float | None:
    """The spindle speed the controller reports; None (take the program's) when it reports
    0 but its accessory flags say the spindle turns."""
    if state.spindle:
        return float(state.spindle)
    if "S" in (state.accessories or "") or "C" in (state.accessories or ""):
        return None
    return 0.0


def _fraction(path: ProgramPath, progress: float) -> float:
    """How far into its segment program time ``progress`` lies, 0..1."""
    k = path.segment_at(progress)
    dt = path.t1[k] - path.t0[k]
    return 0.0 if dt <= 0 else float(np.clip((progress - path.t0[k]) / dt, 0.0, 1.0))


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
