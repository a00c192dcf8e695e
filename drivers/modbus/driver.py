"""``ModbusController``: poll a CNC controller's registers over Modbus TCP or RTU.

URLs (see :mod:`drivers.registry`)::

    modbus+tcp://192.168.1.20:502?map=generic&unit=1&rate=20&timeout=0.5
    modbus+rtu:///dev/ttyUSB1?map=iai_robo_cylinder&baud=38400&parity=N&stopbits=1

``map`` is a TOML file or the name of a shipped map (default ``generic``); ``unit``
overrides the map's device id; ``rate`` is the poll rate (Hz) used by :meth:`states`;
``timeout`` (s) bounds each request; ``feed_hold=1`` enables the feed-hold write (the
driver is read-only otherwise, and always when the map names no feed-hold cell).

Each poll reads the map's fields in as few requests as the layout allows
(:func:`~drivers.modbus.regmap.plan_reads`). :meth:`ModbusController.connect` opens the
link and reads every block once: an exception 1, 2 or 3 there (the map does not fit the
device) fails it, naming the registers. After that :meth:`ModbusController.poll` never
raises for what the link or the controller does (the contract in :mod:`drivers.state`):

* a timeout, an exception answer (busy 6 and acknowledge 5 included), a short or
  undecodable answer (a bad RTU CRC, an answer to another request) gives a MISSED state; the same request is simply asked again at the
  next poll, as the Modbus application protocol intends for busy and acknowledge;
* an answer whose numbers cannot be right (:func:`~drivers.state.implausible`: NaN,
  inf, beyond any machine, huge integers) gives a BAD state with the raw registers;
* three timeouts in a row, or a dropped socket (met by a poll or by the feed-hold write),
  mark the link down: DISCONNECTED states, one reconnect attempt per poll (no growing
  backoff: a refused connect is cheap), and when the controller answers again a
  :class:`~drivers.state.Gap`.

Over RTU an answer carries no transaction id, so after a request that got no answer of
its own (a timeout, a garbled answer) the next request waits until the line is quiet and
discards what arrives meanwhile (:meth:`ModbusController._clear_line`): a late answer is
never read as the next request's. An RTU answer with a bad CRC is a garbled answer, told
as soon as it arrives (pymodbus would wait out the timeout for another).

Every miss is counted by cause in :attr:`ModbusController.counts`; a cause is told once
as a NOTE link event when it appears and once when it clears (LOST/BACK for the link,
BAD for a run of impossible answers).
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from dataclasses import dataclass, replace
from urllib.parse import parse_qs, unquote, urlsplit

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException
from pymodbus.framer import FramerRTU, FramerType

from drivers.errors import ConnectionLost, DriverError
from drivers.modbus.regmap import (AXES, Field, ReadBlock, RegisterMap, decode_field, limits_from_values, load_map,
                                   plan_reads)
from drivers.state import (MAX_REPORTED_INT, Controller, Gap, LinkKind, MachineState, RunState, check_device,
                           implausible, stale_state)

logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # we report failures ourselves

EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}
#: exception codes that mean the map asks for something the device does not have
CONFIG_EXCEPTIONS = (1, 2, 3)
#: consecutive timeouts after which the link counts as down
TIMEOUTS_BEFORE_DOWN = 3
#: causes of a poll without a fresh state, the keys of ``ModbusController.counts``:
#: no answer in time, exception 6, exception 5, another exception code, fewer registers
#: than asked, an answer that does not decode, impossible numbers (BAD), link down, and a
#: failure inside the driver itself (a bug: told, counted, and the polls go on)
CAUSES = ("timeout", "busy", "acknowledge", "exception", "short", "garbled", "bad", "disconnected", "error")
#: RTU: after an answer that went wrong, silence (s) that tells the line is clear again
#: once bytes were seen: 3.5 characters by the standard, but USB serial adapters hand
#: bytes over in bursts up to 16 ms apart
RTU_FRAME_GAP_S = 0.05
#: function codes of the requests the driver sends, by table (reads) and for the writes
READ_FUNCTIONS = {"coil": 1, "discrete": 2, "holding": 3, "input": 4}
WRITE_FUNCTIONS = {"coil": 5, "holding": 6}
#: integer fields whose value is a code or a count: beyond MAX_REPORTED_INT it is garbage
_INT_FIELDS = ("state", "alarm", "line", "feed_override", "rapid_override", "spindle_override")


class ReplyTimeout(DriverError):
    """The controller did not answer a request in time (the feed-hold write)."""


class ModbusExceptionError(DriverError):
    """The controller answered a request with a Modbus exception code."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


