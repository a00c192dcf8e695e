"""Canned cycles as LinuxCNC's rs274 runs them (sim/gcode/cycles.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, interpret, work_end


def moves(text: str) -> np.ndarray:
    return interpret(text).moves


def heights_after_feeds(m: np.ndarray) -> list[float]:
    """Z at the end of the row after each feed (the retract)."""
    feeds = np.flatnonzero(m["kind"] == MoveKind.FEED)
    return [float(work_end(m)[i + 1, 2]) for i in feeds]


def test_cycle_retracts_to_r_when_the_program_names_neither_g98_nor_g99():
    m = moves("G21 G0 X0 Y0 Z20\nG81 X10 Z-2 R2 F100\nX20\nG80\nM2")
    assert heights_after_feeds(m) == [2.0, 2.0]


def test_g98_retracts_to_the_level_before_the_first_cycle_of_the_sequence():
    # the first hole retracts to R (G99); G98 on the second still goes back to 20, not 2
    m = moves("G21 G0 X0 Y0 Z20\nG99 G81 X10 Z-2 R2 F100\nG98 X20\nG80\nM2")
    assert heights_after_feeds(m) == [2.0, 20.0]
    # another motion starts a new sequence: G98 then goes back to where that left the tool
    m = moves("G21 G0 X0 Y0 Z20\nG81 X10 Z-2 R2 F100\nG0 Z5\nG98 G81 X20 Z-2 R2\nG80\nM2")
    assert heights_after_feeds(m) == [2.0, 5.0]


def test_g91_repeated_cycle_measures_r_from_the_level_before_the_first_cycle():
    # R-7 and Z-5 from the initial 10 on every block of the sequence: R 3, bottom -2
    m = moves("G21 G0 X0 Y0 Z10\nG91 G99 G81 X10 Z-5 R-7 F100\nX10\nX10 L2\nG90 G80\nM2")
    feeds = m[m["kind"] == MoveKind.FEED]
    np.testing.assert_allclose(work_end(feeds)[:, [0, 2]], [[10, -2], [20, -2], [30, -2], [40, -2]])


def test_peck_count_is_computed_in_program_units():
    # 0.1 - 3 * 0.2 is a hair below -0.5 in inches: rs274 makes two pecks, then the bottom
    m = moves("G20 G0 X0 Y0 Z1\nG83 X0 Z-0.5 R0.1 Q0.2 F10\nG80\nM2")
    feeds = m[m["kind"] == MoveKind.FEED]
    np.testing.assert_allclose(work_end(feeds)[:, 2] / 25.4, [-0.1, -0.3, -0.5])


def test_g89_feeds_out_to_the_clear_height_and_g88_stops_for_a_manual_retract():
    m = moves("G21 G0 X0 Y0 Z20 S500 M3\nG98 G89 X5 Z-3 R2 P1 F100\nG80\nM2")
    out = m[m["kind"] == MoveKind.FEED][-1]
    assert work_end(out[None])[0, 2] == 20.0
    m = moves("G21 G0 X0 Y0 Z20 S500 M3\nG88 X5 Z-3 R2 P1 F100\nG0 X10\nM2")
    kinds = m["kind"].tolist()
    assert MoveKind.PAUSE in kinds
    # after the stop the program continues from R (the operator retracted the spindle)
    assert work_end(m)[-2, 2] == 2.0


def test_cycle_words_are_needed_unless_the_same_cycle_ran_before():
    interpret("G21 G0 Z5\nG81 X1 Z-1 R1 F100\nX2\nM2")
    for text, what in [("G21 G0 Z5\nG81 X1 Z-1 R1 F100\nG80\nG81 X2\nM2", "R word"),
                       ("G21 G0 Z5\nG81 X1 Z-1 R1 F100\nG82 X2 R1 P1\nM2", "Z word"),
                       ("G21 G0 Z5\nG82 X1 Z-1 R1 F100\nM2", "P word"),
                       ("G21 G0 Z5\nG83 X1 Z-1 R1 F100\nM2", "Q word"),
                       ("G21 G0 Z5\nG86 X1 Z-1 R1 P1 F100\nM2", "spindle"),
                       ("G21 G0 Z5 M3 S100\nG74 X1 Z-1 R1 F100\nM2", "counterclockwise"),
                       ("G21 G0 Z5 G93\nG81 X1 Z-1 R1 F100\nM2", "inverse time")]:
        with pytest.raises(GCodeError, match=what):
            interpret(text)


def test_g80_on_a_line_with_another_motion_code_gives_way_to_it():
    m = moves("G21 G0 Z5\nG80 G1 X3 F100\nG0 G80 X4\nM2")
    assert m["kind"][1:3].tolist() == [MoveKind.FEED, MoveKind.RAPID]


def test_g88_pause_row_carries_the_manual_retract():
    m = moves("G21 G0 X0 Y0 Z20 S500 M3\nG88 X5 Z-3 R2 P1 F100\nG0 X10\nM2")
    pause = m[m["kind"] == MoveKind.PAUSE][0]
    assert pause["start"][2] == -3.0 and pause["end"][2] == 2.0
    np.testing.assert_array_equal(m["start"][1:], m["end"][:-1])   # the rows chain


@pytest.mark.parametrize("text", ["G21 G0 Z5 F100\nG81\nM2", "G21 G0 Z5 F100\nG38.3\nM2"])
def test_a_cycle_or_probe_code_without_axis_words_is_refused(text):
    with pytest.raises(GCodeError, match="needs axis words") as info:
        interpret(text)
    assert info.value.line == 2
