"""Talk to CNC controllers and turn what they say into :class:`MachineState`.

Nothing in this package knows about dexels. Protocol parsing lives in pure functions
(tested without a port); only :mod:`drivers.grbl` imports pyserial and only
:mod:`drivers.modbus` imports pymodbus. A controller is chosen by URL, see
:func:`drivers.registry.open_controller`.
"""

from drivers.errors import DriverError, ProtocolError, ConnectionLost
from drivers.state import MachineState, RunState, Controller

__all__ = [
    "Controller",
    "ConnectionLost",
    "DriverError",
    "MachineState",
    "ProtocolError",
    "RunState",
]
