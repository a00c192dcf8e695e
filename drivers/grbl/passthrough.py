"""Sit between a GRBL machine and the user's own sender (UGS, CNCjs, bCNC, gSender).

:class:`Passthrough` opens the machine's port and offers a pseudo-terminal (and
optionally a TCP port) to the sender. Bytes go both ways unchanged, line by line, while
the passthrough

* learns every line the sender streams, in order, with the ``ok``/``error:N`` it got
  (GRBL acknowledges lines in order, so acknowledgements pair with lines);
* reads the status reports that pass by and turns them into :class:`MachineState`
  (``$$`` replies passing by teach it ``$13`` inches and the rest);
* polls ``?`` on its own when reports do not come at its rate, and takes exactly the
  replies to its own polls out of the sender's stream.

Poll accounting: at most one own ``?`` is outstanding. A status report goes to the
sender when the sender has one outstanding, otherwise it answers an own poll and is
swallowed. A sender ``?`` that arrives while an own poll is outstanding is not sent
again: the report on its way is handed to the sender instead (GRBL may answer two close
``?`` with one report, so sending both could leave a reply nobody asked for).

As a :class:`~drivers.state.Controller` it keeps the driver/monitor contract: ``poll()``
returns a report that arrived after it was called, else MISSED (BAD for numbers no machine
has, DISCONNECTED while the machine's port is away) and never raises; the port is reopened
every :data:`RETRY_S` while gone, each outage is a :class:`~drivers.state.Gap` and LOST /
BACK link events (RESET when the controller's banner passes); no thread dies quietly. The
machine's output is never held up by a sender (see :mod:`drivers.grbl.endpoints`): lines
nobody understands reach the sender unchanged.

URLs (see :func:`from_url`; registered in :mod:`drivers.registry`)::

    grbl+passthrough:///dev/ttyUSB0?tcp=2323            machine on a serial device
    grbl+passthrough+socket://192.168.1.50:23?pty=1     machine over TCP (pyserial socket://)

Query parameters: ``baud`` (115200), ``rate`` (reports/s, 20), ``pty`` (1: offer a
pseudo-terminal; 0: TCP only), ``link`` (a symlink to the pty, a stable path for the
sender), ``tcp`` (also offer this TCP port; 0: any free one), ``host`` (the address the
TCP port listens on, 127.0.0.1).
"""

from __future__ import annotations

import collections
import dataclasses
import math
import re
import threading
import time
from dataclasses import dataclass
from typing import Callable
from urllib.parse import urlsplit

import serial

from drivers.errors import ConnectionLost, DriverError, ProtocolError
from drivers.grbl import protocol as p
from drivers.grbl import readings
from drivers.grbl.driver import read_available, url_params
from drivers.grbl.endpoints import Endpoint, PtyEndpoint, TcpEndpoint
from drivers.state import (Controller, Gap, LinkKind, MachineState, RunState, check_device, implausible,
                           stale_state)

#: a ``$N=value`` line (spaces dropped): a setting the sender writes
_SETTING_LINE = re.compile(r"\$(\d+)=([-+]?(?:\d+\.?\d*|\.\d+))")
#: Grbl 1.1h's on/off settings (invert step enable, limit and probe pins, report inches,
#: soft limits, hard limits, homing, laser mode)
_FLAG_SETTINGS = frozenset({4, 5, 6, 13, 20, 21, 22, 32})
_MAX_HELD = 512  # bytes of an unterminated line held before passing them on anyway
#: pause between attempts to reopen the machine's port while it is gone, s (never grows:
#: a backoff would cost more than the outage)
RETRY_S = 0.05
#: a ``?`` unanswered this long is given up (its reply was garbled or lost), s: own polls
#: resume and a late report goes to the sender
QUERY_TIMEOUT_S = 0.5


@dataclass
class LearnedLine:
    """A line the sender streamed: order ``index`` (0-based), text as sent (no line end),
    ``n`` its N word if any, times (monotonic s), and the controller's answer
    (``"ok"``, ``"error:N"``, ``"reset"``, ``"lost"`` when the machine's port went away
    before it answered or was away when the line was sent, or None while in flight)."""

    index: int
    text: str
    t_sent: float
    n: int | None = None
    result: str | None = None
    t_ack: float | None = None

    @property
    def error_code(self) -> int | None:
        if self.result and self.result.startswith("error:"):
            return int(self.result[6:])
        return None


