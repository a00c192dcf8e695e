"""A GRBL 1.1 protocol peer: the virtual machine behind a pseudo-terminal or TCP socket.

:class:`GrblPeer` answers as Grbl 1.1h does (see ``grbl-wire-facts.md``):

* the banner after a reset, ``[MSG:'$H'|'$X' to unlock]`` after a reset in alarm;
* the ``$`` commands (:mod:`drivers.grbl.peer_system`, system.c);
* real-time bytes taken out of the stream at once: ``?`` (the report of
  :mod:`drivers.grbl.peer_report`: field order, ``$10`` mask, WCO/Ov cadence, ``FS:``
  spindle and ``A:`` accessories), ``!`` ``~`` Ctrl-X, 0x85 jog cancel; override bytes
  set flag bits that are applied once per read, as GRBL applies them once per pass;
* a 128-byte RX buffer: bytes beyond it are dropped, as on hardware; the main loop
  takes one line out, executes it and only then reads the next, so a motion line's
  ``ok`` waits until its block fits in the planner (``vm.planner_free()``);
* a complete feed hold (``Hold:0``, also ``!`` while Idle) or sleep suspends the main
  loop: lines wait in the RX buffer, unread and unanswered, until ``~`` or Ctrl-X;
* the safety door byte 0x84 (in any state but alarm and check mode): ``[MSG:Check Door]``,
  a hold (``Door:2`` while it decelerates, a jog is cancelled), spindle and coolant off,
  then ``Door:0`` (no door pin: the door reads closed); ``~`` restores spindle and coolant
  with the firmware's spin-up delays in machine time (``Door:3``) and resumes; the main
  loop reads no line meanwhile;
* G-code goes through ``sim.gcode.Interpreter(dialect="grbl")``; what it refuses gets
  the ``error:N`` of its ``GCodeError.grbl_code``; spindle, coolant and offset changes
  wait for the planner to empty, as GRBL's ``protocol_buffer_synchronize`` does;
* after a reset not ending in alarm the stored ``$N`` startup blocks run before the next
  line, each reported as ``>block:ok`` / ``>block:error:N``;
* ``ALARM:N`` pushed as the machine raises it; a soft or hard limit is critical: the
  peer says ``[MSG:Reset to continue]`` and ignores lines until Ctrl-X.

What the firmware does is read from its source (gnea/grbl v1.1h: protocol.c, report.c,
system.c, serial.c, gcode.c, spindle_control.c, coolant_control.c, main.c).

Transports: :meth:`GrblPeer.serve_pty` (raw pseudo-terminal, returns the path a sender
opens) and :meth:`GrblPeer.serve_tcp` (returns the bound port). Both can run at once.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Callable

from drivers.grbl import protocol as p
from drivers.grbl import readings
from drivers.grbl.endpoints import Endpoint, PtyEndpoint, TcpEndpoint
from drivers.grbl.peer_gcode import GcodeExecution
from drivers.grbl.peer_report import Accessories, ReportCadence, settings_from_config, status_report
from drivers.grbl.peer_system import SystemCommands
from drivers.state import RunState
from sim.gcode.moves import COOLANT_FLOOD

BANNER = "Grbl 1.1h ['$' for help]"
LINE_BUFFER_SIZE = 80  # GRBL's line buffer: longer lines get error:11
_LINE_MEMORY = 1024  # raw bytes of one line kept (comments and spaces included)
_BYTES_PER_S = 115200 / 10  # serial line speed: 8N1 is 10 bits a byte
_V_EPS = 1e-9  # mm/s: a machine slower than this stands
#: config.h: seconds the door resume waits after turning the spindle, then the coolant, on
SAFETY_DOOR_SPINDLE_DELAY, SAFETY_DOOR_COOLANT_DELAY = 4.0, 1.0
#: the Door:N substate of each phase of the peer's door (report.c; 1, "still ajar", needs a pin)
_DOOR_SUBSTATE = {"stopping": 2, "closed": 0, "restoring": 3}
#: real-time override bytes -> GRBL's exec_motion_override / exec_accessory_override bits
_MOTION_OVERRIDES = frozenset(range(0x90, 0x98))
_ACCESSORY_OVERRIDES = frozenset(range(0x99, 0xA1))


def _default_interpreter():
    # drivers -> sim.gcode is the one allowed arrow
    try:
        from sim.gcode import Interpreter
    except ImportError:
        from sim.gcode.interpreter import Interpreter

    return Interpreter(dialect="grbl", machine_units="mm")


class GrblPeer(GcodeExecution, SystemCommands):
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
        self.settings.update(settings_from_config(vm.config))
        if settings:
            self.settings.update({int(k): float(v) for k, v in settings.items()})
        self.line_numbers = line_numbers
        self._make_interpreter = interpreter_factory or _default_interpreter
        self.interpreter = self._new_interpreter()
        self.startup_lines = ["", ""]  # $N0 $N1, as the main loop keeps them (N_STARTUP_LINE 2)
        self.build_info = ""  # $I=text (EEPROM)
        self._startup_due = False  # a reset not ending in alarm: run the startup blocks first
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
        #: safety door: None, "stopping" (hold decelerating), "closed" (stopped, spindle and
        #: coolant off, ready for '~'), "restoring" (after '~', spin-up delays running)
        self._door: str | None = None
        self._door_outputs = (0, 0.0, 0)  # spindle and coolant to restore
        self._door_coolant_at = self._door_resume_at = 0.0  # machine time (vm.time), s
        self._reset_after_reply = False  # $C leaving check mode, $RST: the ok, then a soft reset
        self._stop = threading.Event()
        self._seq = 0
        self._n_words: dict[int, int] = {}
        self.cadence = ReportCadence()
        self.accessories = Accessories()
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
        """Bytes from a sender: real-time bytes act now, the rest go to the RX buffer.

        Override bytes set flag bits as GRBL's serial interrupt does; the main loop applies
        the bits once per pass, so identical override bytes in one read count once."""
        self._reply_to = transport
        plain = bytearray()
        motion: set[int] = set()
        accessory: set[int] = set()
        for b in data:
            if b in _MOTION_OVERRIDES:
                self.realtime_log.append(b)
                motion.add(b)
            elif b in _ACCESSORY_OVERRIDES:
                self.realtime_log.append(b)
                accessory.add(b)
            elif b in p.REALTIME_BYTES:
                if b == 0x18:
                    if plain:
                        self._buffer(plain)  # bytes before a reset are flushed by it
                        plain = bytearray()
                    motion.clear()  # pending override bits die with the reset
                    accessory.clear()
                self._realtime(b, transport)
            elif b < 0x80:
                plain.append(b)
            # other bytes above 0x7F: GRBL's serial interrupt throws them away
        if plain:
            self._buffer(plain)
        if motion or accessory:
            self._apply_overrides(motion, accessory)

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

    def _suspended(self) -> bool:
        """GRBL's main loop is suspended (protocol_exec_rt_suspend): a feed hold that is
        complete (Hold:0, also an M0 pause) or sleep. It reads no line until ``~`` or a
        reset; bytes wait in the RX buffer. (Read without the machine's lock: a byte's
        path may be decided a moment early or late, as on hardware.)"""
        vm = self.vm
        return (self._door is not None or (vm.state == RunState.HOLD and vm.speed <= _V_EPS)
                or vm.state == RunState.SLEEP)

    def _take_direct(self) -> bool:
        return (not self._executing and self._line_ready is None and not self._startup_due
                and not self._suspended())

    def _take(self, b: int) -> bool:
        """One byte into GRBL; False when the RX buffer is full.

        An idle main loop takes bytes into its line at once (it reads faster than the
        serial line delivers); while it executes a line, or is suspended, they wait in
        the 128-byte RX buffer."""
        if self._take_direct():
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

    def _read_on(self) -> None:
        """The main loop reads on from the RX buffer (under ``_cond``)."""
        waiting = bytes(self._rx)
        self._rx.clear()
        for b in waiting:
            self._take(b)
        self._cond.notify_all()

    def _realtime(self, b: int, transport: Endpoint) -> None:
        vm = self.vm
        self.realtime_log.append(b)
        if b == 0x3F:  # '?'
            self.status_requests += 1
            # protocol.c: after a hard or soft limit the main loop spins until Ctrl-X and
            # never reaches the status report (gnea/grbl#224): the '?' goes unanswered
            if not self._critical:
                self._send(self.status_report(), transport)
            return
        if b == 0x18:
            self.reset()
            return
        with vm.lock:
            if b == 0x21:  # '!'
                # protocol.c: no hold in alarm, check mode, sleep or door; from Idle the
                # hold is complete at once (Hold:0); a jog is cancelled instead
                if (not self._check_mode and self._door is None
                        and vm.state in (RunState.IDLE, RunState.RUN, RunState.JOG)):
                    vm.feed_hold()
            elif b == 0x84:
                self._open_door()
            elif b == 0x7E:  # '~'
                if self._door is not None:
                    self._close_door()
                else:
                    self._cycle_start()
            elif b == 0x85:
                vm.cancel_jog()

    def _cycle_start(self) -> None:
        """``~``: leave a complete hold; the main loop reads on (vm lock held)."""
        vm = self.vm
        if vm.state != RunState.HOLD or vm.speed > _V_EPS:
            return  # GRBL ignores cycle start until the hold is complete
        if self.accessories.stopped:
            self._send("[MSG:Restoring spindle]")
            self.accessories.stopped = False
            self.cadence.flag_ovr()
        vm.resume()
        with self._cond:
            self._read_on()

    # ------------------------------------------------------------------ safety door

    def _open_door(self) -> None:
        """0x84 (vm lock held), as protocol_execute_realtime takes EXEC_SAFETY_DOOR."""
        vm = self.vm
        if self._check_mode or vm.state == RunState.ALARM:
            return  # protocol.c: no hold method in alarm or check mode, not even the message
        self._send("[MSG:Check Door]")
        if vm.state == RunState.SLEEP:
            return  # sleep stays sleep
        if self._door is None:
            self._door_outputs = self.accessories.outputs()
            vm.feed_hold()  # Run: decelerate; Idle: held at once; Jog: cancelled; Hold: as is
        # opened again while restoring: retract again (spindle and coolant off once more)
        self._door = "stopping"
        self._door_update()

    def _close_door(self) -> None:
        """``~`` in the door state (vm lock held): the door reads closed, so once stopped
        the suspend loop restores the spindle, waits, the coolant, waits, and resumes."""
        if self._door != "closed":
            return  # still decelerating (the ajar flag is set): cycle start is ignored
        direction, rpm, coolant = self._door_outputs
        now = self.vm.time
        self._door = "restoring"
        self._door_coolant_at = now
        if direction:
            self._set_door_outputs(direction, rpm, 0)
            self._door_coolant_at = now + SAFETY_DOOR_SPINDLE_DELAY
        self._door_resume_at = self._door_coolant_at + (SAFETY_DOOR_COOLANT_DELAY if coolant else 0.0)
        self._door_update()

    def _door_update(self) -> None:
        """Move the door on as protocol_exec_rt_suspend does (vm lock held): called before a
        status report and by the main loop, so what a sender sees is what the firmware
        would report at that moment."""
        vm = self.vm
        if vm.state == RunState.ALARM:
            self._door = None  # an alarm (a limit while held) takes over until the reset
        elif self._door == "stopping":
            if vm.state == RunState.JOG or vm.speed > _V_EPS:
                return  # the hold (or jog cancel) is not complete
            self.accessories.stopped = False  # the door routine ends a spindle stop override
            self._set_door_outputs(0, 0.0, 0)
            self._door = "closed"  # no door pin: read closed at once (Door:0)
        elif self._door == "restoring":
            if vm.time >= self._door_coolant_at:
                self._set_door_outputs(*self._door_outputs)
            if vm.time >= self._door_resume_at:
                self._door = None
                vm.resume()  # back to Run (blocks left) or Idle
                with self._cond:
                    self._read_on()

    def _set_door_outputs(self, direction: int, rpm: float, coolant: int) -> None:
        acc = self.accessories
        if (acc.direction, acc.rpm, acc.coolant) != (direction, rpm, coolant):
            acc.direction, acc.rpm, acc.coolant = direction, rpm, coolant
            self.cadence.flag_ovr()  # spindle_set_state / coolant_set_state: reported at once

    def _apply_overrides(self, motion: set[int], accessory: set[int]) -> None:
        """Apply one pass of override bits as protocol_exec_rt_system does: each bit once,
        in the firmware's order, in uint8 arithmetic, clamped once at the end."""
        vm = self.vm
        with vm.lock:
            feed, rapid = _feed_override(vm.feed_override, motion), _rapid_override(vm.rapid_override, motion)
            if feed != vm.feed_override or rapid != vm.rapid_override:
                vm.set_feed_override(feed)
                vm.set_rapid_override(rapid)
                self.cadence.flag_ovr()
            spindle = _spindle_override(vm.spindle_override, accessory)
            if spindle != vm.spindle_override:
                vm.set_spindle_override(spindle)
                self.cadence.flag_ovr()
            # the door state is neither a hold nor one the coolant toggle works in
            if 0x9E in accessory and vm.state == RunState.HOLD and self._door is None:  # only in a hold
                self._toggle_spindle_stop()
            if 0xA0 in accessory and not self._check_mode and self._door is None and vm.state in (
                    RunState.IDLE, RunState.RUN, RunState.HOLD, RunState.JOG):
                # flood toggle: the output and the parser's modal state (M8 / M9)
                self.accessories.coolant ^= COOLANT_FLOOD
                if self.interpreter is not None and hasattr(self.interpreter, "coolant"):
                    self.interpreter.coolant = self.accessories.coolant
                self.cadence.flag_ovr()
            # 0xA1 mist toggle: GRBL compiled without M7 ignores it

    def _toggle_spindle_stop(self) -> None:
        acc = self.accessories
        if not acc.stopped:
            if acc.direction:
                acc.stopped = True
        else:
            self._send("[MSG:Restoring spindle]")
            acc.stopped = False
        self.cadence.flag_ovr()

    def _on_vm_event(self, name: str, payload) -> None:
        if name == "alarm":
            code = int(payload)
            self._send(f"ALARM:{code}")
            if code in readings.CRITICAL_ALARMS:
                self._critical = True
                self.accessories.killed = True  # limits.c calls mc_reset: pins off
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
                self._door = None
                self._reset_after_reply = False
                self._startup_due = False
                self.cadence = ReportCadence()  # main.c clears sys: WCO, then Ov, at once
                self.accessories = Accessories()  # mc_reset stops spindle and coolant
                self._cond.notify_all()
            self.interpreter = self._new_interpreter()
            self._sync_offsets_into_interpreter()
        self._send("")
        self._send(BANNER)
        if in_alarm or was_alarm:
            self._send("[MSG:'$H'|'$X' to unlock]")
        elif any(self.startup_lines):
            # protocol_main_loop runs them after the banner, before it reads a line
            with self._cond:
                self._startup_due = True
                self._cond.notify_all()

    def _run_startup_blocks(self, gen: int) -> None:
        """system_execute_startup: each stored block through the G-code path, reported as
        ``>block:ok`` or ``>block:error:N`` (report_execute_startup_message)."""
        for block in self.startup_lines:
            if not block:
                continue
            reply = self._gcode(block, block, gen)
            if reply is None or gen != self._reset_gen:
                return  # a reset or a limit alarm cut it short
            self._send(f">{block}:{reply}")

    # ------------------------------------------------------------------ status

    def status_report(self) -> str:
        """The ``<...>`` report GRBL would send now (and advance the WCO/Ov cadence)."""
        vm = self.vm
        with vm.lock:
            if self._door is not None:
                self._door_update()
            s = vm.snapshot()
            if self._door is not None and s.state != RunState.JOG:
                s = dataclasses.replace(s, state=RunState.DOOR, substate=_DOOR_SUBSTATE[self._door])
            if self._check_mode and s.state in (RunState.IDLE, RunState.RUN):
                name = "Check"
            elif s.state in (RunState.HOLD, RunState.DOOR):
                name = f"{s.state.value}:{s.substate if s.substate is not None else 0}"
            else:
                name = s.state.value
            line = self._n_words.get(s.line) if s.line is not None else None
            return status_report(s, name, self.settings, self.cadence, self.accessories, vm.planner_free(),
                                 p.RX_BUFFER_SIZE - len(self._rx), line)

    # ------------------------------------------------------------------ main loop

    def _main_loop(self) -> None:
        while not self._stop.is_set():
            if self._door is not None:
                with self.vm.lock:  # the door resumes when its delays are over, polled or not
                    self._door_update()
            with self._cond:
                # a line is run only when the main loop is not suspended (a complete hold
                # ends with '~' or a reset, both of which wake this wait)
                self._cond.wait_for(lambda: self._stop.is_set() or self._startup_due
                                    or (self._line_ready is not None and not self._suspended()),
                                    0.5 if self._door is None else 0.01)
                if self._stop.is_set():
                    return
                startup, self._startup_due = self._startup_due, False
                if not startup and self._suspended():
                    continue
                line, overflow = None, False
                if not startup:
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
                    if startup:
                        self._run_startup_blocks(gen)
                        continue
                    reply = "error:11" if overflow else self._execute(line, gen)
                except Exception as exc:  # noqa: BLE001 - an emulator bug must not kill the port
                    self._reply(f"[MSG:dexmon peer error: {type(exc).__name__}: {exc}]")
                    reply = None if startup else "error:20"  # no line of the sender's to answer
                if reply is not None and gen == self._reset_gen:
                    self._reply(reply)
                    if self._reset_after_reply:
                        self.reset()  # $C leaving check mode, $RST: mc_reset acts after the ok
            finally:
                with self._cond:
                    self._executing = False
                    self._read_on()

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
        if state in (RunState.ALARM, RunState.JOG, RunState.SLEEP):
            return "error:9"
        # the parser gets the line as GRBL's main loop keeps it: no spaces, comments or '/'
        return self._gcode(clean, clean, gen)


