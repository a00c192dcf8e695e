"""GRBL over a pseudo-terminal: achieved poll rate, and latency from a state change in
the peer to the MachineState in the driver, polling at 50 Hz. Prints one JSON line.

    .venv/bin/python bench/grbl_bench.py [--rate 50] [--seconds 10] [--transport pty|tcp]
    .venv/bin/python bench/grbl_bench.py --drops 20 [--restart] [--rate 20] [--seed 1]

A changer thread moves the virtual machine's X at random instants (stamping
``time.monotonic()`` under the machine lock); the driver polls with ``states()``; the
latency of a change is the arrival stamp of the first polled state showing it minus the
change's stamp. Expected: p50 about half a poll period plus one ``?`` round trip, p99
about one period. ``request_ms`` is the ``?`` -> report round trip alone, back to back.

``--drops N``: instead, the link is dropped N times (the peer's pty/TCP transport closed,
or with ``--restart`` the whole peer replaced by a fresh one) for 0.05-3 s each (seeded),
1 s up between drops, while the driver polls at ``--rate``. Prints the outage seconds,
the polls that were not fresh beyond what the outage itself costs (total and the worst
drop, in polls; target: at most one poll period per drop), and the longest time without
fresh data (and by how much it exceeds its outage).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import tempfile
import threading
import time

from _poll_latency import XStepper, poll_summary, watch_x
from drivers.grbl.driver import from_url
from drivers.grbl.peer import GrblPeer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=50.0, help="poll rate, Hz")
    ap.add_argument("--seconds", type=float, default=10.0, help="run time, s")
    ap.add_argument("--transport", choices=("pty", "tcp"), default="pty")
    ap.add_argument("--drops", type=int, default=0, help="link drops of 0.05-3 s instead of the latency run")
    ap.add_argument("--restart", action="store_true", help="with --drops: restart the peer instead")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    if args.drops:
        return drops(args)

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


class _Link:
    """The peer behind a stable address (pty symlink or TCP port) that can be dropped,
    served again, or replaced by a freshly started peer."""

    def __init__(self, transport: str, tmp: str):
        self.transport = transport
        self.link = os.path.join(tmp, "ttyGRBL")
        self.peer = GrblPeer(VirtualMachine(MachineConfig(travel_min=None, travel_max=None)), speed=1.0)
        self.port = 0
        self.serve()

    def serve(self) -> None:
        if self.transport == "pty":
            self.peer.serve_pty(link=self.link)
        else:
            self.port = self.peer.serve_tcp(port=self.port)

    @property
    def url(self) -> str:
        return f"grbl://{self.link}" if self.transport == "pty" else f"grbl+socket://127.0.0.1:{self.port}"

    def drop(self, restart: bool) -> None:
        if restart:
            self.peer.close()
            self.peer = GrblPeer(VirtualMachine(MachineConfig(travel_min=None, travel_max=None)), speed=1.0)
        else:
            self.peer.close_transports()


def drops(args) -> dict:
    rng = random.Random(args.seed)
    period = 1.0 / args.rate
    polled: list[tuple[float, bool]] = []  # (time the poll returned, fresh)
    fresh_t: list[float] = []
    windows: list[tuple[float, float]] = []  # (dropped, served again), monotonic s
    with tempfile.TemporaryDirectory() as tmp:
        link = _Link(args.transport, tmp)
        c = from_url(f"{link.url}?rate={args.rate:g}")
        c.connect()
        stop = threading.Event()

        def poll_loop():
            for s in c.states():
                polled.append((time.monotonic(), s.fresh))
                if s.fresh:
                    fresh_t.append(s.t)
                if stop.is_set():
                    return

        poller = threading.Thread(target=poll_loop, daemon=True)
        poller.start()
        for _ in range(args.drops):
            time.sleep(1.0)  # up between drops
            down = rng.uniform(0.05, 3.0)
            t0 = time.monotonic()
            link.drop(args.restart)
            time.sleep(down)
            link.serve()
            windows.append((t0, time.monotonic()))
        time.sleep(1.0)
        stop.set()
        poller.join(5)
        gaps = list(c.gaps)
        c.close()
        link.peer.close()

    outage = sum(b - a for a, b in windows)
    extra = []
    longest_over = 0.0
    for a, b in windows:
        back = next((t for t in fresh_t if t > b), None)
        if back is None:
            continue
        before = max((t for t in fresh_t if t < a), default=a)
        missed = sum(1 for t, fresh in polled if a <= t <= back and not fresh)
        extra.append(missed - (b - a) / period)
        longest_over = max(longest_over, (back - before) - (b - a))
    data_gaps = [b - a for a, b in zip(fresh_t, fresh_t[1:])]
    result = {
        "bench": f"grbl_{args.transport}_{'restarts' if args.restart else 'drops'}",
        "drops": args.drops,
        "rate_hz": args.rate,
        "outage_s": round(outage, 3),
        "polls_missed": sum(1 for _, fresh in polled if not fresh),
        "polls_missed_beyond_outage": round(sum(extra), 1),
        "worst_drop_polls_beyond_outage": round(max(extra, default=0.0), 1),
        "longest_gap_s": round(max(data_gaps, default=0.0), 3),
        "longest_gap_beyond_its_outage_s": round(longest_over, 3),
        "gaps_recorded": len(gaps),
        "came_back_reset": sum(1 for g in gaps if g.came_back),
    }
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
