"""Modbus over TCP: achieved poll rate, and latency from a state change in the server to
the MachineState in the driver, polling at 50 Hz; or, with ``--drops N``, what N link
drops cost. Prints one JSON line.

    .venv/bin/python bench/modbus_bench.py [--rate 50] [--seconds 10] [--map generic]
    .venv/bin/python bench/modbus_bench.py --drops 20 [--rate 20] [--seed 1]

``--drops N``: the server is stopped N times for 0.05-3 s (seeded, uniform), up
0.3-1 s between drops, while the driver polls at ``--rate``. Prints the total outage
(s), the polls that brought no fresh state although they started while the server was up
(``polls_missed_beyond_outage``: the target is at most one per drop), the longest time
without a fresh state (s) against the longest outage, and the gaps and LOST/BACK events
the driver recorded.

A changer thread moves the virtual machine's X at random instants (stamping
``time.monotonic()`` under the machine lock); the driver polls with ``states()``; the
latency of a change is the stamp of the first polled state showing it minus the change's
stamp. Expected: p50 about half a poll period plus one request, p99 about one period.
"""

from __future__ import annotations

import argparse
import json
import random
import threading
import time

from _poll_latency import XStepper, poll_summary, watch_x
from drivers.modbus.driver import ModbusController
from drivers.modbus.regmap import load_map
from drivers.modbus.server import ModbusVirtualServer
from drivers.state import LinkKind
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=50.0, help="poll rate, Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="run time, s")
    ap.add_argument("--map", default="generic", help="register map")
    ap.add_argument("--drops", type=int, default=0, help="stop the server this many times (0: latency bench)")
    ap.add_argument("--seed", type=int, default=1, help="seed of the drop durations")
    args = ap.parse_args(argv)
    result = drops_bench(args) if args.drops else latency_bench(args)
    print(json.dumps(result), flush=True)
    return result


def latency_bench(args) -> dict:
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

    return {
        "bench": "modbus_tcp_poll",
        "map": regmap.name,
        "target_hz": args.rate,
        **poll_summary(seen, stepper.changes, request_s),
    }


def _drop_server(srv, n: int, seed: int, outages: list, done: threading.Event) -> None:
    """Stop ``srv`` ``n`` times for 0.05-3 s; append ``(t_stop, t_back)`` per drop."""
    rng = random.Random(seed)
    pause = threading.Event()  # never set: .wait(s) paces the drops
    for _ in range(n):
        pause.wait(rng.uniform(0.3, 1.0))
        t_stop = time.monotonic()
        srv.stop()
        pause.wait(rng.uniform(0.05, 3.0))
        srv.restart()
        outages.append((t_stop, time.monotonic()))
    pause.wait(1.0)
    done.set()


def drops_bench(args) -> dict:
    regmap = load_map(args.map)
    vm = VirtualMachine(MachineConfig(travel_min=None, travel_max=None))
    period = 1.0 / args.rate
    outages: list[tuple[float, float]] = []
    polls: list[tuple[float, object]] = []  # (t asked, state)
    events = []
    done = threading.Event()
    with ModbusVirtualServer(vm, regmap).start() as srv:
        c = ModbusController(regmap, host="127.0.0.1", port=srv.port, rate=args.rate)
        c.connect()
        dropper = threading.Thread(target=_drop_server, args=(srv, args.drops, args.seed, outages, done))
        dropper.start()
        next_t = time.monotonic()
        while not done.is_set():
            t_ask = time.monotonic()
            polls.append((t_ask, c.poll()))
            events += c.link_events()
            next_t += period
            done.wait(max(0.0, next_t - time.monotonic()))
        dropper.join()
        c.close()

    def during_outage(t: float) -> bool:
        return any(t_stop <= t < t_back for t_stop, t_back in outages)

    fresh_t = [st.t for _, st in polls if st.fresh]
    missed = [t for t, st in polls if not st.fresh]
    return {
        "bench": "modbus_tcp_drops",
        "map": regmap.name,
        "target_hz": args.rate,
        "drops": args.drops,
        "outage_s_total": round(sum(b - a for a, b in outages), 3),
        "outage_s_longest": round(max(b - a for a, b in outages), 3),
        "polls": len(polls),
        "polls_missed": len(missed),
        "polls_during_outage": sum(during_outage(t) for t, _ in polls),
        "polls_missed_beyond_outage": sum(not during_outage(t) for t in missed),
        "longest_gap_of_data_s": round(max(b - a for a, b in zip(fresh_t, fresh_t[1:])), 3),
        "gaps_recorded": len(c.gaps),
        "lost_events": sum(e.kind == LinkKind.LOST for e in events),
        "back_events": sum(e.kind == LinkKind.BACK for e in events),
        "counts": {k: n for k, n in c.counts.items() if n},
    }


if __name__ == "__main__":
    main()
