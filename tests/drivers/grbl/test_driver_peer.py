"""The GRBL driver end to end against the GRBL peer, over a real pty and over TCP."""

from __future__ import annotations

import os
import threading
import time

import pytest

from drivers.errors import DriverError
from drivers.grbl.driver import GrblController, from_url
from drivers.grbl.streaming import GrblError
from drivers.grbl.peer import GrblPeer
from drivers.registry import open_controller
from drivers.state import RunState
from drivers.virtual.machine import VirtualMachine
from drivers.virtual.machine_config import MachineConfig

FAST = dict(max_rate=(3000.0, 3000.0, 3000.0), accel=(200.0, 200.0, 200.0))


def make_vm(travel: float = 200.0) -> VirtualMachine:
    return VirtualMachine(MachineConfig(travel_min=(-travel,) * 3, travel_max=(travel,) * 3, **FAST))


@pytest.fixture
def peer():
    peers = []

    def make(vm=None, speed=1.0, **kw):
        pr = GrblPeer(vm or make_vm(), speed=speed, **kw)
        peers.append(pr)
        return pr

    yield make
    for pr in peers:
        pr.close()


@pytest.fixture(params=["pty", "tcp"])
def link(request, peer):
    """(peer, connected controller) over a pty or TCP."""
    controllers = []

    def make(vm=None, speed=1.0, url_extra="", **kw):
        pr = peer(vm, speed, **kw)
        c = open_controller(pr.serve_url(request.param, f"rate=50{url_extra}"))
        c.connect()
        controllers.append(c)
        return pr, c

    yield make
    for c in controllers:
        c.close()


def idle(c: GrblController, timeout: float = 10.0):
    return c.wait_for_state(lambda s: s.state is RunState.IDLE, timeout)


def test_handshake_learns_the_controller(link):
    pr, c = link()
    assert c.banner is None and 0x18 not in pr.realtime_log  # attaching resets nothing (reset=1 would)
    assert c.version.version.startswith("1.1h") and c.options.blocks == 15 and c.rx_size == 128
    assert c.settings[110] == 3000.0 and c.settings[120] == 200.0 and c.settings[130] == 400.0
    assert c.settings[10] == 1 and c.settings[13] == 0
    assert set(c.offsets) >= {"G54", "G59", "G28", "G30", "G92", "TLO"}
    assert c.parser_state.words[:6] == ("G0", "G54", "G17", "G21", "G90", "G94")
    s = c.poll()
    assert s.state is RunState.IDLE and s.mpos == (0.0,) * 6
    assert c.garbage == type(c.garbage)() and c.unexpected_acks == 0


def test_status_polling_rate_and_fields(link):
    pr, c = link()
    states = []
    for s in c.states(period=0.02):
        states.append(s)
        if len(states) == 12:
            break
    ts = [s.t for s in states]
    assert all(b > a for a, b in zip(ts, ts[1:]))  # stamped at arrival, monotonic
    assert ts[-1] - ts[0] >= 11 * 0.02 * 0.9
    # the first reports after a reset carry WCO then Ov, as Grbl 1.1h does
    assert pr.status_requests >= 12


