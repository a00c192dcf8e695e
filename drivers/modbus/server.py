"""The Modbus peer: a pymodbus TCP server exposing a VirtualMachine through a register map.

Every read is answered from the machine's state at that instant (under ``vm.lock``), so
the registers move with the machine without a copy loop. Addresses the map does not
name answer exception 2 (illegal data address), as a strict device does; writes are
refused (exception 2) except to the map's ``feed_hold`` coil/register, which holds and
resumes the machine. Device ids not in the map get no answer (an RTU line's silence).

    server = ModbusVirtualServer(vm, load_map("generic"), port=0).start()
    print(server.port)          # the bound port
    ...
    server.stop()

Test hooks, all off by default: ``silent = True`` stops answering (clients time out);
``faults`` (a :class:`~drivers.virtual.faults.FaultInjector`) drops, delays or fails
replies; ``answers`` (an :class:`AnswerFaults`, seeded) and :meth:`ModbusVirtualServer.script`
make read answers late, busy (exception 6), acknowledge (5), other exception codes,
short, undecodable, or carry mutated register values (NaN, inf, huge, random words);
:meth:`ModbusVirtualServer.restart` stops and listens again on the same port (a link
drop). ``function_codes`` counts every request received by function code, so a test can
see that no write ever reached the device; ``errors`` collects failures inside the
server (a test asserts it stays empty).

Each answer carries the transaction id of its own request, even when a later request
was answered first (pymodbus's handler would stamp a late answer with the newest id).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import random
import threading
import traceback
from dataclasses import dataclass

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import ExceptionResponse
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler

from drivers.errors import DriverError
from drivers.modbus.regmap import AXES, TYPES, Field, RegisterMap, encode, encode_field
from drivers.state import RunState
from drivers.virtual.faults import REPLY_DROP, REPLY_GARBLE, REPLY_LATE, FaultInjector
from drivers.virtual.machine import VirtualMachine

#: function code -> table
_READ_TABLE = {1: "coil", 2: "discrete", 3: "holding", 4: "input"}
_WRITE_TABLE = {5: "coil", 15: "coil", 6: "holding", 16: "holding"}
#: a dropped reply comes this late (s): later than any sane client timeout
DROP_DELAY_S = 5.0

# pymodbus warns at every context creation that the old datastore API is deprecated;
# we only use its request plumbing, so keep the warning out of the user's terminal.
# (never lower than the driver's level, when both are imported: the driver reports its own)
_pymodbus_log = logging.getLogger("pymodbus")
_pymodbus_log.setLevel(max(_pymodbus_log.getEffectiveLevel(), logging.ERROR))


def machine_values(vm: VirtualMachine, regmap: RegisterMap) -> dict[str, float]:
    """Every mapped field's physical value from the machine now. Call under ``vm.lock``."""
    st = vm.snapshot()
    vel = vm.velocity()
    values: dict[str, float] = {}
    for i, a in enumerate(AXES):
        values[a] = st.mpos[i]
        values[f"wco_{a}"] = st.wco[i]
        values[f"v{a}"] = float(vel[i])
    values["feed"] = st.feed
    values["spindle"] = st.spindle
    code = regmap.state_code(st.state)
    values["state"] = float(code if code is not None else 0)
    values["alarm"] = float(st.alarm or 0)
    values["line"] = float(st.line or 0)
    values["feed_override"], values["rapid_override"], values["spindle_override"] = map(float, st.overrides)
    hold = regmap.feed_hold
    if hold is not None:  # the cell reads back what was written (an active-low coil: 0 when held)
        values["feed_hold"] = float(hold.hold_value if st.state == RunState.HOLD else hold.resume_value)
    cfg = vm.config
    for i, a in enumerate("xyz"):
        values[f"max_rate_{a}"], values[f"accel_{a}"] = float(cfg.max_rate[i]), float(cfg.accel[i])
    values["junction_deviation"] = float(cfg.junction_deviation)
    return values


