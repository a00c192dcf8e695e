"""The Modbus tests' virtual machine (no travel limits) and the pymodbus server on 127.0.0.1:0."""

from __future__ import annotations

import pytest

from drivers.modbus.regmap import load_map
from drivers.modbus.server import ModbusVirtualServer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

#: a machine without travel limits: tests place it anywhere
FREE = MachineConfig(travel_min=None, travel_max=None)


@pytest.fixture
def vm():
    return VirtualMachine(FREE)


@pytest.fixture
def server(vm):
    srv = ModbusVirtualServer(vm, load_map("generic"), port=0).start()
    yield srv
    srv.stop()