def test_wpos_mask_and_g10_offsets(link):
    pr, c = link()
    c.command("$10=0")  # WPos reports: the driver needs WCO to know MPos
    c.command("G10 L20 P1 X5 Y-2 Z1")
    s = c.poll()
    assert "WPos:" in s.raw
    assert s.mpos[:3] == pytest.approx((0.0, 0.0, 0.0))
    assert s.wco[:3] == pytest.approx((-5.0, 2.0, -1.0))
    assert s.wpos[:3] == pytest.approx((5.0, -2.0, 1.0))
    # most reports carry no WCO: the remembered one keeps converting
    for _ in range(5):
        s = c.poll()
    assert s.mpos[:3] == pytest.approx((0.0, 0.0, 0.0))
    replies = c.command("$#")
    g54 = [m for m in replies if getattr(m, "name", "") == "G54"][0]
    assert g54.values == pytest.approx((-5.0, 2.0, -1.0))


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_attaching_to_work_position_reports_never_takes_them_for_machine_positions(peer, transport):
    # report.c: WPos = MPos - WCO in every report, but WCO is printed only every 10th
    # (idle) to 30th (busy) report. A driver attaching mid-count must not take WPos for
    # MPos meanwhile: it knows the offset from its own $# and $G
    pr = peer(make_vm())
    url = pr.serve_url(transport, "rate=50")
    first = open_controller(url)
    first.connect()
    first.command("$10=0")
    first.command("G10 L20 P1 X5 Y-2 Z1")        # WCO -5, 2, -1 at MPos 0, 0, 0
    first.command("G92 X1")                      # and G92 (WPos X1): WCO -1, 2, -1
    for _ in range(3):
        assert first.poll().mpos[:3] == pytest.approx((0.0, 0.0, 0.0))
    first.close()
    c = open_controller(url)
    c.connect()
    try:
        states = [c.poll() for _ in range(12)]
        assert all(s.fresh for s in states), [s.raw for s in states if not s.fresh]
        assert sum("WCO:" in s.raw for s in states) >= 1 and "WCO:" not in states[0].raw
        for s in states:
            assert s.mpos[:3] == pytest.approx((0.0, 0.0, 0.0)), s.raw
            assert s.wco[:3] == pytest.approx((-1.0, 2.0, -1.0)), s.raw
    finally:
        c.close()


def test_a_work_position_report_with_no_offset_known_is_not_a_position():
    from drivers.grbl import protocol as p
    from drivers.grbl import readings

    rep = p.parse_status("<Run|WPos:5.000,-2.000,1.000|FS:300,0>")
    with pytest.raises(readings.OffsetUnknown, match="WCO"):
        readings.status_to_state(rep, {}, None, 0.0)
    s = readings.status_to_state(rep, {}, (-5.0, 2.0, -1.0, 0, 0, 0), 0.0)
    assert s.mpos[:3] == pytest.approx((0.0, 0.0, 0.0))
    # nor is a machine position whose offset is unknown taken with an offset of zero
    with pytest.raises(readings.OffsetUnknown):
        readings.status_to_state(p.parse_status("<Run|MPos:5.000,-2.000,1.000|FS:300,0>"), {}, None, 0.0)


def test_the_offset_in_force_from_dollar_hash_and_dollar_g():
    from drivers.grbl import protocol as p
    from drivers.grbl import readings

    offsets = {"G54": (1.0, 2.0, 3.0), "G55": (10.0, 20.0, 30.0), "G92": (0.5, 0.0, 0.0), "TLO": (2.0,)}
    gc = p.parse_line("[GC:G0 G55 G17 G21 G90 G94 M5 M9 T0 F0 S0]")
    assert readings.offset_in_force(offsets, gc, {13: 0}) == pytest.approx((10.5, 20.0, 32.0, 0, 0, 0))
    # in inches when $13=1, as Grbl prints $#
    assert readings.offset_in_force(offsets, gc, {13: 1})[:3] == pytest.approx((266.7, 508.0, 812.8))
    assert readings.offset_in_force({"G54": (1.0, 2.0, 3.0)}, gc, {}) is None     # no G55, G92, TLO yet
    assert readings.offset_in_force(offsets, None, {}) is None


@pytest.mark.parametrize("mode", ["counting", "send-response"])
def test_stream_program(link, mode):
    pr, c = link(speed=4.0)
    program = ["G21 G90 (setup)", "; a comment line", "F1500"]
    program += [f"G1 X{(i % 10) + 1} Y{i // 10}" for i in range(40)]
    program += ["G0 X0 Y0", "%"]
    acks = []
    res = c.stream(program, mode=mode, on_ack=acks.append)
    assert res.completed and res.errors == [] and res.sent == res.acked == 43
    assert [a.index for a in acks] == sorted(a.index for a in acks)
    assert pr.rx_dropped == 0  # never more than GRBL's RX buffer in flight
    assert c.max_in_flight <= 127
    if mode == "counting":
        assert c.max_in_flight > 40  # several lines in the buffer at once
    else:
        assert c.max_in_flight <= max(len(l) + 1 for l in program)
    s = idle(c, 20)
    assert s.mpos[:2] == pytest.approx((0.0, 0.0))
    # the peer saw every line (comments stripped by the driver, '%' never sent)
    assert pr.received_lines[-41:] == [l for l in program if l[0] in "GF"][-41:]