def _clamped_words(f: Field, value: float) -> list[int]:
    """Words of ``value`` in ``f``, saturated to the integer type's range."""
    if f.type == "bool":
        return [1 if value else 0]
    code = TYPES[f.type][0]
    if code in "hHiI":
        bits = 16 if code in "hH" else 32
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code in "hi" else (0, (1 << bits) - 1)
        raw = min(max(f.to_raw(value), lo), hi)
        value = raw * f.scale + f.offset
    return encode_field(f, value)


#: what can happen to one read answer (besides a normal answer, "ok")
ANSWER_FAULTS = ("late", "busy", "acknowledge", "exception", "short", "garble", "mutate")
#: the exception codes an "exception" fault answers with (5 and 6 have their own faults)
OTHER_EXCEPTION_CODES = (ExcCodes.ILLEGAL_FUNCTION, ExcCodes.ILLEGAL_ADDRESS, ExcCodes.ILLEGAL_VALUE,
                         ExcCodes.DEVICE_FAILURE, ExcCodes.MEMORY_PARITY_ERROR,
                         ExcCodes.GATEWAY_PATH_UNAVIABLE, ExcCodes.GATEWAY_NO_RESPONSE)
#: raw values a "mutate" fault writes into a float field (non-finite, or beyond any machine)
FLOAT_GARBAGE = (math.nan, -math.nan, math.inf, -math.inf, 3.0e38, -1.0e30, 1.0e6, 1.0e300)
#: the largest finite float32
FLOAT32_MAX = 3.4028234663852886e38


@dataclass(frozen=True)
class AnswerFaults:
    """Probabilities (0..1, summing to at most 1) that one read answer is:

    ``late`` (sent ``late_s`` s late, beyond a client's timeout), ``busy`` (exception 6),
    ``acknowledge`` (exception 5), ``exception`` (another code: 1-4, 8, 10, 11),
    ``short`` (fewer registers than asked), ``garble`` (a frame that does not decode, or
    answers for another device), ``mutate`` (one field's words replaced by NaN, inf or
    huge float32/float64 patterns, huge integers or random words). ``seed`` seeds the draws.
    """

    late: float = 0.0
    busy: float = 0.0
    acknowledge: float = 0.0
    exception: float = 0.0
    short: float = 0.0
    garble: float = 0.0
    mutate: float = 0.0
    late_s: float = 1.0
    seed: int = 0

    def __post_init__(self):
        probs = [getattr(self, k) for k in ANSWER_FAULTS]
        if any(not 0.0 <= p <= 1.0 for p in probs) or sum(probs) > 1.0 + 1e-9:
            raise DriverError(f"answer faults {probs}: expected probabilities in 0..1 adding up to at most 1")
        if self.late_s < 0:
            raise DriverError(f"answer faults late_s={self.late_s}: expected >= 0 s")

    def draw(self, rng: random.Random) -> str:
        """One fault name from ``ANSWER_FAULTS``, or ``"ok"``."""
        x = rng.random()
        for kind in ANSWER_FAULTS:
            p = getattr(self, kind)
            if x < p:
                return kind
            x -= p
        return "ok"


def mutate_words(words: list[int], cells: dict[int, tuple[Field, int]], address: int,
                 rng: random.Random) -> list[int]:
    """``words`` (registers from ``address``) with one field's words replaced by garbage:
    for float fields NaN, inf or a huge value in the field's own coding, for integer
    fields the largest word pattern, or random words."""
    out = list(words)
    fields = {cells[address + i][0].name: cells[address + i][0] for i in range(len(words))}
    f = fields[rng.choice(sorted(fields))]
    lo, hi = max(f.address, address), min(f.address + f.count, address + len(words))
    if rng.random() < 0.3:
        garbage = [rng.randrange(0x10000) for _ in range(f.count)]
    elif f.type in ("float32", "float64"):
        value = rng.choice(FLOAT_GARBAGE)
        if f.type == "float32" and abs(value) > FLOAT32_MAX:
            value = math.copysign(math.inf, value)  # what a float32 register can hold of it
        garbage = encode(value, f.type, f.word_order, f.byte_order)
    else:
        garbage = [0xFFFF if k == 0 else rng.randrange(0x10000) for k in range(f.count)]
        if f.word_order == "little":
            garbage.reverse()
    for a in range(lo, hi):
        out[a - address] = garbage[a - f.address]
    return out


