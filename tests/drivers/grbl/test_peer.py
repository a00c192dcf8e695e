"""The GRBL peer byte for byte: what a sender sees on the wire."""

from __future__ import annotations

import socket

import pytest

from drivers.grbl import protocol as p
from drivers.grbl.peer import BANNER, GrblPeer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig


def make_vm(**kw) -> VirtualMachine:
    cfg = dict(max_rate=(3000.0,) * 3, accel=(200.0,) * 3, travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3)
    cfg.update(kw)
    return VirtualMachine(MachineConfig(**cfg))


class Wire:
    """A raw TCP sender: bytes out, lines in (with their \\r\\n checked)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.buf = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def line(self) -> str:
        while b"\r\n" not in self.buf:
            chunk = self.sock.recv(4096)
            assert chunk, "peer closed the connection"
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\r\n", 1)
        return raw.decode("ascii")

    def until(self, predicate) -> list[str]:
        out = []
        while True:
            out.append(self.line())
            if predicate(out[-1]):
                return out

    def reply(self, data: bytes) -> list[str]:
        self.send(data)
        return self.until(lambda s: s == "ok" or s.startswith("error:"))

    def status(self) -> str:
        self.send(b"?")
        return self.until(lambda s: s.startswith("<"))[-1]

    def close(self):
        self.sock.close()


@pytest.fixture
def wire():
    made = []

    def make(vm=None, speed=4.0, **kw):
        peer = GrblPeer(vm or make_vm(), speed=speed, **kw)
        w = Wire(peer.serve_tcp())
        made.append((peer, w))
        return peer, w

    yield make
    for peer, w in made:
        w.close()
        peer.close()


def test_status_cadence_of_wco_and_ov_idle_and_busy():
    vm = make_vm()
    peer = GrblPeer(vm, run=False)
    try:
        reports = [peer.status_report() for _ in range(21)]
        assert reports[0] == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"
        assert reports[1] == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"
        assert all("WCO" not in r and "Ov" not in r for r in reports[2:10])
        assert "WCO:" in reports[10] and "Ov:" in reports[11] and "WCO:" in reports[20]
        # busy: WCO every 30th, Ov every 20th
        rows = peer.interpreter.execute_line("G1 X100 F600", 1)
        with vm.lock:
            vm.queue(rows)
        peer.cadence.flag_wco()
        peer.cadence.flag_ovr()
        busy = [peer.status_report() for _ in range(61)]
        assert [i for i, r in enumerate(busy) if "WCO:" in r] == [0, 30, 60]
        assert [i for i, r in enumerate(busy) if "Ov:" in r] == [1, 21, 41]
        assert all(r.startswith("<Run|") for r in busy)
        for r in reports + busy:
            assert isinstance(p.parse_line(r), p.StatusReport)
    finally:
        peer.close()


def test_status_mask_fields_and_inches():
    vm = make_vm()
    peer = GrblPeer(vm, run=False, settings={10: 2})
    try:
        with vm.lock:
            vm.set_wco((-5.0, 2.0, -1.0))
        r = peer.status_report()
        assert r.startswith("<Idle|WPos:5.000,-2.000,1.000|Bf:15,128|FS:0,0|WCO:-5.000,2.000,-1.000")
        peer.settings[10] = 1
        peer.settings[13] = 1
        peer.cadence.flag_wco()
        r = peer.status_report()
        assert "MPos:0.0000,0.0000,0.0000" in r and "WCO:-0.1969,0.0787,-0.0394" in r
    finally:
        peer.close()


def test_replies_on_the_wire(wire):
    peer, w = wire()
    assert w.reply(b"$I\n") == ["[VER:1.1h.20190830:]", "[OPT:V,15,128]", "ok"]
    assert w.reply(b"$G\n") == ["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]
    lines = w.reply(b"$$\n")
    assert lines[0] == "$0=10" and "$110=3000.000" in lines and "$13=0" in lines and lines[-1] == "ok"
    offs = w.reply(b"$#\n")
    assert offs[:1] == ["[G54:0.000,0.000,0.000]"] and "[TLO:0.000]" in offs
    assert offs[-2:] == ["[PRB:0.000,0.000,0.000:0]", "ok"]
    assert w.reply(b"$\n")[0].startswith("[HLP:$$ $# $G $I $N")
    # comments, lowercase and blank lines are accepted
    assert w.reply(b"g21 (metric) ; trailing\n") == ["ok"]
    assert w.reply(b"\n") == ["ok"]
    # GRBL ends a line at \r and at \n: "\r\n" is a line and an empty line
    w.send(b"G90\r\n")
    assert [w.line(), w.line()] == ["ok", "ok"]
    assert w.reply(b"G1 X1\n") == ["error:22"]
    assert w.reply(b"M6\n") == ["error:20"]
    assert w.reply(b"$10=-1\n") == ["error:4"]
    assert w.reply(b"$0=2\n") == ["error:6"]
    assert w.reply(b"%\n") == ["error:1"]
    assert w.reply(b"G1 X" + b"1" * 90 + b" F100\n") == ["error:11"]


def test_rx_buffer_overflow_drops_bytes_as_hardware_does(wire):
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(50.0,) * 3), speed=1.0)
    # an idle main loop reads a long line at once: the line buffer overflows, error:11
    w.send(b"G1 X" + b"1" * 200 + b" F600\n")
    assert w.line() == "error:11"
    assert peer.rx_dropped == 0
    # fill the planner so the main loop blocks on the next motion line ... (send-response:
    # sent at once, 16 lines would overflow the RX buffer whenever the peer reads late)
    for i in range(15):
        w.send(f"G1 X{i + 1} F600\n".encode())
        assert w.line() == "ok"
    w.send(b"G1 X16 F600\n")
    peer.settings[10] = 3  # report Bf: (as "$10=3" would, but the main loop is blocked)
    while "|Bf:0,128|" not in w.status():  # the 16th line waits for planner room
        pass
    # ... then bytes wait in the 128-byte RX buffer, and beyond it they are lost
    w.send(b"G4 P0 ;" + b"x" * 200 + b"\n")
    s = w.status()
    assert "|Bf:0,0|" in s
    assert peer.rx_dropped == 7 + 200 + 1 - 128
    w.send(b"\x18")
    w.until(lambda s: s == BANNER)


def test_jog_and_jog_cancel(wire):
    peer, w = wire(speed=1.0)
    assert w.reply(b"$J=G91 X5 F600\n") == ["ok"]
    assert w.status().startswith("<Jog|")
    assert w.reply(b"G1 X1 F100\n") == ["error:9"]  # G-code locked out while jogging
    while float(w.status().split("MPos:")[1].split(",")[0]) < 0.5:
        pass
    w.send(b"\x85")
    while not (s := w.status()).startswith("<Idle"):
        pass
    x = float(s.split("MPos:")[1].split(",")[0])
    assert 0.0 < x < 5.0
    assert w.reply(b"$J=G90 X2 Y3 F3000\n") == ["ok"]
    while not (s := w.status()).startswith("<Idle"):
        pass
    assert "MPos:2.000,3.000,0.000" in s
    assert w.reply(b"$J=X1\n") == ["error:22"]  # no feed
    assert w.reply(b"$J=G1 X1 F100\n") == ["error:16"]
    assert w.reply(b"$J=G91 X500 F100\n") == ["error:15"]  # beyond the travel


def test_check_mode_and_sleep(wire):
    peer, w = wire()
    assert w.reply(b"$C\n") == ["[MSG:Enabled]", "ok"]
    assert w.status().startswith("<Check|")
    assert w.reply(b"G1 X50 F100\n") == ["ok"]  # parsed, not moved
    assert w.reply(b"G1 X1 Q5\n")[-1].startswith("error:")
    w.send(b"$C\n")
    assert w.until(lambda s: s == BANNER)[0] == "[MSG:Disabled]"
    assert w.status().startswith("<Idle|MPos:0.000,0.000,0.000")
    assert w.reply(b"$SLP\n") == ["ok"]
    assert w.line() == "[MSG:Sleeping]"
    assert w.status().startswith("<Sleep|")
    w.send(b"\x18")
    assert w.until(lambda s: s.startswith("[MSG:"))[-1] == "[MSG:'$H'|'$X' to unlock]"
    assert w.status().startswith("<Alarm|")
    assert w.reply(b"$X\n") == ["[MSG:Caution: Unlocked]", "ok"]


def test_ok_waits_for_planner_room(wire):
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(50.0,) * 3), speed=1.0)
    assert w.reply(b"F600\n") == ["ok"]
    # 15 short moves fill the planner; the 16th's ok comes only when a block is done
    for i in range(15):
        w.send(f"G1 X{i + 1}\n".encode())
    for _ in range(15):
        assert w.line() == "ok"
    w.send(b"G1 X16\n")
    s = w.status()  # answered while the 16th line waits
    assert s.startswith("<Run|")
    assert w.until(lambda s: s == "ok")
    assert peer.vm.snapshot().mpos[0] >= 0.9  # a block had to finish first
    w.send(b"\x18")
    assert w.until(lambda s: s.startswith("ALARM:"))[-1] == "ALARM:3"
    assert w.until(lambda s: s.startswith("[MSG:"))[-1] == "[MSG:'$H'|'$X' to unlock]"


def test_overrides_bytes(wire):
    peer, w = wire()
    w.send(b"\x91\x93")  # +10 then +1: distinct bytes
    ov = None
    for _ in range(25):
        s = w.status()
        if "Ov:" in s:
            ov = s.split("Ov:")[1].split("|")[0].rstrip(">")
            break
    assert ov == "111,100,100"
    w.send(b"\x97\x9b")
    s = w.status()
    assert "Ov:111,25,90" in s  # the next report after a change carries Ov
    w.send(b"\x90\x95\x99")
    assert "Ov:100,100,100" in w.status()
    assert peer.vm.snapshot().overrides == (100, 100, 100)


def test_work_offsets_persist_over_reset_but_g92_does_not(wire):
    peer, w = wire()
    assert w.reply(b"G10 L20 P1 X5 Y-2 Z1\n") == ["ok"]
    assert w.reply(b"G92 X1\n") == ["ok"]
    offs = w.reply(b"$#\n")
    assert offs[0] == "[G54:-5.000,2.000,-1.000]" and "[G92:-6.000,0.000,0.000]" in offs or "[G92:" in offs[8]
    w.send(b"\x18")
    w.until(lambda s: s == BANNER)
    offs = w.reply(b"$#\n")
    assert offs[0] == "[G54:-5.000,2.000,-1.000]" and offs[8] == "[G92:0.000,0.000,0.000]"
    w.send(b"?")
    s = w.until(lambda s: s.startswith("<"))[-1]
    assert "WCO:-5.000,2.000,-1.000" in s


def test_dwell_and_spindle_changes_wait_for_motion(wire):
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(50.0,) * 3), speed=2.0)
    assert w.reply(b"G1 X3 F600\n") == ["ok"]  # queued: ok at once
    assert w.status().startswith("<Run|")
    assert w.reply(b"G4 P0\n") == ["ok"]  # a sync point: ok when the motion is done
    assert w.status().startswith("<Idle|MPos:3.000,")
    assert w.reply(b"G1 X0\n") == ["ok"]
    assert w.reply(b"M8\n") == ["ok"]  # coolant waits for the move before it
    assert w.status().startswith("<Idle|MPos:0.000,")