class _Miss(Exception):
    """One read brought no usable answer: ``cause`` (a key of ``CAUSES``) and a line
    saying what and where; ``code`` is the exception code for exception answers."""

    def __init__(self, cause: str, message: str, code: int = 0):
        super().__init__(message)
        self.cause = cause
        self.code = code


class _Dropped(Exception):
    """The socket or serial port went away."""


class _BadFrame(Exception):
    """An RTU answer arrived whole but its CRC does not match (noise on the line)."""


class _CheckedRTUFramer(FramerRTU):
    """pymodbus's RTU framer, but an answer with a bad CRC is told at once.

    pymodbus drops such a frame silently and keeps reading until its timeout runs out,
    so a garbled answer (noise on an RS-485 line) looked like no answer at all, took the
    whole timeout, and three in a row marked the link lost. Its ``decode`` returns the
    bytes used without a frame only for a CRC mismatch (a frame not yet complete uses 0).
    """

    def decode(self, data: bytes):
        used, dev_id, tid, frame = super().decode(data)
        if used and not frame:
            raise _BadFrame(f"answer with a bad CRC ({len(data)} bytes: {data[:12].hex(' ')}"
                            f"{' ...' if len(data) > 12 else ''})")
        return used, dev_id, tid, frame


@dataclass
class _Outage:
    """The link is down since ``t_lost`` (monotonic s) because of ``reason``;
    ``polls`` answered DISCONNECTED so far."""

    t_lost: float
    reason: str
    polls: int = 0


@dataclass
class _Trouble:
    """A cause of missed polls, active since ``t_first`` (monotonic s), ``polls`` so far."""

    t_first: float
    polls: int = 0