def test_stream_reports_refused_lines_and_goes_on(link):
    pr, c = link(speed=4.0)
    res = c.stream(["G1 X1", "G1 X1 F300", "G99", "G4", "G1 X2"])
    assert res.completed
    assert [(i, code) for i, _, code, _ in res.errors] == [(0, 22), (2, 20), (3, 28)]
    assert "feed rate" in res.errors[0][3].lower()
    assert idle(c).mpos[0] == pytest.approx(2.0)



def test_stream_and_send_never_put_a_realtime_byte_inside_a_line(link):
    # serial.c picks '!' '~' '?' and Ctrl-X out of the byte stream wherever they stand:
    # a '!' inside a comment would feed-hold the machine. The driver sends lines without
    # their comments (as real senders do) and refuses a real-time byte anywhere else.
    pr, c = link(speed=4.0)
    program = ["G21 G90 F1200 (careful!)", "G1 X5 ; hold? no~", "(a; b) G1 Y2 (x!) X6", "(only a comment!)"]
    res = c.stream(program, timeout=10.0)
    assert res.completed and res.sent == res.acked == 3 and res.errors == []
    assert pr.received_lines[-3:] == ["G21 G90 F1200", "G1 X5", "G1 Y2 X6"]
    assert idle(c).mpos[:2] == pytest.approx((6.0, 2.0))
    assert c.command("G0 X0 (back!)") == []
    assert pr.received_lines[-1] == "G0 X0"
    for bad in ("G1 X1 !", "G1 X1~", "$J=X1?F100", "G0 \x18X1", "G0 X1\nG0 X2", "G0 X1\rG0 X2"):
        with pytest.raises(DriverError, match="real-time|line end"):
            c.send(bad)
        with pytest.raises(DriverError, match="real-time|line end"):
            c.stream([bad])
    assert [b for b in pr.realtime_log if b != ord("?")] == []  # polls only
    assert pr.received_lines[-1] == "G0 X0"  # nothing of a refused line was sent

def test_system_command_errors(link):
    pr, c = link()
    # $Q: no number where system.c reads the setting's (read_float): error:2, not 3
    for line, code in (("$H", 5), ("$99=1", 3), ("$110=-1", 4), ("$Q", 2), ("$Q=1", 2), ("%", 1)):
        with pytest.raises(GrblError) as info:
            c.command(line)
        assert info.value.code == code, line
    help_ = c.command("$")
    assert "$J=line" in help_[0].commands
    assert c.command("$N")[0].raw == "$N0="


def test_line_numbers_and_buffer_fields(link):
    pr, c = link(speed=1.0)
    c.command("$10=3")  # MPos + Bf
    c.send("N77 G1 X20 F600")
    s = c.wait_for_state(lambda s: s.line == 77, 5)
    assert s.state is RunState.RUN and s.buffer is not None and s.buffer[1] <= 128
    assert s.feed > 0
    c.feed_hold()
    c.wait_for_state(lambda s: s.state is RunState.HOLD and s.substate == 0, 5)
    c.soft_reset()


def test_feed_hold_and_resume(link):
    vm = VirtualMachine(MachineConfig(max_rate=(3000.0,) * 3, accel=(20.0,) * 3,
                                      travel_min=(-200.0,) * 3, travel_max=(200.0,) * 3))
    pr, c = link(vm=vm, speed=1.0)
    c.send("G1 X100 F1200")
    c.wait_for_state(lambda s: s.state is RunState.RUN and s.feed >= 600, 5)
    c.feed_hold()
    s = c.wait_for_state(lambda s: s.state is RunState.HOLD, 2)
    assert s.substate in (0, 1)
    held = c.wait_for_state(lambda s: s.state is RunState.HOLD and s.substate == 0, 5)
    assert held.feed == 0
    again = c.poll()
    assert again.mpos == held.mpos  # stopped on the path
    c.resume()
    s = c.wait_for_state(lambda s: s.state is RunState.RUN and s.mpos[0] > held.mpos[0], 5)
    c.soft_reset()


