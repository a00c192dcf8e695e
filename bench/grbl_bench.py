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
import random
import threading
import time

import numpy as np

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
    changes: list[tuple[float, float]] = []  # (t_change, new x)
    stop = threading.Event()
    rng = random.Random(1)

    def changer():
        x = 0.0
        while not stop.wait(rng.uniform(0.05, 0.15)):
            x -= 1.0
            with vm.lock:
                vm.position[0] = x
                changes.append((time.monotonic(), x))

    peer = GrblPeer(vm, speed=1.0)
    try:
        if args.transport == "pty":
            url = f"grbl://{peer.serve_pty()}?rate={args.rate:g}"
        else:
            url = f"grbl+socket://127.0.0.1:{peer.serve_tcp()}?rate={args.rate:g}"
        c = from_url(url)
        c.connect()
        th = threading.Thread(target=changer, daemon=True)
        t_start = time.monotonic()
        th.start()
        seen: list[tuple[float, float]] = []
        for st in c.states():
            seen.append((st.t, st.mpos[0]))
            if st.t - t_start >= args.seconds:
                break
        stop.set()
        th.join()
        elapsed = seen[-1][0] - seen[0][0]
        request_s = []
        for _ in range(200):
            t0 = time.monotonic()
            st = c.poll()
            request_s.append(st.t - t0)
        garbage = len(c.garbage)
        c.close()
    finally:
        peer.close()

    ts = np.array([s[0] for s in seen])
    xs = np.array([s[1] for s in seen])
    lat = []
    for t_change, x in changes:
        idx = np.nonzero((xs <= x + 1e-6) & (ts >= t_change))[0]
        if len(idx):
            lat.append(ts[idx[0]] - t_change)
    lat_ms = np.array(lat) * 1e3
    result = {
        "bench": f"grbl_{args.transport}_poll",
        "target_hz": args.rate,
        "achieved_hz": round((len(seen) - 1) / elapsed, 2),
        "polls": len(seen),
        "changes": len(changes),
        "latency_ms_p50": round(float(np.percentile(lat_ms, 50)), 2),
        "latency_ms_p99": round(float(np.percentile(lat_ms, 99)), 2),
        "latency_ms_max": round(float(lat_ms.max()), 2),
        "request_ms_p50": round(float(np.percentile(request_s, 50)) * 1e3, 3),
        "request_ms_p99": round(float(np.percentile(request_s, 99)) * 1e3, 3),
        "garbage_lines": garbage,
    }
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
