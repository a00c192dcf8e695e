"""GRBL 1.1 wire parsers as pure functions: every field, every malformed form."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings, strategies as st

from drivers.errors import ProtocolError
from drivers.grbl import protocol as p
from drivers.grbl import readings
from drivers.state import MachineState, RunState

#: the work offset a report without WCO is converted with (a driver knows it from an earlier
#: report or from $# and $G; without it status_to_state refuses, see test_driver_peer)
NO_WCO = (0.0,) * 6


# ----------------------------------------------------------------------------- replies


def test_ok_error_alarm_with_meanings():
    assert isinstance(p.parse_line("ok"), p.Ok)
    e = p.parse_line("error:22")
    assert isinstance(e, p.Error) and e.code == 22 and "feed rate" in e.meaning.lower()
    a = p.parse_line("ALARM:3")
    assert isinstance(a, p.Alarm) and a.code == 3 and "reset while in motion" in a.meaning.lower()
    assert "soft limit" in p.parse_line("ALARM:2").meaning.lower()
    assert "unknown" in p.parse_line("error:250").meaning


@pytest.mark.parametrize("text", ["error:", "error:x", "error:1.5", "ALARM:", "ALARM:abc", "okay", "Ok"])
def test_malformed_replies_raise_protocol_error(text):
    with pytest.raises(ProtocolError) as info:
        p.parse_line(text)
    assert text in str(info.value)
    assert info.value.raw == text


def test_banners():
    b = p.parse_line("Grbl 1.1h ['$' for help]")
    assert isinstance(b, p.Banner) and b.firmware == "Grbl" and b.version == "1.1h"
    h = p.parse_line("GrblHAL 1.1f ['$' or '$HELP' for help]")
    assert isinstance(h, p.Banner) and h.firmware == "grblHAL" and h.version == "1.1f"


def test_feedback_messages():
    m = p.parse_line("[MSG:'$H'|'$X' to unlock]")
    assert isinstance(m, p.Feedback) and m.tag == "MSG" and m.text == "'$H'|'$X' to unlock"
    gc = p.parse_line("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]")
    assert isinstance(gc, p.ParserState)
    assert gc.words[:2] == ("G0", "G54") and gc.tool == 0 and gc.feed == 0 and gc.spindle == 0
    hlp = p.parse_line("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
    assert isinstance(hlp, p.Help) and "$J=line" in hlp.commands and "ctrl-x" in hlp.commands
    ver = p.parse_line("[VER:1.1h.20190830:my build]")
    assert isinstance(ver, p.Version) and ver.version == "1.1h.20190830" and ver.info == "my build"
    opt = p.parse_line("[OPT:VN,14,128]")
    assert isinstance(opt, p.Options) and opt.codes == "VN" and opt.blocks == 14 and opt.rx_size == 128
    g54 = p.parse_line("[G54:-5.000,2.000,-1.000]")
    assert isinstance(g54, p.Offset) and g54.name == "G54" and g54.values == (-5.0, 2.0, -1.0)
    for tag in ("G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
        assert p.parse_line(f"[{tag}:0.000,0.000,0.000]").name == tag
    tlo = p.parse_line("[TLO:1.500]")
    assert isinstance(tlo, p.Offset) and tlo.values == (1.5,)
    prb = p.parse_line("[PRB:1.000,2.000,-3.250:1]")
    assert isinstance(prb, p.Probe) and prb.position == (1.0, 2.0, -3.25) and prb.success
    assert not p.parse_line("[PRB:0.000,0.000,0.000:0]").success
    echo = p.parse_line("[echo:G1X10F100]")
    assert isinstance(echo, p.Echo) and echo.text == "G1X10F100"
    other = p.parse_line("[AXS:3:XYZ]")
    assert isinstance(other, p.Feedback) and other.tag == "AXS"


@pytest.mark.parametrize(
    "text",
    [
        "[MSG:unterminated",
        "[GC:G0 X]",
        "[GC:G0 Tfoo]",
        "[G54:1,2,x]",
        "[G54:]",
        "[G54:1,2,3,4,5,6,7]",
        "[PRB:1,2,3]",
        "[PRB:1,2,3:2]",
        "[OPT:V,x,128]",
        "[VER:]",
        "[NOCOLON]",
        "[:x]",
    ],
)
def test_malformed_feedback(text):
    with pytest.raises(ProtocolError, match="GRBL"):
        p.parse_line(text)


def test_settings_and_startup_lines():
    s = p.parse_line("$110=500.000")
    assert isinstance(s, p.Setting) and s.number == 110 and s.value == 500.0
    assert p.parse_line("$10=1").value == 1
    hal = p.parse_line("$300=grblhal")
    assert hal.number == 300 and math.isnan(hal.value) and hal.text == "grblhal"
    n = p.parse_line("$N0=G20 G54")
    assert isinstance(n, p.StartupLine) and n.index == 0 and n.text == "G20 G54"
    r = p.parse_line(">G54G20:ok")
    assert isinstance(r, p.StartupResult) and r.ok and r.text == "G54G20"
    r = p.parse_line(">G1X1:error:22")
    assert not r.ok and r.code == 22 and r.text == "G1X1"


@pytest.mark.parametrize("text", ["$110", "$x=1", "$=3", "$12=", ">G54", ">G1:error:x", ">G1:bad"])
def test_malformed_settings(text):
    with pytest.raises(ProtocolError):
        p.parse_line(text)


# ----------------------------------------------------------------------------- status


def test_status_every_field():
    r = p.parse_line(
        "<Hold:1|MPos:1.000,-2.500,3.125|Bf:12,100|Ln:123|FS:270,12000|Pn:XZP|WCO:-5.000,2.000,-1.000"
        "|Ov:110,50,90|A:SF>"
    )
    assert isinstance(r, p.StatusReport)
    assert r.state == "Hold" and r.substate == 1
    assert r.mpos == (1.0, -2.5, 3.125) and r.wpos is None
    assert r.buffer == (12, 100) and r.line == 123
    assert r.feed == 270 and r.spindle == 12000
    assert r.pins == "XZP" and r.wco == (-5.0, 2.0, -1.0)
    assert r.overrides == (110, 50, 90) and r.accessories == "SF"


def test_status_minimal_and_variants():
    r = p.parse_line("<Idle|WPos:0.000,0.000,0.000|F:500>")
    assert r.wpos == (0.0, 0.0, 0.0) and r.mpos is None and r.feed == 500 and r.spindle is None
    assert r.overrides is None and r.accessories is None and r.wco is None
    r = p.parse_line("<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>")
    assert r.accessories == ""  # Ov without A means every accessory off
    for name in ("Idle", "Run", "Jog", "Alarm", "Check", "Home", "Sleep"):
        assert p.parse_line(f"<{name}|MPos:0,0,0|FS:0,0>").state == name
    for sub in range(4):
        assert p.parse_line(f"<Door:{sub}|MPos:0,0,0|FS:0,0>").substate == sub
    six = p.parse_line("<Run|MPos:1,2,3,4,5,6|FS:0,0|T:2>")  # grblHAL: 6 axes and extras
    assert six.mpos == (1, 2, 3, 4, 5, 6) and ("T", "2") in six.extra


@pytest.mark.parametrize(
    "text",
    [
        "<Idle|MPos:0,0,0",  # truncated
        "Idle|MPos:0,0,0>",
        "<>",
        "<Running|MPos:0,0,0>",
        "<Hold:x|MPos:0,0,0>",
        "<Idle|FS:0,0>",  # no position
        "<Idle|MPos:0,0,0|WPos:0,0,0>",  # both
        "<Idle|MPos:0,0>",
        "<Idle|MPos:0,0,abc>",
        "<Idle|MPos:0,0,0|Bf:15>",
        "<Idle|MPos:0,0,0|Ln:1.5>",
        "<Idle|MPos:0,0,0|FS:1>",
        "<Idle|MPos:0,0,0|Pn:Q>",
        "<Idle|MPos:0,0,0|Ov:100,100>",
        "<Idle|MPos:0,0,0|A:Z>",
        "<Idle|MPos:0,0,0|FS0,0>",
        "<Idle|MPos:0,0,0|MPos:0,0,0>",
        "<Idle|MPos:0,0,0|?x:1>",
    ],
)
def test_malformed_status(text):
    with pytest.raises(ProtocolError) as info:
        p.parse_line(text)
    assert info.value.raw is not None


def test_status_to_state_wpos_plus_remembered_wco():
    r1 = p.parse_line("<Idle|WPos:5.000,-2.000,1.000|FS:0,0|WCO:-5.000,2.000,-1.000>")
    s1 = readings.status_to_state(r1, {10: 0}, None, 1.0)
    assert s1.mpos[:3] == (0.0, 0.0, 0.0) and s1.wco[:3] == (-5.0, 2.0, -1.0)
    # next report carries no WCO: the remembered one still converts WPos -> MPos
    r2 = p.parse_line("<Run|WPos:6.000,-2.000,1.000|FS:300,1000|Ov:120,100,100|A:C>")
    s2 = readings.status_to_state(r2, {10: 0}, s1.wco, 1.05, prev=s1)
    assert s2.mpos[:3] == (1.0, 0.0, 0.0)
    assert s2.wpos[:3] == (6.0, -2.0, 1.0)
    assert s2.state is RunState.RUN and s2.feed == 300 and s2.t == 1.05
    assert s2.overrides == (120, 100, 100) and s2.spindle == -1000 and s2.accessories == "C"
    # a report without Ov keeps overrides and accessories of the previous state
    r3 = p.parse_line("<Run|MPos:1.5,0,0|FS:300,1000>")
    s3 = readings.status_to_state(r3, None, s2.wco, 1.1, prev=s2)
    assert s3.overrides == (120, 100, 100) and s3.accessories == "C" and s3.spindle == -1000


def test_status_to_state_inches_and_alarm():
    r = p.parse_line("<Alarm|MPos:1.000,2.000,0.000|F:10|WCO:0.500,0,0>")
    s = readings.status_to_state(r, {13: 1}, None, 0.0, alarm=2)
    assert s.mpos[:3] == pytest.approx((25.4, 50.8, 0.0))
    assert s.wco[0] == pytest.approx(12.7) and s.feed == pytest.approx(254.0)
    assert s.state is RunState.ALARM and s.alarm == 2
    idle = readings.status_to_state(p.parse_line("<Idle|MPos:0,0,0|FS:0,0>"), None, NO_WCO, 0.0, alarm=2)
    assert idle.alarm is None and isinstance(idle, MachineState)


def test_status_to_state_carries_rotary_axes():
    """grblHAL sends 4 to 6 axes: A B C reach the state in degrees, in MPos, WPos and WCO."""
    s = readings.status_to_state(p.parse_line("<Idle|MPos:1.000,2.000,3.000,90.000|FS:0,0>"), {13: 0}, NO_WCO, 0.0)
    assert s.mpos == (1.0, 2.0, 3.0, 90.0, 0.0, 0.0)
    r = p.parse_line("<Run|WPos:1.000,2.000,3.000,80.000,-10.000,370.000|FS:100,0|WCO:0,0,0,10.000,5.000,0>")
    s = readings.status_to_state(r, {13: 0}, None, 0.0)
    assert s.mpos == (1.0, 2.0, 3.0, 90.0, -5.0, 370.0) and s.wco[3:] == (10.0, 5.0, 0.0)


@pytest.mark.parametrize("settings", [{13: 1, 376: 8}, {13: 1, 376: 56}, {13: 1}])
def test_status_to_state_inches_leave_rotary_axes_in_degrees(settings):
    """grblHAL with $13=1 reports the axes $376 marks rotary in degrees (3 decimals), not
    inches; without $376 read, A B C are taken as rotary."""
    r = p.parse_line("<Idle|MPos:1.0000,2.0000,0.0000,90.000|FS:0,0|WCO:0.5000,0,0,10.000>")
    s = readings.status_to_state(r, settings, NO_WCO, 0.0)
    assert s.mpos[:3] == pytest.approx((25.4, 50.8, 0.0))
    assert s.mpos[3] == 90.0 and s.wco[3] == 10.0 and s.wco[0] == pytest.approx(12.7)


def test_status_to_state_inches_scale_an_axis_376_calls_linear():
    """$376=0 (grblHAL's old default): the A axis is a length, reported in inches like X."""
    r = p.parse_line("<Idle|MPos:1.0000,0.0000,0.0000,2.0000|FS:0,0>")
    s = readings.status_to_state(r, {13: 1, 376: 0}, NO_WCO, 0.0)
    assert s.mpos[3] == pytest.approx(50.8)


def test_status_to_state_substate_buffer_pins_line():
    r = p.parse_line("<Hold:0|MPos:0,0,0|Bf:15,128|Ln:77|FS:0,0|Pn:P>")
    s = readings.status_to_state(r, None, NO_WCO, 2.0)
    assert s.state is RunState.HOLD and s.substate == 0
    assert s.buffer == (15, 128) and s.line == 77 and s.pins == "P"


# ----------------------------------------------------------------------------- assembler


def test_assembler_chunks_and_line_endings():
    a = p.LineAssembler()
    assert a.feed(b"o") == []
    assert a.feed(b"k\r") == []
    assert a.feed(b"\n<Idle|MPos:0,0,0|FS:0,0>\r\nerr") == ["ok", "<Idle|MPos:0,0,0|FS:0,0>"]
    assert a.pending == b"err"
    assert a.feed(b"or:1\n\n\r\nok\n") == ["error:1", "ok"]


def test_assembler_drops_noise_and_non_utf8():
    a = p.LineAssembler()
    lines = a.feed(b"\x00\xff\xfeo\x80k\r\n\x1b[0m\r\n")
    assert lines == ["ok", "[0m"]
    assert a.dropped == 5


def test_assembler_bounds_overlong_lines():
    a = p.LineAssembler(max_line=16)
    out = a.feed(b"x" * 100 + b"\nok\n")
    assert out == ["x" * 16, "ok"] and a.overflows == 1


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=12))
def test_fuzz_assembler_and_parser_only_protocol_errors(chunks):
    a = p.LineAssembler(max_line=200)
    for chunk in chunks:
        for line in a.feed(chunk):
            assert "\n" not in line and line.isascii()
            try:
                msg = p.parse_line(line)
            except ProtocolError:
                continue
            assert isinstance(msg, p.Message)


