"""A passthrough serves its sender until the sender closes: ``wait_sender_closed``
follows a TCP client and a pty's opener (seen as the master hanging up), and the pty
survives a sender closing and opening it again."""

from __future__ import annotations

import socket
import threading

import pytest
import serial

from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

WAIT = 10.0  # generous timeout of every wait, s


@pytest.fixture
def pt():
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(200.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    peer = GrblPeer(vm, speed=4.0)
    pt = Passthrough(peer.serve_pty(), rate=50, tcp_port=0)
    pt.start()
    yield pt
    pt.close()
    peer.close()


def _tcp_command(sock: socket.socket, line: bytes) -> bytes:
    sock.sendall(line + b"\n")
    got = b""
    while not got.endswith(b"ok\r\n"):
        chunk = sock.recv(4096)
        assert chunk, "the passthrough closed the sender's connection"
        got += chunk
    return got


def _pty_command(port: serial.SerialBase, line: bytes) -> bytes:
    port.write(line + b"\n")
    got = b""
    while not got.endswith(b"ok\r\n"):
        chunk = port.read_until(b"\n")
        assert chunk.endswith(b"\n"), f"no answer to {line!r} (got {got + chunk!r})"
        got += chunk
    return got


def _waiter(pt: Passthrough, **kw) -> tuple[threading.Thread, dict]:
    result: dict = {}
    th = threading.Thread(target=lambda: result.update(closed=pt.wait_sender_closed(**kw)), daemon=True)
    th.start()
    return th, result


def test_no_sender_no_wait(pt):
    assert not pt.sender_connected
    assert pt.wait_sender_closed(timeout=WAIT, grace=0)


def test_tcp_sender_is_served_until_it_disconnects(pt):
    sock = socket.create_connection(("127.0.0.1", pt.sender_port), timeout=WAIT)
    try:
        assert b"[VER:" in _tcp_command(sock, b"$I")
        assert pt.sender_connected
        assert not pt.wait_sender_closed(timeout=0.2, grace=0)  # still there
        waiter, result = _waiter(pt, timeout=None, grace=0)
        for _ in range(3):  # the monitor is done; the sender still gets its answers
            assert _tcp_command(sock, b"G4 P0").endswith(b"ok\r\n")
        assert waiter.is_alive()
    finally:
        sock.close()
    waiter.join(WAIT)
    assert result == {"closed": True}


def test_pty_sender_close_is_seen_and_reopen_is_served(pt):
    port = serial.serial_for_url(pt.sender_path, baudrate=115200, timeout=WAIT)
    assert b"[VER:" in _pty_command(port, b"$I")
    assert not pt.wait_sender_closed(timeout=0.2, grace=0)
    port.close()
    assert pt.wait_sender_closed(timeout=WAIT, grace=0)
    # the sender opens it again: served as before, and its close is seen again
    port = serial.serial_for_url(pt.sender_path, baudrate=115200, timeout=WAIT)
    try:
        assert _pty_command(port, b"G4 P0").endswith(b"ok\r\n")
        assert pt.sender_connected
    finally:
        port.close()
    assert pt.wait_sender_closed(timeout=WAIT, grace=0)
    assert [line.result for line in pt.lines] == ["ok", "ok"]


def test_a_reopen_within_the_grace_is_not_the_end(pt):
    port = serial.serial_for_url(pt.sender_path, baudrate=115200, timeout=WAIT)
    _pty_command(port, b"G4 P0")
    waiter, result = _waiter(pt, timeout=None, grace=3.0)
    port.close()
    port = serial.serial_for_url(pt.sender_path, baudrate=115200, timeout=WAIT)
    try:
        assert _pty_command(port, b"G4 P0").endswith(b"ok\r\n")
        assert waiter.is_alive() and not result
    finally:
        port.close()
    waiter.join(WAIT)
    assert result == {"closed": True}
