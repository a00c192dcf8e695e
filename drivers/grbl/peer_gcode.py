"""G-code lines for the GRBL peer, executed as Grbl 1.1h's gc_execute_line / mc_line do.

:class:`GcodeExecution` is a mixin of :class:`~drivers.grbl.peer.GrblPeer`: a line goes
through the interpreter (``sim.gcode``, grbl dialect); spindle, coolant and offset changes
wait until the planner is empty (``protocol_buffer_synchronize``) and act before the
line's own motion; motion rows go to the machine's planner one by one, the line's ``ok``
waiting for room (``mc_line``); M2/M30 end the program as gcode.c does.
"""

from __future__ import annotations

import re

import numpy as np

from drivers.grbl.peer_system import interp_offsets
from drivers.state import RunState
from sim.gcode.moves import MoveKind

_N_WORD = re.compile(r"^N(\d+)")
_WORD = re.compile(r"([A-Z])([-+]?[0-9.]*)")


class GcodeExecution:
    """G-code execution (mixed into GrblPeer, which provides ``vm``, ``interpreter``,
    ``cadence``, ``accessories``, ``_reply``, ``_check_mode``, ``_critical``,
    ``_reset_gen``, ``_stop``, ``_seq`` and ``_n_words``)."""

    def _gcode(self, text: str, clean: str, gen: int) -> str | None:
        """Run one G-code line (``text`` as sent, ``clean`` as GRBL keeps it); return its
        reply, None when a reset (``gen`` changed) or a limit alarm swallowed it."""
        interp = self.interpreter
        if interp is None:
            self._reply("[MSG:dexmon peer has no G-code interpreter (sim.gcode missing)]")
            return "error:20"
        self._seq += 1
        seq = self._seq
        m = _N_WORD.match(clean)
        if m:
            self._n_words[seq] = int(m.group(1))
        from sim.gcode.errors import GCodeError

        with self.vm.lock:
            if not self.vm.busy and hasattr(interp, "set_position"):
                # after a jog, a hold-and-reset or a reset mid-move the parser takes the
                # machine's position (GRBL's gc_sync_position)
                interp.set_position(self.vm.position)
        before = _sync_key(interp)
        coord_before, tlo_before = getattr(interp, "coord", 0), tuple(getattr(interp, "tlo", ()))
        try:
            rows = interp.execute_line(text, seq)
        except GCodeError as exc:
            return f"error:{exc.grbl_code or 20}"
        except (ValueError, ArithmeticError) as exc:
            self._reply(f"[MSG:dexmon peer: {exc}]")
            return "error:20"
        rows = np.atleast_1d(np.asarray(rows)) if rows is not None else np.zeros(0)
        words = _words(clean)
        wco_flag = _flags_wco_change(words, coord_before, tlo_before, interp, self._check_mode)
        if self._check_mode:
            # spindle_sync, coolant_sync and mc_line do nothing in check mode, but the parser's
            # offsets change (and G10 / G28.1 / G30.1 write the EEPROM)
            self._sync_offsets_from_interpreter(wco_flag)
            return "ok"
        outputs = _accessory_outputs(interp)
        if _sync_key(interp) != before or wco_flag or outputs != self.accessories.outputs():
            # spindle, coolant and offset changes wait for the motion before them
            # (protocol_buffer_synchronize), then act before the line's own motion
            if not self._wait_motion_done(gen):
                return None
            self._set_accessories(outputs)
            self._sync_offsets_from_interpreter(wco_flag)
        # M0 / M1 are program flow here, not planner blocks: M0 pauses below, M1 is ignored
        rows = rows[rows["kind"] != MoveKind.PAUSE] if len(rows) else rows
        reply = "ok"
        if len(rows):
            reply = self._queue(rows, gen)
            if reply == "ok" and np.any(rows["kind"] == MoveKind.DWELL):
                # G4 syncs: its ok comes when the dwell is over (senders use G4 P0 to sync)
                if not self._wait_motion_done(gen):
                    return None
        if reply == "ok" and ("M", 0.0) in words:
            return self._program_pause(gen)
        if reply == "ok" and (("M", 2.0) in words or ("M", 30.0) in words):
            if not self._wait_motion_done(gen):
                return None
            self._program_end()
        return reply

    def _program_pause(self, gen: int) -> str | None:
        """M0 (gcode.c): the planner empties, then a feed hold suspends the main loop inside
        this line; its ok comes after cycle start (``~``). None on a reset."""
        if not self._wait_motion_done(gen):
            return None
        vm = self.vm
        with vm.lock:
            if vm.state == RunState.ALARM:
                return None if self._critical else "ok"
            vm.feed_hold()  # from Idle: Hold:0 at once
        while gen == self._reset_gen and not self._stop.is_set():
            with vm.lock:
                if vm.state != RunState.HOLD:
                    return "ok"
            self._stop.wait(0.002)  # '~' comes through the real-time path
        return None

    def _set_accessories(self, outputs: tuple[int, float, int]) -> None:
        """Spindle and coolant outputs to the parser's M3/M4/M5, S, M7/M8/M9; a change is
        reported at once (spindle_set_state / coolant_set_state reset the Ov counter)."""
        if outputs != self.accessories.outputs():
            self.accessories.direction, self.accessories.rpm, self.accessories.coolant = outputs
            self.cadence.flag_ovr()

    def _program_end(self) -> None:
        """M2 / M30 (gcode.c): overrides back to 100 % (RESTORE_OVERRIDES_AFTER_PROGRAM_END),
        the work offset re-read and reported at once."""
        vm = self.vm
        with vm.lock:
            vm.set_feed_override(100)
            vm.set_rapid_override(100)
            vm.set_spindle_override(100)
        self.cadence.flag_wco()

    def _wait_motion_done(self, gen: int) -> bool:
        """Wait until the planner is empty and the machine stands; False on reset."""
        vm = self.vm
        while gen == self._reset_gen and not self._stop.is_set():
            with vm.lock:
                if not vm.busy or vm.state == RunState.ALARM:
                    return True
            self._stop.wait(0.002)  # the runner moves the machine on meanwhile
        return False

    def _queue(self, rows: np.ndarray, gen: int) -> str | None:
        vm = self.vm
        from drivers.virtual.machine import MachineLocked, PlannerFull

        for row in rows:
            # the line's ok waits until its block fits in the planner (mc_line blocks)
            while True:
                if gen != self._reset_gen or self._stop.is_set():
                    return None
                with vm.lock:
                    if vm.state == RunState.ALARM:
                        return None if self._critical else "error:9"
                    if vm.planner_free() >= 1:
                        limit = bool(vm.config.soft_limits and vm.config.out_of_travel(np.asarray(row["end"])))
                        try:
                            vm.queue(row)
                        except PlannerFull:
                            continue
                        except MachineLocked:
                            return "error:9"
                        break
                self._stop.wait(0.002)  # the runner frees blocks as time passes
            if limit:
                # soft limit: ALARM:2 (now or after the hold), no reply, wait for a reset
                self._critical = True
                return None
        return "ok"

    def _sync_offsets_from_interpreter(self, wco_flag: bool) -> None:
        """G10/G92/G43.1/G5x change offsets once the planner is empty (the caller waited);
        ``wco_flag``: the firmware's system_flag_wco_change (WCO in the next report)."""
        interp = self.interpreter
        wco = _interp_wco(interp)
        if wco is None:
            return
        vm = self.vm
        with vm.lock:
            _copy_offsets(interp, vm)
            if not vm.busy:
                vm.set_wco(wco)
        if wco_flag:
            self.cadence.flag_wco()

    def _sync_offsets_into_interpreter(self) -> None:
        """After a reset: G54..G59, G28, G30 persist (EEPROM); the parser is at the machine."""
        interp = self.interpreter
        if interp is None or not hasattr(interp, "set_work_offset"):
            return
        wo = self.vm.work_offsets
        for k in range(6):
            interp.set_work_offset(k + 1, wo.g5x[f"G{54 + k}"], "XYZABC")
        interp.set_home(28, wo.g28)
        interp.set_home(30, wo.g30)
        interp.set_position(self.vm.position)
        if not self.vm.busy:
            self.vm.set_wco(_interp_wco(interp))



