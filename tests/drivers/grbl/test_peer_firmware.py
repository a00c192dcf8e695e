"""The GRBL peer answers as the Grbl 1.1h firmware does (issue 13), on a real pseudo-terminal.

Each test names the firmware source it follows (gnea/grbl v1.1h: report.c, protocol.c,
system.c, serial.c, gcode.c, spindle_control.c, coolant_control.c, main.c)."""

from __future__ import annotations

import os
import select
import termios
import tty

import pytest

from drivers.grbl.peer import BANNER, GrblPeer
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

TIMEOUT_S = 10.0  # generous: the suite must pass with both cores busy


def make_vm(**kw) -> VirtualMachine:
    cfg = dict(max_rate=(3000.0,) * 3, accel=(200.0,) * 3, travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3)
    cfg.update(kw)
    return VirtualMachine(MachineConfig(**cfg))


class PtyWire:
    """A raw sender on the peer's pseudo-terminal: bytes out (one write each), lines in."""

    def __init__(self, path: str):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd, termios.TCSANOW)
        self.buf = b""

    def send(self, data: bytes) -> None:
        assert os.write(self.fd, data) == len(data)

    def line(self) -> str:
        while b"\r\n" not in self.buf:
            ready, _, _ = select.select([self.fd], [], [], TIMEOUT_S)
            assert ready, f"no line from the peer within {TIMEOUT_S} s (have {self.buf!r})"
            self.buf += os.read(self.fd, 4096)
        raw, self.buf = self.buf.split(b"\r\n", 1)
        return raw.decode("ascii")

    def until(self, predicate) -> list[str]:
        out = [self.line()]
        while not predicate(out[-1]):
            out.append(self.line())
        return out

    def reply(self, data: bytes) -> list[str]:
        self.send(data)
        return self.until(lambda s: s == "ok" or s.startswith("error:"))

    def status(self) -> str:
        """Send ``?``; the report (every line before it must be another report)."""
        self.send(b"?")
        lines = self.until(lambda s: s.startswith("<"))
        assert all(s.startswith("<") for s in lines), lines
        return lines[-1]

    def status_until(self, predicate, limit: int = 5000) -> str:
        for _ in range(limit):
            s = self.status()
            if predicate(s):
                return s
        raise AssertionError(f"no status report matched; last {s}")

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def wire():
    made = []

    def make(vm=None, speed=4.0, **kw):
        peer = GrblPeer(vm or make_vm(), speed=speed, **kw)
        w = PtyWire(peer.serve_pty())
        made.append((peer, w))
        return peer, w

    yield make
    for peer, w in made:
        w.close()
        peer.close()


def field(report: str, name: str) -> str | None:
    for part in report.strip("<>").split("|"):
        if part.startswith(name + ":"):
            return part[len(name) + 1:]
    return None


def settle_cadence(w: PtyWire) -> None:
    """The first reports after a reset carry WCO then Ov (counters at 0): take them."""
    assert field(w.status(), "WCO") is not None
    assert field(w.status(), "Ov") is not None


def fresh_wco(w: PtyWire) -> None:
    """Report WCO now (``$13`` flags a WCO change), so it is 9 reports off (idle)."""
    assert w.reply(b"$13=0\n") == ["ok"]
    assert field(w.status(), "WCO") is not None


# ------------------------------------------------------------------ 1. $20


def test_soft_limits_setting_follows_the_configured_travel(wire):
    # stock Grbl: $20=0; the peer reports soft limits only when it has a travel to check
    _, w = wire(vm=make_vm(travel_min=None, travel_max=None))
    assert "$20=0" in w.reply(b"$$\n")
    _, w = wire(vm=make_vm(soft_limits=False))
    assert "$20=0" in w.reply(b"$$\n")
    _, w = wire(vm=make_vm())
    lines = w.reply(b"$$\n")
    assert "$20=1" in lines and "$130=400.000" in lines


# ------------------------------------------------------------------ 2. and 3. holds


