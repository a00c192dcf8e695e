"""Modbus over TCP: achieved poll rate, and latency from a state change in the server to
the MachineState in the driver, polling at 50 Hz. Prints one JSON line.

    .venv/bin/python bench/modbus_bench.py [--rate 50] [--seconds 10] [--map generic]

A changer thread moves the virtual machine's X at random instants (stamping
``time.monotonic()`` under the machine lock); the driver polls with ``states()``; the
latency of a change is the stamp of the first polled state showing it minus the change's
stamp. Expected: p50 about half a poll period plus one request, p99 about one period.
"""

from __future__ import annotations

import argparse
import json
import time

from _poll_latency import XStepper, poll_summary, watch_x
from drivers.modbus.driver import ModbusController
from drivers.modbus.regmap import load_map
from drivers.modbus.server import ModbusVirtualServer
from drivers.virtual.machine import MachineConfig, VirtualMachine


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=50.0, help="poll rate, Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="run time, s")
    ap.add_argument("--map", default="generic", help="register map")
    args = ap.parse_args(argv)

    regmap = load_map(args.map)
    vm = VirtualMachine(MachineConfig(travel_min=None, travel_max=None))
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, rate=args.rate, timeout=1.0)
        c.connect()
        with XStepper(vm) as stepper:
            seen = watch_x(c, args.seconds, time.monotonic())
        # request time alone, back to back
        request_s = []
        for _ in range(200):
            t0 = time.perf_counter()
            c.poll()
            request_s.append(time.perf_counter() - t0)
        c.close()

    result = {
        "bench": "modbus_tcp_poll",
        "map": regmap.name,
        "target_hz": args.rate,
        **poll_summary(seen, stepper.changes, request_s),
    }
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
