"""A register map may name the machine's limits: read once at connect, offered as
``machine_limits()`` (a real pymodbus server on 127.0.0.1, port 0)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import drivers.modbus.regmap as regmap_module
from drivers.modbus.driver import ModbusController
from drivers.modbus.regmap import parse_map
from drivers.modbus.server import ModbusVirtualServer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

GENERIC = Path(regmap_module.__file__).parent / "maps" / "generic.toml"


def map_with_limits():
    doc = tomllib.loads(GENERIC.read_text())
    names = [f"max_rate_{a}" for a in "xyz"] + [f"accel_{a}" for a in "xyz"] + ["junction_deviation"]
    for k, name in enumerate(names):
        doc["fields"][name] = {"table": "holding", "address": 200 + 2 * k, "type": "float32"}
    return parse_map(doc, "limits.toml")


def test_limits_named_by_the_map_are_read_once_at_connect():
    regmap = map_with_limits()
    vm = VirtualMachine(MachineConfig(max_rate=(800.0, 700.0, 300.0), accel=(25.0, 20.0, 12.5),
                                      junction_deviation=0.02))
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port)
        c.connect()
        try:
            c.poll()
            got = c.machine_limits()
        finally:
            c.close()
    # the limits are not in the blocks read at every poll
    assert not any(f.name.startswith(("max_rate", "accel")) for b in c.blocks for f in b.fields)
    assert got.max_rate == (800.0, 700.0, 300.0) and got.acceleration == (25.0, 20.0, 12.5)
    assert abs(got.junction_deviation - 0.02) < 1e-7 and got.source.startswith("Modbus map")


def test_a_map_without_limits_says_none():
    regmap = parse_map(tomllib.loads(GENERIC.read_text()), "generic.toml")
    vm = VirtualMachine(MachineConfig())
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port)
        c.connect()
        try:
            assert c.machine_limits() is None
        finally:
            c.close()
