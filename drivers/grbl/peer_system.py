"""GRBL's ``$`` commands for the peer, as Grbl 1.1h's system.c runs them.

:class:`SystemCommands` is a mixin of :class:`~drivers.grbl.peer.GrblPeer`: ``$`` ``$$``
``$#`` ``$G`` ``$I`` ``$N`` ``$x=val`` ``$X`` ``$H`` ``$C`` ``$SLP`` ``$J=`` ``$RST=``.
Each returns the line's reply (``ok`` / ``error:N``; None: none) after sending what it
reports with ``self._reply``.
"""

from __future__ import annotations

import re

import numpy as np

from drivers.grbl import protocol as p
from drivers.grbl.peer_report import fmt, setting_text, settings_from_config
from drivers.state import RunState

VERSION = "1.1h.20190830"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"


class SystemCommands:
    """The ``$`` commands (system_execute_line); mixed into GrblPeer."""

    def _system(self, line: str, gen: int) -> str | None:
        vm = self.vm
        with vm.lock:
            state = vm.state
            # GRBL's sys.state: check mode is a state of its own (not Idle)
            idle_or_alarm = (state in (RunState.IDLE, RunState.ALARM) and not (state == RunState.IDLE and vm.busy)
                             and not self._check_mode)
        cmd = line[1:]
        if cmd == "":
            self._reply(HELP)
            return "ok"
        if cmd.startswith("J"):
            if state not in (RunState.IDLE, RunState.JOG) or self._check_mode:
                return "error:8"
            if not cmd.startswith("J="):
                return "error:3"
            return self._jog(cmd[2:])
        if cmd[0] in "$GCX":
            if len(cmd) != 1:  # system.c: line[2] must end the line
                return "error:3"
            if cmd == "$":
                if state in (RunState.RUN, RunState.HOLD):
                    return "error:8"
                for n in sorted(self.settings):
                    self._reply(f"${n}={setting_text(n, self.settings[n])}")
                return "ok"
            if cmd == "G":
                self._reply(self._gc_line())
                return "ok"
            if cmd == "C":
                if self._check_mode:
                    # system.c: mc_reset(), [MSG:Disabled], the line's ok; the reset (banner,
                    # parser to defaults, position kept) acts after the ok
                    self._reply("[MSG:Disabled]")
                    self._reset_after_reply = True
                    return "ok"
                if state != RunState.IDLE or not idle_or_alarm:
                    return "error:8"
                self._check_mode = True
                self._reply("[MSG:Enabled]")
                return "ok"
            if cmd == "X":
                with vm.lock:
                    if vm.state == RunState.ALARM:
                        vm.unlock()
                        self._reply("[MSG:Caution: Unlocked]")
                return "ok"
        if not idle_or_alarm:
            return "error:8"
        if cmd == "#":
            self._report_offsets()
            return "ok"
        if cmd[0] == "#":
            return "error:3"
        if cmd[0] == "H":
            if not int(self.settings.get(22, 0)):
                return "error:5"
            if cmd != "H":
                return "error:3"  # no HOMING_SINGLE_AXIS_COMMANDS in a stock build
            with vm.lock:
                vm.unlock()  # homing succeeds at the current position (no switches here)
            self._run_startup_blocks(gen)  # system.c: after a successful $H, before its ok
            return "ok"
        if cmd[0] == "S":
            if cmd != "SLP":
                return "error:3"
            self._reply("ok")
            with vm.lock:
                vm.reset()
                vm.state = RunState.SLEEP
            self._reply("[MSG:Sleeping]")
            return None
        if cmd[0] == "I":
            if cmd == "I":
                self._reply(f"[VER:{VERSION}:{self.build_info}]")
                blocks = vm.config.planner_blocks
                self._reply(f"[OPT:V{'N' if self.line_numbers else ''},{blocks},{p.RX_BUFFER_SIZE}]")
                return "ok"
            if cmd[1] != "=":
                return "error:3"
            self.build_info = cmd[2:]  # ENABLE_BUILD_INFO_WRITE_COMMAND: $I=text
            return "ok"
        if cmd[0] == "R":
            if not (cmd.startswith("RST=") and len(cmd) == 5 and cmd[4] in "$#*"):
                return "error:3"
            # settings_restore: '$' the settings, '#' the offsets kept in EEPROM (G54..G59,
            # G28, G30; G92 is not), '*' both and the startup blocks
            if cmd[4] in "$*":
                self.settings = dict(p.DEFAULT_SETTINGS)
                self.settings.update(settings_from_config(vm.config))
            if cmd[4] in "#*":
                with vm.lock:
                    wo = vm.work_offsets
                    wo.g5x = {name: (0.0,) * 6 for name in wo.g5x}
                    wo.g28 = wo.g30 = (0.0,) * 6
            if cmd[4] == "*":
                self.startup_lines = [""] * len(self.startup_lines)
                self.build_info = ""
            self._reply("[MSG:Restoring defaults]")
            # mc_reset only flags the reset: the line's ok comes first, then the banner
            self._reset_after_reply = True
            return "ok"
        if cmd[0] == "N":
            if cmd == "N":
                for i, text in enumerate(self.startup_lines):
                    self._reply(f"$N{i}={text}")
                return "ok"
            if state != RunState.IDLE:
                return "error:8"
        return self._store(line, gen)

    def _store(self, line: str, gen: int) -> str | None:
        """``$x=val`` and ``$Nx=line``: the default branch of system_execute_line, with its
        error codes in its order."""
        startup = line[1] == "N"
        read = _read_float(line, 2 if startup else 1)
        if read is None:
            return "error:2"
        parameter, i = read
        if line[i:i + 1] != "=":
            return "error:3"
        i += 1
        if startup:
            # the block runs (gc_execute_line) and is stored only if it passes
            block = line[i:]
            reply = self._gcode(block, block, gen) if block else "ok"
            if reply == "ok" and 0 <= int(parameter) < len(self.startup_lines):
                # (stock Grbl does not check the number: $N2= writes past the two blocks
                # into other EEPROM data; here it is dropped)
                self.startup_lines[int(parameter)] = block
            return reply
        read = _read_float(line, i)
        if read is None:
            return "error:2"
        num, i = read
        if i != len(line) or parameter > 255:
            return "error:3"
        # settings_store_global_setting: the sign first, then the number ((uint8_t) cast)
        if num < 0:
            return "error:4"
        n = int(parameter)
        if n not in p.DEFAULT_SETTINGS:
            return "error:3"
        if n == 0 and num < 3:
            return "error:6"
        if n == 20 and num and not int(self.settings.get(22, 0)):
            return "error:10"
        self.settings[n] = num
        if n == 13:
            self.cadence.flag_wco()  # settings.c: WCO in the new units at once
        return "ok"

    def _jog(self, body: str) -> str:
        """``$J=`` with GRBL's jog words: G20/G21 G90/G91 G53, axis words, F (required)."""
        words = re.findall(r"([A-Z])([-+]?\d*\.?\d*)", body)
        if "".join(f"{a}{b}" for a, b in words) != body:
            return "error:2"
        # words not given take the parser's modes; a jog never changes them
        interp = self.interpreter
        incremental = getattr(interp, "distance", 900) == 910
        inches = getattr(interp, "units", 210) == 200
        machine = False
        target: dict[int, float] = {}
        feed = None
        for letter, value in words:
            if value in ("", "+", "-", "."):
                return "error:2"
            v = float(value)
            if letter == "G":
                if v == 91:
                    incremental = True
                elif v == 90:
                    incremental = False
                elif v == 20:
                    inches = True
                elif v == 21:
                    inches = False
                elif v == 53:
                    machine = True
                else:
                    return "error:16"
            elif letter in "XYZ":
                target["XYZ".index(letter)] = v
            elif letter == "F":
                feed = v
            elif letter == "N":
                continue
            else:
                return "error:16"
        if feed is None:
            return "error:22"
        if not target:
            return "error:26"
        scale = p.MM_PER_INCH if inches else 1.0
        vm = self.vm
        from drivers.virtual.machine import MachineLocked, PlannerFull, TravelExceeded

        with vm.lock:
            pos = np.asarray(vm.snapshot().mpos, dtype=float)
            wco = np.asarray(vm.wco, dtype=float)
            goal = pos.copy()
            for axis, v in target.items():
                v *= scale
                if incremental:
                    goal[axis] = pos[axis] + v
                elif machine:
                    goal[axis] = v
                else:
                    goal[axis] = v + wco[axis]
            try:
                vm.jog(goal, feed * scale)
            except TravelExceeded:
                return "error:15"
            except (MachineLocked, PlannerFull):
                return "error:8"
        return "ok"

    def _report_offsets(self) -> None:
        wo = self.vm.work_offsets
        inches = int(self.settings.get(13, 0)) & 1
        scale, dec = (1.0 / p.MM_PER_INCH, 4) if inches else (1.0, 3)
        offsets = interp_offsets(self.interpreter)
        for n in (54, 55, 56, 57, 58, 59):
            name = f"G{n}"
            values = offsets.get(name, wo.g5x.get(name, (0.0,) * 6))
            self._reply(f"[{name}:{fmt(np.asarray(values[:3]) * scale, dec)}]")
        for name, values in (("G28", wo.g28), ("G30", wo.g30)):
            values = offsets.get(name, values)
            self._reply(f"[{name}:{fmt(np.asarray(values[:3]) * scale, dec)}]")
        g92 = offsets.get("G92", wo.g92)
        self._reply(f"[G92:{fmt(np.asarray(g92[:3]) * scale, dec)}]")
        tlo = offsets.get("TLO", (wo.tlo,))
        self._reply(f"[TLO:{tlo[0] * scale:.{dec}f}]")
        self._reply(f"[PRB:{fmt(np.asarray(wo.prb[:3]) * scale, dec)}:{1 if wo.prb_ok else 0}]")

    def _gc_line(self) -> str:
        words = interp_modal_words(self.interpreter)
        if words is None:
            words = "G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0"
        return f"[GC:{words}]"



