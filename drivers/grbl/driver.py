"""GRBL 1.1 driver over any pyserial port: device, pseudo-terminal or ``socket://``.

A reader thread stamps every received line with ``time.monotonic()`` as its bytes
arrive, parses it (:mod:`drivers.grbl.protocol`) and routes it: status reports become
:class:`MachineState`, ``ok``/``error:N`` acknowledge the oldest line in flight, pushes
(``ALARM:N``, ``[MSG:]``, banner ...) are recorded; a line that is not GRBL's is kept in
:attr:`GrblController.garbage` and never stops the reader. :meth:`GrblController.poll`
returns only a report that answered its ``?`` (BAD when its numbers cannot be right),
else MISSED, or DISCONNECTED while the port is away (the contract of
:class:`drivers.state.Controller`). When the port vanishes the reader tries to reopen it
every 10 ms (no backoff: an outage costs what it lasts), redoes the handshake's queries
once the machine is Idle, tells how the controller came back
(reset, alarm) and records the gap in :attr:`GrblController.gaps`; LOST, BACK, RESET, BAD
and NOTE :class:`~drivers.state.LinkEvent` s say it all as it happens.

The driver sends nothing but ``?`` and, while the machine is Idle, its handshake queries
(``$I $$ $# $G``), unless the caller asks for more.

URLs (see :func:`from_url`)::

    grbl:///dev/ttyUSB0?baud=115200&rate=20     serial device (or pty path)
    grbl+pty:///dev/pts/5                         pseudo-terminal
    grbl+socket://127.0.0.1:2323?rate=50          TCP (pyserial socket://)
    grbl+rfc2217://host:port                      any other pyserial URL scheme

Query parameters: ``baud`` (115200), ``rate`` (status polls per second, 20, at most
50), ``timeout`` (s to wait for a reply, 2), ``reset`` (0: never reset, the default;
1: soft reset (Ctrl-X) on connect, and only when the machine is Idle or in Alarm),
``reconnect`` (1).
"""

from __future__ import annotations

import collections
import math
import select
import socket
import threading
import time
import traceback
from typing import Callable, Iterator
from urllib.parse import parse_qsl, urlsplit

import serial

from drivers.errors import ConnectionLost, DriverError, ProtocolError
from drivers.grbl import protocol as p
from drivers.grbl import readings
from drivers.grbl.streaming import Command, Streaming
from drivers.state import (MAX_REPORTED_INT, Controller, Gap, LinkKind, MachineState, RunState, check_device,
                           implausible, stale_state)

MAX_RATE_HZ = 50.0
DEFAULT_RATE_HZ = 20.0
#: s between attempts to reopen a vanished port (a failed open costs a system call; the
#: period is also capped at one poll period)
RETRY_PERIOD_S = 0.01
#: s before the handshake queries are tried again after a refusal or no reply
QUERY_RETRY_S = 1.0
#: the only states a soft reset is safe in: in Run/Jog/Home it loses position (ALARM:3),
#: in Hold it drops the job, in Door:2/Door:3 the firmware raises an alarm
_RESET_SAFE = (RunState.IDLE, RunState.ALARM)


