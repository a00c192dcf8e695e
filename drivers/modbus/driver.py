"""``ModbusController``: poll a CNC controller's registers over Modbus TCP or RTU.

URLs (see :mod:`drivers.registry`)::

    modbus+tcp://192.168.1.20:502?map=generic&unit=1&rate=20&timeout=0.5
    modbus+rtu:///dev/ttyUSB1?map=iai_robo_cylinder&baud=38400&parity=N&stopbits=1

``map`` is a TOML file or the name of a shipped map (default ``generic``); ``unit``
overrides the map's device id; ``rate`` is the poll rate (Hz) used by :meth:`states`;
``timeout`` (s) bounds each request; ``feed_hold=1`` enables the feed-hold write (the
driver is read-only otherwise, and always when the map names no feed-hold cell).

Each poll reads the map's fields in as few requests as the layout allows
(:func:`~drivers.modbus.regmap.plan_reads`). A timeout raises :class:`ReplyTimeout`;
three in a row, or a dropped socket, mark the link down: later polls raise
:class:`~drivers.errors.ConnectionLost` until a reconnect (with exponential backoff,
0.1 s to 5 s) succeeds. Exception responses raise :class:`ModbusExceptionError` naming the
unit, table, registers, fields and exception code.
"""

from __future__ import annotations

import logging
import socket
import math
import time
from dataclasses import replace
from urllib.parse import parse_qs, unquote, urlsplit

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from drivers.errors import ConnectionLost, DriverError
from drivers.modbus.regmap import AXES, Field, RegisterMap, decode_field, load_map, plan_reads
from drivers.state import Controller, MachineState, RunState

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
#: consecutive timeouts after which the link counts as down
TIMEOUTS_BEFORE_DOWN = 3


class ReplyTimeout(DriverError):
    """The controller did not answer a request in time."""


