"""Cutter radius compensation: what the rs274 harness cannot see (messages, row order,
continuity of the tool path, warnings). Geometry against LinuxCNC is in test_rs274.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sim.gcode import GCodeError, Interpreter, MoveKind, interpret, load_program
from sim.tooltable import ToolEntry

RS274 = Path(__file__).resolve().parents[2] / "data" / "rs274"
TOOLS = {1: ToolEntry(number=1, pocket=1, diameter=4.0),
         2: ToolEntry(number=2, pocket=2, diameter=4.0, orientation=2)}
SQUARE = "G21 T1 M6 G0 X-10 Y-10 Z1\nG41 D1 G1 X0 Y0 F100\nG1 X20\n"


def refusal(text: str) -> GCodeError:
    with pytest.raises(GCodeError) as info:
        interpret(text, tool_table=TOOLS)
    return info.value


def test_entry_move_as_long_as_the_radius_is_refused_with_both_lengths():
    err = refusal("G21 T1 M6 G0 X0 Y0\nG41 D1 G1 X2 Y0 F100\nG1 Y10\nM2")
    assert err.line == 2
    assert "entry move (2.0000) is not greater than the tool radius (2.0000)" in err.message


def test_entry_with_no_motion_in_the_plane_is_refused():
    err = refusal("G21 T1 M6 G0 X0 Y0\nG41 D1\nG1 Z-1 F100\nM2")
    assert err.line == 3 and "entry move (0.0000)" in err.message


def test_dynamic_compensation_needs_a_diameter():
    err = refusal("G21 G0 X0 Y0\nG41.1 G1 X10 F100\nM2")
    assert err.line == 2 and "G41.1 needs a D word (tool diameter)" in err.message


def test_lathe_tool_needs_the_xz_plane():
    err = refusal("G21 T2 M6 G0 X0 Y0\nG42 D2\nM2")
    assert "lathe tool (orientation 2) needs the XZ plane (G18)" in err.message


def test_yz_plane_is_refused():
    err = refusal("G21 G19 T1 M6\nG41 D1\nM2")
    assert err.line == 2 and "only in the XY (G17) and XZ (G18) planes" in err.message


def test_arc_just_after_g40_is_refused():
    err = refusal(SQUARE + "G40\nG2 X30 Y10 R10\nM2")
    assert err.line == 5 and "must be straight" in err.message


def test_straight_move_after_g40_allows_arcs_again():
    m = interpret(SQUARE + "G40\nG1 X30\nG2 X40 Y10 R10\nM2", tool_table=TOOLS).moves
    assert MoveKind.ARC_CW in m["kind"]


def test_dwell_waits_behind_the_held_move():
    # the X20 line is held until Y20 shows the corner is concave; the dwell comes after it
    m = interpret(SQUARE + "G4 P1\nG1 Y20\nG40\nM2", tool_table=TOOLS).moves
    kinds = m["kind"].tolist()
    dwell = kinds.index(MoveKind.DWELL)
    assert m["line"][dwell - 1] == 3 and m["line"][dwell + 1] == 5
    np.testing.assert_allclose(m["start"][dwell, :2], [18, 2])   # where the cut-back line ended
    np.testing.assert_allclose(m["end"][dwell - 1, :2], [18, 2])


def test_stop_is_where_the_tool_is():
    m = interpret(SQUARE + "M0\nG1 Y20\nG40\nM2", tool_table=TOOLS).moves
    pause = m[m["kind"] == MoveKind.PAUSE][0]
    np.testing.assert_allclose(pause["end"][:2], [20, 2])   # the held line, made at the stop


def test_held_move_is_lost_without_program_end_and_a_warning_says_so():
    prog = interpret(SQUARE + "G1 Y20\n", tool_table=TOOLS)
    assert 4 not in prog.moves["line"]
    assert any("last move under cutter compensation is not made" in w for w in prog.warnings)


@pytest.mark.parametrize("name", sorted(p.name for p in (RS274 / "programs").glob("comp_*.ngc")))
def test_compensated_tool_path_is_continuous(name):
    """Every row starts where the one before it ended (also across G40 and M0), so the
    dexel simulation sweeps the path the tool really takes (up to a refused line)."""
    prog = load_program(RS274 / "programs" / name, tool_table=RS274 / "tools.tbl", machine_units="inch",
                        keep_going=True)
    m = prog.moves[:prog.errors[0].rows_before] if prog.errors else prog.moves
    np.testing.assert_allclose(m["start"][1:], m["end"][:-1], atol=1e-9)


def test_compensated_arcs_keep_their_turns():
    prog = load_program(RS274 / "programs" / "comp_turns.ngc", tool_table=RS274 / "tools.tbl", machine_units="inch")
    arcs = prog.moves[(prog.moves["kind"] == MoveKind.ARC_CW) | (prog.moves["kind"] == MoveKind.ARC_CCW)]
    assert arcs["turns"].tolist() == [2, 1, 1]   # rs274: ARC_FEED rotation 2, 1 and -1


def test_refused_streamed_line_leaves_compensation_as_it_was():
    it = Interpreter(tool_table=TOOLS)
    it.execute_line("G21 T1 M6 G0 X-10 Y-10")
    with pytest.raises(GCodeError):
        it.execute_line("G41 D1 G1 X0 Y0 F100 Q5")   # Q has no use: the whole line is refused
    assert it.comp == 400 and it.comp_engine is None
    it.execute_line("G41 D1 G1 X0 Y0 F100")
    with pytest.raises(GCodeError):
        it.execute_line("G1 X20 Q5")
    rows = it.execute_line("G1 X20 Y20")   # the X20 line never happened: the entry is cut back here
    assert rows["line"].tolist() == [3]
    np.testing.assert_allclose(rows["end"][0, :2], [-1.4142, 1.4142], atol=1e-4)


@pytest.mark.parametrize("fast", [True, False])
def test_simple_lines_after_g40_start_where_the_tool_is(fast):
    # runs of plain G1 lines may run in bulk (sim.gcode.fastpath): the first still starts at the tool
    simple = "".join(f"G1 X{30 + i}\n" for i in range(10))
    m = interpret(SQUARE + "G1 Y20\nG40\n" + simple + "M2", tool_table=TOOLS, fast=fast).moves
    np.testing.assert_allclose(m["start"][1:], m["end"][:-1], atol=1e-9)
    np.testing.assert_allclose(m["end"][-2, :2], [39, 20])


def test_inverse_time_feeds_are_linuxcncs():
    """G93 under compensation: every row of a block (corner arc, cut-back line) takes the feed
    of the programmed length, as rs274's SET_FEED_RATE calls say."""
    prog = load_program(RS274 / "programs" / "comp_inverse_time.ngc", tool_table=RS274 / "tools.tbl",
                        machine_units="inch")
    m = prog.moves[np.isin(prog.moves["line"], [7, 8, 9, 10, 11])]
    np.testing.assert_allclose(m["feed"], [56.5685, 80, 80, 80, 94.2478, 1.0], atol=1e-4)
