"""Passthrough between a scripted sender on a pty and the GRBL peer."""

from __future__ import annotations

import socket

import pytest
import serial

from drivers.grbl.passthrough import Passthrough
from drivers.grbl.peer import GrblPeer
from drivers.state import RunState
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig


class ScriptedSender:
    """A sender as UGS/CNCjs are: character counting, its own '?' now and then."""

    def __init__(self, port: serial.SerialBase):
        self.port = port
        self.queries = 0
        self.reports: list[str] = []
        self.replies: list[str] = []
        self.other: list[str] = []
        self.raw = bytearray()

    def read_line(self, timeout: float = 5.0) -> str:
        self.port.timeout = timeout
        data = self.port.read_until(b"\n")
        assert data.endswith(b"\n"), f"sender: no line within {timeout} s (got {data!r})"
        self.raw += data
        text = data.decode("ascii").strip()
        if text.startswith("<"):
            self.reports.append(text)
        elif text == "ok" or text.startswith("error:"):
            self.replies.append(text)
        elif text:
            self.other.append(text)
        return text

    def query(self) -> str:
        self.queries += 1
        self.port.write(b"?")
        while True:
            text = self.read_line()
            if text.startswith("<"):
                return text

    def command(self, line: str) -> list[str]:
        self.port.write(line.encode() + b"\n")
        got = []
        while True:
            text = self.read_line()
            got.append(text)
            if text == "ok" or text.startswith("error:"):
                return got

    def stream(self, lines: list[str], poll_every: int = 5) -> list[str]:
        """Character-counting stream; returns the replies in order."""
        in_flight: list[int] = []
        replies = []
        for i, line in enumerate(lines):
            data = line.encode() + b"\n"
            while sum(in_flight) + len(data) > 127:
                text = self.read_line()
                if text == "ok" or text.startswith("error:"):
                    in_flight.pop(0)
                    replies.append(text)
            self.port.write(data)
            in_flight.append(len(data))
            if i % poll_every == 0:
                self.queries += 1
                self.port.write(b"?")
        while in_flight:
            text = self.read_line()
            if text == "ok" or text.startswith("error:"):
                in_flight.pop(0)
                replies.append(text)
        return replies


