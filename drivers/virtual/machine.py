"""A simulated CNC machine that executes move-table rows in simulated time, as GRBL 1.1 does.

The model follows GRBL's planner and stepper (its formulas in :mod:`drivers.virtual.motion_math`,
its settings :class:`~drivers.virtual.machine_config.MachineConfig`):

* every motion row becomes one planner block (arcs become GRBL's chord segments, one
  block each, so an arc fills the planner as on the real firmware);
* a block's nominal speed is the programmed feed x feed override (rapids: the axis
  maximum rate x rapid override), limited per axis by ``max_rate``; its acceleration
  is limited per axis by ``accel`` (GRBL ``limit_value_by_axis_maximum``);
* the speed allowed through the junction of two blocks follows GRBL's junction
  deviation formula ``v^2 = a * delta * sin(theta/2) / (1 - sin(theta/2))``;
* look-ahead re-planning (backward then forward pass over the queued blocks) runs
  whenever a block is queued or an override changes;
* the current block runs a trapezoidal (or triangular) profile, integrated exactly (no
  time step error), so ``advance`` is deterministic and independent of how simulated
  time is sliced.

Units: positions mm (A B C degrees, treated like mm in path length), speeds inside the
class mm/s, feeds in rows and states mm/min, accelerations mm/s^2, time s.

Thread safety: the machine itself is not thread-safe; callers that share it between
threads (the real-time runner and the protocol peers) hold ``vm.lock``.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from drivers.state import MachineState, RunState
from drivers.virtual.machine_config import MachineConfig
from drivers.virtual.motion_math import LEN_EPS, arc_points, junction_speed_sqr, limit_by_axis
from sim.gcode.moves import COOLANT_FLOOD, COOLANT_MIST, MOVE_DTYPE, MoveKind

#: GRBL's MINIMUM_FEED_RATE (mm/min): no block is planned slower than this
MIN_FEED_MM_MIN = 1.0
#: speeds below this (mm/s) are standstill (lengths: motion_math.LEN_EPS)
_V_EPS = 1e-9

#: GRBL alarm codes used here
ALARM_SOFT_LIMIT = 2
ALARM_ABORT_CYCLE = 3


class PlannerFull(Exception):
    """More rows were queued than the planner has free blocks."""


class MachineLocked(Exception):
    """A motion was queued while the machine is in alarm (GRBL answers ``error:9``)."""


class TravelExceeded(ValueError):
    """A jog target lies outside the machine's travel (GRBL answers ``error:15``)."""


@dataclass
class _Block:
    """One planner block: a straight motion, or a zero-length sync action (dwell, pause ...)."""

    row: np.void                 # the MOVE_DTYPE row it came from
    start: np.ndarray            # (6,) mm
    end: np.ndarray              # (6,) mm
    length: float                # mm
    unit: np.ndarray             # (6,)
    rapid: bool
    programmed: float            # mm/s (feed, or axis-limited max rate for rapids)
    rate_limit: float            # mm/s, axis-limited maximum rate along unit
    accel: float                 # mm/s^2
    max_junction_sqr: float = 0.0
    nominal_sqr: float = 0.0
    max_entry_sqr: float = 0.0
    entry_sqr: float = 0.0
    remaining: float = 0.0       # mm left to run
    action: str = "move"         # move | dwell | pause | end | sync
    dwell_left: float = 0.0      # s
    last_of_row: bool = True     # block_done fires after the last segment of a row
    jog: bool = False


@dataclass
class WorkOffsets:
    """Offsets the machine knows (for GRBL ``$#``), each a 6-tuple mm except TLO."""

    g5x: dict[str, tuple[float, ...]] = field(
        default_factory=lambda: {f"G{n}": (0.0,) * 6 for n in (54, 55, 56, 57, 58, 59)}
    )
    g28: tuple[float, ...] = (0.0,) * 6
    g30: tuple[float, ...] = (0.0,) * 6
    g92: tuple[float, ...] = (0.0,) * 6
    tlo: float = 0.0
    prb: tuple[float, ...] = (0.0,) * 6
    prb_ok: bool = False
    active: str = "G54"