class Passthrough(Controller):
    """Forward a sender's bytes to a GRBL machine and back, watching as they pass.

    Parameters
    ----------
    machine_port_url : str
        The machine's port: a device path, any pyserial URL (``socket://h:p``) or a
        ``grbl://`` / ``grbl+socket://`` controller URL.
    baud : int
    rate : float
        Status reports per second wanted (own polls fill in when the sender polls less).
    pty : bool
        Offer a pseudo-terminal to the sender (``sender_path``).
    tcp_port : int or None
        Also offer a TCP port (0: any free one; ``sender_port`` after :meth:`start`).
    link : str or None
        Symlink to the pty, a stable path to give the sender.
    """

    def __init__(self, machine_port_url: str, baud: int = 115200, rate: float = 20.0, pty: bool = True,
                 tcp_port: int | None = None, tcp_host: str = "127.0.0.1", link: str | None = None):
        if machine_port_url.startswith("grbl"):
            from drivers.grbl.driver import from_url

            ctl = from_url(machine_port_url)
            machine_port_url, baud, rate = ctl.port, ctl.baud, ctl.rate
        if not 0 < rate <= 50:
            raise DriverError(f"passthrough: rate must be in (0, 50] reports/s, got {rate:g}")
        self.port = machine_port_url
        self.url = machine_port_url
        self.baud = int(baud)
        self.rate = float(rate)
        self._want_pty, self._tcp_port, self._tcp_host, self._link = pty, tcp_port, tcp_host, link
        self.sender_path: str | None = None
        self.sender_port: int | None = None
        # what was learned
        self.lines: list[LearnedLine] = []
        self.settings: dict[int, float] = {}
        self.messages: collections.deque[tuple[float, p.Message]] = collections.deque(maxlen=1000)
        self.states_seen: collections.deque[MachineState] = collections.deque(maxlen=10000)
        self.alarms: list[tuple[float, int]] = []
        self.gaps: list[Gap] = []
        self.own_polls = 0
        self.swallowed = 0
        #: '?' (own or the sender's) whose report never came within QUERY_TIMEOUT_S
        self.queries_expired = 0
        self.on_state: Callable[[MachineState], None] | None = None
        self.on_line: Callable[[LearnedLine], None] | None = None
        # machinery
        self._ser = None
        self._endpoints: list[Endpoint] = []
        self._cond = threading.Condition()
        self._machine_write = threading.Lock()
        self._sender_rx = bytearray()       # sender's partial line
        self._machine_rx = bytearray()      # machine's partial line
        self._awaiting: collections.deque[LearnedLine | None] = collections.deque()  # None: an empty line
        self._sender_pending = 0
        self._own_pending = 0
        self._last_report_t = 0.0
        self._state: MachineState | None = None     # the newest plausible state
        self._latest: MachineState | None = None    # the newest reading: _state or a BAD one
        self._bad_run = False                       # the newest reports were implausible
        self._query_t: float | None = None          # when the oldest unanswered '?' went out
        self._status_seq = 0
        self._last_t = 0.0                          # t of the state poll() returned last
        # the outage under way: since when, why, what it cost
        self._t_lost = 0.0
        self._lost_reason = "not connected yet"
        self._polls_missed = 0
        self._lines_lost = 0
        self._failures: collections.Counter = collections.Counter()
        self._alarm: int | None = None
        #: ``$#`` lines (name -> values as sent) and the ``$G`` state that passed by
        self.offsets: dict[str, tuple[float, ...]] = {}
        self.parser_state: p.ParserState | None = None
        # a hard/soft limit ALARM code since the last reset: GRBL answers no "?" until
        # Ctrl-X, so polls report the alarm from it (see readings.critical_alarm_state)
        self._critical: int | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._connected = False
        self._asm = p.LineAssembler()

    # ------------------------------------------------------------------ life cycle

    def start(self) -> str | None:
        """Open the machine's port and the sender's endpoints; return the sender's pty path."""
        self._ser = self._open()
        self._connected = True
        if self._want_pty:
            ep = PtyEndpoint(self._from_sender, self._link, on_event=self._endpoint_event)
            self._endpoints.append(ep)
            self.sender_path = ep.path
        if self._tcp_port is not None:
            ep = TcpEndpoint(self._from_sender, self._tcp_host, self._tcp_port, on_event=self._endpoint_event)
            self._endpoints.append(ep)
            self.sender_port = ep.port
        for target, name in ((self._machine_loop, "passthrough machine"), (self._poll_loop, "passthrough poller")):
            th = threading.Thread(target=target, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        return self.sender_path

    def connect(self) -> None:
        if not self._threads:
            self.start()

    def close(self) -> None:
        self._stop.set()
        for ep in self._endpoints:
            ep.close()
        self._endpoints = []
        for th in self._threads:  # first: a reconnect under way must not open a port after this
            th.join(2.0)
        self._threads = []
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # noqa: BLE001
                pass
        with self._cond:
            self._connected = False
            self._cond.notify_all()

    def preflight(self) -> None:
        check_device(self.port, "passthrough: the machine's port")

    def _open(self):
        try:
            return serial.serial_for_url(self.port, baudrate=self.baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"passthrough: cannot open machine port {self.port!r}: {exc}") from exc

    # ------------------------------------------------------------------ sender -> machine

    def _endpoint_event(self, endpoint: Endpoint, kind: str, message: str) -> None:
        """An endpoint's news (from its threads): dropped output and failures become
        NOTE link events; a sender coming or going wakes :meth:`wait_sender_closed`."""
        if kind in ("dropping", "error"):
            self._link_event(LinkKind.NOTE, f"passthrough {message}")
        with self._cond:
            self._cond.notify_all()

    def _from_sender(self, endpoint: Endpoint, data: bytes) -> None:
        out = bytearray()
        t = time.monotonic()
        with self._cond:
            for b in data:
                if b == 0x3F:  # '?'
                    if self._own_pending:
                        # the report on its way answers the sender instead of us
                        self._own_pending -= 1
                        self._sender_pending += 1
                        continue
                    self._sender_pending += 1
                    self._asked(t)
                    out.append(b)
                    continue
                out.append(b)
                if b in p.REALTIME_BYTES:
                    continue
                if b in (0x0A, 0x0D):
                    try:
                        self._end_sender_line(t)
                    except Exception as exc:  # noqa: BLE001 - learning must never stop forwarding
                        self._failed("learning a sender line", exc)
                else:
                    self._sender_rx.append(b)
        if out:
            self._write_machine(bytes(out))

    def _asked(self, t: float) -> None:
        """A '?' went out at ``t``: time it, unless an older one is still unanswered."""
        if self._query_t is None:
            self._query_t = t

    def _end_sender_line(self, t: float) -> None:
        text = self._sender_rx.decode("latin-1").strip()
        self._sender_rx.clear()
        if not text:
            if self._connected:
                self._awaiting.append(None)  # GRBL answers an empty line with ok too
            return
        line = LearnedLine(len(self.lines), text, t)
        stripped = text.lstrip().upper()
        if stripped.startswith("N"):
            digits = ""
            for ch in stripped[1:]:
                if ch.isdigit():
                    digits += ch
                elif ch != " " or digits:
                    break
            line.n = int(digits) if digits else None
        self.lines.append(line)
        if self._connected:
            self._awaiting.append(line)
        else:  # its bytes go nowhere, as with a pulled cable: never answered
            line.result, line.t_ack = "lost", t
            self._lines_lost += 1
        self._cond.notify_all()
        if self.on_line is not None:
            self._call(self.on_line, line)

    def _write_machine(self, data: bytes) -> None:
        ser = self._ser
        if ser is None or not self._connected:
            return  # the machine is away: bytes are lost, as with a pulled cable
        try:
            with self._machine_write:
                ser.write(data)
        except Exception:  # noqa: BLE001 - the machine loop notices and reconnects
            pass

    # ------------------------------------------------------------------ machine -> sender

    def _machine_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._read_machine()
            except Exception as exc:  # noqa: BLE001 - the machine's port went away
                if self._stop.is_set():
                    return
                self._lose(str(exc) or type(exc).__name__)
                if not self._reconnect():
                    return
                continue
            if data:
                try:
                    self._from_machine(data, time.monotonic())
                except Exception as exc:  # noqa: BLE001 - the reader must outlive any chunk
                    self._failed("handling machine output", exc, data)

    def _read_machine(self) -> bytes:
        """What the machine sent within 0.05 s (b"" if nothing); raises if the port is gone."""
        return read_available(self._ser, 0.05)

    def _lose(self, reason: str) -> None:
        """The machine's port went away: fail what was in flight, say so."""
        t = time.monotonic()
        with self._cond:
            self._connected = False
            self._t_lost, self._lost_reason, self._polls_missed = t, reason, 0
            self._lines_lost = self._fail_awaiting("lost", t)
            self._own_pending = self._sender_pending = 0
            self._query_t = None
            self._machine_rx.clear()
            self._asm.reset()
            self._cond.notify_all()
        self._link_event(LinkKind.LOST, f"passthrough: machine port {self.port} lost ({reason}); "
                                        f"retrying every {RETRY_S:g} s", t=t)
        try:
            self._ser.close()
        except Exception:  # noqa: BLE001 - already gone
            pass

    def _reconnect(self) -> bool:
        """Reopen the machine's port every RETRY_S until it opens (True) or close() (False)."""
        while not self._stop.wait(RETRY_S):  # retry pacing, interruptible by close()
            try:
                ser = self._open()
            except Exception:  # noqa: BLE001 - still gone
                continue
            t = time.monotonic()
            with self._cond:
                if self._stop.is_set():
                    ser.close()
                    return False
                self._ser = ser
                self._connected = True
                self._own_pending = self._sender_pending = 0  # '?' sent into the void meanwhile
                self._query_t = None
                gap = Gap(self._t_lost, t, self._lost_reason, self._polls_missed, self._lines_lost)
                self.gaps.append(gap)
                self._cond.notify_all()
            self._link_event(LinkKind.BACK, f"passthrough: machine port {self.port} back after "
                                            f"{gap.seconds:.2f} s ({gap.polls_missed} poll(s) missed, "
                                            f"{gap.lines_lost} line(s) lost)", gap=gap, t=t)
            return True
        return False

    def _fail_awaiting(self, result: str, t: float) -> int:
        """Give every line awaiting its answer ``result`` (under ``_cond``); return how many."""
        n = 0
        for line in self._awaiting:
            if line is not None:
                line.result, line.t_ack = result, t
                n += 1
        self._awaiting.clear()
        return n

    def _from_machine(self, data: bytes, t: float) -> None:
        self._machine_rx += data
        forward = bytearray()
        while True:
            i = self._machine_rx.find(b"\n")
            if i < 0:
                break
            raw = bytes(self._machine_rx[: i + 1])
            del self._machine_rx[: i + 1]
            try:
                keep = self._route_line(raw, t)
            except Exception as exc:  # noqa: BLE001 - a line nobody understands still reaches the sender
                self._failed("reading a machine line", exc, raw)
                keep = True
            if keep:
                forward += raw
        if len(self._machine_rx) > _MAX_HELD:  # no line end coming: pass the noise on
            forward += self._machine_rx
            self._machine_rx.clear()
        if forward:
            for ep in list(self._endpoints):
                ep.write(bytes(forward))  # never blocks (see drivers.grbl.endpoints)

    def _route_line(self, raw: bytes, t: float) -> bool:
        """Learn from one machine line; True if the sender gets it."""
        texts = self._asm.feed(raw)
        if not texts:
            return True
        text = texts[-1]
        try:
            msg = p.parse_line(text)
        except ProtocolError:
            return True
        with self._cond:
            if isinstance(msg, p.StatusReport):
                to_sender = self._answer_query()
                self._on_status(msg, t)
                return to_sender
            self.messages.append((t, msg))
            if isinstance(msg, (p.Ok, p.Error)):
                while self._awaiting:
                    line = self._awaiting.popleft()
                    if line is None:
                        break
                    line.result, line.t_ack = msg.raw.strip(), t
                    if isinstance(msg, p.Ok):
                        self._learn_from_line(line.text)
                    break
            elif isinstance(msg, p.Banner):
                self._critical = None
                self._fail_awaiting("reset", t)
                self._sender_pending = self._own_pending = 0
                self._query_t = None
                self._link_event(LinkKind.RESET, f"passthrough: the controller on {self.port} reset "
                                                 f"({text.strip()})", raw=text, t=t)
            elif isinstance(msg, p.Alarm):
                self._alarm = msg.code
                self.alarms.append((t, msg.code))
                if msg.code in readings.CRITICAL_ALARMS:
                    self._critical = msg.code
            elif isinstance(msg, p.Setting) and math.isfinite(msg.value):
                self.settings[msg.number] = msg.value  # a value no number names is not learned
            elif isinstance(msg, p.Offset):   # $# and $G passing by: the work offset in force
                self.offsets[msg.name] = msg.values
            elif isinstance(msg, p.ParserState):
                self.parser_state = msg
            self._cond.notify_all()
        return True

    def _learn_from_line(self, text: str) -> None:
        """A sender line Grbl accepted (under ``_cond``): ``$N=value`` sets a setting (``$13``
        turns the reports to inches at once); ``$RST=$`` / ``$RST=*`` restore the defaults,
        so every setting is unknown until the next ``$$`` passes (the report format then
        says the units)."""
        cmd = "".join(text.split()).upper()   # Grbl drops spaces and reads letters upper case
        m = _SETTING_LINE.fullmatch(cmd)
        if m:
            number, value = int(m.group(1)), float(m.group(2))
            # settings.c keeps these as flags: any non-zero value reads back as 1
            self.settings[number] = float(value != 0) if number in _FLAG_SETTINGS else value
        elif cmd in ("$RST=$", "$RST=*"):
            self.settings.clear()

    def _answer_query(self) -> bool:
        """A status report arrived (under ``_cond``): whose '?' it answers; True if the
        sender's (or nobody's: the sender gets what it did not ask for, as from GRBL)."""
        to_sender = True
        if self._sender_pending:
            self._sender_pending -= 1
            if self._own_pending:
                self._own_pending -= 1
        elif self._own_pending:
            self._own_pending -= 1
            self.swallowed += 1
            to_sender = False
        self._query_t = time.monotonic() if self._sender_pending or self._own_pending else None
        return to_sender

    def _on_status(self, report: p.StatusReport, t: float) -> None:
        """Turn a report into the newest reading (under ``_cond``): a state, or BAD when
        its numbers cannot be right (the last plausible state is kept)."""
        prev = self._state
        # before any report carried WCO: the offset in force from the sender's $# and $G
        wco = prev.wco if prev else readings.offset_in_force(self.offsets, self.parser_state, self.settings)
        try:
            state = readings.status_to_state(report, self.settings, wco, t, prev=prev, alarm=self._alarm)
            why = implausible(state)
        except readings.OffsetUnknown as exc:
            state, why = None, str(exc)
        except (ArithmeticError, ValueError) as exc:  # numbers no machine has
            state, why = None, f"cannot be converted ({type(exc).__name__}: {exc})"
        self._status_seq += 1
        self._last_report_t = t
        if why is not None:
            self._latest = stale_state(prev, RunState.BAD, t, f"{why}: {report.raw}")
            if not self._bad_run:  # once per run of bad reports, not 20 times a second
                self._link_event(LinkKind.BAD, f"passthrough {self.port}: status report with {why}; "
                                               "recorded as bad and skipped", raw=report.raw, t=t)
            self._bad_run = True
            self._cond.notify_all()
            return
        self._bad_run = False
        self._state = self._latest = state
        self.states_seen.append(state)
        self._cond.notify_all()
        if self.on_state is not None:
            self._call(self.on_state, state)

    # ------------------------------------------------------------------ own polls

    def _poll_loop(self) -> None:
        period = 1.0 / self.rate
        while not self._stop.wait(period / 4):  # pacing the poll clock
            try:
                self._poll_once(period)
            except Exception as exc:  # noqa: BLE001 - the poller must not die quietly
                self._failed("polling", exc)

    def _poll_once(self, period: float) -> None:
        """Send an own '?' when reports do not come at ``period`` and none is outstanding;
        give up a '?' unanswered for QUERY_TIMEOUT_S."""
        with self._cond:
            now = time.monotonic()
            if self._query_t is not None and now - self._query_t > QUERY_TIMEOUT_S:
                self.queries_expired += self._own_pending + self._sender_pending
                self._own_pending = self._sender_pending = 0
                self._query_t = None
            quiet = now - self._last_report_t >= period
            send = quiet and self._connected and not self._own_pending and not self._sender_pending
            if send:
                self._own_pending += 1
                self.own_polls += 1
                self._asked(now)
        if send:
            self._write_machine(p.RT_STATUS)

    # ------------------------------------------------------------------ failures

    def _call(self, callback: Callable, arg) -> None:
        """Call a user's callback; its exception is reported, never fatal to the caller."""
        try:
            callback(arg)
        except Exception as exc:  # noqa: BLE001 - the monitor's bug must not stop the machine's path
            self._failed(f"callback {getattr(callback, '__name__', callback)!r}", exc)

    def _failed(self, doing: str, exc: BaseException, raw: bytes = b"") -> None:
        """A failure inside the passthrough: a NOTE the first time it happens (then counted
        in ``failures``), and the thread goes on."""
        message = f"passthrough {self.port}: {doing} failed: {type(exc).__name__}: {exc}"
        self._failures[message] += 1
        if self._failures[message] == 1:
            self._link_event(LinkKind.NOTE, message, raw=raw.decode("latin-1")[:200])

    @property
    def failures(self) -> dict[str, int]:
        """Failures inside the passthrough that were survived: message -> times."""
        return dict(self._failures)

    # ------------------------------------------------------------------ Controller

    @property
    def last_state(self) -> MachineState | None:
        return self._state

    def machine_limits(self):
        """The machine's limits from the ``$$`` replies the sender's traffic showed (see
        :func:`drivers.grbl.readings.settings_limits`), or None until a sender asked."""
        return readings.settings_limits(dict(self.settings), f"GRBL $$ seen on {self.port}")

    @property
    def learned_lines(self) -> list[LearnedLine]:
        """Every line the sender streamed, in order (appended as they pass)."""
        return self.lines

    @property
    def sender_endpoints(self) -> dict:
        """Where the sender connects, after :meth:`start`: ``pty`` path and/or ``tcp``
        port (with ``host``), and the ``machine`` port they lead to."""
        out: dict = {"machine": self.port}
        if self.sender_path:
            out["pty"] = self.sender_path
        if self.sender_port is not None:
            out["tcp"] = self.sender_port
            out["host"] = self._tcp_host
        return out

    def poll(self, timeout: float = 0.5) -> MachineState:
        """The first status report that arrives after the call (the reply to an own poll
        or to the sender's), stamped at arrival. Never the same state twice: MISSED
        (stamped now, at the last known position) when none comes within ``timeout`` s,
        BAD when its numbers cannot be right, DISCONNECTED while the machine's port is
        away. Never raises."""
        with self._cond:
            seq = self._status_seq
            self._cond.wait_for(lambda: self._status_seq > seq or not self._connected, timeout)
            connected, fresh = self._connected, self._status_seq > seq
            latest, last, critical = self._latest, self._state, self._critical
            if not connected:
                self._polls_missed += 1
        t = time.monotonic()
        if not connected:
            state = stale_state(last, RunState.DISCONNECTED, t,
                                f"machine port {self.port} lost ({self._lost_reason})")
        elif (not fresh or latest is None) and critical is not None:
            state = readings.critical_alarm_state(last, critical, t)
        elif not fresh or latest is None:
            state = stale_state(last, RunState.MISSED, t, f"no status report within {timeout:g} s")
        else:
            state = latest
        if state.t < self._last_t:  # t never goes backwards
            state = dataclasses.replace(state, t=self._last_t)
        self._last_t = state.t
        return state

    def wait_connected(self, timeout: float) -> bool:
        """Wait until the machine's port is (back) up; True if it is."""
        with self._cond:
            return self._cond.wait_for(lambda: self._connected or self._stop.is_set(), timeout) and self._connected

    def wait_lines(self, count: int, timeout: float, acked: bool = True) -> bool:
        """Wait until ``count`` sender lines were seen (and acknowledged when ``acked``)."""
        with self._cond:
            return self._cond.wait_for(
                lambda: len(self.lines) >= count
                and (not acked or all(line.result is not None for line in self.lines[:count])),
                timeout,
            )

    @property
    def sender_output(self) -> dict[str, dict[str, int]]:
        """Per endpoint (pty path or ``tcp:host:port``): machine output bytes ``dropped``
        (a connected sender did not read them in time), ``discarded`` (nobody had it
        open) and ``buffered`` now."""
        return {ep.name: {"dropped": ep.dropped, "discarded": ep.unheard, "buffered": ep.buffered}
                for ep in self._endpoints}

    @property
    def sender_connected(self) -> bool:
        """A sender has the pty or the TCP port open now."""
        return any(ep.sender_present for ep in self._endpoints)

    def wait_sender_closed(self, timeout: float | None = None, grace: float = 1.0) -> bool:
        """Keep serving the sender until it disconnects: True once no sender has any
        endpoint open (none ever did counts) and none opened one again within ``grace``
        s; False when ``timeout`` s (None: no limit) passed first or the passthrough
        closed.

        A TCP sender disconnects by closing its connection; a pty sender by closing the
        port (the master then hangs up). Bytes keep flowing both ways meanwhile, and a
        sender that closes and reopens the port within ``grace`` is served on."""
        deadline = None if timeout is None else time.monotonic() + timeout

        def left() -> float | None:
            return None if deadline is None else max(0.0, deadline - time.monotonic())

        with self._cond:
            while True:
                if not self._cond.wait_for(lambda: not self.sender_connected or self._stop.is_set(), left()):
                    return False
                if self._stop.is_set():
                    return False
                rest = left()
                if not self._cond.wait_for(lambda: self.sender_connected or self._stop.is_set(),
                                           grace if rest is None else min(grace, rest)):
                    return True
                if self._stop.is_set():
                    return False

    def feed_hold(self) -> None:
        """Hold the machine's feed (the only command the monitor may send)."""
        self._write_machine(p.RT_FEED_HOLD)


def from_url(url: str) -> Passthrough:
    """A :class:`Passthrough` for ``url`` (not started). See the module docstring."""
    parts = urlsplit(url)
    scheme = parts.scheme
    if scheme == "grbl+passthrough":
        port = parts.path if not parts.netloc else parts.netloc + parts.path
        if not port:
            raise DriverError(f"controller URL {url!r}: expected the machine's device path, "
                              "e.g. grbl+passthrough:///dev/ttyUSB0")
    elif scheme.startswith("grbl+passthrough+"):
        inner = scheme[len("grbl+passthrough+"):]
        if not parts.netloc:
            raise DriverError(f"controller URL {url!r}: expected host:port, "
                              "e.g. grbl+passthrough+socket://192.168.1.50:23")
        port = f"{inner}://{parts.netloc}{parts.path}"
    else:
        raise DriverError(f"controller URL {url!r}: not a passthrough URL "
                          "(grbl+passthrough://, grbl+passthrough+socket://)")
    kw = url_params(url, {"baud": int, "rate": float, "pty": int, "tcp": int, "host": str, "link": str})
    if "tcp" in kw and not 0 <= kw["tcp"] <= 65535:
        raise DriverError(f"controller URL {url!r}: tcp={kw['tcp']} is not a TCP port (0-65535)")
    pty = bool(kw.get("pty", 1))
    if not pty and "tcp" not in kw:
        raise DriverError(f"controller URL {url!r}: pty=0 needs tcp=PORT, or the sender has nowhere to connect")
    pt = Passthrough(port, baud=kw.get("baud", 115200), rate=kw.get("rate", 20.0), pty=pty,
                     tcp_port=kw.get("tcp"), tcp_host=kw.get("host", "127.0.0.1"), link=kw.get("link"))
    pt.url = url
    return pt
