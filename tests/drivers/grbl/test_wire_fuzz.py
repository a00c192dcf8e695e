"""GRBL wire fuzz (issue 11): 100 short sessions of the driver against the GRBL peer whose
every outgoing line may be mutated (seeded): flipped, inserted and deleted bytes, cut
lines, huge integers, nan/inf/1e308 numbers, junk lines, ``$13=`` garbage, doubled and
lost replies. No thread may end in a traceback, the reader stays alive, ``poll()`` always
returns a MachineState, a fresh state is a report that answered its ``?`` with believable
numbers, and ``t`` never goes backwards."""

from __future__ import annotations

import random
import re
import threading
import time

from drivers.errors import DriverError
from drivers.grbl import protocol as p
from drivers.grbl.peer import GrblPeer
from drivers.registry import open_controller
from drivers.state import NOT_FRESH, MachineState, implausible
from tests.drivers.thread_errors import thread_errors
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

SESSIONS = 100
POLLS = 5
HUGE = str(2**64 + 1).encode()
NON_FINITE = [b"nan", b"inf", b"-inf", b"1e308", b"9" * 400, HUGE]
JUNK = [b"$13=abc", b"$13=1e5", b"$13=nan", b"$13=inf", b"$13=" + b"9" * 400, b"ALARM:" + HUGE,
        b"error:" + HUGE, b"<Idle|MPos:1e308,0,0|FS:0,0>", b"<Idle|MPos:nan,0.000,0.000|FS:0,0>",
        b"<Run|MPos:0.000,0.000,0.000|Ln:" + HUGE + b"|FS:0,0>", b"<Idle|MPos:999999.000,0.000,0.000|FS:0,0>",
        b"<Hold:" + HUGE + b"|MPos:0.000,0.000,0.000|FS:0,0>", b"Grbl 1.1h ['$' for help]", b"ok", b"error:9",
        b"[MSG:\x00\xff]", b"\xff\xfe\x00", b"<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100," + HUGE + b",100>"]
_NUMBER = re.compile(rb"-?\d+(\.\d+)?")


class WireFuzz:
    """The peer's ``mutate`` hook: mutates a share of lines, records all that went out."""

    def __init__(self, seed: int, share: float = 0.15):
        self.rng = random.Random(seed)
        self.share = share
        self.out = bytearray()
        self.lock = threading.Lock()

    def __call__(self, data: bytes) -> bytes:
        with self.lock:
            if data.startswith(b"$13=") and self.rng.random() < 0.5:
                data = b"$13=" + self.rng.choice(NON_FINITE + [b"abc", b"1e5", b"-1", b"2"]) + b"\r\n"
            elif self.rng.random() < self.share:
                data = self._mutate(bytearray(data))
            self.out += data
            return data

    def push(self, data: bytes) -> bytes:
        with self.lock:
            self.out += data
        return data

    def _mutate(self, data: bytearray) -> bytes:
        rng = self.rng
        op = rng.randrange(9)
        i = rng.randrange(len(data))
        if op == 0:
            data[i] ^= 1 << rng.randrange(8)
        elif op == 1:
            data.insert(i, rng.randrange(256))
        elif op == 2:
            del data[i]
        elif op == 3:
            del data[i:]  # cut: the rest joins the next line
        elif op in (4, 5):
            numbers = list(_NUMBER.finditer(data))
            if numbers:
                m = rng.choice(numbers)
                data[m.start():m.end()] = rng.choice(NON_FINITE)
        elif op == 6:
            data += rng.choice(JUNK) + b"\r\n"
        elif op == 7:
            data += bytes(data)  # a doubled reply (two oks for one line)
        else:
            return b""  # a lost reply
        return bytes(data)


def wire_lines(data: bytes) -> set[str]:
    """The lines a driver could have read from ``data``."""
    return set(p.LineAssembler().feed(bytes(data) + b"\n"))


def make_vm() -> VirtualMachine:
    return VirtualMachine(MachineConfig(travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3,
                                        max_rate=(3000.0,) * 3, accel=(200.0,) * 3))


def run_session(seed: int, errors: list) -> dict:
    rng = random.Random(1000 + seed)
    pr = GrblPeer(make_vm(), speed=4.0)
    fuzz = WireFuzz(seed)
    pr.mutate = fuzz
    c = open_controller(pr.serve_url("pty" if seed % 2 else "tcp", "rate=50&timeout=0.3"))
    out = {"connected": False, "fresh": 0, "not_fresh": 0}
    try:
        try:
            c.connect()
        except DriverError:
            return out  # a clear error is allowed: a handshake that saw only garbage
        out["connected"] = True
        if rng.random() < 0.3:
            try:
                c.send(f"G1 X{rng.randint(1, 5)} F3000")
            except DriverError:
                pass
        last_t = -1.0
        for _ in range(POLLS):
            if rng.random() < 0.4:
                pr.inject(fuzz.push(rng.choice(JUNK) + b"\r\n"))
            t_call = time.monotonic()
            s = c.poll(timeout=0.1)
            assert isinstance(s, MachineState), f"session {seed}: poll returned {s!r}"
            assert s.t >= last_t, f"session {seed}: t went back from {last_t} to {s.t}"
            last_t = s.t
            if s.fresh:
                out["fresh"] += 1
                assert s.t >= t_call, f"session {seed}: fresh state older than its poll: {s.raw!r}"
                assert implausible(s) is None, f"session {seed}: fresh but {implausible(s)}: {s.raw!r}"
                assert s.raw in wire_lines(fuzz.out), f"session {seed}: fresh state not from the wire: {s.raw!r}"
            else:
                out["not_fresh"] += 1
                assert s.state in NOT_FRESH and s.raw, f"session {seed}: {s!r}"
        assert c._reader.is_alive(), f"session {seed}: the reader thread died"
        assert errors == [], f"session {seed}: a thread ended in a traceback: {errors[0].exc_value!r}"
    finally:
        c.close()
        pr.close()
    return out


def test_wire_fuzz_100_sessions():
    with thread_errors() as errors:
        results = [run_session(seed, errors) for seed in range(SESSIONS)]
    assert errors == []
    connected = [r for r in results if r["connected"]]
    assert len(connected) >= SESSIONS * 0.8  # mutations are a share, not all: most handshakes succeed
    assert sum(r["fresh"] for r in connected) > 0 and sum(r["not_fresh"] for r in connected) > 0
