"""Passthrough soak: a sender on the passthrough's TCP port streams to the GRBL peer for
minutes; does anything ever stall? Prints one JSON line.

    .venv/bin/python bench/passthrough_soak.py [--minutes 10] [--speed 1] [--poll-hz 10]

The machine is the GRBL peer on a pseudo-terminal (as a USB port is); the passthrough
offers a pty (never opened, as when the sender uses TCP) and a TCP port. The sender
streams a circle of 1 mm segments with character counting (a ``$G`` now and then)
and asks ``?`` at ``--poll-hz`` as UGS does; a monitor thread polls the passthrough at
``--monitor-hz`` as dexmon does.

Figures: lines streamed and answered, bytes each way, ``longest_stall_s`` (the longest
time the sender received nothing while an answer or a report was due: expected about a
``?`` round trip, never seconds), ``longest_ack_s`` (the longest wait for an ``ok``,
planner-full waits included), the monitor's fresh/missed polls and longest time without a
fresh state, and the bytes each endpoint dropped (a connected sender too slow) or
discarded (nobody had it open). A stall longer than ``--stall-limit`` ends the run early
with ``"stalled": true``.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import select
import socket
import threading
import time

from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

RX_BUFFER = 127  # GRBL's serial RX buffer less one, as character-counting senders use it


def program_lines():
    """An endless program: a circle (R 20 mm) of 1 mm segments at F3000, with a ``$G``
    (the parser state, allowed while moving) every 100 lines."""
    yield "G21 G90 G94"
    yield "G1 F3000"
    n_seg = int(2 * math.pi * 20.0)
    k = 0
    while True:
        a = 2 * math.pi * (k % n_seg) / n_seg
        yield f"G1 X{20.0 * math.cos(a):.3f} Y{20.0 * math.sin(a):.3f}"
        k += 1
        if k % 100 == 0:
            yield "$G"


class Sender:
    """A character-counting TCP sender with a ``?`` timer; keeps the soak's figures."""

    def __init__(self, port: int, poll_hz: float, stall_limit: float):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.poll_period = 1.0 / poll_hz
        self.stall_limit = stall_limit
        self.in_flight: collections.deque[tuple[int, float]] = collections.deque()  # (bytes, t sent)
        self.rx = bytearray()
        self.lines = self.ok = self.errors = self.reports = self.queries = self.other = 0
        self.bytes_out = self.bytes_in = 0
        self.longest_stall = self.longest_ack = 0.0
        self.stalled = False
        self._last_query = 0.0
        self._due_since: float | None = None  # when something became due with nothing received

    def _due(self) -> bool:
        return bool(self.in_flight) or self.reports < self.queries

    def _send(self, data: bytes) -> None:
        self.sock.sendall(data)
        self.bytes_out += len(data)

    def _maybe_query(self, now: float) -> None:
        if now - self._last_query >= self.poll_period:
            self._last_query = now
            self.queries += 1
            self._send(b"?")

    def pump(self, timeout: float) -> None:
        """Read what arrived within ``timeout`` s; account answers and stalls."""
        now = time.monotonic()
        self._maybe_query(now)
        if self._due() and self._due_since is None:
            self._due_since = now
        ready, _, _ = select.select([self.sock], [], [], timeout)
        now = time.monotonic()
        if self._due_since is not None:
            self.longest_stall = max(self.longest_stall, now - self._due_since)
            if now - self._due_since > self.stall_limit:
                self.stalled = True
        if not ready:
            return
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionError("the passthrough closed the sender's connection")
        self.bytes_in += len(data)
        self._due_since = None
        self.rx += data
        while (i := self.rx.find(b"\n")) >= 0:
            text = self.rx[:i].decode("ascii", "replace").strip()
            del self.rx[: i + 1]
            if text.startswith("<"):
                self.reports += 1
            elif text == "ok" or text.startswith("error:"):
                self.ok += text == "ok"
                self.errors += text != "ok"
                if self.in_flight:
                    self.longest_ack = max(self.longest_ack, now - self.in_flight.popleft()[1])
            elif text:
                self.other += 1

    def stream(self, lines, until: float) -> None:
        for line in lines:
            if time.monotonic() >= until or self.stalled:
                break
            data = line.encode() + b"\n"
            while self.in_flight and sum(n for n, _ in self.in_flight) + len(data) > RX_BUFFER:
                self.pump(self.poll_period)
                if self.stalled:
                    return
            self._send(data)
            self.in_flight.append((len(data), time.monotonic()))
            self.lines += 1
            self.pump(0.0)
        drain_until = time.monotonic() + self.stall_limit
        while self._due() and not self.stalled and time.monotonic() < drain_until:
            self.pump(self.poll_period)


