"""GRBL over a pseudo-terminal: achieved poll rate, and latency from a state change in
the peer to the MachineState in the driver, polling at 50 Hz. Prints one JSON line.

    .venv/bin/python bench/grbl_bench.py [--rate 50] [--seconds 10] [--transport pty|tcp]

A changer thread moves the virtual machine's X at random instants (stamping
``time.monotonic()`` under the machine lock); the driver polls with ``states()``; the
latency of a change is the arrival stamp of the first polled state showing it minus the
change's stamp. Expected: p50 about half a poll period plus one ``?`` round trip, p99
about one period. ``request_ms`` is the ``?`` -> report round trip alone, back to back.
"""

from __future__ import annotations

import argparse
import json
import time

from _poll_latency import XStepper, poll_summary, watch_x
from drivers.grbl.driver import from_url
from drivers.grbl.peer import GrblPeer
from drivers.virtual.machine import MachineConfig, VirtualMachine


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=50.0, help="poll rate, Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="run time, s")
    ap.add_argument("--transport", choices=("pty", "tcp"), default="pty")
    args = ap.parse_args(argv)

    vm = VirtualMachine(MachineConfig(travel_min=None, travel_max=None))
    peer = GrblPeer(vm, speed=1.0)
    try:
        c = from_url(peer.serve_url(args.transport, f"rate={args.rate:g}"))
        c.connect()
        with XStepper(vm) as stepper:
            seen = watch_x(c, args.seconds, time.monotonic())
        request_s = []
        for _ in range(200):
            t0 = time.monotonic()
            st = c.poll()
            request_s.append(st.t - t0)
        garbage = len(c.garbage)
        c.close()
    finally:
        peer.close()

    result = {
        "bench": f"grbl_{args.transport}_poll",
        "target_hz": args.rate,
        **poll_summary(seen, stepper.changes, request_s),
        "garbage_lines": garbage,
    }
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
