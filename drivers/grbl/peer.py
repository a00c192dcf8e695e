"""A GRBL 1.1 protocol peer: the virtual machine behind a pseudo-terminal or TCP socket.

:class:`GrblPeer` answers as Grbl 1.1h does (see ``grbl-wire-facts.md``):

* the banner after a reset, ``[MSG:'$H'|'$X' to unlock]`` after a reset in alarm;
* ``$`` ``$$`` ``$#`` ``$G`` ``$I`` ``$N`` ``$x=val`` ``$X`` ``$H`` ``$C`` ``$SLP``
  ``$J=`` ``$RST=``;
* real-time bytes taken out of the stream at once: ``?`` (a status report with the
  field order, ``$10`` mask and WCO/Ov cadence of the firmware), ``!`` ``~`` Ctrl-X,
  0x85 jog cancel, overrides 0x90-0x9D;
* a 128-byte RX buffer: bytes beyond it are dropped, as on hardware; the main loop
  takes one line out, executes it and only then reads the next, so a motion line's
  ``ok`` waits until its block fits in the planner (``vm.planner_free()``);
* G-code goes through ``sim.gcode.Interpreter(dialect="grbl")``; what it refuses gets
  the ``error:N`` of its ``GCodeError.grbl_code``;
* ``ALARM:N`` pushed as the machine raises it; a soft or hard limit is critical: the
  peer says ``[MSG:Reset to continue]`` and ignores lines until Ctrl-X.

Transports: :meth:`GrblPeer.serve_pty` (raw pseudo-terminal, returns the path a sender
opens) and :meth:`GrblPeer.serve_tcp` (returns the bound port). Both can run at once.
"""

from __future__ import annotations

import re
import threading
import time
from typing import Callable

import numpy as np

from drivers.grbl import protocol as p
from drivers.grbl.endpoints import Endpoint, PtyEndpoint, TcpEndpoint
from drivers.state import RunState
from sim.gcode.moves import MoveKind

VERSION = "1.1h.20190830"
BANNER = "Grbl 1.1h ['$' for help]"
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
LINE_BUFFER_SIZE = 80  # GRBL's line buffer: longer lines get error:11
_LINE_MEMORY = 1024  # raw bytes of one line kept (comments and spaces included)
_BYTES_PER_S = 115200 / 10  # serial line speed: 8N1 is 10 bits a byte
_BUSY = (RunState.RUN, RunState.HOLD, RunState.JOG, RunState.HOME, RunState.DOOR)
_CRITICAL_ALARMS = (1, 2)  # hard and soft limit: GRBL waits for a reset
_N_WORD = re.compile(r"^N(\d+)")


def _default_interpreter():
    # drivers -> sim.gcode is the one allowed arrow
    try:
        from sim.gcode import Interpreter
    except ImportError:
        from sim.gcode.interpreter import Interpreter

    return Interpreter(dialect="grbl", machine_units="mm")


def _fmt(values, decimals: int) -> str:
    return ",".join(f"{v:.{decimals}f}" for v in values)