class ModbusController(Controller):
    """Poll a Modbus controller through a :class:`RegisterMap`.

    Parameters
    ----------
    regmap : RegisterMap
    host, port : TCP target (``modbus+tcp``), or
    serial_port, baud, parity, stopbits, bytesize : RTU line (``modbus+rtu``)
    rate : float, poll rate (Hz) for :meth:`states`
    timeout : float, seconds per request
    allow_feed_hold : bool, permit :meth:`feed_hold`/:meth:`resume` writes

    Attributes
    ----------
    counts : dict str -> int
        Polls without a fresh state by cause (keys :data:`CAUSES`).
    polls, missed, reconnects : int
        Polls answered, polls without a fresh state, links re-established.
    gaps : list of Gap
        Finished outages.
    """

    def __init__(self, regmap: RegisterMap, host: str | None = None, port: int = 502,
                 serial_port: str | None = None, baud: int = 19200, parity: str = "N",
                 stopbits: int = 1, bytesize: int = 8, rate: float = 20.0, timeout: float = 0.5,
                 allow_feed_hold: bool = False, url: str = ""):
        if (host is None) == (serial_port is None):
            raise DriverError("modbus controller: give either a TCP host or a serial port")
        if not rate > 0 or not timeout > 0:
            raise DriverError(f"modbus controller: rate and timeout must be > 0 (got {rate}, {timeout})")
        self.regmap = regmap
        self.host, self.port = host, int(port)
        self.serial_port, self.baud, self.parity = serial_port, int(baud), parity
        self.stopbits, self.bytesize = int(stopbits), int(bytesize)
        self.rate = float(rate)
        self.timeout = float(timeout)
        self.allow_feed_hold = bool(allow_feed_hold)
        self.url = url or (f"modbus+tcp://{host}:{port}" if host else f"modbus+rtu://{serial_port}")
        self.blocks = plan_reads(regmap.reading_fields())
        self.limit_blocks = plan_reads(regmap.limit_fields()) if regmap.limit_fields() else []
        self._limits = None  # drivers.state.ControllerLimits read at connect, if the map names them
        self.counts = dict.fromkeys(CAUSES, 0)
        self.polls = 0
        self.missed = 0
        self.reconnects = 0
        self.gaps: list[Gap] = []
        # a map without the work offset gives wco 0: not the controller's (Controller.reports_wco)
        self.reports_wco = all(f"wco_{a}" in regmap.fields for a in "xyz")
        self.last_error: str | None = None
        self._client = None
        self._closed = True
        self._lock = threading.RLock()  # one request at a time: polls and the feed-hold write
        self._last: MachineState | None = None   # the last fresh state
        self._last_t = -math.inf                 # t of the last state returned
        self._timeouts = 0                       # consecutive polls without an answer
        self._down: _Outage | None = None
        self._trouble: dict[str, _Trouble] = {}
        # RTU: (since, silence needed) after a request whose answer did not come or did not
        # decode: its bytes may still be on the way (see _clear_line)
        self._line_unsure: tuple[float, float] | None = None

    # ------------------------------------------------------------------ lifecycle
    def _make_client(self):
        if self.host is not None:
            return ModbusTcpClient(self.host, port=self.port, timeout=self.timeout, retries=0,
                                   reconnect_delay=0, reconnect_delay_max=0)
        client = ModbusSerialClient(self.serial_port, framer=FramerType.RTU, baudrate=self.baud,
                                    parity=self.parity, stopbits=self.stopbits, bytesize=self.bytesize,
                                    timeout=self.timeout, retries=0, reconnect_delay=0, reconnect_delay_max=0)
        # the client and its transaction manager share one framer (pymodbus 3.16)
        framer = getattr(client, "framer", None)
        transaction = getattr(client, "transaction", None)
        if isinstance(framer, FramerRTU) and getattr(transaction, "framer", None) is framer:
            client.framer = transaction.framer = _CheckedRTUFramer(framer.decoder)
        return client

    def preflight(self) -> None:
        if self.serial_port is not None:
            check_device(self.serial_port, f"{self.url}")

    def connect(self) -> None:
        """Open the socket or serial line and read every block once.

        Raises ConnectionLost when nothing answers the connect, and
        :class:`ModbusExceptionError` (naming the registers) when the device refuses a
        block with exception 1, 2 or 3: the map does not fit it. Timeouts and busy
        answers here are left to the polls.
        """
        with self._lock:
            self._closed = False
            self._down, self._timeouts = None, 0
            self._trouble.clear()
            if not self._open(explain=True):
                self._closed = True
                raise ConnectionLost(f"{self.url}: cannot connect ({self.last_error})")
            for blk in self.blocks:
                try:
                    self._read_block(blk)
                except _Miss as miss:
                    if miss.cause == "exception" and miss.code in CONFIG_EXCEPTIONS:
                        self.close()
                        raise ModbusExceptionError(f"{self.url}: {miss}: the register map does not fit this device",
                                                   miss.code) from None
                    break
                except _Dropped:
                    break  # the first poll says so
            self._read_limits()

    def _read_limits(self) -> None:
        """The map's limit fields, once (a failure is told; timing then uses the job's
        and the default limits)."""
        if not self.limit_blocks:
            return
        values: dict[str, float] = {}
        try:
            for blk in self.limit_blocks:
                words = self._read_block(blk)
                for f in blk.fields:
                    k = f.address - blk.address
                    values[f.name] = decode_field(f, words[k:k + f.count])
        except (_Miss, _Dropped) as exc:
            self._link_event(LinkKind.NOTE, f"{self.url}: machine limits not read ({exc}); program timing uses "
                                            f"the job's [machine] and the defaults")
            return
        self._limits = limits_from_values(values, f"Modbus map {self.regmap.name} on {self.url}")

    def machine_limits(self):
        """The machine's limits the register map names (read at connect), or None."""
        return self._limits

    def _open(self, explain: bool = False) -> bool:
        """Open a new client; False with ``last_error`` set when it cannot connect
        (``explain``: ask the operating system why, which costs one more TCP connect)."""
        self._drop_client()
        self._client = self._make_client()
        self.last_error = None
        try:
            ok = bool(self._client.connect())
        except Exception as exc:  # noqa: BLE001 - pyserial/socket errors surface differently per transport
            ok = False
            self.last_error = str(exc)
        if not ok:
            self.last_error = self.last_error or (self._tcp_reason() if explain else None) or "cannot connect"
            self._drop_client()
        return ok

    def _tcp_reason(self) -> str | None:
        """Why a TCP connect failed, as the operating system says it.

        pymodbus's ``connect()`` only returns False (the reason goes to its log), so one
        plain socket connect asks again; None for serial links or when it answers now.
        """
        if self.host is None:
            return None
        try:
            with socket.create_connection((self.host, self.port), timeout=self.timeout):
                return None
        except OSError as err:
            return err.strerror or str(err)

    def _drop_client(self) -> None:
        if self._client is not None:
            try:
                self._client.close()
            except Exception:  # noqa: BLE001 - closing a broken link anyway
                pass
        self._client = None

    def close(self) -> None:
        self._closed = True
        self._drop_client()

    # ------------------------------------------------------------------ polling
    def poll(self) -> MachineState:
        """Read every mapped field and return the state, stamped when the last answer
        came; a MISSED, BAD or DISCONNECTED state when there is no fresh one (never raises
        for link or controller trouble once connected)."""
        with self._lock:
            if self._closed:
                raise ConnectionLost(f"{self.url}: not connected")
            self.polls += 1
            try:
                st = self._poll_link()
            except Exception as exc:  # noqa: BLE001 - a failure here must become a state, not a stop
                st = self._missed("error", f"driver failure reading the answer: {type(exc).__name__}: {exc}")
            if not st.fresh:
                self.missed += 1
            if st.t < self._last_t:  # monotonic already; kept so t can never go back
                st = replace(st, t=self._last_t)
            self._last_t = st.t
            return st

    def _poll_link(self) -> MachineState:
        if self._down is not None and not self._reconnect():
            return self._disconnected()
        try:
            values, raw = self._read_all()
        except _Dropped as exc:
            self.last_error = str(exc)
            if self._down is not None:
                self._drop_client()
                return self._disconnected()
            return self._lose(str(exc))
        except _Miss as miss:
            if miss.cause != "timeout":
                self._timeouts = 0
                self._answered()
                return self._missed(miss.cause, str(miss))
            self._timeouts += 1
            if self._down is not None:
                self.last_error = str(miss)
                self._drop_client()  # still silent: a fresh socket at the next poll
                return self._disconnected()
            if self._timeouts >= TIMEOUTS_BEFORE_DOWN:
                self.counts["timeout"] += 1
                return self._lose(f"no reply to {TIMEOUTS_BEFORE_DOWN} requests in a row (last: {miss})")
            return self._missed("timeout", str(miss))
        self._timeouts = 0
        self._answered()
        return self._decoded(values, raw, time.monotonic())

    def _read_all(self) -> tuple[dict[str, float], str]:
        """Every block's fields decoded, and the raw words; raises _Miss / _Dropped at
        the first block without a usable answer (the others would only wait as long)."""
        values: dict[str, float] = {}
        raw_parts = []
        for blk in self.blocks:
            words = self._read_block(blk)
            raw_parts.append(f"{_span(blk.unit, blk.table, blk.address, blk.count)}={words}")
            for f in blk.fields:
                k = f.address - blk.address
                values[f.name] = decode_field(f, words[k:k + f.count])
        return values, " ".join(raw_parts)

    def states(self, period: float | None = None):
        return super().states(1.0 / self.rate if period is None else period)

    def _read_block(self, blk: ReadBlock) -> list[int]:
        """The words (or bits as 0/1) of one block, exactly ``blk.count`` of them."""
        where = _where(blk.unit, blk.table, blk.address, blk.count, blk.fields)
        c = self._client
        readers = {"holding": c.read_holding_registers, "input": c.read_input_registers,
                   "coil": c.read_coils, "discrete": c.read_discrete_inputs}
        rr = self._request(lambda: readers[blk.table](blk.address, count=blk.count, device_id=blk.unit),
                           READ_FUNCTIONS[blk.table], where, _span(blk.unit, blk.table, blk.address, blk.count))
        if blk.table in ("coil", "discrete"):
            words = [1 if b else 0 for b in (rr.bits or [])[:blk.count]]
        else:
            words = list(rr.registers or [])
        if len(words) != blk.count:
            raise _Miss("short", f"{where}: answer holds {len(words)} registers of {blk.count}")
        return words

    def _request(self, send, function: int, where: str, span: str, answer_expected: bool = True):
        """One request, ``send()`` (a call of the pymodbus client with function code
        ``function``), and its answer: the reads and the feed-hold write go through here,
        so both see the link the same way.

        Raises :class:`_Miss` (no usable answer: ``cause`` says why) or :class:`_Dropped`
        (the socket or port went away); returns the answer object, or None when
        ``answer_expected`` is False (a broadcast)."""
        if self.serial_port is not None:
            self._clear_line(where)
        try:
            rr = send()
        except ModbusIOException as exc:
            # pymodbus says "No response received ..." when the timeout ran out; any other
            # I/O error is an answer that did not decode
            if "no response" in str(exc).lower():
                self._mark_line_unsure(self.timeout)  # the answer may yet come
                raise _Miss("timeout", f"no reply within {self.timeout:g} s to {where}") from None
            self._mark_line_unsure(RTU_FRAME_GAP_S)
            raise _Miss("garbled", f"{where}: answer does not decode ({exc})") from None
        except _BadFrame as exc:
            self._mark_line_unsure(RTU_FRAME_GAP_S)  # the rest of a garbled answer may follow
            raise _Miss("garbled", f"{where}: {exc}") from None
        except (ConnectionException, OSError) as exc:
            raise _Dropped(f"{span}: {_drop_reason(exc)}") from None
        except Exception as exc:  # noqa: BLE001 - any other decoding failure is a garbled answer
            self._mark_line_unsure(RTU_FRAME_GAP_S)
            raise _Miss("garbled", f"{where}: answer does not decode ({type(exc).__name__}: {exc})") from None
        if not answer_expected:
            return None
        if rr is None or not hasattr(rr, "isError"):
            raise _Miss("garbled", f"{where}: no answer object ({rr!r})")
        got = int(getattr(rr, "function_code", function)) & 0x7F  # 0x80 marks an exception answer
        if got != function:
            # RTU answers carry no transaction id: this one belongs to an earlier request
            self._mark_line_unsure(RTU_FRAME_GAP_S)
            raise _Miss("garbled", f"{where}: answer to another request (function {got}, asked {function})")
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0) or 0)
            cause = {6: "busy", 5: "acknowledge"}.get(code, "exception")
            raise _Miss(cause, f"{where}: exception code {code} ({EXCEPTION_NAMES.get(code, 'unknown')})",
                        code)
        return rr

    def _mark_line_unsure(self, silence: float) -> None:
        """RTU: the last request got no answer that could be its own; before the next one
        the line must be ``silence`` s quiet (see :meth:`_clear_line`)."""
        if self.serial_port is not None:
            self._line_unsure = (time.monotonic(), silence)

    def _clear_line(self, where: str) -> None:
        """RTU answers carry no transaction id: an answer that comes after its request
        timed out would be read as the next request's, a fresh-looking state from an
        earlier instant. So after a request went wrong, discard what arrives until the line
        is quiet: ``timeout`` s of silence after a timeout (an answer up to twice the
        timeout late is caught; pymodbus only discards bytes already waiting when it
        sends), then :data:`RTU_FRAME_GAP_S` after the last byte seen.

        Bounded: after twice the timeout of chatter the request is not sent, a MISSED
        "garbled" poll, and the line stays unsure."""
        if self._line_unsure is None:
            return
        since, silence = self._line_unsure
        port = getattr(self._client, "socket", None)
        if port is None:
            return  # closed: _open makes a new one; the line is cleared at the next request
        last, discarded = since, 0
        give_up = time.monotonic() + 2 * self.timeout
        old_timeout = port.timeout
        try:
            while True:
                now = time.monotonic()
                quiet_for = silence - (now - last)
                if quiet_for <= 0:
                    break
                if now >= give_up:
                    raise _Miss("garbled", f"line not quiet before {where}: {discarded} stray bytes in "
                                           f"{2 * self.timeout:g} s")
                port.timeout = min(quiet_for, give_up - now)
                data = port.read(max(1, port.in_waiting))  # waits for a byte or the silence
                if data:
                    discarded += len(data)
                    last, silence = time.monotonic(), min(silence, RTU_FRAME_GAP_S)
        except (OSError, ValueError) as exc:  # serial errors are OSErrors (SerialException)
            raise _Dropped(f"{where}: {_drop_reason(exc)}") from None
        finally:
            if self._client is not None and self._client.socket is port:
                port.timeout = old_timeout
        self._line_unsure = None

    # ------------------------------------------------------------------ link state
    def _reconnect(self) -> bool:
        """One attempt to reopen the link while it is down (at every poll)."""
        if self._client is not None:
            return True
        return self._open()

    def _lose(self, reason: str) -> MachineState:
        """The link just went down during a poll: LOST, and a DISCONNECTED state."""
        self._mark_down(reason)
        return self._disconnected()

    def _mark_down(self, reason: str) -> None:
        """The link went down (in a poll or in the feed-hold write): the client is
        closed, LOST is told once, and the polls answer DISCONNECTED and reconnect."""
        self.last_error = reason
        self._drop_client()
        if self._down is not None:
            return  # already down: the outage began earlier
        self._trouble.clear()  # the outage says it all now; BACK ends it
        t = time.monotonic()
        self._down = _Outage(t, reason)
        self._link_event(LinkKind.LOST, f"{self.url}: link lost: {reason}; reconnecting at every poll", t=t)

    def _disconnected(self) -> MachineState:
        down = self._down
        down.polls += 1
        self.counts["disconnected"] += 1
        t = time.monotonic()
        return stale_state(self._last, RunState.DISCONNECTED, t,
                           f"{self.url}: link down for {t - down.t_lost:.1f} s ({down.reason}); "
                           f"last attempt: {self.last_error}")

    def _answered(self) -> None:
        """The controller answered (whatever it said): a link that was down is back."""
        if self._down is None:
            return
        down, self._down = self._down, None
        t = time.monotonic()
        gap = Gap(down.t_lost, t, down.reason, polls_missed=down.polls)
        self.gaps.append(gap)
        self.reconnects += 1
        self._link_event(LinkKind.BACK, f"{self.url}: link back after {gap.seconds:.1f} s, "
                                        f"{down.polls} poll(s) missed ({down.reason})", gap=gap, t=t)

    def _missed(self, cause: str, message: str) -> MachineState:
        """A MISSED state for one poll without a usable answer, counted by ``cause``."""
        self.counts[cause] += 1
        message = f"{self.url}: {message}"
        self._note_trouble(cause, message)
        return stale_state(self._last, RunState.MISSED, time.monotonic(), message)

    def _note_trouble(self, cause: str, message: str, kind: LinkKind = LinkKind.NOTE, raw: str = "") -> None:
        trouble = self._trouble.get(cause)
        if trouble is None:
            self._trouble[cause] = trouble = _Trouble(time.monotonic())
            again = "; recorded as BAD, skipped" if cause == "bad" else "; asking again at every poll"
            self._link_event(kind, message + again, raw=raw)
        trouble.polls += 1

    def _troubles_cleared(self) -> None:
        t = time.monotonic()
        for cause, trouble in self._trouble.items():
            self._link_event(LinkKind.NOTE, f"{self.url}: {cause} cleared: {trouble.polls} poll(s) without a "
                                            f"fresh state over {t - trouble.t_first:.1f} s", t=t)
        self._trouble.clear()

    # ------------------------------------------------------------------ decoding
    def _decoded(self, values: dict[str, float], raw: str, t: float) -> MachineState:
        """The fresh state, or a BAD one when the numbers cannot be right."""
        why = _impossible_value(values)
        st = None
        if why is None:
            st = self._state(values, t, raw)
            why = implausible(st)
        if why is not None:
            self.counts["bad"] += 1
            message = f"{self.url}: impossible answer: {why}"
            self._note_trouble("bad", message, LinkKind.BAD, raw)
            return stale_state(self._last, RunState.BAD, t, f"{message}; {raw}")
        self._troubles_cleared()
        self._last = st
        return st

    def _state(self, v: dict[str, float], t: float, raw: str) -> MachineState:
        mpos = [v.get(a, 0.0) for a in AXES]
        wco = [v.get(f"wco_{a}", 0.0) for a in AXES]
        if "feed" in v:
            feed = v["feed"]
        else:
            feed = math.hypot(*(v.get(f"v{a}", 0.0) for a in AXES))  # no overflow for huge garbage
        alarm = int(v["alarm"]) if "alarm" in v else None
        if "state" in v:
            state = self.regmap.states.get(int(v["state"]), RunState.UNKNOWN)
        elif alarm:
            state = RunState.ALARM
        else:
            state = RunState.RUN if feed > 1e-6 else RunState.IDLE
        line = int(v["line"]) if v.get("line") else None
        overrides = tuple(int(round(v.get(k, 100.0))) for k in ("feed_override", "rapid_override", "spindle_override"))
        return MachineState(t=t, mpos=mpos, wco=wco, state=state, feed=feed, spindle=v.get("spindle", 0.0),
                            line=line, overrides=overrides, alarm=alarm if alarm else None, raw=raw)

    # ------------------------------------------------------------------ commands
    def feed_hold(self) -> None:
        """Write the map's feed-hold cell (only when enabled and mapped)."""
        self._write_hold(True)

    def resume(self) -> None:
        """Release the feed hold (same conditions as :meth:`feed_hold`)."""
        self._write_hold(False)

    def _write_hold(self, hold: bool) -> None:
        f = self.regmap.feed_hold
        if f is None:
            raise DriverError(f"{self.url}: map {self.regmap.path} names no feed_hold coil or register: read-only")
        if not self.allow_feed_hold:
            raise DriverError(f"{self.url}: read-only: feed hold is not enabled (pass feed_hold=1 / allow_feed_hold=True)")
        with self._lock:
            if self._closed:
                raise ConnectionLost(f"{self.url}: not connected")
            if self._client is None and not self._open():
                raise ConnectionLost(f"{self.url}: link down, cannot write the feed hold ({self.last_error})")
            self._write_cell(f, hold)

    def _write_cell(self, f: Field, hold: bool) -> None:
        where = _where(f.unit, f.table, f.address, 1, (f,))
        broadcast = f.unit == 0  # no device answers a broadcast
        value = f.hold_value if hold else f.resume_value  # checked at load: fits the cell
        if f.table == "coil":  # an active-low coil holds on 0
            def send():
                return self._client.write_coil(f.address, bool(value), device_id=f.unit,
                                               no_response_expected=broadcast)
        else:
            def send():
                return self._client.write_register(f.address, value, device_id=f.unit,
                                                   no_response_expected=broadcast)
        try:
            self._request(send, WRITE_FUNCTIONS[f.table], where, _span(f.unit, f.table, f.address, 1),
                          answer_expected=not broadcast)
        except _Dropped as exc:
            # an outage like one met by a poll: LOST now, the polls reconnect, BACK with a gap
            self._mark_down(f"{exc} (during the feed-hold write)")
            raise ConnectionLost(f"{self.url}: connection lost during the feed-hold write ({where}): {exc}") from None
        except _Miss as miss:
            if miss.cause == "timeout":
                raise ReplyTimeout(f"{self.url}: no reply within {self.timeout:g} s to the feed-hold write "
                                   f"({where})") from None
            if miss.code:
                raise ModbusExceptionError(f"{self.url}: feed-hold write to {miss}", miss.code) from None
            raise DriverError(f"{self.url}: feed-hold write: {miss}") from None
        if not broadcast:
            self._answered()  # the controller answered: a link that was down is back