class GrblController(Streaming, Controller):
    """A GRBL 1.1 controller on a pyserial port.

    Parameters
    ----------
    port : str
        pyserial port name or URL (``/dev/ttyUSB0``, ``socket://host:port`` ...).
    baud : int
    rate : float
        Status polls per second for :meth:`states` (default 20, at most 50).
    timeout : float
        Seconds to wait for a reply or the banner.
    reset_on_connect : bool
        Soft-reset (Ctrl-X) during the handshake, and then only when the first status
        report shows the machine Idle or in Alarm: never in Run, Hold, Jog, Home or Door
        (a reset in motion loses position, ALARM:3; in Door:2/3 it raises an alarm) nor
        when the state is unknown. Default False: attaching never stops a machine.
    reconnect : bool
        Reopen the port, every :attr:`retry_period` s, when it vanishes.
    """

    def __init__(self, port: str, baud: int = 115200, rate: float = DEFAULT_RATE_HZ, timeout: float = 2.0,
                 reset_on_connect: bool = False, reconnect: bool = True, url: str | None = None):
        if not 0 < rate <= MAX_RATE_HZ:
            raise DriverError(f"GRBL {port}: rate must be in (0, {MAX_RATE_HZ:g}] polls/s, got {rate:g}")
        self.port = port
        self.url = url or port
        self.baud = int(baud)
        self.rate = float(rate)
        self.timeout = float(timeout)
        self.reset_on_connect = reset_on_connect
        self.reconnect = reconnect
        #: s between attempts to reopen a vanished port: at most one poll period, so an
        #: outage costs the polls it lasts and no more
        self.retry_period = min(RETRY_PERIOD_S, 1.0 / self.rate)
        self.rx_size = p.RX_BUFFER_SIZE
        self.planner_blocks: int | None = None
        # learned from the controller
        self.settings: dict[int, float] = {}
        self.offsets: dict[str, tuple[float, ...]] = {}
        self.parser_state: p.ParserState | None = None
        self.version: p.Version | None = None
        self.options: p.Options | None = None
        self.banner: p.Banner | None = None
        self.probe: p.Probe | None = None
        # records of the run
        self.messages: collections.deque[tuple[float, p.Message]] = collections.deque(maxlen=1000)
        #: (t, line, why) of every received line that was not GRBL's (or not believable)
        self.garbage: collections.deque[tuple[float, str, str]] = collections.deque(maxlen=200)
        self.alarms: list[tuple[float, int]] = []
        self.gaps: list[Gap] = []
        #: polls answered with a not-fresh state, by run state (MISSED, BAD, DISCONNECTED)
        self.poll_counts: collections.Counter[RunState] = collections.Counter()
        self.unexpected_acks = 0
        self.max_in_flight = 0  # most bytes ever unacknowledged in GRBL's RX buffer
        self.on_state: Callable[[MachineState], None] | None = None
        self.on_message: Callable[[float, p.Message], None] | None = None
        # machinery
        self._ser = None
        self._asm = p.LineAssembler()
        self._cond = threading.Condition()
        self._write_lock = threading.Lock()
        self._pending: collections.deque[Command] = collections.deque()
        self._in_flight = 0
        self._state: MachineState | None = None   # the last fresh state
        self._reply: MachineState | None = None   # the last report received: fresh or BAD
        self._reply_seq = 0
        self._last_t = 0.0                         # t of the last state poll() returned
        self._garbage_seq = 0
        self._banner_seq = 0
        self._alarm: int | None = None
        self._alarm_seq = 0
        # a hard/soft limit ALARM code (readings.CRITICAL_ALARMS) since the last reset: GRBL answers
        # no '?' until Ctrl-X, so polls report the alarm from it instead
        self._critical: int | None = None
        self._offset_told = False   # the BAD event of reports with no work offset known yet was sent
        self._reported = RunState.UNKNOWN   # the run state of the latest report, even a BAD one
        self._message_seq = 0
        self._connected = False
        self._closing = threading.Event()
        self._reader: threading.Thread | None = None
        self._handshaking = False
        self._own_reset = False
        # the handshake's $ queries: due until read while Idle (see _read_settings)
        self._queries_due = False
        self._querying = False
        self._next_query_t = 0.0
        # the outage under way: from the port lost until the first report after reopening
        self._in_gap = False
        self._back_pending = False
        self._t_lost = 0.0
        self._lost_reason = ""
        self._gap_polls = 0
        self._lines_lost = 0
        self._banner_since_back = ""
        self._alarm_since_back: int | None = None

    # ------------------------------------------------------------------ connection

    def preflight(self) -> None:
        check_device(self.port, "GRBL")

    def _open_port(self):
        try:
            ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0, write_timeout=self.timeout)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"GRBL: cannot open {self.port!r}: {exc}") from exc
        return ser

    def connect(self) -> None:
        """Open the port, start the reader and do the handshake.

        Handshake: ask ``?`` until a status report comes (a board that resets when its
        port opens prints its banner first); soft reset only when asked
        (``reset_on_connect``) and the machine is Idle or in Alarm; then, only when it is
        Idle, ``$I``, ``$$``, ``$#``, ``$G``. Attached to a busy machine, those wait until
        it is Idle (units meanwhile as the report format says, told as a NOTE event).
        """
        if self._reader is not None:
            return
        self._closing.clear()
        self._ser = self._open_port()
        with self._cond:
            self._connected = True
            self._handshaking = True
        self._reader = threading.Thread(target=self._read_loop, name=f"grbl-reader {self.port}", daemon=True)
        self._reader.start()
        try:
            self._handshake()
        except BaseException:
            self.close()
            raise
        finally:
            self._handshaking = False

    def _handshake(self) -> None:
        state = self._first_state()
        if self.reset_on_connect:
            if state.state in _RESET_SAFE:
                self.soft_reset(wait=True)
                state = self._first_state()
            else:
                self._link_event(LinkKind.NOTE, f"GRBL {self.port}: not reset on connect: the machine is "
                                                f"{_state_name(state)}", raw=state.raw)
        with self._cond:
            self._queries_due = True
        # a report is BAD before the work offset is known (it comes from $#): its run state counts
        if RunState.IDLE in (state.state, self._reported):
            self._read_settings()  # a failure is told, and they are asked again when Idle
            return
        units = "inches" if _inches_by_format(state.raw) else "mm"
        self._link_event(LinkKind.NOTE, f"GRBL {self.port}: settings ($I $$ $# $G) not read while the machine is "
                                        f"{_state_name(state)}; they are read once it is Idle; until then "
                                        f"positions are taken in {units}, as the report format says, and "
                                        f"the machine's limits ($110-$132) are unknown",
                         raw=state.raw)

    def _first_state(self) -> MachineState:
        """Ask ``?`` until a report comes (fresh or BAD); DriverError after ``timeout`` s."""
        deadline = time.monotonic() + self.timeout
        while True:
            s = self.poll(0.25)
            if s.state not in (RunState.MISSED, RunState.DISCONNECTED):
                return s
            if s.state is RunState.DISCONNECTED:
                raise ConnectionLost(f"GRBL {self.port}: port lost during the handshake ({s.raw})")
            if time.monotonic() > deadline:
                raise DriverError(
                    f"GRBL {self.port}: no status report or banner within {self.timeout:g} s "
                    f"(is a GRBL 1.1 controller there at {self.baud} baud?)"
                )

    def _read_settings(self) -> bool:
        """``$I $$ $# $G`` (the machine is Idle); True when all were answered. A refusal
        (``error:8``: it started moving) or no reply leaves them due for the next Idle."""
        for query in ("$I", "$$", "$#", "$G"):
            try:
                self.command(query)
            except DriverError as exc:
                self._link_event(LinkKind.NOTE, f"GRBL {self.port}: handshake query {query} failed ({exc}); "
                                                f"retried when the machine is Idle")
                with self._cond:
                    self._next_query_t = time.monotonic() + QUERY_RETRY_S
                return False
        with self._cond:
            self._queries_due = False
        return True

    def _start_queries(self) -> None:
        """Run the due handshake queries on a worker thread (the reader must stay free to
        read their replies)."""
        with self._cond:
            if (self._querying or not self._queries_due or self._handshaking or self._closing.is_set()
                    or time.monotonic() < self._next_query_t):
                return
            self._querying = True
        threading.Thread(target=self._query_worker, name=f"grbl-handshake {self.port}", daemon=True).start()

    def _query_worker(self) -> None:
        try:
            self._read_settings()
        except Exception as exc:  # noqa: BLE001 - no thread dies quietly
            self._report_failure("handshake", exc)
        finally:
            with self._cond:
                self._querying = False

    def close(self) -> None:
        self._closing.set()
        reader, self._reader = self._reader, None
        if self._ser is not None:
            _close_port(self._ser)
        if reader is not None and reader is not threading.current_thread():
            reader.join(2.0)
        with self._cond:
            self._connected = False
            self._lost_reason = "closed"
            self._fail_pending(ConnectionLost(f"GRBL {self.port}: closed"))
            self._cond.notify_all()

    @property
    def connected(self) -> bool:
        return self._connected

    def wait_connected(self, timeout: float) -> bool:
        """Wait until the port is (back) up; True if it is."""
        with self._cond:
            return self._cond.wait_for(lambda: self._connected or self._closing.is_set(), timeout) and self._connected

    def wait_for_message(self, predicate: Callable[[p.Message], bool], timeout: float,
                         since: float | None = None) -> p.Message | None:
        """Wait for a received message (arrived after ``since``, monotonic s) matching
        ``predicate``; return it, or None on timeout."""
        since = -1.0 if since is None else since

        def find():
            for t, m in reversed(self.messages):
                if t < since:
                    return None
                if predicate(m):
                    return m
            return None

        with self._cond:
            found = None

            def check():
                nonlocal found
                found = find()
                return found is not None

            self._cond.wait_for(check, timeout)
            return found

    def wait_disconnected(self, timeout: float) -> bool:
        """Wait until the reader notices the port is gone; True if it did."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._connected, timeout)

    # ------------------------------------------------------------------ reader

    def _read_loop(self) -> None:
        """The reader thread: receive and route lines; reopen the port while it is away.
        Only close() ends it (or a lost port when ``reconnect`` is off): any failure is
        reported as a NOTE event and the loop goes on."""
        while not self._closing.is_set():
            try:
                if self._connected:
                    self._receive()
                elif not self.reconnect:
                    return
                else:
                    self._try_reopen()
            except Exception as exc:  # noqa: BLE001 - a bug must not end the watch quietly
                self._report_failure("reader", exc)
                self._closing.wait(self.retry_period)  # no hot loop on a failure that repeats

    def _receive(self) -> None:
        try:
            data = read_available(self._ser, 0.05)
        except Exception as exc:  # noqa: BLE001 - any failure of the port means it is gone
            if not self._closing.is_set():
                self._lost(f"{type(exc).__name__}: {exc}")
            return
        if not data:
            return
        t = time.monotonic()
        for line in self._asm.feed(data):
            try:
                self._handle_line(line, t)
            except Exception as exc:  # noqa: BLE001 - one bad line must not stop the reader
                self._garbage(t, line, f"{type(exc).__name__}: {exc}")
                self._report_failure(f"handling {line[:60]!r}", exc, raw=line)

    def _report_failure(self, where: str, exc: BaseException, raw: str = "") -> None:
        self._link_event(LinkKind.NOTE, f"GRBL {self.port}: {where} failed: {type(exc).__name__}: {exc}; "
                                        f"carrying on", raw=raw or traceback.format_exc(limit=4))

    def _garbage(self, t: float, line: str, why: str) -> None:
        with self._cond:
            self.garbage.append((t, line, why))
            self._garbage_seq += 1

    def _handle_line(self, line: str, t: float) -> None:
        try:
            msg = p.parse_line(line)
        except ProtocolError as exc:
            self._garbage(t, line, str(exc))
            return
        if isinstance(msg, p.StatusReport):
            self._on_status(msg, t)
            return
        with self._cond:
            self.messages.append((t, msg))
            self._message_seq += 1
            if isinstance(msg, (p.Ok, p.Error)):
                if self._pending:
                    cmd = self._pending.popleft()
                    self._in_flight -= cmd.nbytes
                    cmd._finish(msg, None, t)
                else:
                    self.unexpected_acks += 1
            elif isinstance(msg, p.Alarm):
                self._alarm = msg.code
                self._alarm_seq += 1
                self.alarms.append((t, msg.code))
                if msg.code in readings.CRITICAL_ALARMS:
                    self._critical = msg.code
                if self._back_pending:
                    self._alarm_since_back = msg.code
            elif isinstance(msg, p.Banner):
                self._on_banner(msg, t)
            else:
                if self._pending:
                    self._pending[0].replies.append(msg)
                if isinstance(msg, p.Setting):
                    self._store_setting(msg, t)
                elif isinstance(msg, p.Offset):
                    self.offsets[msg.name] = msg.values
                elif isinstance(msg, p.ParserState):
                    self.parser_state = msg
                elif isinstance(msg, p.Version):
                    self.version = msg
                elif isinstance(msg, p.Options):
                    self.options = msg
                    if msg.rx_size:
                        self.rx_size = msg.rx_size
                    if msg.blocks:
                        self.planner_blocks = msg.blocks
                elif isinstance(msg, p.Probe):
                    self.probe = msg
            self._cond.notify_all()
        if self.on_message is not None:
            self.on_message(t, msg)

    def _on_banner(self, msg: p.Banner, t: float) -> None:
        """A reset flushes GRBL's RX buffer and planner: lines in flight are gone. Called
        with the lock held."""
        self.banner = msg
        self._banner_seq += 1
        self._critical = None
        self._fail_pending(DriverError(f"GRBL {self.port}: controller reset ({msg.raw})"))
        if self._back_pending:
            self._banner_since_back = msg.raw
        elif self._own_reset:
            self._own_reset = False
        elif not self._handshaking:
            self._queries_due = True  # whoever reset it may have changed its settings
            self._link_event(LinkKind.RESET, f"GRBL {self.port}: the controller reset ({msg.raw}); lines in "
                                             f"flight are lost", raw=msg.raw, t=t)

    def _store_setting(self, msg: p.Setting, t: float) -> None:
        """Keep a ``$N=value`` the controller could have sent; garbage (non-finite, huge,
        a ``$13`` that is not 0/1) is recorded and the last good value kept."""
        value = msg.value
        good = math.isfinite(value) and abs(value) <= MAX_REPORTED_INT
        if msg.number == 13 and value not in (0, 1):
            good = False
        if not good:
            kept = self.settings.get(msg.number)
            self.garbage.append((t, msg.raw, f"setting ${msg.number}={msg.text[:24]!r} is not a value GRBL "
                                             f"reports; kept {kept if kept is not None else 'unknown'}"))
            self._garbage_seq += 1
            return
        self.settings[msg.number] = value

    def _on_status(self, report: p.StatusReport, t: float) -> None:
        prev = self._state
        why = None
        self._reported = report.run_state
        # before any report carried WCO: the offset in force from the handshake's $# and $G
        wco = prev.wco if prev else readings.offset_in_force(self.offsets, self.parser_state, self.settings)
        try:
            state = readings.status_to_state(report, self.settings, wco, t, prev=prev, alarm=self._alarm)
            why = implausible(state)
            no_offset = False
        except readings.OffsetUnknown as exc:
            why, no_offset = str(exc), True
        except Exception as exc:  # noqa: BLE001 - a report that cannot be converted is a bad one
            why, no_offset = f"cannot convert it ({type(exc).__name__}: {exc})", False
        with self._cond:
            if why is None:
                self._state = reply = state
            else:
                reply = stale_state(prev, RunState.BAD, t, f"{why}: {report.raw}")
                if not (no_offset and self._offset_told):   # told once, not for each of 30 reports
                    self._link_event(LinkKind.BAD, f"GRBL {self.port}: status report skipped: {why}",
                                     raw=report.raw, t=t)
            self._offset_told = no_offset
            self._reply = reply
            self._reply_seq += 1
            if self._back_pending:
                self._came_back(reply, t)
            self._cond.notify_all()
        if self._reported is RunState.IDLE and self._queries_due:
            self._start_queries()
        if self.on_state is not None:
            self.on_state(reply)

    def _fail_pending(self, failure: DriverError) -> None:
        t = time.monotonic()
        while self._pending:
            self._pending.popleft()._finish(None, failure, t)
        self._in_flight = 0

    # ------------------------------------------------------------------ reconnect

    def _lost(self, reason: str) -> None:
        t = time.monotonic()
        with self._cond:
            self._connected = False
            self._back_pending = False
            if not self._in_gap:  # a port that reopened and died before any report: the same gap
                self._in_gap = True
                self._t_lost = t
                self._lost_reason = reason
                self._gap_polls = 0
                self._lines_lost = 0
                self._link_event(LinkKind.LOST, f"GRBL {self.port}: link lost ({reason}); retrying every "
                                                f"{self.retry_period:g} s", t=t)
            self._lines_lost += len(self._pending)
            self._fail_pending(ConnectionLost(f"GRBL {self.port}: connection lost ({reason})"))
            self._cond.notify_all()
        _close_port(self._ser)
        self._asm.reset()

    def _try_reopen(self) -> None:
        """One attempt to reopen the port; on failure wait :attr:`retry_period`."""
        try:
            ser = self._open_port()
        except ConnectionLost:
            self._closing.wait(self.retry_period)  # retry pacing, interruptible by close()
            return
        with self._cond:
            if self._closing.is_set():
                ser.close()
                return
            self._ser = ser
            self._connected = True
            # the outage ends with the first report: it says how the controller came back
            self._back_pending = True
            self._banner_since_back = ""
            self._alarm_since_back = None
            self._cond.notify_all()

    def _came_back(self, reply: MachineState, t: float) -> None:
        """The first report after reopening: close the gap, say how the controller came
        back, and have the handshake queries done again. Called with the lock held."""
        how = []
        if self._banner_since_back:
            how.append(f"reset: {self._banner_since_back}")
        if reply.state is RunState.ALARM:
            code = self._alarm_since_back
            how.append(f"in alarm {code} ({p.alarm_meaning(code)})" if code is not None else "in alarm")
        gap = Gap(self._t_lost, t, self._lost_reason, self._gap_polls, self._lines_lost, "; ".join(how))
        self.gaps.append(gap)
        self._in_gap = self._back_pending = False
        self._queries_due = True
        self._link_event(LinkKind.BACK, f"GRBL {self.port}: link back after {gap.seconds:.2f} s "
                                        f"({gap.polls_missed} polls missed, {gap.lines_lost} lines lost)",
                         raw=reply.raw, gap=gap, t=t)
        if gap.came_back:
            self._link_event(LinkKind.RESET, f"GRBL {self.port}: the controller came back {gap.came_back}",
                             raw=reply.raw, gap=gap, t=t)

    # ------------------------------------------------------------------ writing

    def _write(self, data: bytes) -> None:
        if not self._connected:
            raise ConnectionLost(f"GRBL {self.port}: not connected")
        try:
            with self._write_lock:
                self._ser.write(data)
        except Exception as exc:  # noqa: BLE001 - the reader notices and reconnects
            raise ConnectionLost(f"GRBL {self.port}: write failed ({exc})") from exc

    def write_realtime(self, byte: bytes) -> None:
        """Send one real-time byte (``?`` ``!`` ``~`` 0x18, overrides); GRBL acts at once."""
        if len(byte) != 1 or byte[0] not in p.REALTIME_BYTES:
            raise ValueError(f"not a GRBL real-time byte: {byte!r}")
        self._write(byte)

    # ------------------------------------------------------------------ state

    @property
    def last_state(self) -> MachineState | None:
        return self._state

    def machine_limits(self):
        """The machine's limits from the ``$$`` settings read (see
        :func:`drivers.grbl.readings.settings_limits`), or None before ``$$`` was read
        (attached to a busy machine, it is read once the machine is Idle)."""
        with self._cond:
            settings = dict(self.settings)
            codes = self.options.codes if self.options is not None else ""
        return readings.settings_limits(settings, f"GRBL $$ on {self.port}", codes)

    def poll(self, timeout: float | None = None) -> MachineState:
        """Ask ``?`` and return the report it brings, stamped at arrival; never raises.

        Only a report that arrived after this ``?`` is returned, as it is (or as a BAD
        state when its numbers cannot be right, see :func:`drivers.state.implausible`).
        No report within ``timeout`` s (default ``min(timeout, 0.5)``; GRBL does not
        answer while homing; a garbled or lost reply): a MISSED state stamped now. While
        the port is away: a DISCONNECTED state. Both at the last known position.
        """
        timeout = min(self.timeout, 0.5) if timeout is None else timeout
        try:
            return self._ask(timeout)
        except Exception as exc:  # noqa: BLE001 - the contract: poll never raises once connected
            kind = RunState.MISSED if self._connected else RunState.DISCONNECTED
            return self._not_fresh(kind, f"poll failed: {type(exc).__name__}: {exc}")

    def _ask(self, timeout: float) -> MachineState:
        with self._cond:
            connected = self._connected
            seq, garbage0 = self._reply_seq, self._garbage_seq
        if not connected:
            return self._not_fresh(RunState.DISCONNECTED, f"port {self.port} away: {self._lost_reason or 'not open'}")
        t_ask = time.monotonic()
        try:
            self._write(p.RT_STATUS)
        except ConnectionLost as exc:
            return self._not_fresh(RunState.DISCONNECTED, str(exc))

        def answered() -> bool:
            return self._reply_seq > seq and self._reply.t >= t_ask

        with self._cond:
            self._cond.wait_for(lambda: answered() or not self._connected, timeout)
            if not self._connected:
                return self._not_fresh(RunState.DISCONNECTED, f"port {self.port} lost: {self._lost_reason}")
            if answered() and self._reply.t >= self._last_t:
                reply = self._reply
                self._last_t = reply.t
                if not reply.fresh:
                    self.poll_counts[reply.state] += 1
                return reply
            garbled = list(self.garbage)[-min(self._garbage_seq - garbage0, 3):] if self._garbage_seq > garbage0 else []
            critical = self._critical
        if critical is not None:
            return self._silent_alarm(critical)
        why = f"no status report within {timeout:g} s after '?'"
        if garbled:
            why += "; garbled: " + "; ".join(f"{line[:100]!r} ({err[:100]})" for _, line, err in garbled)
        return self._not_fresh(RunState.MISSED, why)

    def _silent_alarm(self, code: int) -> MachineState:
        """Alarm ``code`` that GRBL will not report (see :func:`readings.critical_alarm_state`)."""
        with self._cond:
            t = max(time.monotonic(), self._last_t)
            self._last_t = t
            return readings.critical_alarm_state(self._state, code, t)

    def _not_fresh(self, kind: RunState, why: str) -> MachineState:
        """A ``kind`` (MISSED/DISCONNECTED) state stamped now, at the last known position."""
        with self._cond:
            t = max(time.monotonic(), self._last_t)
            self._last_t = t
            self.poll_counts[kind] += 1
            if self._in_gap:
                self._gap_polls += 1
            return stale_state(self._state, kind, t, why)

    def states(self, period: float | None = None) -> Iterator[MachineState]:
        """Yield a polled state every ``period`` s (default ``1/rate``) until closed."""
        period = 1.0 / self.rate if period is None else max(float(period), 1.0 / MAX_RATE_HZ)
        next_t = time.monotonic()
        while not self._closing.is_set():
            yield self.poll()
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._closing.wait(delay)  # pacing the poll loop
            else:
                next_t = time.monotonic()

    def wait_for_state(self, predicate: Callable[[MachineState], bool], timeout: float) -> MachineState:
        """Poll until ``predicate(state)`` holds; return that state (DriverError on timeout)."""
        deadline = time.monotonic() + timeout
        period = 1.0 / MAX_RATE_HZ
        while True:
            s = self.poll()
            if predicate(s):
                return s
            if time.monotonic() > deadline:
                raise DriverError(f"GRBL {self.port}: state {s.state.value} did not reach the expected one "
                                  f"within {timeout:g} s")
            self._closing.wait(period)

    # ------------------------------------------------------------------ real-time commands

    def feed_hold(self) -> None:
        self.write_realtime(p.RT_FEED_HOLD)

    def resume(self) -> None:
        self.write_realtime(p.RT_CYCLE_START)

    def soft_reset(self, wait: bool = True) -> p.Banner | None:
        """Ctrl-X: GRBL stops at once (ALARM:3 if moving) and prints its banner."""
        with self._cond:
            b0 = self._banner_seq
            self._own_reset = True  # its banner is no news
        self.write_realtime(p.RT_SOFT_RESET)
        if not wait:
            return None
        with self._cond:
            if not self._cond.wait_for(lambda: self._banner_seq > b0, self.timeout):
                raise DriverError(f"GRBL {self.port}: no banner within {self.timeout:g} s after soft reset "
                                  f"(is it a GRBL 1.1 controller at {self.baud} baud?)")
        return self.banner

    def unlock(self) -> None:
        """``$X``: leave the alarm state."""
        self.command("$X")

    def _set_override(self, kind: str, target: int) -> int:
        idx = {"feed": 0, "rapid": 1, "spindle": 2}[kind]
        state = self.poll()
        current = state.overrides[idx]
        for byte in p.override_steps(current, target, kind):
            before = current
            self.write_realtime(byte)
            # identical override bytes in one burst may count once: wait until each shows
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                current = self.poll().overrides[idx]
                if current != before:
                    break
        return current

    def set_feed_override(self, percent: int) -> int:
        """Bring the feed override to ``percent`` (10..200); returns the value GRBL reports."""
        return self._set_override("feed", percent)

    def set_rapid_override(self, percent: int) -> int:
        """Rapid override 100, 50 or 25 %."""
        return self._set_override("rapid", percent)

    def set_spindle_override(self, percent: int) -> int:
        """Spindle override 10..200 %."""
        return self._set_override("spindle", percent)


def _close_port(ser) -> None:
    """Close ``ser`` at once, whatever state it is in. pyserial's ``socket://`` close()
    sleeps 0.3 s "for quick reconnects", which would delay the reconnect and every
    close: its socket is closed first and the port marked closed."""
    sock = getattr(ser, "_socket", None)
    try:
        if sock is not None:
            ser._socket = None
            ser.is_open = False
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()
        else:
            ser.close()
    except Exception:  # noqa: BLE001 - closing a port that may be half gone
        pass


def read_available(ser, wait: float) -> bytes:
    """Bytes available on ``ser`` within ``wait`` s (b"" when none); raises when the port is gone."""
    if ser is None or not ser.is_open:
        raise ConnectionLost("port closed")
    try:
        fd = ser.fileno()
    except Exception:  # noqa: BLE001 - URL handlers without a descriptor (loop://)
        fd = None
    if fd is None:
        ser.timeout = wait
        data = ser.read(1)
        ser.timeout = 0
        return data + ser.read(4096) if data else data
    ready, _, _ = select.select([fd], [], [], wait)
    if not ready:
        return b""
    data = ser.read(4096)
    if not data:
        raise ConnectionLost("port readable but returned no data (device disconnected)")
    return data


def _state_name(state: MachineState) -> str:
    """``Door:2``, ``Run``, or what a not-fresh state is."""
    if state.substate is not None:
        return f"{state.state.value}:{state.substate}"
    return state.state.value


def _inches_by_format(raw: str) -> bool:
    """Whether a status report's text says inches by its format (4 decimals)."""
    try:
        return readings.report_in_inches(p.parse_status(raw))
    except ProtocolError:
        return False