class VirtualMachine:
    """A deterministic GRBL-like machine in simulated time (see module docstring).

    Parameters
    ----------
    config : MachineConfig
    position : array-like of up to 6 floats, initial machine position, mm
    """

    def __init__(self, config: MachineConfig | None = None, position=None):
        self.config = config or MachineConfig()
        self.lock = threading.RLock()
        self.on_event: Callable[[str, object], None] | None = None
        #: called with the machine before each step of :meth:`advance` (under its lock), or
        #: None: a sender streaming the program refills the planner as blocks complete, so
        #: a long advance runs the program in its own time, not 15 blocks and then idle
        self.refill: Callable[["VirtualMachine"], None] | None = None
        self.t0 = 0.0
        self.time = 0.0
        self._rate, self._accel = self.config.axis_arrays()
        self.position = np.zeros(6)
        if position is not None:
            p = np.asarray(position, dtype=np.float64).ravel()
            self.position[: len(p)] = p
        self.work_offsets = WorkOffsets()
        self.wco = np.zeros(6)
        self.track_row_wco = True
        self.feed_override = 100
        self.rapid_override = 100
        self.spindle_override = 100
        self.state = RunState.IDLE
        self.alarm: int | None = None
        self.speed = 0.0                      # mm/s along the path
        self._blocks: deque[_Block] = deque()   # planner (head = executing)
        self._incoming: deque[_Block] = deque()  # arc segments waiting for room
        self._planned_end = self.position.copy()
        self._prev_unit: np.ndarray | None = None
        self._prev_nominal_sqr = 0.0
        self._hold = False       # feed hold requested (decelerating or held)
        self._pause = False      # M0 reached
        self._jog_cancel = False
        self._alarm_after_stop: int | None = None
        self._row: np.void | None = None       # row of the executing (or last executed) block
        self.program_ended = False

    # ------------------------------------------------------------------ queries
    @property
    def busy(self) -> bool:
        """True while blocks are queued or the machine moves."""
        return bool(self._blocks or self._incoming) or self.speed > _V_EPS

    @property
    def idle(self) -> bool:
        return self.state == RunState.IDLE and not self.busy

    def planner_free(self) -> int:
        """Free planner blocks (GRBL ``Bf:`` first number)."""
        return max(0, self.config.planner_blocks - len(self._blocks) - len(self._incoming))

    @property
    def substate(self) -> int | None:
        if self.state == RunState.HOLD:
            return 1 if self.speed > _V_EPS else 0
        return None

    def velocity(self) -> np.ndarray:
        """Axis velocities now, shape (6,) float64, mm/min (deg/min for A B C)."""
        if self.speed <= _V_EPS or not self._blocks or self._blocks[0].action != "move":
            return np.zeros(6)
        return self._blocks[0].unit * self.speed * 60.0

    def snapshot(self) -> MachineState:
        """The machine's state now; ``t`` is simulated seconds + ``t0``."""
        row = self._row
        spindle = 0.0
        acc = ""
        line = None
        if row is not None:
            line = int(row["line"]) if row["line"] > 0 else None
            direction = int(row["spindle_dir"])
            if direction and self.state not in (RunState.ALARM,):
                spindle = float(row["spindle"]) * self.spindle_override / 100.0 * direction
                acc += "S" if direction > 0 else "C"
            if int(row["coolant"]) & COOLANT_FLOOD:
                acc += "F"
            if int(row["coolant"]) & COOLANT_MIST:
                acc += "M"
        return MachineState(
            t=self.t0 + self.time,
            mpos=tuple(self.position),
            wco=tuple(self.wco),
            state=self.state,
            substate=self.substate,
            feed=self.speed * 60.0,
            spindle=spindle,
            line=line,
            overrides=(self.feed_override, self.rapid_override, self.spindle_override),
            alarm=self.alarm if self.state == RunState.ALARM else None,
            buffer=(self.planner_free(), 128),
            accessories=acc,
        )

    # ------------------------------------------------------------------ commands
    def queue(self, rows) -> None:
        """Append move-table rows (MOVE_DTYPE) to the planner.

        Motion starts at once unless the machine is held. A row whose target is outside
        the soft limits raises ALARM:2 instead (before it moves, as GRBL checks targets
        when planning): the machine stops, the planner is flushed, the rest is dropped.

        Raises
        ------
        PlannerFull : more rows than :meth:`planner_free`
        MachineLocked : the machine is in alarm
        """
        rows = np.atleast_1d(np.asarray(rows))
        if rows.dtype != MOVE_DTYPE:
            raise TypeError(f"queue() expects MOVE_DTYPE rows, got {rows.dtype}")
        if self.state == RunState.ALARM:
            raise MachineLocked("machine is in alarm: unlock ($X) or reset first")
        if len(rows) > self.planner_free():
            raise PlannerFull(f"{len(rows)} rows queued, {self.planner_free()} planner blocks free")
        if self.state == RunState.JOG:
            raise MachineLocked("machine is jogging: cancel the jog first")
        for row in rows:
            blocks = self._blocks_for_row(row)
            if blocks is None:  # soft limit
                return
            for b in blocks:
                self._incoming.append(b)
        self.program_ended = False
        self._feed_planner()
        if self.state == RunState.IDLE and (self._blocks or self._incoming):
            self.state = RunState.RUN

    def feed_hold(self) -> None:
        """GRBL ``!``: decelerate along the path (Hold:1) and stop (Hold:0)."""
        if self.state in (RunState.ALARM, RunState.HOLD, RunState.SLEEP):
            return
        if self.state == RunState.JOG:
            self.cancel_jog()
            return
        self._hold = True
        self.state = RunState.HOLD
        self._emit("hold", None)

    def resume(self) -> None:
        """GRBL ``~``: leave a hold (or an M0 pause) and carry on."""
        if self.state != RunState.HOLD or self.speed > _V_EPS:
            return  # GRBL ignores cycle start until the hold is complete
        self._hold = False
        self._pause = False
        self.state = RunState.RUN if (self._blocks or self._incoming) else RunState.IDLE
        self._replan()

    def reset(self) -> None:
        """GRBL Ctrl-X: stop at once, flush the planner; during motion -> ALARM:3.
        Position is kept; overrides return to 100 %."""
        moving = self.speed > _V_EPS or (self.state in (RunState.RUN, RunState.JOG) and self.busy)
        self._flush()
        self.feed_override = self.rapid_override = self.spindle_override = 100
        if moving:
            self._raise_alarm(ALARM_ABORT_CYCLE)
        elif self.state != RunState.ALARM:
            self.state = RunState.IDLE

    def unlock(self) -> None:
        """GRBL ``$X``: leave the alarm state."""
        if self.state == RunState.ALARM:
            self.state = RunState.IDLE
            self.alarm = None

    def power_cycle(self) -> None:
        """The controller restarted (fault injection): planner flushed, position lost
        (0 on every axis, as GRBL starts), in alarm until homed or unlocked (no code)."""
        self._flush()
        self.position[:] = 0.0
        self._planned_end = self.position.copy()
        self._prev_unit = None
        self.feed_override = self.rapid_override = self.spindle_override = 100
        self.state = RunState.ALARM
        self.alarm = None
        self._row = None

    def raise_alarm(self, code: int) -> None:
        """Inject an alarm (fault injection): stop at once, flush, state Alarm."""
        self._flush()
        self._raise_alarm(int(code))

    def set_feed_override(self, pct: int) -> None:
        """Feed override, percent, clamped to GRBL's 10..200."""
        self.feed_override = int(min(200, max(10, pct)))
        self._replan()

    def set_rapid_override(self, pct: int) -> None:
        """Rapid override: GRBL allows 100, 50 or 25 percent; other values are clamped to 25..100."""
        self.rapid_override = int(min(100, max(25, pct)))
        self._replan()

    def set_spindle_override(self, pct: int) -> None:
        """Spindle override, percent, clamped to GRBL's 10..200."""
        self.spindle_override = int(min(200, max(10, pct)))

    def jog(self, target, feed: float) -> None:
        """GRBL ``$J=``: move to ``target`` (machine coords, up to 6 values, mm) at
        ``feed`` mm/min. Raises :class:`TravelExceeded` outside the soft limits and
        :class:`MachineLocked` unless Idle or jogging."""
        if self.state not in (RunState.IDLE, RunState.JOG):
            raise MachineLocked(f"cannot jog in state {self.state.value}")
        tgt = self._planned_end.copy()
        t = np.asarray(target, dtype=np.float64).ravel()
        tgt[: len(t)] = t
        if self.config.out_of_travel(tgt):
            raise TravelExceeded(f"jog target {tuple(np.round(tgt[:3], 3))} is outside the travel")
        if self.planner_free() < 1:
            raise PlannerFull("planner full")
        from sim.gcode.moves import empty_moves

        row = empty_moves(1)[0]
        row["kind"] = MoveKind.FEED
        row["start"] = self._planned_end
        row["end"] = tgt
        # a jog keeps the work offset in force (else track_row_wco would take end - 0)
        row["wco"] = self.wco
        row["feed"] = float(feed)
        if self._row is not None:
            for k in ("spindle", "spindle_dir", "coolant", "tool"):
                row[k] = self._row[k]
        blocks = self._blocks_for_row(row, jog=True)
        for b in blocks or []:
            self._incoming.append(b)
        self._feed_planner()
        if self._blocks:
            self.state = RunState.JOG

    def cancel_jog(self) -> None:
        """GRBL 0x85: decelerate the jog to a stop and drop what is left of it."""
        if self.state == RunState.JOG:
            self._jog_cancel = True

    def set_wco(self, offset) -> None:
        """Set the work coordinate offset in force (reported as WCO), mm, up to 6 values."""
        off = np.asarray(offset, dtype=np.float64).ravel()
        self.wco = np.zeros(6)
        self.wco[: len(off)] = off

    # ------------------------------------------------------------------ time
    def advance(self, dt: float) -> None:
        """Run the machine for ``dt`` simulated seconds."""
        if dt < 0:
            raise ValueError("dt must be >= 0")
        start, left = self.time, float(dt)
        guard = 0  # steps in a row that took no time
        while left > 0.0:
            guard += 1
            if guard > 1_000_000:  # a bug, not a state a user can reach
                raise RuntimeError("virtual machine made no progress")
            if self.refill is not None:
                self.refill(self)
            used = self._step(left)
            if used is None:  # nothing to do: time passes standing still
                break
            left -= used
            guard = 0 if used > 0.0 else guard  # a long advance runs many blocks
            self.time = start + (dt - left)  # events in the step are stamped when they happen
        self.time = start + dt

    def _step(self, budget: float) -> float | None:
        """Advance through at most one phase of the current block; returns time used
        (s), or None when the machine stands still for the rest of ``budget``."""
        if self.state == RunState.ALARM or self.state == RunState.SLEEP:
            self.speed = 0.0
            return None
        self._feed_planner()
        stopping = self._hold or self._jog_cancel
        if stopping and (self.speed <= _V_EPS or not self._blocks):
            self.speed = 0.0
            if self._jog_cancel:
                self._flush()
                self._jog_cancel = False
                self.state = RunState.IDLE
                self._emit("idle", None)
            elif self._alarm_after_stop is not None:
                code = self._alarm_after_stop
                self._flush()
                self._raise_alarm(code)
            return None
        if not self._blocks:
            self.speed = 0.0
            self._go_idle()
            return None
        blk = self._blocks[0]
        if blk.action != "move":
            return self._step_action(blk, budget)
        if self._row is None or self._row is not blk.row:
            self._begin_row(blk)
        if stopping:
            return self._step_decel(blk, budget)
        ve = math.sqrt(self._blocks[1].entry_sqr) if len(self._blocks) > 1 else 0.0
        return self._step_profile(blk, budget, ve)

    def _step_action(self, blk: _Block, budget: float) -> float | None:
        self.speed = 0.0
        self._row = blk.row
        if blk.action == "dwell":
            if blk.dwell_left > budget:
                blk.dwell_left -= budget
                return budget
            used = blk.dwell_left
            self._finish_block()
            return used
        if blk.action == "pause":
            self._finish_block()
            self._pause = True
            self._hold = True
            self.state = RunState.HOLD
            self._emit("pause", blk.row)
            return 0.0
        if blk.action == "end":
            self._finish_block()
            self.program_ended = True
            self._emit("program_end", blk.row)
            return 0.0
        self._finish_block()
        return 0.0

    def _begin_row(self, blk: _Block) -> None:
        self._row = blk.row
        if self.track_row_wco:
            wco = np.asarray(blk.row["wco"])
            if np.all(np.isfinite(wco)):
                self.wco = wco.astype(np.float64)

    def _move(self, dist: float, blk: _Block) -> None:
        dist = min(max(dist, 0.0), blk.remaining)
        blk.remaining -= dist
        if blk.remaining <= LEN_EPS:
            blk.remaining = 0.0
            self.position = blk.end.copy()
        else:
            self.position = blk.end - blk.unit * blk.remaining

    def _step_decel(self, blk: _Block, budget: float) -> float:
        """Feed hold / jog cancel: decelerate at the block's acceleration, across blocks."""
        v, a, s = self.speed, blk.accel, blk.remaining
        d_stop = v * v / (2 * a)
        if d_stop < s - LEN_EPS:
            t_stop = v / a
            if budget >= t_stop:
                self._move(d_stop, blk)
                self.speed = 0.0
                return t_stop
            self._move(v * budget - 0.5 * a * budget * budget, blk)
            self.speed = v - a * budget
            return budget
        # the block ends before the stop: run to its end decelerating
        disc = max(v * v - 2 * a * s, 0.0)
        t_end = (v - math.sqrt(disc)) / a
        if budget >= t_end:
            self._move(s, blk)
            self.speed = math.sqrt(disc)
            self._finish_block()
            return t_end
        self._move(v * budget - 0.5 * a * budget * budget, blk)
        self.speed = v - a * budget
        return budget

    def _step_profile(self, blk: _Block, budget: float, ve: float) -> float:
        """One phase of the trapezoid: accelerate, cruise or decelerate."""
        v, a, s = self.speed, blk.accel, blk.remaining
        vn = math.sqrt(blk.nominal_sqr)
        ve = min(ve, math.sqrt(v * v + 2 * a * s))
        s_dec = (v * v - ve * ve) / (2 * a)
        if s <= LEN_EPS:
            self._move(s, blk)
            self._finish_block()
            return 0.0
        if s <= s_dec + 1e-9 * max(1.0, s):
            # decelerating to the exit speed until the end of the block
            disc = max(v * v - 2 * a * s, 0.0)
            # rounding leaves disc ~1e-13 where it should be ve^2: snap to the planned exit
            v_end = math.sqrt(disc) if disc > ve * ve + 1e-9 * v * v else ve
            t_end = 2 * s / (v + v_end) if v + v_end > 0 else 0.0
            if budget >= t_end:
                self._move(s, blk)
                self.speed = v_end
                self._finish_block()
                return t_end
            # constant deceleration a' that ends at v_end after s
            a_eff = (v * v - v_end * v_end) / (2 * s) if s > 0 else a
            self._move(v * budget - 0.5 * a_eff * budget * budget, blk)
            self.speed = max(v - a_eff * budget, 0.0)
            return budget
        if v < vn - _V_EPS:
            v_peak = min(vn, math.sqrt(max((2 * a * s + v * v + ve * ve) / 2, 0.0)))
            t_acc = (v_peak - v) / a
            if t_acc <= 1e-15:
                return self._cruise(blk, budget, v, s, s_dec)
            if budget >= t_acc:
                self._move((v_peak * v_peak - v * v) / (2 * a), blk)
                self.speed = v_peak
                return t_acc
            self._move(v * budget + 0.5 * a * budget * budget, blk)
            self.speed = v + a * budget
            return budget
        if v > vn + _V_EPS:
            # override lowered: slow down to the new nominal speed
            t_dec = (v - vn) / a
            if budget >= t_dec:
                self._move((v * v - vn * vn) / (2 * a), blk)
                self.speed = vn
                return t_dec
            self._move(v * budget - 0.5 * a * budget * budget, blk)
            self.speed = v - a * budget
            return budget
        return self._cruise(blk, budget, vn, s, s_dec)

    def _cruise(self, blk: _Block, budget: float, v: float, s: float, s_dec: float) -> float:
        if v <= _V_EPS:  # nothing can move us (should not happen: vn >= MIN_FEED)
            self._move(s, blk)
            self._finish_block()
            return 0.0
        d = max(s - s_dec, 0.0)
        t = d / v
        self.speed = v
        if budget >= t:
            self._move(d, blk)
            if blk.remaining <= LEN_EPS:
                self._finish_block()
            return t
        self._move(v * budget, blk)
        return budget

    def _finish_block(self) -> None:
        blk = self._blocks.popleft()
        self._feed_planner()
        if blk.last_of_row and not blk.jog:
            self._emit("block_done", blk.row)
        if not self._blocks and not self._incoming and self.state in (RunState.RUN, RunState.JOG):
            self._go_idle()

    def _go_idle(self) -> None:
        if self.state in (RunState.RUN, RunState.JOG):
            self.state = RunState.IDLE
            self.speed = 0.0
            self._jog_cancel = False
            self._emit("idle", None)

    # ------------------------------------------------------------------ planning
    def _feed_planner(self) -> None:
        moved = False
        while self._incoming and len(self._blocks) < self.config.planner_blocks:
            self._blocks.append(self._incoming.popleft())
            moved = True
        if moved:
            self._replan()

    def _blocks_for_row(self, row, jog: bool = False) -> list[_Block] | None:
        kind = int(row["kind"])
        start = self._planned_end.copy()
        if kind == MoveKind.DWELL:
            return [self._action_block(row, "dwell", dwell=float(row["dwell"]))]
        if kind == MoveKind.END:
            return [self._action_block(row, "end")]
        if kind in (MoveKind.PAUSE, MoveKind.TOOL_CHANGE):
            action = self._action_block(row, "pause" if kind == MoveKind.PAUSE else "sync")
            # one that moves (rs274 re-reading its position after a tool change, G88's manual
            # retract): the stop, then a traverse to the row's end
            end = np.asarray(row["end"], dtype=np.float64)
            move = self._motion_block(row, start, end, float(np.linalg.norm(end - start)), jog)
            if move is None:
                return [action]
            if self.config.out_of_travel(end):
                self._soft_limit()
                return None
            action.last_of_row = False
            self._planned_end = end.copy()
            return [action, move]
        if kind in (MoveKind.ARC_CW, MoveKind.ARC_CCW):
            points = arc_points(start, np.asarray(row["end"], dtype=np.float64), np.asarray(row["center"]),
                                int(row["plane"]), kind == MoveKind.ARC_CW, max(int(row["turns"]), 1),
                                self.config.arc_tolerance)
        else:
            points = np.asarray(row["end"], dtype=np.float64)[None, :]
        for p in points:
            if self.config.out_of_travel(p):
                self._soft_limit()
                return None
        blocks: list[_Block] = []
        # inverse time: the whole row lasts 1/inverse_time minutes
        total_len = 0.0
        prev = start
        for p in points:
            total_len += float(np.linalg.norm(p - prev))
            prev = p
        prev = start
        for i, p in enumerate(points):
            b = self._motion_block(row, prev, p, total_len, jog)
            if b is not None:
                b.last_of_row = False
                blocks.append(b)
            prev = p
        self._planned_end = np.asarray(points[-1], dtype=np.float64).copy()
        if not blocks:
            return [self._action_block(row, "sync")]
        blocks[-1].last_of_row = True
        return blocks

    def _action_block(self, row, action: str, dwell: float = 0.0) -> _Block:
        p = self._planned_end.copy()
        self._prev_unit = None  # motion after a sync starts from rest
        self._prev_nominal_sqr = 0.0
        return _Block(row=row, start=p, end=p, length=0.0, unit=np.zeros(6), rapid=False,
                      programmed=0.0, rate_limit=0.0, accel=1.0, action=action, dwell_left=dwell)

    def _motion_block(self, row, start: np.ndarray, end: np.ndarray, row_len: float, jog: bool) -> _Block | None:
        delta = end - start
        length = float(np.linalg.norm(delta))
        if length <= LEN_EPS:
            return None
        unit = delta / length
        rate_limit = limit_by_axis(self._rate, unit)
        accel = limit_by_axis(self._accel, unit)
        rapid = int(row["kind"]) == MoveKind.RAPID
        if rapid or float(row["feed"]) <= 0 and float(row["inverse_time"]) <= 0:
            programmed = rate_limit
            rapid = True
        elif float(row["inverse_time"]) > 0:
            programmed = row_len * float(row["inverse_time"]) / 60.0
        else:
            programmed = float(row["feed"]) / 60.0
        b = _Block(row=row, start=start.copy(), end=end.copy(), length=length, unit=unit, rapid=rapid,
                   programmed=programmed, rate_limit=rate_limit, accel=accel, remaining=length, jog=jog)
        if self._prev_unit is None:
            b.max_junction_sqr = 0.0
        else:
            b.max_junction_sqr = junction_speed_sqr(self._prev_unit, unit, self._accel,
                                                    self.config.junction_deviation)
        self._prev_unit = unit
        return b

    def _nominal_sqr(self, b: _Block) -> float:
        if b.action != "move":
            return 0.0
        if b.rapid:
            v = b.programmed * self.rapid_override / 100.0
        else:
            v = b.programmed * (100.0 if b.jog else self.feed_override) / 100.0
            v = min(v, b.rate_limit)
        v = max(v, MIN_FEED_MM_MIN / 60.0)
        return v * v

    def _replan(self) -> None:
        """GRBL look-ahead: nominal speeds, junction limits, backward and forward passes.
        The executing block's entry is the current speed."""
        blocks = self._blocks
        if not blocks:
            return
        prev_nom = None
        for i, b in enumerate(blocks):
            b.nominal_sqr = self._nominal_sqr(b)
            if b.action != "move":
                b.max_entry_sqr = 0.0
            elif prev_nom is None:
                b.max_entry_sqr = min(b.max_junction_sqr, b.nominal_sqr) if i > 0 else b.nominal_sqr
            else:
                b.max_entry_sqr = min(b.max_junction_sqr, b.nominal_sqr, prev_nom)
            prev_nom = b.nominal_sqr if b.action == "move" else None
            if b.action == "move" and i > 0 and blocks[i - 1].action != "move":
                b.max_entry_sqr = 0.0
        # the block after the last queued one is unknown: plan to stop at the end
        nxt = 0.0
        for b in reversed(list(blocks)[1:]):
            if b.action != "move":
                b.entry_sqr = 0.0
                nxt = 0.0
                continue
            b.entry_sqr = min(b.max_entry_sqr, nxt + 2 * b.accel * b.length)
            nxt = b.entry_sqr
        head = blocks[0]
        head.entry_sqr = self.speed * self.speed
        prev_exit_cap = self.speed * self.speed + (2 * head.accel * head.remaining if head.action == "move" else 0.0)
        if head.action != "move":
            prev_exit_cap = 0.0
        for b in list(blocks)[1:]:
            if b.action != "move":
                prev_exit_cap = 0.0
                continue
            b.entry_sqr = min(b.entry_sqr, prev_exit_cap)
            prev_exit_cap = b.entry_sqr + 2 * b.accel * b.length

    # ------------------------------------------------------------------ alarms
    def _soft_limit(self) -> None:
        """A target outside the travel: GRBL holds (if moving) then ALARM:2, planner flushed."""
        self._incoming.clear()
        if self.speed > _V_EPS:
            self._hold = True
            self.state = RunState.HOLD
            self._alarm_after_stop = ALARM_SOFT_LIMIT
        else:
            self._flush()
            self._raise_alarm(ALARM_SOFT_LIMIT)

    def _flush(self) -> None:
        self._blocks.clear()
        self._incoming.clear()
        self.speed = 0.0
        self._hold = False
        self._pause = False
        self._jog_cancel = False
        self._alarm_after_stop = None
        self._planned_end = self.position.copy()
        self._prev_unit = None

    def _raise_alarm(self, code: int) -> None:
        self.state = RunState.ALARM
        self.alarm = code
        self._emit("alarm", code)

    def _emit(self, name: str, payload) -> None:
        if self.on_event is not None:
            self.on_event(name, payload)