def _drop_reason(exc: Exception) -> str:
    """One short line for a link that went away (pymodbus's messages run long)."""
    text = str(exc)
    if "unexpectedly closed" in text:
        return "the controller closed the connection"
    if isinstance(exc, OSError):
        return f"connection lost ({exc.strerror or exc})"
    return f"connection lost ({text.removeprefix('Modbus Error: ')})"


def _impossible_value(values: dict[str, float]) -> str | None:
    """Why a decoded field cannot be turned into a state (non-finite, or an integer code
    beyond any controller's), or None."""
    for name, v in values.items():
        if not math.isfinite(v):
            return f"{name}={v!r} is not a number"
        if name in _INT_FIELDS and abs(v) > MAX_REPORTED_INT:
            return f"{name}={v!r} is out of range"
    return None


def _span(unit: int, table: str, address: int, count: int) -> str:
    """``unit 1 input 0..34``: the registers (or bits) of one request."""
    span = f"{address}" if count == 1 else f"{address}..{address + count - 1}"
    return f"unit {unit} {table} {span}"


def _where(unit: int, table: str, address: int, count: int, fields) -> str:
    """:func:`_span` and the names of the fields it holds."""
    return f"{_span(unit, table, address, count)} ({','.join(f.name for f in fields)})"


_TRUE = {"1", "true", "yes", "on"}