def url_params(url: str, known: dict[str, Callable[[str], object]]) -> dict[str, object]:
    """The query parameters of controller URL ``url``, each converted by ``known[name]``
    (``int``, ``float``, ``str``); the last of repeated names wins. Raises DriverError
    naming the URL for a name not in ``known`` or a value its converter refuses."""
    kw = {}
    for key, value in dict(parse_qsl(urlsplit(url).query, keep_blank_values=True)).items():
        if key not in known:
            raise DriverError(f"controller URL {url!r}: unknown parameter {key!r}; expected one of {', '.join(known)}")
        try:
            kw[key] = known[key](value)
        except ValueError:
            raise DriverError(f"controller URL {url!r}: parameter {key}={value!r} is not a number") from None
    return kw


def from_url(url: str) -> GrblController:
    """A :class:`GrblController` for ``url`` (not connected). See the module docstring."""
    parts = urlsplit(url)
    scheme = parts.scheme
    if scheme in ("grbl", "grbl+pty"):
        port = parts.path if not parts.netloc else parts.netloc + parts.path
        if not port:
            raise DriverError(f"controller URL {url!r}: expected a device path, e.g. grbl:///dev/ttyUSB0")
    elif scheme.startswith("grbl+"):
        inner = scheme[5:]
        port = f"{inner}://{parts.netloc}{parts.path}"
        if not parts.netloc:
            raise DriverError(f"controller URL {url!r}: expected host:port, e.g. grbl+socket://127.0.0.1:2323")
    else:
        raise DriverError(f"controller URL {url!r}: not a GRBL URL (grbl://, grbl+socket://, grbl+pty://)")
    kw = url_params(url, {"baud": int, "rate": float, "timeout": float, "reset": int, "reconnect": int})
    return GrblController(
        port,
        baud=kw.get("baud", 115200),
        rate=kw.get("rate", DEFAULT_RATE_HZ),
        timeout=kw.get("timeout", 2.0),
        reset_on_connect=bool(kw.get("reset", 0)),
        reconnect=bool(kw.get("reconnect", 1)),
        url=url,
    )