def test_feed_hold_while_idle_holds_and_lines_wait_for_cycle_start(wire):
    # protocol.c: a hold while IDLE sets SUSPEND_HOLD_COMPLETE at once (Hold:0); the main
    # loop then sits in protocol_exec_rt_suspend and reads no line until '~'
    peer, w = wire(settings={10: 3})
    w.send(b"!")
    assert w.status().startswith("<Hold:0|MPos:0.000,0.000,0.000|Bf:15,128|")
    line = b"G0 X1\n"
    w.send(line)
    # the line waits in the 128-byte RX buffer: neither run nor answered
    s = w.status_until(lambda s: f"|Bf:15,{128 - len(line)}|" in s)
    assert s.startswith("<Hold:0|MPos:0.000,")
    assert w.buf == b"" and peer.received_lines == []
    w.send(b"~")
    assert w.line() == "ok"
    assert w.status_until(lambda s: s.startswith("<Idle|MPos:1.000,"))
    assert peer.received_lines == ["G0 X1"]


def advance(peer: GrblPeer, seconds: float) -> None:
    """Run the machine ``seconds`` of simulated time (a peer made with ``run=False``)."""
    with peer.vm.lock:
        peer.vm.advance(seconds)


def test_lines_sent_in_a_hold_are_buffered_and_dollar_commands_answer_error_8(wire):
    # the machine moves only when the test advances it: no assertion depends on speed
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False, settings={10: 3})
    assert w.reply(b"G1 X20 F600\n") == ["ok"]
    advance(peer, 0.5)
    assert w.status().startswith("<Run|")
    w.send(b"!")
    assert w.status().startswith("<Hold:1|")
    advance(peer, 0.5)  # decelerated: the hold is complete
    assert w.status().startswith("<Hold:0|")
    sent = b"G1 Y5\n$$\n"
    w.send(sent)
    s = w.status_until(lambda s: f"|Bf:14,{128 - len(sent)}|" in s)
    assert s.startswith("<Hold:0|") and w.buf == b"" and peer.received_lines == ["G1 X20 F600"]
    # '~': the cycle resumes (Run), then the main loop reads on: the motion line is planned,
    # and '$$' is refused while the machine runs (system.c: STATE_CYCLE | STATE_HOLD)
    w.send(b"~")
    replies = [r for r in w.until(lambda r: r.startswith("error:")) if not r.startswith("<")]
    assert replies == ["ok", "error:8"]
    assert w.status().startswith("<Run|")
    advance(peer, 10.0)
    assert w.status().startswith("<Idle|MPos:20.000,5.000,")


def test_dollar_commands_during_a_hold_that_decelerates_answer_error_8(wire):
    # Hold:1 (decelerating) is not yet suspended: the main loop still reads lines, and every
    # '$' command but $G / $C / $X / $J checks the state (system.c)
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False)
    assert w.reply(b"G1 X50 F600\n") == ["ok"]
    advance(peer, 0.5)
    w.send(b"!")
    assert w.status().startswith("<Hold:1|")
    assert w.reply(b"$$\n") == ["error:8"]
    assert w.reply(b"$#\n") == ["error:8"]
    assert w.reply(b"$C\n") == ["error:8"]
    assert w.reply(b"$G\n")[-1] == "ok"
    assert w.reply(b"G1 Y1\n") == ["ok"]  # planned behind the held block
    assert w.status().startswith("<Hold:1|")
    w.send(b"\x18")
    w.until(lambda s: s == BANNER)


def test_m0_holds_after_the_motion_and_answers_after_cycle_start(wire):
    # gcode.c: M0 syncs the planner, then a feed hold suspends the main loop inside the
    # line: its ok comes after '~', and the lines behind it wait in the RX buffer
    peer, w = wire(settings={10: 3})
    assert w.reply(b"G0 X1\n") == ["ok"]
    w.send(b"M0\nG0 X2\n")
    s = w.status_until(lambda s: s.startswith("<Hold:0|") and "|Bf:15,122|" in s)
    assert s.startswith("<Hold:0|MPos:1.000,0.000,0.000|") and w.buf == b""
    w.send(b"~")
    assert [w.line(), w.line()] == ["ok", "ok"]
    w.status_until(lambda s: s.startswith("<Idle|MPos:2.000,"))
    assert w.reply(b"M1\n") == ["ok"]  # optional stop: not supported, ignored
    assert w.status().startswith("<Idle|")


