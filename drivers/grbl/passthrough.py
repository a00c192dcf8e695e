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
import select
import threading
import time
from dataclasses import dataclass
from typing import Callable
from urllib.parse import urlsplit

import serial

from drivers.errors import ConnectionLost, DriverError, ProtocolError
from drivers.grbl import protocol as p
from drivers.grbl.driver import url_params
from drivers.grbl.endpoints import Endpoint, PtyEndpoint, TcpEndpoint
from drivers.state import Controller, MachineState, RunState

_MAX_HELD = 512  # bytes of an unterminated line held before passing them on anyway


@dataclass
class LearnedLine:
    """A line the sender streamed: order ``index`` (0-based), text as sent (no line end),
    ``n`` its N word if any, times (monotonic s), and the controller's answer
    (``"ok"``, ``"error:N"``, ``"reset"``, ``"lost"`` when the machine's port went away
    before it answered, or None while in flight)."""

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
        self.gaps: list[tuple[float, float]] = []
        self.own_polls = 0
        self.swallowed = 0
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
        self._state: MachineState | None = None
        self._status_seq = 0
        self._alarm: int | None = None
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
            ep = PtyEndpoint(self._from_sender, self._link)
            self._endpoints.append(ep)
            self.sender_path = ep.path
        if self._tcp_port is not None:
            ep = TcpEndpoint(self._from_sender, self._tcp_host, self._tcp_port)
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
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:  # noqa: BLE001
                pass
        for th in self._threads:
            th.join(2.0)
        self._threads = []
        with self._cond:
            self._connected = False
            self._cond.notify_all()

    def _open(self):
        try:
            return serial.serial_for_url(self.port, baudrate=self.baud, timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ConnectionLost(f"passthrough: cannot open machine port {self.port!r}: {exc}") from exc

    # ------------------------------------------------------------------ sender -> machine

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
                    out.append(b)
                    continue
                out.append(b)
                if b in p.REALTIME_BYTES:
                    continue
                if b in (0x0A, 0x0D):
                    self._end_sender_line(t)
                else:
                    self._sender_rx.append(b)
        if out:
            self._write_machine(bytes(out))

    def _end_sender_line(self, t: float) -> None:
        text = self._sender_rx.decode("latin-1").strip()
        self._sender_rx.clear()
        if not text:
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
        self._awaiting.append(line)
        self._cond.notify_all()
        if self.on_line is not None:
            self.on_line(line)

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
        backoff = 0.05
        while not self._stop.is_set():
            ser = self._ser
            try:
                fd = ser.fileno()
                ready, _, _ = select.select([fd], [], [], 0.05)
                if not ready:
                    continue
                data = ser.read(4096)
                if not data:
                    raise ConnectionLost("machine port readable but returned no data")
            except Exception:  # noqa: BLE001 - the machine's port went away
                if self._stop.is_set():
                    return
                t_lost = time.monotonic()
                with self._cond:
                    self._connected = False
                    self._own_pending = 0
                    self._cond.notify_all()
                try:
                    ser.close()
                except Exception:  # noqa: BLE001
                    pass
                while not self._stop.wait(backoff):
                    try:
                        self._ser = self._open()
                    except ConnectionLost:
                        backoff = min(2.0, backoff * 2)
                        continue
                    with self._cond:
                        self._connected = True
                        self.gaps.append((t_lost, time.monotonic()))
                        for line in self._awaiting:  # their acknowledgements went with the port
                            if line is not None:
                                line.result = "lost"
                        self._awaiting.clear()
                        self._sender_pending = 0
                        self._machine_rx.clear()
                        self._cond.notify_all()
                    backoff = 0.05
                    break
                continue
            self._from_machine(data, time.monotonic())

    def _from_machine(self, data: bytes, t: float) -> None:
        self._machine_rx += data
        forward = bytearray()
        while True:
            i = self._machine_rx.find(b"\n")
            if i < 0:
                break
            raw = bytes(self._machine_rx[: i + 1])
            del self._machine_rx[: i + 1]
            if self._route_line(raw, t):
                forward += raw
        if len(self._machine_rx) > _MAX_HELD:  # no line end coming: pass the noise on
            forward += self._machine_rx
            self._machine_rx.clear()
        if forward:
            for ep in list(self._endpoints):
                ep.write(bytes(forward))

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
                self._on_status(msg, t)
                if self._sender_pending:
                    self._sender_pending -= 1
                    if self._own_pending:
                        self._own_pending -= 1
                    return True
                if self._own_pending:
                    self._own_pending -= 1
                    self.swallowed += 1
                    return False
                return True
            self.messages.append((t, msg))
            if isinstance(msg, (p.Ok, p.Error)):
                while self._awaiting:
                    line = self._awaiting.popleft()
                    if line is None:
                        break
                    line.result, line.t_ack = msg.raw.strip(), t
                    break
            elif isinstance(msg, p.Banner):
                for line in self._awaiting:
                    if line is not None:
                        line.result, line.t_ack = "reset", t
                self._awaiting.clear()
                self._sender_pending = self._own_pending = 0
            elif isinstance(msg, p.Alarm):
                self._alarm = msg.code
                self.alarms.append((t, msg.code))
            elif isinstance(msg, p.Setting):
                self.settings[msg.number] = msg.value
            self._cond.notify_all()
        return True

    def _on_status(self, report: p.StatusReport, t: float) -> None:
        prev = self._state
        state = p.status_to_state(report, self.settings, prev.wco if prev else None, t, prev=prev, alarm=self._alarm)
        self._state = state
        self._status_seq += 1
        self._last_report_t = t
        self.states_seen.append(state)
        self._cond.notify_all()
        if self.on_state is not None:
            self.on_state(state)

    # ------------------------------------------------------------------ own polls

    def _poll_loop(self) -> None:
        period = 1.0 / self.rate
        while not self._stop.is_set():
            with self._cond:
                quiet = time.monotonic() - self._last_report_t >= period
                if quiet and self._connected and not self._own_pending and not self._sender_pending:
                    self._own_pending += 1
                    self.own_polls += 1
                    send = True
                else:
                    send = False
            if send:
                self._write_machine(p.RT_STATUS)
            self._stop.wait(period / 4)  # pacing the poll clock

    # ------------------------------------------------------------------ Controller

    @property
    def last_state(self) -> MachineState | None:
        return self._state

    def machine_limits(self):
        """The machine's limits from the ``$$`` replies the sender's traffic showed (see
        :func:`drivers.grbl.protocol.settings_limits`), or None until a sender asked."""
        return p.settings_limits(dict(self.settings), f"GRBL $$ seen on {self.port}")

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
        """The next status report seen (own poll or the sender's), stamped at arrival."""
        with self._cond:
            seq = self._status_seq
            self._cond.wait_for(lambda: self._status_seq > seq or not self._connected, timeout)
            state = self._state
            connected = self._connected
        if not connected:
            last = state
            t = time.monotonic()
            if last is None:
                return MachineState(t=t, mpos=(0.0,) * 6, state=RunState.DISCONNECTED, raw="machine port lost")
            return MachineState(t=t, mpos=last.mpos, wco=last.wco, state=RunState.DISCONNECTED, raw="machine port lost")
        if state is None:
            raise DriverError(f"passthrough {self.port}: no status report within {timeout:g} s")
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
