"""Words dexmon refuses by design, clearly and where rs274 would read them (issue 13):
U V W axis words (a mill has X Y Z A B C) and the lathe-only G codes. rs274_harness's
BY_DESIGN takes such a refusal as by design when the motions before it equal rs274's."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, interpret, work_end
from tests.sim.gcode.rs274_harness import BY_DESIGN


@pytest.mark.parametrize("line,needle", [
    ("G76 P0.05 Z-1 I-.075 J0.008 K0.045 Q29.5 L2 E0.045", "G76 is a lathe-only threading cycle"),
    ("G7", "G7 is a lathe-only diameter mode"),
    ("G8", "G8 is a lathe-only radius mode"),
    ("G70 Q100", "G70 is a lathe-only finishing cycle"),
    ("G71.1 Q100 X15 Z3 D1", "G71.1 is a lathe-only roughing cycle"),
    ("G72 Q100 X1 Z1 D0.5", "G72 is a lathe-only facing cycle"),
    ("G1 W100 F2000", "W axis words are not supported"),
    ("G0 U1", "U axis words are not supported"),
])
def test_refused_by_design_with_a_clear_message(line, needle):
    with pytest.raises(GCodeError) as info:
        interpret(f"G21 G18\nG0 X1\n{line}\nM2", filename="lathe.ngc")
    assert info.value.line == 3 and needle in info.value.message
    assert BY_DESIGN.search(info.value.message)


def test_g28_without_axis_words_moves_to_its_waypoint_first():
    # LinuxCNC's G28/G30 traverse to the waypoint (here where the tool is) before home
    p = interpret("G21 G0 X1 Y2 Z3\nG28\nM2", var_file={5161: 10.0, 5162: 20.0, 5163: 30.0})
    rows = p.moves[p.moves["kind"] == MoveKind.RAPID]
    np.testing.assert_allclose(work_end(rows)[:, :3], [[1, 2, 3], [1, 2, 3], [10, 20, 30]])


def test_rows_before_counts_the_rows_made_before_an_error_in_a_loop():
    # the harness compares the motions made before a refusal: in a loop these are not the
    # rows of earlier lines (cone.ngc refuses its W word on the first pass of a loop)
    from tests.sim.gcode.rs274_harness import dexmon_motions

    text = "G21\n#1=0\no1 while [#1 LT 3]\nG0 X#1\no2 if [#1 EQ 1]\nG0 W1\no2 endif\n#1=[#1+1]\no1 endwhile\nM2"
    p = interpret(text, keep_going=True)
    assert [e.line for e in p.errors] == [6] and [e.rows_before for e in p.errors] == [2]
    assert [m.end[0] for m in dexmon_motions(p, rows=p.errors[0].rows_before)] == [0, 1]
    assert [e.rows_before for e in interpret("o1 if [1]\nG0 X1\n", keep_going=True).errors] == [None]  # found before the run


def test_grbl_g28_without_axis_words_goes_home_at_once():
    p = interpret("G21 G0 X1 Y2 Z3\nG28\n", dialect="grbl")
    assert (p.moves["kind"] == MoveKind.RAPID).sum() == 2