# ------------------------------------------------------------------ 4. arcs


def test_r_arc_radius_error_is_34_and_same_point_is_33(wire):
    _, w = wire()
    assert w.reply(b"G2 X10 R0 F100\n") == ["error:34"]
    assert w.reply(b"G2 X10 Y0 R4 F100\n") == ["error:34"]  # 4 R^2 < d^2
    assert w.reply(b"G2 X0 Y0 R0 F100\n") == ["error:33"]  # target = position
    assert w.reply(b"G2 X0 Y0 R5 F100\n") == ["error:33"]


# ------------------------------------------------------------------ 5. spindle and coolant


def test_spindle_and_coolant_in_fs_and_a_fields(wire):
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False)
    settle_cadence(w)
    assert w.reply(b"M3 S500\n") == ["ok"]
    # spindle_set_state resets report_ovr_counter: Ov (with A:) comes on the next report
    s = w.status()
    assert field(s, "FS") == "0,500" and s.endswith("|Ov:100,100,100|A:S>")
    assert w.reply(b"M8\n") == ["ok"]
    assert w.status().endswith("|A:SF>")
    assert field(w.status(), "A") is None  # A: comes only with Ov
    assert w.reply(b"G1 X5 F300\n") == ["ok"]
    advance(peer, 0.5)
    s = w.status()
    assert s.startswith("<Run|") and field(s, "FS") == "300,500"
    advance(peer, 5.0)
    assert w.status().startswith("<Idle|MPos:5.000,")
    fresh_wco(w)
    w.send(b"\x9a")  # spindle +10 %: reported at once, rpm scaled
    s = after_change(w, "|Ov:100,100,110|")
    assert field(s, "FS") == "0,550" and s.endswith("|Ov:100,100,110|A:SF>")
    assert w.reply(b"M4 S2000\n") == ["ok"]  # beyond $30=1000 rpm: clamped to it
    s = w.status()
    assert field(s, "FS") == "0,1000" and s.endswith("|A:CF>")
    assert w.reply(b"M5 M9\n") == ["ok"]
    s = w.status()
    assert field(s, "FS") == "0,0" and s.endswith("|Ov:100,100,110>")


def test_spindle_change_waits_for_the_motion_before_it(wire):
    # gcode.c: spindle_sync() empties the planner before the spindle changes
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False)
    assert w.reply(b"G1 X3 F600\n") == ["ok"]
    advance(peer, 0.2)
    w.send(b"M3 S800 G1 X0\n")  # its ok waits until the X3 move is done
    s = w.status()
    assert s.startswith("<Run|") and field(s, "FS").endswith(",0")
    advance(peer, 5.0)  # X3 reached: the spindle turns on, then X0 is planned (not run)
    assert w.line() == "ok"
    s = w.status()
    assert s.startswith("<Run|MPos:3.000,") and field(s, "FS") == "0,800"


def test_flood_toggle_byte_and_program_end(wire):
    peer, w = wire()
    settle_cadence(w)
    w.send(b"\xa0")  # coolant flood toggle (idle): on, reported at once
    assert after_change(w, "|A:F>").endswith("|Ov:100,100,100|A:F>")
    assert w.reply(b"M3 S100\n") == ["ok"]
    w.send(b"\x91")
    after_change(w, "|Ov:110,100,100|A:SF>")
    # M2: spindle and coolant off, overrides back to 100 % (RESTORE_OVERRIDES_AFTER_PROGRAM_END)
    # M2 also re-reads the work offset: WCO first, Ov on the report after it
    assert w.reply(b"M2\n") == ["ok"]
    s = w.status()
    assert field(s, "FS") == "0,0" and "|WCO:" in s and "|Ov:" not in s
    assert w.status().endswith("|FS:0,0|Ov:100,100,100>")