def from_url(url: str) -> ModbusController:
    """Build a :class:`ModbusController` from a ``modbus+tcp://`` or ``modbus+rtu://`` URL."""
    parts = urlsplit(url)
    q = {k: v[-1] for k, v in parse_qs(parts.query, keep_blank_values=True).items()}
    known = {"map", "unit", "rate", "timeout", "feed_hold", "baud", "parity", "stopbits", "bytesize"}
    unknown = sorted(set(q) - known)
    if unknown:
        raise DriverError(f"modbus URL {url!r}: unknown option {unknown[0]!r}; expected one of {', '.join(sorted(known))}")
    regmap = load_map(q.get("map", "generic"))
    try:
        if "unit" in q:
            unit = int(q["unit"])
            if not 1 <= unit <= 247:  # 0 is broadcast: no device answers it (see regmap)
                raise DriverError(f"modbus URL {url!r}: unit={unit}; expected a device id 1..247")
            regmap = replace(regmap, unit=unit, fields={n: replace(f, unit=unit) if f.unit == regmap.unit else f
                                                        for n, f in regmap.fields.items()})
        kw = dict(rate=float(q.get("rate", 20)), timeout=float(q.get("timeout", 0.5)),
                  allow_feed_hold=q.get("feed_hold", "0").lower() in _TRUE, url=url)
        if parts.scheme == "modbus+tcp":
            if not parts.hostname:
                raise DriverError(f"modbus URL {url!r}: expected modbus+tcp://HOST:PORT")
            return ModbusController(regmap, host=parts.hostname, port=parts.port or 502, **kw)
        if parts.scheme == "modbus+rtu":
            dev = unquote(parts.netloc + parts.path)
            if not dev:
                raise DriverError(f"modbus URL {url!r}: expected modbus+rtu:///dev/DEVICE")
            parity = q.get("parity", "N").upper()
            if parity not in ("N", "E", "O"):
                raise DriverError(f"modbus URL {url!r}: parity={parity!r}; expected N, E or O")
            return ModbusController(regmap, serial_port=dev, baud=int(q.get("baud", 19200)), parity=parity,
                                    stopbits=int(q.get("stopbits", 1)), bytesize=int(q.get("bytesize", 8)), **kw)
    except ValueError as exc:
        raise DriverError(f"modbus URL {url!r}: {exc}") from None
    raise DriverError(f"modbus URL {url!r}: scheme must be modbus+tcp or modbus+rtu")


__all__ = ["ModbusController", "ModbusExceptionError", "ReplyTimeout", "from_url", "Field", "RegisterMap"]
