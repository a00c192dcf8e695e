"""The M codes LinuxCNC accepts that move nothing (issue 13): I/O, overrides, orient,
M70-M73 modal state save/restore; user M codes refused as rs274 refuses them.

Whole-program comparisons with rs274: tests/data/rs274/programs/modal_state.ngc and
mcodes_restore.ngc (test_rs274.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, interpret, work_end

MOTION = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE)


def ends(text):
    m = interpret(text).moves
    return work_end(m[np.isin(m["kind"], MOTION)])[:, :3]


@pytest.mark.parametrize("line", ["M66 P0 L0", "M66 P1 L3 Q5", "M66 E0 L0", "M62 P1", "M63 P1", "M64 P0",
                                  "M65 P0", "M67 E1 Q2.5", "M68 E2 Q3", "M19 R90 Q2 P1", "M48", "M49",
                                  "M50 P0", "M51 P1", "M52 P1", "M53 P0", "M52"])
def test_io_and_override_codes_are_accepted_and_move_nothing(line):
    p = interpret(f"G21 G0 X1\n{line}\nG0 Y1\nM2")
    assert len(p.moves) == 3 and p.moves["kind"].tolist()[:2] == [MoveKind.RAPID, MoveKind.RAPID]


def test_m19_stops_the_spindle():
    p = interpret("G21 S1000 M3\nM19 R0\nG1 X1 F10\nM2")
    assert p.moves["spindle_dir"][0] == 0


@pytest.mark.parametrize("line,needle", [
    ("M66 P1 E1", "not both"),
    ("M66 L0", "needs a P"),
    ("M66 P1 L1", "timeout Q"),
    ("M66 E1 L2 Q1", "L must be 0"),
    ("M62", "M62 needs a P word"),
    ("M67 Q1", "M67 needs an E word"),
    ("M19 P3", "M19 P must be 0, 1 or 2"),
    ("M72", "M72 has no saved modal state"),
    ("M70\nM71\nM72", "M72 has no saved modal state"),
    ("M190 P1", "user M codes (M100-M199)"),
    ("M400", "none above M199"),
    ("M54", "unknown M code M54"),
    ("G0 X1 E2", "E word with no M66, M67 or M68"),
    ("G41 D1 G1 X5 F10\nM62 P1", "cutter compensation on"),
])
def test_refusals_name_the_code(line, needle):
    with pytest.raises(GCodeError) as info:
        interpret(f"G21\n{line}\nM2", tool_table={1: _tool()})
    assert needle in info.value.message


def _tool():
    from sim.tooltable import ToolEntry

    return ToolEntry(number=1, pocket=1, diameter=2.0)


def test_m72_restores_modes_but_not_the_motion_mode():
    e = ends("G21 G90 F5 G0 X0\nM70\nG91 G20 G1 X1\nM72\nX7\nM2")
    np.testing.assert_allclose(e[-1], [7, 0, 0])   # G90 mm again; still G1
    p = interpret("G21 G90 F5 G0 X0\nM70\nG91 G20 G1 X1\nM72\nX7\nM2")
    assert p.moves["kind"][2] == MoveKind.FEED and p.moves["feed"][2] == pytest.approx(5.0)


def test_m72_restores_feed_to_one_decimal_and_the_spindle():
    p = interpret("G21 F12.345 S1000 M3 M8\nM70\nF3 S10 M5 M9\nM72\nG1 X1\nM2")
    row = p.moves[0]
    assert row["feed"] == pytest.approx(12.3) and row["spindle"] == 1000
    assert row["spindle_dir"] == 1 and row["coolant"] == 2


def test_m73_restores_at_the_return_of_its_sub():
    text = "G21 G90\no<s> sub\nM73\nG20 G91\nG0 X1\no<s> endsub\no<s> call\nG0 X3\nM2"
    np.testing.assert_allclose(ends(text), [[25.4, 0, 0], [3, 0, 0]])
    # without M73 the sub's modes stay
    np.testing.assert_allclose(ends(text.replace("M73", "")), [[25.4, 0, 0], [25.4 + 76.2, 0, 0]])


def test_m73_at_the_top_level_is_said():
    p = interpret("G21\nM73\nG0 X1\nM2")
    assert any("M73" in m for _, m in p.messages)


def test_g92_2_and_g92_3_set_5210():
    e = ends("G21 G0 X0\nG92 X5\nG0 Y[#5210]\nG92.2\nG0 Y[#5210]\nG92.3\nG0 Y[#5210]\nM2")
    assert e[1:, 1].tolist() == [1, 0, 1]


def test_hal_pin_parameters_are_refused_where_they_are_read():
    # LinuxCNC's plasmac programs: M52 P1 is accepted, the HAL pin read is not (as in rs274)
    with pytest.raises(GCodeError) as info:
        interpret("G21\nG64 P0.005\nM52 P1\nF#<_hal[plasmac.cut-feed-rate]>\nG0 X1\nM2")
    assert info.value.line == 4 and "HAL pin" in info.value.message


def test_m7_and_m8_on_one_line_are_one_modal_group():
    # rs274 2.9: "Two m codes used from same modal group"
    with pytest.raises(GCodeError, match="same modal group"):
        interpret("G21\nM7 M8\nG0 X1\nM2")
    assert interpret("G21\nM7\nM8\nG0 X1\nM2").moves["coolant"][0] == 3


def test_g94_and_g95_clear_the_feed_rate():
    # LinuxCNC's convert_feed_mode: a G94 or G95 block sets F to 0 (before its own F word)
    with pytest.raises(GCodeError, match="zero feed"):
        interpret("G21 G1 X1 F100\nG94 G1 X2\nM2")
    assert interpret("G21 G1 X1 F100\nG94 G1 X2 F50\nM2").moves["feed"][1] == 50
    # M72 restoring G94 from G93 clears F likewise: the next G1 has no feed
    with pytest.raises(GCodeError, match="zero feed") as info:
        interpret("G21 G1 F1 X1\nM70\nG93 G1 X2 F1\nM72\nG1 X3\nM2")
    assert info.value.line == 5


def test_m99_in_the_main_program_ends_it_as_m2():
    # rs274 (no loop_on_main_m99 in an INI) ends the program at a top-level M99
    p = interpret("G21\nG0 X1\nM99\nG0 X2\n")
    assert p.moves["kind"].tolist() == [MoveKind.RAPID, MoveKind.END]
    assert not any("no M2" in w for w in p.warnings)


def test_m99_in_an_o_word_sub_and_m98_are_refused_clearly():
    with pytest.raises(GCodeError, match="endsub or return") as info:
        interpret("G21\no1 sub\nG0 X1\nM99\no1 endsub\no1 call\nM2\n")
    assert info.value.line == 4
    with pytest.raises(GCodeError, match="M98"):
        interpret("G21\nM98 P100\nM2\n")


@pytest.mark.parametrize("line", ["M3 $0 S1", "S100 $-1", "M5 $-1", "M19 $0", "G97 $0 S5"])
def test_spindle_select_word_on_the_one_spindle(line):
    # LinuxCNC's $ (spindle number); rs274 has one spindle, $0 (or $-1: all of them)
    assert len(interpret(f"G21\n{line}\nG0 X2\nM2").moves) == 2


@pytest.mark.parametrize("line,needle", [
    ("M3 $1 S1", "spindle $1"),
    ("M51 P1 $0", "spindle $0"),
    ("G0 X1 $0", "$ word with no"),
])
def test_spindle_select_word_refused_as_rs274(line, needle):
    with pytest.raises(GCodeError) as info:
        interpret(f"G21\n{line}\nM2")
    assert needle in info.value.message and info.value.line == 2