_pieces = st.sampled_from(
    ["<", ">", "|", ":", ",", "MPos", "WPos", "WCO", "Bf", "Ln", "FS", "F", "Pn", "Ov", "A", "Idle", "Hold",
     "0", "1.5", "-2", "x", "[", "]", "MSG", "GC", "PRB", "$", "=", "N", "error", "ALARM", "ok", " ", "."]
)


@settings(max_examples=300, deadline=None)
@given(st.lists(_pieces, max_size=25))
def test_fuzz_parser_structured_noise(parts):
    text = "".join(parts)
    try:
        msg = p.parse_line(text)
    except ProtocolError:
        return
    if isinstance(msg, p.StatusReport):
        s = readings.status_to_state(msg, {13: 0}, NO_WCO, 0.0)
        assert len(s.mpos) == 6


# ----------------------------------------------------------------------------- overrides


@pytest.mark.parametrize("current,target", [(100, 100), (100, 150), (100, 37), (120, 125), (200, 10), (55, 100)])
def test_override_steps_reach_target(current, target):
    value = current
    for b in p.override_steps(current, target, "feed"):
        value = p.apply_override(value, b[0], "feed")
    assert value == target


def test_override_steps_rapid_and_bad_values():
    assert p.override_steps(100, 25, "rapid") == [p.RT_RAPID_OV_LOW]
    with pytest.raises(ValueError):
        p.override_steps(100, 30, "rapid")
    with pytest.raises(ValueError):
        p.override_steps(100, 250, "feed")
    assert p.override_steps(100, 110, "spindle") == [p.RT_SPINDLE_OV_COARSE_PLUS]