class ModbusExceptionError(DriverError):
    """The controller answered a request with a Modbus exception code."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


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
        self._client = None
        self._up = False
        self._closed = True
        self._timeouts = 0
        self._backoff = 0.1
        self._next_attempt = 0.0
        self.reconnects = 0
        self.missed = 0          # polls that produced no state (timeouts, link down)
        self.last_error: str | None = None

    # ------------------------------------------------------------------ lifecycle
    def _make_client(self):
        if self.host is not None:
            return ModbusTcpClient(self.host, port=self.port, timeout=self.timeout, retries=0,
                                   reconnect_delay=0, reconnect_delay_max=0)
        return ModbusSerialClient(self.serial_port, framer=FramerType.RTU, baudrate=self.baud,
                                  parity=self.parity, stopbits=self.stopbits, bytesize=self.bytesize,
                                  timeout=self.timeout, retries=0, reconnect_delay=0, reconnect_delay_max=0)

    def connect(self) -> None:
        """Open the socket or serial line; raises ConnectionLost when nothing answers."""
        self._closed = False
        if not self._open():
            raise ConnectionLost(f"{self.url}: cannot connect ({self.last_error})")

    def _open(self) -> bool:
        self._drop_client()
        self._client = self._make_client()
        try:
            ok = bool(self._client.connect())
        except Exception as exc:  # pyserial/socket errors surface differently per transport
            ok = False
            self.last_error = str(exc)
        if not ok:
            self.last_error = self.last_error or self._tcp_reason() or "no connection"
            self._drop_client()
            return False
        self._up = True
        self._timeouts = 0
        self._backoff = 0.1
        return True

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
            except Exception:
                pass
        self._client = None
        self._up = False

    def close(self) -> None:
        self._closed = True
        self._drop_client()

    def _link_down(self, why: str) -> None:
        self.last_error = why
        self._drop_client()
        self._next_attempt = time.monotonic() + self._backoff

    def _ensure_link(self) -> None:
        if self._closed:
            raise ConnectionLost(f"{self.url}: not connected")
        if self._up:
            return
        now = time.monotonic()
        if now < self._next_attempt:
            raise ConnectionLost(f"{self.url}: link down ({self.last_error}); next reconnect in {self._next_attempt - now:.2f} s")
        if self._open():
            self.reconnects += 1
            return
        self._backoff = min(self._backoff * 2, 5.0)
        self._next_attempt = now + self._backoff
        raise ConnectionLost(f"{self.url}: reconnect failed ({self.last_error}); retrying in {self._backoff:.2f} s")

    # ------------------------------------------------------------------ polling
    def poll(self) -> MachineState:
        """Read every mapped field and return the state, stamped when the last reply came."""
        try:
            self._ensure_link()
            values: dict[str, float] = {}
            raw_parts = []
            for blk in self.blocks:
                words = self._read_block(blk)
                raw_parts.append(f"{blk.unit}:{blk.table}@{blk.address}={words}")
                for f in blk.fields:
                    k = f.address - blk.address
                    values[f.name] = decode_field(f, words[k:k + f.count])
            t = time.monotonic()
        except (ConnectionLost, ReplyTimeout):
            self.missed += 1
            raise
        return self._state(values, t, " ".join(raw_parts))

    def states(self, period: float | None = None):
        return super().states(1.0 / self.rate if period is None else period)

    def _read_block(self, blk):
        c = self._client
        try:
            if blk.table == "holding":
                rr = c.read_holding_registers(blk.address, count=blk.count, device_id=blk.unit)
            elif blk.table == "input":
                rr = c.read_input_registers(blk.address, count=blk.count, device_id=blk.unit)
            elif blk.table == "coil":
                rr = c.read_coils(blk.address, count=blk.count, device_id=blk.unit)
            else:
                rr = c.read_discrete_inputs(blk.address, count=blk.count, device_id=blk.unit)
        except ModbusIOException as exc:
            self._timeouts += 1
            where = _where(blk.unit, blk.table, blk.address, blk.count, blk.fields)
            if self._timeouts >= TIMEOUTS_BEFORE_DOWN or not (c.connected if hasattr(c, "connected") else True):
                self._link_down(f"no reply to {where}")
            raise ReplyTimeout(f"{self.url}: no reply within {self.timeout:g} s to {where}") from None
        except (ConnectionException, OSError) as exc:
            self._link_down(str(exc) or type(exc).__name__)
            raise ConnectionLost(f"{self.url}: connection lost ({self.last_error})") from None
        except ModbusException as exc:  # a reply that does not decode
            raise DriverError(f"{self.url}: bad reply to {_where(blk.unit, blk.table, blk.address, blk.count, blk.fields)}: {exc}") from None
        self._timeouts = 0
        if rr.isError():
            code = int(getattr(rr, "exception_code", 0))
            where = _where(blk.unit, blk.table, blk.address, blk.count, blk.fields)
            raise ModbusExceptionError(
                f"{self.url}: {where}: exception code {code} ({EXCEPTION_NAMES.get(code, 'unknown')})", code)
        if blk.table in ("coil", "discrete"):
            return [1 if b else 0 for b in rr.bits[:blk.count]]
        return list(rr.registers)

    def _state(self, v: dict[str, float], t: float, raw: str) -> MachineState:
        mpos = [v.get(a, 0.0) for a in AXES]
        wco = [v.get(f"wco_{a}", 0.0) for a in AXES]
        if "feed" in v:
            feed = v["feed"]
        else:
            feed = math.sqrt(sum(v.get(f"v{a}", 0.0) ** 2 for a in AXES))
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
        self._ensure_link()
        broadcast = f.unit == 0
        try:
            if f.table == "coil":
                rr = self._client.write_coil(f.address, hold, device_id=f.unit, no_response_expected=broadcast)
            else:
                value = f.hold_value if hold else f.resume_value
                rr = self._client.write_register(f.address, value, device_id=f.unit, no_response_expected=broadcast)
        except ModbusIOException:
            raise ReplyTimeout(f"{self.url}: no reply within {self.timeout:g} s to the feed-hold write ({f.table} {f.address})") from None
        except (ConnectionException, OSError) as exc:
            self._link_down(str(exc))
            raise ConnectionLost(f"{self.url}: connection lost during the feed-hold write") from None
        if rr is not None and rr.isError():
            code = int(getattr(rr, "exception_code", 0))
            raise ModbusExceptionError(
                f"{self.url}: feed-hold write to {_where(f.unit, f.table, f.address, 1, (f,))}: exception code {code} ({EXCEPTION_NAMES.get(code, 'unknown')})", code)


def _where(unit: int, table: str, address: int, count: int, fields) -> str:
    names = ",".join(f.name for f in fields)
    span = f"{address}" if count == 1 else f"{address}..{address + count - 1}"
    return f"unit {unit} {table} {span} ({names})"


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
