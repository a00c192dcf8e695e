"""The Modbus driver end to end against the pymodbus server peer on 127.0.0.1."""

from __future__ import annotations

import math
import threading
import time

import pytest

from drivers.errors import ConnectionLost, DriverError
from drivers.modbus.driver import ModbusController, from_url
from drivers.modbus.regmap import load_map, parse_map
from drivers.modbus.server import ModbusVirtualServer
from drivers.registry import open_controller
from drivers.state import RunState
from drivers.virtual.runner import RealTimeRunner
from tests.drivers.virtual.helpers import line, rows

pace = threading.Event()  # never set: .wait(t) paces retry loops


def until(fn, timeout=10.0, every=0.01):
    """Call ``fn`` until it returns a truthy value (exceptions count as 'not yet')."""
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        try:
            v = fn()
            if v:
                return v
        except DriverError as exc:
            last = exc
        pace.wait(every)
    raise AssertionError(f"condition not met in {timeout} s (last error: {last})")




def client(srv, **q):
    query = "&".join(f"{k}={v}" for k, v in q.items())
    c = open_controller(f"modbus+tcp://127.0.0.1:{srv.port}?{query}")
    c.connect()
    return c


def test_static_state_through_generic_map(vm, server):
    vm.position[:] = (-12.5, 3.25, -7.0, 90.0, 0.0, -45.5)
    vm.set_wco((1.5, -2.0, 0.25))
    vm.set_feed_override(120)
    c = client(server)
    try:
        st = c.poll()
    finally:
        c.close()
    assert st.mpos == pytest.approx((-12.5, 3.25, -7.0, 90.0, 0.0, -45.5))
    assert st.wco[:3] == pytest.approx((1.5, -2.0, 0.25))
    assert st.state == RunState.IDLE and st.line is None and st.alarm is None
    assert st.overrides == (120, 100, 100)
    assert isinstance(c, ModbusController) and len(c.blocks) == 1  # one request per poll


def every_type_map():
    doc = {"map": {"name": "types"}, "fields": {}}
    specs = [
        ("x", "int16", "big", "big", 0.01), ("y", "uint16", "big", "little", 0.01),
        ("z", "int32", "little", "big", 0.001), ("a", "uint32", "little", "little", 0.001),
        ("b", "float32", "little", "big", 1.0), ("c", "float64", "little", "little", 1.0),
        ("wco_x", "float32", "big", "little", 1.0), ("wco_y", "float64", "big", "big", 1.0),
        ("wco_z", "int32", "big", "big", 0.5),
    ]
    addr = 100
    for name, t, wo, bo, scale in specs:
        doc["fields"][name] = {"table": "holding", "address": addr, "type": t, "word_order": wo,
                               "byte_order": bo, "scale": scale, "offset": 1.0 if t == "uint16" else 0.0}
        addr += {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2, "float64": 4}[t] + 1  # gaps
    return parse_map(doc, "types.toml")


def test_every_type_and_order_over_the_wire(vm):
    regmap = every_type_map()
    vm.position[:] = (-123.45, 456.78, -98765.432, 87654.321, -0.15625, math.pi)
    vm.set_wco((2.5, -1e-3, -300.5))
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port)
        c.connect()
        try:
            st = c.poll()
        finally:
            c.close()
        assert len(c.blocks) == 9  # gaps are never bridged
    assert st.mpos[0] == pytest.approx(-123.45, abs=0.005)
    assert st.mpos[1] == pytest.approx(456.78, abs=0.005)
    assert st.mpos[2] == pytest.approx(-98765.432, abs=5e-4)
    assert st.mpos[3] == pytest.approx(87654.321, abs=5e-4)
    assert st.mpos[4] == -0.15625  # exact in float32
    assert st.mpos[5] == math.pi  # exact in float64
    assert st.wco[:3] == pytest.approx((2.5, -1e-3, -300.5), rel=1e-7)


def test_polling_a_moving_machine(vm, server):
    vm.queue(rows(line((-30, 0, 0), 400), line((-30, 20, 0), 400)))
    runner = RealTimeRunner(vm, speed=10.0).start()
    c = client(server, rate=50)
    try:
        seen = []
        for st in c.states():
            seen.append(st)
            if st.state == RunState.IDLE and st.mpos[1] > 19.999:
                break
            assert len(seen) < 2000
    finally:
        c.close()
        runner.stop()
    xs = [s.mpos[0] for s in seen]
    assert all(b <= a + 1e-9 for a, b in zip(xs, xs[1:]))  # X only decreases
    assert {s.line for s in seen if s.state == RunState.RUN} >= {1, 2}
    assert max(s.feed for s in seen) == pytest.approx(400.0, rel=1e-6)
    assert seen[-1].mpos[:2] == pytest.approx((-30.0, 20.0), abs=1e-5)
    ts = [s.t for s in seen]
    assert all(b > a for a, b in zip(ts, ts[1:]))


def test_connect_refused_is_clear():
    c = from_url("modbus+tcp://127.0.0.1:1?timeout=0.2")
    with pytest.raises(ConnectionLost, match="cannot connect"):
        c.connect()


