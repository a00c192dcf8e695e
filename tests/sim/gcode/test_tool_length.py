"""Tool length offsets as LinuxCNC's rs274 applies them (sim/gcode/tool_length.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, MoveKind, interpret, work_end
from sim.tooltable import ToolEntry

TABLE = {
    1: ToolEntry(number=1, pocket=1, diameter=6.0, z_offset=10.0, offsets={"Z": 10.0}),
    2: ToolEntry(number=2, pocket=2, diameter=3.0, z_offset=25.0, offsets={"Z": 25.0}),
}


def rapids(text: str, **kw) -> np.ndarray:
    m = interpret(text, tool_table=TABLE, **kw).moves
    return m[m["kind"] == MoveKind.RAPID]


def test_g43_on_its_own_line_shifts_the_program_position():
    # the machine stays at Z20; the program Z of the next move is one tool length lower
    r = rapids("G21 G0 Z20\nT1 M6\nG43 H1\nG0 X1\nM2")
    assert r["end"][1, 2] == pytest.approx(20.0)
    assert work_end(r)[1, 2] == pytest.approx(10.0)


def test_g43_on_the_tool_change_line_keeps_the_program_position_in_rs274():
    # rs274 stand-alone re-reads its position after M6; its canon never moved for G43:
    # program Z stays 20 and the machine lifts by the tool length
    p = interpret("G21 G0 Z20\nT1 M6 G43 H1\nG0 X1\nM2", tool_table=TABLE, after_tool_change="rs274")
    m = p.moves
    r = m[m["kind"] == MoveKind.RAPID]
    assert work_end(r)[1, 2] == pytest.approx(20.0)
    assert r["end"][1, 2] == pytest.approx(30.0)
    # the rows still chain: the shift is a tool change row from Z20 to Z30
    np.testing.assert_array_equal(m["start"][1:], m["end"][:-1])
    shift = m[(m["kind"] == MoveKind.TOOL_CHANGE) & (m["start"][:, 2] != m["end"][:, 2])]
    assert shift["start"][:, 2].tolist() == [20.0] and shift["end"][:, 2].tolist() == [30.0]


def test_g43_on_the_tool_change_line_keeps_the_machine_still_on_a_machine():
    # LinuxCNC driving a machine re-reads the machine position less the new offset: the
    # machine stays at Z20, no row moves it, the program Z is one tool length lower
    m = interpret("G21 G0 Z20\nT1 M6 G43 H1\nG0 X1\nM2", tool_table=TABLE).moves
    r = m[m["kind"] == MoveKind.RAPID]
    assert r["end"][1, 2] == pytest.approx(20.0)
    assert work_end(r)[1, 2] == pytest.approx(10.0)
    np.testing.assert_array_equal(m["start"][1:], m["end"][:-1])
    changes = m[m["kind"] == MoveKind.TOOL_CHANGE]
    np.testing.assert_array_equal(changes["start"], changes["end"])


def test_a_tool_change_undoes_an_offset_change_no_motion_carried_in_rs274():
    # G43 H2 then M6 with no motion between: the next move is at the old program height
    r = rapids("G21 G0 Z20\nG43 H2\nT1 M6\nG0 X1\nM2", after_tool_change="rs274")
    assert work_end(r)[1, 2] == pytest.approx(20.0)
    # M61 re-reads the position too
    r = rapids("G21 G0 Z20\nM61 Q2 G43\nG0 X1\nM2", after_tool_change="rs274")
    assert work_end(r)[1, 2] == pytest.approx(20.0)
    # on a machine the machine stays: program Z is 20 less tool 2's 25 mm
    r = rapids("G21 G0 Z20\nG43 H2\nT1 M6\nG0 X1\nM2")
    assert r["end"][1, 2] == pytest.approx(20.0) and work_end(r)[1, 2] == pytest.approx(-5.0)


def test_after_tool_change_is_checked():
    with pytest.raises(GCodeError, match="after_tool_change"):
        interpret("G0 X1", after_tool_change="sometimes")


def test_a_motion_on_the_tool_change_line_carries_the_offset():
    r = rapids("G21 G0 Z20\nT1 M6 G43 H1 G0 X1\nG0 X2\nM2")
    assert work_end(r)[2, 2] == pytest.approx(10.0)


def test_g43_h0_and_g43_without_h_take_the_loaded_tool():
    for g43 in ("G43 H0", "G43"):
        r = rapids(f"G21 G0 Z50\nT2 M6\n{g43}\nG0 X1\nM2")
        assert r["tool_length"][1] == 25.0 and work_end(r)[1, 2] == pytest.approx(25.0)


def test_tool_parameters_are_the_loaded_tools_entry_in_machine_units():
    # #5400 tool, #5403 its Z offset, #5410 its diameter: machine units (inch here), even in G21
    r = rapids("G21\nT1 M6\nG0 X[#5400] Y[#5403] Z[#5410]\nM2", machine_units="inch")
    np.testing.assert_allclose(work_end(r)[0, :3], [1.0, 10.0 / 25.4, 6.0 / 25.4])
    r = rapids("G21\nG0 X[#5400] Y[#5403]\nM2")   # no tool loaded: zeros
    np.testing.assert_allclose(work_end(r)[0, :2], [0.0, 0.0])


def test_stored_offsets_read_in_machine_units():
    # #5221 (G54 X) and #5161 (G28 X) are in machine units, as LinuxCNC keeps them
    r = rapids("G21 G10 L2 P1 X25.4\nG0 X0\nG28.1\nG0 X[#5221] Y[#5161]\nM2", machine_units="inch")
    np.testing.assert_allclose(work_end(r)[1, :2], [1.0, 1.0])


def test_g43_2_adds_a_tools_offsets_to_those_in_force():
    r = rapids("G21 G0 Z50\nT1 M6\nG43\nG43.2 H2\nG0 X1\nM2")
    assert r["tool_length"][1] == 35.0 and work_end(r)[1, 2] == pytest.approx(15.0)


@pytest.mark.parametrize("text,what", [
    ("G21 F100 G41 D1 G1 X5\nG43 H1\nM2", "tool length offset with cutter radius compensation"),
    ("G21 F100 G41 D1 G1 X5\nT1 M6\nM2", "cannot change tools with cutter radius compensation"),
    ("G21\nG10 L1 P1\nM2", "G10 L1 without offsets"),
    ("G21\nG43.2\nM2", "G43.2 needs an H word"),
    ("G21\nG43.2 Z1\nM2", "G43.2 with axis words"),
])
def test_refused_where_rs274_refuses(text, what):
    with pytest.raises(GCodeError, match=what) as info:
        interpret(text, tool_table=TABLE)
    assert info.value.line == 2


def test_a_tool_change_stops_the_spindle():
    m = interpret("G21 S1000 M3\nG0 X1\nT1 M6\nG0 X2\nM2", tool_table=TABLE).moves
    assert m["spindle_dir"][m["kind"] == MoveKind.RAPID].tolist() == [1, 0]


def test_g92_1_shares_a_line_with_g92_or_g10_and_runs_after_them():
    # LinuxCNC: G92.1/G92.2/G92.3 are a group of their own, run after G10/G28/G30/G92
    r = rapids("G21 G0 X10\nG92 X0 G92.1\nG0 Y1\nM2")
    assert work_end(r)[1, 0] == pytest.approx(10.0)
    with pytest.raises(GCodeError, match="same modal group"):
        interpret("G92 X0 G92.1", dialect="grbl")