def test_a_command_held_in_a_feed_hold_keeps_the_replies_in_order(link):
    # Grbl 1.1h: '!' while Idle holds (Hold:0) and lines wait, unanswered, until '~'. A
    # command that times out there is not lost: its late reply must not answer the next one
    pr, c = link()
    assert c.command("M3 S500") == []
    c.feed_hold()
    held = c.wait_for_state(lambda s: s.state is RunState.HOLD and s.substate == 0, 5)
    assert held.spindle == 500 and held.accessories == "S"
    with pytest.raises(DriverError, match=r"Hold:0.*cycle start"):
        c.command("$G", timeout=0.2)
    c.resume()
    replies = c.command("$I")  # sent at once: the held $G's reply comes first
    assert [type(r).__name__ for r in replies] == ["Version", "Options"]
    assert c.command("$G")[0].words[6] == "M3"


def test_overrides(link):
    pr, c = link()
    assert c.set_feed_override(150) == 150
    assert c.poll().overrides[0] == 150
    assert c.set_feed_override(37) == 37
    assert c.set_rapid_override(25) == 25
    assert c.set_spindle_override(120) == 120
    assert c.poll().overrides == (37, 25, 120)
    assert c.set_feed_override(100) == 100


def test_soft_limit_alarm_mid_program(link):
    pr, c = link(vm=make_vm(travel=30.0), speed=4.0)
    res = c.stream(["G1 X10 F3000", "G1 X20", "G1 X50", "G1 X0", "G1 Y5"])
    assert not res.completed and res.alarm == 2 and "ALARM:2" in res.stopped
    s = c.wait_for_state(lambda s: s.state is RunState.ALARM, 5)
    assert s.alarm == 2 and s.mpos[0] <= 30.0
    assert any(m.raw == "[MSG:Reset to continue]" for _, m in c.messages)
    with pytest.raises(DriverError):
        c.command("G1 X0", timeout=0.3)  # GRBL ignores lines until the reset
    t_reset = time.monotonic()
    c.soft_reset()
    assert c.wait_for_message(lambda m: m.raw == "[MSG:'$H'|'$X' to unlock]", 2, since=t_reset)
    with pytest.raises(GrblError) as info:
        c.command("G1 X0")
    assert info.value.code == 9  # G-code lock in alarm
    c.unlock()
    assert c.poll().state is RunState.IDLE
    c.command("G1 X0 F3000")
    assert idle(c).mpos[0] == pytest.approx(0.0)


def test_ctrl_x_during_motion_is_alarm_3(link):
    pr, c = link(speed=1.0)
    c.send("G1 X50 F600")
    moving = c.wait_for_state(lambda s: s.state is RunState.RUN and s.mpos[0] > 0.5, 5)
    c.soft_reset()
    s = c.wait_for_state(lambda s: s.state is RunState.ALARM, 2)
    assert s.alarm == 3 and s.mpos[0] >= moving.mpos[0]
    assert c.alarms[-1][1] == 3
    c.unlock()
    assert c.poll().state is RunState.IDLE


def test_garbage_and_truncated_lines_are_survived(link):
    pr, c = link()
    pr.inject(b"\xff\xfe\x00garbage\r\n<Idle|MPos:1.0,2.0\r\nok")  # noise, a cut report, a cut ok
    pr.inject(b"\r\n")  # ... whose end arrives later: "okok"? no: "ok" then newline
    pr.inject(b"<Idle|MPos:9,9,9|FS:0,0|Bogus\r\n[MSG:half")
    pr.inject(b"\r\n")
    s = c.poll()
    assert s.state is RunState.IDLE and s.mpos[:3] == (0.0, 0.0, 0.0)
    raws = [g[1] for g in c.garbage]
    assert "garbage" in raws and "<Idle|MPos:1.0,2.0" in raws and "<Idle|MPos:9,9,9|FS:0,0|Bogus" in raws
    assert c.unexpected_acks == 1  # the injected ok with nothing in flight
    c.command("G1 X1 F3000")
    assert idle(c).mpos[0] == pytest.approx(1.0)