def test_spindle_stop_override_works_only_in_a_hold(wire):
    # protocol.c: 0x9E stops the spindle only in a hold; again (or '~') restores it
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False)
    settle_cadence(w)
    assert w.reply(b"M3 S500\n") == ["ok"]
    w.send(b"\x9e")  # Idle: ignored
    assert w.status().endswith("|FS:0,500|Ov:100,100,100|A:S>")
    assert w.reply(b"G1 X20 F600\n") == ["ok"]
    advance(peer, 0.5)
    w.send(b"!")
    assert w.status().startswith("<Hold:1|")
    advance(peer, 0.5)
    w.send(b"\x9e")
    s = after_change(w, "|Ov:")
    assert s.startswith("<Hold:0|") and field(s, "FS") == "0,0" and field(s, "A") is None
    w.send(b"~")  # cycle start restores the spindle first
    assert w.line() == "[MSG:Restoring spindle]"
    s = after_change(w, "|Ov:")
    assert s.startswith("<Run|") and field(s, "FS") == "0,500" and field(s, "A") == "S"


def test_a_limit_alarm_kills_spindle_and_coolant_outputs(wire):
    # limits.c: a soft limit calls mc_reset(), which turns the spindle and coolant pins
    # off (A: empty) but leaves sys.spindle_speed (FS) until the reset re-initialises
    peer, w = wire(vm=make_vm(travel_min=(-10.0,) * 3, travel_max=(0.0,) * 3))
    assert w.reply(b"M3 S500 M8\n") == ["ok"]
    w.send(b"G0 X-20\n")
    assert w.until(lambda s: s.startswith("[MSG:")) == ["ALARM:2", "[MSG:Reset to continue]"]
    # protocol.c spins until Ctrl-X: a '?' meanwhile gets no report (gnea/grbl#224)
    w.send(b"?")
    w.send(b"\x18")
    assert w.until(lambda s: s.startswith("[MSG:")) == ["", BANNER, "[MSG:'$H'|'$X' to unlock]"]
    s = w.status()
    assert s.startswith("<Alarm|") and field(s, "FS") == "0,0" and field(s, "A") is None


# ------------------------------------------------------------------ 6. check mode


def test_leaving_check_mode_answers_ok_then_resets(wire):
    peer, w = wire()
    assert w.reply(b"G1 X2 F600\n") == ["ok"]
    w.status_until(lambda s: s.startswith("<Idle|MPos:2.000,"))
    assert w.reply(b"$C\n") == ["[MSG:Enabled]", "ok"]
    assert w.reply(b"G91 G1 X50 F100\n") == ["ok"]
    assert w.reply(b"G92 Y3\n") == ["ok"]
    # system.c: mc_reset(), then [MSG:Disabled], then the line's ok; main.c re-initialises:
    # the banner after an empty line, position kept, parser and G92 back to defaults
    w.send(b"$C\n")
    assert [w.line() for _ in range(4)] == ["[MSG:Disabled]", "ok", "", BANNER]
    s = w.status()
    assert s.startswith("<Idle|MPos:2.000,0.000,0.000|") and "WCO:0.000,0.000,0.000" in s
    assert w.reply(b"$G\n")[0] == "[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]"
    assert "[G92:0.000,0.000,0.000]" in w.reply(b"$#\n")