def _sync_key(interp) -> tuple:
    """What GRBL synchronises the planner for when it changes: spindle, coolant, offsets."""
    try:
        return (interp.spindle_dir, interp.spindle, interp.coolant, tuple(interp.offsets()),
                tuple(interp.g28), tuple(interp.g30))
    except AttributeError:
        return ()


def _interp_wco(interp) -> np.ndarray | None:
    """The work offset the interpreter has in force (G5x + G92 + TLO), mm, shape (6,)."""
    offsets = getattr(interp, "offsets", None)
    if not callable(offsets):
        return None
    arr = np.asarray(offsets(), dtype=float).ravel()
    out = np.zeros(6)
    out[: min(6, arr.size)] = arr[:6]
    return out






def _words(clean: str) -> set[tuple[str, float]]:
    """(letter, value) of a cleaned line's words; words without a number are left out."""
    out = set()
    for letter, value in _WORD.findall(clean):
        try:
            out.add((letter, float(value)))
        except ValueError:
            continue
    return out


def _flags_wco_change(words: set[tuple[str, float]], coord_before: int, tlo_before: tuple, interp,
                      check_mode: bool) -> bool:
    """Whether GRBL calls system_flag_wco_change for this line (gcode.c): G92 / G92.1,
    another G54..G59, a changed tool length offset, G10 L2/L20 on the system in use
    (P0 or its number), M2 / M30 (not in check mode)."""
    if ("G", 92.0) in words or ("G", 92.1) in words:
        return True
    if not check_mode and (("M", 2.0) in words or ("M", 30.0) in words):
        return True
    coord = getattr(interp, "coord", 0)
    if coord != coord_before or tuple(getattr(interp, "tlo", ())) != tlo_before:
        return True
    if ("G", 10.0) in words and (("L", 2.0) in words or ("L", 20.0) in words):
        return ("P", 0.0) in words or ("P", float(coord + 1)) in words
    return False


def _accessory_outputs(interp) -> tuple[int, float, int]:
    """(direction, rpm, coolant bits) the parser's modal state asks of the outputs."""
    direction = int(getattr(interp, "spindle_dir", 0))
    return direction, float(getattr(interp, "spindle", 0.0)) if direction else 0.0, int(getattr(interp, "coolant", 0))


def _copy_offsets(interp, vm) -> None:
    offs = interp_offsets(interp)
    wo = vm.work_offsets
    for name, values in offs.items():
        vals = tuple((list(values) + [0.0] * 6)[:6])
        if name in wo.g5x:
            wo.g5x[name] = vals
        elif name == "G28":
            wo.g28 = vals
        elif name == "G30":
            wo.g30 = vals
        elif name == "G92":
            wo.g92 = vals
        elif name == "TLO" and values:
            wo.tlo = float(values[0])

