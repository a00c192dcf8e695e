"""The passthrough never stalls the path between the machine and the sender or the
monitor: an endpoint nobody reads drops its output instead of blocking.

The machine is the GRBL peer on a pty; the senders stream ``$$`` (about 450 bytes of
reply each) and ``?`` with character counting until more than 1 MB came back.
"""

from __future__ import annotations

import collections
import os
import select
import socket

import pytest

from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.state import LinkKind
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

REPLY_BYTES = 1_100_000   # more than 1 MB back to the sender
READ_TIMEOUT = 15.0       # s without a byte while a reply is due: the path stalled
RX_BUFFER = 127           # GRBL's serial RX buffer less one, as senders count it


class FastSender:
    """A character-counting sender over a socket or a pty file descriptor, reading in
    chunks (pyserial's byte-by-byte ``read_until`` is too slow for megabytes)."""

    def __init__(self, send, recv_ready, recv):
        self._send, self._ready, self._recv = send, recv_ready, recv
        self.rx = bytearray()
        self.bytes_in = 0
        self.answers: list[str] = []
        self.reports = 0
        self.queries = 0

    @classmethod
    def tcp(cls, port: int) -> "FastSender":
        sock = socket.create_connection(("127.0.0.1", port), timeout=READ_TIMEOUT)
        s = cls(sock.sendall, lambda t: select.select([sock], [], [], t)[0], lambda: sock.recv(65536))
        s.close = sock.close
        return s

    @classmethod
    def pty(cls, path: str) -> "FastSender":
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY)

        def send(data: bytes) -> None:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]

        s = cls(send, lambda t: select.select([fd], [], [], t)[0], lambda: os.read(fd, 65536))
        s.close = lambda: os.close(fd)
        return s

    def _pump(self, in_flight: collections.deque) -> None:
        if not self._ready(READ_TIMEOUT):
            raise AssertionError(f"sender: no byte for {READ_TIMEOUT} s with {len(in_flight)} line(s) "
                                 f"and {self.queries - self.reports} '?' unanswered, "
                                 f"after {self.bytes_in} bytes and {len(self.answers)} answers")
        data = self._recv()
        assert data, "sender: the passthrough closed the connection"
        self.bytes_in += len(data)
        self.rx += data
        while (i := self.rx.find(b"\n")) >= 0:
            text = self.rx[:i].decode("ascii", "replace").strip()
            del self.rx[: i + 1]
            if text.startswith("<"):
                self.reports += 1
            elif text == "ok" or text.startswith("error:"):
                self.answers.append(text)
                in_flight.popleft()

    def stream_until(self, reply_bytes: int, line: str = "$$", poll_every: int = 4) -> int:
        """Stream ``line`` (and a ``?`` every ``poll_every`` lines) until ``reply_bytes``
        came back and every line and ``?`` was answered; return the lines sent."""
        data = line.encode() + b"\n"
        in_flight: collections.deque = collections.deque()
        sent = 0
        while self.bytes_in < reply_bytes:
            while in_flight and sum(in_flight) + len(data) > RX_BUFFER:
                self._pump(in_flight)
            self._send(data)
            in_flight.append(len(data))
            sent += 1
            if sent % poll_every == 0:
                self.queries += 1
                self._send(b"?")
        while in_flight or self.reports < self.queries:
            self._pump(in_flight)
        return sent


@pytest.fixture
def machine():
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(200.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    peer = GrblPeer(vm, speed=4.0)
    yield peer, peer.serve_pty()
    peer.close()


def test_sender_on_tcp_is_not_stalled_by_the_pty_nobody_opened(machine):
    peer, machine_path = machine
    pt = Passthrough(machine_path, rate=50, tcp_port=0)  # offers a pty too, never opened
    pt.start()
    sender = FastSender.tcp(pt.sender_port)
    try:
        sent = sender.stream_until(REPLY_BYTES)
        assert sender.answers == ["ok"] * sent
        assert sender.reports == sender.queries
        # the monitor side still sees fresh reports (own polls) after the megabyte
        seen = len(pt.states_seen)
        assert pt.poll(timeout=5).fresh and pt.poll(timeout=5).fresh
        assert pt.own_polls > 0 and len(pt.states_seen) > seen
        # what the pty could not deliver was discarded, not queued for a later sender
        pty = pt.sender_output[pt.sender_path]
        assert pty["discarded"] > 0 and pty["dropped"] == 0
    finally:
        sender.close()
        pt.close()


def test_tcp_client_that_never_reads_does_not_stall_the_pty_sender(machine):
    peer, machine_path = machine
    pt = Passthrough(machine_path, rate=50, tcp_port=0)
    pt.start()
    lazy = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    lazy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # fills after a few KB
    lazy.connect(("127.0.0.1", pt.sender_port))
    sender = FastSender.pty(pt.sender_path)
    try:
        sent = sender.stream_until(REPLY_BYTES)
        assert sender.answers == ["ok"] * sent
        assert sender.reports == sender.queries
        assert pt.poll(timeout=5).fresh
        tcp = f"tcp:127.0.0.1:{pt.sender_port}"
        assert pt.sender_output[tcp]["dropped"] > 0
        notes = [ev for ev in pt.link_events() if ev.kind is LinkKind.NOTE and "drop" in ev.message]
        assert len(notes) == 1 and tcp in notes[0].message
    finally:
        sender.close()
        lazy.close()
        pt.close()


def test_sender_on_tcp_is_not_stalled_by_a_pty_opened_and_never_read(machine):
    peer, machine_path = machine
    pt = Passthrough(machine_path, rate=50, tcp_port=0)
    pt.start()
    lazy = os.open(pt.sender_path, os.O_RDWR | os.O_NOCTTY)  # opened, never read
    sender = FastSender.tcp(pt.sender_port)
    try:
        sent = sender.stream_until(REPLY_BYTES)
        assert sender.answers == ["ok"] * sent
        assert sender.reports == sender.queries
        assert pt.poll(timeout=5).fresh
        assert pt.sender_output[pt.sender_path]["dropped"] > 0
        notes = [ev for ev in pt.link_events() if ev.kind is LinkKind.NOTE and "drop" in ev.message]
        assert len(notes) == 1 and pt.sender_path in notes[0].message
    finally:
        sender.close()
        os.close(lazy)
        pt.close()