class Monitor(threading.Thread):
    """Polls the passthrough as dexmon does; counts fresh states and the longest blind time."""

    def __init__(self, pt: Passthrough, hz: float):
        super().__init__(name="soak monitor", daemon=True)
        self.pt, self.period = pt, 1.0 / hz
        self.stop = threading.Event()
        self.polls = self.fresh = 0
        self.states: collections.Counter = collections.Counter()
        self.longest_blind = 0.0

    def run(self) -> None:
        last_fresh = time.monotonic()
        while not self.stop.wait(self.period):  # pacing the poll clock
            st = self.pt.poll()
            self.polls += 1
            self.states[st.state.value] += 1
            if st.fresh:
                self.fresh += 1
                last_fresh = st.t
            self.longest_blind = max(self.longest_blind, time.monotonic() - last_fresh)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="soak time, min")
    ap.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall second")
    ap.add_argument("--poll-hz", type=float, default=10.0, help="the sender's '?' rate, Hz")
    ap.add_argument("--monitor-hz", type=float, default=20.0, help="the monitor's poll rate, Hz")
    ap.add_argument("--stall-limit", type=float, default=30.0, help="a stall this long ends the run, s")
    args = ap.parse_args(argv)

    vm = VirtualMachine(MachineConfig(max_rate=(5000.0,) * 3, accel=(500.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    peer = GrblPeer(vm, speed=args.speed)
    pt = Passthrough(peer.serve_pty(), rate=args.monitor_hz, tcp_port=0)
    t0 = time.monotonic()
    try:
        pt.start()
        monitor = Monitor(pt, args.monitor_hz)
        monitor.start()
        sender = Sender(pt.sender_port, args.poll_hz, args.stall_limit)
        try:
            sender.stream(program_lines(), t0 + 60.0 * args.minutes)
        finally:
            monitor.stop.set()
            monitor.join(5.0)
            sender.sock.close()
        endpoints = pt.sender_output
        events = [f"{ev.kind.value}: {ev.message}" for ev in pt.link_events()]
    finally:
        pt.close()
        peer.close()

    result = {
        "bench": "passthrough_soak",
        "seconds": round(time.monotonic() - t0, 1),
        "lines_streamed": sender.lines,
        "ok": sender.ok,
        "errors": sender.errors,
        "unanswered": len(sender.in_flight),
        "queries": sender.queries,
        "reports_to_sender": sender.reports,
        "bytes_to_machine": sender.bytes_out,
        "bytes_to_sender": sender.bytes_in,
        "longest_stall_s": round(sender.longest_stall, 3),
        "longest_ack_s": round(sender.longest_ack, 3),
        "stalled": sender.stalled,
        "own_polls": pt.own_polls,
        "monitor_polls": monitor.polls,
        "monitor_fresh": monitor.fresh,
        "monitor_states": dict(monitor.states),
        "monitor_longest_blind_s": round(monitor.longest_blind, 3),
        "dropped_bytes": sum(e["dropped"] for e in endpoints.values()),
        "endpoints": endpoints,
        "gaps": len(pt.gaps),
        "link_events": events[:20],
    }
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