def garble_frame(packet: bytes, rng: random.Random) -> bytes:
    """A Modbus TCP answer ``packet`` made undecodable (a byte count beyond the frame, an
    unknown function code) or addressed to another device (clients skip it: a timeout)."""
    buf = bytearray(packet)
    if len(buf) < 9:
        return packet
    how = rng.randrange(3)
    if how == 0:
        buf[8] = 0xFF                  # byte count beyond the frame
    elif how == 1:
        buf[7] = 0x41                  # an unknown function code
    else:
        buf[6] = (buf[6] + 1) & 0xFF   # another device id
    return bytes(buf)


class _InOrderHandler(ServerRequestHandler):
    """pymodbus's request handler, but each answer keeps its own request's transaction
    and device id (the stock one stamps an answer with the newest request's ids when a
    later request arrived while it was pending, e.g. during a late answer)."""

    async def handle_request(self):
        request, addr = self.last_pdu, self.last_addr
        if not request:
            return
        ctx = self.server.context
        try:
            if self.server.broadcast_enable and not request.dev_id:
                for dev_id in ctx.device_ids():
                    await request.datastore_update(ctx, dev_id)
                return
            response = await request.datastore_update(ctx, request.dev_id)
        except NoSuchIdException:
            return  # an RTU line's silence: the client times out
        except asyncio.CancelledError:
            raise
        except Exception:  # noqa: BLE001 - a failing test server answers 4 and says why
            ctx._server.errors.append(traceback.format_exc())
            response = ExceptionResponse(request.function_code, ExcCodes.DEVICE_FAILURE)
        response.transaction_id = request.transaction_id
        response.dev_id = request.dev_id
        self.server_send(response, addr)


class _InOrderTcpServer(ModbusTcpServer):
    def callback_new_connection(self):
        return _InOrderHandler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class _MachineContext(ModbusServerContext):
    """pymodbus datastore answering from the machine (the 'old simulator' code path
    hands every request to ``async_getValues``/``async_setValues`` unchanged)."""

    def __init__(self, server: "ModbusVirtualServer"):  # no super().__init__: no blocks to build
        self.old_simulator = True
        self.simdevices = []
        self._server = server

    def device_ids(self):
        return sorted({f.unit for f in self._server.regmap.fields.values() if f.unit != 0})

    async def async_getValues(self, device_id, func_code, address, count=1):
        return await self._server._answer(device_id, func_code, address, count, None)

    async def async_setValues(self, device_id, func_code, address, values):
        res = await self._server._answer(device_id, func_code, address, len(values), list(values))
        return res if isinstance(res, ExcCodes) else None