def test_offsets_in_check_mode_are_reported_and_g10_outlives_the_reset(wire):
    # gcode.c changes offsets in check mode too (status WCO comes from the parser state),
    # and G10 writes the EEPROM: G54 survives the reset that ends check mode, G92 does not
    peer, w = wire()
    assert w.reply(b"G0 X2\n") == ["ok"]
    w.status_until(lambda s: s.startswith("<Idle|MPos:2.000,"))
    assert w.reply(b"$C\n") == ["[MSG:Enabled]", "ok"]
    assert w.reply(b"G10 L20 P1 X5\n") == ["ok"]
    assert field(w.status(), "WCO") == "-3.000,0.000,0.000"
    assert w.reply(b"G92 Y3\n") == ["ok"]
    assert field(w.status(), "WCO") == "-3.000,-3.000,0.000"
    w.send(b"$C\n")
    assert w.until(lambda s: s == BANNER)[:2] == ["[MSG:Disabled]", "ok"]
    assert field(w.status(), "WCO") == "-3.000,0.000,0.000"
    offsets = w.reply(b"$#\n")
    assert offsets[0] == "[G54:-3.000,0.000,0.000]" and "[G92:0.000,0.000,0.000]" in offsets


# ------------------------------------------------------------------ 7. override bytes


def after_change(w: PtyWire, expected: str) -> str:
    """The report that shows an override, spindle or coolant change: it carries Ov at once.

    A ``?`` read in one piece with the bytes before it is answered before they act (the
    firmware reports before it applies overrides in a pass), so the change may show one
    report later."""
    return w.status_until(lambda s: expected in s, limit=3)


def assert_overrides(w: PtyWire, expected: str) -> None:
    """The next reports show Ov ``expected`` (feed, rapid, spindle %)."""
    after_change(w, f"|Ov:{expected}")


def test_identical_override_bytes_in_one_write_count_once(wire):
    # serial.c sets a bit per override byte; protocol.c applies the bits once per pass
    peer, w = wire()
    settle_cadence(w)
    w.send(b"\x91\x91")
    assert_overrides(w, "110,100,100")
    w.send(b"\x91")
    assert_overrides(w, "120,100,100")  # a later write counts again
    w.send(b"\x92\x91\x93\x93")  # +10 -10 +1: the bits, not the bytes
    assert_overrides(w, "121,100,100")
    w.send(b"\x97\x95")  # rapid reset, then low, in the firmware's order
    assert_overrides(w, "121,25,100")
    w.send(b"\x9a\x9a\x9d")  # +10 (once) -1
    assert_overrides(w, "121,25,109")
    w.send(b"\x90\x92")  # reset, then -10
    assert_overrides(w, "90,25,109")
    for pct in range(80, 0, -10):
        w.send(b"\x92")
        assert_overrides(w, f"{pct},25,109")
    # at the floor, -10 and -1 together wrap the firmware's uint8 to 255, clamped to 200
    w.send(b"\x92\x94")
    assert_overrides(w, "200,25,109")


# ------------------------------------------------------------------ 8. WCO and Ov cadence


def wco_ov_indices(reports: list[str]) -> tuple[list[int], list[int]]:
    return ([i for i, r in enumerate(reports) if "|WCO:" in r],
            [i for i, r in enumerate(reports) if "|Ov:" in r])


def test_wco_reported_whenever_the_firmware_flags_an_offset_change(wire):
    peer, w = wire()
    settle_cadence(w)
    # G92 to the same value still flags the change (gcode.c: system_flag_wco_change)
    for line in (b"G92 X0\n", b"G55\n", b"G10 L20 P2 X0\n", b"G43.1 Z1\n", b"$13=1\n", b"M30\n"):
        assert w.reply(line) == ["ok"]
        assert field(w.status(), "WCO") is not None, line
        assert field(w.status(), "WCO") is None, line
    # what does not flag it: a G10 on another system, the report mask, an unchanged G54
    for line in (b"G54\n", b"G10 L2 P3 X7\n", b"$10=3\n"):
        assert w.reply(line) == ["ok"]
        assert field(w.status(), "WCO") is None, line