def test_read_only_by_default_and_feed_hold_when_enabled(vm, server):
    vm.queue(rows(line((-100, 0, 0), 600)))
    vm.advance(1.0)
    ro = client(server)
    try:
        with pytest.raises(DriverError, match="read-only: feed hold is not enabled"):
            ro.feed_hold()
        assert vm.state == RunState.RUN
    finally:
        ro.close()
    rw = client(server, feed_hold=1)
    try:
        rw.feed_hold()
        assert vm.state == RunState.HOLD
        vm.advance(2.0)
        st = rw.poll()
        assert st.state == RunState.HOLD and st.feed == 0.0
        rw.resume()
        assert vm.state == RunState.RUN
    finally:
        rw.close()


def test_writes_elsewhere_are_refused(vm, server):
    from pymodbus.client import ModbusTcpClient

    cl = ModbusTcpClient("127.0.0.1", port=server.port, timeout=1, retries=0)
    assert cl.connect()
    try:
        rr = cl.write_coil(3, True, device_id=1)
        assert rr.isError() and rr.exception_code == 2
        rr = cl.write_register(0, 5, device_id=1)
        assert rr.isError()
    finally:
        cl.close()


def test_map_without_feed_hold_stays_read_only(vm, server):
    regmap = parse_map({"fields": {"x": {"table": "input", "address": 0, "type": "float32"}}}, "ro.toml")
    c = ModbusController(regmap, host="127.0.0.1", port=server.port, allow_feed_hold=True)
    c.connect()
    try:
        with pytest.raises(DriverError, match="names no feed_hold"):
            c.feed_hold()
    finally:
        c.close()


class RecordingServer(ModbusVirtualServer):
    """The virtual server, keeping every write it receives: (function code, address, values)."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.writes = []

    def _write(self, unit, func_code, address, values):
        self.writes.append((func_code, address, [int(v) for v in values]))
        return super()._write(unit, func_code, address, values)


def test_active_low_feed_hold_coil_writes_the_maps_values(vm):
    """hold_value = 0 / resume_value = 1 on a coil were ignored: feed_hold() wrote ON,
    which such a device takes for resume."""
    regmap = parse_map({"fields": {"x": {"table": "input", "address": 0, "type": "float32"},
                                   "feed_hold": {"table": "coil", "address": 0, "hold_value": 0,
                                                 "resume_value": 1}}}, "active_low.toml")
    vm.queue(rows(line((-100, 0, 0), 600)))
    vm.advance(1.0)
    with RecordingServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, allow_feed_hold=True)
        c.connect()
        try:
            c.feed_hold()
            held = vm.state
            vm.advance(2.0)  # to a stop: like GRBL, the machine ignores resume until then
            c.resume()
        finally:
            c.close()
    assert srv.writes == [(5, 0, [0]), (5, 0, [1])]
    assert held == RunState.HOLD and vm.state == RunState.RUN


def test_iai_map_multi_unit_and_broadcast_pause(vm):
    regmap = load_map("iai_robo_cylinder")
    vm.queue(rows(line((-30, -40, 0), 400)))
    vm.advance(2.0)
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, allow_feed_hold=True)
        c.connect()
        try:
            st = c.poll()
            assert len(c.blocks) == 6  # per unit: PNOW (+ALMC on unit 1) and VNOW
            assert st.mpos[:3] == pytest.approx(tuple(vm.position[:3]), abs=0.006)
            assert st.state == RunState.RUN and st.feed == pytest.approx(400.0, abs=1.0)
            c.feed_hold()  # broadcast to unit 0: no reply expected
            until(lambda: vm.state == RunState.HOLD, timeout=5)
        finally:
            c.close()


def test_url_errors():
    with pytest.raises(DriverError, match="unknown option 'rat'"):
        from_url("modbus+tcp://127.0.0.1:502?rat=5")
    with pytest.raises(DriverError, match="parity"):
        from_url("modbus+rtu:///dev/ttyUSB9?parity=X")
    with pytest.raises(DriverError, match=r"unit=0; expected a device id 1..247"):
        from_url("modbus+tcp://127.0.0.1:502?unit=0")  # broadcast: nothing would ever answer a poll
    c = from_url("modbus+rtu:///dev/ttyUSB9?map=iai_robo_cylinder&baud=38400")
    assert c.serial_port == "/dev/ttyUSB9" and c.baud == 38400
    with pytest.raises(ConnectionLost):
        c.connect()


def test_server_late_faults_still_answer(vm):
    from drivers.virtual.faults import FaultInjector

    with ModbusVirtualServer(vm, load_map("generic"), faults=FaultInjector("late=1,late_s=0.05")).start() as srv:
        c = ModbusController(load_map("generic"), host="127.0.0.1", port=srv.port, timeout=1.0)
        c.connect()
        try:
            t0 = time.monotonic()
            c.poll()
            assert time.monotonic() - t0 >= 0.05
        finally:
            c.close()