class ModbusVirtualServer:
    """Serve ``vm`` through ``regmap`` on Modbus TCP at ``host:port`` (0 = any free port).

    ``answers``: an :class:`AnswerFaults` drawn for every read answer (None: none).
    """

    def __init__(self, vm: VirtualMachine, regmap: RegisterMap, host: str = "127.0.0.1", port: int = 0,
                 faults: FaultInjector | None = None, answers: AnswerFaults | None = None):
        self.vm = vm
        self.regmap = regmap
        self.host = host
        self.requested_port = int(port)
        self.port: int | None = None
        self.faults = faults
        self.answers = answers
        self.silent = False
        #: how late (s) a "late" answer comes
        self.late_s = answers.late_s if answers else 1.0
        self.requests = 0
        #: requests received, by function code (reads 1-4, writes 5, 6, 15, 16 ...)
        self.function_codes: collections.Counter[int] = collections.Counter()
        #: answer faults applied, by name (``ANSWER_FAULTS``)
        self.faults_done: collections.Counter[str] = collections.Counter()
        #: tracebacks of failures inside the server (answered with exception 4)
        self.errors: list[str] = []
        self._script: collections.deque[str] = collections.deque()
        self._garble_next = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._units = {f.unit for f in regmap.fields.values()}
        # (unit, table) -> {address: (field, word index)}
        self._cells: dict[tuple[int, str], dict[int, tuple[Field, int]]] = {}
        for f in regmap.fields.values():
            cells = self._cells.setdefault((f.unit, f.table), {})
            for k in range(f.count):
                cells[f.address + k] = (f, k)

    # ------------------------------------------------------------------ lifecycle
    def start(self, timeout: float = 10.0) -> "ModbusVirtualServer":
        """Listen (on the port bound before, after a :meth:`stop`) and serve from a thread;
        does nothing while serving."""
        if self._thread is not None and self._thread.is_alive():
            return self
        self._ready.clear()
        self._error = None
        self._thread = threading.Thread(target=self._run, name="modbus-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise DriverError(f"modbus server on {self.host}:{self.requested_port} did not start in {timeout} s")
        if self._error is not None:
            raise DriverError(f"modbus server on {self.host}:{self.requested_port}: {self._error}")
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop listening and close every client connection (clients see the link drop)."""
        loop = self._loop
        if loop is not None and loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
            try:
                fut.result(timeout)
            except Exception:  # shutting down anyway
                pass
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def restart(self, timeout: float = 10.0) -> "ModbusVirtualServer":
        """Listen again on the same port after :meth:`stop`."""
        return self.start(timeout)

    @property
    def answers(self) -> AnswerFaults | None:
        """The :class:`AnswerFaults` drawn for every read answer; setting it reseeds the draws."""
        return self._answers

    @answers.setter
    def answers(self, plan: AnswerFaults | None) -> None:
        self._answers = plan
        self._rng = random.Random(plan.seed if plan else 0)
        if plan is not None:
            self.late_s = plan.late_s

    def script(self, *kinds: str) -> None:
        """Apply these faults (names from ``ANSWER_FAULTS``, or ``"ok"``) to the next read
        answers, one each, in order, before any drawn from ``answers``."""
        bad = [k for k in kinds if k not in ANSWER_FAULTS + ("ok",)]
        if bad:
            raise DriverError(f"answer fault {bad[0]!r}: expected one of {', '.join(ANSWER_FAULTS)}, ok")
        self._script.extend(kinds)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve())
            loop.run_forever()
        except BaseException as exc:
            self._error = exc
            self._ready.set()
        finally:
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    async def _serve(self) -> None:
        port = self.port if self.port is not None else self.requested_port
        self._server = _InOrderTcpServer(
            _MachineContext(self), address=(self.host, port),
            broadcast_enable=True, ignore_missing_devices=True,
            trace_packet=self._trace_packet, trace_pdu=self._trace_pdu,
        )
        try:
            await self._server.serve_forever(background=True)
        except RuntimeError as exc:
            raise OSError(f"cannot listen on {self.host}:{port}") from exc
        self.port = self._server.transport.sockets[0].getsockname()[1]
        self._ready.set()

    async def _shutdown(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
        for task in asyncio.all_tasks():
            if task is not asyncio.current_task():
                task.cancel()
        asyncio.get_running_loop().call_soon(asyncio.get_running_loop().stop)

    # ------------------------------------------------------------------ requests
    def _trace_pdu(self, sending: bool, pdu):
        if not sending:
            self.function_codes[pdu.function_code] += 1
        return pdu

    def _trace_packet(self, sending: bool, packet: bytes) -> bytes:
        # the answer a "garble" fault was drawn for is the next one sent: nothing awaits
        # between the datastore returning and the handler sending
        if sending and self._garble_next:
            self._garble_next = False
            return garble_frame(packet, self._rng)
        return packet

    def _next_fault(self) -> str:
        if self._script:
            return self._script.popleft()
        return self._answers.draw(self._rng) if self._answers is not None else "ok"

    async def _answer(self, unit: int, func_code: int, address: int, count: int, values):
        self.requests += 1
        if unit != 0 and unit not in self._units:
            if len(self._units - {0}) == 1 and unit == 255:  # TCP gateways often send 255
                unit = next(iter(self._units - {0}))
            else:
                raise NoSuchIdException(f"device id {unit}")
        while self.silent:
            await asyncio.sleep(0.05)  # the device stopped answering (test hook)
        if self.faults is not None:
            fault = self.faults.reply_fault()
            if fault == REPLY_DROP:
                await asyncio.sleep(DROP_DELAY_S)
            elif fault == REPLY_LATE:
                await asyncio.sleep(self.faults.plan.late_s)
            elif fault == REPLY_GARBLE:
                return ExcCodes.DEVICE_FAILURE
        if values is not None:
            return self._write(unit, func_code, address, values)
        if func_code in _READ_TABLE:
            return await self._read_with_faults(unit, func_code, address, count)
        return self._read(unit, func_code, address, count)  # a write reading its cell back

    async def _read_with_faults(self, unit: int, func_code: int, address: int, count: int):
        fault = self._next_fault()
        if fault != "ok":
            self.faults_done[fault] += 1
        if fault == "late":
            await asyncio.sleep(self.late_s)
        elif fault == "busy":
            return ExcCodes.DEVICE_BUSY
        elif fault == "acknowledge":
            return ExcCodes.ACKNOWLEDGE
        elif fault == "exception":
            return self._rng.choice(OTHER_EXCEPTION_CODES)
        answer = self._read(unit, func_code, address, count)
        if isinstance(answer, ExcCodes):
            return answer
        if fault == "short":
            return answer[:self._rng.randrange(count)]
        if fault == "garble":
            self._garble_next = True
        elif fault == "mutate" and _READ_TABLE[func_code] in ("holding", "input"):
            answer = mutate_words(answer, self._cells[(unit, _READ_TABLE[func_code])], address, self._rng)
        return answer

    def _read(self, unit: int, func_code: int, address: int, count: int):
        # write requests read their cells back through here with the write's function code
        table = _READ_TABLE.get(func_code) or _WRITE_TABLE.get(func_code)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        cells = self._cells.get((unit, table), {})
        if any(a not in cells for a in range(address, address + count)):
            return ExcCodes.ILLEGAL_ADDRESS
        with self.vm.lock:
            values = machine_values(self.vm, self.regmap)
        words: dict[str, list[int]] = {}
        out = []
        for a in range(address, address + count):
            f, k = cells[a]
            if f.name not in words:
                words[f.name] = _clamped_words(f, values.get(f.name, 0.0))
            out.append(words[f.name][k])
        if table in ("coil", "discrete"):
            return [bool(v) for v in out]
        return out

    def _write(self, unit: int, func_code: int, address: int, values):
        table = _WRITE_TABLE.get(func_code)
        if table is None:
            return ExcCodes.ILLEGAL_FUNCTION
        hold = self.regmap.feed_hold
        if hold is None or hold.table != table or address != hold.address or len(values) != 1 \
                or hold.unit not in (0, unit):
            return ExcCodes.ILLEGAL_ADDRESS  # read-only device apart from the feed-hold cell
        v = int(values[0])  # a coil's True/False as 1/0: the map may make 0 the hold
        if v == hold.hold_value:
            do_hold = True
        elif v == hold.resume_value:
            do_hold = False
        else:
            return ExcCodes.ILLEGAL_VALUE
        with self.vm.lock:
            if do_hold:
                self.vm.feed_hold()
            else:
                self.vm.resume()
        return None


def words_of(regmap: RegisterMap, vm: VirtualMachine) -> dict[str, list[int]]:
    """Every field's words for the machine now (diagnostics and tests)."""
    with vm.lock:
        values = machine_values(vm, regmap)
    return {n: _clamped_words(f, values.get(n, 0.0)) for n, f in regmap.fields.items()}


__all__ = ["ModbusVirtualServer", "machine_values", "words_of"]