# ------------------------------------------------------------------ helpers


def _percent_override(current: int, bits: set[int], base: int, lo: int, hi: int) -> int:
    """protocol.c's pass over feed (base 0x90) or spindle (0x99) override bits: reset,
    +10, -10, +1, -1, each at most once, in uint8_t arithmetic, then clamped."""
    new = 100 if base in bits else current
    for offset, delta in ((1, 10), (2, -10), (3, 1), (4, -1)):
        if base + offset in bits:
            new = (new + delta) & 0xFF  # uint8_t: 10 - 10 - 1 wraps to 255 (then 200)
    return max(lo, min(hi, new))


def _feed_override(current: int, bits: set[int]) -> int:
    return _percent_override(current, bits, 0x90, p.FEED_OV_MIN, p.FEED_OV_MAX)


def _spindle_override(current: int, bits: set[int]) -> int:
    return _percent_override(current, bits, 0x99, p.SPINDLE_OV_MIN, p.SPINDLE_OV_MAX)


def _rapid_override(current: int, bits: set[int]) -> int:
    """Reset, then medium, then low: with several bits the last of these wins."""
    new = current
    for byte, level in ((0x95, 100), (0x96, 50), (0x97, 25)):
        if byte in bits:
            new = level
    return new


def _strip_grbl(text: str) -> str:
    """What GRBL's main loop keeps of a line: no spaces, comments, controls or '/'; upper case
    (DEL is kept: gc_execute_line refuses it as a letter, error:1)."""
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
        elif ch <= " " or ch == "/":
            continue  # '/': block delete is not supported, the character is dropped
        else:
            out.append(ch.upper())
    return "".join(out)