def test_port_vanishes_mid_run_and_comes_back_tcp(peer):
    pr = peer(speed=1.0)
    port = pr.serve_tcp()
    c = from_url(f"grbl+socket://127.0.0.1:{port}?rate=50")
    c.connect()
    try:
        c.send("G1 X30 F1200")
        before = c.wait_for_state(lambda s: s.state is RunState.RUN and s.mpos[0] > 0.5, 5)
        pr.close_transports()  # cable pulled
        assert c.wait_disconnected(2)
        s = c.poll()
        assert s.state is RunState.DISCONNECTED and s.mpos == c.last_state.mpos
        assert c.poll().state is RunState.DISCONNECTED
        pr.serve_tcp(port=port)
        assert c.wait_connected(5)
        back = c.poll()
        assert back.state in (RunState.RUN, RunState.IDLE) and back.mpos[0] >= before.mpos[0]
        assert back.fresh and back.t > before.t  # a new report, not the one before the gap
        assert len(c.gaps) == 1
        gap = c.gaps[0]
        t_lost, t_back = gap
        assert t_back > t_lost and gap.polls_missed >= 2 and "disconnected" in gap.reason.lower()
        assert idle(c).mpos[0] == pytest.approx(30.0)  # the machine went on while we were away
    finally:
        c.close()


def test_port_vanishes_and_comes_back_pty(peer, tmp_path):
    pr = peer(speed=1.0)
    link_path = str(tmp_path / "ttyGRBL")
    pr.serve_pty(link=link_path)
    c = from_url(f"grbl://{link_path}?rate=50")
    c.connect()
    try:
        c.command("G1 X5 F3000")
        pr.close_transports()
        assert c.wait_disconnected(2)
        assert not os.path.exists(link_path)
        assert c.poll().state is RunState.DISCONNECTED
        pr.serve_pty(link=link_path)
        assert c.wait_connected(5)
        assert idle(c).mpos[0] == pytest.approx(5.0)
        assert len(c.gaps) == 1 and c.gaps[0].t_back > c.gaps[0].t_lost
    finally:
        c.close()


def test_stream_stops_when_connection_is_lost(peer):
    pr = peer(speed=1.0)
    port = pr.serve_tcp()
    c = from_url(f"grbl+socket://127.0.0.1:{port}?rate=50&reconnect=0")
    c.connect()
    try:
        result = {}
        first_ack = threading.Event()

        def run():
            result["r"] = c.stream([f"G1 X{i} F600" for i in range(1, 60)], on_ack=lambda cmd: first_ack.set())

        th = threading.Thread(target=run)
        th.start()
        assert first_ack.wait(5)
        pr.close_transports()
        th.join(10)
        r = result["r"]
        assert not r.completed and r.stopped == "connection lost" and 0 < r.acked < 59
    finally:
        c.close()


def test_connect_to_silence_is_a_clear_error(tmp_path):
    master, slave = os.openpty()
    try:
        c = GrblController(os.ttyname(slave), timeout=0.3, reconnect=False)
        with pytest.raises(DriverError, match="no status report or banner"):
            c.connect()
    finally:
        os.close(master)
        os.close(slave)


def test_url_errors():
    with pytest.raises(DriverError, match="rate"):
        from_url("grbl:///dev/ttyUSB0?rate=100")
    with pytest.raises(DriverError, match="unknown parameter"):
        from_url("grbl:///dev/ttyUSB0?bogus=1")
    with pytest.raises(DriverError, match="not a number"):
        from_url("grbl:///dev/ttyUSB0?baud=fast")
    with pytest.raises(DriverError, match="host:port"):
        from_url("grbl+socket://")
    c = from_url("grbl+socket://localhost:23?baud=9600&rate=10&reset=0")
    assert c.port == "socket://localhost:23" and c.baud == 9600 and c.rate == 10 and not c.reset_on_connect
    assert not from_url("grbl:///dev/ttyUSB0").reset_on_connect and from_url("grbl:///dev/ttyUSB0?reset=1").reset_on_connect
    assert from_url("grbl+pty:///dev/pts/7").port == "/dev/pts/7"