def test_wco_and_ov_cadence_while_jogging(wire):
    peer, w = wire(run=False)  # the jog lasts as long as the test needs
    settle_cadence(w)
    assert w.reply(b"$J=G91 X-150 F600\n") == ["ok"]
    advance(peer, 0.5)
    reports = [w.status() for _ in range(95)]
    assert all(r.startswith("<Jog|") for r in reports), reports[-1]
    wco, ov = wco_ov_indices(reports)
    # busy: WCO every 30th report, Ov every 20th (one later when it falls on a WCO report)
    assert [b - a for a, b in zip(wco, wco[1:])] == [30] * (len(wco) - 1) and len(wco) >= 3
    assert set(b - a for a, b in zip(ov, ov[1:])) <= {20, 21} and len(ov) >= 4
    assert not set(wco) & set(ov)
    w.send(b"\x85")
    assert w.status().startswith("<Jog|")  # answered after the cancel byte was taken
    advance(peer, 5.0)
    assert w.status().startswith("<Idle|")


# ------------------------------------------------------------------ 9. startup blocks ($N)


def test_startup_blocks_run_after_every_reset_not_in_alarm(wire):
    # system.c: $Nx=line runs the block through gc_execute_line before storing it (its
    # error refuses it); protocol.c runs the stored blocks after a reset or power-up that
    # does not end in alarm, each reported as '>' block ':' ok|error:N (report.c)
    peer, w = wire()
    assert w.reply(b"$n0=g20 (inch)\n") == ["ok"]  # stored as the main loop keeps it
    assert w.reply(b"$G\n")[0].startswith("[GC:G0 G54 G17 G20 ")  # run when stored
    assert w.reply(b"$N1=G1X1\n") == ["error:22"]  # no feed yet: refused, not stored
    assert w.reply(b"$N\n") == ["$N0=G20", "$N1=", "ok"]
    assert w.reply(b"F600\n") == ["ok"]
    assert w.reply(b"$N1=G1X1\n") == ["ok"]  # F600 is modal now: runs (moves) and is stored
    w.status_until(lambda s: s.startswith("<Idle|MPos:25.400,"))  # G20: X1 is an inch
    w.send(b"\x18")
    # the reset forgets F: the second block fails now, and says so
    assert w.until(lambda s: s.startswith(">G1X1:")) == ["", BANNER, ">G20:ok", ">G1X1:error:22"]
    assert w.reply(b"$G\n")[0].startswith("[GC:G0 G54 G17 G20 ")  # a refused block changes nothing
    assert w.reply(b"$N1=\n") == ["ok"]  # an empty block clears the slot: nothing reported
    w.send(b"\x18")
    assert w.until(lambda s: s.startswith(">")) == ["", BANNER, ">G20:ok"]
    assert w.reply(b"G21\n") == ["ok"]


def test_startup_blocks_wait_for_unlock_and_run_after_homing(wire):
    # a reset ending in alarm runs no block, nor does $X (system.c: "Prevents stored moves
    # in startup from causing accidents"); a successful $H runs them before its ok
    peer, w = wire(settings={22: 1})
    assert w.reply(b"$N0=G91\n") == ["ok"]
    assert w.reply(b"$SLP\n") == ["ok"]
    assert w.line() == "[MSG:Sleeping]"
    w.send(b"\x18")  # out of sleep: alarm
    assert w.until(lambda s: s.startswith("[MSG:")) == ["", BANNER, "[MSG:'$H'|'$X' to unlock]"]
    assert w.reply(b"$X\n") == ["[MSG:Caution: Unlocked]", "ok"]
    assert w.reply(b"G90\n") == ["ok"]
    assert w.reply(b"$H\n") == [">G91:ok", "ok"]
    assert w.reply(b"$G\n")[0].startswith("[GC:G0 G54 G17 G21 G91 ")


# ------------------------------------------------------------------ 10. $RST