def test_realtime_bytes_set():
    for b in (b"?", b"!", b"~", b"\x18", b"\x90", b"\x97", b"\x9d", b"\x85", b"\xa1"):
        assert b[0] in p.REALTIME_BYTES
    assert ord("G") not in p.REALTIME_BYTES and 0x98 not in p.REALTIME_BYTES


# ----------------------------------------------------------------------------- bounds

HUGE = str(2**64 + 1)


@pytest.mark.parametrize("text", [
    f"<Idle|MPos:0,0,0|Ln:{HUGE}|FS:0,0>",
    "<Idle|MPos:0,0,0|Ln:-5|FS:0,0>",
    f"<Hold:{HUGE}|MPos:0,0,0|FS:0,0>",
    "<Door:12|MPos:0,0,0|FS:0,0>",
    f"<Idle|MPos:0,0,0|FS:0,0|Ov:100,{HUGE},100>",
    "<Idle|MPos:0,0,0|FS:0,0|Ov:100,-1,100>",
    f"<Idle|MPos:0,0,0|Bf:15,{HUGE}|FS:0,0>",
    f"ALARM:{HUGE}",
    "ALARM:256",
    f"error:{HUGE}",
    f"[OPT:V,{HUGE},128]",
    "[OPT:V,15,-128]",
    f"[GC:G0 G54 G17 G21 G90 G94 M5 M9 T{HUGE} F0 S0]",
    f"${HUGE}=1",
    "<Idle|MPos:" + "9" * 400 + ",0,0|FS:0,0>",  # float() of it is inf
    "[G54:1" + "0" * 400 + ",0,0]",
])
def test_reported_numbers_beyond_sane_ranges_are_protocol_errors(text):
    with pytest.raises(ProtocolError) as info:
        p.parse_line(text)
    assert info.value.raw == text


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, 1e5, 2.0**70, -1.0, 0.5])
def test_status_to_state_survives_any_inch_setting(value):
    # a garbage $13 must never break unit scaling: it is ignored, the report format decides
    r = p.parse_line("<Idle|MPos:1.000,2.000,0.000|FS:10,0>")
    s = readings.status_to_state(r, {13: value}, NO_WCO, 0.0)
    assert s.mpos[:3] == pytest.approx((1.0, 2.0, 0.0)) and s.feed == 10


def test_units_follow_the_report_format_until_the_setting_is_known():
    # Grbl 1.1h prints 4 decimals in inches, 3 in mm (N_DECIMAL_COORDVALUE_INCH / _MM)
    inch = p.parse_line("<Idle|MPos:1.0000,0.0000,0.0000|FS:1.0,0>")
    assert readings.status_to_state(inch, None, NO_WCO, 0.0).mpos[0] == pytest.approx(25.4)
    assert readings.status_to_state(inch, {13: 0}, NO_WCO, 0.0).mpos[0] == pytest.approx(1.0)  # the setting wins
    mm = p.parse_line("<Idle|MPos:1.000,0.000,0.000|FS:1,0>")
    assert readings.status_to_state(mm, None, NO_WCO, 0.0).mpos[0] == pytest.approx(1.0)
    assert readings.report_in_inches(inch) is True and readings.report_in_inches(mm) is False