_FLOAT = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")


def _read_float(line: str, i: int) -> tuple[float, int] | None:
    """nuts_bolts.c read_float at ``line[i]``: a sign, digits with at most one '.', at least
    one digit; (value, index after it), or None when there is no number."""
    m = _FLOAT.match(line, i)
    return (float(m.group()), m.end()) if m else None


def interp_offsets(interp) -> dict[str, tuple[float, ...]]:
    """``$#`` values from the interpreter: G54..G59, G28, G30, G92 (6 floats) and TLO."""
    g5x = getattr(interp, "g5x", None)
    if g5x is None:
        return {}
    out = {f"G{54 + k}": tuple(g5x[k]) for k in range(6)}
    out["G28"] = tuple(interp.g28)
    out["G30"] = tuple(interp.g30)
    out["G92"] = tuple(interp.g92)
    out["TLO"] = (float(interp.tlo[2]),)
    return out


def interp_modal_words(interp) -> str | None:
    """``$G`` words in GRBL's order: motion, WCS, plane, units, distance, feed mode, M, T F S."""
    if interp is None or not hasattr(interp, "state"):
        return None
    st = interp.state
    words = st.gcodes()[:6] + st.mcodes()
    words += [f"T{st.tool}", f"F{st.feed:.0f}", f"S{st.spindle:.0f}"]
    return " ".join(words)