def test_restore_answers_ok_then_resets(wire):
    # system.c: [MSG:Restoring defaults], mc_reset() (a flag), the line's ok (STATUS_OK);
    # then the main loop sees the reset: banner, startup blocks. settings_restore: '$'
    # the settings, '#' the G54..G59 G28 G30 offsets, '*' those and the startup blocks
    peer, w = wire()
    assert w.reply(b"$10=3\n") == ["ok"]
    assert w.reply(b"G10 L20 P1 X5\n") == ["ok"]
    assert w.reply(b"G28.1\n") == ["ok"]
    assert w.reply(b"$N0=G91\n") == ["ok"]
    w.send(b"$RST=$\n")
    assert w.until(lambda s: s.startswith(">")) == ["[MSG:Restoring defaults]", "ok", "", BANNER, ">G91:ok"]
    assert "$10=1" in w.reply(b"$$\n")
    offsets = w.reply(b"$#\n")
    assert offsets[0] == "[G54:-5.000,0.000,0.000]"  # '$' keeps the offsets
    w.send(b"$RST=#\n")
    assert w.until(lambda s: s.startswith(">")) == ["[MSG:Restoring defaults]", "ok", "", BANNER, ">G91:ok"]
    offsets = w.reply(b"$#\n")
    assert offsets[0] == "[G54:0.000,0.000,0.000]" and "[G28:0.000,0.000,0.000]" in offsets
    assert w.reply(b"$10=3\n") == ["ok"]
    w.send(b"$RST=*\n")
    assert w.until(lambda s: s == BANNER) == ["[MSG:Restoring defaults]", "ok", "", BANNER]
    assert w.reply(b"$N\n") == ["$N0=", "$N1=", "ok"]  # no startup block ran, none is left
    assert "$10=1" in w.reply(b"$$\n")
    assert w.reply(b"$RST=x\n") == ["error:3"]


# ------------------------------------------------------------------ 11. line filter and $ errors


def test_block_delete_slash_is_dropped_anywhere(wire):
    # protocol.c: '/' (block delete, not supported) is thrown away like a space
    peer, w = wire()
    assert w.reply(b"G0 X2/\n") == ["ok"]
    assert w.reply(b"/G0 Y/3\n") == ["ok"]
    w.status_until(lambda s: s.startswith("<Idle|MPos:2.000,3.000,"))
    assert w.reply(b"G0 X1 (a/b)\n") == ["ok"]
    # DEL is not a control character to the main loop: it reaches the parser as a letter
    assert w.reply(b"G0 X1\x7f\n") == ["error:1"]


def test_dollar_command_errors_follow_system_c(wire):
    peer, w = wire(settings={22: 1})
    # '$' 'G' 'C' 'X': anything after the letter is an invalid statement
    for line in (b"$$1\n", b"$G0\n", b"$C1\n", b"$X9\n", b"$#1\n", b"$HX\n", b"$SL\n", b"$Ix\n"):
        assert w.reply(line) == ["error:3"], line
    # other letters: read_float for the number (no digit: error:2), then '=' (error:3),
    # read_float for the value (error:2), then the end of the line (error:3)
    cases = {b"$A=1": "error:2", b"$=1": "error:2", b"$-=1": "error:2", b"$10": "error:3",
             b"$10x1": "error:3", b"$10=": "error:2", b"$10=x": "error:2", b"$10=1x": "error:3",
             b"$10=1.5.1": "error:3", b"$256=1": "error:3", b"$103=1": "error:3", b"$7=1": "error:3",
             b"$7=-1": "error:4", b"$NA=G20": "error:2", b"$N0G20": "error:3"}
    for line, want in cases.items():
        assert w.reply(line + b"\n") == [want], line
    assert "$10=1" in w.reply(b"$$\n")  # none of them changed a setting
    # the number is truncated to its integer (uint8_t), the value may end with '.'
    assert w.reply(b"$10.7=2.\n") == ["ok"]
    assert "$10=2" in w.reply(b"$$\n")
    # $I=text stores the build info (uppercase, no spaces, as the main loop keeps it)
    assert w.reply(b"$I=my mill\n") == ["ok"]
    assert w.reply(b"$I\n")[0] == "[VER:1.1h.20190830:MYMILL]"


# ------------------------------------------------------------------ 12. safety door (0x84)


