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

Test hooks: ``silent = True`` stops answering (clients time out); ``faults`` (a
:class:`~drivers.virtual.faults.FaultInjector`) drops, delays or fails replies.
"""

from __future__ import annotations

import asyncio
import logging
import threading

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer

from drivers.errors import DriverError
from drivers.modbus.regmap import AXES, TYPES, Field, RegisterMap, encode_field
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
logging.getLogger("pymodbus").setLevel(logging.ERROR)


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
    values["feed_hold"] = 1.0 if st.state == RunState.HOLD else 0.0
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
    """Serve ``vm`` through ``regmap`` on Modbus TCP at ``host:port`` (0 = any free port)."""

    def __init__(self, vm: VirtualMachine, regmap: RegisterMap, host: str = "127.0.0.1", port: int = 0,
                 faults: FaultInjector | None = None):
        self.vm = vm
        self.regmap = regmap
        self.host = host
        self.requested_port = int(port)
        self.port: int | None = None
        self.faults = faults
        self.silent = False
        self.requests = 0
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
        self._thread = threading.Thread(target=self._run, name="modbus-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise DriverError(f"modbus server on {self.host}:{self.requested_port} did not start in {timeout} s")
        if self._error is not None:
            raise DriverError(f"modbus server on {self.host}:{self.requested_port}: {self._error}")
        return self

    def stop(self, timeout: float = 5.0) -> None:
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
        self._server = ModbusTcpServer(
            _MachineContext(self), address=(self.host, self.requested_port),
            broadcast_enable=True, ignore_missing_devices=True,
        )
        try:
            await self._server.serve_forever(background=True)
        except RuntimeError as exc:
            raise OSError(f"cannot listen on {self.host}:{self.requested_port}") from exc
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
        if values is None:
            return self._read(unit, func_code, address, count)
        return self._write(unit, func_code, address, values)

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
        v = values[0]
        if table == "coil":
            do_hold = bool(v)
        elif int(v) == hold.hold_value:
            do_hold = True
        elif int(v) == hold.resume_value:
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