@pytest.fixture
def rig():
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(200.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    peer = GrblPeer(vm, speed=4.0)
    machine_path = peer.serve_pty()
    pt = Passthrough(machine_path, rate=50, tcp_port=0)
    sender_path = pt.start()
    port = serial.serial_for_url(sender_path, baudrate=115200, timeout=2)
    yield peer, pt, ScriptedSender(port)
    port.close()
    pt.close()
    peer.close()


def test_sender_streams_through_and_passthrough_learns(rig):
    peer, pt, sender = rig
    assert sender.command("$I")[-1] == "ok"
    assert "[VER:1.1h.20190830:]" in sender.other
    program = ["G21 G90", "F1200", "N10 G1 X5", "N20 G1 Y5", "G1 X10 Y10", "G99", "G2 X20 Y0 I5 J-5", "G0 X0 Y0"]
    replies = sender.stream(program, poll_every=3)
    assert replies == ["ok"] * 5 + ["error:20"] + ["ok"] * 2
    # wait for the end of motion the way a sender does: asking '?'
    while not sender.query().startswith("<Idle"):
        pass
    # the sender got exactly one report per '?' it sent, never one of the passthrough's
    assert len(sender.reports) == sender.queries
    assert pt.own_polls > 0 and pt.swallowed > 0
    # bytes reached the machine unchanged and in order
    assert peer.received_lines[-len(program):] == program
    # the passthrough learned every line with its answer
    learned = [(l.text, l.result) for l in pt.lines]
    assert learned[0] == ("$I", "ok")
    assert learned[1:] == [(t, "error:20" if t == "G99" else "ok") for t in program]
    assert [l.n for l in pt.lines if l.n is not None] == [10, 20]
    assert [l.index for l in pt.lines] == list(range(len(program) + 1))
    # and watched the machine move all along (own polls and the sender's)
    states = list(pt.states_seen)
    assert any(s.state is RunState.RUN for s in states)
    assert 20.0 <= max(s.mpos[0] for s in states) <= 15 + 50 ** 0.5 + 1e-3  # the arc bulges past X20
    last = pt.poll()
    assert last.state is RunState.IDLE and last.mpos[:2] == pytest.approx((0.0, 0.0))


def test_quiet_sender_sees_nothing_while_passthrough_polls(rig):
    peer, pt, sender = rig
    assert sender.command("G1 X3 F1200") == ["ok"]
    before = pt.own_polls
    states = [pt.poll() for _ in range(10)]  # reports of own polls only
    assert pt.own_polls >= before + 5
    assert states[-1].t > states[0].t
    # nothing but the 'ok' reached the sender: a read finds no stray report
    sender.port.timeout = 0.1
    assert sender.port.read(4096) == b""
    assert sender.reports == []


def test_sender_over_tcp_and_settings_learned(rig):
    peer, pt, _ = rig
    with socket.create_connection(("127.0.0.1", pt.sender_port), timeout=5) as sock:
        sock.sendall(b"$$\n")
        buf = b""
        while not buf.endswith(b"ok\r\n"):
            chunk = sock.recv(4096)
            assert chunk
            buf += chunk
    assert b"$110=3000.000\r\n" in buf
    assert pt.settings[110] == 3000.0 and pt.settings[13] == 0
    assert pt.lines[-1].text == "$$" and pt.lines[-1].result == "ok"


def test_machine_port_vanishes_and_comes_back():
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(200.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    peer = GrblPeer(vm, speed=4.0)
    port = peer.serve_tcp()
    pt = Passthrough(f"grbl+socket://127.0.0.1:{port}?rate=50")
    sender_path = pt.start()
    sp = serial.serial_for_url(sender_path, baudrate=115200, timeout=2)
    sender = ScriptedSender(sp)
    try:
        assert sender.command("G1 X2 F3000") == ["ok"]
        assert pt.poll().state in (RunState.RUN, RunState.IDLE)
        peer.close_transports()
        assert pt.poll(timeout=2).state is RunState.DISCONNECTED
        peer.serve_tcp(port=port)
        assert pt.wait_connected(5)
        assert sender.command("G1 X4") == ["ok"]  # the sender carries on through the new link
        while not sender.query().startswith("<Idle"):
            pass
        assert len(pt.gaps) == 1 and pt.gaps[0].t_back > pt.gaps[0].t_lost
        assert pt.poll().mpos[0] == pytest.approx(4.0)
        assert len(sender.reports) == sender.queries
    finally:
        sp.close()
        pt.close()
        peer.close()


def test_a_setting_the_sender_changes_is_learned_from_its_ok(rig):
    # a sender reads $$ when it connects, then sets $13=1: Grbl answers ok and reports
    # in inches from then on (settings.c, report.c printFloat_CoordValue); the positions
    # must still come out in mm, not 25.4 times too small
    peer, pt, sender = rig
    assert sender.command("$$")[-1] == "ok"
    assert pt.settings[13] == 0
    assert sender.command("G0 X25.4 Y-12.7") == ["ok"]
    while not sender.query().startswith("<Idle"):
        pass
    assert sender.command("$13=1") == ["ok"]
    assert pt.wait_lines(3, 5)
    assert pt.settings[13] == 1
    report = sender.query()
    assert "MPos:1.0000,-0.5000," in report
    assert pt.poll().mpos[:2] == pytest.approx((25.4, -12.7))
    # settings.c keeps $13 as a flag: any non-zero value is 1; a line Grbl refuses
    # (no such setting: error:3) teaches nothing
    assert sender.command("$13 = 7") == ["ok"] and sender.command("$999=1") == ["error:3"]
    assert pt.wait_lines(5, 5)
    assert pt.settings[13] == 1 and 999 not in pt.settings
    # restoring the defaults makes every learned setting unknown until the next $$
    sender.port.write(b"$RST=$\n")
    while "Grbl 1.1h" not in sender.read_line():
        pass
    assert 13 not in pt.settings and pt.poll().mpos[:2] == pytest.approx((25.4, -12.7))


def test_a_limit_alarm_is_polled_as_alarm_though_grbl_answers_no_report(rig):
    # protocol.c: after a soft limit Grbl spins until Ctrl-X and answers no '?': the
    # passthrough's polls must say Alarm, not Missed until the monitor gives up
    peer, pt, sender = rig
    assert sender.command("G0 X20") == ["ok"]
    while not sender.query().startswith("<Idle"):
        pass
    sender.port.write(b"G0 X500\n")
    while sender.read_line() != "[MSG:Reset to continue]":
        pass
    s = pt.poll(0.2)
    assert s.state is RunState.ALARM and s.alarm == 2 and s.mpos[0] == pytest.approx(20.0)
    sender.port.write(b"\x18")
    while "Grbl 1.1h" not in sender.read_line():
        pass
    assert pt.poll().state is RunState.ALARM and pt.poll().alarm == 2   # reported again: ALARM until unlocked
