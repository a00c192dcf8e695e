"""Choose a controller driver by URL, the way pyserial chooses a port.

=================================  ===========================================
URL                                driver
=================================  ===========================================
``grbl:///dev/ttyUSB0?baud=115200``  GRBL 1.1 on a serial device (or pty path)
``grbl+socket://host:port``         GRBL 1.1 over TCP (pyserial ``socket://``)
``modbus+tcp://host:port?map=F``    Modbus TCP controller with a register map
``modbus+rtu:///dev/ttyUSB1?map=F``  Modbus RTU
``virtual://PROGRAM?speed=N``       the in-process virtual controller
``grbl+passthrough:///dev/ttyUSB0``  GRBL behind your own sender: dexmon opens the
                                   port and offers a pty (``?tcp=PORT``: and a
                                   TCP port) that the sender streams through
``grbl+passthrough+socket://h:p``   the same for a networked GRBL
=================================  ===========================================

Drivers register their scheme in :data:`SCHEMES` lazily (module path and class name),
so importing this module imports neither pyserial nor pymodbus.
"""

from __future__ import annotations

import importlib
from urllib.parse import urlsplit

from drivers.errors import DriverError
from drivers.state import Controller

#: scheme -> "module:factory"; the factory takes the URL string and returns a Controller.
SCHEMES: dict[str, str] = {
    "grbl": "drivers.grbl.driver:from_url",
    "grbl+socket": "drivers.grbl.driver:from_url",
    "grbl+pty": "drivers.grbl.driver:from_url",
    "modbus+tcp": "drivers.modbus.driver:from_url",
    "modbus+rtu": "drivers.modbus.driver:from_url",
    "virtual": "drivers.virtual.controller:from_url",
    "grbl+passthrough": "drivers.grbl.passthrough:from_url",
    "grbl+passthrough+socket": "drivers.grbl.passthrough:from_url",
    "grbl+passthrough+rfc2217": "drivers.grbl.passthrough:from_url",
}


def open_controller(url: str) -> Controller:
    """Return an unconnected :class:`Controller` for ``url`` (call ``connect()`` on it)."""
    scheme = urlsplit(url).scheme
    target = SCHEMES.get(scheme)
    if target is None:
        known = ", ".join(sorted(SCHEMES))
        raise DriverError(f"controller URL {url!r}: unknown scheme {scheme!r}; expected one of {known}")
    module_name, factory_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        raise DriverError(f"controller URL {url!r}: driver {module_name} is not available ({exc})") from exc
    return getattr(module, factory_name)(url)