def test_safety_door_while_idle_stops_spindle_and_coolant_until_cycle_start(wire):
    # serial.c sets EXEC_SAFETY_DOOR in any state; protocol.c: [MSG:Check Door], state
    # DOOR, hold complete at once from Idle; the suspend loop turns spindle and coolant off
    # and, with no door pin, reads the door closed (Door:0); the main loop reads no line.
    # '~' then restores the spindle (4 s spin-up), the coolant (1 s) and resumes (Door:3)
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False, settings={10: 3})
    settle_cadence(w)
    assert w.reply(b"M3 S500 M8\n") == ["ok"]
    assert w.status().endswith("|FS:0,500|Ov:100,100,100|A:SF>")
    w.send(b"\x84")
    assert w.line() == "[MSG:Check Door]"
    s = w.status()  # spindle_set_state / coolant_set_state report the change at once
    assert s.startswith("<Door:0|MPos:0.000,0.000,0.000|") and s.endswith("|FS:0,0|Ov:100,100,100>")
    w.send(b"G0 X1\n")
    assert w.status_until(lambda s: "|Bf:15,122|" in s).startswith("<Door:0|")
    w.send(b"!\xa0")  # no feed hold and no coolant toggle in the door state
    assert w.status().startswith("<Door:0|") and w.status().startswith("<Door:0|")
    w.send(b"~")
    s = w.status()
    assert s.startswith("<Door:3|") and field(s, "FS") == "0,500" and s.endswith("|A:S>")
    advance(peer, 4.0)
    s = w.status()
    assert s.startswith("<Door:3|") and s.endswith("|A:SF>")
    advance(peer, 1.0)
    assert w.status().startswith("<Idle|")
    assert w.line() == "ok"  # the line waiting in the RX buffer is read now
    advance(peer, 5.0)
    assert w.status().startswith("<Idle|MPos:1.000,")


def test_safety_door_during_motion_holds_then_resumes(wire):
    peer, w = wire(vm=make_vm(max_rate=(600.0,) * 3, accel=(100.0,) * 3), run=False)
    assert w.reply(b"G1 X20 F600\n") == ["ok"]
    advance(peer, 0.5)
    w.send(b"\x84")
    assert w.line() == "[MSG:Check Door]"
    assert w.status().startswith("<Door:2|")  # decelerating: the hold is not complete
    advance(peer, 0.5)
    s = w.status()
    assert s.startswith("<Door:0|") and field(s, "FS") == "0,0"
    w.send(b"\x84")  # again: the message again, the door stays closed (no pin)
    assert w.line() == "[MSG:Check Door]"
    assert w.status().startswith("<Door:0|")
    w.send(b"~")  # spindle and coolant were off: no delay
    assert w.status().startswith("<Run|")
    advance(peer, 10.0)
    assert w.status().startswith("<Idle|MPos:20.000,")


def test_safety_door_cancels_a_jog_and_is_ignored_in_alarm_and_check_mode(wire):
    peer, w = wire(run=False)
    assert w.reply(b"$J=G91 X-150 F600\n") == ["ok"]
    advance(peer, 0.5)
    w.send(b"\x84")
    assert w.line() == "[MSG:Check Door]"
    assert w.status().startswith("<Jog|")  # the jog is cancelled first
    advance(peer, 5.0)
    s = w.status()
    assert s.startswith("<Door:0|") and not s.startswith("<Door:0|MPos:-150.000")
    w.send(b"\x18")  # a reset leaves the door state
    w.until(lambda s: s == BANNER)
    assert w.status().startswith("<Idle|")
    assert w.reply(b"$C\n") == ["[MSG:Enabled]", "ok"]
    w.send(b"\x84")
    assert w.status().startswith("<Check|")  # no message either (status() checks)
    w.send(b"$C\n")
    w.until(lambda s: s == BANNER)
    assert w.reply(b"$SLP\n") == ["ok"]
    assert w.line() == "[MSG:Sleeping]"
    w.send(b"\x18")
    w.until(lambda s: s.startswith("[MSG:"))
    w.send(b"\x84")
    assert w.status().startswith("<Alarm|")