class GrblPeer:
    """The virtual machine speaking GRBL 1.1 (see the module docstring).

    Parameters
    ----------
    vm : drivers.virtual.machine.VirtualMachine
    settings : dict int -> float or None
        ``$N`` settings over the defaults; ``$10`` (report mask) and ``$13`` (inches)
        change the reports, ``$22`` enables ``$H``.
    speed : float
        Simulated seconds per wall second for the machine's real-time runner.
    run : bool
        Start a :class:`~drivers.virtual.runner.RealTimeRunner` for ``vm`` (False when
        the caller advances the machine itself).
    interpreter_factory : callable() -> interpreter or None
        Makes the G-code interpreter (called again at every reset); default
        ``sim.gcode.Interpreter(dialect="grbl", machine_units="mm")``.
    line_numbers : bool
        Report ``[OPT:VN,..]`` and one planner block less, as a firmware compiled with
        line numbers does (``Ln:`` is reported whenever a block came with an N word).
    """

    def __init__(self, vm, settings: dict[int, float] | None = None, speed: float = 1.0, run: bool = True,
                 interpreter_factory: Callable[[], object] | None = None, line_numbers: bool = False):
        self.vm = vm
        self.settings = dict(p.DEFAULT_SETTINGS)
        self.settings.update(self._settings_from_config(vm.config))
        if settings:
            self.settings.update({int(k): float(v) for k, v in settings.items()})
        self.line_numbers = line_numbers
        self._make_interpreter = interpreter_factory or _default_interpreter
        self.interpreter = self._new_interpreter()
        self.startup_lines = ["", ""]
        # RX buffer and main loop
        self._rx = bytearray()          # GRBL's serial RX buffer (128 bytes)
        self._line = bytearray()        # the line the main loop is reading
        self._line_ready: bytes | None = None
        self._line_overflow = False
        self._executing = False
        self._cond = threading.Condition()
        self._reset_gen = 0
        self._critical = False
        self._check_mode = False
        self._stop = threading.Event()
        self._seq = 0
        self._n_words: dict[int, int] = {}
        # report cadence (GRBL's report_wco_counter / report_ovr_counter)
        self._wco_counter = 0
        self._ovr_counter = 0
        self._transports: list[Endpoint] = []
        self._reply_to: Endpoint | None = None
        # what the peer saw, for tests and logs
        self.received_lines: list[str] = []
        self.rx_dropped = 0
        self.status_requests = 0
        self.realtime_log: list[int] = []
        #: test hook, off (None) by default: ``mutate(data) -> data`` rewrites every line the
        #: peer sends (``\r\n`` included) before it goes out, e.g. to fuzz a driver with
        #: flipped bytes, lost or doubled replies (return ``b""`` to drop the line)
        self.mutate: Callable[[bytes], bytes] | None = None
        self._chained_event = vm.on_event
        vm.on_event = self._on_vm_event
        self.runner = None
        if run:
            from drivers.virtual.runner import RealTimeRunner

            self.runner = RealTimeRunner(vm, speed=speed).start()
        self._main = threading.Thread(target=self._main_loop, name="grbl-peer main loop", daemon=True)
        self._main.start()

    # ------------------------------------------------------------------ set-up

    @staticmethod
    def _settings_from_config(cfg) -> dict[int, float]:
        out: dict[int, float] = {11: cfg.junction_deviation, 20: 1.0 if cfg.soft_limits else 0.0}
        if getattr(cfg, "arc_tolerance", None) is not None:
            out[12] = cfg.arc_tolerance
        for i in range(3):
            if i < len(cfg.max_rate):
                out[110 + i] = cfg.max_rate[i]
            if i < len(cfg.accel):
                out[120 + i] = cfg.accel[i]
            if cfg.travel_min is not None and cfg.travel_max is not None and i < len(cfg.travel_min):
                out[130 + i] = cfg.travel_max[i] - cfg.travel_min[i]
        return out

    def _new_interpreter(self):
        try:
            return self._make_interpreter()
        except ImportError:
            return None

    # ------------------------------------------------------------------ transports

    def serve_pty(self, link: str | None = None) -> str:
        """Open a raw pseudo-terminal; return the path a sender opens.

        ``link``: also make (atomically replace) a symlink there pointing to the slave,
        a stable name across :meth:`close_transports` / ``serve_pty`` cycles, as udev's
        ``/dev/serial/by-id`` is for a USB adapter plugged again.
        """
        t = PtyEndpoint(self._receive, link)
        self._transports.append(t)
        return t.path

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (0: any free port); return the bound port."""
        t = TcpEndpoint(self._receive, host, port)
        self._transports.append(t)
        return t.port

    def serve_url(self, transport: str = "pty", query: str = "") -> str:
        """Serve the peer over a new pty or TCP port (127.0.0.1, any free port) and return
        the controller URL that reaches it (``grbl://PTY`` / ``grbl+socket://HOST:PORT``),
        with ``query`` (e.g. ``"rate=50"``) appended."""
        if transport == "pty":
            url = f"grbl://{self.serve_pty()}"
        elif transport == "tcp":
            url = f"grbl+socket://127.0.0.1:{self.serve_tcp()}"
        else:
            raise ValueError(f"transport must be 'pty' or 'tcp', got {transport!r}")
        return f"{url}?{query}" if query else url

    def wait_for_client(self, timeout: float) -> bool:
        """Wait until a driver has one of the served ports open (a byte written before
        that is lost, as on a real port nobody has open); True if one has."""
        deadline = time.monotonic() + timeout
        while True:
            transports = list(self._transports)
            if any(t.sender_present for t in transports):
                return True
            left = deadline - time.monotonic()
            if left <= 0 or not transports:
                return False
            transports[0].wait_sender(min(left, 0.05))

    def close_transports(self) -> None:
        """Drop every pty and socket (the cable is pulled); the machine keeps running."""
        transports, self._transports = self._transports, []
        for t in transports:
            t.close()

    def close(self) -> None:
        """Stop the main loop, the runner and every transport. Safe to call twice."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self.close_transports()
        if self.runner is not None:
            self.runner.stop()
            self.runner = None
        self._main.join(2.0)
        if self.vm.on_event == self._on_vm_event:
            self.vm.on_event = self._chained_event

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # ------------------------------------------------------------------ output

    def _send(self, text: str, to: Endpoint | None = None) -> None:
        data = (text + "\r\n").encode("ascii", "replace")
        mutate = self.mutate
        if mutate is not None:
            data = mutate(data)
            if not data:
                return
        if to is not None:
            to.write(data)
            return
        for t in list(self._transports):
            t.write(data)

    def inject(self, data: bytes) -> None:
        """Fault injection: raw bytes to every sender (noise, truncated lines)."""
        for t in list(self._transports):
            t.write(data)

    def _reply(self, text: str) -> None:
        self._send(text, self._reply_to)

    # ------------------------------------------------------------------ input

    def _receive(self, transport: Endpoint, data: bytes) -> None:
        """Bytes from a sender: real-time bytes act now, the rest go to the RX buffer."""
        self._reply_to = transport
        plain = bytearray()
        for b in data:
            if b in p.REALTIME_BYTES:
                if b == 0x18 and plain:
                    self._buffer(plain)  # bytes before a reset are flushed by it
                    plain = bytearray()
                self._realtime(b, transport)
            else:
                plain.append(b)
        if plain:
            self._buffer(plain)

    def _buffer(self, plain: bytes) -> None:
        t0 = time.monotonic()
        with self._cond:
            for k, b in enumerate(plain):
                if not self._take(b) and not self._stop.is_set():
                    # the byte would still be on the wire at 115200 baud: the main loop
                    # may free room before it lands; if not, it is lost as on hardware
                    due = t0 + (k + 1) / _BYTES_PER_S
                    self._cond.wait_for(lambda: len(self._rx) < p.RX_BUFFER_SIZE or self._take_direct(),
                                        max(0.0, due - time.monotonic()))
                    if not self._take(b):
                        self.rx_dropped += 1
            self._cond.notify_all()

    def _take_direct(self) -> bool:
        return not self._executing and self._line_ready is None

    def _take(self, b: int) -> bool:
        """One byte into GRBL; False when the RX buffer is full.

        An idle main loop takes bytes into its line at once (it reads faster than the
        serial line delivers); while it executes a line they wait in the 128-byte RX
        buffer."""
        if not self._executing and self._line_ready is None:
            if b in (0x0A, 0x0D):
                self._line_ready = bytes(self._line)
                self._line.clear()
            elif len(self._line) < _LINE_MEMORY:
                self._line.append(b)
            else:
                self._line_overflow = True
            return True
        if len(self._rx) < p.RX_BUFFER_SIZE:
            self._rx.append(b)
            return True
        return False

    def _feed(self, plain) -> None:
        """Bytes already inside GRBL (the RX buffer) into the main loop's line."""
        for b in plain:
            self._take(b)

    def _realtime(self, b: int, transport: Endpoint) -> None:
        vm = self.vm
        self.realtime_log.append(b)
        if b == 0x3F:  # '?'
            self.status_requests += 1
            self._send(self.status_report(), transport)
            return
        if b == 0x18:
            self.reset()
            return
        with vm.lock:
            if b == 0x21:  # '!'
                if vm.state in (RunState.RUN, RunState.JOG):
                    vm.feed_hold()
            elif b == 0x7E:  # '~'
                vm.resume()
            elif b == 0x85:
                vm.cancel_jog()
            elif b == 0x84:  # safety door: this machine has none; hold as GRBL would
                if vm.state == RunState.RUN:
                    vm.feed_hold()
            elif 0x90 <= b <= 0x94:
                new = p.apply_override(vm.feed_override, b, "feed")
                if new != vm.feed_override:
                    vm.set_feed_override(new)
                    self._ovr_counter = 0
            elif 0x95 <= b <= 0x97:
                new = {0x95: 100, 0x96: 50, 0x97: 25}[b]
                if new != vm.rapid_override:
                    vm.set_rapid_override(new)
                    self._ovr_counter = 0
            elif 0x99 <= b <= 0x9D:
                new = p.apply_override(vm.spindle_override, b, "spindle")
                if new != vm.spindle_override:
                    vm.set_spindle_override(new)
                    self._ovr_counter = 0
            else:  # spindle stop / coolant toggles: reported with the next Ov
                self._ovr_counter = 0

    def _on_vm_event(self, name: str, payload) -> None:
        if name == "alarm":
            code = int(payload)
            self._send(f"ALARM:{code}")
            if code in _CRITICAL_ALARMS:
                self._critical = True
                self._send("[MSG:Reset to continue]")
                with self._cond:
                    self._cond.notify_all()
        if self._chained_event is not None:
            self._chained_event(name, payload)

    # ------------------------------------------------------------------ reset

    def reset(self) -> None:
        """Ctrl-X: stop at once (ALARM:3 when moving), flush RX and planner, banner."""
        vm = self.vm
        with vm.lock:
            was_alarm = vm.state == RunState.ALARM
            was_asleep = vm.state == RunState.SLEEP
            vm.reset()  # raises ALARM:3 through on_event when moving
            if was_asleep:
                # steppers were off: GRBL wakes in alarm, not knowing where it is
                vm.state = RunState.ALARM
            in_alarm = vm.state == RunState.ALARM
            with self._cond:
                self._rx.clear()
                self._line.clear()
                self._line_ready = None
                self._line_overflow = False
                self._reset_gen += 1
                self._critical = False
                self._check_mode = False
                self._wco_counter = self._ovr_counter = 0
                self._cond.notify_all()
            self.interpreter = self._new_interpreter()
            self._sync_offsets_into_interpreter()
        self._send("")
        self._send(BANNER)
        if in_alarm or was_alarm:
            self._send("[MSG:'$H'|'$X' to unlock]")

    # ------------------------------------------------------------------ status

    def status_report(self) -> str:
        """The ``<...>`` report GRBL would send now (and advance the WCO/Ov cadence)."""
        vm = self.vm
        with vm.lock:
            s = vm.snapshot()
            rx_free = p.RX_BUFFER_SIZE - len(self._rx)
            if self._check_mode and s.state in (RunState.IDLE, RunState.RUN):
                name = "Check"
            elif s.state in (RunState.HOLD, RunState.DOOR):
                name = f"{s.state.value}:{s.substate if s.substate is not None else 0}"
            else:
                name = s.state.value
            busy = s.state in _BUSY
            inches = int(self.settings.get(13, 0)) & 1
            scale = 1.0 / p.MM_PER_INCH if inches else 1.0
            dec = 4 if inches else 3
            mask = int(self.settings.get(10, 1))
            pos = np.asarray(s.mpos[:3])
            wco = np.asarray(s.wco[:3])
            fields = [name]
            if mask & 1:
                fields.append("MPos:" + _fmt(pos * scale, dec))
            else:
                fields.append("WPos:" + _fmt((pos - wco) * scale, dec))
            if mask & 2:
                fields.append(f"Bf:{vm.planner_free()},{rx_free}")
            if s.line is not None and s.line in self._n_words:
                fields.append(f"Ln:{self._n_words[s.line]}")
            feed = s.feed * scale
            fields.append(f"FS:{feed:.{1 if inches else 0}f},{abs(s.spindle):.0f}")
            if self._wco_counter > 0:
                self._wco_counter -= 1
            else:
                self._wco_counter = (30 if busy else 10) - 1
                if self._ovr_counter == 0:
                    self._ovr_counter = 1  # Ov on the next report, not with WCO
                fields.append("WCO:" + _fmt(wco * scale, dec))
            if self._ovr_counter > 0:
                self._ovr_counter -= 1
            else:
                self._ovr_counter = (20 if busy else 10) - 1
                fields.append(f"Ov:{s.overrides[0]},{s.overrides[1]},{s.overrides[2]}")
                if s.accessories:
                    fields.append("A:" + s.accessories)
        return "<" + "|".join(fields) + ">"

    # ------------------------------------------------------------------ main loop

    def _main_loop(self) -> None:
        while not self._stop.is_set():
            with self._cond:
                self._cond.wait_for(lambda: self._stop.is_set() or self._line_ready is not None, 0.5)
                if self._stop.is_set():
                    return
                line, self._line_ready = self._line_ready, None
                overflow, self._line_overflow = self._line_overflow, False
                if line is None:
                    continue
                self._executing = True
                gen = self._reset_gen
            try:
                if self._critical:
                    continue  # GRBL waits for a reset after a limit alarm; lines are lost
                try:
                    reply = "error:11" if overflow else self._execute(line, gen)
                except Exception as exc:  # noqa: BLE001 - an emulator bug must not kill the port
                    self._reply(f"[MSG:dexmon peer error: {type(exc).__name__}: {exc}]")
                    reply = "error:20"
                if reply is not None and gen == self._reset_gen:
                    self._reply(reply)
            finally:
                with self._cond:
                    self._executing = False
                    # the main loop reads on from the RX buffer
                    waiting = bytes(self._rx)
                    self._rx.clear()
                    self._feed(waiting)
                    self._cond.notify_all()

    def _execute(self, raw: bytes, gen: int) -> str | None:
        """Run one line as GRBL's protocol_main_loop does; return the reply (None: none)."""
        text = raw.decode("latin-1")
        self.received_lines.append(text)
        clean = _strip_grbl(text)
        if len(clean) >= LINE_BUFFER_SIZE:
            return "error:11"
        if not clean:
            return "ok"
        if clean[0] == "$":
            return self._system(clean, gen)
        vm = self.vm
        with vm.lock:
            state = vm.state
        if state in (RunState.ALARM, RunState.JOG):
            return "error:9"
        if state == RunState.SLEEP:
            return "error:9"
        return self._gcode(text, clean, gen)

    # ------------------------------------------------------------------ G-code

    def _gcode(self, text: str, clean: str, gen: int, jog: bool = False) -> str | None:
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
        try:
            rows = interp.execute_line(text, seq)
        except GCodeError as exc:
            return f"error:{exc.grbl_code or 20}"
        except (ValueError, ArithmeticError) as exc:
            self._reply(f"[MSG:dexmon peer: {exc}]")
            return "error:20"
        rows = np.atleast_1d(np.asarray(rows)) if rows is not None else np.zeros(0)
        if self._check_mode:
            return "ok"
        if len(rows) == 0:
            if _sync_key(interp) != before:
                # spindle, coolant and offset changes wait for the motion before them
                # (GRBL's protocol_buffer_synchronize)
                if not self._wait_motion_done(gen):
                    return None
            self._after_non_motion(gen)
            return "ok"
        reply = self._queue(rows, gen)
        if reply == "ok" and np.any(rows["kind"] == MoveKind.DWELL):
            # G4 syncs: its ok comes when the dwell is over (senders use G4 P0 to sync)
            if not self._wait_motion_done(gen):
                return None
        return reply

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

    def _after_non_motion(self, gen: int) -> None:
        """G10/G92/G43.1 change offsets: GRBL syncs the planner, then WCO changes."""
        self._sync_offsets_from_interpreter(gen)

    def _sync_offsets_from_interpreter(self, gen: int) -> None:
        interp = self.interpreter
        wco = _interp_wco(interp)
        if wco is None:
            return
        vm = self.vm
        with vm.lock:
            _copy_offsets(interp, vm)
            current = np.asarray(vm.wco, dtype=float)
        if np.allclose(current[: len(wco)], wco[: len(current)]):
            return
        while gen == self._reset_gen and not self._stop.is_set():
            with vm.lock:
                if not vm.busy:
                    vm.set_wco(wco)
                    _copy_offsets(interp, vm)
                    self._wco_counter = 0  # report the new WCO at once
                    return
            self._stop.wait(0.002)

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

    # ------------------------------------------------------------------ $ commands

    def _system(self, line: str, gen: int) -> str | None:
        vm = self.vm
        with vm.lock:
            state = vm.state
            idle_or_alarm = state in (RunState.IDLE, RunState.ALARM) and not (state == RunState.IDLE and vm.busy)
        cmd = line[1:]
        if cmd == "":
            self._reply(HELP)
            return "ok"
        if cmd.startswith("J"):
            if state not in (RunState.IDLE, RunState.JOG):
                return "error:8"
            if not cmd.startswith("J="):
                return "error:3"
            return self._jog(cmd[2:])
        if cmd in ("$", "G", "C", "X") or cmd[:1] in ("$", "G", "C", "X") and len(cmd) > 1 and not cmd[1:2].isdigit():
            if len(cmd) != 1:
                return "error:3"
            if cmd == "$":
                if state in (RunState.RUN, RunState.HOLD):
                    return "error:8"
                for n in sorted(self.settings):
                    self._reply(f"${n}={_setting_text(n, self.settings[n])}")
                return "ok"
            if cmd == "G":
                self._reply(self._gc_line())
                return "ok"
            if cmd == "C":
                if self._check_mode:
                    self._reply("[MSG:Disabled]")
                    self.reset()
                    return None
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
            with vm.lock:
                vm.unlock()  # homing succeeds at the current position (no switches here)
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
                self._reply(f"[VER:{VERSION}:]")
                blocks = vm.config.planner_blocks
                self._reply(f"[OPT:V{'N' if self.line_numbers else ''},{blocks},{p.RX_BUFFER_SIZE}]")
                return "ok"
            return "ok" if cmd[1] == "=" else "error:3"
        if cmd[0] == "R":
            if not (cmd.startswith("RST=") and len(cmd) == 5 and cmd[4] in "$#*"):
                return "error:3"
            if cmd[4] in "$*":
                self.settings = dict(p.DEFAULT_SETTINGS)
                self.settings.update(self._settings_from_config(vm.config))
            self._reply("[MSG:Restoring defaults]")
            self.reset()
            return None
        if cmd[0] == "N":
            if cmd == "N":
                for i, text in enumerate(self.startup_lines):
                    self._reply(f"$N{i}={text}")
                return "ok"
            if state != RunState.IDLE:
                return "error:8"
            key, sep, value = cmd[1:].partition("=")
            if not key.isdigit():
                return "error:2"
            if not sep or int(key) >= len(self.startup_lines):
                return "error:3"
            self.startup_lines[int(key)] = value
            return "ok"
        # $x=val
        key, sep, value = cmd.partition("=")
        if not re.fullmatch(r"\d+(\.\d*)?", key):
            return "error:2" if not key[:1].isalpha() else "error:3"
        if not sep:
            return "error:3"
        try:
            num = float(value)
        except ValueError:
            return "error:2"
        n = int(float(key))
        if n not in p.DEFAULT_SETTINGS:
            return "error:3"
        if num < 0:
            return "error:4"
        if n == 0 and num < 3:
            return "error:6"
        if n == 20 and num and not int(self.settings.get(22, 0)):
            return "error:10"
        self.settings[n] = num
        if n == 10 or n == 13:
            self._wco_counter = 0
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
        interp_offsets = _interp_offsets(self.interpreter)
        for n in (54, 55, 56, 57, 58, 59):
            name = f"G{n}"
            values = interp_offsets.get(name, wo.g5x.get(name, (0.0,) * 6))
            self._reply(f"[{name}:{_fmt(np.asarray(values[:3]) * scale, dec)}]")
        for name, values in (("G28", wo.g28), ("G30", wo.g30)):
            values = interp_offsets.get(name, values)
            self._reply(f"[{name}:{_fmt(np.asarray(values[:3]) * scale, dec)}]")
        g92 = interp_offsets.get("G92", wo.g92)
        self._reply(f"[G92:{_fmt(np.asarray(g92[:3]) * scale, dec)}]")
        tlo = interp_offsets.get("TLO", (wo.tlo,))
        self._reply(f"[TLO:{tlo[0] * scale:.{dec}f}]")
        self._reply(f"[PRB:{_fmt(np.asarray(wo.prb[:3]) * scale, dec)}:{1 if wo.prb_ok else 0}]")

    def _gc_line(self) -> str:
        words = _interp_modal_words(self.interpreter)
        if words is None:
            words = "G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0"
        return f"[GC:{words}]"


# ------------------------------------------------------------------ helpers


def _strip_grbl(text: str) -> str:
    """What GRBL's main loop keeps of a line: no spaces, comments or controls; upper case."""
    out = []
    in_paren = False
    for ch in text:
        if in_paren:
            if ch == ")":
                in_paren = False
            continue
        if ch == "(":
            in_paren = True
        elif ch == ";":
            break
        elif ch <= " " or ch == "\x7f":
            continue
        else:
            out.append(ch.upper())
    return "".join(out)


def _setting_text(n: int, v: float) -> str:
    if n in (11, 12, 24, 25, 27) or 100 <= n <= 132:
        return f"{v:.3f}"
    return f"{int(v)}" if float(v).is_integer() else f"{v:.3f}"


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


def _interp_offsets(interp) -> dict[str, tuple[float, ...]]:
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


def _interp_modal_words(interp) -> str | None:
    """``$G`` words in GRBL's order: motion, WCS, plane, units, distance, feed mode, M, T F S."""
    if interp is None or not hasattr(interp, "state"):
        return None
    st = interp.state
    words = st.gcodes()[:6] + st.mcodes()
    words += [f"T{st.tool}", f"F{st.feed:.0f}", f"S{st.spindle:.0f}"]
    return " ".join(words)


def _copy_offsets(interp, vm) -> None:
    offs = _interp_offsets(interp)
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
